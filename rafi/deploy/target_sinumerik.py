"""The SINUMERIK 840D sl target: temperature compensation setting data per axis.

The paper writes the model's estimate to SD 43900 of the 840D sl (Figure 8). What the
controller does with it (``../shared/docs/controllers.md``, the 840D sl function manual):

* MD 32750 ``$MA_TEMP_COMP_TYPE`` (per axis) enables the compensation: bit 0 the
  position-independent offset SD 43900, bit 1 the position-dependent part SD 43910/43920.
* SD 43900 ``$SA_TEMP_COMP_ABS_VALUE``: the offset K_abs in the axis' length unit, mm on a
  metric machine (12.3 um is 0.0123). A DOUBLE.
* SD 43910 ``$SA_TEMP_COMP_SLOPE``: tan(beta), dimensionless (mm per mm); SD 43920
  ``$SA_TEMP_COMP_REF_POSITION``: the reference position P0 in mm, not the axis zero.
  The controller applies K = K_abs + tan(beta) * (P_actual - P0).
* MD 32760 ``$MA_COMP_ADD_VELO_FACTOR`` (0..0.10, default 0.01) caps the compensation travel
  per interpolation cycle at this factor times the axis' maximum velocity (MD 32000): a larger
  step is spread over several cycles *without an alarm*. The same factor caps tan(beta): a
  larger SD 43910 is clipped *silently*. This target refuses such a slope instead.

An axis is written in one of two modes (:class:`SinumerikAxis`):

* ``"offset"`` (MD 32750 bit 0): SD 43900 = ``sign * value_um / 1000`` mm, rounded half away
  from zero to the controller's length resolution ``1 / int_incr_per_mm`` mm (MD 10200).
* ``"slope"`` (MD 32750 bit 1): the value is the error at the axis position
  ``measured_at_mm`` (where the model's displacement was measured); the target writes
  SD 43920 = ``ref_position_mm`` once when opened and, per sample, SD 43910 =
  ``sign * value_um / 1000 / (measured_at_mm - ref_position_mm)``, so that the controller's
  K at ``measured_at_mm`` equals the value and grows linearly with the distance to P0.

The values go to a *sink*: any object with ``write_value(node, value, datatype)`` (the OPC UA
client, :class:`rafi.deploy.opcua_client.OpcUaLink`; it may also have ``open()``/``close()``,
and ``read_value(node)`` for the read-back of :meth:`SinumerikTarget.read_current_um`) or a
callable with the same arguments. :class:`DrySink` records what would be written. The node names follow the
SINUMERIK OPC UA server's NC variable paths, ``/NC/_N_AX_SEA_ACX/$SA_<name>[u<axis>]`` by
default (machine axis number, 1-based), a template the user can replace.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from rafi.deploy.target_base import Target, check_axes
from rafi.errors import TargetError

#: Setting data numbers and names.
SD_ABS_VALUE = "TEMP_COMP_ABS_VALUE"  # SD 43900
SD_SLOPE = "TEMP_COMP_SLOPE"  # SD 43910
SD_REF_POSITION = "TEMP_COMP_REF_POSITION"  # SD 43920
SETTING_DATA = {SD_ABS_VALUE: 43900, SD_SLOPE: 43910, SD_REF_POSITION: 43920}

#: The NC data type of the three setting data, as an OPC UA built-in type name.
DATATYPE = "Double"

#: Default node name: axis-specific setting data of machine axis ``axis`` (1-based).
NODE_TEMPLATE = "/NC/_N_AX_SEA_ACX/$SA_{data}[u{axis}]"

#: Documented range of MD 32760 COMP_ADD_VELO_FACTOR.
VELO_FACTOR_MAX = 0.10

#: No thermal compensation of this target exceeds 1 mm: a larger limit is a unit mistake.
HARD_LIMIT_UM = 1000.0

MODES = ("offset", "slope")


def round_half_away(x: float) -> int:
    """``x`` rounded to the nearest integer, halves away from zero (2.5 -> 3, -2.5 -> -3)."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


@dataclass(frozen=True)
class SinumerikAxis:
    """One machine axis of the SINUMERIK target.

    Parameters
    ----------
    name : str
        The axis' key in the samples (``"Z"``).
    number : int
        The machine axis number (1-based), the index ``[u<number>]`` of its setting data.
    sign : int
        +1 or -1, no default: SD 43900 is ``sign * value``. The compensator's value is the
        model's estimate of the thermal displacement, signed as the displacement was measured
        (``Step.compensation_um``); whether cancelling it needs the same or the opposite sign
        on the axis depends on the probe's direction and the axis' direction, so it is set per
        machine and checked on it (``docs/deploy-targets.md``).
    limit_um : float
        The largest ``|value|`` accepted, in um (the range agreed for the machine, at most
        :data:`HARD_LIMIT_UM`); a larger value is refused, not clipped.
    mode : {"offset", "slope"}
        SD 43900 (position-independent) or SD 43910/43920 (position-dependent).
    ref_position_mm : float, optional
        ``"slope"`` only: P0, written to SD 43920; not 0 (the controller's rule).
    measured_at_mm : float, optional
        ``"slope"`` only: the axis position at which the value holds (where the displacement
        was measured); not equal to ``ref_position_mm``.
    max_velocity_mm_min : float, optional
        MD 32000 of the axis: with the target's ``ipo_cycle_s``, the report says over how many
        interpolation cycles the controller spreads each step.
    """

    name: str
    number: int
    sign: int
    limit_um: float
    mode: str = "offset"
    ref_position_mm: float | None = None
    measured_at_mm: float | None = None
    max_velocity_mm_min: float | None = None

    def check(self) -> None:
        """Raise TargetError for an axis set up wrongly."""
        t, a = "sinumerik", self.name
        if isinstance(self.number, bool) or not isinstance(self.number, int) or self.number < 1:
            raise TargetError(f"machine axis number {self.number!r} is not an integer >= 1", target=t, axis=a)
        if self.sign not in (1, -1) or isinstance(self.sign, bool):
            raise TargetError(f"sign {self.sign!r} is not +1 or -1", target=t, axis=a)
        if not (_finite(self.limit_um) and 0 < self.limit_um <= HARD_LIMIT_UM):
            raise TargetError(
                f"limit_um {self.limit_um!r} is not in (0, {HARD_LIMIT_UM:g}] um", target=t, axis=a
            )
        if self.mode not in MODES:
            raise TargetError(f"mode {self.mode!r} is not one of {list(MODES)}", target=t, axis=a)
        if self.mode == "slope":
            for key in ("ref_position_mm", "measured_at_mm"):
                if not _finite(getattr(self, key)):
                    raise TargetError(f"mode 'slope' needs a finite {key}", target=t, axis=a)
            if self.ref_position_mm == 0:
                raise TargetError("SD 43920 reference position must not be the axis zero", target=t, axis=a)
            if self.measured_at_mm == self.ref_position_mm:
                raise TargetError("measured_at_mm equals ref_position_mm: no slope defined", target=t, axis=a)
        elif self.ref_position_mm is not None or self.measured_at_mm is not None:
            raise TargetError("ref_position_mm / measured_at_mm are for mode 'slope' only", target=t, axis=a)
        if self.max_velocity_mm_min is not None and not (
            _finite(self.max_velocity_mm_min) and self.max_velocity_mm_min > 0
        ):
            raise TargetError(
                f"max_velocity_mm_min {self.max_velocity_mm_min!r} is not > 0", target=t, axis=a
            )

    @property
    def temp_comp_type(self) -> int:
        """The MD 32750 bits this axis needs: 1 (bit 0) for ``offset``, 2 (bit 1) for ``slope``."""
        return 1 if self.mode == "offset" else 2


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


@dataclass(frozen=True)
class WrittenValue:
    """One value as the controller receives it: node name, value, OPC UA data type name."""

    node: str
    value: float
    datatype: str


@dataclass
class DrySink:
    """A sink that writes nothing and records what would have been written, in order.

    ``start`` maps a node to the value it holds before the first write (what
    :meth:`read_value` returns until then; a dry run copies the controller's values there).
    """

    writes: list[WrittenValue] = field(default_factory=list)
    opened: int = 0
    closed: int = 0
    start: dict[str, float] = field(default_factory=dict)

    def open(self) -> None:
        self.opened += 1

    def close(self) -> None:
        self.closed += 1

    def write_value(self, node: str, value: float, datatype: str) -> None:
        self.writes.append(WrittenValue(node, value, datatype))

    def last(self, node: str) -> float | None:
        """The last value written to ``node`` (None if none)."""
        for w in reversed(self.writes):
            if w.node == node:
                return w.value
        return None

    def read_value(self, node: str) -> float | None:
        """The value ``node`` holds: the last written, else its ``start`` value, else None."""
        last = self.last(node)
        return self.start.get(node) if last is None else last


class SinumerikTarget(Target):
    """SINUMERIK 840D sl: per axis SD 43900 (mode ``offset``) or SD 43910/43920 (``slope``).

    Parameters
    ----------
    axes : sequence of SinumerikAxis
        The axes in layout order (names and machine axis numbers unique).
    sink : object with ``write_value(node, value, datatype)``, or callable
        Where the values go (:class:`DrySink` for a dry run). ``open()`` / ``close()`` of the
        sink, if it has them, are called with the target's.
    int_incr_per_mm : int
        MD 10200 ``INT_INCR_PER_MM`` of the controller, its length resolution: SD 43900 and
        SD 43920 are rounded to ``1 / int_incr_per_mm`` mm (default 1000, i.e. 1 um; use the
        machine's value).
    comp_add_velo_factor : float
        MD 32760 of the axes, in (0, 0.10]: the largest |SD 43910| the controller applies
        unclipped; a larger slope is refused. Also sets the step spread in the report.
    ipo_cycle_s : float, optional
        The interpolation cycle in seconds, for the report of how a step is spread.
    node_template : str
        Node name of a setting datum; ``{data}`` is its name (``TEMP_COMP_ABS_VALUE``...) and
        ``{axis}`` the machine axis number.
    skip_unchanged : bool
        Do not write a value equal to the last one written to its node (default: write every
        sample, a visible heartbeat on the controller).

    Attributes
    ----------
    last_report : dict
        Per axis, for the last sample: ``node``, ``value`` (as written), ``step`` (change
        from the previous value, None at the first) and ``ipo_cycles`` (cycles the
        controller needs for that step, None when MD 32000 or the cycle is not given).
    """

    name = "sinumerik"

    def __init__(
        self,
        axes,
        sink,
        *,
        int_incr_per_mm: int = 1000,
        comp_add_velo_factor: float = 0.01,
        ipo_cycle_s: float | None = None,
        node_template: str = NODE_TEMPLATE,
        skip_unchanged: bool = False,
    ):
        axes = tuple(axes)
        for ax in axes:
            if not isinstance(ax, SinumerikAxis):
                raise TargetError(f"{ax!r} is not a SinumerikAxis", target=self.name)
            ax.check()
        super().__init__([ax.name for ax in axes])
        check_axes([str(ax.number) for ax in axes], self.name)  # machine axis numbers unique
        self.axis_config = {ax.name: ax for ax in axes}
        if isinstance(int_incr_per_mm, bool) or not isinstance(int_incr_per_mm, int) or int_incr_per_mm < 1:
            raise TargetError(f"int_incr_per_mm {int_incr_per_mm!r} is not an integer >= 1", target=self.name)
        if not (_finite(comp_add_velo_factor) and 0 < comp_add_velo_factor <= VELO_FACTOR_MAX):
            raise TargetError(
                f"comp_add_velo_factor (MD 32760) {comp_add_velo_factor!r} is not in (0, {VELO_FACTOR_MAX}]",
                target=self.name,
            )
        if ipo_cycle_s is not None and not (_finite(ipo_cycle_s) and 0 < ipo_cycle_s < 1):
            raise TargetError(f"ipo_cycle_s {ipo_cycle_s!r} is not in (0, 1) s", target=self.name)
        if "{data}" not in node_template or "{axis}" not in node_template:
            raise TargetError(f"node_template {node_template!r} lacks {{data}} or {{axis}}", target=self.name)
        self.int_incr_per_mm = int_incr_per_mm
        self.comp_add_velo_factor = float(comp_add_velo_factor)
        self.ipo_cycle_s = ipo_cycle_s
        self.node_template = node_template
        self.skip_unchanged = bool(skip_unchanged)
        self.sink = sink
        self._write_value = sink.write_value if hasattr(sink, "write_value") else sink
        if not callable(self._write_value):
            raise TargetError(
                "sink has no write_value(node, value, datatype) and is not callable", target=self.name
            )
        self.last_written: dict[str, float] = {}
        self.last_report: dict[str, dict] = {}
        self._pending: list[tuple[str, str, float]] = []

    # -- what is written -----------------------------------------------------------------
    def node(self, data: str, axis: str) -> str:
        """The node name of setting datum ``data`` (``TEMP_COMP_ABS_VALUE``...) of ``axis``."""
        return self.node_template.format(data=data, axis=self.axis_config[axis].number)

    def to_length_mm(self, mm: float) -> float:
        """``mm`` rounded half away from zero to the controller's resolution (MD 10200)."""
        return round_half_away(mm * self.int_incr_per_mm) / self.int_incr_per_mm

    def setting_value(self, axis: str, value_um: float) -> tuple[str, float]:
        """The (node, value) a compensation of ``value_um`` on ``axis`` is written as.

        ``offset``: SD 43900 in mm, rounded (:meth:`to_length_mm`); ``slope``: SD 43910,
        dimensionless, not rounded. Raises TargetError outside the axis' limits.
        """
        ax = self.axis_config[axis]
        if abs(value_um) > ax.limit_um:
            raise TargetError(
                f"{value_um!r} um is outside the axis' limit +-{ax.limit_um:g} um: refused, nothing written",
                target=self.name,
                axis=axis,
                value=value_um,
                limit=ax.limit_um,
            )
        if ax.mode == "offset":
            # value_um * incr / 1000 counts of the resolution, rounded in counts (exact for the
            # decimal value a user reads: 12.5 um at 1 um resolution is 13 counts)
            counts = round_half_away(ax.sign * value_um * self.int_incr_per_mm / 1000.0)
            return self.node(SD_ABS_VALUE, axis), counts / self.int_incr_per_mm
        slope = ax.sign * value_um / 1000.0 / (ax.measured_at_mm - ax.ref_position_mm)
        if abs(slope) > self.comp_add_velo_factor:
            raise TargetError(
                f"SD 43910 slope {slope:.6g} for {value_um!r} um exceeds MD 32760 "
                f"({self.comp_add_velo_factor:g}); the controller would clip it silently: refused",
                target=self.name,
                axis=axis,
                value=slope,
                limit=self.comp_add_velo_factor,
            )
        return self.node(SD_SLOPE, axis), slope + 0.0  # + 0.0: no negative zero

    def ipo_cycles(self, axis: str, step: float) -> int | None:
        """Interpolation cycles the controller spreads a step of SD 43900 (mm) over.

        ``ceil(|step| / (MD 32760 * MD 32000 * cycle))``; None without MD 32000 or the cycle.
        For a slope the step is in SD 43910 units and the per-cycle travel depends on the
        position, so None.
        """
        ax = self.axis_config[axis]
        if ax.mode != "offset" or ax.max_velocity_mm_min is None or self.ipo_cycle_s is None:
            return None
        per_cycle_mm = self.comp_add_velo_factor * ax.max_velocity_mm_min / 60.0 * self.ipo_cycle_s
        return max(1, math.ceil(abs(step) / per_cycle_mm - 1e-9)) if step else 0

    def required_temp_comp_type(self) -> dict[int, int]:
        """MD 32750 ``TEMP_COMP_TYPE`` bits each machine axis needs (at least these set)."""
        return {ax.number: ax.temp_comp_type for ax in self.axis_config.values()}

    def value_um(self, axis: str, setting: float) -> float:
        """The compensation in um that setting datum value ``setting`` means on ``axis``: the
        inverse of :meth:`setting_value` (``offset``: ``sign * mm * 1000``; ``slope``:
        ``sign * slope * 1000 * (measured_at_mm - ref_position_mm)``)."""
        ax = self.axis_config[axis]
        if ax.mode == "offset":
            return ax.sign * float(setting) * 1000.0
        return ax.sign * float(setting) * 1000.0 * (ax.measured_at_mm - ax.ref_position_mm)

    def output_nodes(self) -> list[str]:
        """Every node this target writes (SD 43900, or SD 43910 and SD 43920 in slope mode)."""
        nodes = []
        for axis, ax in self.axis_config.items():
            data = (SD_ABS_VALUE,) if ax.mode == "offset" else (SD_SLOPE, SD_REF_POSITION)
            nodes += [self.node(d, axis) for d in data]
        return nodes

    # -- the Target interface ------------------------------------------------------------
    def read_current_um(self) -> dict[str, float | None]:
        """Per axis, the value SD 43900 (``offset``) or SD 43910 (``slope``) holds, read
        through the sink's ``read_value(node)`` and turned back into um (:meth:`value_um`);
        None when the sink cannot read (a callable sink) or returns None."""
        read = getattr(self.sink, "read_value", None)
        out: dict[str, float | None] = {}
        for axis, ax in self.axis_config.items():
            node = self.node(SD_ABS_VALUE if ax.mode == "offset" else SD_SLOPE, axis)
            setting = None if read is None else read(node)
            if setting is not None:
                self.last_written[node] = float(setting)  # the step report and skip_unchanged
            out[axis] = None if setting is None else self.value_um(axis, setting)
        return out

    def check_values(self, values_um) -> None:
        self._pending = [(axis, *self.setting_value(axis, v)) for axis, v in values_um.items()]

    def _send(self, node: str, value: float) -> None:
        if self.skip_unchanged and self.last_written.get(node) == value:
            return
        self._write_value(node, float(value), DATATYPE)
        self.last_written[node] = value

    def _open(self) -> None:
        if hasattr(self.sink, "open"):
            self.sink.open()
        for axis, ax in self.axis_config.items():
            if ax.mode == "slope":
                self._send(self.node(SD_REF_POSITION, axis), self.to_length_mm(ax.ref_position_mm))

    def _write(self, time_s, values_um, status) -> None:
        pending, self._pending = self._pending, []
        report = {}
        for axis, node, value in pending:
            previous = self.last_written.get(node)
            step = None if previous is None else value - previous
            self._send(node, value)
            report[axis] = {
                "node": node,
                "value": value,
                "step": step,
                "ipo_cycles": None if step is None else self.ipo_cycles(axis, step),
            }
        self.last_report = report

    def _close(self) -> None:
        if hasattr(self.sink, "close"):
            self.sink.close()
