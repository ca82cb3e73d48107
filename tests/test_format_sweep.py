"""Malformed files and folders found by the issue-13 format sweep: each is refused with one
clear message (or left out of discovery with a warning line), never a crash, a hang or a
silently wrong table.

Known truth comes from the shipped raw files, changed one way at a time.
"""

from __future__ import annotations

import io
import os
import re
import socket
import zipfile
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

import rafi.readers.parsing as parsing
from rafi.errors import RawFormatError
from rafi.readers.discovery import periodic_tail, safe_name_problem
from rafi.readers.input_spec import discover_machines, log_id
from rafi.readers.logs import read_log, sha256_file
from rafi.readers.mapped_table import check_zip_sizes

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "raw" / "tapping-center-a" / "train_03000rpm.csv"
WORKBOOK = ROOT / "raw" / "machining-center-b" / "thermal_log_2026-10-14.xlsx"
NATIVE = {"format": "native"}
MCB = {
    "format": "xlsx",
    "sheet": "Messdaten",
    "columns": {
        "time": "Zeit [s]",
        "speed_rpm": "Drehzahl [1/min]",
        **{f"T{i}": f"Temperatur {i} [°C]" for i in range(1, 17)},
    },
    "time": {"kind": "elapsed_s", "start": "2026-10-14T06:00:00"},
    "displacement": {"column": "Verlagerung Z1 [µm]", "unit": "um", "sign": -1},
}
SHEET = "xl/worksheets/sheet2.xml"


def _error(path, spec=None) -> RawFormatError:
    with pytest.raises(RawFormatError) as info:
        read_log(path, spec)
    return info.value


def _rezip(path: Path, change) -> Path:
    """The shipped workbook with its sheet XML changed by ``change(bytes) -> bytes``."""
    buf = io.BytesIO()
    with zipfile.ZipFile(WORKBOOK) as zin, zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            data = zin.read(info.filename)
            zout.writestr(info.filename, change(data) if info.filename == SHEET else data)
    path.write_bytes(buf.getvalue())
    return path


# --------------------------------------------------------------------------- not a regular file


def test_a_fifo_is_refused_at_once_not_waited_on(tmp_path):
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    for call in (lambda: read_log(fifo), lambda: sha256_file(fifo), lambda: read_log(fifo, MCB)):
        with pytest.raises(RawFormatError) as info:
            call()
        assert info.value.check == "unreadable" and "a FIFO (named pipe), not a regular file" in str(
            info.value
        )


def test_a_socket_is_refused(tmp_path):
    path = tmp_path / "s.csv"
    sock = socket.socket(socket.AF_UNIX)
    try:
        sock.bind(str(path))
        exc = _error(path)
    finally:
        sock.close()
    assert exc.check == "unreadable" and "a socket, not a regular file" in str(exc)


def test_discovery_names_what_is_not_a_regular_file(tmp_path):
    raw = tmp_path / "raw"
    folder = raw / "m1"
    folder.mkdir(parents=True)
    (folder / "good.csv").write_bytes(SHIPPED.read_bytes())
    os.mkfifo(folder / "fifo.csv")
    (folder / "dir.csv").mkdir()
    (folder / "dangling.csv").symlink_to(folder / "gone.csv")
    sock = socket.socket(socket.AF_UNIX)
    try:
        sock.bind(str(folder / "sock.csv"))
        found, warnings = discover_machines(raw, lambda m: NATIVE)
    finally:
        sock.close()
    assert list(found["m1"]) == ["good"]
    said = {re.search(r"m1/(\w+)\.csv", w).group(1): w for w in warnings}
    assert all(w.startswith("not_a_file: skipped ") for w in warnings)
    assert "a FIFO (named pipe)" in said["fifo"] and "a socket" in said["sock"]
    assert "a folder" in said["dir"] and "leads nowhere" in said["dangling"]


# --------------------------------------------------------------------------- sizes


def test_a_file_over_the_size_limit_is_refused_before_it_is_read(tmp_path, monkeypatch):
    monkeypatch.setattr(parsing, "FILE_MAX_BYTES", 1000)
    path = tmp_path / "big.csv"
    path.write_bytes(SHIPPED.read_bytes())
    for call in (lambda: read_log(path), lambda: sha256_file(path)):
        with pytest.raises(RawFormatError) as info:
            call()
        assert info.value.check == "file_too_large"
        assert f"file of {path.stat().st_size} bytes, larger than the limit of 1000 bytes" in str(info.value)


def test_the_shipped_files_are_far_below_the_size_limit():
    assert max(p.stat().st_size for p in (SHIPPED, WORKBOOK)) * 50 < parsing.FILE_MAX_BYTES


def test_a_zip_bomb_workbook_is_refused_before_it_is_inflated(tmp_path):
    # 300 MB of blanks inside the sheet XML: about 300 kB on disk
    bomb = tmp_path / "bomb.xlsx"
    buf = io.BytesIO()
    with zipfile.ZipFile(WORKBOOK) as zin, zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            data = zin.read(info.filename)
            if info.filename != SHEET:
                zout.writestr(info.filename, data)
                continue
            end = data.index(b"</sheetData>")
            with zout.open(SHEET, "w", force_zip64=True) as fh:
                fh.write(data[:end])
                for _ in range(300):
                    fh.write(b" " * (1 << 20))
                fh.write(data[end:])
    bomb.write_bytes(buf.getvalue())
    assert bomb.stat().st_size < parsing.FILE_MAX_BYTES // 10
    exc = _error(bomb, MCB)
    assert exc.check == "file_too_large" and "a zip bomb" in str(exc)
    assert "'xl/worksheets/sheet2.xml'" in str(exc)


def test_the_shipped_workbook_passes_the_inflate_limit():
    check_zip_sizes(WORKBOOK, WORKBOOK.read_bytes())  # no error
    with pytest.raises(RawFormatError):
        check_zip_sizes(WORKBOOK, WORKBOOK.read_bytes(), limit=1 << 20)


def test_a_header_of_too_many_columns_is_refused(tmp_path):
    lines = SHIPPED.read_bytes().split(b"\n")
    extra = b"".join(b",x%d" % i for i in range(parsing.COLUMNS_MAX))
    lines = [*lines[:4], lines[4] + extra, *(ln + b"," * parsing.COLUMNS_MAX for ln in lines[5:] if ln)]
    path = tmp_path / "wide.csv"
    path.write_bytes(b"\n".join(lines) + b"\n")
    exc = _error(path)
    assert exc.check == "too_many_columns" and "line 5" in str(exc)
    assert (
        f"header of {19 + parsing.COLUMNS_MAX} columns, more than the limit of {parsing.COLUMNS_MAX}"
        in str(exc)
    )


# --------------------------------------------------------------------------- workbook structure


def test_rows_past_a_stale_dimension_are_read_not_dropped(tmp_path):
    # the sheet claims A1:W100; the reader used to stop there silently
    path = _rezip(
        tmp_path / "stale.xlsx", lambda d: re.sub(rb'<dimension ref="[^"]*"', b'<dimension ref="A1:W100"', d)
    )
    assert len(read_log(path, MCB)) == len(read_log(WORKBOOK, MCB)) == 11511


def test_a_row_number_beyond_excel_is_refused_quickly(tmp_path):
    path = _rezip(tmp_path / "rows.xlsx", lambda d: d.replace(b'<row r="3">', b'<row r="99999999">', 1))
    exc = _error(path, MCB)
    assert "row 1048577" in str(exc) and "beyond 1048576, the last row of an Excel sheet" in str(exc)


# --------------------------------------------------------------------------- names


@pytest.mark.parametrize(
    "name",
    [
        "L" * 251 + ".csv",
        "log_" + "0" * 30 + ".csv",
        "new\nline.csv",
        "tab\tx.csv",
        "$(touch PWNED).csv",
        "-rf.csv",
    ],
    ids=["255-bytes", "periodic", "newline", "tab", "command", "leading-dash"],
)
def test_any_file_name_gets_an_output_name_snakemake_accepts(tmp_path, name):
    raw = tmp_path / "raw"
    (raw / "m1").mkdir(parents=True)
    (raw / "m1" / name).write_bytes(SHIPPED.read_bytes())
    found, warnings = discover_machines(raw, lambda m: NATIVE)
    (key,) = found["m1"]
    assert warnings == [] and found["m1"][key] == str(raw / "m1" / name)
    assert safe_name_problem(key) is None and len((key + ".summary.csv").encode()) + 15 <= 255
    assert not (tmp_path / "PWNED").exists() and not Path("PWNED").exists()


@given(st.text(min_size=1, max_size=300))
def test_log_ids_are_safe_and_distinct(stem):
    key = log_id(stem)
    assert safe_name_problem(key) is None and not periodic_tail(key)
    assert log_id(stem + "x") != key


@pytest.mark.parametrize("folder", ["m" * 30, "bad\nname", "x" * 200])
def test_a_machine_folder_whose_name_cannot_be_an_output_path_is_skipped_with_a_warning(tmp_path, folder):
    raw = tmp_path / "raw"
    (raw / folder).mkdir(parents=True)
    (raw / folder / "a.csv").write_bytes(SHIPPED.read_bytes())
    (raw / "ok").mkdir()
    (raw / "ok" / "a.csv").write_bytes(SHIPPED.read_bytes())
    found, warnings = discover_machines(raw, lambda m: NATIVE)
    assert list(found) == ["ok"]
    assert (
        len(warnings) == 1
        and warnings[0].startswith("skipping machine folder ")
        and "rename the folder" in warnings[0]
    )
