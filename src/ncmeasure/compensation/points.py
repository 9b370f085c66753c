"""Friction compensation points from the results of one measurement. Pure numpy.

A controller that compensates friction adds, at each commanded velocity, the
motor current that friction takes there. This module reads that curve out of
``results.json`` per axis and direction:

* the friction is the fitted model of each measuring position where one
  describes the curve (``model`` of the direction: Coulomb + viscous, Stribeck
  or extended Stribeck), and the measured points with the axis' offset taken
  out (``direction × (median − offset_removed)``) below the range of a
  Coulomb + viscous fit, where the line does not hold (Stribeck region);
* the positions are averaged: a controller has one table per axis, not one
  per place along the travel;
* the velocities lie between the slowest and the fastest speed measured at
  every one of those positions, spaced geometrically, so that they are denser
  at low speed where friction changes fastest (the Stribeck region). Nothing
  is extrapolated beyond the measured speeds;
* values in the friction quantity are converted to motor current with the
  torque constant (I = T / k_T) when the results are in Nm.

An axis whose direction has no model at any position, or that was measured
in one direction only, gives no compensation: :class:`~ncmeasure.errors.ConfigError`
with one line that says which axis and why.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ncmeasure.errors import ConfigError
from ncmeasure.formats.axis import AxisMechanics
from ncmeasure.formats.results import AxisResult, DirectionResult, Results

__all__ = [
    "AxisFriction",
    "DirectionFriction",
    "axis_friction",
    "friction_curve",
    "select_axes",
    "speed_grid",
]

Direction = Literal["positive", "negative"]
SIGN: dict[Direction, int] = {"positive": 1, "negative": -1}

MIN_SPEED_RATIO = 1.0 + 1e-9
"""Two speeds closer than this ratio count as one (a measured range needs two)."""


@dataclass(frozen=True)
class DirectionFriction:
    """Friction of one direction over speed, averaged over the positions that describe it.

    Attributes:
        direction: ``positive`` or ``negative``.
        speed_range_mm_min: Slowest and fastest speed measured at every used position.
        positions_mm: The measuring positions averaged.
        models: The model of each used position (``linear``, ``stribeck``, ``extended``).
        below_fit_mm_min: Speed below which measured points stand in for a Coulomb +
            viscous fit (its range starts there), the largest over the positions; None
            when the models cover every measured speed.
    """

    direction: Direction
    speed_range_mm_min: tuple[float, float]
    positions_mm: tuple[float, ...]
    models: tuple[str, ...]
    below_fit_mm_min: float | None
    _curves: tuple[tuple[DirectionResult, float, int], ...]

    def friction(self, speed_mm_min: float) -> float:
        """Friction magnitude at ``speed_mm_min`` (inside the range), in the quantity."""
        low, high = self.speed_range_mm_min
        if not low / MIN_SPEED_RATIO <= speed_mm_min <= high * MIN_SPEED_RATIO:
            raise ValueError(f"{speed_mm_min} mm/min is outside the measured {low}–{high}")
        values = [_position_friction(d, off, sign, speed_mm_min) for d, off, sign in self._curves]
        return float(np.mean(values))

    def spread_percent(self, speed_mm_min: float) -> float:
        """How much the averaged positions differ at ``speed_mm_min``: (max − min)/mean × 100
        (0 for one position)."""
        values = [
            abs(_position_friction(d, off, sign, speed_mm_min)) for d, off, sign in self._curves
        ]
        mean = float(np.mean(values))
        return (max(values) - min(values)) / mean * 100.0 if mean > 0 else 0.0


@dataclass(frozen=True)
class AxisFriction:
    """Both directions of one axis and what converts them into motor current."""

    axis: str
    unit: Literal["Nm", "A"]
    mechanics: AxisMechanics
    """The axis' mechanics as the results state them (torque constant, vertical, ...)."""
    offset: float | None
    """Direction-independent part (gravity on a vertical axis), in the quantity."""
    positive: DirectionFriction
    negative: DirectionFriction

    def current_a(self, value: float) -> float:
        """A value in the axis' quantity as motor current (A)."""
        if self.unit == "A":
            return value
        if not self.torque_constant_nm_per_a:
            raise ConfigError(
                f"axis {self.axis}: the results are in Nm without a torque constant; "
                "motor current cannot be computed"
            )
        return value / self.torque_constant_nm_per_a

    @property
    def torque_constant_nm_per_a(self) -> float | None:
        """k_T of the motor, where the results state it."""
        return self.mechanics.torque_constant_nm_per_a

    @property
    def vertical(self) -> bool | None:
        """Whether the axis is vertical (None: the results do not say)."""
        return self.mechanics.vertical

    @property
    def common_range_mm_min(self) -> tuple[float, float]:
        """Speeds measured in both directions."""
        low = max(self.positive.speed_range_mm_min[0], self.negative.speed_range_mm_min[0])
        high = min(self.positive.speed_range_mm_min[1], self.negative.speed_range_mm_min[1])
        return low, high


def _nonlinear(d: DirectionResult) -> dict[str, float] | None:
    fit = d.extended if d.model == "extended" else d.stribeck
    return fit.parameters if fit is not None else None


def _points(d: DirectionResult, offset: float, sign: int) -> tuple[np.ndarray, np.ndarray]:
    """Speeds (ascending, distinct) and friction magnitudes of the measured points."""
    speed = np.abs(np.array([p.velocity_mm_min for p in d.points], dtype=np.float64))
    value = sign * (np.array([p.median for p in d.points], dtype=np.float64) - offset)
    unique, inverse = np.unique(speed, return_inverse=True)
    mean = np.bincount(inverse, weights=value) / np.bincount(inverse)
    return unique, mean


def _position_friction(d: DirectionResult, offset: float, sign: int, speed: float) -> float:
    """One position's friction at ``speed``: its model where it holds, else its points."""
    if d.model == "linear" and d.fit is not None:
        coulomb, viscous = d.fit.coulomb, d.fit.viscous_per_mm_min
        if (
            coulomb is not None
            and viscous is not None
            and speed * MIN_SPEED_RATIO >= d.fit.velocity_range_mm_min[0]
        ):
            return coulomb + viscous * speed
    elif d.model in ("stribeck", "extended"):
        p = _nonlinear(d)
        if p is not None:
            value = (
                p["T_C"]
                + (p["T_S"] - p["T_C"]) * math.exp(-((speed / p["v_S"]) ** p["delta"]))
                + p["b"] * speed
            )
            if d.model == "extended":
                # fit.py: the rolling term is f_w·(v / 1000 mm/min)^k
                value += p["f_w"] * (speed / 1000.0) ** p["k"]
            return value
    speeds, values = _points(d, offset, sign)
    return float(np.interp(speed, speeds, values))


def _usable(d: DirectionResult | None) -> bool:
    """A direction with a model that gives numbers."""
    if d is None or d.model is None or len(d.points) < 2:
        return False
    if d.model == "linear":
        return d.fit is not None and d.fit.coulomb is not None
    return _nonlinear(d) is not None


def friction_curve(axis_name: str, axis: AxisResult, direction: Direction) -> DirectionFriction:
    """The friction of one direction of an axis, averaged over the positions with a model.

    Raises:
        ConfigError: the direction was not measured, or no model describes it anywhere.
    """
    measured = [p for p in axis.positions if p.directions.get(direction) is not None]
    if not measured:
        raise ConfigError(
            f"axis {axis_name}: the {direction} direction was not measured; a compensation "
            "needs both directions"
        )
    used = [p for p in measured if _usable(p.directions[direction])]
    if not used:
        raise ConfigError(
            f"axis {axis_name}: no friction model describes the {direction} direction at any "
            f"of its {len(measured)} position(s) (see the results' model_reason); no "
            "compensation from this measurement"
        )
    curves: list[tuple[DirectionResult, float, int]] = []
    lows, highs, below = [], [], []
    for position in used:
        d = position.directions[direction]
        assert d is not None
        speed = [abs(p.velocity_mm_min) for p in d.points]
        lows.append(min(speed))
        highs.append(max(speed))
        offset = d.offset_removed or 0.0
        curves.append((d, offset, SIGN[direction]))
        if d.model == "linear" and d.fit is not None and d.fit.points_below_range:
            below.append(d.fit.velocity_range_mm_min[0])
    low, high = max(lows), min(highs)
    if high < low * MIN_SPEED_RATIO:
        raise ConfigError(
            f"axis {axis_name}: the {direction} direction's positions share no range of "
            "measured speeds; no compensation from this measurement"
        )
    return DirectionFriction(
        direction=direction,
        speed_range_mm_min=(low, high),
        positions_mm=tuple(p.position_mm for p in used),
        models=tuple(str(p.directions[direction].model) for p in used),  # type: ignore[union-attr]
        below_fit_mm_min=max(below) if below else None,
        _curves=tuple(curves),
    )


def axis_friction(results: Results, axis_name: str) -> AxisFriction:
    """Both directions of one analysed axis.

    Raises:
        ConfigError: the axis is not in the results, was not analysed, or a direction
            has no usable friction model.
    """
    if axis_name not in results.axes:
        if axis_name in results.skipped:
            raise ConfigError(
                f"axis {axis_name} was not analysed ({results.skipped[axis_name]}); "
                "no compensation from this measurement"
            )
        known = ", ".join(results.axes) or "none"
        raise ConfigError(f"axis {axis_name} is not in the results (analysed axes: {known})")
    axis = results.axes[axis_name]
    return AxisFriction(
        axis=axis_name,
        unit=axis.unit,
        mechanics=axis.mechanics(),
        offset=axis.offset.value if axis.offset is not None else None,
        positive=friction_curve(axis_name, axis, "positive"),
        negative=friction_curve(axis_name, axis, "negative"),
    )


def select_axes(results: Results, names: Sequence[str] | None) -> list[str]:
    """The axes asked for (in the order given), or every analysed axis.

    Raises:
        ConfigError: nothing was analysed.
    """
    if names:
        return list(dict.fromkeys(names))
    if not results.axes:
        raise ConfigError("the results hold no analysed axis; no compensation")
    return list(results.axes)


def speed_grid(low_mm_min: float, high_mm_min: float, count: int) -> list[float]:
    """``count`` speeds from ``low`` to ``high``, geometrically spaced (denser at low speed).

    Both ends are measured speeds; every speed lies between them.

    Raises:
        ValueError: fewer than two points, or a range that is not positive.
    """
    if count < 2:
        raise ValueError("a speed grid needs at least two points")
    if not 0 < low_mm_min < high_mm_min:
        raise ValueError(f"not a range of speeds: {low_mm_min} to {high_mm_min}")
    ratio = high_mm_min / low_mm_min
    grid = [low_mm_min * ratio ** (k / (count - 1)) for k in range(count)]
    grid[0], grid[-1] = low_mm_min, high_mm_min  # exact ends: no rounding past the data
    return grid
