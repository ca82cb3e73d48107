"""Bounded input (issue 13): line and field limits in every reader, bounded messages, formulas
without values, unreadable files, and one message (no traceback) for a user error.

Hostile files are built from the shipped raw files; every check also runs on the shipped
files and must stay silent there.
"""

from __future__ import annotations

import errno
import io
import os
import re
import shutil
import sys
import types
from pathlib import Path

import openpyxl
import pandas as pd
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import rafi.cli
import rafi.readers.parsing as parsing
from rafi.errors import (
    MESSAGE_MAX_CHARS,
    QUOTE_MAX_CHARS,
    InputSpecError,
    RafiUserError,
    RawFormatError,
    SettingsError,
    bound_message,
    quote,
)
from rafi.ops.run_messages import last_failure_line
from rafi.readers.logs import read_log, sha256_file
from rafi.readers.parsing import FIELD_MAX_CHARS, LINE_MAX_BYTES, METADATA_MAX_CHARS, first_long_line
from rafi.settings import machine_settings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from project_copy import copy_project, run_snakemake  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NATIVE_DIR = ROOT / "raw" / "tapping-center-a"
XLSX = ROOT / "raw" / "machining-center-b" / "thermal_log_2026-10-14.xlsx"
SHIPPED = NATIVE_DIR / "train_03000rpm.csv"


def _config() -> dict:
    return yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))


def _parts() -> tuple[str, str, list[str]]:
    """(metadata lines, header line, data lines) of a shipped native file."""
    lines = SHIPPED.read_text(encoding="utf-8").splitlines(keepends=True)
    k = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    return "".join(lines[:k]), lines[k], lines[k + 1 :]


def _with_comment(tmp_path: Path, comment_at: dict[int, str], name="bad.csv", meta_extra="") -> Path:
    """The shipped file with an extra text column ``comment`` ('ok', or the given text)."""
    meta, header, data = _parts()
    rows = [row.rstrip("\n") + "," + comment_at.get(i, "ok") + "\n" for i, row in enumerate(data)]
    path = tmp_path / name
    path.write_text(meta + meta_extra + header.rstrip("\n") + ",comment\n" + "".join(rows), encoding="utf-8")
    return path


def _error(path, spec=None) -> RawFormatError:
    with pytest.raises(RawFormatError) as info:
        read_log(path, spec)
    return info.value


# --------------------------------------------------------------------------- message bound


@settings(max_examples=200, deadline=None)
@given(
    reason=st.text(max_size=3000),
    field=st.text(max_size=3000),
    name=st.text(st.characters(blacklist_characters="/\x00"), min_size=1, max_size=250),
    column=st.one_of(st.none(), st.text(max_size=500)),
    sheet=st.one_of(st.none(), st.text(max_size=100)),
    line=st.integers(1, 10**9),
)
def test_any_message_is_bounded_and_names_file_and_line(reason, field, name, column, sheet, line):
    exc = RawFormatError(
        f"raw/m/{name}", f"{field!r} {reason}; expected x", line=line, column=column, sheet=sheet
    )
    text = str(exc)
    assert len(text) <= MESSAGE_MAX_CHARS
    shown_name = name if len(f"raw/m/{name}") <= 160 else name[:QUOTE_MAX_CHARS]
    assert text.startswith(f"raw/m/{name}" if len(f"raw/m/{name}") <= 160 else f".../{shown_name}")
    assert f", {'row' if sheet is not None else 'line'} {line}" in text
    assert "\n" not in exc.reason
    # no run of offending text longer than the quote limit survives (a path aside)
    body = text.split(": ", 1)[1] if ": " in text else text
    longest_run = max((len(run) for run in re.findall(r"\S+", body)), default=0)
    assert longest_run < QUOTE_MAX_CHARS + 20


@given(st.text(max_size=5000), st.integers(1, 200))
def test_quote_shows_at_most_limit_characters_and_the_length(text, limit):
    shown = quote(text, limit)
    assert len(shown) <= limit + 2 + len(f"... ({len(text)} characters)")
    if len(text) > limit:
        assert shown.endswith(f"... ({len(text)} characters)")
    else:
        assert shown == repr(text) or shown.endswith(f"({len(text)} characters)")


@pytest.mark.parametrize("kind", [InputSpecError, SettingsError])
def test_configuration_errors_are_bounded_user_errors_and_still_value_errors(kind):
    exc = kind("input.columns.T3: " + "x" * 1_000_000 + " is not a header")
    assert isinstance(exc, RafiUserError) and isinstance(exc, ValueError)
    assert exc.exit_status == 64
    assert len(str(exc)) <= MESSAGE_MAX_CHARS and str(exc).startswith("input.columns.T3: xxx")
    assert "(1000000 characters)" in str(exc)
    assert RawFormatError("a.csv", "x").exit_status == 65


def test_a_50_mb_message_is_cut_in_linear_time_and_keeps_both_ends():
    text = bound_message("start " + "ab " * 10_000_000 + "the end")
    assert len(text) <= MESSAGE_MAX_CHARS
    assert text.startswith("start ab") and text.endswith("the end") and "characters cut" in text


# --------------------------------------------------------------------------- line and field limits


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.sampled_from([b"a", b"bb", b"\n", b"\r", b"\r\n", b"x" * 9]), max_size=60),
    st.integers(1, 12),
    st.integers(1, 9),
)
def test_first_long_line_agrees_with_the_editor_line_split(parts, limit, chunk):
    raw = b"".join(parts)
    lines = parsing.split_lines(raw.decode("latin-1"))
    expected = next(((i + 1, len(line)) for i, line in enumerate(lines) if len(line) > limit), None)
    old, parsing._SCAN_CHUNK = parsing._SCAN_CHUNK, chunk  # tiny chunks: lines cross their borders
    try:
        found = first_long_line(raw, limit)
    finally:
        parsing._SCAN_CHUNK = old
    assert (found[0], found[2]) == expected if found else expected is None


def test_a_50_mb_notes_line_is_refused_with_a_short_message(tmp_path):
    meta, header, data = _parts()
    path = tmp_path / "notes.csv"
    path.write_bytes((meta + "# notes: " + "n" * 50_000_000 + "\n" + header + "".join(data)).encode())
    exc = _error(path)
    assert exc.check == "line_too_long" and exc.line == meta.count("\n") + 1
    assert len(str(exc)) < MESSAGE_MAX_CHARS
    assert f"line of 50000009 bytes, longer than the limit of {LINE_MAX_BYTES} bytes" in str(exc)
    assert "'# notes: nnnn" in str(exc)


def test_a_50_mb_field_is_refused_with_a_short_message(tmp_path):
    path = _with_comment(tmp_path, {5: "x" * 50_000_000})
    exc = _error(path)
    assert exc.check == "line_too_long" and len(str(exc)) < MESSAGE_MAX_CHARS
    assert exc.line == _parts()[0].count("\n") + 2 + 5


def test_a_long_field_names_line_and_column(tmp_path):
    path = _with_comment(tmp_path, {7: "y" * (FIELD_MAX_CHARS + 1)})
    exc = _error(path)
    assert exc.check == "field_too_long" and exc.column == "comment"
    assert exc.line == _parts()[0].count("\n") + 2 + 7
    assert f"field of {FIELD_MAX_CHARS + 1} characters, longer than the limit of {FIELD_MAX_CHARS}" in str(
        exc
    )
    assert f"'{'y' * QUOTE_MAX_CHARS}'... ({FIELD_MAX_CHARS + 1} characters)" in str(exc)


def test_a_field_at_the_limit_is_read_and_its_parquet_reads_back(tmp_path):
    notes = "# notes: " + "n" * (FIELD_MAX_CHARS - 20) + "\n"
    path = _with_comment(tmp_path, {3: "z" * FIELD_MAX_CHARS}, meta_extra=notes * 10)
    frame = read_log(path)
    assert frame["comment"].iloc[3] == "z" * FIELD_MAX_CHARS
    frame.to_parquet(tmp_path / "x.parquet")
    back = pd.read_parquet(tmp_path / "x.parquet")
    assert back["comment"].iloc[3] == "z" * FIELD_MAX_CHARS


def test_an_unclosed_quote_swallowing_a_line_is_named(tmp_path):
    path = _with_comment(tmp_path, {2: '"' + "w" * (FIELD_MAX_CHARS + 10)})
    exc = _error(path)
    assert exc.check == "field_too_long" and "unclosed quote" in str(exc)


def test_metadata_value_and_metadata_in_all_are_bounded(tmp_path):
    exc = _error(_with_comment(tmp_path, {}, meta_extra="# notes: " + "n" * FIELD_MAX_CHARS + "\n"))
    assert exc.check == "field_too_long" and "metadata 'notes' of" in str(exc)
    many = ("# notes: " + "n" * 4000 + "\n") * (METADATA_MAX_CHARS // 4000 + 1)
    exc = _error(_with_comment(tmp_path, {}, name="many.csv", meta_extra=many))
    assert exc.check == "field_too_long" and f"more than {METADATA_MAX_CHARS} characters" in str(exc)


def test_a_long_header_name_is_refused(tmp_path):
    meta, header, data = _parts()
    path = tmp_path / "h.csv"
    path.write_text(meta + header.rstrip("\n") + "," + "h" * 5000 + "\n" + "".join(data), encoding="utf-8")
    exc = _error(path)
    assert exc.check == "field_too_long" and exc.line == meta.count("\n") + 1


def _csv_spec(header_row: int) -> dict:
    return {"format": "csv", "header_row": header_row}


def test_mapped_csv_has_the_same_limits(tmp_path):
    meta, header, data = _parts()
    first = meta.count("\n") + 1
    exc = _error(_with_comment(tmp_path, {4: "q" * (FIELD_MAX_CHARS + 1)}), _csv_spec(first))
    assert exc.check == "field_too_long" and exc.column == "comment" and exc.line == first + 5
    exc = _error(_with_comment(tmp_path, {4: "q" * (LINE_MAX_BYTES + 1)}, name="l.csv"), _csv_spec(first))
    assert exc.check == "line_too_long" and exc.line == first + 5
    assert len(read_log(_with_comment(tmp_path, {}, name="ok.csv"), _csv_spec(first))) == len(data)


def _small_xlsx(path: Path, n_rows=40, cell=None, formulas=False) -> Path:
    """A workbook with the shipped native file's first rows (native header names)."""
    frame = read_log(SHIPPED).head(n_rows)
    wb = openpyxl.Workbook()
    ws = wb.active
    ws.title = "Messdaten"
    columns = [c for c in frame.columns if c != "coolant_c"] + ["comment"]
    ws.append(columns)
    for k, (_, row) in enumerate(frame.iterrows()):
        values = [row["time"].to_pydatetime(), *[float(row[c]) for c in columns[1:-1]], "ok"]
        if cell is not None and k == cell[0]:
            values[-1] = cell[1]
        if formulas and k >= 10:
            r = k + 2  # Excel row of this record
            values[columns.index("T2")] = f"=C{r}+0.1"  # T2 = T1 + 0.1, no cached value
        ws.append(values)
    wb.save(path)
    return path


XLSX_SPEC = {"format": "xlsx", "sheet": "Messdaten"}


def test_xlsx_cells_have_the_field_limit(tmp_path):
    path = _small_xlsx(tmp_path / "a.xlsx", cell=(6, "c" * (FIELD_MAX_CHARS + 1)))
    exc = _error(path, XLSX_SPEC)
    assert exc.check == "field_too_long" and exc.sheet == "Messdaten" and exc.line == 8
    assert exc.column == "comment" and len(str(exc)) < MESSAGE_MAX_CHARS


# --------------------------------------------------------------------------- formula_without_value


def test_formulas_without_cached_values_are_refused_with_the_cure(tmp_path):
    path = _small_xlsx(tmp_path / "f.xlsx", formulas=True)
    exc = _error(path, XLSX_SPEC)
    assert exc.check == "formula_without_value"
    assert exc.sheet == "Messdaten" and exc.line == 12 and exc.column == "T2"
    text = str(exc)
    assert "cell D12 holds the formula '=C12+0.1'" in text and "(30 such cell(s) in the sheet)" in text
    assert "open and save it in Excel or LibreOffice" in text and "export the sheet as CSV" in text


def test_formulas_with_cached_values_are_read(tmp_path):
    path = _small_xlsx(tmp_path / "f.xlsx", formulas=True)
    # what Excel saves: each formula with its value (<v>) - added to the sheet XML here
    import zipfile

    cached = tmp_path / "cached.xlsx"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(cached, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename.startswith("xl/worksheets/"):
                data = re.sub(
                    rb"<f>([^<]*)</f><v\s*/>|<f>([^<]*)</f>(?!<v>)", rb"<f>\1\2</f><v>21.5</v>", data
                )
            dst.writestr(item, data)
    frame = read_log(cached, XLSX_SPEC)
    assert (frame["T2"].iloc[10:] == 21.5).all() and frame["T2"].notna().all()


def test_shipped_xlsx_has_dropouts_and_no_formula_alarm():
    spec = machine_settings(_config(), "machining-center-b")["input"]
    frame = read_log(XLSX, spec)
    assert frame.isna().to_numpy().sum() > 0  # empty cells, so the formula check looked


# --------------------------------------------------------------------------- unreadable


def test_a_directory_named_like_a_log_is_unreadable(tmp_path):
    folder = tmp_path / "run.csv"
    folder.mkdir()
    for call in (lambda: read_log(folder), lambda: sha256_file(folder)):
        with pytest.raises(RawFormatError) as info:
            call()
        assert info.value.check == "unreadable"
        assert "cannot read the file: it is a directory, not a file (EISDIR)" in str(info.value)


@pytest.mark.parametrize("code, words", [(errno.EIO, "I/O error (EIO)"), (errno.EACCES, "permission denied")])
@pytest.mark.parametrize("fmt", ["native", "csv", "xlsx"])
def test_io_errors_and_permissions_give_one_clear_message(tmp_path, monkeypatch, code, words, fmt):
    path = tmp_path / ("x.xlsx" if fmt == "xlsx" else "x.csv")
    path.write_bytes(SHIPPED.read_bytes())
    real_open, real_os_open = open, os.open

    def failing_open(file, *args, **kwargs):
        if str(file) == str(path):
            raise OSError(code, "simulated")
        return real_open(file, *args, **kwargs)

    def failing_os_open(file, *args, **kwargs):  # the readers open raw files with os.open
        if str(file) == str(path):
            raise OSError(code, "simulated")
        return real_os_open(file, *args, **kwargs)

    monkeypatch.setattr("builtins.open", failing_open)
    monkeypatch.setattr("os.open", failing_os_open)
    spec = {"format": fmt} if fmt != "native" else None
    for call in (lambda: read_log(path, spec), lambda: sha256_file(path)):
        with pytest.raises(RawFormatError) as info:
            call()
        assert info.value.check == "unreadable" and words in str(info.value)
        assert str(info.value).startswith(str(path)) and "check the file's permissions or the disk" in str(
            info.value
        )


def test_an_io_error_inside_the_workbook_is_unreadable(tmp_path, monkeypatch):
    path = _small_xlsx(tmp_path / "a.xlsx")

    def broken(*args, **kwargs):
        raise OSError(errno.EIO, "simulated")

    monkeypatch.setattr(openpyxl, "load_workbook", broken)
    exc = _error(path, XLSX_SPEC)
    assert exc.check == "unreadable" and "I/O error" in str(exc)


# --------------------------------------------------------------------------- no false alarms


@pytest.mark.parametrize("path", sorted(NATIVE_DIR.glob("*.csv")), ids=lambda p: p.name)
def test_shipped_native_files_pass_every_limit(path):
    frame = read_log(path, machine_settings(_config(), "tapping-center-a")["input"])
    assert len(frame) > 100
    raw = path.read_bytes()
    assert first_long_line(raw) is None


# --------------------------------------------------------------------------- one message


sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
import _glue  # noqa: E402


def _fake_smk(tmp_path, config):
    return types.SimpleNamespace(
        log=[str(tmp_path / "logs" / "clean.log")], rule="clean", wildcards={"stem": "a"}, config=config
    )


@pytest.mark.parametrize("debug", [False, True, "true"])
def test_glue_ends_the_log_with_one_bounded_line_for_a_user_error(tmp_path, monkeypatch, debug):
    """Without debug: exit 1, the log ends with the one line (the Snakefile's onerror repeats it
    last) and holds no traceback. With debug: the error is re-raised, its traceback in the log."""
    terminal = io.StringIO()
    monkeypatch.setattr(sys, "__stderr__", terminal)
    smk = _fake_smk(tmp_path, {"debug": debug})
    error = RawFormatError("raw/m/a.csv", "x" * 10_000 + " is not a number", line=3, column="T1")
    expected = SystemExit if debug is False else RawFormatError
    with pytest.raises(expected):
        with _glue.step(smk):
            raise error
    log = Path(smk.log[0]).read_text(encoding="utf-8")
    if debug is False:
        last = log.strip().splitlines()[-1]
        assert last.startswith("RAFI clean (stem=a) failed: raw/m/a.csv, line 3")
        assert len(last) < MESSAGE_MAX_CHARS + 50
        assert "Traceback" not in log and terminal.getvalue() == ""
        assert last_failure_line(smk.log[0]) == last
    else:
        shown = terminal.getvalue().splitlines()
        assert len(shown) == 2 and shown[0].startswith("RAFI clean (stem=a) failed: raw/m/a.csv, line 3")
        assert "Traceback (most recent call last)" in log


def test_glue_reraises_a_bug(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "__stderr__", io.StringIO())
    with pytest.raises(ZeroDivisionError):
        with _glue.step(_fake_smk(tmp_path, {})):
            1 / 0  # noqa: B018


def _fake_command(monkeypatch, exc):
    module = types.ModuleType("rafi_fake_command")
    module.add_arguments = lambda parser: None

    def run(args):
        raise exc

    module.run = run
    monkeypatch.setitem(sys.modules, "rafi_fake_command", module)
    monkeypatch.setitem(rafi.cli.COMMANDS, "fake", ("rafi_fake_command", "a test command"))


@pytest.mark.parametrize(
    "exc, status",
    [(RawFormatError("raw/m/a.csv", "bad " + "v" * 5000, line=4), 65), (InputSpecError("input.x: bad"), 64)],
)
def test_cli_prints_one_line_and_a_documented_status(monkeypatch, capsys, exc, status):
    _fake_command(monkeypatch, exc)
    assert rafi.cli.main(["fake"]) == status
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("rafi fake: ") and "Traceback" not in err
    assert rafi.cli.main(["--debug", "fake"]) == status
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and err.rstrip().endswith(str(exc))


# --------------------------------------------------------------------------- the real workflow


@pytest.fixture(scope="module")
def bad_project(tmp_path_factory) -> Path:
    """A project with one shipped file, one with a 10,000-character field, one link out of raw/."""
    tmp = tmp_path_factory.mktemp("bounded")
    proj = copy_project(tmp / "proj")
    machine = proj / "raw" / "tapping-center-a"
    machine.mkdir(parents=True)
    shutil.copy2(SHIPPED, machine / SHIPPED.name)
    _with_comment(machine, {5: "y" * 10_000}, name="zz_bad.csv")
    (tmp / "outside.csv").write_bytes(SHIPPED.read_bytes())
    (machine / "zz_link.csv").symlink_to(tmp / "outside.csv")
    return proj


@pytest.mark.slow
def test_a_user_error_in_a_job_shows_its_message_once_and_no_traceback(bad_project):
    done = run_snakemake(bad_project, "results/tapping-center-a/clean", "-q")
    out = done.stdout + done.stderr
    assert done.returncode != 0
    assert out.count("field of 10000 characters") == 1 and "RAFI clean (machine=tapping-center-a" in out
    assert "Traceback" not in out and "RawFormatError" not in out
    # the last thing the user reads is the message (the Snakefile's onerror repeats it)
    assert out.strip().splitlines()[-1].startswith("RAFI clean (machine=tapping-center-a) failed: ")
    log = (bad_project / "logs" / "tapping-center-a" / "clean.log").read_text(encoding="utf-8")
    assert "Traceback" not in log and log.strip().splitlines()[-1].startswith("RAFI clean (")
    again = run_snakemake(bad_project, "-q", "--config", "debug=true", "--", "results/tapping-center-a/clean")
    assert "Traceback (most recent call last)" in again.stdout + again.stderr


def test_planning_warns_of_links_and_settling_files(bad_project):
    dry = run_snakemake(bad_project, "-n", "--config", "settle_s=1000000000")
    out = dry.stdout + dry.stderr
    assert dry.returncode == 0, out
    assert "link_outside_raw: refused raw/tapping-center-a/zz_link.csv: a symbolic link to" in out
    assert "settling: waits for the next run: raw/tapping-center-a/train_03000rpm.csv" in out
