"""The friction table: robust statistics of the current per position, direction and step.

For every (position, direction, velocity step) of an axis the table pools
the samples of all windows of that step (repetitions included) and gives the
**median** (robust against outliers, the figure the fits use), the mean, the
sample standard deviation (ddof = 1, NaN for a single sample), the sample
count, and the **standard error** of the median.

Every sample of a window counts. The window itself was checked against the
axis' velocity (:mod:`~ncmeasure.analysis.windows.finder`: after settling, its
velocity agrees with the commanded one within the signal's noise and
resolution); selecting samples one by one by their velocity reading would
select by the noise, and at low speed, where one velocity count exceeds any
band, it would select nearly none.

Two properties of real drive data shape the statistics:

* **A quantised current.** Drives report the current in counts (CiA 402: per
  mille of the rated current), so at constant velocity most samples sit on
  two or three levels. The plain median is then one of those levels; the
  median of grouped data (the level's lower edge plus the count up to the
  middle, interpolated over the level: ``L − q/2 + q·(n/2 − below)/at``)
  resolves friction between the counts the way the noise dithers them. With
  a continuous current it is the plain median.
* **Correlated samples.** The servo loop and the motor's cogging make
  neighbouring samples alike, so ``std/√n`` understates the uncertainty. The
  unit of replication is a *batch*: each window is cut into up to
  :data:`BATCHES_PER_WINDOW` consecutive stretches of at least
  :data:`MIN_BATCH_SAMPLES` samples (a short window is one batch); the
  standard error is the scatter of the batch medians over √batches, and never
  less than the independent-sample figure √(π/2)·std/√n. Where a step has
  several windows (repetitions), what differs between them (drift, the
  cogging phase at the window's place) is sampled once per window: the
  scatter of the window medians over √windows then counts too, and the
  largest of the three figures is the standard error.

With a torque constant the table is in Nm (T = k_T · I), else in A.

This is the hot path of the analysis (an hour at 1 kHz is 3.6 M rows), so it
is vectorised, and it works through the groups in chunks of about
:data:`_CHUNK_SAMPLES` samples (its memory does not grow with the recording,
and a chunk's arrays stay small enough for the allocator to hand the same
memory back chunk after chunk). The windows are sorted by group;
a chunk's samples are gathered at once (its windows' slices of a contiguous
current, as a recording holds its channels; from a column of a wider array
by an index built as a running sum of steps) and its sums come from
``np.add.reduceat``. The batches
are sorted as the rows of one padded block (numpy sorts short rows with
vectorised sorting networks), which gives the batch medians. The window and
group medians are *selected*, not sorted for: the median of a union lies
between the least and the largest median of its parts (:func:`medians_within`), so
each window needs only its values between its batches' medians, each group
those between its windows' medians, counted and picked in the sorted batch
rows by a bisection in all rows at once, and those few are sorted. Every
median is the exact order statistic, so the table is the same, bit for bit,
as one sorted group by group. Python loops run over chunks (and, for
segments of very different lengths, over blocks of similar length), never
windows or samples.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from operator import attrgetter
from typing import Final, Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.friction.medians import (
    grouped_medians,
    medians_within,
    middle,
    order_statistics,
    sample_index,
    sorted_rows,
)
from ncmeasure.analysis.windows.model import VelocityWindow
from ncmeasure.formats.results import Point

__all__ = [
    "BATCHES_PER_WINDOW",
    "MIN_BATCH_SAMPLES",
    "FrictionTable",
    "friction_table",
    "grouped_median",
    "window_samples",
    "window_table",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]

BATCHES_PER_WINDOW: Final = 5
"""A window is cut into at most this many batches for the standard error."""

MIN_BATCH_SAMPLES: Final = 5
"""A batch holds at least this many samples (a shorter window is one batch)."""

_MEDIAN_SE_FACTOR: Final = math.sqrt(math.pi / 2)

_CHUNK_SAMPLES: Final = 1 << 17
"""Whole groups are worked through in chunks of about this many samples (1 MiB of float64).

Chunks four times larger were 6 % faster in ``benchmarks/analysis.py`` (run after
pandas' work) and slower in fresh processes, where their larger arrays were faulted
in page by page on every call: the table ``ncmeasure analyze`` builds
(:func:`window_table`) took 30.7 ms (29.1–33.2) for the benchmark's hour, against
24.5 ms (18.2–31.7) with these chunks (six processes each)."""


@dataclass(frozen=True)
class FrictionTable:
    """One axis' friction table: one row per (position, direction, step), columns as arrays.

    Rows are sorted by position index, then direction (−1 before +1), then step.
    ``stderr`` is the standard error of ``median`` (batches, see the module).
    """

    axis: str
    quantity: Literal["torque_nm", "current_a"]
    unit: Literal["Nm", "A"]
    torque_constant_nm_per_a: float | None
    position_index: IntArray
    direction: IntArray
    step: IntArray
    velocity_mm_min: FloatArray
    median: FloatArray
    mean: FloatArray
    std: FloatArray
    stderr: FloatArray
    n: IntArray
    windows: IntArray
    batches: IntArray

    def __len__(self) -> int:
        return int(self.step.shape[0])

    @property
    def samples(self) -> int:
        """Samples used, over all rows."""
        return int(self.n.sum())

    def points(self, position_index: int, direction: int) -> list[Point]:
        """The rows of one position and direction as result points, slowest first."""
        rows = np.flatnonzero(
            (self.position_index == position_index) & (self.direction == direction)
        )
        rows = rows[np.argsort(np.abs(self.velocity_mm_min[rows]), kind="stable")]
        return [
            Point(
                velocity_mm_min=float(self.velocity_mm_min[i]),
                median=float(self.median[i]),
                mean=float(self.mean[i]),
                std=float(self.std[i]) if self.n[i] > 1 else 0.0,
                stderr=float(self.stderr[i]) if math.isfinite(self.stderr[i]) else None,
                n=int(self.n[i]),
                step=int(self.step[i]),
                windows=int(self.windows[i]),
            )
            for i in rows
        ]


def grouped_median(values: FloatArray, quantum: float = 0.0) -> float:
    """The median of ``values``, interpolated within one count when they are quantised.

    For a quantum q > 0 the values are read as grouped data with classes of
    width q centred on the counts: with L the count holding the middle sample,
    ``below`` the samples under L and ``at`` those on L, the median is
    L − q/2 + q·(n/2 − below)/at. Where noise dithers the signal between two
    counts, it moves between them in proportion to the samples on each, where
    the plain median jumps from count to count. With q = 0 it is the plain
    median. NaN when empty.
    """
    count = len(values)
    if count == 0:
        return math.nan
    lower = (count - 1) // 2
    if quantum <= 0:
        if count % 2:
            return float(np.partition(values, lower)[lower])
        low, high = np.partition(values, (lower, lower + 1))[lower : lower + 2]
        return float((low + high) / 2)
    level = float(np.partition(values, lower)[lower])
    half = 0.5 * quantum
    below = int(np.count_nonzero(values < level - half))
    at = int(np.count_nonzero(np.abs(values - level) <= half))
    if at == 0:  # not on the lattice after all
        return level
    return level - half + quantum * (0.5 * count - below) / at


def window_samples(windows: Sequence[VelocityWindow]) -> tuple[IntArray, IntArray]:
    """The sample indices of all windows and the window each belongs to, vectorised.

    Returns:
        ``(index, window)``: sample indices, and for each the position of its
        window in ``windows``.
    """
    starts = np.fromiter((w.start for w in windows), dtype=np.intp, count=len(windows))
    stops = np.fromiter((w.stop for w in windows), dtype=np.intp, count=len(windows))
    lengths = np.maximum(stops - starts, 0)
    owner = np.repeat(np.arange(len(windows), dtype=np.intp), lengths)
    return sample_index(starts, lengths), owner


def _batch_count(lengths: IntArray) -> IntArray:
    """The batches of windows of ``lengths`` finite samples (one for a short or empty window)."""
    return np.maximum(1, np.minimum(BATCHES_PER_WINDOW, lengths // MIN_BATCH_SAMPLES))


def _batch_bounds(window_bounds: IntArray) -> IntArray:
    """Cut each window ``[b[w], b[w + 1])`` into up to BATCHES_PER_WINDOW equal batches.

    The edges are those of ``np.linspace(start, stop, count + 1).round()`` per
    window (the same float arithmetic: k · ((stop − start) / count) + start,
    the last edge exactly ``stop``), for all windows at once.
    """
    start = window_bounds[:-1]
    stop = window_bounds[1:]
    length = stop - start
    count = _batch_count(length)
    owner = np.repeat(np.arange(len(count), dtype=np.intp), count)
    k = np.arange(int(count.sum()), dtype=np.intp) - np.repeat(np.cumsum(count) - count, count) + 1
    step = (length.astype(np.float64) / count)[owner]
    edges = np.round(k * step + start[owner].astype(np.float64)).astype(np.intp)
    last = k == count[owner]
    edges[last] = stop[owner][last]
    return np.concatenate((window_bounds[:1], edges)).astype(np.intp)


def _scatter_over_root_n(
    values: FloatArray, group: IntArray, groups: int
) -> tuple[FloatArray, IntArray]:
    """Per group: the standard deviation of ``values`` over √count (NaN below 2), and count.

    The standard error of a mean of independent units: batch or window medians.
    """
    count = np.bincount(group, minlength=groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(group, weights=values, minlength=groups) / count
        spread = values - mean[group]
        variance = np.bincount(group, weights=spread * spread, minlength=groups) / (count - 1)
        return np.sqrt(np.maximum(variance, 0.0) / count), count


def friction_table(
    axis: str,
    current_a: FloatArray,
    windows: Sequence[VelocityWindow],
    *,
    torque_constant_nm_per_a: float | None = None,
    current_quantum_a: float = 0.0,
) -> FrictionTable:
    """Median, standard error, mean, std and count of the current per (position, direction, step).

    Args:
        axis: The axis name.
        current_a: The motor current of the axis, all samples (n,).
        windows: Its labelled windows (:func:`~ncmeasure.analysis.windows.find.find_windows`).
        torque_constant_nm_per_a: k_T; the table is in Nm when given, else in A.
        current_quantum_a: One count of a quantised current (0: continuous);
            medians are then medians of grouped data (:func:`grouped_median`).

    Returns:
        The table; rows without a single finite sample are left out.
    """
    current = np.asarray(current_a, dtype=np.float64)
    start = np.fromiter(map(attrgetter("start"), windows), dtype=np.intp, count=len(windows))
    stop = np.fromiter(map(attrgetter("stop"), windows), dtype=np.intp, count=len(windows))
    # A contiguous column (a recording's, as Recording.open holds them) is gathered
    # slice by slice, and so are windows beyond its ends (slices clip); a column of a
    # wider array, faster by index.
    if current.strides[0] == current.itemsize or (
        len(windows) and (start.min() < 0 or stop.max() > len(current))
    ):
        parts = [current[w.start : w.stop] for w in windows]
        return _table(axis, windows, parts, None, torque_constant_nm_per_a, current_quantum_a)
    return _table(
        axis, windows, None, (current, start, stop), torque_constant_nm_per_a, current_quantum_a
    )


def window_table(
    axis: str,
    window_current_a: Sequence[FloatArray],
    windows: Sequence[VelocityWindow],
    *,
    torque_constant_nm_per_a: float | None = None,
    current_quantum_a: float = 0.0,
) -> FrictionTable:
    """:func:`friction_table` from the current of each window alone.

    For an analysis that does not hold the whole recording: it keeps the
    samples of the windows only (``window_current_a[i]`` is the current of
    ``windows[i]``, ``stop − start`` samples) and gets the same table.
    """
    return _table(
        axis, windows, window_current_a, None, torque_constant_nm_per_a, current_quantum_a
    )


@dataclass
class _Groups:
    """The windows sorted into groups (position, direction, step) of contiguous samples.

    The groups are worked through in chunks of whole groups, about
    :data:`_CHUNK_SAMPLES` samples each (``chunk_groups``: the first group of
    every chunk, and the number of groups last). The window arrays are in the
    sorted order.
    """

    count: int  # windows
    order: IntArray  # sorted position of every window
    keys: IntArray  # (position, direction, step) of every sorted window
    first: BoolArray  # a sorted window begins its group
    group_of_window: IntArray
    groups: int
    velocity: FloatArray  # of every window, unsorted
    lengths: IntArray  # samples of every sorted window
    parts: list[FloatArray] | None  # the current of every sorted window
    current: FloatArray | None  # or the whole current, gathered by index from ``start``
    start: IntArray | None  # sorted starts, with ``current``
    window_of_group: IntArray  # first sorted window of every group, then ``count``
    sample_bounds: IntArray  # first sample of every sorted window, then the total
    chunk_groups: list[int]
    # The batches of every window, were every sample finite (the usual case).
    batches_all: IntArray
    first_batch_all: IntArray
    batch_bounds_all: IntArray


def _groups(
    windows: Sequence[VelocityWindow],
    window_current: Sequence[FloatArray] | None,
    samples: tuple[FloatArray, IntArray, IntArray] | None,
) -> _Groups:
    count = len(windows)
    # Group key per window; windows sorted by key make every group's samples contiguous.
    position = np.fromiter(map(attrgetter("position_index"), windows), dtype=np.intp, count=count)
    direction = np.fromiter(map(attrgetter("direction"), windows), dtype=np.intp, count=count)
    step = np.fromiter(map(attrgetter("step"), windows), dtype=np.intp, count=count)
    velocity = np.fromiter(
        map(attrgetter("velocity_mm_min"), windows), dtype=np.float64, count=count
    )
    current: FloatArray | None = None
    if samples is None:
        start = np.fromiter(map(attrgetter("start"), windows), dtype=np.intp, count=count)
    else:
        current, start, stop = samples
    order = np.lexsort((start, step, direction, position))
    keys = np.stack([position[order], direction[order], step[order]], axis=1)
    first = np.ones(count, dtype=np.bool_)
    first[1:] = (keys[1:] != keys[:-1]).any(axis=1)
    group_of_window = np.cumsum(first) - 1
    groups = int(first.sum())

    parts: list[FloatArray] | None = None
    sorted_start: IntArray | None = None
    if window_current is not None:
        parts = [window_current[i] for i in order.tolist()]
        lengths = np.fromiter(map(len, parts), dtype=np.intp, count=count)
    else:  # the samples by index, a chunk at a time
        lengths = np.maximum(stop - start, 0)[order]
        sorted_start = start[order]
    # Chunks of whole groups, about _CHUNK_SAMPLES each: every statistic works
    # on one chunk's samples at a time (little memory, in the processor's cache).
    window_of_group = np.concatenate(([0], np.flatnonzero(first[1:]) + 1, [count]))
    sample_bounds = np.concatenate(([0], np.cumsum(lengths)))
    cut = np.flatnonzero(np.diff(sample_bounds[window_of_group[:-1]] // _CHUNK_SAMPLES)) + 1
    chunk_groups = np.concatenate(([0], cut, [groups])).tolist() if groups else [0]
    batches_all = _batch_count(lengths)
    return _Groups(
        count=count,
        order=order,
        keys=keys,
        first=first,
        group_of_window=group_of_window,
        groups=groups,
        velocity=velocity,
        lengths=lengths,
        parts=parts,
        current=current,
        start=sorted_start,
        window_of_group=window_of_group,
        sample_bounds=sample_bounds,
        chunk_groups=chunk_groups,
        batches_all=batches_all,
        first_batch_all=np.concatenate(([0], np.cumsum(batches_all))),
        batch_bounds_all=_batch_bounds(sample_bounds),
    )


@dataclass
class _Sums:
    """What the chunks give, per group, per sorted window and per batch."""

    total: FloatArray
    squares: FloatArray
    per_window: IntArray  # finite samples
    window_low: FloatArray
    window_high: FloatArray
    window_median: FloatArray
    group_low: FloatArray
    group_high: FloatArray
    median: FloatArray
    batch_low: list[FloatArray]
    batch_high: list[FloatArray]
    batch_lengths: list[IntArray]
    batch_median: list[FloatArray]

    @classmethod
    def empty(cls, count: int, groups: int) -> _Sums:
        return cls(
            total=np.zeros(groups),
            squares=np.zeros(groups),
            per_window=np.zeros(count, dtype=np.intp),
            window_low=np.full(count, np.nan),
            window_high=np.full(count, np.nan),
            window_median=np.full(count, np.nan),
            group_low=np.full(groups, np.nan),
            group_high=np.full(groups, np.nan),
            median=np.full(groups, np.nan),
            batch_low=[np.zeros(0)],
            batch_high=[np.zeros(0)],
            batch_lengths=[np.zeros(0, dtype=np.intp)],
            batch_median=[np.zeros(0)],
        )


def _add_chunk(
    g: _Groups, acc: _Sums, g0: int, g1: int, offset: int, current_quantum_a: float
) -> int:
    """Add the groups ``g0`` ..< ``g1`` (one chunk) to ``acc``; the finite samples so far."""
    w0, w1 = int(g.window_of_group[g0]), int(g.window_of_group[g1])
    sample_bounds, window_of_group = g.sample_bounds, g.window_of_group
    if g.parts is not None:
        values = np.concatenate(g.parts[w0:w1], dtype=np.float64)
    else:
        assert g.current is not None and g.start is not None
        values = g.current[sample_index(g.start[w0:w1], g.lengths[w0:w1])]
    # Every sample finite (the usual case) when every group's sum is: then the
    # windows and batches are those of all samples, else they are recounted.
    kept = g.lengths[w0:w1]
    window_bounds = sample_bounds[w0 : w1 + 1] - sample_bounds[w0]
    group_bounds = window_bounds[window_of_group[g0 : g1 + 1] - w0]
    n = np.diff(group_bounds)
    filled = np.flatnonzero(n > 0)
    sums = np.add.reduceat(values, group_bounds[filled]) if len(filled) else np.zeros(0)
    if np.isfinite(sums).all() and offset == sample_bounds[w0]:
        batches = g.batches_all[w0:w1]
        cuts = g.batch_bounds_all[g.first_batch_all[w0] : g.first_batch_all[w1] + 1] - offset
    else:
        finite = np.isfinite(values)
        cumulative = np.concatenate(([0], np.cumsum(finite)))
        ends = sample_bounds[w0 + 1 : w1 + 1] - sample_bounds[w0]
        kept = cumulative[ends] - cumulative[ends - kept]
        values = values[finite]
        del finite
        batches = _batch_count(kept)
        # Batch edges are rounded from offsets among all finite samples: the same here.
        window_bounds = np.concatenate(([0], np.cumsum(kept)))
        cuts = _batch_bounds(window_bounds + offset) - offset
        group_bounds = window_bounds[window_of_group[g0 : g1 + 1] - w0]
        n = np.diff(group_bounds)
        filled = np.flatnonzero(n > 0)
        sums = np.add.reduceat(values, group_bounds[filled]) if len(filled) else sums[:0]
    acc.per_window[w0:w1] = kept
    if len(filled):
        acc.total[g0 + filled] = sums
        with np.errstate(invalid="ignore", divide="ignore"):
            deviation = np.repeat(sums / n[filled], n[filled])
        np.subtract(values, deviation, out=deviation)
        deviation *= deviation
        acc.squares[g0 + filled] = np.add.reduceat(deviation, group_bounds[filled])
        del deviation

    # Batch medians from a sort of every batch (short rows); window and group
    # medians from their parts' medians and the few values between them.
    sizes = np.diff(cuts)
    block = sorted_rows(values, sizes)
    window_rows: tuple[FloatArray, IntArray] | None = None
    group_rows: tuple[FloatArray, IntArray] | None = None
    if block is not None:  # the usual case: batches of similar length
        every = np.arange(len(block))
        low = block[every, np.maximum(sizes - 1, 0) // 2]
        high = block[every, sizes // 2]
        first_batch = np.concatenate(([0], np.cumsum(batches)))
        window_rows = (block, first_batch)
        group_rows = (block, first_batch[window_of_group[g0 : g1 + 1] - w0])
    else:
        low, high = order_statistics(values, cuts, (sizes - 1) // 2, sizes // 2)
    acc.batch_low.append(low)
    acc.batch_high.append(high)
    acc.batch_lengths.append(sizes)
    w_low, w_high = medians_within(values, window_bounds, low, high, batches, window_rows)
    acc.window_low[w0:w1] = w_low
    acc.window_high[w0:w1] = w_high
    used = kept > 0
    w_parts = np.add.reduceat(used, window_of_group[g0:g1] - w0, dtype=np.intp)
    acc.group_low[g0:g1], acc.group_high[g0:g1] = medians_within(
        values, group_bounds, w_low[used], w_high[used], w_parts, group_rows
    )
    if current_quantum_a > 0:
        quantum = current_quantum_a
        acc.batch_median.append(grouped_medians(values, cuts, low, quantum))
        acc.window_median[w0:w1] = grouped_medians(values, window_bounds, w_low, quantum)
        acc.median[g0:g1] = grouped_medians(values, group_bounds, acc.group_low[g0:g1], quantum)
    return offset + len(values)


def _table(
    axis: str,
    windows: Sequence[VelocityWindow],
    window_current: Sequence[FloatArray] | None,
    samples: tuple[FloatArray, IntArray, IntArray] | None,
    torque_constant_nm_per_a: float | None,
    current_quantum_a: float,
) -> FrictionTable:
    """The table from the current of every window, or from ``samples``: the whole
    current and the windows' starts and stops."""
    g = _groups(windows, window_current, samples)
    acc = _Sums.empty(g.count, g.groups)
    offset = 0  # finite samples before the chunk
    for g0, g1 in itertools.pairwise(g.chunk_groups):
        offset = _add_chunk(g, acc, g0, g1, offset, current_quantum_a)
    return _finished(axis, g, acc, torque_constant_nm_per_a, current_quantum_a > 0)


def _finished(
    axis: str,
    g: _Groups,
    acc: _Sums,
    torque_constant_nm_per_a: float | None,
    quantised: bool,
) -> FrictionTable:
    """The table from the sums of every chunk: medians, mean, std, standard errors."""
    quantity: Literal["torque_nm", "current_a"] = (
        "torque_nm" if torque_constant_nm_per_a is not None else "current_a"
    )
    unit: Literal["Nm", "A"] = "Nm" if torque_constant_nm_per_a is not None else "A"
    scale = torque_constant_nm_per_a if torque_constant_nm_per_a is not None else 1.0
    groups, per_window, group_of_window = g.groups, acc.per_window, g.group_of_window
    sizes = np.concatenate(acc.batch_lengths)
    batch_median, window_median, median = acc.batch_median, acc.window_median, acc.median
    if not quantised:
        batch_median = [
            middle(sizes, np.concatenate(acc.batch_low), np.concatenate(acc.batch_high))
        ]
        window_median = middle(per_window, acc.window_low, acc.window_high)
    n = np.zeros(groups, dtype=np.intp)
    if groups:
        n[:] = np.add.reduceat(per_window, g.window_of_group[:-1])
        if not quantised:
            median = middle(n, acc.group_low, acc.group_high)
    used_windows = np.bincount(group_of_window[per_window > 0], minlength=groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = acc.total / n
        variance = acc.squares / (n - 1)
    std = np.where(n > 1, np.sqrt(np.maximum(variance, 0.0)), np.nan)

    # Batches: consecutive stretches of every window; their medians scatter by what
    # correlates the samples (servo loop, cogging), unlike the samples themselves.
    batch_filled = sizes > 0
    by_batches, batches_used = _scatter_over_root_n(
        np.concatenate(batch_median)[batch_filled],
        np.repeat(group_of_window, _batch_count(per_window))[batch_filled],
        groups,
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        independent = _MEDIAN_SE_FACTOR * std / np.sqrt(n)
    stderr = np.where(batches_used > 1, np.fmax(by_batches, independent), independent)
    # Repeated windows of a step: their medians' scatter over √windows.
    filled_windows = per_window > 0
    by_windows, _ = _scatter_over_root_n(
        window_median[filled_windows], group_of_window[filled_windows], groups
    )
    stderr = np.where(used_windows > 1, np.fmax(stderr, by_windows), stderr)

    # All windows of a group share the step velocity; take its first window's.
    group_velocity = g.velocity[g.order][g.first]
    filled_rows = n > 0
    head = g.keys[g.first][filled_rows]
    return FrictionTable(
        axis=axis,
        quantity=quantity,
        unit=unit,
        torque_constant_nm_per_a=torque_constant_nm_per_a,
        position_index=head[:, 0].astype(np.intp),
        direction=head[:, 1].astype(np.intp),
        step=head[:, 2].astype(np.intp),
        velocity_mm_min=group_velocity[filled_rows],
        median=median[filled_rows] * scale,
        mean=mean[filled_rows] * scale,
        std=std[filled_rows] * scale,
        stderr=stderr[filled_rows] * scale,
        n=n[filled_rows].astype(np.intp),
        windows=used_windows[filled_rows].astype(np.intp),
        batches=batches_used[filled_rows].astype(np.intp),
    )
