"""Fits on synthetic friction curves whose true parameters are known."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import optimize

import ncmeasure.analysis.friction.stribeck as fit_module
from ncmeasure.analysis.friction.fit import (
    MEDIAN_SE_FACTOR,
    fit_direction,
    point_sigma,
    separate_offset,
)
from ncmeasure.analysis.friction.linear import fit_linear
from ncmeasure.analysis.friction.stribeck import fit_nonlinear
from ncmeasure.formats.results import Point

# The schedule of the example machine: 50 geometric steps, 10..15000 mm/min.
SPEEDS = np.geomspace(10.0, 15000.0, 50)
T_C, T_S, V_S, DELTA, B = 1.5, 2.2, 60.0, 1.0, 2e-4  # Nm, Nm, mm/min, -, Nm per mm/min


def stribeck(
    v: np.ndarray,
    tc: float = T_C,
    ts: float = T_S,
    vs: float = V_S,
    delta: float = DELTA,
    b: float = B,
    fw: float = 0.0,
    k: float = 1.0,
) -> np.ndarray:
    return tc + (ts - tc) * np.exp(-((v / vs) ** delta)) + b * v + fw * (v / 1000.0) ** k


def points(
    speeds: np.ndarray,
    magnitude: np.ndarray,
    sigma: float | np.ndarray,
    direction: int = 1,
    offset: float = 0.0,
    n: int = 100,
) -> list[Point]:
    """Points as the friction table writes them: signed velocity and median, std of samples.

    ``sigma`` is the standard error of each median, so std = σ·√n / √(π/2).
    """
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), speeds.shape)
    return [
        Point(
            velocity_mm_min=direction * float(v),
            median=direction * float(t) + offset,
            mean=direction * float(t) + offset,
            std=float(s) * math.sqrt(n) / MEDIAN_SE_FACTOR,
            n=n,
        )
        for v, t, s in zip(speeds, magnitude, sig, strict=True)
    ]


# --------------------------------------------------------------------------- linear


@pytest.mark.parametrize("weighted", [True, False])
def test_linear_standard_errors_cover_the_truth(weighted: bool) -> None:
    sigma = 0.02
    hits = np.zeros(2)
    runs = 200
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        value = T_C + B * SPEEDS + rng.normal(0.0, sigma, SPEEDS.size)
        fit = fit_linear(SPEEDS, value, np.full(SPEEDS.size, sigma) if weighted else None)
        assert fit is not None
        hits[0] += abs(fit.coulomb - T_C) <= 2 * fit.coulomb_stderr
        hits[1] += abs(fit.viscous_per_mm_min - B) <= 2 * fit.viscous_stderr
    coverage = hits / runs
    # ±2σ covers 95.4 %; the binomial scatter of 200 trials is ±1.5 %.
    assert np.all(coverage >= 0.90), coverage
    assert np.all(coverage <= 0.99), coverage


def test_linear_chi2_accepts_the_right_model_and_rejects_a_stribeck_hump() -> None:
    rng = np.random.default_rng(7)
    sigma = np.full(SPEEDS.size, 0.01)
    right = fit_linear(SPEEDS, T_C + B * SPEEDS + rng.normal(0, 0.01, SPEEDS.size), sigma)
    wrong = fit_linear(SPEEDS, stribeck(SPEEDS) + rng.normal(0, 0.01, SPEEDS.size), sigma)
    assert right is not None and wrong is not None
    assert right.accepted and 0.5 < right.chi2_reduced < 1.6
    assert not wrong.accepted and wrong.chi2_reduced > 10
    # The same hump data pass with k large enough: the flag follows k_accept.
    lenient = fit_linear(SPEEDS, stribeck(SPEEDS), sigma, k_accept=1e6)
    assert lenient is not None and lenient.accepted


def test_linear_without_sigma_uses_residual_scatter_so_chi2_is_one() -> None:
    fit = fit_linear(SPEEDS, stribeck(SPEEDS))
    assert fit is not None
    assert fit.chi2_reduced == pytest.approx(1.0)
    assert fit.accepted
    assert fit.n_points == SPEEDS.size
    assert fit.velocity_range_mm_min == pytest.approx((10.0, 15000.0))


def test_linear_drops_bad_points_and_refuses_too_few() -> None:
    assert fit_linear([100.0, 200.0], [1.0, 1.1]) is None
    assert fit_linear([100.0, 100.0, 100.0], [1.0, 1.1, 1.2]) is None
    fit = fit_linear([-100.0, 200.0, np.nan, 400.0], [1.1, 1.2, 5.0, 1.4], [0.01, 0.01, 0.01, 0.0])
    # NaN speed and σ = 0 dropped; signs of speeds ignored: 2 points left.
    assert fit is None
    fit = fit_linear([-100.0, 200.0, 300.0, 400.0], [1.1, 1.2, 1.3, 1.4])
    assert fit is not None and fit.coulomb == pytest.approx(1.0)
    assert fit.velocity_range_mm_min == (100.0, 400.0)


@settings(max_examples=50, deadline=None)
@given(
    coulomb=st.floats(0.05, 20.0),
    viscous=st.floats(0.0, 1e-3),
    low=st.floats(1.0, 100.0),
)
def test_linear_is_exact_on_exact_data(coulomb: float, viscous: float, low: float) -> None:
    speeds = np.geomspace(low, low * 500.0, 12)
    fit = fit_linear(speeds, coulomb + viscous * speeds)
    assert fit is not None
    assert fit.coulomb == pytest.approx(coulomb, rel=1e-9, abs=1e-9)
    assert fit.viscous_per_mm_min == pytest.approx(viscous, rel=1e-7, abs=1e-12)
    assert fit.coulomb_stderr < 1e-8 * max(coulomb, 1.0)


# --------------------------------------------------------------------------- nonlinear


def test_stribeck_recovers_its_parameters_and_is_identifiable() -> None:
    rng = np.random.default_rng(3)
    sigma = 0.01 * (1 + 3 * np.exp(-SPEEDS / 30) + SPEEDS / 15000)  # rough at low speed
    fit = fit_nonlinear(
        SPEEDS, stribeck(SPEEDS) + rng.normal(0, 1, SPEEDS.size) * sigma, sigma, model="stribeck"
    )
    assert fit is not None
    assert fit.identifiable
    assert fit.stribeck_velocity_mm_min == fit.parameters["v_S"]
    truth = {"T_C": T_C, "T_S": T_S, "v_S": V_S, "delta": DELTA, "b": B}
    for name, value in truth.items():
        low, high = fit.ci95[name]
        assert low <= value <= high, (name, fit.ci95[name])
        assert high - low < 0.5 * abs(value), name
    assert 0.5 < fit.chi2_reduced < 2.0


def test_stribeck_intervals_cover_the_truth() -> None:
    truth = {"T_C": T_C, "T_S": T_S, "v_S": V_S, "delta": DELTA, "b": B}
    hits = dict.fromkeys(truth, 0)
    runs = 60
    for seed in range(runs):
        rng = np.random.default_rng(100 + seed)
        value = stribeck(SPEEDS) + rng.normal(0, 0.015, SPEEDS.size)
        fit = fit_nonlinear(SPEEDS, value, np.full(SPEEDS.size, 0.015), model="stribeck")
        assert fit is not None and fit.identifiable
        for name, true in truth.items():
            hits[name] += fit.ci95[name][0] <= true <= fit.ci95[name][1]
    for name, count in hits.items():
        assert count / runs >= 0.85, (name, count)


def test_stribeck_is_not_identifiable_on_coulomb_viscous_data() -> None:
    for seed in range(10):
        rng = np.random.default_rng(seed)
        value = T_C + B * SPEEDS + rng.normal(0, 0.01, SPEEDS.size)
        fit = fit_nonlinear(SPEEDS, value, np.full(SPEEDS.size, 0.01), model="stribeck")
        assert fit is None or not fit.identifiable


def test_extended_model_finds_a_negative_rolling_term() -> None:
    # A ball screw with many loaded balls: the curve bends down at high speed.
    fw, k, b = -0.06, 1.5, 5e-4
    rng = np.random.default_rng(11)
    value = stribeck(SPEEDS, b=b, fw=fw, k=k) + rng.normal(0, 0.01, SPEEDS.size)
    sigma = np.full(SPEEDS.size, 0.01)
    fit = fit_nonlinear(SPEEDS, value, sigma, model="extended")
    assert fit is not None
    assert set(fit.parameters) == {"T_C", "T_S", "v_S", "delta", "b", "f_w", "k"}
    assert fit.identifiable
    truth = {"T_C": T_C, "T_S": T_S, "v_S": V_S, "delta": DELTA, "b": b, "f_w": fw, "k": k}
    for name, true in truth.items():
        low, high = fit.ci95[name]
        # within 1.5 half-widths of the 95 % interval, i.e. about 3 standard errors
        assert abs(fit.parameters[name] - true) <= 0.75 * (high - low), name
    assert fit.ci95["f_w"][1] < 0  # significantly negative
    # The plain Stribeck model cannot bend down: it fails the χ² test on the same data.
    plain = fit_nonlinear(SPEEDS, value, sigma, model="stribeck")
    assert plain is not None and plain.chi2_reduced > 10 * fit.chi2_reduced


@pytest.mark.parametrize(
    ("speeds", "values"),
    [
        (SPEEDS[:6], stribeck(SPEEDS[:6])),  # 6 < 5 parameters + 2
        (np.full(20, 100.0), np.full(20, 1.0)),  # one speed
        (SPEEDS, np.full(SPEEDS.size, np.nan)),
        (SPEEDS, np.zeros(SPEEDS.size)),
        (np.zeros(20), np.ones(20)),
    ],
)
def test_nonlinear_returns_none_instead_of_raising(speeds: np.ndarray, values: np.ndarray) -> None:
    for model in ("stribeck", "extended"):
        result = fit_nonlinear(speeds, values, model=model)
        assert result is None or not result.identifiable


def test_extended_needs_more_points_than_stribeck() -> None:
    speeds = SPEEDS[::6][:8]  # 8 points: Stribeck needs 5 + 2, extended 7 + 2
    assert fit_nonlinear(speeds, stribeck(speeds), model="stribeck") is not None
    assert fit_nonlinear(speeds, stribeck(speeds), model="extended") is None
    assert fit_nonlinear(SPEEDS[::5], stribeck(SPEEDS[::5]), model="extended") is not None


# --------------------------------------------------------------------------- per direction


@pytest.mark.parametrize("direction", [1, -1])
def test_fit_direction_uses_only_points_above_the_stribeck_region(direction: int) -> None:
    rng = np.random.default_rng(5)
    sigma = 0.01
    magnitude = stribeck(SPEEDS) + rng.normal(0, sigma, SPEEDS.size)
    found = fit_direction(points(SPEEDS, magnitude, sigma, direction), direction)  # type: ignore[arg-type]
    linear, strib, extended = found.fit, found.stribeck, found.extended
    assert strib is not None and strib.identifiable and strib.parameters is not None
    assert extended is not None
    assert linear is not None
    assert linear.coulomb is not None and linear.coulomb_stderr is not None
    assert linear.viscous_per_mm_min is not None and linear.viscous_stderr is not None
    assert found.model == "stribeck"
    v_s = strib.parameters["v_S"]
    assert linear.velocity_range_mm_min[0] >= 3 * v_s
    assert linear.n_points < SPEEDS.size
    # Above the hump the line is the true Coulomb + viscous line ...
    assert abs(linear.coulomb - T_C) <= 3 * linear.coulomb_stderr
    assert abs(linear.viscous_per_mm_min - B) <= 3 * linear.viscous_stderr
    assert linear.accepted
    # ... while a line through all points is biased and fails the χ² test.
    everything = fit_linear(SPEEDS, magnitude, np.full(SPEEDS.size, sigma))
    assert everything is not None and not everything.accepted
    assert everything.coulomb is not None and everything.coulomb_stderr is not None
    assert abs(everything.coulomb - T_C) > 5 * everything.coulomb_stderr


def test_fit_direction_uses_all_points_without_a_stribeck_region() -> None:
    rng = np.random.default_rng(9)
    magnitude = T_C + B * SPEEDS + rng.normal(0, 0.01, SPEEDS.size)
    found = fit_direction(points(SPEEDS, magnitude, 0.01, -1), -1)
    linear, strib = found.fit, found.stribeck
    assert strib is None or not strib.identifiable
    assert strib is None or (strib.parameters is None and strib.reason)
    assert linear is not None
    assert linear.n_points == SPEEDS.size
    assert linear.points_below_range == 0
    assert linear.velocity_range_mm_min[0] == pytest.approx(10.0)
    assert linear.coulomb == pytest.approx(T_C, abs=0.02)
    assert found.model == "linear"
    assert "every point" in found.model_reason


def test_linear_fit_holds_above_a_hump_the_stribeck_fit_cannot_resolve() -> None:
    """Real data: a curve rising at low speed, 8 steps, no identifiable Stribeck fit.

    Fitted over every speed, the line was dragged by the hump (χ²ᵣ 237, Coulomb 10 %
    off a fit of the linear region). The line is fitted over the range where it holds.
    """
    rng = np.random.default_rng(4)
    speeds = np.array([20.0, 50.0, 120.0, 300.0, 800.0, 2000.0, 5000.0, 12000.0])
    sigma = 0.004
    magnitude = 1.5 + 0.6 * np.exp(-speeds / 40.0) + 1e-4 * speeds
    magnitude = magnitude + rng.normal(0, sigma, speeds.size)
    found = fit_direction(points(speeds, magnitude, sigma), 1)
    everything = fit_linear(speeds, magnitude, np.full(speeds.size, sigma))
    assert everything is not None and not everything.accepted
    linear = found.fit
    assert linear is not None and linear.accepted and linear.coulomb is not None
    assert linear.points_below_range >= 1
    assert linear.velocity_range_mm_min[0] > 20.0
    assert linear.coulomb == pytest.approx(1.5, rel=0.01)
    assert found.model in ("linear", "stribeck")
    if found.model == "linear":
        assert "holds from" in found.model_reason


def test_a_negative_coulomb_is_published_as_null_with_the_reason() -> None:
    """Gravity left in the points of the downward direction: 'friction' below zero."""
    magnitude = -14.0 + 2e-5 * SPEEDS  # F − o with o (gravity) far above F
    fit = fit_linear(SPEEDS, magnitude, np.full(SPEEDS.size, 0.01))
    assert fit is not None
    assert fit.coulomb is None and fit.viscous_per_mm_min is None
    assert fit.reason is not None and "gravity" in fit.reason
    assert not fit.accepted


def test_a_nonlinear_fit_that_is_not_identifiable_publishes_no_parameters() -> None:
    rng = np.random.default_rng(2)
    magnitude = T_C + B * SPEEDS + rng.normal(0, 0.01, SPEEDS.size)  # no hump at all
    fit = fit_nonlinear(SPEEDS, magnitude, np.full(SPEEDS.size, 0.01), model="stribeck")
    assert fit is not None and not fit.identifiable
    assert fit.parameters is None and fit.ci95 is None
    assert fit.reason and "hump" in fit.reason


def test_the_offset_is_taken_out_before_fitting() -> None:
    gravity = 14.0
    up = points(SPEEDS, stribeck(SPEEDS), 0.01, 1, offset=gravity)
    down = points(SPEEDS, stribeck(SPEEDS), 0.01, -1, offset=gravity)
    offset = separate_offset(up, down)
    assert offset is not None
    for sign, pts in ((1, up), (-1, down)):
        found = fit_direction(pts, sign, offset=offset)  # type: ignore[arg-type]
        assert found.offset_removed == pytest.approx(gravity)
        assert found.fit is not None and found.fit.coulomb is not None
        assert found.fit.coulomb == pytest.approx(T_C, rel=0.02)
    # Without the offset, the downward direction is no friction: null, never negative.
    raw = fit_direction(down, -1)
    assert raw.fit is not None and raw.fit.coulomb is None


def test_point_sigma_guards_zero_std_and_empty_windows() -> None:
    pts = [
        Point(velocity_mm_min=10.0, median=1.0, mean=1.0, std=0.1, n=100),  # σ 0.01
        Point(velocity_mm_min=20.0, median=1.0, mean=1.0, std=0.0, n=100),  # quantised
        Point(velocity_mm_min=30.0, median=1.0, mean=1.0, std=0.3, n=0),  # no samples
        Point(velocity_mm_min=40.0, median=1.0, mean=1.0, std=0.3, n=100),  # σ 0.03
    ]
    sigma = point_sigma(pts)
    assert sigma is not None
    np.testing.assert_allclose(sigma, np.array([0.01, 0.02, 0.02, 0.03]) * MEDIAN_SE_FACTOR)
    assert point_sigma([Point(velocity_mm_min=1.0, median=1.0, mean=1.0, std=0.0, n=5)]) is None
    empty = fit_direction([], 1)
    assert empty.fit is None and empty.model is None


def test_point_sigma_takes_the_batch_standard_error_where_given() -> None:
    pts = [
        Point(velocity_mm_min=10.0, median=1.0, mean=1.0, std=0.1, n=100, stderr=0.05),
        Point(velocity_mm_min=20.0, median=1.0, mean=1.0, std=0.1, n=100),
    ]
    sigma = point_sigma(pts)
    assert sigma is not None
    np.testing.assert_allclose(sigma, [0.05, 0.01 * MEDIAN_SE_FACTOR])


# --------------------------------------------------------------------------- offset


def test_separate_offset_recovers_gravity_on_a_vertical_axis() -> None:
    gravity = 0.8  # Nm: the weight's torque on the screw, same sign in both directions
    rng = np.random.default_rng(2)
    friction = stribeck(SPEEDS)
    up = points(SPEEDS, friction + rng.normal(0, 0.01, SPEEDS.size), 0.01, 1, gravity)
    down = points(SPEEDS, friction + rng.normal(0, 0.01, SPEEDS.size), 0.01, -1, gravity)
    result = separate_offset(up, down)
    assert result is not None
    assert result.stderr is not None and 0 < result.stderr < 0.01
    assert abs(result.value - gravity) <= 3 * result.stderr
    assert "gravity" in result.explanation
    assert "significant" in result.explanation
    assert "50 speed(s)" in result.explanation


def test_separate_offset_matches_speeds_within_half_a_percent() -> None:
    up = points(np.array([100.0, 1000.0]), np.array([1.0, 1.2]), 0.01, 1, 0.5)
    close = points(np.array([100.3, 1010.0]), np.array([1.0, 1.2]), 0.01, -1, 0.5)
    result = separate_offset(up, close)  # 0.3 % matches, 1 % does not
    assert result is not None
    assert result.value == pytest.approx(0.5)
    assert "1 speed(s)" in result.explanation
    assert result.stderr == pytest.approx(0.5 * math.sqrt(2) * 0.01)
    far = points(np.array([110.0, 1100.0]), np.array([1.0, 1.2]), 0.01, -1, 0.5)
    assert separate_offset(up, far) is None
    assert separate_offset(up, []) is None


# --------------------------------------------------------------------------- search


def _reference_search(p: fit_module._Problem) -> tuple[list[np.ndarray], float, np.ndarray]:
    """The exhaustive search the fast one must reproduce: one lstsq per grid point, full fits.

    Every (v_S, δ[, k]) of the start grid solved on its own by
    :func:`numpy.linalg.lstsq`, the three best with distinct v_S, then
    ``least_squares`` on all parameters from each for up to 1000 evaluations.
    Returns the starts, the lowest cost and its parameters.
    """
    lo, hi = fit_module._log_us_bounds(p)
    ranked = []
    for lus in np.linspace(lo, hi, 25)[1:-1]:
        for delta in (0.4, 0.6, 0.8, 1.0, 1.4, 2.0, 2.8):
            for k in (0.4, 0.7, 1.3, 1.6, 1.9) if p.extended else (None,):
                e = np.exp(-((p.u / math.exp(lus)) ** delta))
                cols = [np.ones_like(p.u), e, p.u] + ([] if k is None else [p.u**k])
                basis = np.column_stack(cols) / p.s[:, None]
                coef, *_ = np.linalg.lstsq(basis, p.y / p.s, rcond=None)
                if coef[1] < 0:
                    reduced, *_ = np.linalg.lstsq(
                        np.delete(basis, 1, axis=1), p.y / p.s, rcond=None
                    )
                    coef = np.insert(reduced, 1, 0.0)
                rss = float(np.sum((basis @ coef - p.y / p.s) ** 2))
                ranked.append((rss, float(lus), delta, k, coef))
    ranked.sort(key=lambda item: item[0])
    starts: list[np.ndarray] = []
    for _, lus, delta, k, coef in ranked:
        if any(abs(lus - s[2]) < 0.3 for s in starts):
            continue
        x0 = [float(coef[0]), max(float(coef[1]), 1e-3), lus, delta, float(coef[2])]
        starts.append(np.array(x0 + ([] if k is None else [float(coef[3]), k])))
        if len(starts) == 3:
            break
    lower, upper = fit_module._bounds(p)
    best_cost, best_x = math.inf, np.empty(0)
    for x0 in starts:
        res = optimize.least_squares(
            lambda x: (fit_module._model_internal(x, p)[0] - p.y) / p.s,
            np.clip(x0, np.add(lower, 1e-9), np.subtract(upper, 1e-9)),
            jac=lambda x: fit_module._model_internal(x, p)[1] / p.s[:, None],
            bounds=(lower, upper),
            method="trf",
            x_scale="jac",
            max_nfev=1000,
        )
        if res.status > 0 and res.cost < best_cost:
            best_cost, best_x = float(res.cost), res.x
    return starts, best_cost, best_x


def _problem(v: np.ndarray, y: np.ndarray, s: np.ndarray, extended: bool) -> fit_module._Problem:
    v_ref, t_ref = float(v.max()), float(np.median(np.abs(y)))
    return fit_module._Problem(
        u=v / v_ref, y=y / t_ref, s=s / t_ref, v_ref=v_ref, t_ref=t_ref, extended=extended
    )


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("model", ["stribeck", "extended"])
def test_fast_search_matches_the_exhaustive_one(seed: int, model: str) -> None:
    """Same starts, and an optimum at least as good as the exhaustive search's.

    Noisy curves of the industrial schedule; the extended model on Stribeck
    data has a valley (b against f_w as k → 1) along which full fits crawl.
    """
    rng = np.random.default_rng(seed)
    sigma = np.full(SPEEDS.size, 0.01)
    fw = (0.0, -0.3, 0.0, 0.2)[seed]
    value = stribeck(SPEEDS, fw=fw, k=0.7) + rng.normal(0.0, 0.01, SPEEDS.size)
    p = _problem(SPEEDS, value, sigma, model == "extended")
    ref_starts, ref_cost, ref_x = _reference_search(p)
    starts = fit_module._starts(p)
    assert len(starts) == len(ref_starts)
    for mine, theirs in zip(starts, ref_starts, strict=True):
        np.testing.assert_allclose(mine, theirs, rtol=1e-9, atol=1e-12)
    best = fit_module._solve(p, starts)[0]
    assert float(best.cost) <= ref_cost * (1 + 1e-6)
    fit = fit_nonlinear(SPEEDS, value, sigma, model=model)  # type: ignore[arg-type]
    assert fit is not None
    dof = SPEEDS.size - len(ref_x)
    assert fit.chi2_reduced <= 2 * ref_cost / dof * (1 + 1e-6)
    if fit.parameters is not None and float(best.cost) >= ref_cost * (1 - 1e-6):
        # The same optimum: the same parameters.
        reference = fit_module._physical(ref_x, p)
        for name, value_ in fit.parameters.items():
            assert value_ == pytest.approx(reference[name], rel=1e-5, abs=1e-12)
