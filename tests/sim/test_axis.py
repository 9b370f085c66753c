"""The feed-axis friction model against the method's test rig and its own physics.

Expectations come from the method summary (../shared/method.md, "Reference
numbers" and "What the patterns mean"): the rig's component friction, and the
shapes of friction along the travel for each assembly variance.
"""

from __future__ import annotations

import math
from typing import Any, Literal, get_args

import numpy as np
import pytest

from ncmeasure.analysis.judgement.diagnosis import position_dependency
from ncmeasure.config import AxisConfig
from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import CauseName
from ncmeasure.sim.axis import (
    EXAMPLE_VARIATIONS,
    AxisModel,
    AxisParameters,
    Component,
    Components,
    Variation,
    default_components,
    parse_variation,
)
from ncmeasure.sim.rig import RIG_MECHANICS, rig_mechanics

# Five measuring positions as the NC program places them on the rig's 0–750 mm
# travel with a 5 mm margin: next to the fixed bearing (travel min), three in
# between, next to the loose bearing (travel max).
POSITIONS_MM = np.linspace(5.0, 745.0, 5)
FEED_MM_MIN = 3000.0
# Velocity steps, geometric as the NC program spaces them.
VELOCITIES_MM_MIN = np.geomspace(50.0, 15000.0, 8)

RIG_COULOMB_NM = 0.72 + 0.09 + 0.09 + 0.25 + 0.205
RIG_VISCOUS_NMS_RAD = 0.05 + 0.00048 + 0.00048 + 0.00019 + 0.000014


def omega_rad_s(velocity_mm_min: float | np.ndarray, lead_mm: float = 20.0) -> np.ndarray:
    return np.asarray(2 * math.pi * np.asarray(velocity_mm_min) / 60.0 / lead_mm)


def change(variation: Variation, positions_mm: np.ndarray = POSITIONS_MM) -> np.ndarray:
    """Friction with the variation minus friction without it, at FEED_MM_MIN."""
    base = AxisModel().friction_torque_nm(positions_mm, FEED_MM_MIN)
    return AxisModel(variation=variation).friction_torque_nm(positions_mm, FEED_MM_MIN) - base


def r_squared(x: np.ndarray, y: np.ndarray) -> float:
    return float(np.corrcoef(x, y)[0, 1] ** 2)


# --- (1) components at default -------------------------------------------------------


def test_components_are_the_rig_values() -> None:
    comps = default_components()
    table = {name: (c.coulomb_nm, c.viscous_nms_rad) for name, c in comps.items()}
    assert table["motor"] == (0.72, 0.05)
    assert table["fixed_bearing"] == (0.09, 0.00048)
    assert table["loose_bearing"] == (0.09, 0.00048)
    assert table["nut"] == (0.25, 0.00019)
    assert table["guides"] == (0.205, 0.000014)
    assert table["covers"] == (0.0, 0.0)
    assert comps.coulomb_nm == pytest.approx(RIG_COULOMB_NM)
    assert comps.viscous_nms_rad == pytest.approx(RIG_VISCOUS_NMS_RAD)


def test_breakdown_adds_up_to_the_total() -> None:
    model = AxisModel()
    x, v = np.meshgrid(POSITIONS_MM, [-6000.0, -50.0, 0.0, 3.0, 500.0, 7500.0])
    parts = model.component_breakdown(x, v)
    assert set(parts) == {"motor", "fixed_bearing", "loose_bearing", "nut", "guides", "covers"}
    np.testing.assert_allclose(sum(parts.values()), model.friction_torque_nm(x, v), rtol=1e-12)


def test_linear_fit_at_speed_recovers_the_rig_totals() -> None:
    """Above the Stribeck region, T = T_C + t_v·ω with the summed rig parameters."""
    velocity = np.linspace(3000.0, 7500.0, 20)
    torque = AxisModel().friction_torque_nm(375.0, velocity)
    slope, intercept = np.polyfit(omega_rad_s(velocity), torque, 1)
    assert intercept == pytest.approx(RIG_COULOMB_NM, rel=1e-3)
    assert slope == pytest.approx(RIG_VISCOUS_NMS_RAD, rel=1e-3)
    # each component on its own, too
    parts = AxisModel().component_breakdown(375.0, 6000.0)
    for name, comp in default_components().items():
        expected = comp.coulomb_nm + comp.viscous_nms_rad * omega_rad_s(6000.0)
        assert parts[name] == pytest.approx(expected, rel=1e-3, abs=1e-9), name


def test_friction_is_odd_smooth_and_shows_stribeck() -> None:
    model = AxisModel()
    v = np.linspace(-2000.0, 2000.0, 4001)
    torque = model.friction_torque_nm(300.0, v)
    np.testing.assert_allclose(torque, -torque[::-1], atol=1e-12)
    assert torque[2000] == 0.0  # v = 0
    assert np.all(np.isfinite(torque))
    # continuous through standstill: the sign turns over ~1 mm/min (tanh), no jump
    fine = model.friction_torque_nm(300.0, np.linspace(-5.0, 5.0, 1001))
    assert np.max(np.abs(np.diff(fine))) < 0.05
    assert np.all(np.diff(fine[450:551]) > 0)  # rising through ±0.5 mm/min
    # static friction above Coulomb at low speed, decaying towards it
    speeds = np.array([20.0, 300.0, 1500.0])
    static = model.friction_torque_nm(300.0, speeds) - RIG_VISCOUS_NMS_RAD * omega_rad_s(speeds)
    assert static[0] > RIG_COULOMB_NM * 1.15
    assert np.all(np.diff(static) < 0)
    assert static[-1] == pytest.approx(RIG_COULOMB_NM, rel=0.01)
    # a magnitude in the range of the rig (a few Nm at 7500 mm/min)
    assert 2.0 < float(model.friction_torque_nm(300.0, 7500.0)) < 8.0


def test_friction_map_is_the_grid_of_friction_torque() -> None:
    model = AxisModel(variation=Variation(loose_bearing_shift_um=300))
    positions = np.array([10.0, 400.0, 740.0])
    velocities = np.array([-1000.0, 100.0, 5000.0, 7000.0])
    grid = model.friction_map(positions, velocities)
    assert grid.shape == (3, 4)
    for i, p in enumerate(positions):
        np.testing.assert_allclose(grid[i], model.friction_torque_nm(p, velocities))


# --- (2) the test-rig findings -------------------------------------------------------


def mean_change_percent(variation: Variation, axis: AxisParameters | None = None) -> np.ndarray:
    """Per position, the change against the nominal axis in %, averaged over velocities.

    What ``ncmeasure simulate`` prints (there over the machine's velocity range).
    """
    nominal = AxisModel(axis).friction_map(POSITIONS_MM, VELOCITIES_MM_MIN)
    varied = AxisModel(axis, variation=variation).friction_map(POSITIONS_MM, VELOCITIES_MM_MIN)
    return np.asarray(((varied / nominal - 1.0) * 100.0).mean(axis=1))


@pytest.mark.parametrize("shift_um", [20.0, 500.0, 1000.0])
def test_loose_bearing_shift_rises_gradually_towards_the_loose_bearing(shift_um: float) -> None:
    delta = change(Variation(loose_bearing_shift_um=shift_um))
    # next to the fixed bearing: no change worth the name
    assert delta[0] < 0.05 * delta[-1]
    assert np.all(np.diff(delta) > 0)
    # a rise along the travel, not a jump in the last interval (the analysis calls a
    # last jump >= 3 times every other one a step)
    jumps = np.diff(delta)
    assert jumps[-1] < 2 * jumps[-2]
    assert r_squared(POSITIONS_MM, delta) > 0.8


def test_loose_bearing_shim_of_the_rig_gives_a_clear_rise() -> None:
    """A 0.5 mm shim (the rig used 0.5–1 mm): +20–35 % next to it, ~0 at the other end."""
    percent = mean_change_percent(Variation(loose_bearing_shift_um=500.0))
    assert 20.0 < percent[-1] < 35.0
    assert percent[0] < 1.5
    at_feed = change(Variation(loose_bearing_shift_um=500.0))
    base = AxisModel().friction_torque_nm(POSITIONS_MM, FEED_MM_MIN)
    assert 0.2 < at_feed[-1] / base[-1] < 0.35


def test_fixed_bearing_shift_mirrors_the_loose_bearing() -> None:
    delta = change(Variation(fixed_bearing_shift_um=500.0))
    loose = change(Variation(loose_bearing_shift_um=500.0))
    assert np.all(np.diff(delta) < 0)
    np.testing.assert_allclose(delta, loose[::-1], rtol=1e-9)


def test_fixed_bearing_at_max_mirrors_the_axis() -> None:
    mirrored = AxisParameters(rig_mechanics(fixed_bearing_end="max"))
    variation = Variation(loose_bearing_shift_um=400.0, nut_shift_um=100.0, rail_misalignment_um=30)
    left = AxisModel(variation=variation).friction_torque_nm(POSITIONS_MM, FEED_MM_MIN)
    right = AxisModel(mirrored, variation=variation).friction_torque_nm(
        POSITIONS_MM[::-1], FEED_MM_MIN
    )
    np.testing.assert_allclose(left, right, rtol=1e-12)


@pytest.mark.parametrize("shift_um", [20.0, 500.0])
def test_nut_shift_rises_next_to_both_bearings(shift_um: float) -> None:
    delta = change(Variation(nut_shift_um=shift_um))
    assert delta[0] > 0 and delta[-1] > 0
    assert np.argmin(delta) == 2  # lowest mid-travel
    np.testing.assert_allclose(delta, delta[::-1], rtol=1e-9)  # symmetric bearing clearances
    # mid-travel about a third of the change next to the bearings (the rig: none)
    assert delta[2] < 0.34 * min(delta[0], delta[-1])


def test_nut_shim_of_the_rig_is_clear_next_to_both_bearings() -> None:
    percent = mean_change_percent(Variation(nut_shift_um=500.0))
    assert percent[0] >= 15.0 and percent[-1] >= 15.0
    assert percent[2] <= percent[0] / 3 + 0.1


def test_constraining_force_grows_as_the_nut_nears_the_misaligned_support() -> None:
    forces = AxisModel(variation=Variation(loose_bearing_shift_um=50.0)).normal_forces_n(
        np.linspace(0.0, 750.0, 31)
    )
    assert np.all(np.diff(forces["loose_bearing"]) > 0)
    np.testing.assert_allclose(forces["fixed_bearing"], 0.0, atol=1e-9)
    np.testing.assert_allclose(forces["nut"], forces["loose_bearing"])
    # Far from the shifted bearing, the cantilever 3EI/ℓ³ governs (span ~ 830 mm).
    params = AxisParameters()
    span_m = (params.span_mm - params.bearing_clearance_mm) / 1000.0
    beam = 3 * params.bending_stiffness_nm2 / span_m**3
    series = 1 / (1 / beam + 1 / (params.support_stiffness_n_per_um * 1e6))
    assert forces["loose_bearing"][0] == pytest.approx(series * 50e-6, rel=1e-6)
    # Next to it, the support chain caps the force at about k_s · δ.
    assert forces["loose_bearing"][-1] == pytest.approx(
        params.support_stiffness_n_per_um * 50.0, rel=0.05
    )


def test_constraining_forces_use_the_constraint_coefficient() -> None:
    """Friction added by a bent screw = Σ coefficient × force, times the Stribeck factor."""
    variation = Variation(nut_shift_um=300.0)
    model = AxisModel(variation=variation)
    forces = model.normal_forces_n(POSITIONS_MM)
    comps = Components()
    expected = sum(
        getattr(comps, name).constraint_coefficient_nm_per_n * forces[name]
        for name in ("fixed_bearing", "loose_bearing", "nut")
    )
    # at 7500 mm/min the Stribeck excess has decayed to ~1e-11
    np.testing.assert_allclose(
        model.friction_torque_nm(POSITIONS_MM, 7500.0)
        - AxisModel().friction_torque_nm(POSITIONS_MM, 7500.0),
        expected,
        rtol=1e-6,
    )


def test_per_newton_coefficients_follow_their_sources() -> None:
    comps = Components()
    # nut: preload drag torque 0.05 (tan β)^-0.5 · F · h / 2π, tan β = h / (π d)
    jis = 0.05 / math.sqrt(20.0 / (math.pi * 40.0)) * 0.020 / (2 * math.pi)
    assert comps.nut.torque_per_newton_nm == pytest.approx(jis)
    assert comps.nut.constraint_coefficient_nm_per_n == pytest.approx(jis)
    assert comps.nut.nominal_normal_force_n == pytest.approx(0.7 * 0.25 / jis)  # ≈ 440 N
    # bearings: radial load on a 60° contact counts tan 60° / 0.8 ≈ 2.2 times the axial one
    for bearing in (comps.fixed_bearing, comps.loose_bearing):
        assert bearing.constraint_coefficient_nm_per_n == pytest.approx(
            2.2 * bearing.torque_per_newton_nm
        )
    # guides: μ 0.003 through the lead
    assert comps.guides.torque_per_newton_nm == pytest.approx(0.003 * 0.020 / (2 * math.pi))


def test_constraint_coefficient_defaults_to_the_preload_one() -> None:
    plain = Component(1.0, 0.0, load_share=0.5, torque_per_newton_nm=1e-4)
    assert plain.constraint_coefficient_nm_per_n == 1e-4
    own = Component(
        1.0, 0.0, load_share=0.5, torque_per_newton_nm=1e-4, constraint_torque_per_newton_nm=3e-4
    )
    assert own.constraint_coefficient_nm_per_n == 3e-4
    assert own.nominal_normal_force_n == pytest.approx(5000.0)  # preload: own coefficient
    with pytest.raises(ConfigError, match="constraint_torque_per_newton_nm"):
        Component(1.0, 0.0, constraint_torque_per_newton_nm=-1e-4)


@pytest.mark.parametrize(
    ("key", "value", "sign"),
    [
        ("bearing_preload_change", -0.6, -1),
        ("nut_preload_change", -0.6, -1),
        ("nut_preload_change", 0.3, 1),
        ("carriage_preload_change", 0.5, 1),
    ],
)
def test_preload_change_is_a_constant_offset(key: str, value: float, sign: int) -> None:
    delta = change(Variation(**{key: value}))
    mean = float(np.mean(delta))
    assert sign * mean > 0
    assert np.ptp(delta) < 0.02 * abs(mean)


def test_bearing_preload_loss_matches_the_load_dependent_share() -> None:
    """−60 % preload on both bearings: 0.6 × load share × Coulomb each, at speed."""
    comps = Components()
    expected = -0.6 * sum(
        c.load_share * c.coulomb_nm for c in (comps.fixed_bearing, comps.loose_bearing)
    )
    delta = AxisModel(variation=Variation(bearing_preload_change=-0.6)).friction_torque_nm(
        300.0, 7500.0
    ) - AxisModel().friction_torque_nm(300.0, 7500.0)
    assert float(delta) == pytest.approx(expected, rel=1e-3)


# --- (3) rail bow and covers ---------------------------------------------------------


def test_rail_bow_peaks_mid_travel() -> None:
    positions = np.linspace(0.0, 750.0, 31)
    delta = change(Variation(rail_misalignment_um=30.0), positions)
    assert delta[0] == pytest.approx(0.0, abs=1e-12)
    assert delta[-1] == pytest.approx(0.0, abs=1e-12)
    assert int(np.argmax(delta)) == 15  # 375 mm
    np.testing.assert_allclose(delta, delta[::-1], rtol=1e-9, atol=1e-12)
    # it follows the bow 4t(1 − t) exactly: force k_guide · δ · bow on the guides
    t = positions / 750.0
    np.testing.assert_allclose(delta / delta[15], 4 * t * (1 - t), atol=1e-9)
    model = AxisModel(variation=Variation(rail_misalignment_um=-30.0))
    params = AxisParameters()
    np.testing.assert_allclose(
        model.normal_forces_n(positions)["guides"],
        params.guide_stiffness_n_per_um * 30.0 * 4 * t * (1 - t),
        rtol=1e-9,
        atol=1e-9,
    )
    # the guides alone carry it
    parts = model.component_breakdown(positions, FEED_MM_MIN)
    base = AxisModel().component_breakdown(positions, FEED_MM_MIN)
    np.testing.assert_allclose(parts["guides"] - base["guides"], delta, rtol=1e-9, atol=1e-12)


def test_rail_bow_of_50_um_gives_a_clear_mid_travel_rise() -> None:
    percent = mean_change_percent(Variation(rail_misalignment_um=50.0))
    assert percent[2] >= 10.0
    assert percent[0] < 1.0 and percent[-1] < 1.0


def test_cover_step_is_a_step_of_the_given_size() -> None:
    positions = np.linspace(0.0, 750.0, 31)
    variation = Variation(cover_step=0.2, cover_step_position_mm=500.0)
    base = AxisModel().friction_torque_nm(positions, FEED_MM_MIN)
    stepped = AxisModel(variation=variation).friction_torque_nm(positions, FEED_MM_MIN)
    before = positions < 500.0
    np.testing.assert_allclose(stepped[before], base[before], rtol=1e-12)
    np.testing.assert_allclose(stepped[~before] / base[~before], 1.2, rtol=1e-9)
    # both directions
    negative = AxisModel(variation=variation).friction_torque_nm(700.0, -FEED_MM_MIN)
    assert float(negative) == pytest.approx(-1.2 * float(base[-1]), rel=1e-9)


def test_cover_step_defaults_to_40_percent_of_the_travel_and_must_be_inside() -> None:
    model = AxisModel(variation=Variation(cover_step=0.2))  # travel 0..750 mm: step at 300 mm
    below, above = model.friction_torque_nm(np.array([295.0, 305.0]), FEED_MM_MIN)
    assert above / below == pytest.approx(1.2, rel=1e-9)
    with pytest.raises(ConfigError, match="invalid assembly variation") as info:
        AxisModel(variation=Variation(cover_step=0.2, cover_step_position_mm=900.0))
    assert "cover_step_position_mm: 900 mm is outside the travel" in str(info.value)


# --- (3b) the example variations through the real analysis ---------------------------


def diagnose(variation: Variation, fixed_bearing_end: Literal["min", "max"] = "min") -> Any:
    axis = AxisParameters(rig_mechanics(fixed_bearing_end=fixed_bearing_end))
    friction = AxisModel(axis, variation=variation).friction_map(POSITIONS_MM, VELOCITIES_MM_MIN)
    return position_dependency(
        POSITIONS_MM,
        VELOCITIES_MM_MIN,
        np.abs(friction).T,
        travel_mm=axis.mechanics.travel_mm,
        fixed_bearing_end=fixed_bearing_end,
    )


def test_example_variations_cover_every_cause() -> None:
    assert set(EXAMPLE_VARIATIONS) == set(get_args(CauseName)) - {"none"}
    with pytest.raises(TypeError):
        EXAMPLE_VARIATIONS["screw_nut"] = Variation()  # type: ignore[index]


@pytest.mark.parametrize("end", ["min", "max"])
@pytest.mark.parametrize("cause", sorted(set(EXAMPLE_VARIATIONS) - {"preload_or_carriage"}))
def test_the_analysis_ranks_each_example_cause_first(
    cause: str, end: Literal["min", "max"]
) -> None:
    result = diagnose(EXAMPLE_VARIATIONS[cause], end)
    assert result.causes[0].cause == cause, (result.signature, result.causes[0].evidence)
    assert result.spread_percent > 10.0


@pytest.mark.parametrize("end", ["min", "max"])
def test_a_preload_example_is_flat_but_raises_the_level(end: Literal["min", "max"]) -> None:
    variation = EXAMPLE_VARIATIONS["preload_or_carriage"]
    result = diagnose(variation, end)
    assert result.signature == "flat"
    assert result.spread_percent < 0.1
    axis = AxisParameters(rig_mechanics(fixed_bearing_end=end))
    nominal = AxisModel(axis).friction_map(POSITIONS_MM, VELOCITIES_MM_MIN)
    varied = AxisModel(axis, variation=variation).friction_map(POSITIONS_MM, VELOCITIES_MM_MIN)
    assert float(varied.mean()) > 1.10 * float(nominal.mean())
    assert np.all(varied > nominal)  # at every position and velocity


def test_variation_as_text_reads_back() -> None:
    assert Variation().as_text() == ""
    assert EXAMPLE_VARIATIONS["loose_bearing"].as_text() == "loose_bearing_shift_um=500"
    assert EXAMPLE_VARIATIONS["cover_or_seal"].as_text() == "cover_step=0.2"
    odd = Variation(
        nut_shift_um=0.1 + 0.2,
        bearing_preload_change=-0.3,
        cover_step=0.1,
        cover_step_position_mm=0.0,
    )
    assert odd.as_text() == (
        "nut_shift_um=0.30000000000000004,bearing_preload_change=-0.3,cover_step=0.1,"
        "cover_step_position_mm=0"
    )
    for variation in (odd, *EXAMPLE_VARIATIONS.values()):
        assert parse_variation(variation.as_text()) == variation


# --- (4) parse_variation -------------------------------------------------------------


def test_parse_variation_reads_pairs() -> None:
    assert parse_variation("loose_bearing_shift_um=20") == Variation(loose_bearing_shift_um=20.0)
    assert parse_variation(" nut_shift_um=5, cover_step=0.2  rail_misalignment_um=-10 ") == (
        Variation(nut_shift_um=5.0, cover_step=0.2, rail_misalignment_um=-10.0)
    )
    assert parse_variation("") == Variation()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("loose_bearing_shft_um=20", "loose_bearing_shft_um: unknown variation key"),
        ("nut_shift_um=abc", "nut_shift_um: 'abc' is not a number"),
        ("nut_shift_um=nan", "nut_shift_um: 'nan' is not a finite number"),
        ("nut_shift_um", "'nut_shift_um': expected key=value"),
        ("=3", "'=3': expected key=value"),
        ("nut_shift_um=1,nut_shift_um=2", "nut_shift_um: given twice"),
        ("bearing_preload_change=-1.5", "bearing_preload_change: -1.5 must be > -1"),
        ("cover_step=-2", "cover_step: -2.0 must be >= -1"),
    ],
)
def test_parse_variation_errors_name_key_and_value(text: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_variation(text)
    assert message in str(info.value)
    assert isinstance(info.value, ValueError)


def test_unknown_key_error_lists_the_known_keys() -> None:
    with pytest.raises(ConfigError, match="known: fixed_bearing_shift_um, loose_bearing"):
        parse_variation("x=1")


# --- (5) motor current ---------------------------------------------------------------


def revolution_positions(start_mm: float, revolutions: int, per_rev: int = 360) -> np.ndarray:
    lead = 20.0
    return start_mm + np.arange(revolutions * per_rev) * lead / per_rev


def test_cogging_averages_out_over_a_revolution() -> None:
    model = AxisModel()
    ripple = model.cogging_current_a(revolution_positions(100.0, 1))
    assert abs(float(np.mean(ripple))) < 1e-12
    assert float(np.ptp(ripple)) > 0.01  # but it is there
    # periodic in the motor angle: one lead further is the same current
    np.testing.assert_allclose(
        model.cogging_current_a(np.array([33.3])), model.cogging_current_a(np.array([53.3]))
    )


def test_current_at_constant_velocity_is_friction_over_kt() -> None:
    model = AxisModel(variation=Variation(loose_bearing_shift_um=200.0))
    x = revolution_positions(300.0, 1)
    current = model.motor_current_a(x, 2000.0, 0.0)
    friction = model.friction_torque_nm(x, 2000.0)
    np.testing.assert_allclose(current, friction / 2.1 + model.cogging_current_a(x), rtol=1e-12)
    assert float(np.mean(current)) == pytest.approx(float(np.mean(friction)) / 2.1, rel=1e-9)


def test_vertical_axis_adds_gravity() -> None:
    params = AxisParameters(rig_mechanics(vertical=True), moved_mass_kg=300.0)
    model = AxisModel(params)
    x = revolution_positions(300.0, 1)
    gravity_nm = 300.0 * 9.81 * 0.020 / (2 * math.pi)
    for velocity in (1500.0, -1500.0):
        current = model.motor_current_a(x, velocity)
        expected = (float(np.mean(model.friction_torque_nm(x, velocity))) + gravity_nm) / 2.1
        assert float(np.mean(current)) == pytest.approx(expected, rel=1e-9)


def test_acceleration_term_is_inertia_times_angular_acceleration() -> None:
    params = AxisParameters()
    model = AxisModel(params)
    accel = 2.0
    extra = model.motor_current_a(200.0, 3000.0, accel) - model.motor_current_a(200.0, 3000.0)
    alpha = 2 * math.pi * accel * 1000.0 / 20.0
    assert float(extra) == pytest.approx(params.inertia_kgm2 * alpha / 2.1, rel=1e-12)
    # rotor + screw (Ø40, 910 mm) + 500 kg through a 20 mm lead
    screw = math.pi * 7850 * 0.910 * 0.040**4 / 32
    table = 500.0 * (0.020 / (2 * math.pi)) ** 2
    assert params.inertia_kgm2 == pytest.approx(0.0193 + screw + table)


def test_noise_and_outliers_are_seeded_and_robust_to_the_median() -> None:
    model = AxisModel()
    x = revolution_positions(100.0, 20)
    clean = model.motor_current_a(x, 1000.0)
    noisy = model.motor_current_a(x, 1000.0, rng=np.random.default_rng(7))
    again = model.motor_current_a(x, 1000.0, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(noisy, again)
    residual = noisy - clean
    outliers = np.abs(residual) > 1.0
    assert 0 < outliers.sum() < 30  # rate 1e-3 of 7200 samples
    assert float(np.std(residual[~outliers])) == pytest.approx(0.02, rel=0.1)
    assert float(np.median(noisy)) == pytest.approx(float(np.median(clean)), abs=0.01)


def test_axis_config_supplies_travel_bearing_end_and_drive_data() -> None:
    config = AxisConfig(
        name="X",
        travel_mm=(-100.0, 500.0),
        park_mm=0.0,
        max_velocity_mm_min=20000.0,
        max_acceleration_m_s2=2.0,
        max_jerk_m_s3=50.0,
        fixed_bearing_end="max",
        vertical=True,
        torque_constant_nm_per_a=1.5,
        screw_lead_mm=10.0,
    )
    model = AxisModel(config)
    assert model.axis.mechanics.travel_mm == (-100.0, 500.0)
    assert model.axis.mechanics.fixed_bearing_end == "max"
    assert model.axis.mechanics.vertical
    assert model.axis.torque_constant_nm_per_a == 1.5
    assert model.axis.screw_lead_mm == 10.0
    assert model.axis.gravity_torque_nm > 0
    # the shifted loose bearing now sits at travel min
    delta = AxisModel(config, variation=Variation(loose_bearing_shift_um=300)).friction_torque_nm(
        np.array([-90.0, 490.0]), 1000.0
    ) - model.friction_torque_nm(np.array([-90.0, 490.0]), 1000.0)
    assert delta[0] > 5 * delta[1]


def test_invalid_parameters_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="travel_mm: min"):
        AxisParameters(rig_mechanics(travel_mm=(10.0, 10.0)))
    with pytest.raises(ConfigError, match="torque_constant_nm_per_a"):
        AxisParameters(rig_mechanics(torque_constant_nm_per_a=0.0))
    # the model's own check, for mechanics that were not validated
    unchecked = RIG_MECHANICS.model_copy(update={"torque_constant_nm_per_a": 0.0})
    with pytest.raises(ConfigError, match=r"torque_constant_nm_per_a: 0\.0 must be > 0"):
        AxisParameters(unchecked)
    # the model needs k_T and the lead stated
    with pytest.raises(ConfigError) as unstated:
        AxisParameters(rig_mechanics(torque_constant_nm_per_a=None, screw_lead_mm=None))
    assert unstated.value.problems == (
        "torque_constant_nm_per_a: None must be > 0",
        "screw_lead_mm: None must be > 0",
    )
