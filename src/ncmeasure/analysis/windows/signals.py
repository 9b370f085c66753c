"""Vectorised helpers on signals: runs of a mask, clusters, bands, the position's velocity.

Loops run over windows or clusters, never over samples.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from typing import Final

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.model import Cluster
from ncmeasure.analysis.windows.rolling import rolling_max, rolling_min
from ncmeasure.analysis.windows.settings import HOLE_NEIGHBOURS, HOLE_PERIODS

__all__ = [
    "HoleCounter",
    "align",
    "cluster_gaps",
    "clusters_of",
    "command_repeats",
    "correlated_noise",
    "hole_rows",
    "nan_median",
    "odd",
    "plateau_mask",
    "position_velocity",
    "runs",
    "segment_sums",
    "unit_factor",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]


def nan_median(values: FloatArray) -> float:
    """``np.nanmedian`` of a 1-D array, without its cost where no value is NaN.

    ``np.nanmedian`` of an array without NaN is ``np.median`` of it (the same
    float); the check for NaN first is a third of its time on a window's samples.
    """
    if len(values) and not np.isnan(values).any():
        return float(np.median(values))
    return float(np.nanmedian(values))


def runs(mask: BoolArray) -> tuple[IntArray, IntArray]:
    """Start and stop (exclusive) indices of the runs of True in ``mask``."""
    edges = np.diff(mask.astype(np.int8), prepend=np.int8(0), append=np.int8(0))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def hole_rows(time_s: FloatArray, period_s: float, before_s: Sequence[float] = ()) -> IntArray:
    """Indices into ``time_s`` of the rows that follow a hole of the time axis.

    A hole is a time step longer than :data:`HOLE_PERIODS` times the sample
    period ``period_s`` and than the step before it: the files of an import may
    differ in sample period (the recording's is their median step), and a file
    sampled more slowly is no run of holes; its first step after the gap into it
    is no hole either. ``before_s``: the times of the (up to two) rows before
    ``time_s[0]``, in order; a recording's first step has the period before it.
    """
    earlier = [float(t) for t in before_s][-2:]
    times = np.concatenate((earlier, np.asarray(time_s, dtype=np.float64)))
    steps = np.diff(times)
    previous = np.concatenate(([period_s], steps[:-1]))
    if len(earlier) == 2:
        previous[0] = earlier[1] - earlier[0]
    hole = steps > HOLE_PERIODS * np.maximum(period_s, previous)
    found: IntArray = np.flatnonzero(hole) + 1 - len(earlier)
    return found


class HoleCounter:
    """Holes of a time axis given chunk by chunk, and the samples lost in them.

    A hole is a time step longer than :data:`HOLE_PERIODS` times the regular
    period around it: the median of the :data:`HOLE_NEIGHBOURS` steps before it
    or of those after it, the larger (those there are at the ends of the axis;
    the nominal period where the axis has one step). It lost round(step /
    regular period) − 1 samples. So a file sampled more slowly than the one
    before it in an import is no run of holes, nor is the step into it, and
    each step of an outage broken by a sample or a few is a hole of its own,
    divided by the sampling period (a step against the step before it saw 0.2 s
    after 0.204 s at 4 ms as none). A step that ends at one of ``starts_s`` (the
    start of another file of an import) is no hole. A step is judged once the
    steps after it are in (:meth:`finish` judges the last ones): the counts are
    the same in chunks of any size.
    """

    def __init__(self, period_s: float, starts_s: FloatArray) -> None:
        self.period_s = period_s
        self.starts_s = np.asarray(starts_s, dtype=np.float64)
        self.holes = 0
        self.lost = 0
        # The times of the steps not yet judged, after those of the steps before them.
        self._times = np.empty(0, dtype=np.float64)
        self._judged = 0  # steps at the start of _times already judged (their neighbours)

    def feed(self, time_s: FloatArray) -> None:
        """Count the holes among the steps that have their neighbours after them now."""
        self._times = np.concatenate((self._times, np.asarray(time_s, dtype=np.float64)))
        self._judge(final=False)

    def finish(self) -> tuple[int, int]:
        """Judge the last steps; the holes and the samples lost in them."""
        self._judge(final=True)
        return self.holes, self.lost

    def _judge(self, *, final: bool) -> None:
        k = HOLE_NEIGHBOURS
        steps = np.diff(self._times)
        end = len(steps) if final else len(steps) - k
        if end <= self._judged:
            return
        # A step can only be a hole if longer than HOLE_PERIODS times the shortest
        # step about it (no longer than their median): only those need the median.
        padded = np.concatenate((np.full(k, np.inf), steps, np.full(k, np.inf)))
        shortest = rolling_min(padded, 2 * k + 1)[k : k + len(steps)]
        rows = np.arange(self._judged, end)
        rows = rows[steps[rows] > HOLE_PERIODS * shortest[rows]]
        if len(rows):
            self._count(steps, rows)
        keep = max(0, end - k)  # the times of the k steps before the next to judge
        self._times = self._times[keep:]
        self._judged = end - keep

    def _count(self, steps: FloatArray, rows: IntArray) -> None:
        k = HOLE_NEIGHBOURS
        padded = np.concatenate((np.full(k, np.nan), steps, np.full(k, np.nan)))
        for block in np.array_split(rows, max(1, len(rows) // 65536)):
            regular = np.fmax(
                _median_of(padded[block[:, None] + np.arange(k)[None, :]]),
                _median_of(padded[block[:, None] + k + np.arange(1, k + 1)[None, :]]),
            )
            regular[np.isnan(regular)] = self.period_s
            hole = steps[block] > HOLE_PERIODS * regular
            hole &= ~np.isin(self._times[block + 1], self.starts_s)
            self.holes += int(hole.sum())
            self.lost += int(np.sum(np.round(steps[block][hole] / regular[hole]) - 1))


def _median_of(rows: FloatArray) -> FloatArray:
    """The median of every row's numbers (NaN where it has none)."""
    found = np.full(len(rows), np.nan)
    some = ~np.isnan(rows).all(axis=1)
    if some.any():
        found[some] = np.nanmedian(rows[some], axis=1)
    return found


def segment_sums(values: FloatArray, holes: IntArray, carry: float) -> tuple[FloatArray, float]:
    """The running sum of ``values`` that starts again at 0 on every row of ``holes``.

    Sums from ``carry`` up to the first hole (the sum of the rows before, e.g. of the
    chunk before); a sequential sum, so the same bits in chunks of any size. Returns
    the sums and the carry of the rows after.
    """
    bounds = [0, *np.asarray(holes).tolist(), len(values)]
    parts = [
        np.cumsum(np.concatenate(([carry if k == 0 else 0.0], values[a:b])))[1:]
        for k, (a, b) in enumerate(itertools.pairwise(bounds))
    ]
    summed = np.asarray(np.concatenate(parts), dtype=np.float64)
    return summed, float(summed[-1]) if len(summed) else carry


def align(ok: BoolArray) -> list[int | None]:
    """Match rows (found windows) to columns (planned windows), both in program order.

    The most pairs ``ok[i, j]`` such that the order is kept on both sides (a
    longest common subsequence, by dynamic programming row by row). A greedy
    match would let one stray stretch (a warm-up stroke at a measured velocity)
    jump ahead in the schedule and lose every window before the one it took.
    Among equally long alignments, later rows take the later columns.
    """
    rows, cols = ok.shape
    table = np.zeros((rows + 1, cols + 1), dtype=np.int64)
    for i in range(1, rows + 1):
        best = np.maximum(table[i - 1, 1:], table[i - 1, :-1] + ok[i - 1])
        table[i, 1:] = np.maximum.accumulate(best)
    result: list[int | None] = [None] * rows
    i, j = rows, cols
    while i > 0 and j > 0:
        if ok[i - 1, j - 1] and table[i, j] == table[i - 1, j - 1] + 1:
            result[i - 1] = j - 1
            i, j = i - 1, j - 1
        elif table[i, j] == table[i - 1, j]:
            i -= 1
        else:
            j -= 1
    return result


VARIOGRAM_SHARE: Final = 8
"""The noise's variogram is read up to this share of a stretch's length: longer lags hold
few independent differences, and a step between two levels weighs in more."""


def correlated_noise(values: FloatArray) -> tuple[float, float]:
    """Standard deviation and lag-1 autocorrelation of a stretch's noise.

    For a stationary noise of standard deviation σ and autocorrelation ρ at lag 1
    (ρ² at lag 2, as a drive's moving average gives), the first differences have
    the variance 2σ²(1 − ρ) and the second ones 2σ²(1 − ρ)(3 − ρ): their ratio
    is 3 − ρ, whatever σ. So ρ = 3 − var₂/var₁ and σ = √(var₁ / (2(1 − ρ))).
    White noise gives ρ ≈ 0 and the plain second-difference figure; a drive's
    averaged velocity (ρ of 0.7 to 0.9) gives the 1.8 to 3.5 times larger σ
    that second differences alone miss. The variances are mean squares, not
    median deviations (of a velocity in counts most differences are 0 or one
    count, where a median says nothing), without the differences beyond five
    times the typical one (a step between two levels, a spike). ρ is held to
    0 .. 0.95, and σ to at most the scatter around the stretch's median.
    Returns (0, 0) under 5 finite values or on a constant level.
    """
    data = np.asarray(values, dtype=np.float64)
    data = data[np.isfinite(data)]
    if len(data) < 5:
        return 0.0, 0.0
    var1 = _trimmed_square(np.diff(data))
    var2 = _trimmed_square(np.diff(data, n=2))
    if var1 <= 0.0 or var2 <= 0.0:
        return 0.0, 0.0
    rho = min(max(3.0 - var2 / var1, 0.0), 0.95)
    sigma = math.sqrt(var1 / (2.0 * (1.0 - rho)))
    # White readings (counts, an encoder's differences) on top of a correlated wobble (a
    # speed loop's ripple) make the differences look white and hide the wobble: the
    # differences over longer lags (the variogram) grow until the lag exceeds the noise's
    # correlation, and level off at 2σ². Their largest mean square, trimmed like the
    # others, holds σ whatever the mixture.
    lag = 2
    while lag <= len(data) // VARIOGRAM_SHARE:
        wide = math.sqrt(_trimmed_square(data[lag:] - data[:-lag]) / 2.0)
        if wide > sigma:
            sigma = wide
            rho = min(max(1.0 - var1 / (2.0 * sigma * sigma), 0.0), 0.95)
        lag *= 2
    # Where 1 − ρ is small its estimate is uncertain: the scatter around the median
    # (the level of a steady stretch) bounds σ; a step between levels does not count
    # there, the differences hold σ down.
    direct = math.sqrt(_trimmed_square(data - float(np.median(data))))
    return min(sigma, direct), rho


def _trimmed_square(differences: FloatArray) -> float:
    """Mean square of the differences, without those beyond 5 × the middle 90 %'s RMS."""
    size = np.abs(differences)
    middle = size[size <= np.quantile(size, 0.9)]
    typical = math.sqrt(float(np.mean(middle**2))) if len(middle) else 0.0
    kept = size[size <= 5.0 * typical] if typical > 0 else middle
    return float(np.mean(kept**2)) if len(kept) else 0.0


def odd(count: float) -> int:
    size = max(1, round(count))
    return size if size % 2 else size + 1


def unit_factor(ratios: Sequence[float]) -> float | None:
    """The common factor of position rate over velocity, when the ratios share one.

    A position in another unit moves every window by the same factor (25.4, 1000,
    0.001); frozen readings at standstill give ratios near 0, and an axis that
    did not follow its command gives scattered ones: no factor then.
    """
    values = np.array([r for r in ratios if math.isfinite(r) and r > 0], dtype=np.float64)
    if len(values) < max(2, 0.8 * len(ratios)):
        return None
    logs = np.log(values)
    centre = float(np.median(logs))
    if abs(centre) < math.log(1.2) or float(np.max(np.abs(logs - centre))) > math.log(1.1):
        return None
    return math.exp(centre)


def cluster_gaps(values: Sequence[float] | FloatArray, gaps: FloatArray | float) -> IntArray:
    """Gap-based 1-D clustering: sorted values split where neighbours are further apart.

    Args:
        values: The values (any order).
        gaps: The largest distance inside a cluster: one number, or one per
            value, applying to the gap *below* that value in sorted order.

    Returns:
        The cluster index of every value, 0 for the lowest cluster, in the
        order of ``values``.
    """
    data = np.asarray(values, dtype=np.float64)
    labels = np.zeros(len(data), dtype=np.intp)
    if len(data) < 2:
        return labels
    order = np.argsort(data, kind="stable")
    ordered = data[order]
    limit = np.broadcast_to(np.asarray(gaps, dtype=np.float64), data.shape)[order]
    breaks = np.diff(ordered) > limit[1:]
    labels[order] = np.concatenate(([0], np.cumsum(breaks)))
    return labels


def clusters_of(values: FloatArray, labels: IntArray) -> list[Cluster]:
    result = []
    for index in range(int(labels.max()) + 1 if len(labels) else 0):
        members = values[labels == index]
        result.append(
            Cluster(
                index=index,
                centre=float(np.median(members)),
                low=float(members.min()),
                high=float(members.max()),
                windows=len(members),
            )
        )
    return result


def position_velocity(
    time_s: FloatArray, position_mm: FloatArray, h: int, lo: int, hi: int, offset: int, n: int
) -> FloatArray:
    """Velocity from the position by central differences over ±h rows, in mm/min.

    For the rows ``lo`` .. ``hi`` of a recording of ``n`` rows, from arrays that
    hold its rows from ``offset`` on (at least ``lo − h`` .. ``hi + h``, clipped
    to the recording): the same values whether the arrays hold the whole
    recording or a stretch of it.
    """
    rows = np.arange(lo, hi)
    ahead = np.minimum(rows + h, n - 1) - offset
    behind = np.maximum(rows - h, 0) - offset
    span = time_s[ahead] - time_s[behind]
    with np.errstate(invalid="ignore", divide="ignore"):
        velocity = np.where(span > 0, (position_mm[ahead] - position_mm[behind]) / span * 60.0, 0.0)
    return np.asarray(velocity, dtype=np.float64)


def command_repeats(command: FloatArray) -> BoolArray:
    """Per row after the first: whether it repeats the row before (within rounding)."""
    jump = np.abs(np.diff(command))
    limit = 1e-4 * np.abs(command[1:]) + 1e-3
    repeats: BoolArray = jump <= limit
    return repeats


def plateau_mask(
    smooth: FloatArray,
    band: Callable[[FloatArray], FloatArray],
    standstill: float,
    length: int,
    n: int,
    offset: int = 0,
) -> BoolArray:
    """The rows covered by a flat span of ``length`` rows of the smoothed velocity.

    ``smooth`` holds the rows ``offset`` .. ``offset + len(smooth)`` of a
    recording of ``n`` rows. A row's value needs the smoothed velocity
    ``length`` rows either side: it is exact where ``smooth`` reaches that far
    or to the recording's ends.
    """
    count = len(smooth)
    # ok[j]: the smoothed velocity stays within the tolerance over [j, j + length).
    low = rolling_min(smooth, length, mode="nearest", origin=-(length // 2))
    high = rolling_max(smooth, length, mode="nearest", origin=-(length // 2))
    slowest = rolling_min(np.abs(smooth), length, mode="nearest", origin=-(length // 2))
    ok = (high - low) <= band(smooth)
    ok &= slowest >= standstill
    ok[max(0, n - length + 1 - offset) :] = False
    # Samples covered by any good span of `length` samples.
    covered = rolling_max(ok.astype(np.int8), length, origin=(length - 1) // 2) > 0
    # Two levels that touch without a ramp between them are two plateaus.
    jump = np.zeros(count, dtype=np.bool_)
    jump[1:] = np.abs(np.diff(smooth)) > 0.5 * band(smooth[1:])
    mask: BoolArray = covered & ~jump
    return mask
