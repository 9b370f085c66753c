"""Results of a synthetic measurement with known friction, for the compensation tests.

Built from the pydantic models with the fits written out (no fitting), so the
numbers and the golden files do not depend on scipy:

* X, horizontal, in Nm with k_T = 2 Nm/A: Coulomb + viscous friction,
  T_C = 1.5 Nm positive and 1.7 Nm negative, 1e-4 Nm per mm/min, at two
  positions, the second with 20 % more friction (the mean is 1.1 ×);
* Z, vertical, in A: a Stribeck curve (T_C 1.0 A, T_S 1.6 A, v_S 100 mm/min,
  δ 1, b 2e-4 A per mm/min) in both directions and a gravity offset of 2.0 A;
* Y: measured, but no model describes its points.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from ncmeasure.formats.results import (
    AxisResult,
    DirectionResult,
    LinearFit,
    NonlinearFit,
    OffsetResult,
    Point,
    PositionResult,
    RecordingInfo,
    Results,
    Verdict,
)

SPEEDS_MM_MIN = (50.0, 100.0, 200.0, 400.0, 800.0, 1600.0, 3200.0, 6000.0)
X_COULOMB = {"positive": 1.5, "negative": 1.7}
X_VISCOUS = 1e-4
X_FACTORS = (1.0, 1.2)
TORQUE_CONSTANT = 2.0
Z_STRIBECK = {"T_C": 1.0, "T_S": 1.6, "v_S": 100.0, "delta": 1.0, "b": 2e-4}
Z_OFFSET_A = 2.0
SIGNS = {"positive": 1, "negative": -1}


def x_friction_nm(direction: str, speed: float) -> float:
    """The mean friction of X over its two positions, Nm."""
    return sum(X_FACTORS) / len(X_FACTORS) * (X_COULOMB[direction] + X_VISCOUS * speed)


def z_friction_a(speed: float) -> float:
    p = Z_STRIBECK
    return (
        p["T_C"]
        + (p["T_S"] - p["T_C"]) * math.exp(-((speed / p["v_S"]) ** p["delta"]))
        + (p["b"] * speed)
    )


def _points(direction: str, friction: Callable[[float], float], offset: float) -> list[Point]:
    sign = SIGNS[direction]
    return [
        Point(
            velocity_mm_min=sign * v,
            median=sign * friction(v) + offset,
            stderr=0.002,
            mean=sign * friction(v) + offset,
            std=0.01,
            n=200,
            step=i,
        )
        for i, v in enumerate(SPEEDS_MM_MIN)
    ]


def _linear(coulomb: float | None, viscous: float | None, low: float, below: int) -> LinearFit:
    return LinearFit(
        coulomb=coulomb,
        viscous_per_mm_min=viscous,
        coulomb_stderr=0.001 if coulomb is not None else None,
        viscous_stderr=1e-7 if viscous is not None else None,
        chi2_reduced=1.0,
        accepted=coulomb is not None,
        n_points=len(SPEEDS_MM_MIN) - below,
        velocity_range_mm_min=(low, SPEEDS_MM_MIN[-1]),
        points_below_range=below,
        reason=None if coulomb is not None else "the line is rejected",
    )


def _x_direction(direction: str, factor: float) -> DirectionResult:
    coulomb = factor * X_COULOMB[direction]
    viscous = factor * X_VISCOUS
    return DirectionResult(
        points=_points(direction, lambda v: coulomb + viscous * v, 0.0),
        fit=_linear(coulomb, viscous, SPEEDS_MM_MIN[0], 0),
        model="linear",
        model_reason="Coulomb + viscous friction describes every point.",
        offset_removed=0.0,
    )


def _z_direction(direction: str) -> DirectionResult:
    params = dict(Z_STRIBECK)
    return DirectionResult(
        points=_points(direction, z_friction_a, Z_OFFSET_A),
        fit=_linear(1.0, 2e-4, 400.0, 3),
        stribeck=NonlinearFit(
            model="stribeck",
            parameters=params,
            ci95={k: (0.9 * v, 1.1 * v) for k, v in params.items()},
            identifiable=True,
            chi2_reduced=1.0,
            stribeck_velocity_mm_min=params["v_S"],
        ),
        model="stribeck",
        model_reason="The Stribeck model describes every point.",
        offset_removed=Z_OFFSET_A,
    )


def _y_direction(direction: str) -> DirectionResult:
    return DirectionResult(
        points=_points(direction, lambda v: 0.5 + 1e-4 * v, 0.0),
        fit=_linear(None, None, SPEEDS_MM_MIN[0], 0),
        model=None,
        model_reason="No model describes the points (linear: the line is rejected).",
    )


def _axis(
    positions: list[PositionResult],
    unit: str,
    *,
    vertical: bool,
    offset: float | None = None,
) -> AxisResult:
    return AxisResult(
        verdict=Verdict(level="ok", reason="fine", action="nothing"),
        quantity="torque_nm" if unit == "Nm" else "current_a",
        unit=unit,  # type: ignore[arg-type]
        torque_constant_nm_per_a=TORQUE_CONSTANT if unit == "Nm" else None,
        vertical=vertical,
        window_source="marker",
        windows=len(SPEEDS_MM_MIN) * 2 * len(positions),
        samples_used=1000,
        positions=positions,
        offset=None
        if offset is None
        else OffsetResult(value=offset, stderr=0.01, explanation="gravity"),
    )


def example_results() -> Results:
    """X (Coulomb + viscous, Nm), Y (no model), Z (vertical, Stribeck, A, offset 2 A)."""
    x = [
        PositionResult(
            position_mm=position,
            position_index=i,
            directions={d: _x_direction(d, factor) for d in ("positive", "negative")},
        )
        for i, (position, factor) in enumerate(zip((100.0, 600.0), X_FACTORS, strict=True))
    ]
    y = [
        PositionResult(
            position_mm=200.0,
            position_index=0,
            directions={d: _y_direction(d) for d in ("positive", "negative")},
        )
    ]
    z = [
        PositionResult(
            position_mm=-250.0,
            position_index=0,
            directions={d: _z_direction(d) for d in ("positive", "negative")},
        )
    ]
    return Results(
        created_utc="2026-01-15T09:00:00Z",
        recording=RecordingInfo(
            directory="run1",
            machine="Example mill",
            start_utc="2026-01-15T08:30:00Z",
            config_hash="0123456789ab",
            source="canopen",
        ),
        settings={},
        axes={
            "X": _axis(x, "Nm", vertical=False),
            "Y": _axis(y, "Nm", vertical=False),
            "Z": _axis(z, "A", vertical=True, offset=Z_OFFSET_A),
        },
        skipped={"W": "the current channel is dead"},
    )
