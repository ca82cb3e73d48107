"""What the report says of the displacement probe a unit qualifies: where it measured
(:func:`probe_words`), the one wording the verdict and the test record share.

A machine with several probes (``input.probes``, docs/raw-format.md "Several probes") is qualified
one probe at a time; a unit's settings name its probe in ``input.probes`` (that probe only) and
its column in ``input.displacement``. Nothing here assumes the paper's rig: the spindle axis is
named only where ``report.paper_rig`` says the machine is that rig.
"""

from __future__ import annotations


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
