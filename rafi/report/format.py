"""Number and text formatting of the qualification report (the template only prints strings).

Every number the report shows goes through one of these: a true minus sign, no-break spaces
as thousands separators and before units, an en dash for a missing value.
"""

from __future__ import annotations

import math
import re

from markupsafe import Markup, escape

from rafi.settings import truthy  # noqa: F401 (the report reads flags with it)

NBSP = "\u00a0"
MINUS = "\u2212"
DASH = "\u2013"


def isnum(x) -> bool:
    """A finite number (not a bool, not ``None``, not NaN or infinite)."""
    try:
        return x is not None and not isinstance(x, bool) and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def fmt_num(x, digits: int = 2, unit: str = "", *, signed: bool = False) -> str:
    """Fixed-point number with a true minus sign and an optional unit; ``-`` for missing."""
    if not isnum(x):
        return DASH
    v = float(x)
    if round(v, digits) == 0:
        v = 0.0
    s = f"{v:+,.{digits}f}" if signed else f"{v:,.{digits}f}"
    s = s.replace(",", NBSP).replace("-", MINUS)
    return f"{s}{NBSP}{unit}" if unit else s


def fmt_sig(x, sig: int = 3, unit: str = "") -> str:
    """Significant digits; scientific notation (a x 10^b) outside 1e-3..1e6."""
    if not isnum(x):
        return DASH
    v = float(x)
    if v == 0:
        s = "0"
    elif 1e-3 <= abs(v) < 1e5:
        digits = max(sig - 1 - int(math.floor(math.log10(abs(v)))), 0)
        s = f"{v:,.{digits}f}".replace(",", NBSP)
    else:
        mant, exp = f"{v:.{sig - 1}e}".split("e")
        s = f"{mant}\u00d710{_superscript(int(exp))}"
    s = s.replace("-", MINUS)
    return f"{s}{NBSP}{unit}" if unit else s


_SUP = str.maketrans("0123456789-", "\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b")
_SUB = str.maketrans("0123456789", "\u2080\u2081\u2082\u2083\u2084\u2085\u2086\u2087\u2088\u2089")


def _superscript(n: int) -> str:
    """An integer in superscript digits: ``-6`` -> ``⁻⁶``."""
    return str(n).translate(_SUP)


def subscript(text) -> str:
    """Digits as subscripts: ``"12"`` -> ``"₁₂"``."""
    return str(text).translate(_SUB)


def fmt_p(p) -> str:
    """p-value: 3 significant digits, ``< 0.001`` below."""
    if not isnum(p):
        return DASH
    return "<" + NBSP + "0.001" if float(p) < 1e-3 else f"{float(p):.3f}"


def fmt_speed(rpm) -> str:
    """A spindle speed: ``3 000 r/min``."""
    return fmt_num(rpm, 0, "r/min")


def fmt_speed_range(lo, hi) -> str:
    """A speed range: ``598–4 803 r/min``; one speed when both ends print the same
    (``0 r/min``, never ``0–0 r/min``); an en dash when neither is a number."""
    if not isnum(lo) or not isnum(hi):
        return fmt_speed(hi if isnum(hi) else lo)
    a, b = fmt_num(min(float(lo), float(hi)), 0), fmt_num(max(float(lo), float(hi)), 0)
    return fmt_speed(float(hi)) if a == b else f"{a}{DASH}{b}{NBSP}r/min"


#: Without a ``kind``, a run whose speed ends lie farther apart than this (r/min) is shown as a range.
VARYING_SPREAD_RPM = 100.0


def fmt_run_speed(run) -> str:
    """A run's speed as every section of the report shows it, from its row of ``runs.csv``.

    Parameters
    ----------
    run : mapping
        ``kind``, ``speed_rpm``, ``speed_min_rpm`` and ``speed_max_rpm`` of ``runs.csv``
        (:mod:`rafi.method.runs`: the rest before start is left out of the three speeds).

    Returns
    -------
    str
        A varying run its range (``3 119–7 123 r/min``, :func:`fmt_speed_range`), any other run
        its speed (``3 500 r/min``). Without a ``kind`` a run is varying where its ends lie more
        than :data:`VARYING_SPREAD_RPM` apart; without its ends, its ``speed_rpm``.
    """
    get = run.get if hasattr(run, "get") else (lambda k, d=None: getattr(run, k, d))
    lo, hi, kind = get("speed_min_rpm"), get("speed_max_rpm"), get("kind")
    kind = "" if kind is None or (isinstance(kind, float) and math.isnan(kind)) else str(kind)
    if isnum(lo) and isnum(hi):
        varying = kind == "varying" if kind else float(hi) - float(lo) > VARYING_SPREAD_RPM
        if varying:
            return fmt_speed_range(lo, hi)
    return fmt_speed(get("speed_rpm"))


def run_speeds(runs) -> dict:
    """Run id -> :func:`fmt_run_speed` of every run of ``runs.csv`` (``{}`` without it): the
    speed a section shows beside a run it reads from another table."""
    if runs is None or not len(runs) or "run_id" not in runs:
        return {}
    return {str(r["run_id"]): fmt_run_speed(r) for r in runs.to_dict("records")}


_UM = re.compile(r"(?<=[\d\s(])um\b")


def micro(text) -> str:
    """``um`` after a number written as ``µm`` (text from tables and JSON written by other
    parts of rafi), so the report spells the unit one way."""
    return _UM.sub("µm", str(text))


def fmt_duration(seconds) -> str:
    """``4.00 h`` for runs, ``45 min`` under an hour."""
    if not isnum(seconds):
        return DASH
    s = float(seconds)
    return fmt_num(s / 3600.0, 2, "h") if s >= 3600 else fmt_num(s / 60.0, 0, "min")


def term_text(term: str, variables: dict | None = None) -> Markup:
    """``x1*x2^2`` -> ``x₁·x₂²`` (HTML-safe)."""
    if term == "1":
        return Markup("")
    parts = []
    for factor in term.replace(" ", "").split("*"):
        name, _, power = factor.partition("^")
        idx = name[1:]
        s = "x" + subscript(idx)
        if power:
            s += power.translate(_SUP)
        parts.append(s)
    return Markup("\u00b7".join(str(escape(p)) for p in parts))


def equation_text(coefs, terms, variables: dict | None = None) -> Markup:
    """``dz = 0.12 + 1.23·x₁ − ...`` with 4 significant digits per coefficient (HTML-safe; the
    template sets it in ``<span class="eq">``)."""
    pieces = []
    for _k, (b, t) in enumerate(zip(coefs, terms)):
        if not isnum(b):
            continue
        mag = fmt_sig(abs(float(b)), 4)
        tt = term_text(t, variables)
        body = f"{mag}{NBSP}{tt}" if str(tt) else mag
        sign = MINUS if float(b) < 0 else "+"
        if not pieces:
            pieces.append((MINUS if float(b) < 0 else "") + body)
        else:
            pieces.append(f" {sign} {body}")
    text = "dz = " + "".join(pieces) if pieces else "dz = 0"
    return Markup(escape(text))


def run_label(run_id) -> Markup:
    """A run id that may wrap: ``<wbr>`` after ``_`` / ``-`` and before ``#``
    (``thermal_log_2026-10-14#3`` breaks as ``thermal_log_`` / ``2026-10-14`` / ``#3``)."""
    text = str(escape(str(run_id)))
    text = text.replace("_", "_<wbr>").replace("#", "<wbr>#")
    return Markup(text)


def identifier(name) -> Markup:
    """A name of the code (a model, a kind, a setting) that may wrap after each ``_`` and nowhere
    else: ``prior_shared_ridge`` breaks as ``prior_`` / ``shared_`` / ``ridge``, never with a
    hyphen inside a word (``<wbr>`` after ``_``, in ``<span class="id">``: the template's CSS
    lets no other break into it)."""
    return Markup('<span class="id">' + str(escape(str(name))).replace("_", "_<wbr>") + "</span>")


def short_id(value, n: int = 12) -> str:
    """The first ``n`` characters of a hash or model id; an en dash for none."""
    return str(value)[:n] if isinstance(value, str) and value else DASH


def speed_key(x):
    """A speed as a dict key: ``3000.0`` -> ``3000`` (non-numbers unchanged)."""
    try:
        v = float(x)
        return int(v) if v.is_integer() else v
    except (TypeError, ValueError):
        return x


def fmt_value(value, fmt: str | None = None, digits: int = 2, unit: str = "", signed: bool = False):
    """``value`` as one of the report's formats.

    Parameters
    ----------
    value
        A number, a text or ``None``.
    fmt : str, optional
        ``num`` (:func:`fmt_num` with ``digits``, ``unit``, ``signed``), ``sig`` (:func:`fmt_sig`,
        ``digits`` significant), ``p`` (:func:`fmt_p`), ``speed``, ``duration``, ``run``
        (:func:`run_label`), ``short_id``, ``micro``; ``None``: the value as it is, an en dash for
        ``None``.

    Returns
    -------
    str or Markup
    """
    if fmt is None:
        return DASH if value is None else value
    if fmt == "num":
        return fmt_num(value, digits, unit, signed=signed)
    if fmt == "sig":
        return fmt_sig(value, digits, unit)
    simple = {
        "p": fmt_p,
        "speed": fmt_speed,
        "duration": fmt_duration,
        "run": run_label,
        "short_id": short_id,
        "micro": micro,
    }
    if fmt not in simple:
        raise ValueError(f"unknown format {fmt!r}")
    return simple[fmt](value)


def fmt_column(value, column: dict):
    """``value`` formatted as ``column`` says (the column spec of the templates' ``frame_table``:
    ``fmt``, ``digits``, ``unit``, ``signed``; see :func:`fmt_value`)."""
    return fmt_value(
        value,
        column.get("fmt"),
        column.get("digits", 2),
        column.get("unit", ""),
        column.get("signed", False),
    )


def records(frame, columns: dict | None = None) -> list[dict]:
    """The rows of a small frame as plain dicts (what the templates' ``frame_table`` shows).

    Parameters
    ----------
    frame : DataFrame
    columns : dict, optional
        ``new name -> column`` to keep and rename (default: every column as it is).

    Returns
    -------
    list of dict
        One dict per row; NaN and NA become ``None``, NumPy scalars Python numbers.
    """
    if columns is not None:
        frame = frame[list(columns.values())].set_axis(list(columns), axis=1)
    out = []
    for row in frame.to_dict("records"):
        out.append({k: plain(v) for k, v in row.items()})
    return out


def plain(value):
    """A frame's cell as a plain Python value (``None`` for NaN)."""
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def css_string(text) -> Markup:
    """``text`` for the inside of a double-quoted CSS string (a backslash, a quote and a line
    break escaped), marked safe: HTML escaping does not apply inside CSS."""
    out = str(text).replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\a ")
    return Markup(out)


#: The filters of the report's templates (:func:`rafi.report.render._environment`).
FILTERS = {
    "num": fmt_num,
    "sig": fmt_sig,
    "p": fmt_p,
    "speed": fmt_speed,
    "speed_range": fmt_speed_range,
    "run_speed": fmt_run_speed,
    "duration": fmt_duration,
    "run": run_label,
    "ident": identifier,
    "short_id": short_id,
    "micro": micro,
    "subscript": subscript,
    "equation": equation_text,
    "term": term_text,
    "column": fmt_column,
    "css_string": css_string,
}
