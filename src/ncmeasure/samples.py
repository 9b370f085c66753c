"""The sample vocabulary every stage speaks, and the clocks (the bottom layer).

A drive link, an importer or a synthetic recording hands out
:class:`SampleBlock` objects: rows of samples, one timestamp per row, one
column per :class:`Channel` (``X_current_a``, ``X_velocity_mm_min``, ...), all
in ncmeasure's units (A, mm/min, mm, see :data:`SIGNAL_UNITS`). Things that
happen on the way (missing cycles, drive faults, reboots, reconnects) are
:class:`LinkEvent` objects. Recordings store both; the analysis reads them.

Time stamps are seconds on a :class:`LinkClock`: real time for real drives, or a
:class:`SimulatedClock` that the link advances cycle by cycle when it talks to
ncmeasure's own simulator (:mod:`ncmeasure.sim`).

Nothing here imports another part of ncmeasure: links, recordings, importers,
the simulator and the analysis all build on this module.
"""

from __future__ import annotations

import threading
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
    "SimulatedClock",
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
    """The clock a link paces itself by and time-stamps with: real time.

    Real drives sample on the wall clock; a link talking to them keeps their
    time with :meth:`now` (``time.perf_counter``, the system's monotonic clock,
    the same epoch in every process) and waits with :meth:`sleep`.
    :class:`SimulatedClock` is the other kind: the time of a simulation that
    advances cycle by cycle, as fast as the computer allows.
    """

    __slots__ = ()

    @property
    def real_time(self) -> bool:
        """True: this clock is the wall clock."""
        return True

    @property
    def lockstep(self) -> bool:
        """True for a :class:`SimulatedClock`: link and simulator take turns, cycle by cycle."""
        return False

    def now(self) -> float:
        """The time on this clock in seconds (monotonic; only differences mean anything)."""
        return time.perf_counter()

    def sleep(self, seconds: float) -> None:
        """Sleep ``seconds`` of this clock."""
        if seconds > 0:
            time.sleep(seconds)

    def wall(self, seconds: float) -> float:
        """``seconds`` of this clock in wall-clock seconds (how long to wait for them)."""
        return seconds

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LinkClock):
            return NotImplemented
        return type(self) is type(other) and (type(self) is LinkClock or self is other)

    def __hash__(self) -> int:
        return hash(type(self)) if type(self) is LinkClock else id(self)

    def __repr__(self) -> str:
        return "LinkClock()"


#: The clock of real drives: wall-clock time.
REAL_TIME: LinkClock = LinkClock()


class SimulatedClock(LinkClock):
    """Simulated time, advanced by the link cycle by cycle: link and simulator in lockstep.

    Where ncmeasure talks to its own simulator (simulated CiA 402 drives on a
    virtual CAN bus, a simulated Modbus drive on 127.0.0.1, the demo, the
    tests), the link sets the time of every cycle with :meth:`advance_to`
    before it asks for the cycle, and the simulator answers with the state of
    the machine at that time. Nothing waits for the wall clock: cycle ``k`` is
    the machine state at ``k × period`` however slow or busy the computer is,
    and the same seed gives the same recording on an idle and a loaded machine.

    The time lives in shared memory, so a simulator in another process (the
    Modbus server of :func:`ncmeasure.sim.modbus_drive.running_server`) reads
    it too. A simulator in the same process (the CAN bus of python-can's
    ``virtual`` interface is one process) also reports each step done
    (:meth:`step_done`), and the link waits for it (:meth:`wait_step`) before
    it starts the next cycle. A simulator that leaves a request unanswered on
    purpose (a silent drive) says so (:meth:`leave_unanswered`, shared memory
    too): the link then stops waiting for that answer at once, so a time-out
    is the simulator's word, not a wall-clock wait that a busy computer could
    run out while a good answer is on its way.
    """

    __slots__ = ("_cond", "_done", "_sent", "_time", "_unanswered")

    def __init__(self) -> None:
        import multiprocessing

        context = multiprocessing.get_context("spawn")
        # A shared double: written by the link, read by a simulator process.
        self._time: Any = context.Value("d", 0.0, lock=False)
        # A shared count: written by the simulator (one writer), read by the link.
        self._unanswered: Any = context.Value("q", 0, lock=False)
        self._cond = threading.Condition()
        self._done = -1
        self._sent = 0

    @property
    def real_time(self) -> bool:
        """False: the time of a simulation."""
        return False

    @property
    def lockstep(self) -> bool:
        """True: link and simulator take turns, cycle by cycle."""
        return True

    def now(self) -> float:
        """The simulated time in seconds: what the link last set with :meth:`advance_to`."""
        return float(self._time.value)

    def advance_to(self, time_s: float) -> None:
        """Set the simulated time (the link does, before it asks for a cycle)."""
        self._time.value = float(time_s)

    def sleep(self, seconds: float) -> None:
        """Return at once: simulated time does not pass by waiting."""

    def wall(self, seconds: float) -> float:
        """0: nothing waits for simulated time."""
        return 0.0

    def step_done(self, step: int, frames_sent: int) -> None:
        """The simulator has answered step ``step`` and sent ``frames_sent`` frames in all."""
        with self._cond:
            self._done = max(self._done, step)
            self._sent = frames_sent
            self._cond.notify_all()

    def wait_step(self, step: int, timeout_s: float) -> int | None:
        """Wait until the simulator has answered ``step``; its frame count, or None on timeout.

        The timeout only guards against a simulator that is not there: it is not
        part of the simulation.
        """
        with self._cond:
            if not self._cond.wait_for(lambda: self._done >= step, timeout_s):
                return None
            return self._sent

    def leave_unanswered(self) -> None:
        """The simulator will not answer the request it has now (a silent drive).

        A link waiting for that answer in lockstep sees :meth:`unanswered` grow and
        stops waiting: the request timed out in simulated time.
        """
        self._unanswered.value += 1

    def unanswered(self) -> int:
        """How many requests the simulator has left unanswered on purpose so far."""
        return int(self._unanswered.value)

    def __getstate__(self) -> dict[str, Any]:
        return {"time": self._time, "unanswered": self._unanswered}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self._time = state["time"]
        self._unanswered = state["unanswered"]
        self._cond = threading.Condition()
        self._done = -1
        self._sent = 0

    def __repr__(self) -> str:
        return f"SimulatedClock(now={self.now():g} s)"


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
