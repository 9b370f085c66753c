"""Exact medians of many segments at once: batches, windows and groups of the friction table.

The batches of a chunk are sorted as the rows of one padded block
(:func:`sorted_rows`: numpy sorts short rows with vectorised sorting networks),
which gives their medians. The medians of windows and groups are *selected*,
not sorted for: the median of a union lies between the least and the largest
median of its parts (:func:`medians_within`), so each segment needs only its
values between its parts' medians, counted and picked in the sorted rows by a
bisection in all rows at once, and those few are sorted. Every median is the
exact order statistic. With a quantised current the medians are medians of
grouped data (:func:`grouped_medians`).
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "count_below",
    "grouped_medians",
    "medians_within",
    "middle",
    "order_statistics",
    "sample_index",
    "sorted_rows",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

_PAD_WASTE: Final = 2
"""A padded block holds at most this many slots per value (plus :data:`_PAD_SLACK`)."""
_PAD_SLACK: Final = 1 << 16


def sample_index(starts: IntArray, lengths: IntArray) -> IntArray:
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


def sorted_rows(values: FloatArray, lengths: IntArray) -> FloatArray | None:
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


def count_below(block: FloatArray, threshold: FloatArray) -> IntArray:
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


def order_statistics(
    values: FloatArray, bounds: IntArray, low_rank: IntArray, high_rank: IntArray
) -> tuple[FloatArray, FloatArray]:
    """Two order statistics of every segment ``values[bounds[s]:bounds[s + 1]]``.

    ``low_rank[s]`` and ``high_rank[s]`` are 0-based ranks within segment s
    (the ``low_rank[s]``-th smallest value), each below its length; NaN for an
    empty segment. The segments are sorted as the rows of padded blocks
    (:func:`sorted_rows`): all at once, or, where their lengths differ
    widely, in blocks of segments up to :data:`_PAD_WASTE` times as long as
    the shortest of each.
    """
    values = values[bounds[0] : bounds[-1]]
    lengths = np.diff(bounds)
    count = len(lengths)
    low = np.full(count, np.nan)
    high = np.full(count, np.nan)
    block = sorted_rows(values, lengths)
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
        block = sorted_rows(
            values[sample_index(bounds[rows] - bounds[0], row_lengths)], row_lengths
        )
        assert block is not None  # lengths within a factor _PAD_WASTE
        at = np.arange(len(rows))
        low[rows] = block[at, low_rank[rows]]
        high[rows] = block[at, high_rank[rows]]
        first = end
    return low, high


def medians_within(
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
    (:func:`sorted_rows`), and the first row of every segment (and the end):
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
        under, up_to = np.split(count_below(block, np.concatenate((floor, ceiling))), 2)
        run = np.maximum(up_to - under, 0)
        below = np.add.reduceat(under, row_bounds[:-1])
        counts = np.add.reduceat(run, row_bounds[:-1])
        starts = np.arange(0, block.size, block.shape[1]) + under
        picked = block.ravel()[sample_index(starts, run)]
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
    least[chosen], largest[chosen] = order_statistics(
        picked,
        np.concatenate(([0], np.cumsum(counts[chosen]))),
        (lengths[chosen] - 1) // 2 - shift,
        lengths[chosen] // 2 - shift,
    )
    return least, largest


def middle(lengths: IntArray, low: FloatArray, high: FloatArray) -> FloatArray:
    """The median of every segment from its lower and upper median; NaN for an empty one."""
    with np.errstate(invalid="ignore"):
        middle = np.where(lengths % 2 == 1, low, (low + high) / 2)
    return np.where(lengths > 0, middle, np.nan)


def grouped_medians(
    values: FloatArray, bounds: IntArray, low: FloatArray, quantum: float
) -> FloatArray:
    """:func:`~ncmeasure.analysis.friction.table.grouped_median` of every segment, from ``low``.

    ``bounds`` cut ``values`` into consecutive segments; NaN for an empty one.
    The arithmetic is the same, so are the numbers.
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
