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
is vectorised: the windows are sorted by group and their samples copied once
into one buffer (every group, window and batch a contiguous slice), sums come
from ``np.add.reduceat``, and the medians of all batches, windows and groups
from ``np.partition`` of padded blocks of float32 keys, read back exactly
(:func:`_segment_medians`): no sort, no index array per sample, nothing
written back. Python loops run over blocks of similar segments, never
samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
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


def _selection_keys(buffer: FloatArray) -> NDArray[np.float32]:
    """Float32 keys of ``buffer``: in the same order as the values (ties aside), never ±inf.

    Rounding to float32 never reverses two values, so a row's k-th smallest value
    has the k-th smallest key, and selecting among 32-bit keys is several times
    faster than among float64 values. Clipped to the float32 range, no key of a
    finite value equals the ±inf padding.
    """
    limit = float(np.finfo(np.float32).max)
    keys = np.empty(len(buffer), dtype=np.float32)
    np.clip(buffer, -limit, limit, out=keys, casting="same_kind")
    return keys


def _row_counts(mask: NDArray[np.bool_]) -> IntArray:
    """The True entries of each row of ``mask``, rows at most :data:`_PAD_LONGEST` wide.

    Summed as bytes into uint16 (a row counts 4096 at most), several times faster
    than ``np.count_nonzero(mask, axis=1)``.
    """
    counts: NDArray[np.uint16] = mask.view(np.uint8).sum(axis=1, dtype=np.uint16)
    return counts.astype(np.intp)


def _segment_medians(
    buffer: FloatArray, keys: NDArray[np.float32], bounds: IntArray, quantum: float
) -> FloatArray:
    """:func:`grouped_median` of every segment ``buffer[bounds[s]:bounds[s + 1]]``.

    NaN for an empty segment. ``buffer`` holds finite values, and at least
    :data:`_PAD_LONGEST` values (any finite) before the first segment and after
    the last: the margin a padded row may reach into; ``keys`` are its
    :func:`_selection_keys`. Neither is changed.

    Segments of similar length (within :data:`_PAD_RATIO`) are the rows of one
    block, each copied from the keys as the ``width`` keys centred on it
    (``width`` the longest row's length: the copy of a contiguous stretch, no
    index array). The keys of a row's neighbours on its left become −inf and
    those on its right +inf, so many that the row's lower median lands in the
    same column ``centre = (width − 1) // 2`` for every row whatever its length.
    One ``np.partition`` of the float32 keys at that column finds every row's
    median key (O(width) per row, no sort); the upper median of an even row has
    the smallest key right of it. The values are then read back exactly: those
    whose key lies between the two median keys (mostly one or two a row; more
    only where values repeat or differ by less than a float32 step) are sorted
    where they differ, and the median is the one at its rank after the keys
    below. Segments longer than :data:`_PAD_LONGEST` are few and long:
    :func:`grouped_median` each. The arithmetic is :func:`grouped_median`'s, so
    the numbers are the same bit for bit.
    """
    lengths = np.diff(bounds)
    starts = bounds[:-1]
    result = np.full(len(lengths), np.nan)
    for s in np.flatnonzero(lengths > _PAD_LONGEST).tolist():
        result[s] = grouped_median(buffer[starts[s] : starts[s] + lengths[s]], quantum)
    short = np.flatnonzero((lengths > 0) & (lengths <= _PAD_LONGEST))
    short = short[np.argsort(lengths[short], kind="stable")]
    sorted_lengths = lengths[short]
    half = 0.5 * quantum
    first = 0
    while first < len(short):
        shortest = int(sorted_lengths[first])
        end = int(np.searchsorted(sorted_lengths, math.floor(shortest * _PAD_RATIO), "right"))
        end = min(end, first + max(1, _PAD_BLOCK // shortest))
        rows = short[first:end]
        length = sorted_lengths[first:end]
        first = end
        width = int(length[-1])
        centre = (width - 1) // 2
        lead = centre - (length - 1) // 2
        origin = starts[rows] - lead
        row_keys = sliding_window_view(keys, width)[origin]
        if width > shortest:
            columns = np.arange(width, dtype=np.intp)
            left = int(lead[0])  # the shortest row has the most padding
            np.copyto(row_keys[:, :left], -np.inf, where=columns[:left] < lead[:, None])
            tail = lead + length
            right = int(tail[0])
            np.copyto(row_keys[:, right:], np.inf, where=columns[right:] >= tail[:, None])
        selected = row_keys.copy()
        selected.partition(centre, axis=1)
        low_key = selected[:, centre]
        even = (length % 2 == 0) if quantum <= 0 else np.zeros(len(rows), dtype=np.bool_)
        high_key = low_key
        if even.any():  # an odd row's next key may be padding: its band stays at its median
            high_key = np.where(even, selected[:, centre + 1 :].min(axis=1), low_key)
        # Keys below the median key: all left of the centre in the partitioned rows.
        below = _row_counts(selected[:, :centre] < low_key[:, None])
        del selected
        # The values whose keys lie from the lower to the upper median key, row by row.
        band = row_keys >= low_key[:, None]
        band &= row_keys <= high_key[:, None]
        flat = np.flatnonzero(band)
        row = flat // width
        candidates = buffer[origin[row] + flat - row * width]
        count = np.bincount(row, minlength=len(rows))
        offset = np.cumsum(count) - count
        low = np.minimum.reduceat(candidates, offset)
        high = np.maximum.reduceat(candidates, offset)
        mixed = np.flatnonzero(low != high)
        if len(mixed):  # values differ within a key: sort those rows' candidates
            take = (low != high)[row]
            part, part_row = candidates[take], row[take]
            part = part[np.lexsort((part, part_row))]
            part_offset = np.cumsum(count[mixed]) - count[mixed] - below[mixed]
            low[mixed] = part[part_offset + centre]
            if even.any():  # an odd row's band ends at its median
                high[mixed] = part[part_offset + centre + even[mixed]]
        if quantum > 0:  # counts below and at the level: the row's values, padded as its keys
            values = sliding_window_view(buffer, width)[origin]
            if width > shortest:
                np.copyto(values[:, :left], -np.inf, where=columns[:left] < lead[:, None])
                np.copyto(values[:, right:], np.inf, where=columns[right:] >= tail[:, None])
            below = _row_counts(values < (low - half)[:, None]) - lead
            np.subtract(values, low[:, None], out=values)
            at = _row_counts(np.abs(values, out=values) <= half)
            with np.errstate(invalid="ignore", divide="ignore"):
                interpolated = low - half + quantum * (0.5 * length - below) / at
            result[rows] = np.where(at == 0, low, interpolated)
        else:
            result[rows] = np.where(even, (low + high) / 2, low)
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
    # The samples, by group and window, between margins a padded row may reach into.
    margin = _PAD_LONGEST
    buffer = np.empty(margin + int(lengths.sum()) + margin)
    buffer[:margin] = buffer[len(buffer) - margin :] = 0.0
    values = buffer[margin : len(buffer) - margin]
    if parts:
        np.concatenate(parts, out=values)
    finite = np.isfinite(values)
    if finite.all():
        per_window = lengths
    else:
        kept = np.concatenate(([0], np.cumsum(finite)))
        ends = np.cumsum(lengths)
        per_window = kept[ends] - kept[ends - lengths]
        buffer = np.concatenate((buffer[:margin], values[finite], buffer[:margin]))
        values = buffer[margin : len(buffer) - margin]
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
        deviation = np.repeat(mean, n)  # one array of n, worked in place
        np.subtract(values, deviation, out=deviation)
        np.multiply(deviation, deviation, out=deviation)
        if len(filled):
            squares[filled] = np.add.reduceat(deviation, group_bounds[filled])
        del deviation
        variance = squares / (n - 1)
    std = np.where(n > 1, np.sqrt(np.maximum(variance, 0.0)), np.nan)

    # Medians of batches, windows and groups: selections in padded blocks of the buffer.
    batch_bounds = _batch_bounds(window_bounds)
    order_keys = _selection_keys(buffer)
    batch_median_all = _segment_medians(
        buffer, order_keys, batch_bounds + margin, current_quantum_a
    )
    window_median_all = _segment_medians(
        buffer, order_keys, window_bounds + margin, current_quantum_a
    )
    median = _segment_medians(buffer, order_keys, group_bounds + margin, current_quantum_a)

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
