# The fleet overview's place in the final targets (functions only; included by fleet.smk).
#
# fleet.smk is included right after common.smk: these wrappers add the page to all_targets()
# and nightly_targets() before rule `all` (Snakefile) and rule `nightly` (registry.smk) read them.

#: The fleet overview page (rule fleet_index).
FLEET_INDEX = f"{REPORTS_DIR}/index.html"

_targets_without_fleet_index = all_targets
_nightly_targets_without_fleet_index = nightly_targets


def all_targets():
    """common.smk's all_targets() and the fleet overview (``rule all``)."""
    return _targets_without_fleet_index() + [FLEET_INDEX]


def nightly_targets():
    """common.smk's nightly_targets() and, when the night covers every machine, the fleet
    overview (a night for some machines, ``rafi nightly --machine M``, rewrites the page itself)."""
    targets = _nightly_targets_without_fleet_index()
    return targets + ([FLEET_INDEX] if _nightly_machines() == MACHINES else [])
