"""``rafi init``: read a new machine's logs, say what they hold, propose its config block.

``rafi init --machine M PATH...`` reads the files (or every csv/xlsx file of a folder), prints
what it found to stderr (each column's role, unit, confidence and why; the sample period; one
continuous log or separate runs; the speed steps; what you must decide) and the proposed
``machines: M:`` block to stdout. ``--write`` adds the block to config.yaml instead (never over
an existing entry of M), after checking the whole config. ``--preview`` reads an already
configured machine's raw files as the pipeline would and prints the runs it finds
(:mod:`rafi.ops.init_preview`). ``docs/init.md`` explains it.
"""

from __future__ import annotations

import sys
from pathlib import Path

#: ``rafi init --help``.
CLI_DESCRIPTION = """Read a new machine's logs and propose its config block.

  rafi init --machine M raw/M/                 print what was found and the block for M
  rafi init --machine M raw/M/*.xlsx --write   add the block to config.yaml (checked first)
  rafi init --preview --machine M              the runs the pipeline will find, before any fit

Each column gets a role (time, speed, temperature, displacement) from its content and header,
with a unit, a confidence and why. What the data cannot tell (a unit, the probe's sign, a
period, the start date) is said and written commented out with '# CHECK:' (docs/init.md).
"""

#: File name endings read from a folder given as PATH.
LOG_SUFFIXES = (".csv", ".txt", ".tsv", ".xlsx")


def add_arguments(parser) -> None:
    """``rafi init`` options."""
    parser.add_argument("paths", nargs="*", metavar="PATH", help="log files, or folders of them")
    parser.add_argument("--machine", required=True, help="the machine's name (its folder under raw/)")
    parser.add_argument("--config", default="config.yaml", help="config file (default: config.yaml)")
    parser.add_argument("--write", action="store_true", help="add the block to the config file")
    parser.add_argument(
        "--preview", action="store_true", help="print the runs of an already configured machine"
    )
    parser.add_argument(
        "--period-s", type=float, default=None, help="seconds between two rows (files without a time column)"
    )


def log_paths(paths: list[str]) -> list[Path]:
    """The files named, and the log files of each folder named (sorted, hidden ones left out)."""
    from rafi.errors import SettingsError

    out: list[Path] = []
    for text in paths:
        p = Path(text)
        if p.is_dir():
            found = sorted(
                f
                for f in p.iterdir()
                if f.suffix.lower() in LOG_SUFFIXES and not f.name.startswith((".", "~$"))
            )
            if not found:
                raise SettingsError(f"{text}: no {', '.join(LOG_SUFFIXES)} file in this folder")
            out += found
        elif p.exists():
            out.append(p)
        else:
            raise SettingsError(f"{text}: no such file or folder")
    if not out:
        raise SettingsError("no PATH given: name the machine's log files or their folder")
    return out


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def _table(rows: list[list[str]]) -> list[str]:
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]) - 1)]
    return ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[-1] for r in rows]


def _period_lines(s) -> list[str]:
    """The sample period found, given (``--period-s``) or left to the user, as a line."""
    if s.time is None and s.given_period_s is not None:
        return [f"sample period: {s.given_period_s:g} s, given with --period-s (no time column)"]
    if s.time is None:
        return ["sample period: no time column; give it (--period-s), it is left for you in the block"]
    if s.period_s is not None:
        return [f"sample period: {s.period_s:g} s (median step, {s.regular_share:.0%} of steps regular)"]
    return []


def findings(s) -> list[str]:
    """What ``rafi init`` found, as the lines it prints (``s``: a :class:`rafi.ops.init_survey.Survey`)."""
    out = [f"rafi init: machine {s.machine}, {len({t.path for t in s.tables})} file(s)"]
    shown = set()
    for t in s.tables:
        if t.path in shown:
            continue
        shown.add(t.path)
        where = f", sheet {t.layout['sheet']!r}" if t.format == "xlsx" else ""
        header = (
            "no header row (columns by letter)" if t.headerless else f"header row {t.layout['header_row']}"
        )
        out.append(f"  {t.path.name}: {t.format}{where}, {header}, {t.n_rows} rows")
        for sh in t.sheets:
            out.append(f"    sheet {sh.name!r}: {sh.kind}, {sh.rows} rows, {sh.columns} columns")
    if len(s.first.sheet_group) > 1:
        glob = f"input.sheet: {s.sheet_glob!r}" if s.sheet_glob else "no pattern matches only them"
        out.append(f"  {len(s.first.sheet_group)} sheets share one layout, each a log ({glob})")
    out += [f"  note: {n}" for n in s.notes]
    rows = [["col", "header", "role", "unit", "confidence", "why"]]
    rows += [[g.letter, g.header, g.role, g.unit or "-", g.confidence, g.why] for g in s.guesses]
    out += [f"columns (of {s.first.name}):", *_table(rows)]
    if s.join:
        rows = [["col", "header", "role", "unit", "confidence", "why"]]
        rows += [[g.letter, g.header, g.role, g.unit or "-", g.confidence, g.why] for g in s.partner_guesses]
        out += [f"columns of its partner {s.partner.path.name}:", *_table(rows)]
    out += _period_lines(s)
    if s.kind == "continuous":
        out.append(f"layout: one continuous log ({s.kind_why}): proposing reference: {{rule: log_start}}")
    else:
        out.append(f"layout: separate runs ({s.kind_why})")
    for shape in s.shapes:
        if shape.steps:
            out.append(f"speed steps of {shape.name}:")
            for st in shape.steps:
                level = (
                    f"{st.low_rpm:g}-{st.high_rpm:g} r/min"
                    if st.kind == "varying"
                    else f"{st.level_rpm:g} r/min"
                )
                out.append(f"  {_hours(st.start_s):>8} +{_hours(st.duration_s):>8}  {st.kind:<8} {level}")
    if s.training.get("speeds"):
        speeds = ", ".join(f"{x:g}" for x in s.training["speeds"])
        out.append(f"training speeds proposed: {speeds} r/min ({s.training['why']})")
    if s.min_constant:
        out.append(f"runs.min_constant_s proposed: {s.min_constant[0]:g} ({s.min_constant[1]})")
    if s.probes:
        out.append("displacement candidates: " + ", ".join(f"{g.letter} {g.header!r}" for g in s.probes))
    out.append(f"CHECK ({len(s.checks)}): what the data cannot tell you")
    out += [f"  - {c}" for c in s.checks]
    return out


def run(args) -> int:
    from rafi.errors import SettingsError

    if args.preview:
        from rafi.ops.init_preview import preview

        print("\n".join(preview(args.config, args.machine)))
        return 0
    from rafi.ops.init_config import add_machine, config_block, parse_block
    from rafi.ops.init_survey import survey
    from rafi.readers.infer_files import read_unknown_logs

    paths = log_paths(args.paths)
    s = survey(args.machine, [t for p in paths for t in read_unknown_logs(p)], period_s=args.period_s)
    block = config_block(s, period_s=args.period_s)
    parse_block(block, args.machine)
    if not args.write:
        print("\n".join(findings(s)), file=sys.stderr)
        print("machines:\n" + block, end="")
        return 0
    print("\n".join(findings(s)))
    config = Path(args.config)
    try:
        text = config.read_text(encoding="utf-8") if config.exists() else ""
    except OSError as exc:
        raise SettingsError(f"{config}: cannot read the config ({exc})") from None
    new, _ = add_machine(text, block, args.machine)
    import rafi.artefact

    rafi.artefact.write_text_atomic(config, new)
    print(f"wrote machine {args.machine} to {config} ({len(s.checks)} CHECK line(s) to look at)")
    return 0
