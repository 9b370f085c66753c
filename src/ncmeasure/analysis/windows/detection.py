"""What an axis' signals resolve: the sample counts of the settings' durations, the bands.

Every rule of the finder is a duration (``docs/analysis.md``, section 1); the
counts follow from the sample period. The velocity signal's count and noise
widen every tolerance band and raise the standstill threshold; where they
exceed ``velocity_floor_mm_min`` and a position was recorded, windows are found
and measured by the position's central differences instead.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.settings import (
    FILTER_PLATEAU_SHARE,
    FLOOR_REFERENCE_MM_MIN,
    FLOOR_SIGNAL_TO_NOISE,
    MIN_FILTER_SAMPLES,
    MIN_WINDOW_SAMPLES,
    NOISE_BAND_FACTOR,
    SegmentSettings,
)
from ncmeasure.analysis.windows.signals import odd

__all__ = ["Detection", "min_window_rows"]

FloatArray = NDArray[np.float64]


class Detection:
    """The counts and bands a window finder works with, from its axis' statistics.

    The base of the finders: :meth:`setup_counts` from the sample period,
    :meth:`setup_resolution` from the signals' counts and noise,
    :meth:`setup_detection` once it is known whether the position moves as
    the velocity readings say.
    """

    axis: str
    settings: SegmentSettings
    dt: float
    positions_known: bool
    warnings: list[str]

    def scale_floors(self, top: float, noise: float) -> None:
        """The settings' absolute floors scaled down where every speed is small.

        The floors (``velocity_floor_mm_min``, ``standstill_mm_min``,
        ``step_floor_mm_min``) are set for a feed axis in mm/min. A recording
        whose velocity never reaches :data:`FLOOR_REFERENCE_MM_MIN` in magnitude
        counts in another unit (a rotary joint in rad/s or deg/s: 0.01 to 1
        rad/s would all lie below standstill): the floors are scaled by ``top``
        over that reference, and a warning says so. The velocity's own count
        and noise still widen the bands. An axis holding its position is no
        other unit: its top speed (its noise, or one count) is not
        :data:`FLOOR_SIGNAL_TO_NOISE` times its noise, ``noise`` (σ or one count).
        """
        if not math.isfinite(top) or not 0 < top < FLOOR_REFERENCE_MM_MIN:
            return
        if not top >= FLOOR_SIGNAL_TO_NOISE * noise:
            return
        factor = top / FLOOR_REFERENCE_MM_MIN
        settings = self.settings
        self.settings = settings.model_copy(
            update={
                name: getattr(settings, name) * factor
                for name in ("velocity_floor_mm_min", "standstill_mm_min", "step_floor_mm_min")
            }
        )
        self.warnings.append(
            f"the velocity never exceeds {top:.3g} in magnitude (in mm/min: a rotary axis in "
            "rad/s or deg/s?): the absolute floors of the tolerance, standstill and steps are "
            f"scaled by {factor:.3g} (standstill {self.settings.standstill_mm_min:.3g})"
        )

    def setup_counts(self) -> None:
        """Sample counts of the settings' durations at the sample period ``dt``."""
        settings = self.settings
        self.detect_resolution = 0.0
        self.settle_n = round(settings.settle_s / self.dt)
        self.min_n = min_window_rows(settings, self.dt)
        self.plateau_n = max(MIN_WINDOW_SAMPLES, round(settings.plateau_min_s / self.dt))
        # The smoothing: plateau_filter_s, and at least MIN_FILTER_SAMPLES where a plateau
        # holds FILTER_PLATEAU_SHARE such widths (an odd count: a median has a middle).
        least = min(MIN_FILTER_SAMPLES, self.plateau_n // FILTER_PLATEAU_SHARE)
        least = max(1, least if least % 2 else least - 1)
        self.filter_n = max(odd(settings.plateau_filter_s / self.dt), least)

    def setup_resolution(self, v_quantum: float, x_quantum: float, sigma: float) -> None:
        """What the velocity signal resolves, and whether windows come from the position."""
        # What the velocity signal can resolve: one count, and the noise of the
        # rolling median over filter_n samples (√(π/2)·σ/√n).
        self.v_quantum = v_quantum
        self.x_quantum = x_quantum
        smoothed_noise = math.sqrt(math.pi / 2) * sigma / math.sqrt(self.filter_n)
        self.resolution = max(self.v_quantum, NOISE_BAND_FACTOR * smoothed_noise)
        # A velocity signal coarser than the tolerance floor cannot tell the slow steps
        # apart: find and measure windows by the position instead, where recorded.
        self.from_position = (
            self.positions_known and self.resolution > self.settings.velocity_floor_mm_min
        )

    def setup_detection(self, ratio: float | None) -> None:
        """Keep the position's velocity when it agrees with the readings (``ratio``)."""
        settings = self.settings
        if self.from_position and (ratio is None or not 0.9 <= ratio <= 1.1):
            self.warnings.append(
                "the velocity signal is coarse, but the position does not move as the "
                "velocity says"
                + (f" (its rate is {ratio:.3g} × the velocity)" if ratio is not None else "")
                + ": windows are found by the velocity readings (another unit of the "
                "position?)"
            )
            self.from_position = False
            self.detect_resolution = 0.0
        if self.from_position:
            self.warnings.append(
                f"the velocity signal resolves {self.resolution:.3g} mm/min"
                + (f" (one count is {self.v_quantum:.3g} mm/min)" if self.v_quantum else "")
                + ": windows are found and measured by the position (displacement over time)"
            )
            self.standstill = max(settings.standstill_mm_min, self.detect_resolution)
        else:
            self.standstill = max(settings.standstill_mm_min, self.v_quantum * (1 + 1e-6))

    def position_h(self, sigma_x: float) -> int:
        """Half-width h of the position's central differences; sets their resolution.

        h is long enough that a position count, or the position's noise, moves
        the estimate by at most a quarter of the tolerance floor, and at most a
        quarter of a plateau. The resolution of the estimate (one position count
        over the span, three standard errors of its smoothed noise) widens the
        tolerance band like the velocity readings' resolution does.
        """
        floor = max(self.settings.velocity_floor_mm_min, 1e-9)
        step = max(self.x_quantum, 2.0 * sigma_x)
        wanted = math.ceil(60.0 * step / (0.25 * floor * 2 * self.dt))
        h = int(min(max(1, wanted), max(1, self.plateau_n // 4)))
        # The estimate's noise: two position samples of σ_x over 2h samples.
        noise = 60.0 * math.sqrt(2.0) * sigma_x / (2 * h * self.dt)
        self.detect_resolution = max(
            60.0 * self.x_quantum / (2 * h * self.dt), NOISE_BAND_FACTOR * noise
        )
        return h

    def band(self, level: float | FloatArray) -> FloatArray:
        """The accepted |velocity − level|: the settings' tolerance, at least the resolution."""
        resolution = self.detect_resolution if self.from_position else self.resolution
        return np.maximum(self.settings.tolerance_mm_min(level), resolution)


def min_window_rows(settings: SegmentSettings, dt: float) -> int:
    """Samples of the shortest window (``min_window_s``) at the sample period ``dt``."""
    return max(MIN_WINDOW_SAMPLES, math.ceil(settings.min_window_s / dt - 1e-9))
