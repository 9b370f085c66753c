"""The friction table: robust statistics of the current per position, direction and step.

For every (position, direction, velocity step) of an axis the table pools
the samples of all windows of that step (repetitions included) and gives the
**median** (robust against outliers, the figure the fits use), the mean, the
sample standard deviation (ddof = 1, NaN for a single sample), the sample
count, and the **standard error** of the median.

Every sample of a window counts. The window itself was checked against the
axis' velocity (:mod:`~ncmeasure.analysis.segment`: after settling, its
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
is vectorised: the windows are sorted by group, the sample indices of all
windows are built at once (``np.repeat`` of the window offsets), sums come
from ``np.bincount``, and medians from one ``np.partition`` per group or
batch on its contiguous slice. Python loops run over windows, batches and
groups, never samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.results import Point
from ncmeasure.analysis.segment import VelocityWindow

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

BATCHES_PER_WINDOW: Final = 5
"""A window is cut into at most this many batches for the standard error."""

MIN_BATCH_SAMPLES: Final = 5
"""A batch holds at least this many samples (a shorter window is one batch)."""

_MEDIAN_SE_FACTOR: Final = math.sqrt(math.pi / 2)

_SortKind = Literal["quicksort", "stable"]
_PAD_RATIO: Final = 1.25
"""Segments sorted in one padded block differ in length by at most this factor."""
_PAD_LONGEST: Final = 4096
"""Longer segments are sorted one by one."""
_PAD_BLOCK: Final = 1 << 20
"""Largest padded block, in values (8 MiB of float64, plus its index)."""


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
    offsets = np.cumsum(lengths) - lengths
    total = int(lengths.sum())
    owner = np.repeat(np.arange(len(windows), dtype=np.intp), lengths)
    index = np.arange(total, dtype=np.intp) + np.repeat(starts - offsets, lengths)
    return index, owner


def _batch_bounds(window_bounds: IntArray) -> IntArray:
    """Cut each window ``[b[w], b[w + 1])`` into up to BATCHES_PER_WINDOW equal batches.

    The edges are those of ``np.linspace(start, stop, count + 1).round()`` per
    window (the same float arithmetic: k · ((stop − start) / count) + start,
    the last edge exactly ``stop``), for all windows at once.
    """
    start = window_bounds[:-1]
    stop = window_bounds[1:]
    length = stop - start
    count = np.maximum(1, np.minimum(BATCHES_PER_WINDOW, length // MIN_BATCH_SAMPLES))
    owner = np.repeat(np.arange(len(count), dtype=np.intp), count)
    k = np.arange(int(count.sum()), dtype=np.intp) - np.repeat(np.cumsum(count) - count, count) + 1
    step = (length.astype(np.float64) / count)[owner]
    edges = np.round(k * step + start[owner].astype(np.float64)).astype(np.intp)
    last = k == count[owner]
    edges[last] = stop[owner][last]
    return np.concatenate((window_bounds[:1], edges)).astype(np.intp)


def _sort_segments(buffer: FloatArray, bounds: IntArray, kind: _SortKind) -> None:
    """Sort every segment ``buffer[bounds[s]:bounds[s + 1]]`` in place.

    ``buffer`` ends in one spare slot holding +inf, after the last segment.
    Segments of similar length (within :data:`_PAD_RATIO`) are sorted together
    as the rows of one block: a row shorter than the block reads the spare slot
    as padding (+inf sorts behind every finite sample) and writes it back there,
    so a block is one gather, one vectorised sort and one scatter instead of a
    call per segment. Segments longer than :data:`_PAD_LONGEST` are sorted one
    by one: they are few, and a call costs little against their length.
    """
    spare = len(buffer) - 1
    lengths = np.diff(bounds)
    starts = bounds[:-1]
    for s in np.flatnonzero(lengths > _PAD_LONGEST).tolist():
        buffer[starts[s] : starts[s] + lengths[s]].sort(kind=kind)
    short = np.flatnonzero((lengths > 1) & (lengths <= _PAD_LONGEST))
    short = short[np.argsort(lengths[short], kind="stable")]
    sorted_lengths = lengths[short]
    first = 0
    while first < len(short):
        shortest = int(sorted_lengths[first])
        end = int(np.searchsorted(sorted_lengths, math.floor(shortest * _PAD_RATIO), "right"))
        end = min(end, first + max(1, _PAD_BLOCK // shortest))
        rows = short[first:end]
        width = int(sorted_lengths[end - 1])
        columns = np.arange(width, dtype=np.intp)
        index = starts[rows][:, None] + columns
        if width > shortest:
            index = np.where(columns < lengths[rows][:, None], index, spare)
        block = buffer.take(index)
        block.sort(axis=1, kind=kind)
        buffer.put(index, block)
        first = end


def _sorted_medians(buffer: FloatArray, bounds: IntArray, quantum: float) -> FloatArray:
    """:func:`grouped_median` of every segment of ``buffer``, each segment sorted.

    ``bounds`` cut the buffer (but a spare slot) into consecutive segments; NaN for an empty
    one. The arithmetic is :func:`grouped_median`'s, so the numbers are the same.
    """
    lengths = np.diff(bounds)
    result = np.full(len(lengths), np.nan)
    filled = np.flatnonzero(lengths > 0)
    if not len(filled):
        return result
    count = lengths[filled]
    start = bounds[:-1][filled]
    low = buffer[start + (count - 1) // 2]
    if quantum <= 0:
        high = buffer[start + count // 2]
        result[filled] = np.where(count % 2 == 1, low, (low + high) / 2)
        return result
    half = 0.5 * quantum
    level = np.repeat(low, count)
    buffer = buffer[: len(level)]  # without a spare slot after the segments
    below = np.add.reduceat((buffer < level - half).astype(np.intp), start)
    at = np.add.reduceat((np.abs(buffer - level) <= half).astype(np.intp), start)
    with np.errstate(invalid="ignore", divide="ignore"):
        interpolated = low - half + quantum * (0.5 * count - below) / at
    result[filled] = np.where(at == 0, low, interpolated)
    return result


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
        windows: Its labelled windows (:func:`~ncmeasure.analysis.segment.find_windows`).
        torque_constant_nm_per_a: k_T; the table is in Nm when given, else in A.
        current_quantum_a: One count of a quantised current (0: continuous);
            medians are then medians of grouped data (:func:`grouped_median`).

    Returns:
        The table; rows without a single finite sample are left out.
    """
    current = np.asarray(current_a, dtype=np.float64)
    return window_table(
        axis,
        [current[w.start : w.stop] for w in windows],
        windows,
        torque_constant_nm_per_a=torque_constant_nm_per_a,
        current_quantum_a=current_quantum_a,
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
    quantity: Literal["torque_nm", "current_a"] = (
        "torque_nm" if torque_constant_nm_per_a is not None else "current_a"
    )
    unit: Literal["Nm", "A"] = "Nm" if torque_constant_nm_per_a is not None else "A"
    scale = torque_constant_nm_per_a if torque_constant_nm_per_a is not None else 1.0
    count = len(windows)

    # Group key per window; windows sorted by key make every group's samples contiguous,
    # so every statistic below works on consecutive slices of one buffer.
    position = np.fromiter((w.position_index for w in windows), dtype=np.intp, count=count)
    direction = np.fromiter((w.direction for w in windows), dtype=np.intp, count=count)
    step = np.fromiter((w.step for w in windows), dtype=np.intp, count=count)
    velocity = np.fromiter((w.velocity_mm_min for w in windows), dtype=np.float64, count=count)
    start = np.fromiter((w.start for w in windows), dtype=np.intp, count=count)
    order = np.lexsort((start, step, direction, position))
    keys = np.stack([position[order], direction[order], step[order]], axis=1)
    first = np.ones(count, dtype=np.bool_)
    first[1:] = (keys[1:] != keys[:-1]).any(axis=1)
    group_of_window = np.cumsum(first) - 1
    groups = int(first.sum())

    parts = [np.asarray(window_current_a[i], dtype=np.float64) for i in order.tolist()]
    lengths = np.fromiter((len(p) for p in parts), dtype=np.intp, count=count)
    # One buffer for the samples and, after them, the spare slot of _sort_segments:
    # the statistics and the sorts below work in it and one more array at most.
    buffer = np.empty(int(lengths.sum()) + 1, dtype=np.float64)
    if parts:
        np.concatenate(parts, out=buffer[:-1])
    del parts
    values = buffer[:-1]
    finite = np.isfinite(values)
    if finite.all():
        per_window = lengths
    else:
        kept = np.concatenate(([0], np.cumsum(finite)))
        ends = np.cumsum(lengths)
        per_window = kept[ends] - kept[ends - lengths]
        count_finite = int(kept[-1])
        buffer[:count_finite] = values[finite]
        buffer = buffer[: count_finite + 1]
        values = buffer[:-1]
    del finite
    n = np.bincount(group_of_window, weights=per_window, minlength=groups).astype(np.intp)
    used_windows = np.bincount(group_of_window[per_window > 0], minlength=groups)
    group_bounds = np.concatenate(([0], np.cumsum(n)))
    window_bounds = np.concatenate(([0], np.cumsum(per_window)))

    filled = np.flatnonzero(n > 0)
    total = np.zeros(groups)
    squares = np.zeros(groups)
    if len(filled):
        total[filled] = np.add.reduceat(values, group_bounds[filled])
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / n
        deviation = np.repeat(mean, n)
        np.subtract(values, deviation, out=deviation)
        deviation *= deviation
        if len(filled):
            squares[filled] = np.add.reduceat(deviation, group_bounds[filled])
        del deviation
        variance = squares / (n - 1)
    std = np.where(n > 1, np.sqrt(np.maximum(variance, 0.0)), np.nan)

    # Medians of batches, windows and groups from one buffer sorted three times:
    # batches nest in windows and windows in groups, so each sort merges sorted runs.
    ordered = buffer  # sorted in place from here on: ``values`` is not read again
    ordered[-1] = np.inf  # the spare slot of _sort_segments
    del values
    batch_bounds = _batch_bounds(window_bounds)
    _sort_segments(ordered, batch_bounds, "quicksort")
    batch_median_all = _sorted_medians(ordered, batch_bounds, current_quantum_a)
    _sort_segments(ordered, window_bounds, "stable")
    window_median_all = _sorted_medians(ordered, window_bounds, current_quantum_a)
    _sort_segments(ordered, group_bounds, "stable")
    median = _sorted_medians(ordered, group_bounds, current_quantum_a)

    # Batches: consecutive stretches of every window; their medians scatter by what
    # correlates the samples (servo loop, cogging), unlike the samples themselves.
    batch_filled = np.diff(batch_bounds) > 0
    batch_median = batch_median_all[batch_filled]
    batch_window = np.repeat(
        np.arange(count, dtype=np.intp),
        np.maximum(1, np.minimum(BATCHES_PER_WINDOW, per_window // MIN_BATCH_SAMPLES)),
    )
    batch_group = group_of_window[batch_window][batch_filled]
    by_batches, batches = _scatter_over_root_n(batch_median, batch_group, groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        independent = _MEDIAN_SE_FACTOR * std / np.sqrt(n)
    stderr = np.where(batches > 1, np.fmax(by_batches, independent), independent)
    # Repeated windows of a step: their medians' scatter over √windows.
    filled_windows = per_window > 0
    window_median = window_median_all[filled_windows]
    by_windows, _ = _scatter_over_root_n(window_median, group_of_window[filled_windows], groups)
    stderr = np.where(used_windows > 1, np.fmax(stderr, by_windows), stderr)

    # All windows of a group share the step velocity; take its first window's.
    group_velocity = velocity[order][first]
    rows = n > 0
    head = keys[first][rows]
    return FrictionTable(
        axis=axis,
        quantity=quantity,
        unit=unit,
        torque_constant_nm_per_a=torque_constant_nm_per_a,
        position_index=head[:, 0].astype(np.intp),
        direction=head[:, 1].astype(np.intp),
        step=head[:, 2].astype(np.intp),
        velocity_mm_min=group_velocity[rows],
        median=median[rows] * scale,
        mean=mean[rows] * scale,
        std=std[rows] * scale,
        stderr=stderr[rows] * scale,
        n=n[rows].astype(np.intp),
        windows=used_windows[rows].astype(np.intp),
        batches=batches[rows].astype(np.intp),
    )
