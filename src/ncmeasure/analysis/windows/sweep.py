"""The pieces of a pass over a recording's rows, chunk by chunk, for the window finder.

:func:`cleaned_rows` turns the chunks of a pass into blocks of rows cleaned and
bridged as the whole signals would be (implausible values left out, gaps
bridged from the neighbours :mod:`~ncmeasure.analysis.windows.scan` noted, the
velocity derived from the position by central differences that look ``h``
rows ahead). :class:`Ahead` carries rows across chunk edges for filters that
look beyond them, :class:`Runs` joins runs of a mask given block by block, and
:class:`Keeper` keeps the samples of given stretches as a :class:`Sparse`,
which the finder reads like the whole array, by slices.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.scan import AxisStatistics, Rows, bridge_chunk
from ncmeasure.analysis.windows.signals import hole_rows, position_velocity, runs, segment_sums
from ncmeasure.recording import RowChunk

__all__ = [
    "Ahead",
    "Block",
    "Found",
    "Keeper",
    "Runs",
    "Sparse",
    "SweepState",
    "as_array",
    "cleaned_rows",
    "merged",
    "moving_runs",
]

FloatArray = NDArray[np.float64]
Columns = dict[str, FloatArray]
Block = tuple[int, int, Columns]
"""Rows ``lo`` .. ``hi`` of a recording: their columns, in rows lo..hi."""


class Sparse:
    """Stretches of one signal of a recording, read like the whole array by slices.

    ``values[a:b]`` gives the samples a..b when one stretch holds them all; a
    slice reaching outside the stretches is an error of the analysis, never
    a silent gap.
    """

    def __init__(self, rows: int, starts: Sequence[int], parts: Sequence[FloatArray]) -> None:
        self.rows = rows
        self.starts = list(starts)
        self.parts = list(parts)

    def __len__(self) -> int:
        return self.rows

    def __getitem__(self, index: slice) -> FloatArray:
        start = 0 if index.start is None else int(index.start)
        stop = self.rows if index.stop is None else int(index.stop)
        k = bisect.bisect_right(self.starts, start) - 1
        if k < 0 or stop - self.starts[k] > len(self.parts[k]) or index.step is not None:
            raise IndexError(f"rows {start}..{stop} are outside the slices kept")
        offset = self.starts[k]
        return self.parts[k][start - offset : stop - offset]

    @property
    def samples(self) -> int:
        """Samples held."""
        return sum(len(p) for p in self.parts)


def as_array(values: Sparse) -> FloatArray:
    """A :class:`Sparse` where the finder keeps its arrays.

    The finder reads them by slices of its candidates (with their margins)
    only, which a Sparse answers; what reads a whole signal is overridden in
    :class:`~ncmeasure.analysis.windows.chunked.ChunkedFinder`.
    """
    return cast("FloatArray", values)


class Ahead:
    """Columns of consecutive rows, kept ``left`` rows behind and ``right`` ahead.

    :meth:`push` appends a chunk's rows and says which rows are now complete:
    those with ``right`` rows after them, or every row once the last one
    (row ``n − 1``) is in. The buffer keeps ``left`` rows before them.
    """

    def __init__(self, left: int, right: int, n: int) -> None:
        self.left = left
        self.right = right
        self.n = n
        self.offset = 0
        self.done = 0
        self.columns: Columns = {}

    def push(self, columns: Columns) -> tuple[int, int] | None:
        if not self.columns:
            self.columns = dict(columns)
        else:
            self.columns = {k: np.concatenate((self.columns[k], columns[k])) for k in self.columns}
        held = len(next(iter(self.columns.values())))
        available = self.offset + held
        end = available if available >= self.n else available - self.right
        if end <= self.done:
            return None
        begin, self.done = self.done, end
        return begin, end

    def forget(self) -> None:
        """Drop the rows no later row needs."""
        keep = max(self.offset, self.done - self.left)
        cut = keep - self.offset
        if cut > 0:
            self.columns = {k: v[cut:] for k, v in self.columns.items()}
            self.offset = keep


@dataclass
class Runs:
    """Runs of a mask given block by block, in order."""

    open_start: int | None = None
    starts: list[int] = field(default_factory=list)
    stops: list[int] = field(default_factory=list)

    def add(self, mask: NDArray[np.bool_], lo: int, last: bool) -> None:
        starts, stops = runs(mask)
        starts = (starts + lo).tolist()
        stops = (stops + lo).tolist()
        hi = lo + len(mask)
        if self.open_start is not None:
            if starts and starts[0] == lo:
                starts[0] = self.open_start
            else:
                starts.insert(0, self.open_start)
                stops.insert(0, lo)
            self.open_start = None
        if stops and stops[-1] == hi and not last:
            self.open_start = starts.pop()
            stops.pop()
        self.starts.extend(starts)
        self.stops.extend(stops)


def merged(stretches: Iterable[tuple[int, int]]) -> list[tuple[int, int]]:
    """Stretches sorted, overlapping or touching ones joined."""
    merged: list[list[int]] = []
    for a, b in sorted(stretches):
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return [(a, b) for a, b in merged]


class Keeper:
    """The samples of one signal inside given stretches, from blocks of rows in order."""

    def __init__(self, stretches: Sequence[tuple[int, int]]) -> None:
        self.stretches = stretches
        self.starts = [a for a, _ in stretches]
        self.pieces: list[list[FloatArray]] = [[] for _ in stretches]

    def add(self, lo: int, hi: int, values: FloatArray) -> None:
        k = max(0, bisect.bisect_right(self.starts, lo) - 1)
        while k < len(self.stretches) and self.stretches[k][0] < hi:
            a, b = self.stretches[k]
            if b > lo:
                self.pieces[k].append(values[max(a, lo) - lo : min(b, hi) - lo].copy())
            k += 1

    def sparse(self, rows: int) -> Sparse:
        parts = [
            np.concatenate(p) if len(p) > 1 else (p[0] if p else np.empty(0, dtype=np.float64))
            for p in self.pieces
        ]
        self.pieces = []
        return Sparse(rows, self.starts, parts)


def moving_runs(forward: Runs, backward: Runs, least: int) -> list[tuple[int, int]]:
    """The runs of both directions that hold ``least`` rows, in order."""
    both = zip(forward.starts + backward.starts, forward.stops + backward.stops, strict=True)
    return sorted((a, b) for a, b in both if b - a >= least)


@dataclass
class Found:
    """What the pass over the rows found for one axis."""

    marker_starts: list[int] = field(default_factory=list)
    marker_stops: list[int] = field(default_factory=list)
    marker_values: list[float] = field(default_factory=list)
    command: list[tuple[int, int, float]] = field(default_factory=list)
    plateaus: list[tuple[int, int]] = field(default_factory=list)
    moving: list[tuple[int, int]] = field(default_factory=list)
    """Runs of one direction above standstill, of a plateau's length at least, in order."""
    longest_moving: int = 0
    plateaus_swept: bool = False


@dataclass
class SweepState:
    """What the pass over the rows carries from one block of rows to the next."""

    plateaus: Ahead
    want_plateaus: bool
    want_still: bool
    plateau_runs: Runs = field(default_factory=Runs)
    forward: Runs = field(default_factory=Runs)
    """Runs of the smoothed velocity above standstill, positive."""
    backward: Runs = field(default_factory=Runs)
    """Runs of the smoothed velocity below minus standstill."""
    marker_on: bool = False
    marker_value: float = math.nan
    command_last: float | None = None
    command_begin: int | None = None
    command_level: float = math.nan
    moving_open: int = 0
    moving_best: int = 0


def cleaned_rows(
    axis: str,
    statistics: AxisStatistics,
    source: Rows,
    has: Mapping[str, bool],
    *,
    positions_known: bool,
    dt: float,
    h: int,
    derived: bool,
    holes: list[int] | None = None,
) -> Callable[[RowChunk], list[Block]]:
    """For one pass: a chunk's rows -> the blocks of rows now complete.

    The columns t, v, x, and where recorded (``has``) cmd, marker, i, and with
    ``derived`` vd (the velocity the windows are found by): the position's
    central differences need ``h`` rows ahead, so blocks lag by ``h`` rows.
    Without a usable position, x is the integrated velocity, relative to the start
    of its segment: the sum starts again after every hole of the time axis
    (:func:`~ncmeasure.analysis.windows.signals.hole_rows`), where the axis may
    have moved any distance. ``holes``, where given, gets the rows that follow a hole.
    """
    stats = statistics
    n = stats.rows
    scale = dt / 60.0
    carry = {"x": 0.0}
    times_before: list[float] = []
    ahead = Ahead(h, h, n)

    def cleaned(chunk: RowChunk, signal: str) -> FloatArray:
        return source.clean(chunk, f"{axis}_{signal}")

    def bridged(chunk: RowChunk, signal: str, index: int) -> FloatArray:
        before, after = stats.neighbours[signal]
        return bridge_chunk(cleaned(chunk, signal), chunk.time_s, before[index], after[index])

    def held(chunk: RowChunk, index: int) -> FloatArray:
        values = cleaned(chunk, "velocity_cmd_mm_min")
        bad = ~np.isfinite(values)
        if not bad.any() or stats.finite.get("velocity_cmd_mm_min", 0) == 0:
            return values
        before, after = stats.neighbours["velocity_cmd_mm_min"]
        good = np.flatnonzero(~bad)
        previous = before[index]
        if previous is not None:
            fallback = previous[1]
        elif len(good):
            fallback = float(values[good[0]])
        else:
            following = after[index]
            assert following is not None
            fallback = following[1]
        last = np.maximum.accumulate(np.where(bad, -1, np.arange(len(values))))
        return np.where(last >= 0, values[np.maximum(last, 0)], fallback)

    def rows(chunk: RowChunk) -> list[Block]:
        index = chunk.first // stats.chunk_rows
        columns: Columns = {"t": chunk.time_s}
        columns["v"] = bridged(chunk, "velocity_mm_min", index)
        after = hole_rows(chunk.time_s, dt, times_before)
        times_before[:] = [*times_before, *chunk.time_s[-2:].tolist()][-2:]
        if holes is not None:
            holes.extend((after + chunk.first).tolist())
        if positions_known:
            columns["x"] = bridged(chunk, "position_mm", index)
        else:
            filled = np.where(np.isfinite(columns["v"]), columns["v"], 0.0)
            summed, carry["x"] = segment_sums(filled, after, carry["x"])
            columns["x"] = summed * scale
        if has["velocity_cmd_mm_min"]:
            columns["cmd"] = held(chunk, index)
        if has["marker"]:
            columns["marker"] = cleaned(chunk, "marker")
        if has["current_a"]:
            columns["i"] = cleaned(chunk, "current_a")
        span = ahead.push(columns)
        if span is None:
            return []
        lo, hi = span
        offset = ahead.offset
        part = {k: v[lo - offset : hi - offset] for k, v in ahead.columns.items()}
        if derived:
            if h:
                part["vd"] = position_velocity(
                    ahead.columns["t"], ahead.columns["x"], h, lo, hi, offset, n
                )
            else:
                part["vd"] = part["v"]
        ahead.forget()
        return [(lo, hi, part)]

    return rows
