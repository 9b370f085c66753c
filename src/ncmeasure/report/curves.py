"""The fitted friction models as curves over signed velocity, to draw through the points.

The fits (:mod:`ncmeasure.analysis.friction.fit`) describe friction as a positive
magnitude over speed |v|; the points of the negative direction are negative.
A curve is therefore the direction's sign times the magnitude model. Where
the analysis took the offset (gravity) out before fitting while the points
still carry it, the offset is added back: of the curve with and without the
offset, the one closer to the points is drawn.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.friction.stribeck import (
    EXTENDED_PARAMETERS,
    ROLLING_REFERENCE_MM_MIN,
    STRIBECK_PARAMETERS,
)
from ncmeasure.formats.results import (
    AxisResult,
    DirectionResult,
    LinearFit,
    NonlinearFit,
    OffsetResult,
    Point,
)

__all__ = [
    "drawn_model",
    "linear_curve",
    "linear_spans",
    "offset_is_significant",
    "speed_range",
    "speed_text",
    "stribeck_curve",
    "stribeck_magnitude",
    "unit_label",
]

FloatArray = NDArray[np.float64]


def offset_is_significant(offset: OffsetResult | None) -> bool:
    """True for an offset beyond twice its standard error (or any non-zero one without)."""
    if offset is None or not math.isfinite(offset.value) or offset.value == 0:
        return False
    if offset.stderr is None or not math.isfinite(offset.stderr):
        return True
    return abs(offset.value) > 2 * offset.stderr


def stribeck_magnitude(fit: NonlinearFit, speed_mm_min: FloatArray) -> FloatArray | None:
    """The friction magnitude of a Stribeck or extended fit at the speeds |v|.

    T = T_C + (T_S − T_C)·exp(−(v/v_S)^δ) + b·v, the extended model plus
    f_w·(v / 1000 mm/min)^k.

    Returns:
        The values, or None when the fit lacks one of its parameters.
    """
    names = EXTENDED_PARAMETERS if fit.model == "extended" else STRIBECK_PARAMETERS
    p = fit.parameters
    if p is None:
        return None
    if not all(name in p and math.isfinite(p[name]) for name in names) or p["v_S"] <= 0:
        return None
    v = np.abs(np.asarray(speed_mm_min, dtype=np.float64))
    value = p["T_C"] + (p["T_S"] - p["T_C"]) * np.exp(-((v / p["v_S"]) ** p["delta"])) + p["b"] * v
    if fit.model == "extended":
        value = value + p["f_w"] * (v / ROLLING_REFERENCE_MM_MIN) ** p["k"]
    result: FloatArray = np.asarray(value, dtype=np.float64)
    return result


def _in_sense(
    velocity_mm_min: FloatArray,
    magnitude: Callable[[FloatArray], FloatArray],
    sign: float,
    points: Sequence[Point],
    offset: float | None,
) -> FloatArray:
    """sign × magnitude, plus the offset when that brings the curve closer to the points."""
    curve: FloatArray = sign * magnitude(velocity_mm_min)
    if offset is None or not math.isfinite(offset) or not points:
        return curve
    speeds = np.array([p.velocity_mm_min for p in points], dtype=np.float64)
    medians = np.array([p.median for p in points], dtype=np.float64)
    at_points = sign * magnitude(speeds)
    without = float(np.sum((medians - at_points) ** 2))
    with_offset = float(np.sum((medians - at_points - offset) ** 2))
    if with_offset < without:
        shifted: FloatArray = curve + offset
        return shifted
    return curve


def linear_curve(
    fit: LinearFit,
    velocity_mm_min: FloatArray,
    sign: float,
    points: Sequence[Point] = (),
    offset: float | None = None,
) -> FloatArray:
    """The Coulomb + viscous line at the signed velocities of one direction.

    Args:
        fit: The linear fit of one position and direction.
        velocity_mm_min: Where to evaluate.
        sign: +1 for the positive, −1 for the negative direction.
        points: The measured points of that direction.
        offset: The axis' offset, added where the points carry it and the fit does not.
    """

    def magnitude(v: FloatArray) -> FloatArray:
        if fit.coulomb is None or fit.viscous_per_mm_min is None:
            return np.full(np.shape(v), np.nan)
        result: FloatArray = fit.coulomb + fit.viscous_per_mm_min * np.abs(v)
        return result

    return _in_sense(velocity_mm_min, magnitude, sign, points, offset)


def stribeck_curve(
    fit: NonlinearFit,
    velocity_mm_min: FloatArray,
    sign: float,
    points: Sequence[Point] = (),
    offset: float | None = None,
) -> FloatArray | None:
    """The Stribeck (or extended) model at the signed velocities of one direction.

    Returns:
        The curve, or None when the fit lacks one of its parameters.
    """
    if stribeck_magnitude(fit, np.ones(1)) is None:
        return None

    def magnitude(v: FloatArray) -> FloatArray:
        values = stribeck_magnitude(fit, v)
        return values if values is not None else np.full_like(v, np.nan)

    return _in_sense(velocity_mm_min, magnitude, sign, points, offset)


def unit_label(result: AxisResult) -> str:
    """The friction axis' label of an axis' figures."""
    if result.quantity == "torque_nm":
        return "friction torque [Nm]"
    return "friction as motor current [A]"


def drawn_model(direction: DirectionResult) -> NonlinearFit | None:
    """The nonlinear fit to draw: the extended model where identifiable, else Stribeck."""
    for fit in (direction.extended, direction.stribeck):
        if fit is not None and fit.identifiable:
            return fit
    return None


def speed_range(result: AxisResult) -> tuple[float, float]:
    """The slowest and the fastest measured speed of an axis (|v| > 0; 10 and 10,000 mm/min
    where none is): the span of its velocity figure."""
    speeds = [
        abs(p.velocity_mm_min)
        for position in result.positions
        for d in position.directions.values()
        if d is not None
        for p in d.points
        if p.velocity_mm_min != 0
    ]
    return (min(speeds), max(speeds)) if speeds else (10.0, 10000.0)


def linear_spans(
    fit: LinearFit, slowest: float, count: int
) -> tuple[FloatArray, FloatArray | None]:
    """The speeds to draw a linear fit at, on a velocity figure that starts at ``slowest``:
    ``count`` over the speeds it was fitted to (from ``slowest`` on), and ``count // 2``
    from ``slowest`` up to them where it was fitted above the slowest speed (extrapolated:
    drawn lighter), else None."""
    low, high = fit.velocity_range_mm_min
    low = max(low, slowest)
    inside = np.geomspace(low, max(high, low), count)
    below = np.geomspace(slowest, low, count // 2) if low > slowest * 1.01 else None
    return inside, below


def speed_text(value: float, sign: float) -> str:
    """A speed as a tick label: ``10 000``, ``0.5``, with ``−`` on the negative side."""
    if value <= 0:
        return ""
    text = f"{value:,.0f}".replace(",", " ") if value >= 1 else f"{value:g}"
    return f"−{text}" if sign < 0 else text
