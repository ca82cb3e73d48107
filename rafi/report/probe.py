"""What the report says of the displacement probe a unit qualifies: where it measured
(:func:`probe_words`), the one wording the verdict and the test record share.

A machine with several probes (``input.probes``, docs/raw-format.md "Several probes") is qualified
one probe at a time; a unit's settings name its probe in ``input.probes`` (that probe only) and
its column in ``input.displacement``. Nothing here assumes the paper's rig: the spindle axis is
named only where ``report.paper_rig`` says the machine is that rig.
"""

from __future__ import annotations

from collections.abc import Mapping


def probe_words(settings: dict) -> str:
    """Where the probe measured, in words.

    Parameters
    ----------
    settings : dict
        The unit's settings (``input.displacement``, ``input.probes``, ``report.paper_rig``).

    Returns
    -------
    str
        Its ``description`` (``input.probes``) beside its name and channel, e.g. ``"on probe ch1
        (channel 'ch1(um)')"``; else, on the paper's rig, ``"on the spindle axis (Z)"``; else its
        channel (``"on channel 'Z1'"``), or the native format's ``disp_um``.
    """
    inp = settings.get("input") or {}
    disp = inp.get("displacement") or {}
    probes = inp.get("probes") or {}
    for name, probe in probes.items():
        if probe.get("column") == disp.get("column"):
            described = f": {probe['description']}" if probe.get("description") else ""
            return f"on probe {name} (channel '{probe['column']}'{described})"
    if (settings.get("report") or {}).get("paper_rig"):
        return "on the spindle axis (Z)"
    column = disp.get("column")
    return f"on channel '{column}'" if column else "on the machine's displacement channel (disp_um)"


def _files(names: list[str], limit: int = 3) -> str:
    """``a.csv``, ``a.csv and b.csv``, ..., or ``N files`` beyond ``limit`` names."""
    if len(names) > limit:
        return f"{len(names)} files"
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _moves(names: list[str], sign: int) -> str:
    """``"a.csv rises"`` / ``"3 files fall"``: what the files' displacement does while the spindle heats."""
    verb = ("rises" if sign > 0 else "falls") if len(names) == 1 else ("rise" if sign > 0 else "fall")
    return f"{_files(names)} {verb}"


def file_signs(audit) -> dict:
    """``file -> probe sign`` (+1 / -1 / 0: no clear evidence) of ``audit.csv`` (its ``probe_sign``
    column, the clean job's per-file sign; docs/raw-format.md "Checks"); ``{}`` without it."""
    if audit is None or "probe_sign" not in audit or "file" not in audit:
        return {}
    out = {}
    for file, value in zip(audit["file"].astype(str), audit["probe_sign"]):
        try:
            sign = int(float(value))
        except (TypeError, ValueError):
            continue
        out[file] = 0 if sign == 0 else (1 if sign > 0 else -1)
    return out


def _verdict_line(head: str, seen: str, key: str, contradicted: bool, unconfirmed: bool) -> str | None:
    """A flagged sign in one line for the verdict box (:func:`probe_sign_record`): what the data
    say and the key that settles it (``key``: the one that sets the sign, or the one to set; an
    unconfirmed sign is a default, so it is the one to set); None when not flagged."""
    if contradicted:
        said = seen.split(": ", 1)[1]  # "the data contradict it: <files> falls while ..."
        return (
            f"{head} contradicted by the data: {said}; set {key} to the probe's sign, or confirm the "
            "file's sign in checks.confirmed."
        )
    if unconfirmed:
        return f"{head} unconfirmed: the default, and {seen}; set {key} (or checks.probe_sign) to settle it."
    return None


def probe_sign_record(settings: dict, sign_key: str | None, audit) -> dict:
    """Where the unit's probe sign comes from and whether the data agree, for the report.

    The data's word is the pipeline's own: ``audit.csv`` ``probe_sign`` per file (the sign of the
    correlation between the signed displacement and the spindle's heat input, 0 without clear
    evidence; docs/raw-format.md "Checks"), judged against the direction
    ``checks.probe_sign`` expects (``negative``: falls; ``positive`` and ``auto``: rises, the
    documented convention). Nothing is estimated here.

    Parameters
    ----------
    settings : dict
        The unit's settings: ``input.displacement.sign``, ``input.probes`` (the probe's name),
        ``checks.probe_sign`` and ``checks.confirmed``.
    sign_key : str or None
        The key of config.yaml that sets the sign (:func:`sign_key`); ``None``: not
        set, the default.
    audit : DataFrame or None
        ``audit.csv``.

    Returns
    -------
    dict
        ``sign`` (+1 / -1), ``source`` (``set``: in the settings; ``stated``: not set, but
        ``checks.probe_sign`` states the direction; ``default``), ``key`` (the key that sets it,
        or the one to set), ``data`` (``agree``, ``contradict``: a file with a clear sign against
        the expected one, ``no evidence``: no file with a clear sign, ``unknown``: no
        ``audit.csv``), ``flagged`` (the data contradict it, a file a person confirmed in
        ``checks.confirmed`` aside, or a default no file gives clear evidence for), ``short`` (a few words
        for a table cell), ``head`` (``"Probe sign +1"``), ``body`` (where it comes from, what the
        data say, and what to do when flagged), ``text`` (``head: body``) and ``verdict_line`` (a
        flagged sign in one line for the verdict box, naming the key that settles it; None when
        not flagged).
    """
    from rafi.readers.checks_machine import CONFIGURED_SIGNS, is_confirmed

    inp = settings.get("input") or {}
    sign = -1 if int((inp.get("displacement") or {}).get("sign", 1)) < 0 else 1
    checks = settings.get("checks") or {}
    stated = str(checks.get("probe_sign", "auto"))
    expected = CONFIGURED_SIGNS.get(stated, 1)
    probes = list(inp.get("probes") or {})
    to_set = f"input.probes.{probes[0]}.sign" if len(probes) == 1 else "input.displacement.sign"
    signs = file_signs(audit)
    agree = [f for f, s in signs.items() if s == expected]
    against = [f for f, s in signs.items() if s == -expected]
    accepted = [f for f in against if is_confirmed(f, "probe_sign", checks.get("confirmed") or [])]
    if sign_key:
        source, said = "set", f"set in the settings ({sign_key})"
    elif stated in CONFIGURED_SIGNS:
        source, said = "stated", f"{to_set} not set; checks.probe_sign: {stated} states the direction"
    else:
        source, said = "default", f"the default ({to_set} not set)"

    def where(value: int) -> str:
        # the clean job measures the displacement the reader already multiplied by the sign
        applied = f", measured after the configured sign {sign:+d} is applied" if sign < 0 else ""
        return f"(audit.csv probe_sign {value:+d}{applied})".replace("-", "\u2212")

    if audit is None:
        data, seen = "unknown", "no audit.csv: what the data say is not known"
    elif against:
        data = "contradict"
        heats = f"while the spindle heats {where(-expected)}"
        seen = f"the data contradict it: {_moves(against, -expected)} {heats}"
        if len(accepted) == len(against):
            seen += ", confirmed in checks.confirmed"
    elif agree:
        data = "agree"
        seen = f"the data agree: {_moves(agree, expected)} while the spindle heats {where(expected)}"
    else:
        data = "no evidence"
        seen = (
            f"the data show no clear direction ({_files(list(signs))}: audit.csv probe_sign 0)"
            if signs
            else "no file of audit.csv has a probe sign"
        )
    contradicted = data == "contradict" and len(accepted) < len(against)
    unconfirmed = source == "default" and data in ("no evidence", "unknown")
    head = f"Probe sign {sign:+d}".replace("-", "\u2212")
    text = f"{said}; {seen}."
    if contradicted:
        text += (
            f" Contradicted: a reversed probe? Set {to_set} to the probe's sign, or confirm the "
            "file's sign in checks.confirmed."
        )
    elif unconfirmed:
        text += (
            f" Unconfirmed: nothing confirms the direction; check the probe and set {to_set} "
            "(or checks.probe_sign)."
        )
    short = {"set": "set in the settings", "stated": "checks.probe_sign", "default": "default"}[source]
    if contradicted:
        short += ", contradicted by the data"
    elif unconfirmed:
        short += ", unconfirmed"
    elif data == "agree":
        short += ", the data agree"
    return {
        "sign": sign,
        "source": source,
        "key": sign_key or to_set,
        "data": data,
        "flagged": contradicted or unconfirmed,
        "short": short,
        "head": head,
        "body": text,
        "text": f"{head}: {text}",
        "verdict_line": _verdict_line(head, seen, sign_key or to_set, contradicted, unconfirmed),
    }


def sign_key(config: Mapping, machine: str) -> str | None:
    """The key of ``config.yaml`` that sets the sign of ``machine``'s displacement probe, or None
    where nothing sets it and the sign is the default (+1; ``rafi init`` leaves it a ``# CHECK:``
    line for a person to decide).

    Parameters
    ----------
    config : Mapping
        ``config.yaml`` as loaded.
    machine : str
        A machine, or a probe of one (``<machine>@<probe>``, :func:`split_unit`).

    Returns
    -------
    str or None
        ``machines.<m>.input.probes.<probe>.sign``, ``machines.<m>.input.displacement.sign`` or
        ``defaults.input.displacement.sign``, the first that is given (a probe's own sign wins;
        a probe without one takes ``displacement.sign``, as
        :func:`rafi.readers.input_spec.normalise_input_spec` fills it in).
    """
    from rafi.settings import split_unit

    folder, probe = split_unit(machine)
    own = ((config.get("machines") or {}).get(folder) or {}).get("input") or {}
    if probe is not None:
        entry = (own.get("probes") or {}).get(probe)
        if isinstance(entry, Mapping) and "sign" in entry:
            return f"machines.{folder}.input.probes.{probe}.sign"
    if "sign" in (own.get("displacement") or {}):
        return f"machines.{folder}.input.displacement.sign"
    shared = ((config.get("defaults") or {}).get("input") or {}).get("displacement") or {}
    return "defaults.input.displacement.sign" if "sign" in shared else None
