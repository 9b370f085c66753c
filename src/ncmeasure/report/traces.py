"""The raw-data figures' data, bounded whatever the recording's length.

For every axis, the :class:`~ncmeasure.report.raw_svg.RawTrace` that
:func:`~ncmeasure.report.raw_svg.raw_trace` gives for a recording in memory,
from the rows chunk by chunk, keeping only what the figure shows: an
overview of the velocity over the axis' measurement (the lowest and highest
reading of each of :data:`~ncmeasure.report.raw_svg.OVERVIEW_BINS` equal
stretches of time, peaks kept) and the samples of the detailed stretch
(about ``stretch_s`` seconds).

Both follow the axis' windows, so the rows are looked at once the windows are
known. :class:`RawTraces` does it while the analysis reads the recording
(``analyze``'s ``on_windows``): every axis' trace is gathered on the
analysis' next reading of the file, and only the last axis' needs one more
reading, of its own channels. :func:`read_raw_traces` reads a recording on
its own: up to three passes over the file, all axes together (the times and,
for an axis without windows, the peak velocity; where such an axis moved;
then the overview and the stretch). Both give the same traces.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.streaming import Task, run_tasks
from ncmeasure.analysis.windows.watch import AxisWindows, NamedChunk, Watch
from ncmeasure.errors import RecordingError
from ncmeasure.recording import Recording, RecordingHead, iter_chunks
from ncmeasure.report.raw_svg import OVERVIEW_BINS, RawTrace, _stretch

__all__ = ["RawTraces", "read_raw_traces"]

FloatArray = NDArray[np.float64]
Feed = Callable[[NamedChunk], None]


@dataclass
class _Axis:
    """What the passes gather for one axis."""

    name: str
    windows: tuple[tuple[float, float], ...]
    command: bool
    peak: float = 0.0
    first_moving: float | None = None
    last_moving: float | None = None
    span: tuple[float, float] = (0.0, 0.0)
    stretch: tuple[float, float] = (0.0, 0.0)
    low: FloatArray = field(default_factory=lambda: np.full(OVERVIEW_BINS, math.inf))
    low_t: FloatArray = field(default_factory=lambda: np.zeros(OVERVIEW_BINS))
    high: FloatArray = field(default_factory=lambda: np.full(OVERVIEW_BINS, -math.inf))
    high_t: FloatArray = field(default_factory=lambda: np.zeros(OVERVIEW_BINS))
    parts: dict[str, list[FloatArray]] = field(default_factory=dict)

    @property
    def velocity(self) -> str:
        return f"{self.name}_velocity_mm_min"

    @property
    def channels(self) -> tuple[str, ...]:
        """The channels the figure shows: current, velocity, the command where recorded."""
        found = (f"{self.name}_current_a", self.velocity)
        return (*found, f"{self.name}_velocity_cmd_mm_min") if self.command else found


class RawTraces:
    """The raw-data figures' data, gathered while the analysis reads the recording::

        traces = RawTraces(head)
        windows: dict[str, list[tuple[float, float]]] = {}
        results = analyze(head, schedule=schedule, window_times=windows,
                          on_windows=traces.watch)
        write_report(results, "report.html", recording=head, windows=windows,
                     traces=traces.found)

    Args:
        recording: The recording the analysis reads.
        stretch_s: Length of the detailed stretch in seconds.

    Attributes:
        found: Per axis, its trace, once gathered.
    """

    def __init__(self, recording: Recording | RecordingHead, *, stretch_s: float = 30.0) -> None:
        self.channel_names = frozenset(recording.channel_names)
        self.stretch_s = stretch_s
        self.found: dict[str, RawTrace] = {}

    def watch(self, axis: AxisWindows) -> Watch | None:
        """``analyze``'s ``on_windows``: the task that gathers the axis' trace.

        None where the axis lacks its current or velocity (no figure to gather:
        :func:`~ncmeasure.report.write_report` says why).
        """
        name = axis.axis
        if not {f"{name}_current_a", f"{name}_velocity_mm_min"} <= self.channel_names:
            return None
        entry = _Axis(
            name,
            tuple(sorted((float(a), float(b)) for a, b in axis.windows)),
            f"{name}_velocity_cmd_mm_min" in self.channel_names,
        )
        if axis.rows == 0:
            self.found[name] = _empty_trace(entry, 0)
            return None
        extent = (axis.start_s, axis.end_s)
        task = _trace_task(entry, extent, axis.rows, self.stretch_s, peak=None)
        # With windows, only the rows of the span matter (the stretch lies in it).
        between = _span(entry, extent) if entry.windows else None
        return Watch(entry.channels, self._kept(entry, task), between)

    def _kept(self, entry: _Axis, task: Task[NamedChunk, RawTrace]) -> Task[NamedChunk, None]:
        self.found[entry.name] = yield from task


def read_raw_traces(
    head: RecordingHead,
    axes: Sequence[str],
    windows: Mapping[str, Sequence[tuple[float, float]]],
    *,
    stretch_s: float = 30.0,
    rows: int = 1 << 16,
) -> dict[str, RawTrace | RecordingError]:
    """The raw-data figure's data of every axis, read chunk by chunk.

    Args:
        head: The recording.
        axes: The axes.
        windows: Per axis, the windows the analysis used, (t_start, t_end) in s.
        stretch_s: Length of the detailed stretch in seconds.
        rows: Rows per chunk.

    Returns:
        Per axis its trace, or why it has none (no current or velocity channel).
    """
    names = set(head.channel_names)
    result: dict[str, RawTrace | RecordingError] = {}
    found: list[_Axis] = []
    for axis in axes:
        missing = [
            f"{axis}_{s}" for s in ("current_a", "velocity_mm_min") if f"{axis}_{s}" not in names
        ]
        if missing:
            result[axis] = RecordingError(
                f"{head.directory}: no channel {missing[0]!r} "
                f"(channels: {', '.join(head.channel_names)})"
            )
            continue
        cuts = tuple(sorted((float(a), float(b)) for a, b in windows.get(axis, ())))
        found.append(_Axis(axis, cuts, f"{axis}_velocity_cmd_mm_min" in names))
    channels = tuple(c for entry in found for c in entry.channels)
    column = {name: k for k, name in enumerate(channels)}
    verified: set[int] = set()

    def read() -> Iterator[NamedChunk]:
        for chunk in iter_chunks(head.directory, rows, channels, verified=verified):
            yield NamedChunk(chunk.first, chunk.time_s, chunk.values, column)

    # The first pass: the times, and the peak velocity of the axes without windows.
    total = 0
    first_t = last_t = math.nan
    for chunk in read():
        if len(chunk.time_s) == 0:
            continue
        if total == 0:
            first_t = float(chunk.time_s[0])
        last_t = float(chunk.time_s[-1])
        total += len(chunk.time_s)
        for entry in found:
            if not entry.windows:
                _peak(entry, chunk)
    if total == 0 or not found:
        for entry in found:
            result[entry.name] = _empty_trace(entry, total)
        return {axis: result[axis] for axis in axes if axis in result}
    tasks = {
        entry.name: _trace_task(entry, (first_t, last_t), total, stretch_s, peak=entry.peak)
        for entry in found
    }
    result.update(run_tasks(read, tasks))
    return {axis: result[axis] for axis in axes}


def _empty_trace(entry: _Axis, total: int) -> RawTrace:
    empty = np.empty(0, dtype=np.float64)
    nothing = (empty, empty, empty, empty, empty, None, total)
    return RawTrace(entry.name, entry.windows, (0.0, 0.0), (0.0, 0.0), *nothing)


def _peak(entry: _Axis, chunk: NamedChunk) -> None:
    speeds = np.abs(chunk.channel(entry.velocity))
    if np.isfinite(speeds).any():
        entry.peak = max(entry.peak, float(np.nanmax(speeds)))


def _trace_task(
    entry: _Axis,
    extent: tuple[float, float],
    total: int,
    stretch_s: float,
    *,
    peak: float | None,
) -> Task[NamedChunk, RawTrace]:
    """The passes of one axis' trace over all rows (one where the axis has windows).

    ``extent`` is the time of the recording's first and last row, ``total``
    its rows; ``peak`` the axis' peak speed where known (only an axis without
    windows needs it: a pass finds it where it is None).
    """
    if not entry.windows:
        if peak is None:
            yield lambda chunk: _peak(entry, chunk)
        else:
            entry.peak = peak
        if entry.peak > 0:
            yield lambda chunk: _moving(entry, chunk)
    entry.span = _span(entry, extent)
    entry.stretch = _stretch(entry.span, entry.windows, stretch_s)
    entry.parts = {"t": [], "i": [], "v": [], "cmd": []}
    yield lambda chunk: _gather(entry, chunk)
    return _trace(entry, total)


def _span(entry: _Axis, extent: tuple[float, float]) -> tuple[float, float]:
    """The overview's span: the windows with a margin, else where the axis moved."""
    first_t, last_t = extent
    if entry.windows:
        start = min(w[0] for w in entry.windows)
        end = max(w[1] for w in entry.windows)
        pad = 0.02 * max(end - start, 1.0)
        return max(first_t, start - pad), min(last_t, end + pad)
    if entry.first_moving is not None and entry.last_moving is not None:
        return entry.first_moving, entry.last_moving
    return first_t, last_t


def _moving(entry: _Axis, chunk: NamedChunk) -> None:
    """The first and last time the axis moved faster than 1 % of its peak."""
    above = np.flatnonzero(np.abs(chunk.channel(entry.velocity)) > 0.01 * entry.peak)
    if len(above):
        if entry.first_moving is None:
            entry.first_moving = float(chunk.time_s[above[0]])
        entry.last_moving = float(chunk.time_s[above[-1]])


def _gather(entry: _Axis, chunk: NamedChunk) -> None:
    """A chunk's share of the overview and of the stretch (which lies in the span)."""
    time_s = chunk.time_s
    if not len(time_s) or time_s.max() < entry.span[0] or time_s.min() > entry.span[1]:
        return  # no row of the chunk is in the span
    velocity = chunk.channel(entry.velocity)
    _overview(entry, time_s, velocity)
    start, end = entry.stretch
    part = (time_s >= start) & (time_s <= end)
    if part.any():
        entry.parts["t"].append(time_s[part])
        entry.parts["i"].append(chunk.channel(f"{entry.name}_current_a")[part])
        entry.parts["v"].append(velocity[part])
        if entry.command:
            entry.parts["cmd"].append(chunk.channel(f"{entry.name}_velocity_cmd_mm_min")[part])


def _trace(entry: _Axis, total: int) -> RawTrace:
    kept = entry.high >= entry.low
    pairs = np.column_stack([entry.low_t, entry.high_t])[kept]
    levels = np.column_stack([entry.low, entry.high])[kept]
    order = np.argsort(pairs, axis=1, kind="stable")
    overview_t = np.take_along_axis(pairs, order, axis=1).ravel()
    overview_v = np.take_along_axis(levels, order, axis=1).ravel()

    def joined(key: str) -> FloatArray:
        parts = entry.parts[key]
        return np.concatenate(parts) if parts else np.empty(0, dtype=np.float64)

    return RawTrace(
        entry.name,
        entry.windows,
        entry.span,
        entry.stretch,
        overview_t,
        overview_v,
        joined("t"),
        joined("i"),
        joined("v"),
        joined("cmd") if entry.command else None,
        total,
    )


def _overview(entry: _Axis, time_s: FloatArray, velocity: FloatArray) -> None:
    """The lowest and highest velocity (and their times) per bin of the axis' span.

    Where a bin's values come in several chunks, the first of equal extremes
    is kept, as ``argmin`` and ``argmax`` keep it within one.
    """
    low, high = entry.span
    inside = (time_s >= low) & (time_s <= high) & np.isfinite(velocity)
    if not inside.any():
        return
    times, values = time_s[inside], velocity[inside]
    width = (high - low) / OVERVIEW_BINS
    index = (
        np.minimum(((times - low) / width).astype(np.intp), OVERVIEW_BINS - 1)
        if width > 0
        else np.zeros(len(times), dtype=np.intp)
    )
    starts = np.flatnonzero(np.diff(index, prepend=-1))
    bins = index[starts]
    if np.any(np.diff(bins) <= 0):
        _overview_by_bin(entry, times, values, index, starts)
        return
    # Times rise, so each bin's rows are consecutive: all bins of the chunk at once.
    ends = np.append(starts[1:], len(values))
    for extreme, better, level, at in (
        (np.minimum, np.less, entry.low, entry.low_t),
        (np.maximum, np.greater, entry.high, entry.high_t),
    ):
        per_bin = extreme.reduceat(values, starts)
        hits = np.flatnonzero(values == np.repeat(per_bin, ends - starts))
        first = hits[np.searchsorted(hits, starts)]  # the first extreme of each bin
        new = better(values[first], level[bins])
        level[bins[new]] = values[first[new]]
        at[bins[new]] = times[first[new]]


def _overview_by_bin(
    entry: _Axis,
    times: FloatArray,
    values: FloatArray,
    index: NDArray[np.intp],
    starts: NDArray[np.intp],
) -> None:
    """:func:`_overview` bin by bin, for times that do not rise."""
    for begin, stop in zip(starts.tolist(), [*starts[1:].tolist(), len(index)], strict=True):
        k = int(index[begin])
        chunk = values[begin:stop]
        i_low, i_high = int(np.argmin(chunk)), int(np.argmax(chunk))
        if chunk[i_low] < entry.low[k]:
            entry.low[k], entry.low_t[k] = chunk[i_low], times[begin + i_low]
        if chunk[i_high] > entry.high[k]:
            entry.high[k], entry.high_t[k] = chunk[i_high], times[begin + i_high]
