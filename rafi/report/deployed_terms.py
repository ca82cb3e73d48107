"""The model offered to the machine written out: what it reads, its equation and every
coefficient exactly as its artefact stores it (section "The model offered to the machine",
:mod:`rafi.report.deployed_section`).

Everything is read from the artefact (``rafi.model/1``): the ridge kinds' feature names
(:func:`parse_feature`) and coefficients in the artefact's order, RAFI's terms and per-speed
coefficients. A coefficient is written as the shortest decimal that reads back to the same
float (:func:`exact`), so the written table is the model ``rafi.family`` and
``rafi.deploy.compensator`` evaluate (``tests/test_report_deployed.py`` re-evaluates it).
"""

from __future__ import annotations

import re

from markupsafe import Markup, escape

from rafi.report.format import fmt_num

UM = "\u00b5m"
TAU = "\u03c4"


#: At most this many columns of exact coefficients side by side (each needs ~30 mm).
MAX_COEF_COLUMNS = 4


def column_groups(n: int) -> list[range]:
    """``range(n)`` cut into as few balanced groups of at most :data:`MAX_COEF_COLUMNS` as needed."""
    k = max(1, -(-n // MAX_COEF_COLUMNS))
    size = -(-n // k) if n else 0
    return [range(i, min(i + size, n)) for i in range(0, n, size)] if n else []


def exact(x) -> str:
    """A coefficient exactly as stored: the shortest decimal that reads back to the same float."""
    return repr(float(x))


# ---------------------------------------------------------------------------- ridge kinds
_RISE = re.compile(r"^d([A-Za-z][A-Za-z0-9_]*)@([0-9.eE+-]+)s(\*n_krpm)?$")
_POWER = re.compile(r"^L([0-9.eE+-]+)s\(n\^([0-9.eE+-]+)\)$")
_DRAW = re.compile(r"^L([0-9.eE+-]+)s\(n2_krpm2\)$")


def parse_feature(name: str, powers=()) -> dict:
    """What a ridge-kind feature name of the artefact stands for.

    ``dT6@0s`` (rise), ``dT6@120s`` (filtered), ``dT6@0s*n_krpm`` (rise times speed),
    ``n_krpm`` / ``n2_krpm2`` (speed terms; for ``grey_box`` ``n2_krpm2`` is the unlagged
    draw-in), ``L60s(n^1.667)`` (filtered speed power), ``L10s(n2_krpm2)`` (lagged draw-in).

    Parameters
    ----------
    name : str
        A name of the artefact's ``features``.
    powers : sequence of float
        The artefact's ``hyperparameters.speed_powers``. A name holds the power rounded to 4
        significant digits (``n^1.667`` for 5/3); the power returned is the one of ``powers``
        that rounds to it, i.e. the one the model computes with.

    Returns
    -------
    dict
        ``type`` (``rise``, ``rise_speed``, ``speed``, ``speed2``, ``power``, ``draw_in``) and
        ``sensor``, ``tau_s``, ``power`` where they apply.
    """
    m = _RISE.match(name)
    if m:
        return {
            "type": "rise_speed" if m.group(3) else "rise",
            "sensor": m.group(1),
            "tau_s": float(m.group(2)),
        }
    m = _POWER.match(name)
    if m:
        power = float(m.group(2))
        exact_power = [float(q) for q in powers if f"{float(q):.4g}" == m.group(2)]
        if powers and len(exact_power) != 1:
            raise ValueError(
                f"feature {name!r}: no single speed power of {list(powers)} is written {m.group(2)}"
            )
        return {
            "type": "power",
            "tau_s": float(m.group(1)),
            "power": exact_power[0] if exact_power else power,
        }
    m = _DRAW.match(name)
    if m:
        return {"type": "draw_in", "tau_s": float(m.group(1))}
    if name == "n_krpm":
        return {"type": "speed"}
    if name == "n2_krpm2":
        return {"type": "speed2"}
    raise ValueError(f"feature {name!r} is not one the report can write out")


def _powers(art: dict) -> list[float]:
    """The speed powers a ``grey_box`` artefact computes with (none for the other kinds)."""
    return [float(q) for q in (art.get("hyperparameters") or {}).get("speed_powers") or []]


def _power_text(p: float) -> str:
    if p == 0:
        return "running (1 if |n| > the speed tolerance, else 0)"  # P0: the equation gives the tolerance
    short = f"{p:g}"
    frac = "5/3" if p == 5.0 / 3.0 else short if float(short) == p else repr(float(p))  # the exponent used
    return f"(n / 10\u00a0000 r/min)^{frac}"


def ridge_tables(art: dict) -> tuple[list, list]:
    """The coefficient tables of a ridge kind and the flat list of ``(feature, exact text)``
    in the artefact's order (what the test evaluates).

    Parameters
    ----------
    art : dict
        The artefact (``features``, ``coefficients``, ``regressor_ranges``, ...).

    Returns
    -------
    blocks : list of dict
        One per table, as ``templates/sections/deployed.html.j2`` sets it: ``kind``
        (``temperature``: a row per sensor, a column per (``type``, ``tau_s``), ``range`` the
        trained rise; ``heat``: a row per speed ``power``, a column per ``tau_s``; ``speed``:
        a row per speed or draw-in term, ``type``, ``tau_s``, ``coef``), ``part`` (``[k, of]``:
        at most :data:`MAX_COEF_COLUMNS` coefficient columns per table), ``columns``, ``rows``
        (``coefs``: the exact text of each column's coefficient, ``None`` where the term is not
        in the model) and ``widths``.
    terms : list of tuple
        ``(feature, exact text)``.
    """
    names, coef = list(art["features"]), [float(c) for c in art["coefficients"]]
    if len(names) != len(coef):
        raise ValueError(f"artefact: {len(names)} features but {len(coef)} coefficients")
    terms = [(n, exact(c)) for n, c in zip(names, coef)]
    parsed = [parse_feature(n, _powers(art)) for n in names]
    ranges = art.get("regressor_ranges") or {}
    out = []
    # rises (and rises x speed): one row per sensor, one column per filter constant
    sensors = list(dict.fromkeys(p["sensor"] for p in parsed if p["type"] in ("rise", "rise_speed")))
    cols = list(dict.fromkeys((p["type"], p["tau_s"]) for p in parsed if p["type"] in ("rise", "rise_speed")))
    if sensors:
        at = {(p["sensor"], p["type"], p["tau_s"]): c for p, (_, c) in zip(parsed, terms) if "sensor" in p}
        groups = column_groups(len(cols))
        for g, idx in enumerate(groups):
            part = [cols[i] for i in idx]
            rows = [
                {"sensor": s, "coefs": [at.get((s, typ, t)) for typ, t in part], "range": ranges.get(s)}
                for s in sensors
            ]
            w_first, w_last = 8, 13
            w = round((100 - w_first - w_last) / MAX_COEF_COLUMNS, 1)
            out.append(
                {
                    "kind": "temperature",
                    "part": [g + 1, len(groups)],
                    "columns": [{"type": typ, "tau_s": t} for typ, t in part],
                    "rows": rows,
                    "widths": [w_first] + [w] * len(part) + [w_last],
                }
            )
    # heat input: one row per power, one column per filter constant
    powers = list(dict.fromkeys(p["power"] for p in parsed if p["type"] == "power"))
    ptaus = list(dict.fromkeys(p["tau_s"] for p in parsed if p["type"] == "power"))
    if powers:
        at = {(p["power"], p["tau_s"]): c for p, (_, c) in zip(parsed, terms) if p["type"] == "power"}
        groups = column_groups(len(ptaus))
        for g, idx in enumerate(groups):
            part = [ptaus[i] for i in idx]
            w = round(76 / MAX_COEF_COLUMNS, 1)
            out.append(
                {
                    "kind": "heat",
                    "part": [g + 1, len(groups)],
                    "columns": [{"tau_s": t} for t in part],
                    "rows": [{"power": _power_text(q), "coefs": [at[(q, t)] for t in part]} for q in powers],
                    "widths": [24] + [w] * len(part),
                }
            )
    # speed and draw-in terms: one row each
    rows = [
        {"type": p["type"], "tau_s": p.get("tau_s"), "coef": c}
        for p, (_, c) in zip(parsed, terms)
        if p["type"] in ("speed", "speed2", "draw_in")
    ]
    if rows:
        out.append({"kind": "speed", "part": [1, 1], "columns": [], "rows": rows, "widths": []})
    return out, terms


def ridge_equation(art: dict) -> list[Markup]:
    """The model's formula, line by line (HTML), from the features the artefact holds."""
    parsed = [parse_feature(n, _powers(art)) for n in art["features"]]
    types = {p["type"] for p in parsed}
    tol = float((art.get("hyperparameters") or {}).get("speed_tolerance_rpm", 50.0))
    rise_taus = sorted({p["tau_s"] for p in parsed if p["type"] == "rise"})
    sum_t = "&sum;<sub>i</sub>" if rise_taus == [0.0] else "&sum;<sub>i</sub> &sum;<sub>&tau;</sub>"
    f_t = "dT<sub>i</sub>(t)" if rise_taus == [0.0] else "F<sub>&tau;</sub>T<sub>i</sub>(t)"
    b = "b<sub>i</sub>" if rise_taus == [0.0] else "b<sub>i,&tau;</sub>"
    parts = [f"{sum_t} {b}&middot;{f_t}"]
    if "rise_speed" in types:
        parts.append(f"{sum_t} g{b[1:]}&middot;{f_t}&middot;n(t)")
    if "speed" in types:
        parts.append("c<sub>1</sub>&middot;(n(t) &minus; n<sub>0</sub>)")
    if "speed2" in types:
        parts.append("c<sub>2</sub>&middot;(n(t)<sup>2</sup> &minus; n<sub>0</sub><sup>2</sup>)")
    if "power" in types:
        parts.append(
            "&sum;<sub>p</sub> &sum;<sub>&sigma;</sub> c<sub>p,&sigma;</sub>&middot;"
            "F<sub>&sigma;</sub>P<sub>p</sub>(t)"
        )
    if "draw_in" in types:
        parts.append("d&middot;(L<sub>&lambda;</sub>[n<sup>2</sup>](t) &minus; n<sub>0</sub><sup>2</sup>)")
    lines = [
        Markup(
            "dz(t) = " + " + ".join(parts) + "&nbsp;&nbsp;(&micro;m; no intercept: 0 at the reference state)"
        )
    ]
    if rise_taus != [0.0]:
        lines.append(
            Markup(
                "F<sub>&tau;</sub>T<sub>i</sub>(t) = L<sub>&tau;</sub>[T<sub>i</sub>](t) &minus; its median "
                "over the reference window; L<sub>0</sub>[T<sub>i</sub>] = T<sub>i</sub>, so "
                "F<sub>0</sub>T<sub>i</sub> = "
                "dT<sub>i</sub>, the rise"
            )
        )
    else:
        lines.append(
            Markup("dT<sub>i</sub>(t) = T<sub>i</sub>(t) &minus; its median over the reference window")
        )
    if "power" in types:
        lines.append(
            Markup(
                "F<sub>&sigma;</sub>P<sub>p</sub>(t) = L<sub>&sigma;</sub>[P<sub>p</sub>](t) &minus; its "
                "median over the reference window, with P<sub>0</sub> = 1 while the spindle runs (|n| &gt; "
                f"{fmt_num(tol, 0)} r/min; else 0) and P<sub>p</sub> = (n / 10&nbsp;000 r/min)<sup>p</sup>"
            )
        )
    if types & {"rise_speed", "speed", "speed2", "draw_in"}:
        lines.append(Markup("n in krpm (r/min / 1000); n<sub>0</sub> = the speed of the reference state"))
    where = ["b: the temperature terms below (one column per filter constant &tau;)"]
    if "rise_speed" in types:
        where.append("g: their &middot;&nbsp;n columns")
    if "power" in types:
        where.append("c<sub>p,&sigma;</sub>: the heat-input terms (one column per filter constant &sigma;)")
    if types & {"speed", "speed2", "draw_in"}:
        lag = [p["tau_s"] for p in parsed if p["type"] == "draw_in"]
        what = (
            "c<sub>1</sub>, c<sub>2</sub>, d"
            if "draw_in" in types and "speed" in types
            else ("d" if "draw_in" in types else "c<sub>1</sub>, c<sub>2</sub>")
        )
        where.append(what + ": the speed terms" + (f" (&lambda; = {fmt_num(lag[0], 0)} s)" if lag else ""))
    lines.append(Markup("Coefficients: " + "; ".join(where)))
    if any(p.get("tau_s", 0) > 0 for p in parsed):
        lines.append(
            Markup(
                "L<sub>&tau;</sub>: the causal first-order low-pass, sample by sample "
                "y[k] = y[k&minus;1] + (1 &minus; e<sup>&minus;(t[k] &minus; t[k&minus;1]) / &tau;</sup>)"
                "&middot;"
                "(x[k] &minus; y[k&minus;1]), run over the absolute input from the first sample of the log "
                "(settled there: y = x), through cool-downs and short gaps"
            )
        )
    return lines


def ridge_inputs(art: dict) -> list[tuple[str, Markup | str]]:
    """``(what, value)`` rows of what a ridge kind reads."""
    sel, hyper = art.get("selected") or {}, art.get("hyperparameters") or {}
    parsed = [parse_feature(n, _powers(art)) for n in art["features"]]
    ref = art.get("reference") or {}
    rows = [("temperature sensors", ", ".join(art.get("key_sensors") or []))]
    taus = [t for t in sel.get("taus_s", []) if t > 0]
    rows.append(
        (
            "temperature filters",
            "the rises as they are"
            + (
                f" and low-pass filtered with {TAU} = " + ", ".join(fmt_num(t, 0) for t in taus) + " s"
                if taus
                else ""
            ),
        )
    )
    uses_speed = any(p["type"] != "rise" for p in parsed)
    if uses_speed:
        what = []
        if any(p["type"] == "power" for p in parsed):
            st = sel.get("speed_taus_s") or []
            what.append("heat-input filters \u03c3 = " + ", ".join(fmt_num(t, 0) for t in st) + " s")
        if any(p["type"] == "draw_in" for p in parsed):
            what.append(
                f"draw-in n\u00b2 through a lag \u03bb = {fmt_num(sel.get('centrifugal_lag_s'), 0)} s"
            )
        if any(p["type"] in ("speed", "speed2") for p in parsed):
            what.append("n \u2212 n\u2080 and n\u00b2 \u2212 n\u2080\u00b2")
        if any(p["type"] == "rise_speed" for p in parsed):
            what.append("speed-dependent gains dT\u00b7n")
        rows.append(("spindle speed", "; ".join(what)))
    elif art.get("kind") == "temperature_ridge":
        rows.append(("spindle speed", "not read by the model (temperature_ridge has no speed input)"))
    else:
        rows.append(
            (
                "spindle speed",
                "not read by the model (no speed term: CV or the identifiability rule left them out)",
            )
        )
    rows.append(("displacement", "never an input (only the target of the fit)"))
    rule = ref.get("rule", "")
    rule_text = {
        "run_start": (
            "the median of the first {w} s of each run (reference.rule run_start: the controller "
            "captures it at the start of a job)"
        ),
        "log_start": "the median of the first {w} s of each log segment (reference.rule log_start: power-on)",
    }.get(rule, "reference.rule {rule}")
    rows.append(("reference state", rule_text.format(w=fmt_num(ref.get("window_s"), 0), rule=rule)))
    if uses_speed:
        srule = (art.get("speed_reference") or {}).get("rule", "")
        rows.append(
            (
                "reference speed n\u2080",
                "the median speed of the reference window"
                if srule == "run_start"
                else "0 r/min (the log starts at rest)",
            )
        )
    if any(p.get("tau_s", 0) > 0 for p in parsed):
        rows.append(
            (
                "filter restart",
                f"settled on the first sample of a log and after a gap longer than "
                f"{fmt_num(hyper.get('filter_restart_gap_s'), 0)} s",
            )
        )
    return rows


# ---------------------------------------------------------------------------- RAFI kinds
def rafi_tables(art: dict) -> tuple[list, list]:
    """RAFI's per-speed coefficient tables (terms x training speeds, exact; at most
    :data:`MAX_COEF_COLUMNS` speeds per table) and the flat list ``((speed, term), exact text)``.

    Parameters
    ----------
    art : dict
        A ``rafi`` or ``rafi_linear`` artefact (``speeds``, ``terms``).

    Returns
    -------
    blocks : list of dict
        ``kind`` ``rafi``, ``part`` (``[k, of]``), ``columns`` (``speed_rpm`` each), ``rows``
        (``term`` and ``coefs``, the exact text per column) and ``widths``.
    flat : list of tuple
        ``((speed, term), exact text)``.
    """
    speeds = sorted(art["speeds"], key=lambda s: float(s["speed_rpm"]))
    terms = list(art["terms"])
    flat = [
        ((float(s["speed_rpm"]), t), exact(s["coefficients"][j])) for s in speeds for j, t in enumerate(terms)
    ]
    text = dict(flat)
    blocks = []
    groups = column_groups(len(speeds))
    for g, cols in enumerate(groups):
        sp = [float(speeds[i]["speed_rpm"]) for i in cols]
        w = round(88 / MAX_COEF_COLUMNS, 1)
        blocks.append(
            {
                "kind": "rafi",
                "part": [g + 1, len(groups)],
                "columns": [{"speed_rpm": v} for v in sp],
                "rows": [{"term": t, "coefs": [text[(v, t)] for v in sp]} for t in terms],
                "widths": [12] + [w] * len(sp),
            }
        )
    return blocks, flat


def rafi_equation(art: dict) -> list[Markup]:
    var = art.get("variables") or {}
    names = ", ".join(f"x{k[1:]} = d{v}" for k, v in sorted(var.items()))
    return [
        Markup(
            "dz(t) = &sum;<sub>s</sub> w<sub>s</sub>(n(t))&middot;P<sub>s</sub>(x(t)), "
            "P<sub>s</sub>(x) = &sum;<sub>j</sub> a<sub>s,j</sub>&middot;term<sub>j</sub>(x)"
            "&nbsp;&nbsp;(&micro;m)"
        ),
        Markup(
            f"x: the rises (K) of the key sensors, {escape(names)}, each minus its median over the "
            "reference window"
        ),
        Markup(
            "w<sub>s</sub>: triangular memberships centred on the training speeds (the two "
            "neighbouring speeds, "
            "weights summing to 1); outside the trained speeds the edge model with weight 1"
        ),
        Markup("Coefficients a<sub>s,j</sub>: the tables below (row: term j; column: training speed s)"),
    ]


def rafi_inputs(art: dict) -> list[tuple[str, str]]:
    ref = art.get("reference") or {}
    return [
        ("temperature sensors", ", ".join(art.get("key_sensors") or [])),
        ("temperature filters", "none (the rises as they are)"),
        ("spindle speed", "only to blend the per-speed models"),
        ("displacement", "never an input (only the target of the fit)"),
        (
            "reference state",
            f"the median of the first {fmt_num(ref.get('window_s'), 0)} s "
            f"(reference.rule {ref.get('rule', '')})",
        ),
    ]
