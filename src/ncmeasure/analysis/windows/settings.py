"""How windows are found: the settings, written into results.json, and their fixed limits."""

from __future__ import annotations

from typing import Final, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

__all__ = [
    "COARSE_WINDOW_SAMPLES",
    "CORRELATED_RHO",
    "DISPLACEMENT_QUANTA",
    "FILTER_PLATEAU_SHARE",
    "FLOOR_REFERENCE_MM_MIN",
    "FLOOR_SIGNAL_TO_NOISE",
    "HOLE_NEIGHBOURS",
    "HOLE_PERIODS",
    "JOIN_GAP_SAMPLES",
    "JOIN_SPREAD",
    "MIN_FILTER_SAMPLES",
    "MIN_WINDOW_SAMPLES",
    "NOISE_BAND_FACTOR",
    "STEADY_MEAN_SHARE",
    "STEADY_SCATTER",
    "STEADY_SHARE",
    "STEP_QUANTA",
    "THIN_STEP_SHARE",
    "Method",
    "SegmentSettings",
    "WindowSource",
]

WindowSource = Literal["marker", "command", "plateau", "schedule"]
Method = Literal["auto", "marker", "command", "plateau"]

FloatArray = NDArray[np.float64]

MIN_WINDOW_SAMPLES: Final = 3
"""No window keeps fewer samples, whatever ``min_window_s``: a median and a spread need 3."""

MIN_FILTER_SAMPLES: Final = 5
"""The rolling median spans at least this many samples (and ``plateau_filter_s``), as far
as :data:`FILTER_PLATEAU_SHARE` allows: a drive's averaged velocity wanders over several
samples (lag-1 autocorrelation 0.7 to 0.9), and a median of one to three of them follows
every excursion, which breaks a steady run apart or leaves it without a plateau."""

FILTER_PLATEAU_SHARE: Final = 4
"""The rolling median spans at most a plateau (``plateau_min_s``) over this many samples
where ``plateau_filter_s`` asks for less: the shortest plateau, and a step between two
speeds, stay resolved (the median keeps an edge, and cuts half its width off each end)."""

FLOOR_REFERENCE_MM_MIN: Final = 1000.0
"""A feed axis' recording reaches this velocity in mm/min (its rapids, its faster steps);
one that never does counts in another unit, and the absolute floors scale with its top
speed (:meth:`~ncmeasure.analysis.windows.detection.Detection.scale_floors`)."""

FLOOR_SIGNAL_TO_NOISE: Final = 100.0
"""The floors scale only where the top speed is this many times the velocity's noise (σ)
and count: an axis holding its position reads its noise, not a speed in another unit."""

COARSE_WINDOW_SAMPLES: Final = 20
"""Windows holding fewer samples than this (median over the axis) make the data coarse:
their medians are uncertain and the Stribeck curve at low speed is not resolved."""

HOLE_PERIODS: Final = 1.5
"""A time step longer than this many sample periods, and than this many times the step
before it, is a hole for the window finder (a link outage, the step between two files of
an import): no window spans it, no position is carried across it. The hole counter
(:class:`~ncmeasure.analysis.windows.signals.HoleCounter`) takes a step longer than this
many times the regular period around it for a hole."""

HOLE_NEIGHBOURS: Final = 7
"""The hole counter's regular period around a step is the median of this many steps
before it, or of as many after it: up to half of them may be holes (an outage broken by
a sample or a few) and the median stays the sampling period."""

DISPLACEMENT_QUANTA: Final = 2.0
"""A window's displacement is known to this many position counts (one at each end)."""

NOISE_BAND_FACTOR: Final = 3.0
"""The tolerance band is at least this many standard errors of the smoothed velocity."""

JOIN_SPREAD: Final = 6.0
"""Plateaus next to each other are one speed when their levels, and the velocity between
and in them, stay within this many standard deviations of its own noise of their common
level (the largest excursion of 500 samples of correlated noise is about 4 of them)."""

STEP_QUANTA: Final = 1.5
"""Without a schedule, window levels this many velocity counts apart or closer are one step."""

THIN_STEP_SHARE: Final = 0.125
"""Without a command or a schedule, a velocity step whose windows hold fewer than this
share of the samples of each step next to it is no step of its own: a fragment of a run
(the velocity wandered off its level at a run's start or end, an overshoot) whose level
the readings happened to hold. Windows of one program at neighbouring speeds differ in
length by the speeds' ratio, a few times at most."""

STEADY_SCATTER: Final = 0.25
"""Plateaus are joined only where JOIN_SPREAD standard deviations of the noise stay within
this fraction of the speed (a drive's averaged velocity: 6–12 %)."""

STEADY_MEAN_SHARE: Final = 0.35
"""A run is judged at one speed only where three standard errors of its rolling mean stay
within this fraction of its level: a robot joint's slow run (velocity scatter 10 to 40 %)
averages down to 8 to 21 %; the ramps of a move through several speeds do not."""

STEADY_SHARE: Final = 0.9
"""A run is one speed when at least this share of the rolling means over its middle half
lie within the band of its level (the others: noise beyond three standard errors)."""

CORRELATED_RHO: Final = 0.5
"""A velocity whose noise has at least this lag-1 autocorrelation is an averaged one."""

JOIN_GAP_SAMPLES: Final = 400
"""Plateaus at most this many samples apart may be joined (at least: twice
``plateau_min_s``): an excursion of a drive's averaged velocity at 6.4 ms per sample
lasts up to a few hundred samples; the readings between must stay near the level."""


class SegmentSettings(BaseModel):
    """How windows are found and which samples they keep.

    The defaults suit ncmeasure's own programs (windows of 0.2 to 0.4 s,
    settle 0.1 s, 1 to 4 ms sampling, lowest step about 10 mm/min) and hold
    for foreign recordings down to 100 ms sampling: every duration is in
    seconds, and the sample counts follow from the sample period. They are
    written into ``results.json`` (``settings``), so a result says how it was
    made. :class:`~ncmeasure.analysis.analyze.AnalysisSettings` is this model.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    velocity_tolerance: float = Field(
        default=0.03,
        gt=0,
        lt=1,
        description="A window's velocity must agree with its commanded (or scheduled) one "
        "within this fraction, or velocity_floor_mm_min, or the velocity signal's resolution "
        "(one count, its noise), whichever is largest. Also the flatness a plateau must keep.",
    )
    velocity_floor_mm_min: float = Field(
        default=2.0,
        ge=0,
        description="Absolute floor of the velocity tolerance in mm/min: at low speed the "
        "relative tolerance would be smaller than the velocity signal's noise.",
    )
    settle_s: float = Field(
        default=0.1,
        ge=0,
        description="Samples until this long after the actual velocity entered the "
        "tolerance band are cut from each window (acceleration transient, overshoot).",
    )
    min_window_s: float = Field(
        default=0.1,
        gt=0,
        description="A window shorter than this after the cut is dropped; it keeps at least "
        f"{MIN_WINDOW_SAMPLES} samples whatever the sample period.",
    )
    plateau_min_s: float = Field(
        default=0.2,
        gt=0,
        description="Shortest plateau of constant actual velocity that counts as a window "
        "(only without marker and commanded velocity).",
    )
    plateau_filter_s: float = Field(
        default=0.02,
        ge=0,
        description="Width of the rolling median that smooths the actual velocity before "
        "plateaus and the end of transients are detected.",
    )
    standstill_mm_min: float = Field(
        default=1.0,
        ge=0,
        description="Velocities below this are standstill, never a window. A velocity of "
        "one count of the velocity signal or less is standstill too.",
    )
    step_tolerance: float = Field(
        default=0.01,
        gt=0,
        description="Without a schedule: windows whose velocities differ by less than this "
        "fraction (or step_floor_mm_min) belong to the same velocity step.",
    )
    step_floor_mm_min: float = Field(
        default=0.5,
        ge=0,
        description="Absolute floor of step_tolerance in mm/min.",
    )
    position_gap_mm: float = Field(
        default=20.0,
        gt=0,
        description="Without a schedule: window centres further apart than this (or "
        "position_gap_fraction of their span) belong to different measuring positions.",
    )
    position_gap_fraction: float = Field(
        default=0.05,
        ge=0,
        lt=1,
        description="Relative part of the position gap.",
    )
    max_velocity_mm_min: float | None = Field(
        default=None,
        gt=0,
        description="Windows faster than this are rapid traverse. Default: the schedule's "
        "top step; without a schedule, rapids are recognised by their count and duration.",
    )
    duration_outlier_factor: float = Field(
        default=4.0,
        gt=1,
        description="Without a schedule: windows lasting this many times longer than the "
        "trend of window duration over velocity are traverses or warm-up strokes.",
    )
    rapid_count_factor: float = Field(
        default=3.0,
        gt=1,
        description="Without a schedule: the fastest velocity level is rapid traverse when "
        "it holds this many times more windows than a typical level.",
    )
    window_method: Method = Field(
        default="auto",
        description="auto: marker, else commanded velocity, else plateaus. The others force "
        "one way.",
    )

    def tolerance_mm_min(self, velocity_mm_min: float | FloatArray) -> FloatArray:
        """The accepted |actual − target| at a target velocity: relative with a floor.

        The segmentation widens it further by the resolution of the velocity
        signal it finds in the data (:attr:`Segmentation.velocity_resolution_mm_min`).
        """
        return np.maximum(
            self.velocity_tolerance * np.abs(np.asarray(velocity_mm_min, dtype=np.float64)),
            self.velocity_floor_mm_min,
        )
