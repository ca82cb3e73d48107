"""``input.missing_values``: the texts a logger writes in a cell without a value (``---``, ``#N/A``,
``NaN``, ``ERR``, ``n/a``, ``-``) are missing values in every numeric column of a csv or xlsx log,
cleaned as any dropout; without the key the reader names the cell and the key; ``rafi init``
finds them and proposes the key."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from layout_files import write_table

from rafi import SENSORS
from rafi.errors import InputSpecError, RawFormatError
from rafi.method.clean import clean_log
from rafi.ops.init_cli import findings
from rafi.ops.init_config import config_block, parse_block
from rafi.ops.init_survey import survey
from rafi.readers.infer import missing_markers
from rafi.readers.infer_files import read_unknown_logs
from rafi.readers.input_spec import normalise_input_spec
from rafi.readers.logs import read_log
from rafi.settings import machine_settings, validate_config
from rafi.twin.synthetic_logs import schedule_log

TOKENS = ("---", "#N/A", "NaN", "ERR", "n/a", "-")

COLUMNS = {"time": "Zeit", "speed_rpm": "Drehzahl", **{s: f"Temp {s}" for s in SENSORS}, "disp_um": "Z [um]"}


def logger_table(n: int = 240, seed: int = 0) -> pd.DataFrame:
    """A log of ``n`` rows at 30 s under the headers of :data:`COLUMNS`, with an extra column."""
    frame, _ = schedule_log([(0, 300), (3000, n * 30 - 300)], period_s=30.0, seed=seed)
    frame = frame.iloc[:n]
    out = pd.DataFrame({"Zeit": frame["time"].dt.strftime("%Y-%m-%d %H:%M:%S")})
    out["Drehzahl"] = frame["speed_rpm"].round()
    for s in SENSORS:
        out[f"Temp {s}"] = frame[s].round(2)
    out["Z [um]"] = frame["disp_um"].round(3)
    out["Kuehlmittel"] = 19.5
    return out


#: Cells given the marker: (data row, header); the extra column's too.
HOLES = ((10, "Temp T3"), (11, "Temp T3"), (50, "Z [um]"), (120, "Drehzahl"), (130, "Kuehlmittel"))


def with_marker(table: pd.DataFrame, token: str) -> pd.DataFrame:
    out = table.astype(object)
    for row, col in HOLES:
        out.loc[row, col] = token
    return out


def write(table: pd.DataFrame, path: Path) -> Path:
    return write_table(table, path, sheet="Daten", sep=";")


def spec(path: Path, **more) -> dict:
    fmt = "xlsx" if path.suffix == ".xlsx" else "csv"
    layout = {"delimiter": ";"} if fmt == "csv" else {}
    return {"format": fmt, **layout, "columns": COLUMNS, **more}


@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
@pytest.mark.parametrize("token", TOKENS)
def test_a_declared_marker_is_a_missing_value_in_every_numeric_column(tmp_path, token, suffix):
    table = logger_table()
    path = write(with_marker(table, token), tmp_path / f"log{suffix}")
    frame = read_log(path, spec(path, missing_values=["unused", token]))
    # cleaning handles the marker's cells as any dropout
    clean, audit = clean_log(
        frame,
        file=path.name,
        sample_period_s=30.0,
        max_interpolate_gap_s=120.0,
        spike_threshold=8.0,
        open_circuit_values=[],
    )
    assert clean[["speed_rpm", *SENSORS, "disp_um"]].notna().all().all()
    assert {"T3", "disp_um"} <= set(audit.loc[audit["action"] == "dropout_interpolated", "column"])
    plain = read_log(write(table, tmp_path / f"plain{suffix}"), spec(path))
    for row, header in HOLES:
        canon = next((k for k, v in COLUMNS.items() if v == header), "kuehlmittel")
        assert np.isnan(frame[canon].iloc[row]), (token, header)
        frame.loc[frame.index[row], canon] = plain[canon].iloc[row]
    assert frame["kuehlmittel"].dtype == np.float64  # a marker does not make the column text
    pd.testing.assert_frame_equal(frame, plain, check_like=True, check_exact=False)


@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
@pytest.mark.parametrize("token", TOKENS)
def test_an_undeclared_marker_names_the_cell_and_the_key(tmp_path, token, suffix):
    table = logger_table().astype(object)
    table.loc[10, "Temp T3"] = token
    path = write(table, tmp_path / f"log{suffix}")
    with pytest.raises(RawFormatError) as info:
        read_log(path, spec(path))
    message = str(info.value)
    row = 10 + 2  # the header is line/row 1
    where = f"sheet 'Daten', row {row}" if suffix == ".xlsx" else f"line {row}"
    assert message.startswith(f"{path}, {where}, column 'Temp T3': {token!r} is not a")
    assert "expected a number (deg C) for T3" in message
    assert f'a missing-value marker? list it in input.missing_values: ["{token}"]' in message


def test_a_number_or_a_decimal_comma_is_not_called_a_marker(tmp_path):
    table = logger_table().astype(object)
    table.loc[10, "Temp T3"] = "21,5"
    path = write(table, tmp_path / "log.csv")
    with pytest.raises(RawFormatError, match="decimal comma") as info:
        read_log(path, spec(path))
    assert "missing_values" not in str(info.value)


@pytest.mark.parametrize(
    "value, fragment",
    [
        ("---", "expected a list of texts"),
        ([None], r"missing_values\[0\]: None is not a text; quote the marker"),
        (["-9999"], "is a number; .* clean.open_circuit_values"),
        (["NaN", "NaN"], "listed twice"),
        ([" "], "1 to 32 characters"),
    ],
)
def test_a_wrong_missing_values_key_is_refused_naming_it(value, fragment):
    with pytest.raises(InputSpecError, match=f"input.{fragment}" if fragment[0] == "m" else fragment):
        normalise_input_spec({"format": "csv", "missing_values": value})


@pytest.mark.parametrize("fmt", ["native", "csv", "xlsx"])
def test_missing_values_is_a_key_of_every_format_and_validates_in_the_config(fmt):
    assert normalise_input_spec({"format": fmt, "missing_values": ["---"]})["missing_values"] == ["---"]
    assert normalise_input_spec({"format": fmt})["missing_values"] == []
    config = {"machines": {"m": {"input": {"format": fmt, "missing_values": ["#N/A", "---"]}}}}
    validate_config(config)
    assert machine_settings(config, "m")["input"]["missing_values"] == ["#N/A", "---"]


def native_text(table: pd.DataFrame) -> str:
    """``table`` (:func:`logger_table`) in the native layout: its columns under the canonical names."""
    names = {header: canon for canon, header in COLUMNS.items()} | {"Kuehlmittel": "kuehlmittel"}
    return table.rename(columns=names).to_csv(index=False)


@pytest.mark.parametrize("token", TOKENS)
def test_the_native_reader_reads_a_declared_marker_as_the_mapped_reader_does(tmp_path, token):
    path = tmp_path / "log.csv"
    path.write_text(native_text(with_marker(logger_table(), token)), encoding="utf-8")
    markers = ["unused", token]
    frame = read_log(path, {"format": "native", "missing_values": markers})
    mapped = read_log(path, {"format": "csv", "missing_values": markers})
    for row, header in HOLES:
        canon = next((k for k, v in COLUMNS.items() if v == header), "kuehlmittel")
        assert np.isnan(frame[canon].iloc[row]), (token, header)
    assert frame["kuehlmittel"].dtype == np.float64  # a marker does not make the column text
    pd.testing.assert_frame_equal(frame, mapped)
    plain = tmp_path / "plain.csv"
    plain.write_text(native_text(logger_table()), encoding="utf-8")
    assert read_log(plain, {"format": "native", "missing_values": markers}).notna().all().all()


@pytest.mark.parametrize("token", TOKENS)
def test_an_undeclared_marker_in_a_native_log_names_the_cell_and_the_key(tmp_path, token):
    table = logger_table().astype(object)
    table.loc[10, "Temp T3"] = token
    path = tmp_path / "log.csv"
    path.write_text(native_text(table), encoding="utf-8")
    with pytest.raises(RawFormatError) as info:
        read_log(path)
    message = str(info.value)
    assert message.startswith(f"{path}, line 12, column 'T3': {token!r} is not a")
    assert f'a missing-value marker? list it in input.missing_values: ["{token}"]' in message


def test_init_proposes_the_markers_of_native_logs_and_the_block_reads_them(tmp_path):
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    path = folder / "log.csv"
    path.write_text(native_text(with_marker(logger_table(), "---")), encoding="utf-8")
    s = survey("m", read_unknown_logs(path))
    assert s.format == "native" and dict(s.missing_values) == {"---": 5}
    block = config_block(s)
    assert "format: native" in block and 'missing_values: ["---"]' in block
    config = {"machines": {"m": parse_block(block, "m")}}
    validate_config(config)
    frame = read_log(path, machine_settings(config, "m")["input"])
    assert frame["T3"].isna().sum() == 2 and frame["disp_um"].isna().sum() == 1


def test_markers_found_only_in_columns_of_numbers():
    numbers = [str(x) for x in range(40)]
    columns = [
        numbers[:-2] + ["---", "NaN"],
        numbers[:-1] + ["---"],
        ["2026-01-01 08:00"] * 39 + ["ERR"],  # a time column: not a column of numbers
        ["Start"] + [None] * 39,  # remarks
        numbers[:-1] + ["12a"],  # a text with a digit is not a marker
    ]
    assert dict(missing_markers(columns)) == {"---": 2, "NaN": 1}
    words = ["alpha", "beta", "gamma", "delta", "epsilon", "zeta", "eta", "theta", "iota"]
    assert not missing_markers([numbers + words])  # nine different texts: text, not markers


@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
def test_init_proposes_the_markers_and_the_block_reads_the_logs(tmp_path, suffix):
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    paths = []
    for k, token in enumerate(("---", "#N/A")):
        table = with_marker(logger_table(seed=k), token)
        table.loc[200, "Temp T5"] = "NaN"
        paths.append(write(table, folder / f"log{k}{suffix}"))
    s = survey("m", [t for p in paths for t in read_unknown_logs(p)])
    assert dict(s.missing_values) == {"---": 5, "#N/A": 5, "NaN": 2}
    assert {g.header: g.role for g in s.guesses}["Temp T3"] == "temperature"
    lines = "\n".join(findings(s))
    assert "missing values: '---' in 5 cells, '#N/A' in 5, 'NaN' in 2" in lines
    block = config_block(s)
    assert 'missing_values: ["---", "#N/A", "NaN"]' in block
    entry = parse_block(block, "m")
    config = {"machines": {"m": entry}}
    validate_config(config)
    settings = machine_settings(config, "m")
    for path in paths:
        frame = read_log(path, settings["input"])
        assert frame["T3"].isna().sum() == 2 and frame["disp_um"].isna().sum() == 1


#: Marker texts: no digit (a text with one is never a marker), no delimiter, quote or line end.
MARKER_TEXT = st.text(alphabet="-#/_!?*.abcNAnERr ", min_size=1, max_size=12).filter(str.strip)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    marker=MARKER_TEXT,
    cells=st.sets(
        st.tuples(st.integers(0, 59), st.sampled_from(["Temp T5", "Z [um]", "Kuehlmittel"])), max_size=8
    ),
)
def test_a_marker_is_missing_in_exactly_its_cells_in_the_native_and_the_mapped_reader(marker, cells):
    table = logger_table(60).astype(object)
    for row, header in cells:
        table.loc[row, header] = marker
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "log.csv"
        path.write_text(native_text(table), encoding="utf-8")
        native = read_log(path, {"format": "native", "missing_values": [marker]})
        mapped = read_log(path, {"format": "csv", "missing_values": [marker]})
    pd.testing.assert_frame_equal(native, mapped)
    for header, canon in (("Temp T5", "T5"), ("Z [um]", "disp_um"), ("Kuehlmittel", "kuehlmittel")):
        holes = {row for row, h in cells if h == header}
        assert set(np.flatnonzero(native[canon].isna().to_numpy())) == holes
