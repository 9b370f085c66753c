"""A fleet of runs: robust outliers by the modified z-score, and per axis the fleet's figures.

The modified z-score (Iglewicz & Hoaglin) of a run's mean friction against
the others, 0.6745·(x − median)/MAD, tells a machine that stands out from
identical ones; :func:`modified_z_leave_one_out` gives it for a whole fleet at
once (the fleet store's outliers).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from ncmeasure.formats.comparison import Direction, FleetAxis, Limits
from ncmeasure.formats.results import Results

__all__ = ["Cell", "fleet_axes", "modified_z_against", "modified_z_leave_one_out"]

Cell = tuple[str, int, Direction, int]
"""A compared point: axis, base position index, direction, base point index."""

_MAD_TO_SIGMA = 0.6745
"""Iglewicz & Hoaglin: modified z = 0.6745·(x − median)/MAD."""

_MEAN_AD_TO_SIGMA = 0.7979
"""Fallback when MAD = 0: modified z = 0.7979·(x − median)/mean |x − median|."""


def _modified_z(values: Sequence[float]) -> list[float]:
    x = np.asarray(values, dtype=np.float64)
    centre = float(np.median(x))
    mad = float(np.median(np.abs(x - centre)))
    if mad > 0:
        return [float(z) for z in _MAD_TO_SIGMA * (x - centre) / mad]
    mean_ad = float(np.mean(np.abs(x - centre)))
    if mean_ad > 0:
        return [float(z) for z in _MEAN_AD_TO_SIGMA * (x - centre) / mean_ad]
    return [0.0] * x.size


def modified_z_against(value: float, reference: Sequence[float] | NDArray[np.float64]) -> float:
    """The modified z-score of ``value`` against other values (not including it).

    0.6745·(value − median)/MAD of ``reference``, with the mean absolute deviation
    (× 0.7979) where the MAD is 0, and 0 where the reference does not scatter at all.
    """
    x = np.asarray(reference, dtype=np.float64)
    centre = float(np.median(x))
    mad = float(np.median(np.abs(x - centre)))
    if mad > 0:
        return _MAD_TO_SIGMA * (value - centre) / mad
    mean_ad = float(np.mean(np.abs(x - centre)))
    if mean_ad > 0:
        return _MEAN_AD_TO_SIGMA * (value - centre) / mean_ad
    return 0.0


def _median_without(ordered: NDArray[np.float64], rank: NDArray[np.intp]) -> NDArray[np.float64]:
    """For each rank r: the median of ``ordered`` (sorted) without its element at r."""
    m = ordered.size - 1  # elements left

    def at(position: int) -> NDArray[np.float64]:  # the rest's element ``position``
        chosen: NDArray[np.float64] = np.where(
            position < rank, ordered[position], ordered[position + 1]
        )
        return chosen

    if m % 2:
        return at((m - 1) // 2)
    return (at(m // 2 - 1) + at(m // 2)) / 2.0


def modified_z_leave_one_out(
    values: Sequence[float] | NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each value's modified z-score against all the others, and the others' median.

    The same figures as :func:`modified_z_against` of each value against the rest,
    for a whole fleet at once in O(n log n): leaving one value out moves the median
    to one of at most three values, and the MAD about each of them is again a median
    with one element left out.
    """
    x = np.asarray(values, dtype=np.float64)
    n = x.size
    if n < 2:
        raise ValueError("leave-one-out needs at least two values")
    order = np.argsort(x, kind="stable")
    rank = np.empty(n, dtype=np.intp)
    rank[order] = np.arange(n)
    centre = _median_without(x[order], rank)
    z = np.zeros(n)
    for c in np.unique(centre):
        members = np.flatnonzero(centre == c)
        d = np.abs(x - c)
        d_order = np.argsort(d, kind="stable")
        d_rank = np.empty(n, dtype=np.intp)
        d_rank[d_order] = np.arange(n)
        ordered = d[d_order]
        mad = _median_without(ordered, d_rank)[members]
        # the others' sum without a subtraction (which would lose a tiny rest to rounding):
        # the sum of the smaller deviations plus that of the larger ones
        before = np.concatenate(([0.0], np.cumsum(ordered)[:-1]))
        after = np.concatenate((np.cumsum(ordered[::-1])[::-1][1:], [0.0]))
        ranks = d_rank[members]
        mean_ad = (before[ranks] + after[ranks]) / (n - 1)
        diff = x[members] - c
        with np.errstate(over="ignore"):  # a spread of 1e-300: z is inf, as one at a time
            by_mad = _MAD_TO_SIGMA * diff / np.where(mad > 0, mad, 1.0)
            by_mean = _MEAN_AD_TO_SIGMA * diff / np.where(mean_ad > 0, mean_ad, 1.0)
        z[members] = np.where(mad > 0, by_mad, np.where(mean_ad > 0, by_mean, 0.0))
    return z, centre


def fleet_axes(
    base: Results,
    base_label: str,
    other_labels: Sequence[str],
    base_cells: dict[Cell, float],
    run_cells: Sequence[dict[Cell, float]],
    limits: Limits,
    problems: list[str],
) -> list[FleetAxis]:
    """Per axis, the mean friction of every run over the points all runs share; outliers."""
    out = []
    labels = [base_label, *other_labels]
    for axis in sorted({cell[0] for cell in base_cells}):
        common = [
            cell
            for cell in base_cells
            if cell[0] == axis and all(cell in cells for cells in run_cells)
        ]
        if not common:
            problems.append(f"fleet: axis {axis} has no point measured in every run")
            continue
        means = [float(np.mean([base_cells[c] for c in common]))]
        means += [float(np.mean([cells[c] for c in common])) for cells in run_cells]
        values = np.array(means)
        mean = float(values.mean())
        z = _modified_z(means)
        enough = len(means) >= limits.outlier_min_runs
        out.append(
            FleetAxis(
                axis=axis,
                unit=base.axes[axis].unit,
                runs=labels,
                mean_friction=means,
                common_points=len(common),
                mean=mean,
                spread_percent=float(np.ptp(values) / mean * 100.0) if mean > 0 else 0.0,
                std=float(values.std(ddof=1)) if values.size > 1 else 0.0,
                modified_z=z,
                outliers=[
                    label
                    for label, score in zip(labels, z, strict=True)
                    if enough and abs(score) > limits.outlier_z
                ],
            )
        )
    return out
