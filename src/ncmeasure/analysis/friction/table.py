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
between the least and the largest median of its parts (:func:`_within`), so
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
_PAD_WASTE: Final = 2
"""A padded block holds at most this many slots per value (plus :data:`_PAD_SLACK`)."""
_PAD_SLACK: Final = 1 << 16


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
    return _sample_index(starts, lengths), owner


def _sample_index(starts: IntArray, lengths: IntArray) -> IntArray:
    """The indices ``starts[i] ..< starts[i] + lengths[i]`` of all ``i``, concatenated.

    A running sum of steps: 1 within a run, the jump to the next start where one
    begins (one pass to write, one to sum; faster than repeating the offsets).
    """
    filled = lengths > 0
    if not filled.all():
        starts, lengths = starts[filled], lengths[filled]
    if not len(lengths):
        return np.zeros(0, dtype=np.intp)
    step = np.ones(int(lengths.sum()), dtype=np.intp)
    step[0] = starts[0]
    step[np.cumsum(lengths[:-1])] = starts[1:] - (starts[:-1] + lengths[:-1]) + 1
    return np.cumsum(step, out=step)


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


def _sorted_rows(values: FloatArray, lengths: IntArray) -> FloatArray | None:
    """Consecutive segments of ``values`` as the rows of one block, each row sorted.

    Row s holds the ``lengths[s]`` values of segment s, then +inf (which sorts
    behind every finite value) up to the longest segment; numpy sorts a short
    row with a vectorised network, all rows in one call. None when the block
    would hold more than :data:`_PAD_WASTE` slots per value (plus
    :data:`_PAD_SLACK`): segments of very different lengths.
    """
    width = int(lengths.max()) if len(lengths) else 0
    if width == 0 or len(lengths) * width > _PAD_WASTE * len(values) + _PAD_SLACK:
        return None
    block = np.full((len(lengths), width), np.inf)
    if width < 1 << 15:  # the mask of the slots is faster to build in int16
        slots = np.arange(width, dtype=np.int16) < lengths.astype(np.int16)[:, None]
    else:
        slots = np.arange(width) < lengths[:, None]
    block[slots] = values
    block.sort(axis=1)
    return block


def _count_below(block: FloatArray, threshold: FloatArray) -> IntArray:
    """Per sorted row r of ``block``: how many of its values are below ``threshold[r]``.

    ``threshold`` may hold several thresholds per row, one after the other
    (``threshold[i]`` is for row ``i % rows``). A bisection in all rows at
    once: a step per power of two, each step taken where the value before the
    new count is still below (a step beyond the row's end goes to its end).
    """
    rows, width = block.shape
    flat = block.ravel()
    before = np.tile(np.arange(-1, block.size - 1, width), len(threshold) // max(rows, 1))
    count = np.zeros(len(threshold), dtype=np.intp)
    step = 1 << width.bit_length()
    while step > 1:
        step >>= 1
        reach = np.minimum(count + step, width)
        count = np.where(flat[before + reach] < threshold, reach, count)
    return count


def _order_statistics(
    values: FloatArray, bounds: IntArray, low_rank: IntArray, high_rank: IntArray
) -> tuple[FloatArray, FloatArray]:
    """Two order statistics of every segment ``values[bounds[s]:bounds[s + 1]]``.

    ``low_rank[s]`` and ``high_rank[s]`` are 0-based ranks within segment s
    (the ``low_rank[s]``-th smallest value), each below its length; NaN for an
    empty segment. The segments are sorted as the rows of padded blocks
    (:func:`_sorted_rows`): all at once, or, where their lengths differ
    widely, in blocks of segments up to :data:`_PAD_WASTE` times as long as
    the shortest of each.
    """
    values = values[bounds[0] : bounds[-1]]
    lengths = np.diff(bounds)
    count = len(lengths)
    low = np.full(count, np.nan)
    high = np.full(count, np.nan)
    block = _sorted_rows(values, lengths)
    if block is not None:
        filled = np.flatnonzero(lengths > 0)
        low[filled] = block[filled, low_rank[filled]]
        high[filled] = block[filled, high_rank[filled]]
        return low, high
    by_length = np.argsort(lengths, kind="stable")
    by_length = by_length[lengths[by_length] > 0]
    ordered = lengths[by_length]
    first = 0
    while first < len(by_length):
        end = int(np.searchsorted(ordered, _PAD_WASTE * ordered[first], "right"))
        rows = by_length[first:end]
        row_lengths = lengths[rows]
        block = _sorted_rows(
            values[_sample_index(bounds[rows] - bounds[0], row_lengths)], row_lengths
        )
        assert block is not None  # lengths within a factor _PAD_WASTE
        at = np.arange(len(rows))
        low[rows] = block[at, low_rank[rows]]
        high[rows] = block[at, high_rank[rows]]
        first = end
    return low, high


def _within(
    values: FloatArray,
    bounds: IntArray,
    part_low: FloatArray,
    part_high: FloatArray,
    parts: IntArray,
    rows: tuple[FloatArray, IntArray] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The lower and upper median of every segment, from the medians of its parts.

    A segment ``values[bounds[s]:bounds[s + 1]]`` (a window, a group) is the
    union of ``parts[s]`` parts (its batches, its windows; those of segment
    s + 1 follow those of s) whose lower medians ``part_low`` and upper medians
    ``part_high`` are known. The lower median of a union lies between the
    least and the largest lower median of its parts, the upper median between
    those of the upper medians: at most Σ⌊(n_j − 1)/2⌋ ≤ ⌊(n − 1)/2⌋ values lie
    below the least, at least Σ⌈n_j/2⌉ ≥ ⌈n/2⌉ at or below the largest. So
    both are found among the segment's values within [least lower, largest
    upper] (the candidates: few where the parts agree) at their ranks less the
    values below; where the parts agree exactly, or a segment is one part,
    that value is the answer. Exact whatever the values; NaN for an empty segment.

    ``rows``: the values again as the sorted rows of a block
    (:func:`_sorted_rows`), and the first row of every segment (and the end):
    the candidates are then found in each row's run of them, else in ``values``.
    """
    lengths = np.diff(bounds)
    count = len(lengths)
    least = np.full(count, np.nan)
    largest = np.full(count, np.nan)
    with_parts = np.flatnonzero(parts > 0)
    if not len(with_parts):
        return least, largest
    first = (np.cumsum(parts) - parts)[with_parts]
    least[with_parts] = np.minimum.reduceat(part_low, first)
    largest[with_parts] = np.maximum.reduceat(part_high, first)
    least[lengths == 0] = np.nan
    largest[lengths == 0] = np.nan
    need = (parts > 1) & (least < largest)
    chosen = np.flatnonzero(need)
    if not len(chosen):
        return least, largest
    floor = np.where(need, least, np.inf)
    ceiling = np.where(need, largest, -np.inf)
    if rows is not None:  # sorted rows: the candidates are a run in each
        block, row_bounds = rows
        per_row = np.diff(row_bounds)
        # Per row, the values below the floor and those up to the ceiling (below the
        # next float), by a bisection in all rows at once.
        floor = np.repeat(floor, per_row)
        ceiling = np.nextafter(np.repeat(ceiling, per_row), np.inf)
        under, up_to = np.split(_count_below(block, np.concatenate((floor, ceiling))), 2)
        run = np.maximum(up_to - under, 0)
        below = np.add.reduceat(under, row_bounds[:-1])
        counts = np.add.reduceat(run, row_bounds[:-1])
        starts = np.arange(0, block.size, block.shape[1]) + under
        picked = block.ravel()[_sample_index(starts, run)]
    else:
        has = np.flatnonzero(lengths > 0)
        values = values[bounds[0] : bounds[-1]]
        floor = np.repeat(floor, lengths)
        ceiling = np.repeat(ceiling, lengths)
        starts = bounds[:-1][has] - bounds[0]
        below = np.zeros(count, dtype=np.intp)
        below[has] = np.add.reduceat(values < floor, starts, dtype=np.intp)
        candidate = values >= floor
        candidate &= values <= ceiling
        picked = values[candidate]
        counts = np.zeros(count, dtype=np.intp)
        counts[has] = np.add.reduceat(candidate, starts, dtype=np.intp)
        del candidate
    del floor, ceiling
    shift = below[chosen]
    least[chosen], largest[chosen] = _order_statistics(
        picked,
        np.concatenate(([0], np.cumsum(counts[chosen]))),
        (lengths[chosen] - 1) // 2 - shift,
        lengths[chosen] // 2 - shift,
    )
    return least, largest


def _medians(lengths: IntArray, low: FloatArray, high: FloatArray) -> FloatArray:
    """The median of every segment from its lower and upper median; NaN for an empty one."""
    with np.errstate(invalid="ignore"):
        middle = np.where(lengths % 2 == 1, low, (low + high) / 2)
    return np.where(lengths > 0, middle, np.nan)


def _grouped_medians(
    values: FloatArray, bounds: IntArray, low: FloatArray, quantum: float
) -> FloatArray:
    """:func:`grouped_median` of every segment of ``values``, from its lower median ``low``.

    ``bounds`` cut ``values`` into consecutive segments; NaN for an empty one.
    The arithmetic is :func:`grouped_median`'s, so the numbers are the same.
    """
    lengths = np.diff(bounds)
    result = np.full(len(lengths), np.nan)
    filled = np.flatnonzero(lengths > 0)
    if not len(filled):
        return result
    count = lengths[filled]
    low = low[filled]
    half = 0.5 * quantum
    start = bounds[:-1][filled] - bounds[0]
    level = np.repeat(low, count)
    values = values[bounds[0] : bounds[-1]]
    below = np.add.reduceat(values < level - half, start, dtype=np.intp)
    at = np.add.reduceat(np.abs(values - level) <= half, start, dtype=np.intp)
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
        windows: Its labelled windows (:func:`~ncmeasure.analysis.windows.finder.find_windows`).
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
    quantity: Literal["torque_nm", "current_a"] = (
        "torque_nm" if torque_constant_nm_per_a is not None else "current_a"
    )
    unit: Literal["Nm", "A"] = "Nm" if torque_constant_nm_per_a is not None else "A"
    scale = torque_constant_nm_per_a if torque_constant_nm_per_a is not None else 1.0
    count = len(windows)

    # Group key per window; windows sorted by key make every group's samples contiguous.
    position = np.fromiter(map(attrgetter("position_index"), windows), dtype=np.intp, count=count)
    direction = np.fromiter(map(attrgetter("direction"), windows), dtype=np.intp, count=count)
    step = np.fromiter(map(attrgetter("step"), windows), dtype=np.intp, count=count)
    velocity = np.fromiter(
        map(attrgetter("velocity_mm_min"), windows), dtype=np.float64, count=count
    )
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

    if window_current is not None:
        parts = [window_current[i] for i in order.tolist()]
        lengths = np.fromiter(map(len, parts), dtype=np.intp, count=count)
    else:  # the samples by index, a chunk at a time
        lengths = np.maximum(stop - start, 0)[order]
        start = start[order]
    quantised = current_quantum_a > 0
    # Chunks of whole groups, about _CHUNK_SAMPLES each: every statistic below works
    # on one chunk's samples at a time (little memory, in the processor's cache).
    window_of_group = np.concatenate(([0], np.flatnonzero(first[1:]) + 1, [count]))
    sample_bounds = np.concatenate(([0], np.cumsum(lengths)))
    cut = np.flatnonzero(np.diff(sample_bounds[window_of_group[:-1]] // _CHUNK_SAMPLES)) + 1
    chunk_groups = np.concatenate(([0], cut, [groups])).tolist() if groups else [0]
    # The batches of every window, were every sample finite (the usual case).
    batches_all = _batch_count(lengths)
    first_batch_all = np.concatenate(([0], np.cumsum(batches_all)))
    batch_bounds_all = _batch_bounds(sample_bounds)

    total = np.zeros(groups)
    squares = np.zeros(groups)
    per_window = np.zeros(count, dtype=np.intp)
    window_low = np.full(count, np.nan)
    window_high = np.full(count, np.nan)
    window_median = np.full(count, np.nan)
    group_low = np.full(groups, np.nan)
    group_high = np.full(groups, np.nan)
    median = np.full(groups, np.nan)
    batch_low: list[FloatArray] = [np.zeros(0)]
    batch_high: list[FloatArray] = [np.zeros(0)]
    batch_lengths: list[IntArray] = [np.zeros(0, dtype=np.intp)]
    batch_median: list[FloatArray] = [np.zeros(0)]
    offset = 0  # finite samples before the chunk
    for g0, g1 in itertools.pairwise(chunk_groups):
        w0, w1 = int(window_of_group[g0]), int(window_of_group[g1])
        if window_current is not None:
            values = np.concatenate(parts[w0:w1], dtype=np.float64)
        else:
            values = current[_sample_index(start[w0:w1], lengths[w0:w1])]
        # Every sample finite (the usual case) when every group's sum is: then the
        # windows and batches are those of all samples, else they are recounted.
        kept = lengths[w0:w1]
        window_bounds = sample_bounds[w0 : w1 + 1] - sample_bounds[w0]
        group_bounds = window_bounds[window_of_group[g0 : g1 + 1] - w0]
        n = np.diff(group_bounds)
        filled = np.flatnonzero(n > 0)
        sums = np.add.reduceat(values, group_bounds[filled]) if len(filled) else np.zeros(0)
        if np.isfinite(sums).all() and offset == sample_bounds[w0]:
            batches = batches_all[w0:w1]
            cuts = batch_bounds_all[first_batch_all[w0] : first_batch_all[w1] + 1] - offset
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
        per_window[w0:w1] = kept
        if len(filled):
            total[g0 + filled] = sums
            with np.errstate(invalid="ignore", divide="ignore"):
                deviation = np.repeat(sums / n[filled], n[filled])
            np.subtract(values, deviation, out=deviation)
            deviation *= deviation
            squares[g0 + filled] = np.add.reduceat(deviation, group_bounds[filled])
            del deviation

        # Batch medians from a sort of every batch (short rows); window and group
        # medians from their parts' medians and the few values between them.
        sizes = np.diff(cuts)
        block = _sorted_rows(values, sizes)
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
            low, high = _order_statistics(values, cuts, (sizes - 1) // 2, sizes // 2)
        batch_low.append(low)
        batch_high.append(high)
        batch_lengths.append(sizes)
        w_low, w_high = _within(values, window_bounds, low, high, batches, window_rows)
        window_low[w0:w1] = w_low
        window_high[w0:w1] = w_high
        used = kept > 0
        w_parts = np.add.reduceat(used, window_of_group[g0:g1] - w0, dtype=np.intp)
        group_low[g0:g1], group_high[g0:g1] = _within(
            values, group_bounds, w_low[used], w_high[used], w_parts, group_rows
        )
        if quantised:
            batch_median.append(_grouped_medians(values, cuts, low, current_quantum_a))
            window_median[w0:w1] = _grouped_medians(values, window_bounds, w_low, current_quantum_a)
            median[g0:g1] = _grouped_medians(
                values, group_bounds, group_low[g0:g1], current_quantum_a
            )
        offset += len(values)
        del values, block, window_rows, group_rows

    sizes = np.concatenate(batch_lengths)
    if not quantised:
        batch_median = [_medians(sizes, np.concatenate(batch_low), np.concatenate(batch_high))]
        window_median = _medians(per_window, window_low, window_high)
    n = np.zeros(groups, dtype=np.intp)
    if groups:
        n[:] = np.add.reduceat(per_window, window_of_group[:-1])
        if not quantised:
            median = _medians(n, group_low, group_high)
    used_windows = np.bincount(group_of_window[per_window > 0], minlength=groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / n
        variance = squares / (n - 1)
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
    group_velocity = velocity[order][first]
    filled_rows = n > 0
    head = keys[first][filled_rows]
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
