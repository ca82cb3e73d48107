"""Where a project's files are, as ``rafi nightly`` sees them (config, raw/, results/)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rafi.settings import run_settings


def config_path(directory: Path, config_file: str | Path) -> Path:
    """``config_file`` resolved against the project ``directory`` unless absolute."""
    path = Path(config_file)
    return path if path.is_absolute() else Path(directory) / path


def load_config(directory: Path, config_file: str | Path) -> dict:
    """The pipeline config (YAML) of the project in ``directory``; ``{}`` for an empty file.

    Raises
    ------
    OSError
        If the file cannot be read.
    """
    import yaml

    with open(config_path(directory, config_file), encoding="utf-8") as fh:
        return yaml.safe_load(fh) or {}


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
        return self.results_dir / machine / "registry"
