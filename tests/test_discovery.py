"""Machines and raw files as the workflow plans them (rafi.readers.input_spec.discover_machines)
and the names of a raw file's outputs (log_id): any legal file name must work."""

from __future__ import annotations

from urllib.parse import unquote

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rafi.errors import InputSpecError, RawFormatError
from rafi.readers.discovery import safe_name_problem
from rafi.readers.input_spec import discover_machines, has_braces, log_id

NATIVE = {"format": "native"}


@given(st.text(min_size=1))
def test_log_id_has_no_braces_and_keeps_names_apart(stem):
    assert not has_braces(log_id(stem))
    # percent-encoded (braces, %, control characters), or cut and hashed (long or periodic stems)
    assert "%~" in log_id(stem) or unquote(log_id(stem)) == stem
    assert safe_name_problem(log_id(stem)) is None


@given(st.text(min_size=1), st.text(min_size=1))
def test_log_id_is_injective(a, b):
    assert (log_id(a) == log_id(b)) == (a == b)


def _touch(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("x\n", encoding="utf-8")


def test_any_legal_file_name_is_found_under_its_log_id(tmp_path):
    names = ["log_{date}.csv", "with space é.csv", "日本.csv", "100%.csv", "a}{b.csv"]
    for name in names:
        _touch(tmp_path / "m1" / name)
    _touch(tmp_path / "m1" / ".hidden.csv")
    _touch(tmp_path / "m1" / "notes.txt")
    found, warnings = discover_machines(tmp_path, lambda m: NATIVE)
    assert warnings == []
    assert found == {"m1": {log_id(n[:-4]): str(tmp_path / "m1" / n) for n in names}}
    assert found["m1"]["log_%7Bdate%7D"].endswith("log_{date}.csv")


def test_folders_left_out_are_said_why(tmp_path):
    _touch(tmp_path / "m1" / "a.csv")
    _touch(tmp_path / "{m2}" / "a.csv")
    (tmp_path / "empty").mkdir()
    _touch(tmp_path / ".git" / "a.csv")
    found, warnings = discover_machines(tmp_path, lambda m: NATIVE, configured=["m1", "m9"])
    assert list(found) == ["m1"]
    assert any("{m2}" in w and "cannot hold" in w for w in warnings)
    assert any("empty" in w and "no file matches input.pattern '*.csv'" in w for w in warnings)
    assert any("'m9'" in w and "does not exist" in w for w in warnings)
    assert not any(".git" in w for w in warnings)


def test_two_files_with_one_stem_stop_with_both_names(tmp_path):
    _touch(tmp_path / "m1" / "a.csv")
    _touch(tmp_path / "m1" / "a.CSV")
    with pytest.raises(RawFormatError, match=r"same stem 'a'.*rename one"):
        discover_machines(tmp_path, lambda m: {"format": "native", "pattern": ["*.csv", "*.CSV"]})


def test_a_bad_input_mapping_names_the_machine(tmp_path):
    _touch(tmp_path / "m1" / "a.csv")
    with pytest.raises(InputSpecError, match=r"machine 'm1': input.format"):
        discover_machines(tmp_path, lambda m: {"format": "parquet"})


def test_a_missing_raw_dir_is_a_warning_not_a_crash(tmp_path):
    assert discover_machines(tmp_path / "nope", lambda m: NATIVE) == (
        {},
        [f"raw_dir {str(tmp_path / 'nope')!r} does not exist; no machines to process"],
    )
