"""The writer interface of the controller targets (:class:`Target`), and its shared checks.

Split from :mod:`rafi.deploy.targets` so that each target module imports the interface
without an import cycle; use the targets through :mod:`rafi.deploy.targets`.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Mapping

from rafi.errors import TargetError


def check_axes(axes, target: str) -> tuple[str, ...]:
    """The axis names as a tuple: non-empty, unique, simple names (letters, digits, ``_``)."""
    names = tuple(axes)
    if not names:
        raise TargetError("no axis configured", target=target)
    for name in names:
        if not isinstance(name, str) or not name or not name.replace("_", "").isalnum():
            raise TargetError(f"axis name {name!r} is not a simple name (letters, digits, _)", target=target)
    if len(set(names)) != len(names):
        raise TargetError(f"axis names repeat: {list(names)}", target=target)
    return names


class Target(abc.ABC):
    """The writer interface every controller target implements.

    Subclasses implement :meth:`_open`, :meth:`_write` (a sample already checked) and
    :meth:`_close`; this base checks the sample (:meth:`check_sample`) and the state.

    Parameters
    ----------
    axes : sequence of str
        The axis names, in the order of the target's layout (file columns, controller axes).
    """

    #: Short name of the target in messages and documents.
    name = "target"

    def __init__(self, axes):
        self.axes = check_axes(axes, self.name)
        self.is_open = False
        self.closed = False
        self.samples_written = 0

    # -- the interface -------------------------------------------------------------------
    def open(self) -> Target:
        """Open the target (a file, a session); returns the target. Opening twice is an error."""
        if self.is_open or self.closed:
            raise TargetError("already opened (a target is opened once)", target=self.name)
        self._open()
        self.is_open = True
        return self

    def write(self, time_s: float, values_um: Mapping[str, float], status: str) -> None:
        """Write one sample: the time, the compensation per axis in micrometres, the status.

        Parameters
        ----------
        time_s : float
            The sample time in seconds (the compensator's clock: since its start or the epoch).
        values_um : mapping of str to float
            The compensation per axis in micrometres, exactly the configured axes.
        status : str
            The compensator's status for this sample (one line of text).

        Raises
        ------
        TargetError
            The target is not open, or the sample is refused; nothing of it is written.
        """
        if not self.is_open:
            state = "closed" if self.closed else "not opened"
            raise TargetError(f"write to a target that is {state}", target=self.name)
        time_s, values, status = self.check_sample(time_s, values_um, status)
        self._write(time_s, values, status)
        self.samples_written += 1

    def read_current_um(self) -> dict[str, float | None]:
        """The value each axis holds now, in micrometres (None: not known).

        The live loop starts from it and, after a lost connection, resumes from it, so that its
        first write is no step (``docs/deploy.md``, Transitions). Default: not known.
        """
        return {axis: None for axis in self.axes}

    def close(self) -> None:
        """Close the target; closing again (or a target never opened) does nothing."""
        if self.is_open:
            self.is_open = False
            self.closed = True
            self._close()

    def __enter__(self) -> Target:
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.close()
        return False

    # -- checks shared by every target ---------------------------------------------------
    def check_sample(self, time_s, values_um, status) -> tuple[float, dict[str, float], str]:
        """The sample as ``(time_s, {axis: value_um} in layout order, status)``, or TargetError."""
        if isinstance(time_s, bool) or not isinstance(time_s, (int, float)) or not math.isfinite(time_s):
            raise TargetError(f"sample time {time_s!r} is not a finite number of seconds", target=self.name)
        if not isinstance(values_um, Mapping):
            raise TargetError(
                f"values must map each axis {list(self.axes)} to micrometres, got {type(values_um).__name__}",
                target=self.name,
            )
        missing = [a for a in self.axes if a not in values_um]
        extra = sorted(str(a) for a in values_um if a not in self.axes)
        if missing or extra:
            raise TargetError(
                f"the sample's axes do not match the target's {list(self.axes)}: "
                f"missing {missing}, unknown {extra}",
                target=self.name,
            )
        values = {}
        for axis in self.axes:
            v = values_um[axis]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise TargetError(
                    f"value {v!r} um is not a finite number", target=self.name, axis=axis, value=v
                )
            values[axis] = float(v)
        if not isinstance(status, str) or "\n" in status or "\r" in status:
            raise TargetError(f"status {status!r} is not one line of text", target=self.name)
        self.check_values(values)
        return float(time_s), values, status

    def check_values(self, values_um: dict[str, float]) -> None:
        """Target-specific limits; raise TargetError to refuse. Default: none."""
        return None

    # -- what a subclass implements ------------------------------------------------------
    @abc.abstractmethod
    def _open(self) -> None: ...

    @abc.abstractmethod
    def _write(self, time_s: float, values_um: dict[str, float], status: str) -> None: ...

    @abc.abstractmethod
    def _close(self) -> None: ...
