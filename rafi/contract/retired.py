"""Settings that were tried, not adopted and then removed: each with what took its place.

A ``config.yaml`` that still sets one is refused with one line naming the key and what replaced it
(:func:`retired_setting`, called by :func:`rafi.settings.validate_config` before the schema),
rather than the schema's "Additional properties are not allowed". Why each was not adopted is in
``docs/decisions.md``; ``CHANGELOG.md`` lists them under 2026-11-29 (issue 49).
"""

from __future__ import annotations

from collections.abc import Mapping

#: ``(section, key)`` of a per-machine setting -> what replaced it.
RETIRED_SETTINGS: dict[tuple[str, str], str] = {
    ("models", "cv_forward_hyperparameters"): (
        "the ridge kinds choose their hyperparameters on the whole-run CV; the forward folds score"
        " the selection only (models.cv_forward_runs)"
    ),
    ("models", "interval_forward_units"): (
        "the prediction intervals calibrate on the whole-run CV folds alone"
    ),
    ("models", "grey_box_slow_rises"): (
        "give grey_box's rise filters as a list in models.grey_box_taus_s (e.g. up to the run length)"
    ),
    ("models", "grey_box_heat_input"): "grey_box's heat-input filters are in or out by CV",
    ("models", "grey_box_filter_search"): (
        "grey_box fits every filter constant at once (models.grey_box_taus_s, grey_box_speed_taus_s),"
        " the ridge penalty by CV"
    ),
    ("models", "grey_box_max_taus"): (
        "grey_box fits every rise filter of models.grey_box_taus_s at once; shorten that list instead"
    ),
    ("models", "grey_box_max_speed_taus"): (
        "grey_box fits every heat-input filter of models.grey_box_speed_taus_s at once; shorten that"
        " list instead"
    ),
}


def retired_setting(config: Mapping) -> str | None:
    """The first retired setting ``config`` (``config.yaml`` as loaded) still sets, as one line
    (``config.yaml: machines.m.models.grey_box_slow_rises was removed on 2026-11-29 (issue 49):
    ...``), or ``None``. Looked for under ``defaults:`` and every ``machines.<name>:``."""
    places = [("defaults", config.get("defaults"))]
    machines = config.get("machines")
    if isinstance(machines, Mapping):
        places += [(f"machines.{name}", block) for name, block in machines.items()]
    for where, block in places:
        if not isinstance(block, Mapping):
            continue
        for (section, key), instead in RETIRED_SETTINGS.items():
            part = block.get(section)
            if isinstance(part, Mapping) and key in part:
                return f"config.yaml: {where}.{section}.{key} was removed on 2026-11-29 (issue 49): {instead}"
    return None
