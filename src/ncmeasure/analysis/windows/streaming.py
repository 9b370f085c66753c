"""Exact whole-signal statistics of recordings too long to hold: medians, quanta, noise.

The segmentation needs statistics of a whole signal (the median time step,
the count of a quantised signal, the noise of its second differences). A
24 h recording at 1 kHz is 86 million rows, more than memory should hold, so
these statistics are computed here from the rows chunk by chunk, in a few
passes over the file, with memory bounded whatever the length, and *exactly*:
the same float as numpy on the whole array, bit for bit, so that an analysis
does not depend on how it was read.

A statistic is a *task*: a generator that, for every pass it needs, yields a
function to be fed every chunk in order, and finally returns its value.
:func:`run_tasks` runs many tasks together, reading the data once per pass
for all of them::

    def read():
        return (c.values[:, 0] for c in iter_chunks("run1", channels=("X_velocity_mm_min",)))

    found = run_tasks(read, {"median": median_task(whole), "count": quantum_task(whole)})

Each task takes a *view*: a factory of a fresh function from a chunk to the
values it looks at, so a view may carry state across chunk boundaries
(differences) and starts afresh every pass (:func:`differences`).

Medians are found by exact selection: a first pass counts the values and
keeps a bounded, evenly spaced subsample; the subsample brackets the middle
ranks; a second pass counts the values below the bracket and keeps those
inside it, and the middle values are picked from those. Where the bracket
misses or holds too many values (ties, data ordered against the subsample),
a histogram of the bracket narrows it pass by pass until it holds few enough,
unless the bracket holds few distinct values (ties: a signal standing still),
which the pass counts and picks the middle values from. The noise's second
median (of the deviations from the first) takes its subsample from the first's
values, so it needs no pass of its own for it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Hashable, Iterable, Iterator, Mapping
from fractions import Fraction
from typing import Any, Final, TypeVar

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "LATTICE_SHARE",
    "ExactSum",
    "Feed",
    "Task",
    "View",
    "chunks_of",
    "differences",
    "median_task",
    "noise_sigma_task",
    "quantum_task",
    "run_task",
    "run_tasks",
    "select_task",
    "whole",
]

FloatArray = NDArray[np.float64]
C = TypeVar("C")
R = TypeVar("R")
K = TypeVar("K", bound=Hashable)

Feed = Callable[[C], None]
"""Takes one chunk of a pass (chunks arrive in order)."""

Task = Generator[Callable[[C], None], None, R]
"""Yields the feed of each pass it needs, returns its value."""

View = Callable[[], Callable[[C], FloatArray]]
"""Makes, for one pass, a function from a chunk to the values a task looks at."""

LATTICE_SHARE: Final = 0.95
"""A signal is quantised when this share of its sample-to-sample steps are whole
multiples of its smallest step."""

SAMPLE_BUDGET: Final = 1 << 16
"""Values the first pass of a selection keeps at most (evenly spaced)."""

COLLECT_BUDGET: Final = 1 << 21
"""Values a pass of a selection keeps at most (16 MiB): a bracket holding more is narrowed."""

HISTOGRAM_CELLS: Final = 4096
"""Cells of the histogram that narrows a bracket holding too many values."""

DISTINCT_BUDGET: Final = 4096
"""Distinct values a pass of a selection counts at most once its bracket holds more values
than it keeps (ties): fewer, and the values at the ranks come from their counts."""


def run_tasks(read: Callable[[], Iterable[C]], tasks: Mapping[K, Task[C, Any]]) -> dict[K, Any]:
    """Run tasks together: one reading of the data per pass, shared by every task.

    Args:
        read: Returns the chunks anew, in the same order every time.
        tasks: The tasks by name.

    Returns:
        The value of every task, by name.
    """
    results: dict[K, Any] = {}
    feeds: dict[K, Callable[[C], None]] = {}

    def advance(key: K, task: Task[C, Any]) -> None:
        try:
            feeds[key] = next(task)
        except StopIteration as stop:
            feeds.pop(key, None)
            results[key] = stop.value

    for key, task in tasks.items():
        advance(key, task)
    while feeds:
        active = list(feeds.items())
        for chunk in read():
            for _, feed in active:
                feed(chunk)
        for key, _ in active:
            advance(key, tasks[key])
    return results


def run_task(read: Callable[[], Iterable[C]], task: Task[C, R]) -> R:
    """The value of one task (see :func:`run_tasks`)."""
    value: R = run_tasks(read, {0: task})[0]
    return value


def differences(view: View[C], order: int = 1) -> View[C]:
    """The ``order``-th differences of a view's values, carried across chunk boundaries.

    The same values as ``np.diff(whole, n=order)`` of the concatenated values.
    """

    def make() -> Callable[[C], FloatArray]:
        inner = view()
        tail = np.empty(0, dtype=np.float64)

        def apply(chunk: C) -> FloatArray:
            nonlocal tail
            values = inner(chunk)
            # Nothing carried (the first chunk, or a recording read as one): no copy.
            joined = np.concatenate((tail, values)) if len(tail) else np.asarray(values, np.float64)
            tail = (joined[-order:] if len(joined) >= order else joined).copy()
            if len(joined) <= order:
                return np.empty(0, dtype=np.float64)
            return np.diff(joined, n=order)

        return apply

    return make


def _mapped(view: View[C], function: Callable[[FloatArray], FloatArray]) -> View[C]:
    def make() -> Callable[[C], FloatArray]:
        inner = view()
        return lambda chunk: function(inner(chunk))

    return make


def _feeding(
    add: Callable[[FloatArray], None], apply: Callable[[C], FloatArray]
) -> Callable[[C], None]:
    """A pass's feed: the view's values of every chunk to ``add``."""
    return lambda chunk: add(apply(chunk))


# --- exact selection -------------------------------------------------------------------


class _Sampler:
    """First pass: count, range and an evenly spaced subsample of at most a budget."""

    def __init__(self, budget: int) -> None:
        self.budget = budget
        self.count = 0
        self.stride = 1
        self.kept: list[FloatArray] = []
        self.held = 0
        self.low = math.inf
        self.high = -math.inf

    def add(self, values: FloatArray) -> None:
        if len(values) == 0:
            return
        self.low = min(self.low, float(values.min()))
        self.high = max(self.high, float(values.max()))
        # Keep the values whose index in the whole stream is a multiple of the stride.
        offset = (-self.count) % self.stride
        picked = values[offset :: self.stride]
        self.count += len(values)
        self.kept.append(np.array(picked, dtype=np.float64, copy=True))
        self.held += len(picked)
        while self.held > self.budget:
            # Every second kept value: those at multiples of twice the stride.
            joined = np.concatenate(self.kept)
            self.kept = [joined[::2].copy()]
            self.held = len(self.kept[0])
            self.stride *= 2

    def sample(self) -> FloatArray:
        return np.sort(np.concatenate(self.kept)) if self.kept else np.empty(0)

    def deviations(self, centre: float) -> _Sampler:
        """The first pass of the values |v − centre| of the same values, without a pass.

        The same indices are kept (the values at multiples of the stride), so the
        subsample is as evenly spaced; the range is a bound: from 0 to the farther
        end of this one's (|v − c| grows away from c, rounding too)."""
        shifted = _Sampler(self.budget)
        shifted.count = self.count
        shifted.stride = self.stride
        if self.kept:
            shifted.kept = [np.abs(np.concatenate(self.kept) - centre)]
            shifted.held = len(shifted.kept[0])
            shifted.low = 0.0
            shifted.high = max(abs(self.low - centre), abs(self.high - centre))
        return shifted


class _Bracket:
    """A pass over a bracket [low, high]: counts below and inside, a histogram, the values."""

    def __init__(
        self, low: float, high: float, budget: int, cells: int, distinct: int = DISTINCT_BUDGET
    ) -> None:
        self.low, self.high = low, high
        self.budget = budget
        self.below = 0
        self.inside = 0
        self.values: list[FloatArray] | None = []
        # Once more values than kept: the distinct values inside and their counts, sorted,
        # while there are at most ``distinct`` of them (else None).
        self.distinct_budget = distinct
        self.distinct: tuple[FloatArray, NDArray[np.int64]] | None = (
            np.empty(0, dtype=np.float64),
            np.empty(0, dtype=np.int64),
        )
        self.edges = np.linspace(low, high, cells + 1) if high > low and cells else None
        self.histogram = np.zeros(cells + 1, dtype=np.int64)
        self.smallest = math.inf
        self.largest = -math.inf

    def add(self, values: FloatArray) -> None:
        self.below += int(np.count_nonzero(values < self.low))
        inside = values[(values >= self.low) & (values <= self.high)]
        self.inside += len(inside)
        if len(inside):
            self.smallest = min(self.smallest, float(inside.min()))
            self.largest = max(self.largest, float(inside.max()))
        if self.values is not None:
            if self.inside <= self.budget:
                self.values.append(inside)
            else:
                for part in (*self.values, inside):
                    self._count(part)
                self.values = None
        elif len(inside):
            self._count(inside)
        if self.edges is not None and len(inside):
            # Cell k holds edges[k] <= v < edges[k + 1]; the last one v == high.
            cell = np.searchsorted(self.edges, inside, side="right") - 1
            self.histogram += np.bincount(cell, minlength=len(self.histogram))

    def _count(self, values: FloatArray) -> None:
        """Add values to the counts of the distinct values (given up beyond the budget)."""
        if self.distinct is None or len(values) == 0:
            return
        keys, counts = self.distinct
        if len(keys):
            spot = np.minimum(np.searchsorted(keys, values), len(keys) - 1)
            known = keys[spot] == values
            counts = counts + np.bincount(spot[known], minlength=len(keys))
            values = values[~known]
        if len(values):
            new, number = np.unique(values, return_counts=True)
            if len(keys) + len(new) > self.distinct_budget:
                self.distinct = None
                return
            keys = np.concatenate((keys, new))
            counts = np.concatenate((counts, number))
            order = np.argsort(keys, kind="stable")
            keys, counts = keys[order], counts[order]
        self.distinct = (keys, counts)


def select_task(
    view: View[C],
    ranks: Callable[[int], tuple[int, ...]],
    *,
    sample_budget: int = SAMPLE_BUDGET,
    collect_budget: int = COLLECT_BUDGET,
    sampled: _Sampler | None = None,
) -> Generator[Callable[[C], None], None, tuple[int, list[float]]]:
    """The values at some ranks (0 = smallest) of all values of a view, exactly.

    Args:
        view: The values (finite).
        ranks: The ranks wanted, from the number of values (known after the
            first pass); each below that number.
        sample_budget: Values the first pass keeps at most.
        collect_budget: Values a later pass keeps at most.
        sampled: The first pass already made (its subsample of the view's values).

    Returns:
        The number of values and the values at the ranks (an empty list
        without values).
    """
    sampler = sampled
    if sampler is None:
        sampler = _Sampler(sample_budget)
        yield _feeding(sampler.add, view())
    count = sampler.count
    if count == 0:
        return 0, []
    wanted = ranks(count)
    first, last = min(wanted), max(wanted)
    sample = sampler.sample()
    stride = sampler.stride
    margin = max(8, len(sample) // 256)
    below_index = first // stride - margin
    above_index = last // stride + margin
    low = sampler.low if below_index <= 0 else float(sample[below_index])
    high = sampler.high if above_index >= len(sample) - 1 else float(sample[above_index])
    ties = _ties(sample, stride, first, last, (low, high), collect_budget)
    while True:
        bracket = _Bracket(low, high, collect_budget, HISTOGRAM_CELLS)
        # Beside it, the first time, a bracket about the ranks alone (ties: few distinct values).
        tie = _Bracket(*ties, collect_budget, 0) if ties is not None else None
        ties = None
        feed = _feeding(bracket.add if tie is None else _both(bracket, tie), view())
        yield feed
        if tie is not None:
            picked = _picked(tie, first, last, wanted)
            if picked is not None:
                return count, picked
        below, inside = bracket.below, bracket.inside
        if below > first and below + inside <= last:
            # The ranks on both sides of the bracket: the whole range.
            low, high = sampler.low, sampler.high
            continue
        if below > first:
            # A rank below the bracket: the next stretch of the subsample below it, the
            # bracket kept where another rank lies in it (moving past that rank would lose
            # it, and the next bracket would move back: the bracket only grows).
            index = int(np.searchsorted(sample, low)) - 1 - margin
            if below > last:
                high = float(np.nextafter(low, -np.inf))
            low = sampler.low if index <= 0 else float(sample[index])
            continue
        if below + inside <= last:
            # A rank above the bracket: the next stretch of the subsample above it, the
            # bracket kept where another rank lies in it.
            index = int(np.searchsorted(sample, high, side="right")) + margin
            if below + inside <= first:
                low = float(np.nextafter(high, np.inf))
            high = sampler.high if index >= len(sample) - 1 else float(sample[index])
            continue
        picked = _picked(bracket, first, last, wanted)
        if picked is not None:
            return count, picked
        assert bracket.edges is not None
        cumulative = np.cumsum(bracket.histogram)
        cell_first = int(np.searchsorted(cumulative, first - below, side="right"))
        cell_last = int(np.searchsorted(cumulative, last - below, side="right"))
        edges = bracket.edges
        new_low = max(float(edges[cell_first]), bracket.smallest)
        new_high = (
            high
            if cell_last >= len(edges) - 1
            else float(np.nextafter(edges[cell_last + 1], -np.inf))
        )
        new_high = max(min(new_high, bracket.largest), new_low)
        if (new_low, new_high) == (low, high):
            # No narrower bracket between neighbouring floats: count the few distinct values.
            picked = yield from _distinct(view, low, high, below, wanted)
            return count, picked
        low, high = new_low, new_high


def _both(one: _Bracket, other: _Bracket) -> Callable[[FloatArray], None]:
    def add(values: FloatArray) -> None:
        one.add(values)
        other.add(values)

    return add


def _ties(
    sample: FloatArray,
    stride: int,
    first: int,
    last: int,
    bracket: tuple[float, float],
    budget: int,
) -> tuple[float, float] | None:
    """A narrow bracket about the ranks where the subsample says the wide one holds too many.

    The values of the subsample next to the ranks wanted: where the signal is mostly
    ties (a position standing still), these are few distinct values, which a pass
    counts (:class:`_Bracket`) while the wide bracket would overflow.
    """
    low, high = bracket
    held = int(np.searchsorted(sample, high, side="right") - np.searchsorted(sample, low))
    if held * stride <= budget or len(sample) == 0:
        return None
    narrow = (
        float(sample[max(0, first // stride - 8)]),
        float(sample[min(len(sample) - 1, last // stride + 8)]),
    )
    return narrow if narrow != bracket else None


def _picked(
    bracket: _Bracket, first: int, last: int, wanted: tuple[int, ...]
) -> list[float] | None:
    """The values at the ranks from a pass over a bracket, where it holds them and tells them."""
    below, inside = bracket.below, bracket.inside
    if below > first or below + inside <= last:
        return None
    if bracket.smallest == bracket.largest:
        return [bracket.smallest] * len(wanted)
    if bracket.values is not None:
        values = np.sort(np.concatenate(bracket.values))
        return [float(values[r - below]) for r in wanted]
    if bracket.distinct is not None:
        keys, counts = bracket.distinct
        cumulative = np.cumsum(counts)
        return [
            float(keys[int(np.searchsorted(cumulative, r - below, side="right"))]) for r in wanted
        ]
    return None


def _distinct(
    view: View[C], low: float, high: float, below: int, ranks: tuple[int, ...]
) -> Generator[Callable[[C], None], None, list[float]]:
    """The values at ``ranks`` from the counts of the distinct values in [low, high]."""
    counts: dict[float, int] = {}
    apply = view()

    def add(chunk: C) -> None:
        values = apply(chunk)
        inside = values[(values >= low) & (values <= high)]
        for value, number in zip(*np.unique(inside, return_counts=True), strict=True):
            counts[float(value)] = counts.get(float(value), 0) + int(number)

    yield add
    keys = sorted(counts)
    cumulative = np.cumsum([counts[k] for k in keys])
    return [keys[int(np.searchsorted(cumulative, r - below, side="right"))] for r in ranks]


def _middle_ranks(count: int) -> tuple[int, int]:
    return (count - 1) // 2, count // 2


def median_task(
    view: View[C], *, sample_budget: int = SAMPLE_BUDGET, collect_budget: int = COLLECT_BUDGET
) -> Generator[Callable[[C], None], None, float]:
    """The median of all values of a view, as ``np.median`` gives it (NaN without values).

    The values must be finite (``np.median`` of data with NaN is NaN).
    """
    return (
        yield from _median(view, None, sample_budget=sample_budget, collect_budget=collect_budget)
    )


def _median(
    view: View[C],
    sampled: _Sampler | None,
    *,
    sample_budget: int = SAMPLE_BUDGET,
    collect_budget: int = COLLECT_BUDGET,
) -> Generator[Callable[[C], None], None, float]:
    """:func:`median_task`, its first pass already made where ``sampled`` is given."""
    count, (low, high) = yield from _pair(
        select_task(
            view,
            _middle_ranks,
            sample_budget=sample_budget,
            collect_budget=collect_budget,
            sampled=sampled,
        )
    )
    if count == 0:
        return math.nan
    if low == high:
        return low
    # np.median of an even count: the mean of the two middle values, (a + b) / 2.
    return float(np.mean(np.array([low, high], dtype=np.float64)))


def _pair(
    task: Generator[Callable[[C], None], None, tuple[int, list[float]]],
) -> Generator[Callable[[C], None], None, tuple[int, tuple[float, float]]]:
    count, picked = yield from task
    if count == 0:
        return 0, (math.nan, math.nan)
    return count, (picked[0], picked[1])


# --- the statistics of the segmentation --------------------------------------------


def quantum_task(view: View[C]) -> Generator[Callable[[C], None], None, float]:
    """The resolution of a quantised signal (one count), or 0 for a continuous one.

    ``view`` gives the signal's finite values in order. A signal is quantised
    when nearly all (:data:`LATTICE_SHARE`) of its non-zero sample-to-sample
    steps are whole multiples of the smallest one: a velocity read in counts
    of 8.5 mm/min, a current in per mille of the rated current. Steps below
    10⁻⁹ of the signal's range are rounding noise of the unit conversion, not
    steps. The count is the sum of the lattice steps over the sum of their
    multiples, summed exactly (so it does not depend on the chunks).
    """
    count = 0
    scale = 0.0
    apply = view()

    def first(chunk: C) -> None:
        nonlocal count, scale
        values = apply(chunk)
        count += len(values)
        if len(values):
            scale = max(scale, float(np.max(np.abs(values))))

    yield first
    if count < 3:
        return 0.0
    floor = 1e-9 * scale
    steps_view = _mapped(differences(view), np.abs)
    steps = 0
    smallest = math.inf
    apply = steps_view()

    def second(chunk: C) -> None:
        nonlocal steps, smallest
        values = apply(chunk)
        values = values[values > floor]
        steps += len(values)
        if len(values):
            smallest = min(smallest, float(values.min()))

    yield second
    if steps < 10:
        return 0.0
    on_count = 0
    multiples = 0.0
    total = ExactSum()
    apply = steps_view()

    def third(chunk: C) -> None:
        nonlocal on_count, multiples
        values = apply(chunk)
        values = values[values > floor]
        ratio = values / smallest
        nearest = np.round(ratio)
        on = np.abs(ratio - nearest) <= 0.02
        on_count += int(np.count_nonzero(on))
        # Whole numbers below 2**53: their float sum is exact in any order.
        multiples += float(np.sum(nearest[on]))
        total.add(values[on])

    yield third
    if on_count < LATTICE_SHARE * steps:
        return 0.0
    return total.value() / multiples


class ExactSum:
    """The exact sum of many floats, rounded once at the end: the same in any order.

    Every float is m·2^(e−53) with an integer m below 2^53 (``np.frexp``); the
    integers are summed per exponent as Python integers, so nothing is lost
    whatever the chunks.
    """

    def __init__(self) -> None:
        self.by_exponent: dict[int, int] = {}

    def add(self, values: FloatArray) -> None:
        """Add every value (finite)."""
        if len(values) == 0:
            return
        mantissa, exponent = np.frexp(np.asarray(values, dtype=np.float64))
        whole = (mantissa * float(1 << 53)).astype(np.int64)
        for e in np.unique(exponent).tolist():
            part = whole[exponent == e]
            # Blocks of 512: a block sum stays below 2**62, then Python integers.
            sums = np.add.reduceat(part, np.arange(0, len(part), 512))
            self.by_exponent[e] = self.by_exponent.get(e, 0) + sum(sums.tolist())

    def value(self) -> float:
        """The sum, correctly rounded."""
        total = Fraction(0)
        for e, m in self.by_exponent.items():
            total += Fraction(m) * (Fraction(2) ** (e - 53))
        return float(total)


def noise_sigma_task(view: View[C]) -> Generator[Callable[[C], None], None, float]:
    """Robust standard deviation of a signal's sample-to-sample noise (0 under 5 values).

    ``view`` gives the signal's finite values in order. From second
    differences (zero on a constant level and on a ramp), scaled by the median
    absolute deviation: v[i+1] − 2v[i] + v[i−1] of white noise of σ has the
    standard deviation √6·σ.
    """
    second = differences(view, 2)
    sampler = _Sampler(SAMPLE_BUDGET)
    yield _feeding(sampler.add, second())
    centre = yield from _median(second, sampler)
    if math.isnan(centre):
        return 0.0
    # The deviations' subsample from the same pass: the same values, shifted.
    mad = yield from _median(
        _mapped(second, lambda d: np.abs(d - centre)), sampler.deviations(centre)
    )
    if math.isnan(mad):
        return 0.0
    return 1.4826 * mad / math.sqrt(6.0)


def chunks_of(values: FloatArray, rows: int) -> Callable[[], Iterator[FloatArray]]:
    """A reader of an array in chunks of ``rows`` (tests, and arrays already in memory)."""
    return lambda: (values[i : i + rows] for i in range(0, max(len(values), 1), rows))


def identity(chunk: FloatArray) -> FloatArray:
    """A view's function that looks at the chunk itself."""
    return chunk


def whole() -> Callable[[FloatArray], FloatArray]:
    """The view of a reader of 1-D arrays: every value as it comes."""
    return identity
