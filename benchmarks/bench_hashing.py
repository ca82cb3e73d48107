"""What hashing the raw files costs (issue 13 item 5: content decides change).

    python benchmarks/bench_hashing.py [--machines 50] [--keep DIR] [--no-planning]

The clean rule carries each raw file's SHA-256 as a param (``workflow/rules/common.smk``,
``raw_stamp``; ``rafi.ops.raw_hashes``), cached in ``results/.raw_hashes.json`` on
``(path, size, mtime_ns, ctime_ns, inode)``. This prints, in a table:

* cold hash of the shipped ``raw/`` (empty cache: every file read and hashed);
* cold hash of a raw tree of ``--machines`` machines built from copies of the shipped folders
  (real copies: new inodes, so nothing is shared with the shipped files);
* warm: the same tree with the cache written (only ``stat`` per file);
* planning: ``snakemake -n`` of that project with no cache (the dry run hashes every file and,
  being a dry run, writes no cache) and with the cache a real run would have left.

"Cold" is cold for the cache, not for the disk: the files are in the page cache (just
copied), so the figures are the CPU cost of SHA-256 plus reading from memory. Figures are wall
times; run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rafi.ops.raw_hashes import CACHE_NAME, RawHashCache, raw_stamps  # noqa: E402


def raw_paths(raw: Path) -> list[Path]:
    """Every visible file under ``raw`` (one folder per machine), sorted."""
    return sorted(p for p in raw.glob("*/*") if p.is_file() and not p.name.startswith("."))


def build_tree(dest: Path, n_machines: int) -> Path:
    """``dest/raw`` with ``n_machines`` folders, each a real copy of one shipped machine folder."""
    shipped = sorted(p for p in (ROOT / "raw").iterdir() if p.is_dir())
    raw = dest / "raw"
    for i in range(n_machines):
        src = shipped[i % len(shipped)]
        shutil.copytree(src, raw / f"{src.name}-{i:02d}")
    return raw


def time_hash(paths: list[Path], cache: Path) -> tuple[float, int, int]:
    """Seconds for :func:`raw_stamps` over ``paths`` (cache saved); files hashed, files reused."""
    t0 = time.perf_counter()
    raw_stamps(paths, cache)
    elapsed = time.perf_counter() - t0
    probe = RawHashCache(cache)  # count what a second pass would do, outside the timing
    for p in paths:
        probe.sha256(p)
    return elapsed, len(paths), probe.reused


def plan_seconds(proj: Path) -> float:
    """Wall time of ``snakemake -n --cores 1`` in ``proj`` (a frozen copy of rafi/ beside it)."""
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "--cores", "1", "-q"],
        cwd=proj,
        capture_output=True,
        text=True,
    )
    elapsed = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"snakemake -n failed:\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return elapsed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--machines", type=int, default=50, help="machines in the large tree (default 50)")
    parser.add_argument("--keep", help="build in this folder and keep it (default: a temporary one)")
    parser.add_argument("--no-planning", action="store_true", help="skip the snakemake -n timings")
    args = parser.parse_args(argv)

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="rafi-bench-hash-"))
    rows = []
    try:
        shipped = raw_paths(ROOT / "raw")
        mb = sum(p.stat().st_size for p in shipped) / 1e6
        t, n, _ = time_hash(shipped, work / "shipped" / CACHE_NAME)
        rows.append(("cold hash, shipped raw/", n, mb, t))

        proj = work / "proj"
        proj.mkdir(parents=True, exist_ok=True)
        raw = build_tree(proj, args.machines)
        big = raw_paths(raw)
        big_mb = sum(p.stat().st_size for p in big) / 1e6
        cache = proj / "results" / CACHE_NAME
        t, n, _ = time_hash(big, cache)
        rows.append((f"cold hash, {args.machines} machines", n, big_mb, t))
        t, n, reused = time_hash(big, cache)
        rows.append((f"warm (cache), {args.machines} machines", n, big_mb, t))
        assert reused == n, "the warm pass should reuse every cached hash"

        if not args.no_planning:
            shutil.copy2(ROOT / "Snakefile", proj / "Snakefile")
            shutil.copy2(ROOT / "config.yaml", proj / "config.yaml")
            for name in ("workflow", "rafi"):
                shutil.copytree(ROOT / name, proj / name, ignore=shutil.ignore_patterns("__pycache__"))
            cache.unlink()
            rows.append((f"snakemake -n, no cache, {args.machines} m.", len(big), big_mb, plan_seconds(proj)))
            raw_stamps(big, cache)  # what a real run leaves behind
            rows.append((f"snakemake -n, cache, {args.machines} m.", len(big), big_mb, plan_seconds(proj)))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)

    print(f"{'case':<36} {'files':>6} {'MB':>8} {'s':>8} {'MB/s':>8} {'ms/file':>8}")
    for name, n, size, t in rows:
        rate = "-" if name.startswith("snakemake") else f"{size / t:.0f}"  # planning is not all hashing
        print(f"{name:<36} {n:>6} {size:>8.1f} {t:>8.3f} {rate:>8} {1000 * t / max(n, 1):>8.2f}")
    print(f"(cpu count {os.cpu_count()}; python {sys.version.split()[0]})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
