"""The jerk-limited profile: closed forms against a numerical integration."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ncmeasure.profile import move_time_s, ramp, s_curve


def _integrate_ramp(v_m_s: float, a: float, j: float) -> tuple[float, float]:
    """Integrate a jerk-limited ramp numerically: (time, distance in m)."""
    dt = 1e-6
    t = s = v = acc = 0.0
    # jerk up, hold, jerk down, as a controller plans it
    t_j = min(a / j, math.sqrt(v_m_s / j))
    a_peak = j * t_j
    t_a = max(0.0, v_m_s / a_peak - t_j)
    for phase, duration in ((j, t_j), (0.0, t_a), (-j, t_j)):
        steps = round(duration / dt)
        for _ in range(steps):
            acc += phase * dt
            v += acc * dt
            s += v * dt
            t += dt
    return t, s


@pytest.mark.parametrize(
    ("v_mm_min", "a", "j"),
    [(15000, 2.0, 40.0), (100, 2.0, 40.0), (3000, 1.0, 5.0), (30000, 5.0, 500.0)],
)
def test_ramp_matches_numerical_integration(v_mm_min: float, a: float, j: float) -> None:
    expected_t, expected_s = _integrate_ramp(v_mm_min / 60000, a, j)
    got = ramp(v_mm_min, a, j)
    assert got.time_s == pytest.approx(expected_t, rel=1e-3)
    assert got.distance_mm == pytest.approx(expected_s * 1000, rel=2e-3)


def test_ramp_reference_numbers() -> None:
    # 15 m/min, 2 m/s², 40 m/s³: a²/j = 0.1 m/s < 0.25 m/s, so t = v/a + a/j = 0.175 s
    got = ramp(15000, 2.0, 40.0)
    assert got.time_s == pytest.approx(0.175)
    assert got.distance_mm == pytest.approx(0.25 * 0.175 / 2 * 1000)


def test_move_time_long_and_short_moves() -> None:
    r = ramp(6000, 2.0, 40.0)
    # long move: two ramps plus cruising at 100 mm/s
    assert move_time_s(500, 6000, 2.0, 40.0) == pytest.approx(
        2 * r.time_s + (500 - 2 * r.distance_mm) / 100
    )
    # short move never reaches the velocity and takes less than the two full ramps
    short = move_time_s(1.0, 6000, 2.0, 40.0)
    assert 0 < short < 2 * r.time_s
    assert move_time_s(0.0, 6000, 2.0, 40.0) == 0.0
    times = [move_time_s(d, 6000, 2.0, 40.0) for d in np.linspace(0.01, 50, 40)]
    assert all(b >= a for a, b in itertools.pairwise(times))


@pytest.mark.parametrize(
    ("distance", "v_mm_min", "a", "j"),
    [
        (740.0, 15000, 2.0, 40.0),
        (0.2, 50, 2.0, 40.0),
        (100.0, 30000, 3.0, 60.0),
        (5.0, 15000, 2.0, 40.0),
    ],
)
def test_s_curve_is_a_consistent_jerk_limited_move(
    distance: float, v_mm_min: float, a: float, j: float
) -> None:
    curve = s_curve(distance, v_mm_min, a, j)
    assert curve.duration_s == pytest.approx(move_time_s(distance, v_mm_min, a, j), rel=1e-9)
    t = np.linspace(-0.1, curve.duration_s + 0.1, 400_001)
    s, v, acc = curve.at(t)
    dt = t[1] - t[0]
    assert s[0] == 0.0 and s[-1] == pytest.approx(distance, abs=1e-9)
    assert v[0] == v[-1] == 0.0 and acc[0] == acc[-1] == 0.0
    assert np.all(np.diff(s) >= -1e-12)  # never moves back
    assert v.max() <= v_mm_min * (1 + 1e-9)
    assert np.abs(acc).max() <= a * (1 + 1e-9)
    # velocity is the derivative of the distance, acceleration that of the velocity,
    # and the jerk stays within its limit
    assert np.max(np.abs(np.gradient(s, dt) * 60.0 - v)) < 1e-3 * max(v_mm_min, 1.0)
    assert np.max(np.abs(np.gradient(v / 60_000.0, dt) - acc)[1:-1]) < 1e-3 * a + 1e-4
    jerk = np.diff(acc) / dt
    assert np.abs(jerk).max() <= j * (1 + 1e-3)


def test_s_curve_of_no_distance_is_standstill() -> None:
    curve = s_curve(0.0, 1000.0, 2.0, 40.0)
    assert curve.duration_s == 0.0
    s, v, a = curve.at(np.array([0.0, 1.0]))
    assert s.tolist() == v.tolist() == a.tolist() == [0.0, 0.0]
