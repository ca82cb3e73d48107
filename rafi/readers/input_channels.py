"""The channels of an ``input:`` mapping: the machine's temperature sensors and its displacement
probes (standard library only; :func:`rafi.readers.input_spec.normalise_input_spec` calls them).

A machine has its own sensors (``input.sensors``, or the sensor keys of ``input.columns``; the
paper rig's ``T1`` .. ``T16`` where it names none) and one displacement channel, or several probes
(``input.probes``), each of which is qualified on its own (:func:`probe_spec`).
"""

from __future__ import annotations

import copy
import re

from rafi.contract import (
    DEFAULT_SENSORS,
    MAX_SENSORS,
    NON_SENSOR_COLUMNS,
    PROBE_KEYS,
    PROBE_NAME_RE,
    RESERVED_NAMES,
    SENSOR_NAME_RE,
)
from rafi.errors import InputSpecError


def _spec_error(key: str, message: str) -> InputSpecError:
    return InputSpecError(f"input.{key}: {message}")


def first_duplicate(items):
    seen = set()
    for item in items:
        if item in seen:
            return item
        seen.add(item)
    return None


def sensor_name_problem(name) -> str | None:
    """Why ``name`` cannot name a temperature sensor, or ``None`` if it can."""
    if not isinstance(name, str) or not re.match(SENSOR_NAME_RE, name):
        return (
            f"{name!r} is not a sensor name: a letter, then up to 31 letters, digits or '_' "
            "(e.g. T1, spindle_front)"
        )
    if name in RESERVED_NAMES:
        return (
            f"{name!r} is a column of the pipeline's own ({', '.join(RESERVED_NAMES)}); "
            "name the sensor otherwise"
        )
    return None


def check_sensors(out: dict) -> None:
    """Resolve ``sensors``, the machine's temperature sensors, in order: the list given; else the
    keys of ``columns`` other than time, speed_rpm and disp_um; else the paper rig's ``T1`` ..
    ``T16``. One to :data:`MAX_SENSORS` valid, distinct names, none the rise column ``d<name>``
    of another. ``out`` is changed in place."""
    given = out["sensors"]
    if given is None:
        mapped = [str(k) for k in out["columns"] if k not in NON_SENSOR_COLUMNS]
        sensors = mapped or list(DEFAULT_SENSORS)
        key = "columns" if mapped else "sensors"
    else:
        if isinstance(given, str) or not isinstance(given, (list, tuple)):
            raise _spec_error("sensors", f"{given!r}: expected a list of sensor names")
        sensors, key = list(given), "sensors"
    if not 1 <= len(sensors) <= MAX_SENSORS:
        raise _spec_error(
            key, f"{len(sensors)} sensors: a machine has 1 to {MAX_SENSORS} temperature sensors"
        )
    for name in sensors:
        problem = sensor_name_problem(name)
        if problem:
            raise _spec_error(key if key == "sensors" else f"columns.{name}", problem)
    dup = first_duplicate(sensors)
    if dup is not None:
        raise _spec_error(key, f"sensor {dup!r} is listed twice")
    clash = sorted(s for s in sensors if s.startswith("d") and s[1:] in sensors)
    if clash:
        raise _spec_error(
            key, f"sensor {clash[0]!r} is also the name of the rise of sensor {clash[0][1:]!r}; rename one"
        )
    out["sensors"] = sensors


def check_probes(out: dict) -> None:
    """``probes``: several displacement probes, each by name with its ``column``, ``unit`` and
    ``sign`` (the two default to ``displacement``'s) and an optional ``description``; then
    ``displacement.column`` stays unset (each probe names its own). ``out`` is changed in place:
    every probe complete."""
    probes = out["probes"]
    if probes is None:
        out["probes"] = {}
        return
    if not isinstance(probes, dict):
        raise _spec_error("probes", f"expected a mapping of probe names to columns, got {probes!r}")
    if probes and out["format"] == "native":
        raise _spec_error("probes", "needs format csv or xlsx: a native log has one displacement, disp_um")
    one_probe = (
        len(probes) == 1
        and (next(iter(probes.values())) or {}).get("column") == out["displacement"]["column"]
    )  # the mapping of one probe of a machine (probe_spec), read again
    if probes and out["displacement"]["column"] is not None and not one_probe:
        raise _spec_error(
            "displacement.column", "with input.probes, each probe names its column there; remove this one"
        )
    complete = {}
    for name, probe in probes.items():
        where = f"probes.{name}"
        if not isinstance(name, str) or not re.match(PROBE_NAME_RE, name):
            raise _spec_error(
                where, "not a probe name: a letter, then up to 15 letters, digits or '_' (X, ch1)"
            )
        if isinstance(probe, str):
            probe = {"column": probe}
        if not isinstance(probe, dict):
            raise _spec_error(where, f"expected {{column: <header>, unit: um|mm, sign: 1|-1}}, got {probe!r}")
        extra = sorted(set(probe) - set(PROBE_KEYS))
        if extra:
            raise _spec_error(f"{where}.{extra[0]}", "unknown key; accepted keys: " + ", ".join(PROBE_KEYS))
        column = probe.get("column")
        if not isinstance(column, str) or not column.strip():
            raise _spec_error(f"{where}.column", f"{column!r}: expected the probe's header text")
        unit = probe.get("unit", out["displacement"]["unit"])
        sign = probe.get("sign", out["displacement"]["sign"])
        if unit not in ("um", "mm"):
            raise _spec_error(f"{where}.unit", f"{unit!r}: expected um or mm")
        if isinstance(sign, bool) or sign not in (1, -1):
            raise _spec_error(f"{where}.sign", f"{sign!r}: expected 1 or -1")
        complete[name] = {
            "column": column,
            "unit": unit,
            "sign": sign,
            "description": probe.get("description"),
        }
    out["probes"] = complete


def probe_spec(spec: dict, probe: str) -> dict:
    """The normalised ``input:`` mapping ``spec`` reading probe ``probe`` as its displacement
    (``displacement`` = the probe's column, unit and sign; ``probes`` = that probe only); a new
    dict, which normalises to itself.

    Raises
    ------
    InputSpecError
        ``probe`` is not one of ``spec["probes"]``.
    """
    if probe not in spec["probes"]:
        known = ", ".join(spec["probes"]) or "none"
        raise _spec_error("probes", f"the machine has no probe {probe!r} (its probes: {known})")
    out = copy.deepcopy(spec)
    chosen = spec["probes"][probe]
    out["displacement"] = {key: chosen[key] for key in ("column", "unit", "sign")}
    out["probes"] = {probe: dict(chosen)}
    return out
