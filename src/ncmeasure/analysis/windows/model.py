"""What the finder works on and gives: candidate stretches, windows, clusters, segmentations."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.settings import WindowSource
from ncmeasure.formats.schedule import Window as ScheduledWindow

__all__ = ["Candidate", "Cluster", "Segmentation", "VelocityWindow", "labelled_window", "nan_mean"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class VelocityWindow:
    """One window of constant velocity of one axis.

    Attributes:
        axis: The axis name.
        start: First sample index of the window.
        stop: One past the last sample index (``values[start:stop]``).
        velocity_mm_min: The signed velocity of the window's step: the
            schedule's, or the centre of its velocity cluster.
        level_mm_min: This window's own signed velocity: the commanded one
            where recorded, else the median actual velocity. Samples are kept
            where the actual velocity is within the tolerance of it.
        direction: +1 or −1.
        position_mm: Mean measured position over the window (integrated
            velocity where no position was recorded).
        position_index: Index of the measuring position, 0 = lowest.
        step: Velocity step index, 0 = slowest.
        source: How the window was found.
        window_id: The schedule's window id, when labelled by a schedule.
        repetition: The schedule's repetition, when labelled by a schedule.
    """

    axis: str
    start: int
    stop: int
    velocity_mm_min: float
    level_mm_min: float
    direction: Literal[1, -1]
    position_mm: float
    position_index: int
    step: int
    source: WindowSource
    window_id: int | None = None
    repetition: int | None = None

    @property
    def samples(self) -> int:
        """Number of samples in the window."""
        return self.stop - self.start


@dataclass(frozen=True)
class Cluster:
    """A velocity level or a measuring position found in the data (or given by the schedule).

    ``centre`` is the reported value (|v| in mm/min, or mm); ``low``/``high``
    the range of the windows in it.
    """

    index: int
    centre: float
    low: float
    high: float
    windows: int


@dataclass
class Segmentation:
    """What :func:`find_windows` found for one axis.

    Attributes:
        axis: The axis name.
        windows: The labelled windows, in time order.
        source: How the windows were found.
        labelled_by: ``"schedule"`` or ``"clusters"``.
        steps: Velocity levels (|v|), index = step, ascending.
        positions: Measuring positions, index = position_index, ascending.
        warnings: What the analysis should tell the user.
        tried: What was tried before ``source`` worked, one line each.
    """

    axis: str
    windows: list[VelocityWindow]
    source: WindowSource
    labelled_by: Literal["schedule", "clusters"]
    steps: list[Cluster]
    positions: list[Cluster]
    warnings: list[str] = field(default_factory=list)
    tried: list[str] = field(default_factory=list)
    sample_period_s: float = math.nan
    velocity_quantum_mm_min: float = 0.0
    velocity_resolution_mm_min: float = 0.0
    position_quantum_mm: float = 0.0
    coarse: bool = False

    @property
    def median_window_samples(self) -> float:
        """Median samples per window (NaN without windows)."""
        if not self.windows:
            return math.nan
        return float(np.median([w.samples for w in self.windows]))


@dataclass
class Candidate:
    """A stretch of samples that may hold a window, before labelling."""

    start: int
    stop: int
    level_mm_min: float
    marker_value: float | None = None
    scheduled: ScheduledWindow | None = None
    noise_mm_min: float = 0.0
    """The scatter of the velocity around the level where plateaus were joined (0: none)."""


def nan_mean(values: FloatArray) -> float:
    """``np.nanmean`` of a 1-D array, without its cost where no value is NaN.

    Where none is NaN, ``np.nanmean`` is the sum over the count, as ``np.mean``
    takes it (the same float), after a copy with the NaN set to 0.
    """
    if len(values) and not np.isnan(values).any():
        return float(np.mean(values))
    return float(np.nanmean(values))


def labelled_window(
    axis: str,
    candidate: Candidate,
    x: FloatArray,
    source: WindowSource,
    **labels: int | float,
) -> VelocityWindow:
    """The window of a candidate, with its labels; its position the mean of ``x`` over it."""
    direction: Literal[1, -1] = 1 if candidate.level_mm_min > 0 else -1
    inside = x[candidate.start : candidate.stop]
    position = nan_mean(inside) if np.isfinite(inside).any() else float("nan")
    return VelocityWindow(
        axis=axis,
        start=candidate.start,
        stop=candidate.stop,
        velocity_mm_min=float(labels.get("velocity_mm_min", candidate.level_mm_min)),
        level_mm_min=candidate.level_mm_min,
        direction=direction,
        position_mm=position,
        position_index=int(labels.get("position_index", -1)),
        step=int(labels.get("step", -1)),
        source=source,
        window_id=int(labels["window_id"]) if "window_id" in labels else None,
        repetition=int(labels["repetition"]) if "repetition" in labels else None,
    )
