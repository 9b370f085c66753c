"""The sample vocabulary every stage speaks, and the clocks (the bottom layer).

A drive link, an importer or a synthetic recording hands out
:class:`SampleBlock` objects: rows of samples, one timestamp per row, one
column per :class:`Channel` (``X_current_a``, ``X_velocity_mm_min``, ...), all
in ncmeasure's units (A, mm/min, mm, see :data:`SIGNAL_UNITS`). Things that
happen on the way (missing cycles, drive faults, reboots, reconnects) are
:class:`LinkEvent` objects. Recordings store both; the analysis reads them.

Time stamps are seconds on a :class:`LinkClock`: real time for real drives, or
the clock of a virtual machine (:mod:`ncmeasure.sim`).

Nothing here imports another part of ncmeasure: links, recordings, importers,
the simulator and the analysis all build on this module.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "REAL_TIME",
    "REQUIRED_SIGNALS",
    "SIGNAL_UNITS",
    "Channel",
    "EventKind",
    "LinkClock",
    "LinkEvent",
    "SampleBlock",
    "Signal",
    "channels_for",
]

Signal = Literal["current_a", "velocity_mm_min", "position_mm", "velocity_cmd_mm_min", "marker"]

#: The signals a link may deliver per axis, with their units. The first three
#: are what the friction analysis needs; the others are read where available.
SIGNAL_UNITS: Mapping[str, str] = {
    "current_a": "A",
    "velocity_mm_min": "mm/min",
    "position_mm": "mm",
    "velocity_cmd_mm_min": "mm/min",
    "marker": "1",
}
REQUIRED_SIGNALS: tuple[str, ...] = ("current_a", "velocity_mm_min", "position_mm")


@dataclass(frozen=True)
class Channel:
    """One recorded column: an axis' signal in its unit."""

    axis: str
    signal: str
    unit: str

    @property
    def name(self) -> str:
        """Column name, e.g. ``X_current_a``."""
        return f"{self.axis}_{self.signal}"


def channels_for(
    axes: Sequence[str], signals: Sequence[str] = REQUIRED_SIGNALS
) -> tuple[Channel, ...]:
    """Channels for ``signals`` of every axis, axis by axis."""
    return tuple(Channel(a, s, SIGNAL_UNITS[s]) for a in axes for s in signals)


@dataclass(frozen=True)
class SampleBlock:
    """Rows of samples: ``time_s`` (n,) and ``values`` (n, channels), float64.

    ``time_s`` is seconds since the link was opened, on the link's clock
    (SYNC count × period for CANopen, response time for Modbus, recorded time
    for replay; machine time when the link runs on a :class:`LinkClock` faster
    than real time); it increases strictly within a block.
    """

    time_s: NDArray[np.float64]
    values: NDArray[np.float64]

    def __post_init__(self) -> None:
        if self.time_s.ndim != 1 or self.values.ndim != 2:
            raise ValueError("time_s must be 1-D and values 2-D")
        if self.values.shape[0] != self.time_s.shape[0]:
            raise ValueError("time_s and values differ in length")

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @classmethod
    def from_rows(
        cls, time_s: Sequence[float], rows: Sequence[Sequence[float]], channels: int
    ) -> SampleBlock:
        """Build a block from Python lists (an empty block when there are no rows)."""
        values = np.asarray(rows, dtype=np.float64).reshape(len(time_s), channels)
        return cls(np.asarray(time_s, dtype=np.float64), values)


class LinkClock:
    """The clock a link paces itself by and time-stamps with.

    Real time (speed 1) for real drives. A virtual machine may run faster than
    real time: speed 4 means 4 s of this clock pass per wall-clock second.
    The clock holds only its speed, so it pickles into another process, and
    :meth:`now` has the same epoch in every process (``time.perf_counter``,
    the system's monotonic clock on Linux): a simulated drive in a server
    process and the link reading it agree on the time.

    Args:
        speed: Seconds of this clock per wall-clock second; finite and positive.

    Raises:
        ValueError: ``speed`` is not a finite positive number.
    """

    __slots__ = ("_speed",)

    def __init__(self, speed: float = 1.0) -> None:
        speed = float(speed)
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"a clock speed must be finite and positive, not {speed!r}")
        self._speed = speed

    @property
    def speed(self) -> float:
        """Seconds of this clock per wall-clock second."""
        return self._speed

    @property
    def real_time(self) -> bool:
        """True for speed 1."""
        return self._speed == 1.0

    def now(self) -> float:
        """The time on this clock in seconds (monotonic; only differences mean anything)."""
        return time.perf_counter() * self._speed

    def sleep(self, seconds: float) -> None:
        """Sleep ``seconds`` of this clock (``seconds / speed`` of wall-clock time)."""
        if seconds > 0:
            time.sleep(seconds / self._speed)

    def wall(self, seconds: float) -> float:
        """``seconds`` of this clock in wall-clock seconds."""
        return seconds / self._speed

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LinkClock):
            return NotImplemented
        return self._speed == other._speed

    def __hash__(self) -> int:
        return hash(self._speed)

    def __repr__(self) -> str:
        return f"LinkClock(speed={self._speed:g})"


#: The clock of real drives: wall-clock time.
REAL_TIME: LinkClock = LinkClock()


EventKind = Literal["gap", "fault", "emcy", "reboot", "reconnect", "info"]


@dataclass(frozen=True)
class LinkEvent:
    """Something that happened on the link, in link time."""

    time_s: float
    kind: EventKind
    message: str
    axis: str | None = None
    lost_samples: int = 0
    """Samples (rows) that are missing because of this event, where known."""
    details: Mapping[str, Any] = field(default_factory=dict)
