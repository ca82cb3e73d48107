"""Mapped readers: bring a machine's own CSV or xlsx layout into the canonical frame.

A machine's ``input:`` mapping in ``config.yaml`` (documented in
``docs/raw-format.md``, "Bringing your own layout") says where its columns are,
what they are called, which units and sign they use. :func:`read_mapped` reads one
file with such a mapping and returns the same canonical frame as
:func:`rafi.readers.native.read_raw_log`: ``time``, ``speed_rpm``, ``T1``..``T16``, ``disp_um``
then the remaining columns under sanitised names, indexed by the 1-based line (CSV)
or row (xlsx, as Excel shows it) of each record.

A file without a time column (``time.kind: none``) gets the times ``time.start + k *
time.period_s`` (:mod:`rafi.readers.mapped_time`); a file without a speed column its
configured constant speed (:mod:`rafi.readers.input_assumed`); both are recorded in
``attrs['metadata']['assumed']``. Cells are parsed by :mod:`rafi.readers.mapped_cells`.

Every problem with a file raises :class:`rafi.errors.RawFormatError` naming the
file, the sheet (xlsx), the line/row and the column as written in the file. A
mapping that is itself wrong raises :class:`rafi.errors.InputSpecError`.
"""

from __future__ import annotations

import difflib
import hashlib
import io
import os
import re
import unicodedata
from pathlib import Path

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.errors import RawFormatError, quote
from rafi.readers.input_assumed import constant_speed, has_constant_speed
from rafi.readers.input_spec import (
    _spec_error,
    norm_header,
    normalise_input_spec,
    resolve_columns,
)
from rafi.readers.mapped_cells import (
    XLSX_MAX_ROWS,
    Table,
    check_formulas,
    check_zip_sizes,
    excel_column,
    numeric,
    text,
)
from rafi.readers.mapped_time import assumed_notes, row_times, row_times_error, timestamps
from rafi.readers.parsing import (
    FIELD_MAX_CHARS,
    NUMERIC_COLUMNS,
    check_column_count,
    check_fields,
    decode_bytes,
    field_count_error,
    read_file_bytes,
    split_fields,
    split_lines,
    to_naive_ns,
    unreadable_error,
)

# --------------------------------------------------------------------------- the mapping


def sanitise_name(header: str) -> str:
    """A header as a snake_case ASCII column name: ``'Verlagerung X1 [µm]'`` -> ``'verlagerung_x1_um'``."""
    text = norm_header(header).replace("µ", "u").replace("μ", "u").replace("°", "")
    text = text.replace("ß", "ss").replace("%", "pct")
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^0-9a-zA-Z]+", "_", text).strip("_").lower()
    if not text:
        return "column"
    if text[0].isdigit():
        text = "c_" + text
    return text


def _simple(text: str) -> str:
    return re.sub(r"[\W_]+", "", sanitise_name(text)).casefold()


def closest_headers(wanted: str, available: list[str], n: int = 3) -> list[str]:
    """The ``n`` available headers most like ``wanted`` (difflib ratio, units/case/punctuation
    differences forgiven first): ``'Temperatur 3 [°C]'`` finds ``'Temperatur 3 [C]'``."""
    sw = _simple(wanted)

    def score(h: str) -> float:
        sh = _simple(h)
        exact = 1.0 if sh == sw and sw else 0.0
        return exact + max(
            difflib.SequenceMatcher(None, wanted, h).ratio(), difflib.SequenceMatcher(None, sw, sh).ratio()
        )

    ranked = sorted(available, key=score, reverse=True)
    return [h for h in ranked[:n] if score(h) >= 0.4]


# --------------------------------------------------------------------------- file readers


def _read_csv_table(path: Path, raw: bytes, spec: dict) -> Table:
    text = decode_bytes(
        path, raw, spec["encoding"], hint="set input.encoding to the file's encoding (e.g. latin-1, cp1252)"
    )
    lines = split_lines(text)
    hr = spec["header_row"]
    if hr > len(lines) or not lines[hr - 1].strip():
        raise RawFormatError(
            path,
            f"no header at line {hr} (input.header_row); the file has {len(lines)} line(s)",
            line=min(hr, max(len(lines), 1)),
        )
    delim = spec["delimiter"]
    header = [h.strip() for h in split_fields(path, lines[hr - 1], hr, delim)]
    check_fields(path, header, hr)
    check_column_count(path, header, hr)
    if len(header) == 1:
        for other in (";", ",", "\t", "|"):
            if other != delim and other in header[0]:
                raise RawFormatError(
                    path,
                    f"header is separated by {other!r}, not by the "
                    f"configured delimiter {delim!r}; set input.delimiter",
                    line=hr,
                )
    rows, numbers = [], []
    first_data = hr + spec["skip_rows"]  # 0-based index of the first data line
    for i in range(first_data, len(lines)):
        line = lines[i]
        if not line.strip():
            continue
        line_no = i + 1
        fields = split_fields(path, line, line_no, delim)
        if len(line) > FIELD_MAX_CHARS:
            check_fields(path, fields, line_no, header, raw_line=line)
        if len(fields) > len(header) and not any(f.strip() for f in fields[len(header) :]):
            fields = fields[: len(header)]
        if len(fields) != len(header):
            if [norm_header(f) for f in fields] == [norm_header(h) for h in header]:
                raise RawFormatError(
                    path,
                    "the header line is repeated inside the data; expected one header only",
                    line=line_no,
                )
            raise field_count_error(
                path,
                line,
                line_no,
                len(fields),
                len(header),
                last=i == len(lines) - 1,
                too_many_hint=(
                    "a decimal comma with delimiter ','? set input.delimiter and input.decimal"
                    if delim == ","
                    else "a delimiter inside a value?"
                ),
            )
        rows.append(fields)
        numbers.append(line_no)
    return Table(path, header, rows, numbers, hr, None)


def _read_xlsx_table(path: Path, raw: bytes, spec: dict) -> Table:
    """The sheet of the workbook whose bytes are ``raw`` (read once: the file is not opened again)."""
    try:
        import openpyxl
    except ImportError as exc:  # pragma: no cover - openpyxl is a dependency
        raise RawFormatError(path, f"reading xlsx needs openpyxl ({exc})") from None
    check_zip_sizes(path, raw)
    try:
        wb = openpyxl.load_workbook(io.BytesIO(raw), read_only=True, data_only=True)
    except OSError as exc:
        raise unreadable_error(path, exc) from None
    except Exception as exc:  # zip, XML, openpyxl's own errors: all mean "not a workbook"
        raise RawFormatError(
            path,
            f"not a readable .xlsx workbook ({type(exc).__name__}: {quote(exc)}); "
            "save it as Excel Workbook (.xlsx)",
        ) from None
    try:
        names = list(wb.sheetnames)
        sheet = spec["sheet"]
        available = ", ".join(repr(n) for n in names)
        if isinstance(sheet, int):
            if sheet >= len(names):
                raise RawFormatError(
                    path, f"no sheet number {sheet} (0-based, input.sheet); the workbook has: {available}"
                )
            name = names[sheet]
        else:
            match = [n for n in names if norm_header(n) == norm_header(sheet)]
            if not match:
                close = difflib.get_close_matches(sheet, names, n=3, cutoff=0.5)
                hint = f"; closest: {', '.join(map(repr, close))}" if close else ""
                raise RawFormatError(
                    path, f"no sheet {sheet!r} (input.sheet); the workbook has: {available}{hint}"
                )
            name = match[0]
        ws = wb[name]
        # the sheet's own <dimension> may be stale or forged: rows past it would be dropped
        # silently, and a forged A1:XFD1048576 pads every row to 16384 cells
        ws.reset_dimensions()
        hr = spec["header_row"]
        header = None
        header_cells: list = []
        rows, numbers = [], []
        try:
            for row_no, values in enumerate(ws.iter_rows(values_only=True), start=1):
                if row_no > XLSX_MAX_ROWS:
                    raise RawFormatError(
                        path,
                        f"a row numbered beyond {XLSX_MAX_ROWS}, the last row of an Excel sheet: "
                        "a corrupted or crafted workbook; open and save it in Excel or LibreOffice",
                        line=row_no,
                        sheet=name,
                    )
                if row_no < hr:
                    continue
                values = list(values)
                if row_no == hr:
                    header_cells = list(values)
                    while values and (values[-1] is None or str(values[-1]).strip() == ""):
                        values.pop()
                    header = ["" if v is None else str(v) for v in values]
                    check_fields(path, header, row_no, sheet=name)
                    check_column_count(path, header, row_no, sheet=name)
                    continue
                if row_no <= hr + spec["skip_rows"]:
                    continue
                if all(v is None or (isinstance(v, str) and not v.strip()) for v in values):
                    continue
                check_fields(path, values, row_no, header, sheet=name)
                if len(values) > len(header):
                    for j in range(len(header), len(values)):
                        if values[j] is not None and str(values[j]).strip():
                            raise RawFormatError(
                                path,
                                f"cell {excel_column(j)}{row_no} holds {quote(values[j])} but "
                                "its column has no header",
                                line=row_no,
                                column=excel_column(j),
                                sheet=name,
                            )
                    values = values[: len(header)]
                elif len(values) < len(header):
                    values = values + [None] * (len(header) - len(values))
                rows.append(values)
                numbers.append(row_no)
        except RawFormatError:
            raise
        except OSError as exc:
            raise unreadable_error(path, exc) from None
        except Exception as exc:  # malformed sheet XML
            raise RawFormatError(
                path, f"cannot read the sheet ({type(exc).__name__}: {quote(exc)})", sheet=name
            ) from None
        if not header:
            raise RawFormatError(
                path,
                f"no header in row {hr} (input.header_row); the sheet is empty there",
                line=hr,
                sheet=name,
            )
        table = Table(path, header, rows, numbers, hr, name)
        check_formulas(table, header_cells[: len(header)], raw)
        return table
    finally:
        wb.close()


# --------------------------------------------------------------------------- main entry


def _file_speed(path: Path, spec: dict) -> tuple[float, str] | None:
    """The file's configured constant speed and its key; None when the speed is read from a column."""
    if not has_constant_speed(spec):
        return None
    found = constant_speed(path.name, spec)
    if found is None:
        globs = ", ".join(repr(g) for g in spec["speed"]["constant_rpm_by_file"])
        raise RawFormatError(
            path,
            f"no speed for this file: the mapping reads no speed column and no glob of "
            f"input.speed.constant_rpm_by_file ({globs}) matches the file name {path.name!r}; "
            "add a glob that matches it, or set input.speed.constant_rpm for the machine",
        )
    return found


def read_mapped(path: str | os.PathLike, input_spec: dict) -> pd.DataFrame:
    """Read a csv or xlsx log with a machine's ``input:`` mapping into the canonical frame.

    Parameters
    ----------
    path : str or os.PathLike
        The raw file.
    input_spec : dict
        The ``input:`` mapping (normalised here with :func:`normalise_input_spec`);
        ``format`` must be ``csv`` or ``xlsx``.

    Returns
    -------
    pandas.DataFrame
        Canonical frame: ``time``, ``speed_rpm``, ``T1``..``T16`` (deg C),
        ``disp_um`` (um, sign and unit applied), then the other columns of the file
        under sanitised names (``'Verlagerung X1 [µm]'`` -> ``verlagerung_x1_um``,
        values as in the file). Index ``line`` = 1-based line (csv) or row (xlsx).
        ``attrs``: ``metadata`` (``format``, ``sheet`` for xlsx, ``columns`` =
        canonical -> header used, ``sample_period_s`` if the spec gives it,
        ``assumed`` = canonical column -> sentence for ``time`` / ``speed_rpm`` when they
        come from the config rather than the file, see
        :func:`rafi.readers.mapped_time.assumed_notes`), ``source``, ``sha256``.
        Without a time column (``time.kind: none``) data row k is at ``time.start + k *
        time.period_s``; without a speed column every row has the file's constant speed
        (:func:`rafi.readers.input_spec.constant_speed`).

    Raises
    ------
    RawFormatError
        Naming file, sheet (xlsx), line/row and the column as written in the file; also a
        file with no configured constant speed when the mapping reads no speed column.
    InputSpecError
        If the mapping is invalid (two speed globs with different speeds match the file
        included).
    """
    path = Path(path)
    spec = normalise_input_spec(input_spec)
    if spec["format"] not in ("csv", "xlsx"):
        raise _spec_error("format", f"read_mapped reads csv or xlsx, not {spec['format']!r}")
    raw = read_file_bytes(path)
    speed = _file_speed(path, spec)
    if spec["format"] == "csv":
        table = _read_csv_table(path, raw, spec)
    else:
        if not raw:
            raise RawFormatError(path, "file is empty; expected an .xlsx workbook")
        table = _read_xlsx_table(path, raw, spec)

    header = table.header
    wanted = resolve_columns(spec)
    where_row = table.header_row
    positions: dict[str, int] = {}
    for canon, theirs in wanted.items():
        key = norm_header(theirs)
        hits = [j for j, h in enumerate(header) if h == key]
        if not hits:
            candidates = [h for h in header if h]
            close = closest_headers(key, candidates)
            if close:
                hint = "closest: " + ", ".join(repr(c) for c in close)
            else:
                hint = (
                    "available: "
                    + ", ".join(repr(c) for c in candidates[:8])
                    + (", ..." if len(candidates) > 8 else "")
                )
            where = (
                "input.displacement.column"
                if (canon == "disp_um" and spec["displacement"]["column"])
                else f"input.columns.{canon}"
            )
            raise RawFormatError(
                path,
                f"header {theirs!r} ({where}) not found in the header row; {hint}",
                line=where_row,
                column=theirs,
                sheet=table.sheet,
            )
        if len(hits) > 1:
            raise RawFormatError(
                path,
                f"header {theirs!r} appears {len(hits)} times "
                f"(columns {', '.join(excel_column(j) for j in hits)}); "
                f"cannot tell which one is {canon}",
                line=where_row,
                column=theirs,
                sheet=table.sheet,
            )
        positions[canon] = hits[0]
    if not table.rows:
        raise RawFormatError(path, "header found but no data rows", line=where_row, sheet=table.sheet)

    cols = list(zip(*table.rows))
    index = pd.Index(table.row_numbers, name="line", dtype="int64")
    frame = pd.DataFrame(index=index)
    if spec["time"]["kind"] == "none":
        problem = row_times_error(len(table.rows), spec)
        if problem:
            raise RawFormatError(path, problem, line=table.row_numbers[-1], sheet=table.sheet)
        times = row_times(len(table.rows), spec)
    else:
        j = positions["time"]
        times = timestamps(table, list(cols[j]), spec, header[j], j)
    frame["time"] = to_naive_ns(times).to_numpy()
    for canon in NUMERIC_COLUMNS:
        if canon == "speed_rpm" and speed is not None:
            frame[canon] = np.full(len(index), speed[0], dtype="float64")
            continue
        j = positions[canon]
        unit = {"speed_rpm": "r/min", "disp_um": spec["displacement"]["unit"]}.get(
            canon, "deg " + spec["temperature_unit"]
        )
        values = numeric(
            table, list(cols[j]), spec["decimal"], header[j], j, f"a number ({unit}) for {canon}"
        )
        if canon == "disp_um":
            values = values * (1000.0 if spec["displacement"]["unit"] == "mm" else 1.0)
            values = values * spec["displacement"]["sign"] + 0.0  # no -0.0
        elif canon in SENSORS and spec["temperature_unit"] == "K":
            values = values - 273.15
        frame[canon] = values.astype("float64")

    if spec["keep_extra"]:
        used = set(positions.values())
        taken = set(frame.columns) | {"line"}
        for j, name in enumerate(header):
            if j in used:
                continue
            values = list(cols[j])
            if not name and all(v is None or str(v).strip() == "" for v in values):
                continue
            base = sanitise_name(name) if name else f"column_{excel_column(j).lower()}"
            new, n = base, 2
            while new in taken:
                new, n = f"{base}_{n}", n + 1
            taken.add(new)
            try:
                frame[new] = numeric(table, values, spec["decimal"], name, j, "a number")
            except RawFormatError:
                frame[new] = pd.Series(text(values), index=index, dtype="str")

    meta: dict = {"format": spec["format"]}
    if table.sheet is not None:
        meta["sheet"] = table.sheet
    meta["columns"] = {canon: header[j] for canon, j in positions.items()}
    if spec["sample_period_s"] is not None:
        meta["sample_period_s"] = spec["sample_period_s"]
    assumed = assumed_notes(spec, speed=speed)
    if assumed:
        meta["assumed"] = assumed
    frame.attrs["metadata"] = meta
    frame.attrs["source"] = str(path)
    frame.attrs["sha256"] = hashlib.sha256(raw).hexdigest()
    return frame
