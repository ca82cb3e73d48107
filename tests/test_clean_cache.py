"""The clean step of one machine in one job (rafi.ops.clean_job) and its content-addressed cache
(rafi.ops.clean_cache): an unchanged file gets back the very bytes it was cleaned to, a changed
file, changed settings or changed code clean again, a quarantined file is never taken from the
cache (a fail-mode run still fails on it), and the cache holds only what the raw files use."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import pytest

from rafi.errors import RawFormatError
from rafi.ops.clean_cache import CleanCache, code_fingerprint, files_in, output_paths, stems_in
from rafi.ops.clean_job import CleanSettings, clean_machine

ROOT = Path(__file__).resolve().parents[1]
A = "tapping-center-a"
STEMS = ("valid_04500rpm", "valid_16500rpm")
SETTINGS = CleanSettings(
    input_spec={"format": "native"},
    sample_period_s=5,
    clean={"max_interpolate_gap_s": 60, "spike_threshold": 8, "open_circuit_values": [-999.0, 999.9, 850.0]},
    checks={
        "min_run_s": 1800,
        "sample_period_s": 5,
        "open_circuit_values": [-999.0, 999.9, 850.0],
        "training_speeds_rpm": [3000, 6000, 9000, 12000, 15000, 18000],
        "speed_tolerance_rpm": 50,
        "machine": A,
    },
)
LOG = logging.getLogger("test_clean_cache")


@pytest.fixture
def machine(tmp_path) -> dict[str, str]:
    raw = tmp_path / "raw" / A
    raw.mkdir(parents=True)
    for stem in STEMS:
        shutil.copy2(ROOT / "raw" / A / f"{stem}.csv", raw / f"{stem}.csv")
    return {stem: str(raw / f"{stem}.csv") for stem in STEMS}


def _run(tmp_path: Path, raw_paths, *, settings=SETTINGS, code="code-1", fail_mode=False):
    folder = tmp_path / "results" / A / "clean"
    shutil.rmtree(folder, ignore_errors=True)  # what Snakemake does to a directory output
    cache = CleanCache(tmp_path / "results" / A / ".clean_cache")
    done = clean_machine(raw_paths, folder, settings, cache=cache, code=code, fail_mode=fail_mode, log=LOG)
    return done, folder


def _contents(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_unchanged_files_come_back_from_the_cache_byte_for_byte(tmp_path, machine):
    done, folder = _run(tmp_path, machine)
    assert done == {s: "ok" for s in STEMS}
    first = _contents(folder)
    mtimes = {n: (folder / n).stat().st_mtime_ns for n in first}
    assert stems_in(folder) == sorted(STEMS) and len(files_in(folder, "parquet")) == 2

    done, folder = _run(tmp_path, machine)
    assert done == {s: "cached" for s in STEMS}
    assert _contents(folder) == first
    assert {n: (folder / n).stat().st_mtime_ns for n in first} == mtimes

    # a cache-less run writes the same bytes: the cache changes no result
    shutil.rmtree(folder)
    clean_machine(machine, folder, SETTINGS, cache=None, code="code-1", fail_mode=False, log=LOG)
    assert _contents(folder) == first


def test_a_changed_file_settings_or_code_clean_again_and_the_cache_keeps_only_what_is_used(tmp_path, machine):
    _run(tmp_path, machine)
    cache_root = tmp_path / "results" / A / ".clean_cache"
    assert len(list(cache_root.iterdir())) == 2

    with open(machine[STEMS[1]], "a", encoding="utf-8") as fh:
        fh.write("\n")  # same data, other bytes
    done, _ = _run(tmp_path, machine)
    assert done == {STEMS[0]: "cached", STEMS[1]: "ok"}
    assert len(list(cache_root.iterdir())) == 2  # the old entry of the edited file is gone

    other = CleanSettings(**{**SETTINGS.__dict__, "clean": {**SETTINGS.clean, "spike_threshold": 9}})
    assert _run(tmp_path, machine, settings=other)[0] == {s: "ok" for s in STEMS}
    assert _run(tmp_path, machine, settings=other, code="code-2")[0] == {s: "ok" for s in STEMS}
    assert _run(tmp_path, machine, settings=other, code="code-2")[0] == {s: "cached" for s in STEMS}


def test_a_quarantined_file_is_never_cached_and_fails_a_fail_mode_run(tmp_path, machine):
    bad = Path(machine[STEMS[0]]).with_name("zz_broken.csv")
    shutil.copy2(ROOT / "tests" / "data" / "bad" / "text_in_numeric.csv", bad)
    paths = {**machine, "zz_broken": str(bad)}
    done, folder = _run(tmp_path, paths)
    assert done["zz_broken"] == "quarantined"
    assert _run(tmp_path, paths)[0] == {STEMS[0]: "cached", STEMS[1]: "cached", "zz_broken": "quarantined"}
    with pytest.raises(RawFormatError, match=r"zz_broken\.csv, line 13, column 'T3'"):
        _run(tmp_path, paths, fail_mode=True)
    # a failed job prunes nothing: the good files are still cached
    assert _run(tmp_path, machine)[0] == {s: "cached" for s in STEMS}


def test_an_incomplete_cache_entry_is_not_used(tmp_path, machine):
    _run(tmp_path, machine)
    cache_root = tmp_path / "results" / A / ".clean_cache"
    for entry in cache_root.iterdir():
        (entry / f"{STEMS[0]}.parquet").unlink(missing_ok=True)
    assert _run(tmp_path, machine)[0] == {STEMS[0]: "ok", STEMS[1]: "cached"}


def test_code_fingerprint_follows_content_not_place(tmp_path):
    a, b = tmp_path / "a" / "m.py", tmp_path / "b" / "m.py"
    for path in (a, b):
        path.parent.mkdir()
        path.write_text("x = 1\n")
    assert code_fingerprint([a]) == code_fingerprint([b])
    b.write_text("x = 2\n")
    assert code_fingerprint([a]) != code_fingerprint([b])


def test_output_paths_and_stems_in_sort_by_log_id(tmp_path):
    folder = tmp_path / "clean"
    folder.mkdir()
    for stem in ("a-b", "a", "a_b"):
        for path in output_paths(folder, stem).values():
            path.write_text("")
    # "a-b.summary.csv" sorts before "a.summary.csv" as a file name, not as a log id
    assert stems_in(folder) == ["a", "a-b", "a_b"]
