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


def cell(text, cls: str = "") -> dict:
    """A table cell with a CSS class (``pass``, ``fail``, ...)."""
    return {"text": text, "cls": cls}


def table(headers, rows, *, cls: str = "", widths=None, caption: str = "") -> dict:
    """A table for the template: headers (str), rows of cells (str or ``cell()`` dicts)."""
    norm = [[c if isinstance(c, dict) else cell(c) for c in r] for r in rows]
    return {"headers": list(headers), "rows": norm, "cls": cls, "widths": widths or [], "caption": caption}


def term_text(term: str, variables: dict) -> Markup:
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


def equation_text(coefs, terms, variables: dict) -> Markup:
    """``dz = 0.12 + 1.23·x₁ − ...`` with 4 significant digits per coefficient."""
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
    return Markup(f'<span class="eq">{escape(text)}</span>')


def run_label(run_id) -> Markup:
    """A run id that may wrap: ``<wbr>`` after ``_`` / ``-`` and before ``#``
    (``thermal_log_2026-10-14#3`` breaks as ``thermal_log_`` / ``2026-10-14`` / ``#3``)."""
    text = str(escape(str(run_id)))
    text = text.replace("_", "_<wbr>").replace("#", "<wbr>#")
    return Markup(text)


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
