"""The friction table: robust statistics of the current per position, direction and step.

For every (position, direction, velocity step) of an axis the table pools
the samples of all windows of that step (repetitions included) and gives the
**median** (robust against outliers, the figure the fits use), the mean, the
sample standard deviation (ddof = 1, NaN for a single sample) and the sample
count. A sample counts only where the actual velocity is within the
tolerance of its window's velocity (``level_mm_min``) and the current is
finite: the method keeps "only samples inside a window where the actual
velocity is within a tolerance of the commanded one".

With a torque constant the table is in Nm (T = k_T · I), else in A.

This is the hot path of the analysis (an hour at 1 kHz is 3.6 M rows), so it
is vectorised: the windows are sorted by group, the sample indices of all
windows are built at once (``np.repeat`` of the window offsets), sums come
from ``np.bincount``, and medians from one ``np.median`` per group on its
contiguous slice. Python loops run over windows and groups, never samples.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.results import Point
from ncmeasure.analysis.segment import VelocityWindow

__all__ = ["FrictionTable", "friction_table", "window_samples"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


@dataclass(frozen=True)
class FrictionTable:
    """One axis' friction table: one row per (position, direction, step), columns as arrays.

    Rows are sorted by position index, then direction (−1 before +1), then step.
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
    n: IntArray
    windows: IntArray

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
                n=int(self.n[i]),
                step=int(self.step[i]),
                windows=int(self.windows[i]),
            )
            for i in rows
        ]


def _medians(values: FloatArray, bounds: IntArray) -> FloatArray:
    """Median of every contiguous group ``values[bounds[g]:bounds[g + 1]]``; NaN when empty.

    The same numbers as ``np.median`` per group (the middle value, or the mean
    of the two middle values), with one ``np.partition`` per group and none
    of ``np.median``'s per-call overhead: the groups are few (steps ×
    positions × directions), the samples many.
    """
    result = np.full(len(bounds) - 1, np.nan)
    for g in range(len(bounds) - 1):
        part = values[bounds[g] : bounds[g + 1]]
        count = len(part)
        if count == 0:
            continue
        half = count // 2
        if count % 2:
            result[g] = np.partition(part, half)[half]
        else:
            low, high = np.partition(part, (half - 1, half))[half - 1 : half + 1]
            result[g] = (low + high) / 2
    return result


def window_samples(
    windows: Sequence[VelocityWindow],
    *,
    velocity_mm_min: FloatArray | None = None,
    velocity_tolerance: float = 0.03,
    velocity_floor_mm_min: float = 2.0,
) -> tuple[IntArray, IntArray]:
    """The sample indices of all windows and the window each belongs to, vectorised.

    Args:
        windows: The windows (any order).
        velocity_mm_min: The actual velocity; when given, samples outside
            ``max(velocity_tolerance·|level|, velocity_floor_mm_min)`` of their
            window's ``level_mm_min`` are left out.
        velocity_tolerance: Relative velocity tolerance.
        velocity_floor_mm_min: Its absolute floor.

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
    if velocity_mm_min is not None and total:
        levels = np.fromiter(
            (w.level_mm_min for w in windows), dtype=np.float64, count=len(windows)
        )
        tolerance = np.maximum(velocity_tolerance * np.abs(levels), velocity_floor_mm_min)
        error = np.abs(velocity_mm_min[index] - levels[owner])
        keep = error <= tolerance[owner]
        index, owner = index[keep], owner[keep]
    return index, owner


def friction_table(
    axis: str,
    current_a: FloatArray,
    windows: Sequence[VelocityWindow],
    *,
    velocity_mm_min: FloatArray | None = None,
    velocity_tolerance: float = 0.03,
    velocity_floor_mm_min: float = 2.0,
    torque_constant_nm_per_a: float | None = None,
) -> FrictionTable:
    """Median, mean, std and count of the current per (position, direction, step).

    Args:
        axis: The axis name.
        current_a: The motor current of the axis, all samples (n,).
        windows: Its labelled windows (:func:`~ncmeasure.analysis.segment.find_windows`).
        velocity_mm_min: The actual velocity (n,), to keep only samples within
            the tolerance of their window's velocity; None keeps every sample.
        velocity_tolerance: Relative velocity tolerance.
        velocity_floor_mm_min: Its absolute floor.
        torque_constant_nm_per_a: k_T; the table is in Nm when given, else in A.

    Returns:
        The table; rows without a single usable sample are left out.
    """
    quantity: Literal["torque_nm", "current_a"] = (
        "torque_nm" if torque_constant_nm_per_a is not None else "current_a"
    )
    unit: Literal["Nm", "A"] = "Nm" if torque_constant_nm_per_a is not None else "A"
    scale = torque_constant_nm_per_a if torque_constant_nm_per_a is not None else 1.0
    current = np.asarray(current_a, dtype=np.float64)

    # Group key per window; windows sorted by key make every group's samples contiguous.
    position = np.fromiter((w.position_index for w in windows), dtype=np.intp, count=len(windows))
    direction = np.fromiter((w.direction for w in windows), dtype=np.intp, count=len(windows))
    step = np.fromiter((w.step for w in windows), dtype=np.intp, count=len(windows))
    velocity = np.fromiter(
        (w.velocity_mm_min for w in windows), dtype=np.float64, count=len(windows)
    )
    start = np.fromiter((w.start for w in windows), dtype=np.intp, count=len(windows))
    order = np.lexsort((start, step, direction, position))
    ordered = [windows[i] for i in order]
    keys = np.stack([position[order], direction[order], step[order]], axis=1)
    if len(keys):
        first = np.ones(len(keys), dtype=np.bool_)
        first[1:] = (keys[1:] != keys[:-1]).any(axis=1)
        group_of_window = np.cumsum(first) - 1
    else:
        first = np.zeros(0, dtype=np.bool_)
        group_of_window = np.zeros(0, dtype=np.intp)
    groups = int(first.sum())

    index, owner = window_samples(
        ordered,
        velocity_mm_min=velocity_mm_min,
        velocity_tolerance=velocity_tolerance,
        velocity_floor_mm_min=velocity_floor_mm_min,
    )
    values = current[index]
    finite = np.isfinite(values)
    if not finite.all():
        values, owner = values[finite], owner[finite]
    group = group_of_window[owner]
    n = np.bincount(group, minlength=groups)
    has_samples = np.bincount(owner, minlength=len(windows)) > 0
    used_windows = np.bincount(group_of_window[has_samples], minlength=groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(group, weights=values, minlength=groups) / n
        deviation = values - mean[group]
        variance = np.bincount(group, weights=deviation * deviation, minlength=groups) / (n - 1)
    std = np.where(n > 1, np.sqrt(np.maximum(variance, 0.0)), np.nan)
    bounds = np.concatenate(([0], np.cumsum(n)))
    median = _medians(values, bounds)
    group_velocity = np.full(groups, np.nan)
    if groups:
        # All windows of a group share the step velocity; take its first window's.
        group_velocity = velocity[order][first]
    rows = n > 0
    head = keys[first][rows] if groups else np.zeros((0, 3), dtype=np.intp)
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
        n=n[rows].astype(np.intp),
        windows=used_windows[rows].astype(np.intp),
    )
