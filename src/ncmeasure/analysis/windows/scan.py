"""The whole-signal statistics of an axis, read from a recording chunk by chunk.

The first pass of an analysis whose memory does not grow with the recording:
everything :mod:`~ncmeasure.analysis.windows.finder` and
:mod:`~ncmeasure.analysis.analyze` derive from a whole signal before they
look for windows (the median sample period, the count of the velocity,
position and current signals, the noise of velocity and position, how many
values are missing or implausible), computed from the chunks of a reading
(:class:`Rows`: a file read by :func:`~ncmeasure.recording.iter_chunks`, or a
recording in memory as one chunk) with :mod:`~ncmeasure.analysis.windows.streaming`,
and equal, bit for bit, to what numpy gives on the whole arrays:

* implausible values (:mod:`ncmeasure.validity`) become NaN first;
* a channel's missing values are bridged (linear in time between the
  neighbouring values, the nearest value at the ends); a first pass notes the
  first and last finite value of every chunk, so a later pass bridges a gap
  across chunk boundaries without reading ahead;
* the position is used only where at least half of its rows hold a value.

Memory is a chunk plus a few numbers per chunk, whatever the length.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.streaming import (
    differences,
    median_task,
    noise_sigma_task,
    quantum_task,
    run_tasks,
)
from ncmeasure.recording import RowChunk
from ncmeasure.validity import Implausible, implausible

__all__ = [
    "Along",
    "AxisStatistics",
    "Rows",
    "axes_statistics",
    "axes_statistics_along",
    "bridge_chunk",
]

FloatArray = NDArray[np.float64]
Good = tuple[float, float]  # (time, value) of a finite sample
_SCANNED = ("velocity_cmd_mm_min", "marker")
"""Signals only cleaned and counted in the first pass (no statistics of their own)."""
View = Callable[[], Callable[[RowChunk], FloatArray]]
Task = Generator[Callable[[RowChunk], None], None, float]


@dataclass(frozen=True)
class Rows:
    """A recording's rows as the passes of the analysis read them.

    Attributes:
        read: Returns a fresh reading of the rows: chunks in order, each of
            ``chunk_rows`` rows but the last, every time the same.
        column: The column of every channel in the chunks' values, by name.
        chunk_rows: Rows per chunk (the neighbours of a gap are noted per chunk).
        limits: The implausibility bound per channel name
            (:meth:`~ncmeasure.validity.Implausible.for_channels`); codes only
            for a channel without one.
        checked: False: every value is taken as it is, none left out as
            implausible (the windows of given arrays).
    """

    read: Callable[[], Iterator[RowChunk]]
    column: Mapping[str, int]
    chunk_rows: int
    limits: Mapping[str, float | None] = field(default_factory=dict)
    checked: bool = True
    kept: bool = False
    _cleaned: dict[str, tuple[RowChunk, FloatArray]] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )
    _every: dict[tuple[str, int], tuple[RowChunk, FloatArray]] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )
    _plain: set[tuple[str, int, int]] = field(
        default_factory=set, init=False, repr=False, compare=False
    )

    def clean(self, chunk: RowChunk, name: str) -> FloatArray:
        """A channel's values in a chunk, the implausible ones NaN (where checked).

        Every task of a pass looks at the same chunk, and a recording in memory
        is the same chunk on every pass: a channel's last chunk is cleaned
        once (the arrays returned are never written to). Where the reading's
        chunks are ``kept`` (the same chunks on every pass), every chunk's
        channel is cleaned once for all passes: a view of the chunk's column
        where nothing was left out, so that costs no memory. A chunk the first
        pass found nothing to leave out in (:meth:`note_plain`) is not checked
        again on a later reading.
        """
        held = self._cleaned.get(name)
        if held is not None and held[0] is chunk:
            return held[1]
        if self.kept:
            known = self._every.get((name, chunk.first))
            if known is not None and known[0] is chunk:
                return known[1]
        values = chunk.values[:, self.column[name]]
        if self.checked and (name, chunk.first, len(chunk.time_s)) not in self._plain:
            bad = implausible(values, self.limits.get(name))
            if bad.any():
                values = values.copy()
                values[bad] = np.nan
        cleaned = np.ascontiguousarray(values, dtype=np.float64)
        self._cleaned[name] = (chunk, cleaned)
        if self.kept:
            self._every[name, chunk.first] = (chunk, cleaned)
        return cleaned

    def note_plain(self, chunk: RowChunk, name: str) -> None:
        """The chunk's channel holds no implausible value: a later reading takes it as it is."""
        self._plain.add((name, chunk.first, len(chunk.time_s)))

    def forget(self) -> None:
        """Let go of the channels cleaned for every chunk (the passes are done)."""
        self._every.clear()
        self._cleaned.clear()
        self._plain.clear()


@dataclass
class AxisStatistics:
    """The whole-signal statistics of one axis (see the module docstring).

    Attributes:
        rows: Rows of the recording.
        sample_period_s: Median time step (NaN under 2 rows).
        velocity_quantum_mm_min: One count of the (bridged) velocity, 0 if continuous.
        position_quantum_mm: One count of the (bridged) position; 0 without a usable one.
        current_quantum_a: One count of the current (0 without a current channel).
        velocity_sigma_mm_min: Noise of the bridged velocity (second differences).
        position_sigma_mm: Noise of the bridged position (0 without a usable one).
        position_usable: A position channel holding a value in at least half of the rows.
        velocity_bridged: Velocity values without a value, bridged (0 if none at all).
        finite: Finite values per signal, after the implausible ones are left out.
        low: Smallest finite value per signal.
        high: Largest finite value per signal.
        implausible: The checker with the counts of the values left out.
        chunk_rows: Rows per chunk of the reading (the neighbours are per chunk).
        neighbours: Per signal and chunk, the last finite (time, value) before the
            chunk and the first one after it: :func:`bridge_chunk` bridges a chunk's
            gaps with them as the whole-array bridge does.
        start_s: Time of the first row (NaN without rows).
        end_s: Time of the last row (NaN without rows).
    """

    rows: int
    sample_period_s: float
    velocity_quantum_mm_min: float
    position_quantum_mm: float
    current_quantum_a: float
    velocity_sigma_mm_min: float
    position_sigma_mm: float
    position_usable: bool
    velocity_bridged: int
    finite: dict[str, int] = field(default_factory=dict)
    low: dict[str, float] = field(default_factory=dict)
    high: dict[str, float] = field(default_factory=dict)
    implausible: Implausible | None = None
    chunk_rows: int = 0
    neighbours: dict[str, tuple[list[Good | None], list[Good | None]]] = field(default_factory=dict)
    start_s: float = math.nan
    end_s: float = math.nan


def bridge_chunk(
    values: FloatArray, time_s: FloatArray, previous: Good | None, following: Good | None
) -> FloatArray:
    """A chunk's NaN values bridged linearly in time, as the whole-array bridge does.

    ``previous`` and ``following`` are the last finite sample before the chunk
    and the first after it (:attr:`AxisStatistics.neighbours`); a channel
    without any finite value stays NaN.
    """
    bad = ~np.isfinite(values)
    if not bad.any():
        return values
    good = ~bad
    xp = [time_s[good]]
    fp = [values[good]]
    if previous is not None:
        xp.insert(0, np.array([previous[0]]))
        fp.insert(0, np.array([previous[1]]))
    if following is not None:
        xp.append(np.array([following[0]]))
        fp.append(np.array([following[1]]))
    if sum(len(x) for x in xp) == 0:
        return values
    filled = values.copy()
    filled[bad] = np.interp(time_s[bad], np.concatenate(xp), np.concatenate(fp))
    return filled


@dataclass
class _Scan:
    """The first pass: rows, finite counts, ranges and each chunk's first and last good."""

    channels: tuple[str, ...]
    rows: int = 0
    chunks: int = 0
    start_s: float = math.nan
    end_s: float = math.nan
    finite: dict[str, int] = field(default_factory=dict)
    low: dict[str, float] = field(default_factory=dict)
    high: dict[str, float] = field(default_factory=dict)
    first_good: dict[str, list[Good | None]] = field(default_factory=dict)
    last_good: dict[str, list[Good | None]] = field(default_factory=dict)

    def neighbours(self, name: str) -> tuple[list[Good | None], list[Good | None]]:
        """Per chunk, the last good before it and the first good after it."""
        before: list[Good | None] = []
        carried: Good | None = None
        for last in self.last_good[name]:
            before.append(carried)
            carried = last if last is not None else carried
        after: list[Good | None] = [None] * self.chunks
        carried = None
        for index in range(self.chunks - 1, -1, -1):
            after[index] = carried
            first = self.first_good[name][index]
            carried = first if first is not None else carried
        return before, after


def _signals(axes: Sequence[str], present: set[str]) -> dict[str, tuple[str, ...]]:
    """The signals of every axis that the statistics look at (velocity always)."""
    return {
        axis: tuple(
            s
            for s in ("velocity_mm_min", "position_mm", "current_a", *_SCANNED)
            if s == "velocity_mm_min" or f"{axis}_{s}" in present
        )
        for axis in axes
    }


def _scan_task(
    scan: _Scan, checkers: Mapping[str, Implausible], source: Rows
) -> Generator[Callable[[RowChunk], None], None, None]:
    """The first pass: rows, times, finite counts, ranges, each chunk's first and last good."""
    owner = {name: axis for axis, checker in checkers.items() for name in checker.limits}

    def add(chunk: RowChunk) -> None:
        if len(chunk.time_s):
            if scan.rows == 0:
                scan.start_s = float(chunk.time_s[0])
            scan.end_s = float(chunk.time_s[-1])
        scan.rows += len(chunk.time_s)
        scan.chunks += 1
        for name in scan.channels:
            values = chunk.values[:, source.column[name]]
            if source.checked:
                column = values
                values = checkers[owner[name]].clean(name, chunk.time_s, values)
                if values is column:
                    source.note_plain(chunk, name)
            good = np.flatnonzero(np.isfinite(values))
            scan.finite[name] += len(good)
            if len(good):
                kept = values[good]
                scan.low[name] = min(scan.low[name], float(kept.min()))
                scan.high[name] = max(scan.high[name], float(kept.max()))
                first, last = int(good[0]), int(good[-1])
                scan.first_good[name].append((float(chunk.time_s[first]), float(values[first])))
                scan.last_good[name].append((float(chunk.time_s[last]), float(values[last])))
            else:
                scan.first_good[name].append(None)
                scan.last_good[name].append(None)

    yield add


def _finite(values: FloatArray) -> FloatArray:
    """The finite values (the array itself where all are: no copy)."""
    finite = np.isfinite(values)
    return values if finite.all() else values[finite]


def _bridged(scan: _Scan, source: Rows, name: str) -> View:
    """The channel's finite values after bridging its gaps (then the finite ones)."""
    before, after = scan.neighbours(name)

    def make() -> Callable[[RowChunk], FloatArray]:
        def apply(chunk: RowChunk) -> FloatArray:
            index = chunk.first // source.chunk_rows
            values = source.clean(chunk, name)
            values = bridge_chunk(values, chunk.time_s, before[index], after[index])
            return _finite(values)

        return apply

    return make


def _cleaned(source: Rows, name: str) -> View:
    """The channel's finite values, the implausible ones left out."""

    def make() -> Callable[[RowChunk], FloatArray]:
        def apply(chunk: RowChunk) -> FloatArray:
            values = source.clean(chunk, name)
            return _finite(values)

        return apply

    return make


def _times() -> Callable[[RowChunk], FloatArray]:
    return lambda chunk: chunk.time_s


def _statistic_tasks(
    scan: _Scan, source: Rows, axes: Sequence[str]
) -> tuple[dict[tuple[str, str], Task], dict[str, bool]]:
    """The tasks of the later passes (sample period, counts, noise); which position is usable."""
    tasks: dict[tuple[str, str], Task] = {("", "dt"): median_task(differences(_times))}
    usable: dict[str, bool] = {}
    for axis in axes:
        velocity, position, current = (
            f"{axis}_velocity_mm_min",
            f"{axis}_position_mm",
            f"{axis}_current_a",
        )
        tasks[axis, "v_quantum"] = quantum_task(_bridged(scan, source, velocity))
        tasks[axis, "v_sigma"] = noise_sigma_task(_bridged(scan, source, velocity))
        usable[axis] = position in scan.channels and scan.finite[position] >= 0.5 * scan.rows
        if usable[axis]:
            tasks[axis, "x_quantum"] = quantum_task(_bridged(scan, source, position))
            tasks[axis, "x_sigma"] = noise_sigma_task(_bridged(scan, source, position))
        if current in scan.channels:
            tasks[axis, "i_quantum"] = quantum_task(_cleaned(source, current))
    return tasks, usable


Along = Callable[
    [Mapping[str, "AxisStatistics"], Callable[[], float | None]],
    Mapping[str, Generator[Callable[[RowChunk], None], None, Any]],
]
"""Tasks that ride the statistics' passes: made from what the first pass found (every
statistic NaN or 0 but the rows, ranges, counts, neighbours and whether the position
is usable) and a getter of the median sample period (None until it is known)."""


def axes_statistics(source: Rows, axes: Sequence[str]) -> dict[str, AxisStatistics]:
    """The whole-signal statistics of every axis of ``axes``, read chunk by chunk.

    All axes share every reading of the rows: a few passes in all, whatever
    the number of axes.

    Args:
        source: The rows; the ``velocity_mm_min`` channel of each axis must be
            among its columns.
        axes: The axes.
    """
    return axes_statistics_along(source, axes, None)[0]


def axes_statistics_along(
    source: Rows, axes: Sequence[str], along: Along | None
) -> tuple[dict[str, AxisStatistics], dict[str, Any]]:
    """:func:`axes_statistics`, and the values of the tasks ``along`` makes, which ride
    the readings of the statistics after the first (more readings only where they need
    them)."""
    signals = _signals(axes, set(source.column))
    channels = tuple(f"{axis}_{s}" for axis in axes for s in signals[axis])
    checkers = {
        axis: Implausible({f"{axis}_{s}": source.limits.get(f"{axis}_{s}") for s in signals[axis]})
        for axis in axes
    }
    scan = _Scan(channels)
    for name in channels:
        scan.finite[name] = 0
        scan.low[name] = math.inf
        scan.high[name] = -math.inf
        scan.first_good[name] = []
        scan.last_good[name] = []
    run_tasks(source.read, {"scan": _scan_task(scan, checkers, source)})
    tasks, usable = _statistic_tasks(scan, source, axes)
    first: dict[str, AxisStatistics] = {}
    for axis in axes:
        missing = scan.rows - scan.finite[f"{axis}_velocity_mm_min"]
        mine = [f"{axis}_{s}" for s in signals[axis]]
        first[axis] = AxisStatistics(
            rows=scan.rows,
            sample_period_s=math.nan,
            velocity_quantum_mm_min=0.0,
            position_quantum_mm=0.0,
            current_quantum_a=0.0,
            velocity_sigma_mm_min=math.nan,
            position_sigma_mm=0.0,
            position_usable=usable[axis],
            velocity_bridged=missing if missing < scan.rows else 0,
            finite={n.removeprefix(f"{axis}_"): scan.finite[n] for n in mine},
            low={n.removeprefix(f"{axis}_"): scan.low[n] for n in mine},
            high={n.removeprefix(f"{axis}_"): scan.high[n] for n in mine},
            implausible=checkers[axis],
            chunk_rows=source.chunk_rows,
            neighbours={n.removeprefix(f"{axis}_"): scan.neighbours(n) for n in mine},
            start_s=scan.start_s,
            end_s=scan.end_s,
        )
    period: list[float] = []
    tasks["", "dt"] = _noted(tasks["", "dt"], period)
    riding: dict[str, Generator[Callable[[RowChunk], None], None, Any]] = {}
    if along is not None:
        # After the statistics' tasks: each pass advances them first, so a rider sees
        # the sample period as soon as its median is known.
        riding = dict(along(first, lambda: period[0] if period else None))
    everything: dict[tuple[str, str], Task | Generator[Callable[[RowChunk], None], None, Any]]
    everything = {**tasks, **{("along", key): task for key, task in riding.items()}}
    found = run_tasks(source.read, everything)
    result = {
        axis: replace(
            first[axis],
            sample_period_s=found["", "dt"],
            velocity_quantum_mm_min=found[axis, "v_quantum"],
            position_quantum_mm=found.get((axis, "x_quantum"), 0.0),
            current_quantum_a=found.get((axis, "i_quantum"), 0.0),
            velocity_sigma_mm_min=found[axis, "v_sigma"],
            position_sigma_mm=found.get((axis, "x_sigma"), 0.0),
        )
        for axis in axes
    }
    return result, {key: found["along", key] for key in riding}


def _noted(task: Task, into: list[float]) -> Task:
    """The task, its value also appended to ``into`` as soon as it is known."""
    value = yield from task
    into.append(value)
    return value
