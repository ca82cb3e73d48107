"""Where a project's files are, as ``rafi nightly`` sees them (config, raw/, results/)."""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass
from pathlib import Path

from rafi.contract import REGISTRY_DIR, result_file
from rafi.errors import InputSpecError, RawFormatError, SettingsError
from rafi.settings import machine_settings, read_config, run_settings, split_unit, validate_config


def config_path(directory: Path, config_file: str | Path) -> Path:
    """``config_file`` resolved against the project ``directory`` unless absolute."""
    path = Path(config_file)
    return path if path.is_absolute() else Path(directory) / path


def load_config(directory: Path, config_file: str | Path, *, say: bool = True) -> dict:
    """The pipeline config (YAML) of the project in ``directory``; ``{}`` for an empty file
    (:func:`rafi.settings.read_config`; ``say=False``: a second reading says nothing again).

    Raises
    ------
    rafi.errors.SettingsError
        If the file cannot be read or parsed, or the config does not follow the contract
        (:func:`rafi.settings.validate_config`); a prior's id in ``checks.confirmed`` written
        unquoted is taken back first where it can only be that id
        (:func:`rafi.family.confirmation.unquoted_ids`).
    """
    config = read_config(config_path(directory, config_file), say=say)
    validate_config(config)
    return config


@dataclass
class Paths:
    """The project folder and its ``raw_dir`` / ``results_dir`` (from the config)."""

    directory: Path
    raw_dir: Path
    results_dir: Path

    @classmethod
    def from_config(cls, directory: Path, config: dict) -> Paths:
        """Paths of the project in ``directory`` with ``config``'s ``raw_dir``/``results_dir``.

        Raises
        ------
        rafi.errors.SettingsError
            The config puts a setting where nothing reads it (:func:`rafi.settings.run_settings`).
        """
        run = run_settings(config)
        d = Path(directory).resolve()
        return cls(d, d / str(run["raw_dir"]), d / str(run["results_dir"]))

    def machines(self) -> list[str]:
        """Folders of ``raw_dir`` holding at least one visible file, sorted."""
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
        """``<results>/<machine>/registry``."""
        return self.results_dir / machine / REGISTRY_DIR


def units(config: dict, machines: list[str]) -> list[str]:
    """What is qualified of ``machines``: a machine with several probes as one unit per probe
    (:func:`rafi.settings.machine_units`); a machine whose settings do not resolve as itself (the
    pipeline reports its mistake)."""
    from rafi.errors import RafiUserError
    from rafi.settings import machine_units

    out = []
    for machine in machines:
        try:
            out += machine_units(config, machine)
        except RafiUserError:
            out.append(machine)
    return out


def raw_logs(paths: Paths, config: dict, machine: str) -> list[Path]:
    """The raw files of ``machine`` the pipeline reads (its ``input.pattern`` and the recordings
    of ``rafi record``: :mod:`rafi.readers.recordings`; every visible file of the folder if the
    machine's settings cannot be resolved)."""
    from rafi.readers.input_spec import find_logs
    from rafi.readers.recordings import find_recordings

    folder = paths.raw_dir / machine
    try:
        spec = machine_settings(config, machine)["input"]
        recorded, _ = find_recordings(folder, spec, paths.raw_dir) if folder.is_dir() else ([], [])
        return sorted(set(find_logs(folder, spec, paths.raw_dir)) | set(recorded))
    except (InputSpecError, SettingsError, OSError):
        return sorted(p for p in folder.glob("*") if p.is_file() and not p.name.startswith("."))


def unmatched_folders(paths: Paths, config: dict, machines: list[str]) -> dict[str, str]:
    """Machine -> why, of the ``machines`` none of whose files matches its ``input.pattern``
    (the run skips them; :func:`rafi.readers.discovery.no_match_reason`)."""
    from rafi.readers.discovery import no_match_reason

    found = {}
    for machine in machines:
        try:
            pattern = machine_settings(config, machine)["input"]["pattern"]
        except (InputSpecError, SettingsError, KeyError):
            continue
        if not raw_logs(paths, config, machine):
            found[machine] = no_match_reason(paths.raw_dir / machine, pattern, machine)
    return found


def _settling_function():
    """``settling_files(paths, settle_s, now) -> [(path, age_s)]`` of the readers (None if absent)."""
    for module in ("rafi.readers.discovery", "rafi.readers.input_spec"):
        try:
            func = getattr(importlib.import_module(module), "settling_files", None)
        except ImportError:
            continue
        if func is not None:
            return func
    return None


def settling(
    paths: Paths, config: dict, machines: list[str], settle_s: float, now: float | None = None
) -> list[tuple[Path, float]]:
    """The raw files of ``machines`` modified less than ``settle_s`` seconds before ``now``:
    the pipeline leaves them out tonight (``settle_s``) and reads them the next night.

    Returns
    -------
    list of (Path, float)
        Each waiting file (relative to the project folder where possible) and its age in s.
    """
    func = _settling_function()
    if func is None or not settle_s or settle_s <= 0:
        return []
    files = [f for m in machines for f in raw_logs(paths, config, m)]
    out = []
    for path, age in func(files, settle_s, time.time() if now is None else now):
        path = Path(path)
        if path.is_relative_to(paths.directory):
            path = path.relative_to(paths.directory)
        out.append((path, float(age)))
    return out


def raw_log_files(paths: Paths, config: dict, machine: str) -> dict[str, list[Path]]:
    """The logs of ``machine``'s raw files, by log id (:func:`rafi.readers.log_sources.expand_logs`:
    a file, a sheet of a workbook, a file with its partner, a recording), each with the raw files
    it is read from; by file stem where the machine's ``input`` cannot be resolved."""
    from rafi.readers.input_spec import find_logs, normalise_input_spec
    from rafi.readers.log_sources import expand_logs, log_id
    from rafi.readers.recordings import find_recordings

    folder = paths.raw_dir / machine
    try:
        spec = normalise_input_spec(machine_settings(config, machine)["input"])
        recorded, _ = find_recordings(folder, spec, paths.raw_dir) if folder.is_dir() else ([], [])
        logs, _ = expand_logs(find_logs(folder, spec, paths.raw_dir), spec, recorded)
    except (InputSpecError, RawFormatError, SettingsError, OSError):
        return {log_id(p.stem): [p] for p in raw_logs(paths, config, machine)}
    return {
        key: [Path(f) for f in (src["path"], src.get("partner")) if f and Path(f).exists()]
        for key, src in logs.items()
    }


def _mtime(path: Path) -> float | None:
    try:
        return path.stat().st_mtime
    except OSError:
        return None


def unjudged_files(paths: Paths, config: dict, unit: str, since: float) -> list[str]:
    """The raw files of ``unit`` a decision taken at ``since`` has not judged.

    A raw file of one of the unit's logs (:func:`raw_log_files`, of the machine's folder for a
    probe's unit) counts when it was modified after ``since``, or when its log was not cleaned
    in its present content: no ``results/<unit>/clean/<log id>.summary.csv``, or one older than
    the file (a file ``rafi nightly`` left out while it was still being written, ``settle_s``; a
    copy that kept an older modification time). The next night judges them.

    Parameters
    ----------
    paths : Paths
        The project.
    config : dict
        The project's config (each machine's ``input``).
    unit : str
        ``<machine>`` or ``<machine>@<probe>``.
    since : float
        When the last decision was taken (seconds since the epoch).

    Returns
    -------
    list of str
        The files, relative to the machine's raw folder, sorted (empty: none).
    """
    machine = split_unit(unit)[0]
    folder = paths.raw_dir / machine
    found = set()
    for key, files in raw_log_files(paths, config, machine).items():
        cleaned = _mtime(paths.results_dir / unit / result_file("clean_summary").format(stem=key))
        for path in files:
            modified = _mtime(path)
            if modified is not None and (modified > since or cleaned is None or cleaned < modified):
                found.add(path.relative_to(folder).as_posix() if path.is_relative_to(folder) else path.name)
    return sorted(found)
