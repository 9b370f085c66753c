"""The friction read out of results.json: known friction in, the same friction out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ncmeasure.analysis.friction.fit import fit_direction, separate_offset
from ncmeasure.compensation.points import axis_friction, speed_grid
from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import AxisResult, Point, PositionResult
from tests.compensation.example import (
    SPEEDS_MM_MIN,
    TORQUE_CONSTANT,
    Z_OFFSET_A,
    example_results,
    x_friction_nm,
    z_friction_a,
)


def test_speed_grid_is_geometric_within_the_measured_range() -> None:
    grid = speed_grid(50.0, 5000.0, 5)
    assert grid[0] == 50.0 and grid[-1] == 5000.0
    assert grid == pytest.approx([50.0, 158.11, 500.0, 1581.1, 5000.0], rel=1e-4)
    steps = np.diff(grid)
    assert np.all(steps > 0) and np.all(np.diff(steps) > 0)  # denser at low speed
    with pytest.raises(ValueError):
        speed_grid(50.0, 50.0, 5)


@pytest.mark.parametrize("direction", ["positive", "negative"])
def test_coulomb_and_viscous_friction_come_back_as_current(direction: str) -> None:
    friction = axis_friction(example_results(), "X")
    curve = getattr(friction, direction)
    assert curve.speed_range_mm_min == (SPEEDS_MM_MIN[0], SPEEDS_MM_MIN[-1])
    assert curve.positions_mm == (100.0, 600.0)
    for speed in (50.0, 123.4, 999.0, 6000.0):
        expected_a = x_friction_nm(direction, speed) / TORQUE_CONSTANT
        assert friction.current_a(curve.friction(speed)) == pytest.approx(expected_a, rel=1e-9)


def test_stribeck_model_and_offset_of_a_vertical_axis() -> None:
    friction = axis_friction(example_results(), "Z")
    assert friction.vertical is True
    assert friction.offset == Z_OFFSET_A
    for speed in (50.0, 100.0, 250.0, 6000.0):
        assert friction.positive.friction(speed) == pytest.approx(z_friction_a(speed))
        assert friction.negative.friction(speed) == pytest.approx(z_friction_a(speed))


def test_nothing_outside_the_measured_speeds() -> None:
    curve = axis_friction(example_results(), "X").positive
    with pytest.raises(ValueError, match="outside"):
        curve.friction(40.0)
    with pytest.raises(ValueError, match="outside"):
        curve.friction(6500.0)


@pytest.mark.parametrize(
    ("axis", "message"),
    [
        ("Y", "axis Y: no friction model describes the positive direction"),
        ("W", r"axis W was not analysed \(the current channel is dead\)"),
        ("Q", r"axis Q is not in the results \(analysed axes: X, Y, Z\)"),
    ],
)
def test_an_axis_without_friction_is_refused_in_one_line(axis: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        axis_friction(example_results(), axis)
    assert "\n" not in str(info.value)


def test_one_direction_only_is_refused() -> None:
    results = example_results()
    z = results.axes["Z"]
    position = z.positions[0]
    one_way = position.model_copy(
        update={"directions": {"positive": position.directions["positive"], "negative": None}}
    )
    axis = z.model_copy(update={"positions": [one_way]})
    results = results.model_copy(update={"axes": {**results.axes, "Z": axis}})
    with pytest.raises(ConfigError, match="the negative direction was not measured"):
        axis_friction(results, "Z")


def _measured(direction: int, coulomb: float, viscous: float, offset: float) -> list[Point]:
    """Points as the analysis makes them, with a little deterministic scatter."""
    rng = np.random.default_rng(7)
    points = []
    for i, speed in enumerate(SPEEDS_MM_MIN):
        value = direction * (coulomb + viscous * speed) + offset + rng.normal(0, 0.002)
        points.append(
            Point(
                velocity_mm_min=direction * speed,
                median=value,
                stderr=0.002,
                mean=value,
                std=0.02,
                n=400,
                step=i,
            )
        )
    return points


def test_the_analysis_fits_give_the_known_friction_back() -> None:
    """End to end through the analysis' own fits: Coulomb 0.8 A, viscous 5e-5 A per mm/min,
    gravity 1.2 A on a vertical axis; the compensation finds them within 1 %."""
    positive = _measured(1, 0.8, 5e-5, 1.2)
    negative = _measured(-1, 0.8, 5e-5, 1.2)
    offset = separate_offset(positive, negative)
    assert offset is not None
    directions = {
        "positive": fit_direction(positive, 1, offset=offset),
        "negative": fit_direction(negative, -1, offset=offset),
    }
    results = example_results()
    axis = AxisResult.model_validate(
        {
            **results.axes["Z"].model_dump(),
            "positions": [PositionResult(position_mm=0.0, position_index=0, directions=directions)],
            "offset": offset.model_dump(),
        }
    )
    results = results.model_copy(update={"axes": {"Z": axis}})
    friction = axis_friction(results, "Z")
    assert friction.offset == pytest.approx(1.2, abs=0.01)
    for speed in speed_grid(*friction.common_range_mm_min, 8):
        expected = 0.8 + 5e-5 * speed
        assert friction.positive.friction(speed) == pytest.approx(expected, rel=0.01)
        assert friction.negative.friction(speed) == pytest.approx(expected, rel=0.01)
    assert not math.isnan(friction.positive.friction(SPEEDS_MM_MIN[0]))
