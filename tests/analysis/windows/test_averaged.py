"""Windows on a drive's averaged velocity: correlated noise, 1-rpm counts, 6.4 to 256 ms.

The captures (:mod:`tests.analysis.windows.averaged`) have the properties of a
maxon EPOS2's "velocity actual value averaged": a steady-speed scatter of 1.5 %
of the speed with lag-1 autocorrelation 0.8, quantised to counts of 2 mm/min,
500 samples per capture, current moving with the ripple, no command and no
position (as the drive's exports hold them).
"""

from __future__ import annotations

import numpy as np
import pytest

from ncmeasure.analysis.friction.table import friction_table
from ncmeasure.analysis.windows.find import find_windows
from ncmeasure.analysis.windows.signals import correlated_noise
from tests.analysis.windows.averaged import CAPTURE_SAMPLES, LEAD_MM, SPEEDS_MM_MIN, captures

PERIODS_S = (0.0064, 0.032, 0.256)


@pytest.mark.parametrize("dt_s", PERIODS_S)
@pytest.mark.parametrize("seed", [1, 2])
def test_one_window_per_capture_at_every_sample_period(dt_s: float, seed: int) -> None:
    data = captures(dt_s, seed=seed)
    seg = find_windows("X", data.time_s, data.velocity_mm_min)
    assert seg.source == "plateau"
    assert len(seg.windows) == len(data.speeds_mm_min)
    assert [w.velocity_mm_min for w in seg.windows] == pytest.approx(
        list(data.speeds_mm_min), rel=0.02
    )
    # Each window is its whole capture, less the settling time, not a fragment of it.
    long = [w.samples >= 0.8 * CAPTURE_SAMPLES for w in seg.windows]
    assert sum(long) >= len(long) - 1


@pytest.mark.parametrize("dt_s", PERIODS_S)
def test_one_step_per_speed_whatever_count_the_median_lands_on(dt_s: float) -> None:
    data = captures(dt_s, seed=1)
    seg = find_windows("X", data.time_s, data.velocity_mm_min)
    assert len(seg.steps) == len(SPEEDS_MM_MIN)
    assert [s.centre for s in seg.steps] == pytest.approx(list(SPEEDS_MM_MIN), rel=0.01)
    assert all(s.windows == 2 for s in seg.steps)  # both directions, nothing dropped


@pytest.mark.parametrize("dt_s", PERIODS_S)
def test_cell_levels_within_2_percent_of_truth(dt_s: float) -> None:
    data = captures(dt_s, seed=1)
    seg = find_windows("X", data.time_s, data.velocity_mm_min)
    table = friction_table("X", data.current_a, seg.windows)
    assert len(table) == len(data.speeds_mm_min)
    for velocity, median in zip(table.velocity_mm_min, table.median, strict=True):
        assert median == pytest.approx(data.truth_a(float(velocity)), rel=0.02)


@pytest.mark.parametrize("dt_s", PERIODS_S)
def test_a_command_still_gives_one_window_per_capture(dt_s: float) -> None:
    data = captures(dt_s, seed=3)
    seg = find_windows("X", data.time_s, data.velocity_mm_min, command_mm_min=data.command_mm_min)
    assert seg.source == "command"
    assert len(seg.windows) == len(data.speeds_mm_min)
    assert len(seg.steps) == len(SPEEDS_MM_MIN)


@pytest.mark.parametrize("rho", [0.0, 0.72, 0.8, 0.87])
def test_correlated_noise_holds_for_averaged_velocity(rho: float) -> None:
    rng = np.random.default_rng(5)
    noise = np.empty(2000)
    noise[0] = rng.normal()
    innovations = rng.normal(size=len(noise)) * np.sqrt(1 - rho**2)
    for k in range(1, len(noise)):
        noise[k] = rho * noise[k - 1] + innovations[k]
    sigma_true = 20.0
    readings = LEAD_MM * np.round((1000.0 + sigma_true * noise) / LEAD_MM)
    sigma, found_rho = correlated_noise(readings)
    # The plain second-difference figure is 1.8 to 3.5 times low for ρ of 0.72 to 0.87;
    # σ from the corrected ratio holds within its estimate's spread (1 − ρ is small).
    plain = 1.4826 * np.median(np.abs(np.diff(readings, n=2))) / np.sqrt(6.0)
    if rho > 0.5:
        assert plain < 0.6 * sigma_true
    assert sigma == pytest.approx(sigma_true, rel=0.4)
    assert found_rho == pytest.approx(rho, abs=0.12)


def test_correlated_noise_leaves_a_step_between_levels_out() -> None:
    rng = np.random.default_rng(6)
    readings = np.concatenate((np.full(300, 100.0), np.full(300, 200.0)))
    readings += rng.normal(0, 0.5, len(readings))
    sigma, _ = correlated_noise(readings)
    assert sigma == pytest.approx(0.5, rel=0.2)


@pytest.mark.parametrize(
    ("dt_s", "scatter", "rho", "seed"),
    [
        (0.0064, 0.02, 0.87, 1),
        (0.0064, 0.015, 0.72, 3),
        (0.0064, 0.01, 0.72, 2),
        (0.01, 0.02, 0.72, 2),
    ],
)
def test_smoothing_spans_several_samples_of_an_averaged_velocity(
    dt_s: float, scatter: float, rho: float, seed: int
) -> None:
    # A median of 3 samples (0.02 s at 6.4 ms) follows every excursion of the averaged
    # velocity: captures broke apart or found no plateau at all (2 of 10 captures lost).
    data = captures(dt_s, seed=seed, scatter=scatter, rho=rho)
    seg = find_windows("X", data.time_s, data.velocity_mm_min)
    assert len(seg.windows) == len(data.speeds_mm_min)
    assert len(seg.steps) == len(SPEEDS_MM_MIN)
    assert all(w.samples >= 0.8 * CAPTURE_SAMPLES for w in seg.windows)


def test_a_fragment_of_a_run_is_no_step_of_its_own() -> None:
    # At 32 ms the readings hold 492 mm/min for 15 samples at the start of the 500 capture,
    # then wander to 499: without a rule a step of its own beside the 497-sample ones.
    data = captures(0.032, seed=3, scatter=0.015, rho=0.8)
    seg = find_windows("X", data.time_s, data.velocity_mm_min)
    assert [s.centre for s in seg.steps] == pytest.approx(list(SPEEDS_MM_MIN), rel=0.01)
    assert all(s.windows == 2 for s in seg.steps)
    # The run at 500 mm/min is one window of its samples, the fragment's among them
    # (a run at one speed is one window), or the fragment is dropped as a thin step.
    at_500 = [w for w in seg.windows if abs(abs(w.velocity_mm_min) - 500) < 25]
    absorbed = all(w.samples >= 0.8 * CAPTURE_SAMPLES for w in at_500)
    assert absorbed or any("1 windows at 492 mm/min dropped" in w for w in seg.warnings)


def test_an_overshoot_of_a_few_samples_is_no_step_above_the_top_speed() -> None:
    # An overshoot to 216 mm/min after the run-up to 200, where nothing ran above 200: a
    # window of 4 samples once the transient is cut, and without a rule a step of its own.
    data = captures(0.256, seed=1, speeds_mm_min=(50.0, 100.0, 200.0))
    velocity = data.velocity_mm_min.copy()
    first = int(np.argmax(velocity >= 200.0))
    velocity[first : first + 6] = 216.0
    seg = find_windows("X", data.time_s, velocity)
    assert [s.centre for s in seg.steps] == pytest.approx([50.0, 100.0, 200.0], rel=0.02)
    assert any(
        "at 216 mm/min dropped" in w and "fewer than an eighth of" in w for w in seg.warnings
    )
    assert max(abs(w.velocity_mm_min) for w in seg.windows) < 205.0


def test_a_fastest_speed_ten_times_the_next_is_a_step_of_its_own() -> None:
    # Runs over one travel: the time at a speed falls as 1/speed, so at 1000 mm/min, ten
    # times the next speed, the windows hold a tenth of the samples of those at 100.
    rng = np.random.default_rng(4)
    dt_s, travel_mm = 0.01, 50.0
    pieces: list[np.ndarray] = []
    for speed in (50.0, 100.0, 1000.0):
        for sign in (1.0, -1.0):
            n = int(travel_mm / speed * 60.0 / dt_s)
            ramp = sign * speed * np.arange(1, 11) / 10
            run = sign * speed * (1.0 + 0.005 * rng.normal(size=n))
            pieces += [np.zeros(20), ramp, run, ramp[::-1], np.zeros(20)]
    velocity = np.concatenate(pieces)
    seg = find_windows("X", dt_s * np.arange(len(velocity)), velocity)
    assert [s.centre for s in seg.steps] == pytest.approx([50.0, 100.0, 1000.0], rel=0.01)
    assert not any("dropped" in w for w in seg.warnings)


def test_correlated_noise_holds_under_white_readings() -> None:
    # A robot joint's encoder-derived velocity: white counts on top of the speed loop's
    # correlated wobble. The differences look white and hid the wobble (σ 1.6 times low).
    rng = np.random.default_rng(8)
    wobble = np.empty(5000)
    wobble[0] = 0.0
    for k in range(1, len(wobble)):
        wobble[k] = 0.95 * wobble[k - 1] + rng.normal() * np.sqrt(1 - 0.95**2)
    white = rng.normal(size=len(wobble))
    readings = 100.0 + 4.0 * wobble + 1.5 * white
    sigma, rho = correlated_noise(readings)
    assert sigma == pytest.approx(np.hypot(4.0, 1.5), rel=0.15)
    assert rho > 0.5
