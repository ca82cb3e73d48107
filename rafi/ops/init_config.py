"""The commented config block ``rafi init`` proposes for a machine, and adding it to config.yaml.

:func:`config_block` writes YAML text for ``machines: <machine>:`` from a
:class:`rafi.ops.init_survey.Survey`: every key the data decide, with a comment saying where it
came from; every key the data leave open (a unit, a sign, a period, a start date) commented out
with ``# CHECK:`` and what to decide. Keys the data answer but that are the user's decision
(training speeds, the split) are written and carry a ``# CHECK:`` too. :func:`parse_block`
reads the text back (it must load as YAML to the machine's entry); :func:`add_machine` puts it
under ``machines:`` of a config text, refusing a machine that is already there, and checks the
whole config with :mod:`rafi.settings`.
"""

from __future__ import annotations

import json
import re

import yaml

from rafi.contract import EPOCH_CLOCKS
from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.errors import RafiUserError, SettingsError
from rafi.ops.init_pairs import main_pattern
from rafi.ops.init_survey import (
    FALL_BACK_ZONES,
    Survey,
    clock_back_text,
    elapsed_kind,
    footer_counts,
    markers_text,
    probe_names,
)
from rafi.readers.name_dates import dates_in_name
from rafi.settings import machine_settings, validate_config

#: Column at which line comments start (when the text is shorter).
COMMENT_COLUMN = 40

#: Longest line with a comment beside its key; a longer comment goes on the line above.
LINE_MAX = 110


def q(text) -> str:
    """A YAML scalar for ``text``: a double-quoted string (JSON escapes are YAML's), a number as it is."""
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        return f"{text:g}" if isinstance(text, float) else str(text)
    return json.dumps(str(text), ensure_ascii=False)


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


class _Lines:
    """YAML lines with aligned comments; ``off`` writes the key commented out."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def add(self, indent: int, text: str, comment: str | None = None, *, off: bool = False) -> None:
        body = " " * indent + ("# " if off else "") + text
        if comment and len(body.ljust(COMMENT_COLUMN - 1)) + 3 + len(comment) > LINE_MAX:
            self.note(indent, comment)  # a long comment goes on its own line, above its key
        elif comment:
            body = body.ljust(COMMENT_COLUMN - 1) + " # " + comment
        self.lines.append(body.rstrip())

    def note(self, indent: int, comment: str) -> None:
        self.lines.append(" " * indent + "# " + comment)

    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


def _period_comment(s: Survey) -> str:
    return f"median time step of {s.time.header!r} ({s.regular_share:.0%} of steps regular)"


def _method_keys(out: _Lines, s: Survey, period: float | None) -> None:
    """sample_period_s, training_speeds_rpm, reference, runs (indent 4)."""
    if period is not None and s.period_s is not None and s.regular_share >= 0.9:
        out.add(
            4, f"sample_period_s: {_num(period)}", _period_comment(s) if s.time else "given with --period-s"
        )
    elif period is not None:
        out.add(4, f"sample_period_s: {_num(period)}", "given with --period-s")
    elif s.format != "native":
        why = "no time column" if s.time is None else "irregular time steps"
        out.add(4, "sample_period_s: 60", f"CHECK: {why}; the seconds between two rows", off=True)
    speeds = s.training.get("speeds")
    if speeds:
        out.add(
            4, f"training_speeds_rpm: [{', '.join(_num(x) for x in speeds)}]", f"CHECK: {s.training['why']}"
        )
    else:
        out.add(
            4, "training_speeds_rpm: []", "CHECK: no speed steps found; name the training speeds", off=True
        )
    if s.kind == "continuous":
        out.add(4, "reference:")
        out.add(6, "rule: log_start", "one continuous log: its runs do not start cold")
    runs = []
    if s.kind == "continuous" and "split_s" in s.training:
        split = _num(s.training["split_s"])
        runs.append(("idle_training: true", "the cool-downs before the split train too"))
        runs.append(("windows:", f"CHECK: a chronological split at {s.training['split_s'] / 3600:.1f} h"))
        glob = f", log: {q(s.training['log'])}" if len(s.tables) > 1 else ""
        runs.append((f"  - {{role: training, end: {split}, unit: elapsed_s{glob}}}", None))
        runs.append((f"  - {{role: validation, start: {split}, unit: elapsed_s{glob}}}", None))
    if s.min_constant is not None:
        runs.append((f"min_constant_s: {_num(s.min_constant[0])}", s.min_constant[1]))
    if runs:
        out.add(4, "runs:")
        for text, comment in runs:
            out.add(6, text, comment)


def _time_keys(out: _Lines, s: Survey, period: float | None) -> None:
    """input.time (indent 6)."""
    out.add(6, "time:")
    if s.time is None:
        out.add(8, "kind: none", "no time column: row k at start + k * period_s")
        if period is not None:
            out.add(8, f"period_s: {_num(period)}", "given with --period-s")
        else:
            out.add(8, "period_s: 60", "CHECK: the seconds between two rows (--period-s)", off=True)
        out.add(8, 'start: "2026-01-01T00:00:00"', "CHECK: when the first row was logged", off=True)
        return
    if s.time.unit == "timeofday" and s.date is None and s.date_from_name:
        out.add(8, "kind: timestamp", f"{s.time.header!r}: {s.time.why}")
        name = s.first.path.name
        why = f"the date in the file names ({name}: {dates_in_name(name, s.date_from_name)[0]})"
        if s.date_from_name_check:
            out.note(8, f"CHECK: {s.date_from_name_check}")
        out.add(8, f"date_from_name: {q(s.date_from_name)}", why)
        _timezone_key(out, s)
        return
    if s.time.unit == "timeofday" and s.date is not None:
        out.add(8, "kind: timestamp", f"{s.time.header!r}: {s.time.why}")
        out.add(8, f"date_column: {q(s.date.header)}", f"{s.date.header!r}: {s.date.why}")
        if s.time_format:
            out.add(8, f"format: {q(s.time_format)}", "of the date and the time of day joined by a space")
        _timezone_key(out, s)
        return
    if s.time.unit == "timestamp":
        out.add(8, "kind: timestamp", f"{s.time.header!r}: {s.time.why}")
        if s.time_format:
            out.add(8, f"format: {q(s.time_format)}")
        _timezone_key(out, s)
        return
    if s.time.unit in EPOCH_CLOCKS:
        out.add(8, f"kind: {s.time.unit}", f"{s.time.header!r}: {s.time.why}")
        return
    out.add(8, f"kind: {elapsed_kind(s.time.unit)}", f"{s.time.header!r}: {s.time.why}")
    hint = s.first.start_hint
    if hint:
        out.add(8, f"start: {q(hint[0])}", f"from {hint[1]}")
    else:
        out.add(8, 'start: "2026-01-01T00:00:00"', "CHECK: when elapsed second 0 was", off=True)


def _timezone_key(out: _Lines, s: Survey) -> None:
    """input.time.timezone, commented out, when a clock goes back by about an hour (indent 8)."""
    if s.clock_back is not None:
        zone = s.clock_back_zone or FALL_BACK_ZONES[0]
        region = ""
        if s.clock_back_zone:
            region = f" ({zone}'s clocks go back that day; another zone of its region may be yours)"
        why = f"CHECK: {clock_back_text(s.clock_back)} your logger's time zone{region}"
        out.add(8, f"timezone: {q(zone)}", why, off=True)


def _displacement_keys(out: _Lines, s: Survey) -> None:
    """input.displacement (indent 6)."""
    if not s.probes:
        out.add(6, "displacement:")
        out.add(8, 'column: "..."', "CHECK: no displacement column found; your probe's header", off=True)
        return
    first = s.probes[0]
    several = len(s.probes) > 1
    out.add(6, "displacement:")
    if not several:
        out.add(8, f"column: {q(first.header)}", first.why)
    if first.unit in ("um", "mm"):
        out.add(8, f"unit: {first.unit}", first.why if several else None)
    else:
        out.add(8, "unit: um", f"CHECK: {first.check or 'um or mm?'}", off=True)
    flip = -1 if s.sign == -1 else 1
    why = f"CHECK: {s.sign_why}; -1 if your probe counts growth towards the table as negative"
    out.add(8, f"sign: {flip}", why, off=True)
    if several:
        out.add(6, "probes:", f"{len(s.probes)} displacement columns: one model and one verdict per probe")
        directions = s.probe_signs if len(s.probe_signs) == len(s.probes) else [(None, "")] * len(s.probes)
        names = probe_names([g.header for g in s.probes])
        for name, guess, (_, direction) in zip(names, s.probes, directions, strict=True):
            entry, why = f"column: {q(guess.header)}", None
            if guess.unit in ("um", "mm") and guess.unit != first.unit:  # its own, not the first's
                entry, why = f"{entry}, unit: {guess.unit}", guess.why
            elif guess.unit not in ("um", "mm"):
                why = f"CHECK: {guess.check or 'um or mm?'}"
            out.add(8, f"{name}: {{{entry}}}", "; ".join(w for w in (why, direction) if w) or None)


def _temperature_unit(out: _Lines, s: Survey) -> None:
    units = {g.unit for g in s.temperatures}
    unsure = [g for g in s.temperatures if g.check]
    if units == {"K"}:
        out.add(6, "temperature_unit: K", "every temperature reads 250-400: Kelvin")
    elif units == {"degF"}:
        out.add(6, "temperature_unit: F", "every temperature header says deg F: converted to deg C as read")
    elif "degF" in units:
        out.add(
            6,
            "temperature_unit: C",
            "CHECK: some headers say deg F, others not: one unit a machine",
            off=True,
        )
    elif unsure:
        out.add(6, "temperature_unit: C", f"CHECK: {unsure[0].check}", off=True)
    elif units:
        out.add(6, "temperature_unit: C")


def _input_keys(out: _Lines, s: Survey, period: float | None) -> None:
    """input: (indent 4)."""
    table = s.first
    out.add(4, "input:")
    if s.format == "native":
        _native_keys(out, table.header)
        _missing_values_key(out, s)
        return
    ext = table.path.suffix.lower() or ".csv"
    out.add(6, f"format: {s.format}")
    if s.join:
        names = [t.path.name for t in s.logs]
        why = f"the files holding {s.join[0]!r}; their partners are joined (join: below)"
        out.add(6, f"pattern: {q(main_pattern(s.join[0], names, ext))}", why)
    else:
        others = [t.path.name for t in s.tables if t.path.suffix.lower() == ext and t not in s.logs]
        others = sorted(set(others) - {t.path.name for t in s.logs})
        if others:
            shown = ", ".join(others[:3]) + (", ..." if len(others) > 3 else "")
            why = (
                f"CHECK: it also matches {len(others)} file(s) of another layout ({shown}), which this "
                "block does not read: move them to a folder of their own and run rafi init there"
            )
            out.add(6, f"pattern: {q('*' + ext)}", why)
        else:
            out.add(6, f"pattern: {q('*' + ext)}")
    if s.format == "xlsx":
        _sheet_key(out, s)
    else:
        _text_keys(out, table.layout)
    _header_keys(out, table.headerless, table.layout)
    footers = footer_counts(s)
    if len(footers) > 1:
        why = (
            f"CHECK: the logs end in {' or '.join(map(str, footers))} summary rows; one count for every file"
        )
        out.add(6, f"footer_rows: {footers[-1]}", why)
    elif footers[0]:
        out.add(
            6, f"footer_rows: {footers[0]}", "summary rows at the end of each log (Mean, Max, ...): dropped"
        )
    _missing_values_key(out, s)
    _column_keys(out, s)
    _time_keys(out, s, period)
    if s.speed is None:
        _speed_keys(out, s)
    _displacement_keys(out, s)
    if s.join:
        _join_keys(out, s)
    _temperature_unit(out, s)


def _missing_values_key(out: _Lines, s: Survey) -> None:
    """input.missing_values, the markers found in the numeric columns (indent 6)."""
    if s.missing_values:
        markers = ", ".join(q(text) for text, _ in s.missing_values.most_common())
        why = "cells without a value in numeric columns: " + markers_text(s.missing_values)
        out.add(6, f"missing_values: [{markers}]", why)


def _native_keys(out: _Lines, header: list[str]) -> None:
    """format: native, and the sensors where they are not the paper's rig's (indent 6)."""
    sensors = header[2 : header.index("disp_um")]
    out.add(6, "format: native", "the project's own layout: time, speed_rpm, the sensors, disp_um")
    if tuple(sensors) != DEFAULT_SENSORS:
        why = f"{len(sensors)} temperature columns of the header"
        out.add(6, f"sensors: [{', '.join(sensors)}]", why)


def _header_keys(out: _Lines, headerless: bool, lay: dict) -> None:
    """header_row and skip_rows (indent 6)."""
    if headerless:
        out.add(6, "header_row: none", "no header row: the columns are given by letter")
        if lay.get("skip_rows"):
            out.add(6, f"skip_rows: {lay['skip_rows']}", "lines above the first row of numbers")
        out.note(6, "CHECK: no header row: each column's role is from its content alone; check the letters")
        return
    out.add(6, f"header_row: {lay['header_row']}")
    if lay.get("skip_rows"):
        out.add(6, f"skip_rows: {lay['skip_rows']}", "label rows (units) after the header")


def _column_keys(out: _Lines, s: Survey) -> None:
    """columns: the time, speed and sensor columns found (indent 6, the columns at 8)."""
    out.add(6, "columns:")
    if s.time is not None:
        out.add(8, f"time: {q(s.time.header)}")
    if s.speed is not None:
        out.add(8, f"speed_rpm: {q(s.speed.header)}")
    for name, header in s.sensors.items():
        out.add(8, f"{name}: {q(header)}")
    if not s.sensors:
        out.note(8, "CHECK: no temperature column found; map your sensors here (name: header)")


def _text_keys(out: _Lines, lay: dict) -> None:
    """delimiter, decimal, encoding of a text file where they are not the defaults (indent 6)."""
    delim = "tab" if lay["delimiter"] == "\t" else lay["delimiter"]
    if delim != ",":
        out.add(6, f"delimiter: {q(delim)}")
    if lay["decimal"] != ".":
        out.add(6, f"decimal: {q(lay['decimal'])}")
    if lay["encoding"] != "utf-8":
        out.add(6, f"encoding: {lay['encoding']}")


def _sheet_key(out: _Lines, s: Survey) -> None:
    """input.sheet: the sheet, or a pattern when several sheets share the layout (indent 6)."""
    table = s.first
    sheets = ", ".join(
        f"{x.name} ({x.kind}{f', {x.rows} rows' if x.kind == 'data' else ''})" for x in table.sheets[:6]
    ) + (f", ... ({len(table.sheets)} sheets)" if len(table.sheets) > 6 else "")
    group = table.sheet_group
    if len(group) > 1 and s.sheet_glob is not None:
        others = [x.name for x in table.sheets if x.name not in group]
        but = f"; not {', '.join(others)}" if others else ""
        out.note(6, f"{len(group)} sheets of one layout: each matching sheet is a log, named after it{but}")
        out.add(6, f"sheet: {q(s.sheet_glob)}", f"sheets: {sheets}")
    elif len(group) > 1:
        out.add(6, f"sheet: {q(table.layout['sheet'])}", "CHECK: a pattern for the sheets of this layout?")
        out.note(6, f"sheets of this layout: {', '.join(group)}")
    else:
        out.add(6, f"sheet: {q(table.layout['sheet'])}", f"sheets: {sheets}")


def _join_keys(out: _Lines, s: Survey) -> None:
    """input.join: the partner file of every log (indent 6)."""
    partner, main = s.partner, s.first
    example = f"{main.path.name} + {main.path.name.replace(*s.join)}"
    out.add(6, "join:", "temperatures and displacement in two files")
    out.add(8, f"replace: [{q(s.join[0])}, {q(s.join[1])}]", example)
    if s.join_by == "time":
        out.add(8, "by: time", "each row takes the partner's row nearest its time")
    else:
        out.add(8, "by: row", "CHECK: no time column in both files: row k takes the partner's row k")
    own = {}
    if partner.format != main.format:
        own["format"] = partner.format
    if partner.format == "csv" and main.format == "csv":
        own.update(
            {k: partner.layout[k] for k in ("delimiter", "decimal") if partner.layout[k] != main.layout[k]}
        )
    if partner.layout.get("header_row") != main.layout.get("header_row"):
        own["header_row"] = "none" if partner.headerless else partner.layout["header_row"]
    time = next((g for g in s.partner_guesses if g.role == "time"), None)
    if s.join_by == "time" and time is not None and time.header != s.time.header:
        own["columns"] = f"{{time: {q(time.header)}, disp_um: {q(s.probes[0].header)}}}"
    if own:
        out.add(8, "input:", f"{partner.path.name}'s own layout")
        for key, value in own.items():
            out.add(10, f"{key}: {value if key in ('columns', 'header_row') else q(value)}")


def _speed_keys(out: _Lines, s: Survey) -> None:
    out.add(6, "speed:")
    if s.speed_by_file:
        out.add(8, "constant_rpm_by_file:", "no speed column: the speed of each file, from its name")
        for glob, rpm in s.speed_by_file.items():
            out.add(10, f"{q(glob)}: {_num(rpm)}")
    else:
        out.add(8, "constant_rpm: 3000", "CHECK: no speed column; the speed of every file", off=True)


def config_block(s: Survey, *, period_s: float | None = None) -> str:
    """The machine's entry as commented YAML text, indented to sit under ``machines:``.

    Parameters
    ----------
    s : Survey
        What ``rafi init`` found.
    period_s : float, optional
        The sample period the user gave (``--period-s``): used where the file has no clock.

    Returns
    -------
    str
        Lines starting ``  <machine>:``; loads (under ``machines:``) as the machine's entry.
    """
    period = period_s if period_s is not None else (s.period_s if s.regular_share >= 0.9 else None)
    out = _Lines()
    names = list(dict.fromkeys(t.path.name for t in s.tables))
    files = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
    out.note(2, f"proposed by rafi init from {len(names)} file(s): {files}")
    out.note(2, "lines marked CHECK need your decision (commented-out keys keep their defaults)")
    out.add(2, f"{s.machine}:")
    _method_keys(out, s, period)
    _input_keys(out, s, period)
    return out.text()


def parse_block(text: str, machine: str) -> dict:
    """The machine's entry from :func:`config_block`'s text (raises if it does not load as one)."""
    loaded = yaml.safe_load("machines:\n" + text)
    if not isinstance(loaded, dict) or machine not in (loaded.get("machines") or {}):
        raise SettingsError(f"the proposed block for {machine!r} does not load as its machines: entry")
    return loaded["machines"][machine]


_TOP_KEY = re.compile(r"^[^\s#][^:]*:")


def add_machine(config_text: str, block: str, machine: str) -> tuple[str, dict]:
    """``config_text`` with ``block`` added under ``machines:``, and the config it loads to.

    The block goes at the end of the ``machines:`` mapping (a ``machines: {}`` or a missing
    key becomes a mapping holding it). The result is checked: it loads, the machine's entry is
    the block's, :func:`rafi.settings.validate_config` and
    :func:`rafi.settings.machine_settings` accept it.

    Raises
    ------
    SettingsError
        The machine is already under ``machines:`` (one line naming it), or the result is not
        a valid config (the message names the key).
    """
    try:
        config = yaml.safe_load(config_text) or {}
    except yaml.YAMLError as exc:
        raise SettingsError(f"config.yaml: not valid YAML ({exc}); nothing written") from None
    if not isinstance(config, dict):
        raise SettingsError("config.yaml: expected a mapping of settings; nothing written")
    if machine in (config.get("machines") or {}):
        raise SettingsError(
            f"machine {machine!r} is already under machines: in config.yaml; nothing written "
            "(edit its entry, or remove it first to have rafi init propose a new one)"
        )
    lines = config_text.splitlines()
    at = next((k for k, ln in enumerate(lines) if re.match(r"^machines\s*:", ln)), None)
    if at is None:
        head = config_text.rstrip("\n")
        new = (head + "\n\n" if head else "") + "machines:\n" + block
    else:
        if re.match(r"^machines\s*:\s*(\{\s*\}|null|~)?\s*(#.*)?$", lines[at]) and "{" in lines[at]:
            lines[at] = "machines:"
        end = next((k for k in range(at + 1, len(lines)) if _TOP_KEY.match(lines[k])), len(lines))
        while end > at + 1 and not lines[end - 1].strip():
            end -= 1
        new = "\n".join(lines[:end] + [""] + block.rstrip("\n").split("\n") + lines[end:]) + "\n"
    try:
        loaded = yaml.safe_load(new)
    except yaml.YAMLError:
        loaded = {}
    if (loaded.get("machines") or {}).get(machine) != parse_block(block, machine):
        raise SettingsError(
            f"config.yaml: the block for {machine!r} cannot be added under machines: (a mapping in flow "
            "style?); nothing written - add the printed block by hand"
        )
    try:
        validate_config(loaded)
        machine_settings(loaded, machine)
    except RafiUserError as exc:
        raise SettingsError(
            f"machine {machine!r}: the proposed block is not a valid config yet ({exc}); nothing written - "
            "fill in its CHECK lines (a period: --period-s) and add it by hand"
        ) from None
    return new, loaded
