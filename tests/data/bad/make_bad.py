"""Regenerate the bad-input corpus in this folder and its README (deterministic).

    python tests/data/bad/make_bad.py

``CASES`` is the single source of truth: ``tests/test_bad_input.py`` imports it and
checks that reading (``rafi.readers.logs.read_log``) and checking (``rafi.readers.checks.check_log``)
each file raises ``RawFormatError`` whose message names the file, the line/row and
column given here and contains the fragment.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
SENSORS = [f"T{i}" for i in range(1, 17)]
HEADER = ["time", "speed_rpm", *SENSORS, "disp_um"]
N_ROWS = 40
META = ["# machine: test-rig", "# sample_period_s: 5"]          # lines 1-2; header = line 3

#: Mapped layouts used by the corpus (the machining-center-b mapping, csv and xlsx).
MCB_COLUMNS = {"time": "Zeit [s]", "speed_rpm": "Drehzahl [1/min]",
               **{f"T{i}": f"Temperatur {i} [°C]" for i in range(1, 17)}}
MCB_HEADER = (["Zeit [s]", "Drehzahl [1/min]"] + [f"Temperatur {i} [°C]" for i in range(1, 17)]
              + ["Verlagerung X1 [µm]", "Verlagerung Y1 [µm]", "Verlagerung Z1 [µm]",
                 "Verlagerung Z2 [µm]", "Bemerkung"])
SPECS = {
    "native": None,
    "mcb_xlsx": {"format": "xlsx", "pattern": "*.xlsx", "sheet": "Messdaten", "header_row": 1,
                 "columns": MCB_COLUMNS, "time": {"kind": "elapsed_s"}, "sample_period_s": 15,
                 "displacement": {"column": "Verlagerung Z1 [µm]", "unit": "um", "sign": -1}},
    "mcb_csv": {"format": "csv", "pattern": "*.csv", "delimiter": ";", "decimal": ",",
                "encoding": "utf-8", "columns": MCB_COLUMNS, "time": {"kind": "elapsed_s"},
                "sample_period_s": 15,
                "displacement": {"column": "Verlagerung Z1 [µm]", "unit": "um", "sign": -1}},
}
#: check_log keyword arguments used for every case unless a case overrides them.
CHECKS = {"min_run_s": 0, "open_circuit_values": [-999.0, 999.9, 850.0]}


@dataclass
class Case:
    file: str
    what: str
    fragment: str
    line: int | None = None
    column: str | None = None
    spec: str = "native"
    checks: dict = field(default_factory=dict)
    sheet: str | None = None


def rows() -> list[list[str]]:
    """A valid 40-row native log body: 5 s sampling, 6000 r/min, temperatures +4 K."""
    out = []
    for k in range(N_ROWS):
        frac = k / (N_ROWS - 1)
        temps = [f"{21.0 + 0.2 * i + 4.0 * frac * (1 + i / 16) + 0.01 * ((k * 7 + i) % 3):.2f}"
                 for i in range(16)]
        disp = f"{25.0 * frac + 0.003 * ((k * 5) % 7):.3f}"
        out.append([f"2026-03-01T08:{(k * 5) // 60:02d}:{(k * 5) % 60:02d}", "6000", *temps, disp])
    return out


def native(body=None, header=None, meta=META) -> str:
    lines = list(meta) + [",".join(header or HEADER)]
    lines += [",".join(r) for r in (body if body is not None else rows())]
    return "\n".join(lines) + "\n"


def line_of(k: int) -> int:
    """File line of body row k (0-based) in a file written by native()."""
    return len(META) + 2 + k


def _set(body, k, col, value):
    body[k][HEADER.index(col)] = value
    return body


CASES: list[Case] = [
    Case("empty.csv", "zero bytes", "file is empty"),
    Case("header_only.csv", "metadata and header, no data", "header found but no data rows", line=3),
    Case("no_header.csv", "metadata lines only", "no header line found", line=2),
    Case("missing_column.csv", "T7 missing from the header", "missing from header: T7",
         line=3, column="T7"),
    Case("semicolon_delimiter.csv", "';' used as delimiter", "separated by ';'", line=3),
    Case("decimal_comma.csv", "decimal commas in a comma-separated file", "decimal comma",
         line=line_of(0)),
    Case("text_in_numeric.csv", "'ERR' in T3", "'ERR' is not a number", line=line_of(9),
         column="T3"),
    Case("infinite_value.csv", "'inf' in disp_um", "'inf' is not a number", line=line_of(4),
         column="disp_um"),
    Case("time_backwards.csv", "clock reset: time jumps back one hour", "clock reset",
         line=line_of(25), column="time"),
    Case("too_short.csv", "195 s log, min_run_s 1800", "shorter than the minimum run",
         line=line_of(N_ROWS - 1), column="time", checks={"min_run_s": 1800}),
    Case("all_nan_sensor.csv", "T5 empty in every row", "T5 has no value", column="T5"),
    Case("open_circuit_sensor.csv", "T11 reads the open-circuit value -999 throughout",
         "T11 has no value", column="T11"),
    Case("constant_disp.csv", "disp_um stuck at 12.345", "is constant", column="disp_um"),
    Case("mm_not_um.csv", "displacement logged in mm", "values look like millimetres; set "
         "displacement.unit: mm", column="disp_um"),
    Case("negative_speed.csv", "speed -6000 r/min", "is negative", line=line_of(7),
         column="speed_rpm"),
    Case("absurd_speed.csv", "speed 600000 r/min", "is absurd", line=line_of(3),
         column="speed_rpm"),
    Case("temp_out_of_range.csv", "T9 reads 450 (not an open-circuit value; -999 in T2 is)",
         "outside -40..200", line=line_of(20), column="T9"),
    Case("truncated_last_line.csv", "last line cut off mid-row", "last line looks truncated",
         line=line_of(N_ROWS - 1)),
    Case("latin1_bytes.csv", "latin-1 'ü' in a metadata line", "not valid UTF-8", line=3),
    Case("utf16.csv", "saved as UTF-16", "UTF-16", line=1),
    Case("nul_bytes.csv", "NUL bytes inside a row", "NUL byte", line=line_of(5)),
    Case("duplicated_header.csv", "header repeated inside the data", "header line is repeated",
         line=line_of(15)),
    Case("duplicate_column.csv", "T3 twice in the header", "appears twice", line=3, column="T3"),
    Case("empty_timestamp.csv", "empty time field", "empty timestamp", line=line_of(11),
         column="time"),
    Case("bad_timestamp.csv", "German date format in a native file", "is not an ISO-8601",
         line=line_of(0), column="time"),
    Case("year_out_of_range.csv", "timestamp in year 3026", "outside the supported years",
         line=line_of(6), column="time"),
    Case("bad_metadata.csv", "sample_period_s: five", "expected a number of seconds", line=2),
    Case("stray_quote.csv", "an unclosed quote swallows the rest of a row", "found 6 fields",
         line=line_of(8)),
    Case("wrong_sheet.xlsx", "mapping asks for sheet 'Messdaten', workbook has 'Tabelle1'",
         "no sheet 'Messdaten' (input.sheet); the workbook has: 'Tabelle1'", spec="mcb_xlsx"),
    Case("not_a_workbook.xlsx", "a CSV renamed to .xlsx", "not a readable .xlsx workbook",
         spec="mcb_xlsx"),
    Case("text_cell.xlsx", "'Fühlerbruch' in Temperatur 4 at row 7",
         "'Fühlerbruch' is not a number", line=7, column="Temperatur 4 [°C]", spec="mcb_xlsx",
         sheet="Messdaten"),
    Case("mapped_missing_header.csv", "'Temperatur 3 [C]' written without the degree sign",
         "closest: 'Temperatur 3 [C]'", line=1, column="Temperatur 3 [°C]", spec="mcb_csv"),
    Case("mapped_wrong_delimiter.csv", "comma-separated although the mapping says ';'",
         "set input.delimiter", line=1, spec="mcb_csv"),
    Case("mapped_z1_stuck.csv", "mapped target channel Z1 constant (probe stuck)", "is constant",
         column="disp_um", spec="mcb_csv"),
]


def _mcb_rows(n=30):
    out = []
    for k in range(n):
        frac = k / (n - 1)
        temps = [round(21.0 + 0.1 * i + 4.0 * frac, 2) for i in range(16)]
        z1 = round(-20.0 * frac, 3)
        out.append([k * 15, 6000, *temps, 0.5 * frac, -0.4 * frac, z1, 0.9 * z1, None])
    return out


def _mcb_csv(rows_, header=MCB_HEADER, delim=";") -> bytes:
    def cell(v):
        if v is None:
            return ""
        return f"{v:g}".replace(".", ",") if isinstance(v, (int, float)) else str(v)
    lines = [delim.join(header)] + [delim.join(cell(v) for v in r) for r in rows_]
    return ("\n".join(lines) + "\n").encode("utf-8")


def _xlsx(path: Path, sheets: dict[str, list[list]]) -> None:
    import openpyxl
    wb = openpyxl.Workbook()
    first = True
    for name, table in sheets.items():
        ws = wb.active if first else wb.create_sheet(name)
        ws.title = name
        first = False
        for r in table:
            ws.append(r)
    wb.save(path)


def build() -> None:
    w = {}
    w["empty.csv"] = b""
    w["header_only.csv"] = native(body=[])
    w["no_header.csv"] = "\n".join(META) + "\n"
    hdr = [c for c in HEADER if c != "T7"]
    w["missing_column.csv"] = native(body=[[v for c, v in zip(HEADER, r) if c != "T7"]
                                           for r in rows()], header=hdr)
    w["semicolon_delimiter.csv"] = native().replace(",", ";")
    w["decimal_comma.csv"] = native(body=[[v.replace(".", ",") for v in r] for r in rows()])
    w["text_in_numeric.csv"] = native(_set(rows(), 9, "T3", "ERR"))
    w["infinite_value.csv"] = native(_set(rows(), 4, "disp_um", "inf"))
    b = rows()
    for k in range(25, N_ROWS):
        b[k][0] = b[k][0].replace("T08:", "T07:")
    w["time_backwards.csv"] = native(b)
    w["too_short.csv"] = native()
    b = rows()
    for r in b:
        r[HEADER.index("T5")] = ""
    w["all_nan_sensor.csv"] = native(b)
    b = rows()
    for r in b:
        r[HEADER.index("T11")] = "-999.0"
    w["open_circuit_sensor.csv"] = native(b)
    b = rows()
    for r in b:
        r[-1] = "12.345"
    w["constant_disp.csv"] = native(b)
    b = rows()
    for r in b:
        r[-1] = f"{float(r[-1]) / 1000:.5f}"
    w["mm_not_um.csv"] = native(b)
    w["negative_speed.csv"] = native(_set(rows(), 7, "speed_rpm", "-6000"))
    w["absurd_speed.csv"] = native(_set(rows(), 3, "speed_rpm", "600000"))
    b = _set(rows(), 20, "T9", "450.00")
    w["temp_out_of_range.csv"] = native(_set(b, 12, "T2", "-999.0"))
    text = native()
    w["truncated_last_line.csv"] = text[: text.rstrip("\n").rfind(",", 0, len(text) - 30)]
    w["latin1_bytes.csv"] = ("# machine: test-rig\n# sample_period_s: 5\n# notes: Prüfstand\n"
                             + native(meta=[])).encode("latin-1")
    w["utf16.csv"] = native().encode("utf-16")
    b = rows()
    b[5][3] = "21\x00\x0045"
    w["nul_bytes.csv"] = native(b)
    lines = native().splitlines()
    lines.insert(line_of(15) - 1, lines[len(META)])
    w["duplicated_header.csv"] = "\n".join(lines) + "\n"
    w["duplicate_column.csv"] = native(header=[*HEADER[:-1], "T3"])
    w["empty_timestamp.csv"] = native(_set(rows(), 11, "time", ""))
    b = rows()
    for r in b:
        d, t = r[0].split("T")
        y, m, dd = d.split("-")
        r[0] = f"{dd}.{m}.{y} {t}"
    w["bad_timestamp.csv"] = native(b)
    b = rows()
    b[6][0] = b[6][0].replace("2026", "3026")
    w["year_out_of_range.csv"] = native(b)
    w["bad_metadata.csv"] = native(meta=["# machine: test-rig", "# sample_period_s: five"])
    b = rows()
    b[8][5] = '"' + b[8][5]
    # the quote runs to the end of the line: 5 + 1 + ... -> the remaining fields merge
    w["stray_quote.csv"] = native(b)
    w["not_a_workbook.xlsx"] = native()
    w["mapped_missing_header.csv"] = _mcb_csv(
        _mcb_rows(), header=[h.replace("Temperatur 3 [°C]", "Temperatur 3 [C]") for h in MCB_HEADER])
    w["mapped_wrong_delimiter.csv"] = _mcb_csv(_mcb_rows(), delim=",")
    r = _mcb_rows()
    for row in r:
        row[20] = -3.25
    w["mapped_z1_stuck.csv"] = _mcb_csv(r)

    for name, data in w.items():
        (HERE / name).write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    _xlsx(HERE / "wrong_sheet.xlsx", {"Tabelle1": [MCB_HEADER, *_mcb_rows()]})
    r = _mcb_rows()
    r[5][5] = "Fühlerbruch"          # row 7 in Excel (header row 1, data from row 2)
    _xlsx(HERE / "text_cell.xlsx", {"Info": [["Maschine", "B"]], "Messdaten": [MCB_HEADER, *r]})

    names = {c.file for c in CASES}
    missing = names - {p.name for p in HERE.iterdir()}
    assert not missing, missing
    readme = ["# Bad-input corpus", "",
              "Small files that must each be refused with a `RawFormatError` naming the file, the",
              "line (or sheet and row) and the column. Generated by `make_bad.py` (the `CASES`",
              "list there is what `tests/test_bad_input.py` checks); do not edit by hand.",
              "Mapping `mcb_xlsx` / `mcb_csv` = the machining-center-b layout (docs/raw-format.md).",
              "",
              "Two more corpora, generated because their files are large: logs that look valid but",
              "are wrong (units, sign, channels, copies, metadata, links, files still being written;",
              "`rafi.twin.hostile`, `rafi simulate hostile`, checked end to end by",
              "`tests/test_hostile_corpus.py`) and malformed formats and names (zip bombs, FIFOs,",
              "10,000 columns, hostile file names; `tests/test_format_sweep.py`).",
              "", "| file | mapping | what is wrong | line/row | column | message contains |",
              "|---|---|---|---|---|---|"]
    for c in CASES:
        readme.append(f"| `{c.file}` | {c.spec} | {c.what} | {c.line or ''} | "
                      f"{c.column or ''} | {c.fragment.replace('|', '/')} |")
    (HERE / "README.md").write_text("\n".join(readme) + "\n", encoding="utf-8")


if __name__ == "__main__":
    build()
