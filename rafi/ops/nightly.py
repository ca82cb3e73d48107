"""Nightly retraining: pick up new logs, retrain, qualify, promote or keep the champion.

Runs the Snakemake pipeline (target rule `nightly`: every table, the champion/challenger
decision and the report of every machine under raw/) under an exclusive lock, then reads
each machine's registry/decision.json and audit.csv. See docs/operations.md.

Exit codes (most severe first when several apply: 1 > 3 > 2 > 4 > 0):
  0   all good (promoted, kept, or nothing new)
  1   the pipeline failed (Snakemake error; other machines carried on with --keep-going)
  3   recalibration due: the champion drifted on the newest validation logs
  2   tonight's candidate failed qualification (the champion was kept)
  4   some input was quarantined (other machines/files carried on)
  64  usage error (unknown machine or model id for --promote)
  75  another nightly run holds the lock (EX_TEMPFAIL: try again later)

Examples:
  rafi nightly --cores 2                   # cron / systemd
  rafi nightly --dry-run                   # what would run, no lock, no changes
  rafi nightly --machine tapping-center-a --promote 3f2a9c1b   # roll back the champion
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import fcntl
import json
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from rafi.errors import LockHeld

EXIT_OK = 0
EXIT_PIPELINE_FAILED = 1
EXIT_REJECTED = 2
EXIT_RECALIBRATION_DUE = 3
EXIT_QUARANTINED = 4
EXIT_USAGE = 64
EXIT_LOCKED = 75  # EX_TEMPFAIL (sysexits.h)

#: Severity order used when several codes apply (first wins).
SEVERITY = (EXIT_PIPELINE_FAILED, EXIT_RECALIBRATION_DUE, EXIT_REJECTED, EXIT_QUARANTINED, EXIT_OK)

LOCK_NAME = ".nightly.lock"
STATE_NAME = ".nightly.state.json"

#: Test hook: seconds to sleep while holding the lock, before anything else (tests only).
HOLD_ENV = "RAFI_NIGHTLY_TEST_HOLD_S"


def most_severe(codes) -> int:
    """The most severe of ``codes`` by :data:`SEVERITY` (0 for none)."""
    codes = set(codes)
    for code in SEVERITY:
        if code in codes:
            return code
    return EXIT_OK


# --------------------------------------------------------------------------- lock


class NightlyLock:
    """Exclusive, non-blocking ``flock`` on ``results/.nightly.lock``.

    The kernel releases a flock when its process dies, so a crashed night never leaves
    a stale lock. The file itself is kept (deleting lock files races); while held it
    holds ``pid=<pid> started=<UTC time> host=<host>``, and it is emptied on release.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._fd: int | None = None

    def __enter__(self) -> NightlyLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 4096, 0).decode("utf-8", "replace")
            finally:
                os.close(fd)
            raise LockHeld(self.path, holder) from None
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        text = f"pid={os.getpid()} started={stamp} host={os.uname().nodename}\n".encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, text, 0)
        os.fsync(fd)
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)


def lock_is_free(path: str | os.PathLike) -> bool:
    """True if nobody holds the flock on ``path`` (probe; for tests and status)."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)


# --------------------------------------------------------------------------- config


def load_config(directory: Path, config_file: str) -> dict:
    import yaml

    path = Path(config_file)
    if not path.is_absolute():
        path = directory / path
    with open(path, encoding="utf-8") as fh:
        return yaml.safe_load(fh) or {}


@dataclass
class Paths:
    directory: Path
    raw_dir: Path
    results_dir: Path

    @classmethod
    def from_config(cls, directory: Path, config: dict) -> Paths:
        d = directory.resolve()
        return cls(d, d / str(config.get("raw_dir", "raw")), d / str(config.get("results_dir", "results")))

    def machines(self) -> list[str]:
        if not self.raw_dir.is_dir():
            return []
        return sorted(
            p.name
            for p in self.raw_dir.iterdir()
            if p.is_dir()
            and not p.name.startswith(".")
            and any(f.is_file() and not f.name.startswith(".") for f in p.iterdir())
        )

    def registry(self, machine: str) -> Path:
        return self.results_dir / machine / "registry"


# --------------------------------------------------------------------------- snakemake


def snakemake_base(args, config_overrides: dict) -> list[str]:
    cfg = Path(args.config_file)
    cfg = cfg if cfg.is_absolute() else Path(args.directory) / cfg
    # rafi.ops.snakemake_run = `python -m snakemake` without Snakemake's idle second at exit
    cmd = [
        sys.executable,
        "-m",
        "rafi.ops.snakemake_run",
        "--directory",
        str(args.directory),
        "--configfile",
        str(cfg),
    ]
    snakefile = Path(args.directory) / "Snakefile"
    if snakefile.exists():
        cmd += ["--snakefile", str(snakefile)]
    if config_overrides:
        cmd += ["--config"] + [f"{k}={v}" for k, v in config_overrides.items()]
    return cmd


def config_overrides(args) -> dict:
    over = {"on_bad_input": "quarantine"}
    if args.machine:
        over["nightly_machines"] = args.machine
    if getattr(args, "no_report", False):
        over["nightly_report"] = "false"
    return over


_TABLE_ROW = re.compile(r"^(\w+)\s+(\d+)$")


def pending_jobs(args, overrides: dict) -> tuple[int, dict[str, int], str]:
    """Dry run: ``(returncode, {rule: n_jobs}, output)``; empty dict = nothing to do."""
    cmd = snakemake_base(args, overrides) + ["-n", "--cores", str(args.cores), "nightly"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=args.directory)
    text = proc.stdout + proc.stderr
    jobs: dict[str, int] = {}
    if proc.returncode == 0 and "Nothing to be done" not in text:
        in_table = False
        for line in text.splitlines():
            s = line.strip()
            if s == "Job stats:":
                in_table = True
                continue
            if in_table:
                m = _TABLE_ROW.match(s)
                if m and m.group(1) == "total":
                    break
                if m and m.group(1) not in ("job", "nightly"):
                    jobs[m.group(1)] = int(m.group(2))
        if not jobs and "Job stats:" in text:
            jobs["nightly"] = 1  # only the target itself is out of date
    return proc.returncode, jobs, text


@dataclass
class JobTracker:
    """Turns Snakemake's log stream into one progress line per finished job."""

    out: object = sys.stdout
    jobs: dict = field(default_factory=dict)
    ran: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    _rule: str | None = None
    _wildcards: str = ""
    _jobid: str | None = None
    _total: str = "?"
    nothing_to_do: bool = False

    def feed(self, line: str) -> None:
        s = line.strip()
        if s.startswith("Nothing to be done"):
            self.nothing_to_do = True
            return
        m = re.match(r"^(?:local)?rule (\w+):$", s)
        if m:
            self._rule, self._wildcards, self._jobid = m.group(1), "", None
            return
        if s.startswith("wildcards:") and self._rule:
            self._wildcards = s.split(":", 1)[1].strip()
            if self._jobid is not None:
                self.jobs[self._jobid] = (self._rule, self._wildcards)
            return
        m = re.match(r"^jobid: (\d+)$", s)
        if m and self._rule:
            self._jobid = m.group(1)
            self.jobs[self._jobid] = (self._rule, self._wildcards)
            return
        m = re.match(r"^Finished jobid: (\d+)", s)
        if m:
            rule, wc = self.jobs.get(m.group(1), ("?", ""))
            if rule != "nightly":
                self.ran.append((rule, wc))
                print(
                    f"rafi nightly: [{len(self.ran)}/{self._total}] done {rule}" + (f" ({wc})" if wc else ""),
                    file=self.out,
                    flush=True,
                )
            return
        m = re.match(r"^\d+ of (\d+) steps", s)
        if m:
            self._total = str(max(int(m.group(1)) - 1, 0))
            return
        m = re.match(r"^Error in rule (\w+):", s)
        if m:
            self.failed.append(m.group(1))
            print(f"rafi nightly: FAILED {m.group(1)} (see the Snakemake log)", file=self.out, flush=True)


def run_snakemake(args, overrides: dict, log_fh, planned: int = 0) -> tuple[int, JobTracker]:
    cmd = snakemake_base(args, overrides) + [
        "--cores",
        str(args.cores),
        "--rerun-incomplete",
        "--keep-going",
        "nightly",
    ]
    tracker = JobTracker(_total=str(planned) if planned else "?")
    print("rafi nightly: " + " ".join(cmd[1:]), flush=True)
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=args.directory, bufsize=1
    )
    assert proc.stdout is not None
    tail: collections.deque = collections.deque(maxlen=25)
    for line in proc.stdout:
        if log_fh is not None:
            log_fh.write(line)
        tail.append(line)
        tracker.feed(line)
    code = proc.wait()
    if code != 0 and not tracker.failed:  # it failed before any job: show why
        print("".join(tail), file=sys.stderr, end="")
        print("rafi nightly: the pipeline cannot be planned (see above)", file=sys.stderr)
    return code, tracker


# --------------------------------------------------------------------------- fast path


def _tree(root: Path, skip=()) -> list[str]:
    out = []
    if root.is_file():
        st = root.stat()
        return [f"{root.name}\t{st.st_size}\t{st.st_mtime_ns}"]
    if not root.is_dir():
        return out
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in ("__pycache__", ".snakemake"))
        for name in sorted(filenames):
            p = Path(dirpath) / name
            rel = str(p.relative_to(root))
            if rel in skip or name.endswith(".part"):
                continue
            with contextlib.suppress(OSError):
                st = p.stat()
                out.append(f"{rel}\t{st.st_size}\t{st.st_mtime_ns}")
    return out


def fingerprint(args, paths: Paths, overrides: dict) -> str:
    """Hash of everything that can make Snakemake re-run a job: config, overrides, Snakefile
    and workflow/, the rafi package, raw/ and results/ (names, sizes, mtimes).

    Equal to the value stored after the last successful night -> nothing can be out of
    date, and the Snakemake dry run (2-7 s) is skipped. Any doubt -> the dry run decides.
    """
    import hashlib
    import importlib.util

    h = hashlib.sha256()
    cfg = Path(args.config_file)
    cfg = cfg if cfg.is_absolute() else paths.directory / cfg
    h.update(cfg.read_bytes() if cfg.exists() else b"")
    h.update(json.dumps(overrides, sort_keys=True).encode())
    spec = importlib.util.find_spec("rafi")
    rafi_dir = Path(spec.origin).parent if spec and spec.origin else Path(__file__).parent
    parts = {
        "snakefile": _tree(paths.directory / "Snakefile"),
        "workflow": _tree(paths.directory / "workflow"),
        "rafi": _tree(rafi_dir),
        "raw": _tree(paths.raw_dir),
        "results": _tree(paths.results_dir, skip={LOCK_NAME, STATE_NAME, "nightly.log"}),
    }
    h.update(json.dumps(parts, sort_keys=True).encode())
    return h.hexdigest()


def read_state(paths: Paths) -> dict:
    with contextlib.suppress(OSError, ValueError):
        return json.loads((paths.results_dir / STATE_NAME).read_text(encoding="utf-8"))
    return {}


def write_state(paths: Paths, fp: str) -> None:
    from rafi.artefact import write_text_atomic

    write_text_atomic(
        paths.results_dir / STATE_NAME,
        json.dumps({"fingerprint": fp, "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}) + "\n",
    )


# --------------------------------------------------------------------------- status


@dataclass
class MachineStatus:
    machine: str
    decision: dict | None
    quarantined: list[str]
    tonight: bool

    def codes(self) -> set[int]:
        codes = set()
        d = self.decision or {}
        if d.get("recalibration_due"):
            codes.add(EXIT_RECALIBRATION_DUE)
        if self.tonight and d.get("decision") == "rejected":
            codes.add(EXIT_REJECTED)
        if self.quarantined:
            codes.add(EXIT_QUARANTINED)
        return codes

    def line(self) -> str:
        d = self.decision
        if not d:
            return f"{self.machine}: no decision yet"
        text = (
            f"{self.machine}: {d.get('decision')}"
            f"{' tonight' if self.tonight else ' (' + str(d.get('time')) + ')'}; champion "
            f"{_short(d.get('champion_id_after'))}"
        )
        if d.get("decision") in ("promoted", "rejected"):
            text += f", candidate {_short(d.get('candidate_id'))}"
        sp = [str(s.get("speed_rpm")) for s in d.get("retrained_speeds") or []]
        if sp and d.get("decision") == "promoted":
            text += f", retrained speeds {', '.join(sp)} r/min"
        if d.get("recalibration_due"):
            dr = d.get("drift") or {}
            text += (
                f"; RECALIBRATION DUE: max residual {_num(dr.get('new_max_residual_um'))} um on "
                f"new logs vs {_num(dr.get('reference_max_residual_um'))} um at promotion"
            )
        if self.quarantined:
            text += f"; quarantined: {', '.join(self.quarantined)}"
        return text


def _short(mid) -> str:
    return str(mid)[:12] if mid else "none"


def _num(v) -> str:
    return "?" if v is None else f"{float(v):.2f}"


def _parse_time(text) -> float | None:
    if not text:
        return None
    try:
        import calendar

        return calendar.timegm(time.strptime(str(text), "%Y-%m-%dT%H:%M:%SZ"))
    except ValueError:
        return None


def machine_status(paths: Paths, machine: str, night_start: float | None) -> MachineStatus:
    decision = None
    dpath = paths.registry(machine) / "decision.json"
    if dpath.exists():
        with contextlib.suppress(ValueError, OSError):
            decision = json.loads(dpath.read_text(encoding="utf-8"))
    quarantined = []
    audit = paths.results_dir / machine / "audit.csv"
    if audit.exists():
        import csv

        with open(audit, newline="", encoding="utf-8") as fh:
            for row in csv.DictReader(fh):
                if (row.get("status") or "").strip() == "quarantined":
                    quarantined.append(f"{row.get('file')} ({row.get('reason') or 'no reason'})")
    tonight = False
    if decision and night_start is not None:
        t = _parse_time(decision.get("time"))
        tonight = t is not None and t >= night_start - 1
    return MachineStatus(machine, decision, quarantined, tonight)


def last_activity(statuses: list[MachineStatus]) -> str:
    times = [s.decision.get("time") for s in statuses if s.decision and s.decision.get("time")]
    return max(times) if times else "the first run"


# --------------------------------------------------------------------------- CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cores", type=int, default=2, help="cores for Snakemake (default 2)")
    parser.add_argument(
        "--dry-run", action="store_true", help="only show what would run (no lock, nothing written)"
    )
    parser.add_argument("--machine", help="only this machine (folder under raw/)")
    parser.add_argument(
        "--config-file",
        default="config.yaml",
        help="pipeline config (default config.yaml, relative to --directory)",
    )
    parser.add_argument("--directory", default=".", help="project directory (default .)")
    parser.add_argument(
        "--promote",
        metavar="MODEL_ID",
        help="point the champion of --machine at this registered model "
        "(id or unique prefix; rollback) and exit",
    )
    parser.add_argument(
        "--full-check",
        action="store_true",
        help="always ask Snakemake what is out of date (skip the fast "
        "fingerprint check of config, code, raw/ and results/)",
    )
    parser.add_argument(
        "--no-report", action="store_true", help="leave the report out of tonight's targets (faster; tests)"
    )
    parser.add_argument(
        "--log-file", help="append Snakemake's full output to this file (default results/nightly.log)"
    )


def run(args) -> int:
    directory = Path(args.directory).resolve()
    args.directory = directory
    try:
        config = load_config(directory, args.config_file)
    except OSError as exc:
        print(f"rafi nightly: cannot read config: {exc}", file=sys.stderr)
        return EXIT_USAGE
    paths = Paths.from_config(directory, config)
    machines = paths.machines()
    if args.machine and args.machine not in machines:
        print(
            f"rafi nightly: no machine {args.machine!r} under {paths.raw_dir} "
            f"(found: {', '.join(machines) or 'none'})",
            file=sys.stderr,
        )
        return EXIT_USAGE
    if args.machine:
        machines = [args.machine]
    overrides = config_overrides(args)

    if args.dry_run:
        rc, jobs, text = pending_jobs(args, overrides)
        if rc != 0:
            print(text, file=sys.stderr)
            return EXIT_PIPELINE_FAILED
        if not jobs:
            print("rafi nightly (dry run): nothing to do")
        else:
            print(
                "rafi nightly (dry run): would run " + ", ".join(f"{r} x{n}" for r, n in sorted(jobs.items()))
            )
        return EXIT_OK

    lock_path = paths.results_dir / LOCK_NAME
    try:
        with NightlyLock(lock_path):
            print(f"rafi nightly: lock {lock_path} acquired (pid {os.getpid()})", flush=True)
            hold = os.environ.get(HOLD_ENV)
            if hold:
                time.sleep(float(hold))
            if args.promote:
                return _promote(args, paths, machines)
            return _night(args, paths, machines, overrides)
    except LockHeld as exc:
        print(
            f"rafi nightly: another nightly run is in progress ({exc.holder}; lock "
            f"{exc.path}); exiting with {EXIT_LOCKED} (try again later)",
            file=sys.stderr,
        )
        return EXIT_LOCKED


def _promote(args, paths: Paths, machines: list[str]) -> int:
    from rafi.errors import RegistryError
    from rafi.ops.registry import promote

    if not args.machine:
        if len(machines) != 1:
            print("rafi nightly: --promote needs --machine", file=sys.stderr)
            return EXIT_USAGE
        args.machine = machines[0]
    reg = paths.registry(args.machine)
    try:
        rec = promote(reg, args.machine, args.promote, decision_path=reg / "decision.json")
    except RegistryError as exc:
        print(f"rafi nightly: {exc}", file=sys.stderr)
        return EXIT_USAGE
    print(
        f"rafi nightly: {args.machine}: champion {_short(rec['champion_id_before'])} -> "
        f"{_short(rec['champion_id_after'])} (recorded in {reg / 'history.jsonl'})"
    )
    return EXIT_OK


def _night(args, paths: Paths, machines: list[str], overrides: dict) -> int:
    started = time.time()
    night_start = float(int(started))
    fp = None if args.full_check else fingerprint(args, paths, overrides)
    if fp is not None and read_state(paths).get("fingerprint") == fp:
        # nothing changed since the last successful night: no need to ask Snakemake
        return _nothing_new(paths, machines, started)
    # One Snakemake run, no separate dry run (it would build the job graph twice): Snakemake
    # itself says "Nothing to be done" when no new data arrived.
    log_file = Path(args.log_file) if args.log_file else paths.results_dir / "nightly.log"
    log_file.parent.mkdir(parents=True, exist_ok=True)
    with open(log_file, "a", encoding="utf-8") as log_fh:
        log_fh.write(
            f"\n===== rafi nightly {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} pid {os.getpid()}\n"
        )
        src, tracker = run_snakemake(args, overrides, log_fh)
    if src == 0 and tracker.nothing_to_do and not tracker.ran:
        write_state(paths, fingerprint(args, paths, overrides))
        return _nothing_new(paths, machines, started)
    if src == 0:
        write_state(paths, fingerprint(args, paths, overrides))
    else:
        with contextlib.suppress(FileNotFoundError):
            (paths.results_dir / STATE_NAME).unlink()
    statuses = [machine_status(paths, m, night_start) for m in machines]
    code = _report(statuses, pipeline_failed=src != 0)
    print(
        f"rafi nightly: {len(tracker.ran)} job(s) in {time.time() - started:.1f} s; "
        f"exit {code} (log {log_file})"
    )
    return code


def _nothing_new(paths: Paths, machines: list[str], started: float) -> int:
    statuses = [machine_status(paths, m, None) for m in machines]
    champs = (
        ", ".join(f"{s.machine} {_short((s.decision or {}).get('champion_id_after'))}" for s in statuses)
        or "none"
    )
    print(
        f"rafi nightly: nothing new since {last_activity(statuses)}: champion {champs} "
        f"stays ({time.time() - started:.1f} s)"
    )
    return _report(statuses)


def _report(statuses: list[MachineStatus], pipeline_failed: bool = False) -> int:
    codes = {EXIT_PIPELINE_FAILED} if pipeline_failed else set()
    for s in statuses:
        print("rafi nightly: " + s.line())
        codes |= s.codes()
    if pipeline_failed:
        print("rafi nightly: the pipeline FAILED for some job (details in the log)")
    return most_severe(codes)


def main(argv=None) -> int:  # pragma: no cover - `python -m rafi.ops.nightly`
    parser = argparse.ArgumentParser(
        prog="rafi nightly", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
