"""Position dependency: each signature on synthetic tables with the method's magnitudes."""

from __future__ import annotations

import re
from typing import Literal

import numpy as np
import pytest

from ncmeasure.analysis.judgement.diagnosis import FLAT_THRESHOLD_PERCENT, position_dependency
from ncmeasure.formats.results import PositionDependency

TRAVEL = (0.0, 750.0)  # the test rig's travel
SPEEDS = np.geomspace(10.0, 15000.0, 50)


def curve(v: np.ndarray) -> np.ndarray:
    """Stribeck curve of a healthy axis in Nm (1.5 Nm Coulomb, hump, viscous)."""
    return 1.5 + 0.7 * np.exp(-v / 60.0) + 2e-4 * v


def positions(n: int) -> np.ndarray:
    return np.linspace(50.0, 700.0, n)


def table(
    effect: list[float],
    *,
    noise: float = 0.02,
    seed: int = 0,
    speeds: np.ndarray = SPEEDS,
    coulomb_only: bool = False,
) -> np.ndarray:
    """Friction per (speed, position): the healthy curve raised by ``effect`` (fraction)."""
    rng = np.random.default_rng(seed)
    rise = np.asarray(effect)[None, :]
    if coulomb_only:
        # A constraint raises the normal force, so the Coulomb part; sized to give the
        # same relative effect at 1500 mm/min as the proportional case.
        values = curve(speeds)[:, None] + rise * float(curve(np.array([1500.0]))[0])
    else:
        values = curve(speeds)[:, None] * (1.0 + rise)
    return np.asarray(values * (1.0 + rng.normal(0.0, noise, values.shape)))


def diagnose(
    effect: list[float],
    fixed: Literal["min", "max"] = "min",
    *,
    with_noise: bool = True,
    noise: float = 0.02,
    seed: int = 0,
    speeds: np.ndarray = SPEEDS,
    coulomb_only: bool = False,
) -> PositionDependency:
    values = table(effect, noise=noise, seed=seed, speeds=speeds, coulomb_only=coulomb_only)
    return position_dependency(
        positions(len(effect)).tolist(),
        speeds.tolist(),
        values,
        travel_mm=TRAVEL,
        fixed_bearing_end=fixed,
        noise=noise * values if with_noise else None,
    )


def mirrored(effect: list[float], fixed: Literal["min", "max"]) -> list[float]:
    """``effect`` given from the fixed-bearing end, laid out along the travel."""
    return effect if fixed == "min" else effect[::-1]


# Effects listed from the fixed-bearing end to the loose-bearing end.
LOOSE = {3: [0.0, 0.2, 0.4], 5: [0.0, 0.1, 0.2, 0.3, 0.4]}  # ~40 % along the axis
NUT = {3: [0.2, 0.0, 0.2], 5: [0.2, 0.05, 0.0, 0.05, 0.2]}  # both ends, none mid
STEP = {3: [0.0, 0.2, 0.2], 5: [0.0, 0.0, 0.2, 0.2, 0.2]}  # a ~20 % cover step


@pytest.mark.parametrize("n", [3, 5])
@pytest.mark.parametrize("fixed", ["min", "max"])
@pytest.mark.parametrize("with_noise", [True, False])
def test_loose_bearing_rises_towards_the_loose_bearing(
    n: int, fixed: Literal["min", "max"], with_noise: bool
) -> None:
    result = diagnose(mirrored(LOOSE[n], fixed), fixed, with_noise=with_noise)
    assert result.signature == "rising_to_loose_bearing"
    assert result.causes[0].cause == "loose_bearing"
    assert result.causes[0].score >= 0.8
    assert "guide_rail" in [c.cause for c in result.causes[1:]]
    # 1.4 / 1.2 - 1.0 / 1.2 = 33 % of the mean
    assert result.spread_percent == pytest.approx(100 * 0.4 / 1.2, abs=2.0)
    # 40 % of 1.2 over 650 mm = 5.1 % per 100 mm, towards the loose bearing
    expected = 100 * 0.4 / 1.2 / 6.5 * (1 if fixed == "min" else -1)
    assert result.trend_per_100mm == pytest.approx(expected, abs=0.4)
    assert "%" in result.causes[0].evidence


@pytest.mark.parametrize("n", [3, 5])
@pytest.mark.parametrize("fixed", ["min", "max"])
def test_fixed_bearing_rises_towards_the_fixed_bearing(
    n: int, fixed: Literal["min", "max"]
) -> None:
    result = diagnose(mirrored(LOOSE[n][::-1], fixed), fixed)
    assert result.signature == "rising_to_fixed_bearing"
    assert [c.cause for c in result.causes] == ["fixed_bearing", "guide_rail"]


@pytest.mark.parametrize("n", [3, 5])
def test_screw_nut_is_high_at_both_ends(n: int) -> None:
    result = diagnose(NUT[n])
    assert result.signature == "high_at_both_ends"
    assert result.causes[0].cause == "screw_nut"
    assert result.causes[0].score > result.causes[1].score
    assert abs(result.trend_per_100mm) < 0.5  # symmetric: no trend


@pytest.mark.parametrize("n", [3, 5])
@pytest.mark.parametrize("fixed", ["min", "max"])
def test_cover_step(n: int, fixed: Literal["min", "max"]) -> None:
    result = diagnose(mirrored(STEP[n], fixed), fixed)
    assert result.signature == "step"
    assert result.causes[0].cause == "cover_or_seal"
    assert "guide_rail" in [c.cause for c in result.causes]
    # The step in % of the side before it, read along the travel: +20 % up, or
    # 1.0 / 1.2 - 1 = -16.7 % down when the cover sits at the other end.
    match = re.search(r"changes by ([+-][0-9.]+) %", result.causes[0].evidence)
    assert match is not None
    assert float(match.group(1)) == pytest.approx(20.0 if fixed == "min" else -16.7, abs=1.5)


def test_step_next_to_a_bearing_names_that_bearing_as_alternative() -> None:
    result = diagnose([0.0, 0.0, 0.2])  # fixed at min: the jump is next to the loose bearing
    assert result.signature == "step"
    assert [c.cause for c in result.causes] == ["cover_or_seal", "loose_bearing", "guide_rail"]


@pytest.mark.parametrize("n", [3, 5])
def test_speed_dependent_effect_is_still_recognised(n: int) -> None:
    # A constraint adds Coulomb friction only: relatively large at low, small at high speed.
    for effect, signature in (
        (LOOSE[n], "rising_to_loose_bearing"),
        (NUT[n], "high_at_both_ends"),
        (STEP[n], "step"),
    ):
        assert diagnose(effect, coulomb_only=True).signature == signature


@pytest.mark.parametrize("n", [3, 5])
@pytest.mark.parametrize("with_noise", [True, False])
def test_noise_only_is_flat(n: int, with_noise: bool) -> None:
    for seed in range(20):
        result = diagnose([0.0] * n, seed=seed, noise=0.05, with_noise=with_noise)
        assert result.signature == "flat", seed
        assert result.spread_percent < FLAT_THRESHOLD_PERCENT
        assert result.causes[0].cause == "none"
        assert result.causes[0].score >= 0.5
        assert [c.cause for c in result.causes] == ["none", "preload_or_carriage"]
        assert "comparison" in result.causes[1].evidence


def test_large_spread_within_the_noise_is_flat() -> None:
    # Three velocities, 30 % noise per value: a 10 % spread is not significant.
    speeds = np.array([100.0, 1000.0, 10000.0])
    result = diagnose([0.0, 0.1, 0.0, 0.1, 0.0], speeds=speeds, noise=0.3, seed=4)
    assert result.spread_percent > FLAT_THRESHOLD_PERCENT
    assert result.signature == "flat"
    assert "noise" in result.causes[0].evidence


def test_irregular_profile() -> None:
    result = diagnose([0.0, 0.2, 0.0, 0.2, 0.0])
    assert result.signature == "irregular"
    assert result.causes[0].cause == "guide_rail"
    assert result.causes[0].score < 0.6  # a weak diagnosis


def test_fewer_than_three_positions_is_insufficient() -> None:
    result = diagnose([0.0, 0.3])
    assert result.signature == "insufficient_data"
    assert result.causes[0].score == 0.0
    assert "at least 3" in result.causes[0].evidence
    assert result.spread_percent > 20  # still reported

    values = table([0.0, 0.0, 0.3])
    values[:, 1] = np.nan  # the middle position missing at every velocity
    result = position_dependency(
        positions(3).tolist(), SPEEDS.tolist(), values, travel_mm=TRAVEL, fixed_bearing_end="min"
    )
    assert result.signature == "insufficient_data"


def test_profiles_average_first_and_missing_cells() -> None:
    values = table(LOOSE[5])
    values[0, 2] = np.nan  # one cell missing
    values[1, :4] = np.nan  # a velocity with a single position: no profile
    result = position_dependency(
        positions(5)[::-1].tolist(),  # any order
        SPEEDS.tolist(),
        values[:, ::-1],
        travel_mm=TRAVEL,
        fixed_bearing_end="min",
    )
    average = result.profiles[0]
    assert average.velocity_mm_min is None
    assert average.positions_mm == sorted(average.positions_mm)
    assert len(result.profiles) == 1 + SPEEDS.size - 1
    first = result.profiles[1]
    assert first.velocity_mm_min == pytest.approx(SPEEDS[0])
    assert len(first.positions_mm) == 4 and 375.0 not in first.positions_mm
    assert result.signature == "rising_to_loose_bearing"
    # The average is in Nm: its mean is the mean friction level, not 1.
    assert np.mean(average.values) == pytest.approx(np.nanmean(values), rel=0.05)


def test_high_and_low_speeds_weigh_alike() -> None:
    # Effect only at the lowest speed: normalised per velocity it counts like any other row.
    values = np.tile(curve(SPEEDS)[:, None], (1, 3))
    values[0] *= np.array([1.0, 1.0, 1.5])
    result = position_dependency(
        positions(3).tolist(), SPEEDS.tolist(), values, travel_mm=TRAVEL, fixed_bearing_end="min"
    )
    assert result.profiles[1].spread_percent == pytest.approx(100 * 0.5 / (3.5 / 3), rel=1e-6)
    assert result.spread_percent < 2.0  # one row of 50, not weighted by its Nm


def test_scores_are_ranked_and_bounded() -> None:
    for effect in (LOOSE[5], NUT[5], STEP[5], [0.0] * 5, [0.0, 0.2, 0.0, 0.2, 0.0]):
        causes = diagnose(effect).causes
        scores = [c.score for c in causes]
        assert scores == sorted(scores, reverse=True)
        assert all(0.0 <= s <= 1.0 for s in scores)
        assert len({c.cause for c in causes}) == len(causes)


def test_stronger_pattern_scores_higher() -> None:
    weak = diagnose([0.0, 0.04, 0.08, 0.12, 0.16])
    strong = diagnose(LOOSE[5])
    assert weak.signature == strong.signature == "rising_to_loose_bearing"
    assert weak.causes[0].score < strong.causes[0].score


def test_shape_mismatch_is_an_error() -> None:
    with pytest.raises(ValueError, match="expected"):
        position_dependency(
            [0.0, 1.0, 2.0],
            [10.0, 20.0],
            np.ones((3, 2)),
            travel_mm=TRAVEL,
            fixed_bearing_end="min",
        )
    with pytest.raises(ValueError, match="noise"):
        position_dependency(
            [0.0, 1.0, 2.0],
            [10.0],
            np.ones(3),
            travel_mm=TRAVEL,
            fixed_bearing_end="min",
            noise=np.ones(4),
        )


def test_json_round_trip() -> None:
    values = table(STEP[5])
    values[3, 1] = np.nan
    result = position_dependency(
        positions(5).tolist(), SPEEDS.tolist(), values, travel_mm=TRAVEL, fixed_bearing_end="max"
    )
    assert result.signature == "step"
    assert PositionDependency.model_validate_json(result.model_dump_json()) == result


def test_the_fastest_cells_do_not_decide_the_profile() -> None:
    """A fault adds the same torque at every speed, so viscous friction dilutes it where the
    axis runs fast (15 % of friction at 20 mm/min, 5 % at 12,000). The fast cells have the
    smallest relative error: weighted by (T/σ)² they made the profile 8.8 %; each cell
    counts at most as much as the table's typical one, so every speed has its say."""
    positions = [50.0, 225.0, 400.0, 575.0, 750.0]
    speeds = np.geomspace(20.0, 12000.0, 8)
    coulomb = np.array([1.0, 1.0, 1.0, 1.0, 1.15])
    exact = coulomb[None, :] + 2.0 / 12000.0 * speeds[:, None]
    rng = np.random.default_rng(1)
    table = exact + rng.normal(0.0, 0.004, exact.shape)
    per_speed = exact[:, 4] / exact[:, :4].mean(axis=1) - 1.0
    assert per_speed[0] > 2.9 * per_speed[-1]  # the dilution
    dependency = position_dependency(
        positions,
        speeds,
        table,
        travel_mm=(0.0, 800.0),
        fixed_bearing_end="min",
        noise=np.full_like(table, 0.004),
    )
    assert dependency.spread_percent == pytest.approx(100 * per_speed.mean(), abs=1.0)


@pytest.mark.parametrize(
    ("positions", "values", "signature"),
    [
        # a shifted loose bearing: every jump rises, the last three times the others
        ([5.0, 190.0, 375.0, 560.0, 745.0], [1.003, 1.004, 1.008, 1.013, 1.031], "rising"),
        # a cover step at the end with a small rise beside it: three points fit any power
        ([5.0, 375.0, 745.0], [1.00, 1.01, 1.20], "step"),
    ],
)
def test_a_convex_rise_to_a_bearing_is_no_step(
    positions: list[float], values: list[float], signature: str
) -> None:
    speeds = np.geomspace(20.0, 12000.0, 6)
    noise = 0.0002 if signature == "rising" else 0.005
    for seed in range(30):
        rng = np.random.default_rng(seed)
        table = np.array(values)[None, :] * (1.0 + noise * rng.standard_normal((6, len(values))))
        dependency = position_dependency(
            positions,
            speeds,
            table,
            travel_mm=(0.0, 750.0),
            fixed_bearing_end="min",
            flat_threshold_percent=2.0,
        )
        assert dependency.signature.startswith(signature), (seed, dependency.signature)
