"""The planner: windows inside the limits, run-up before, stop after, short rapids."""

from __future__ import annotations

import itertools
from collections.abc import Callable

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import PlanError
from ncmeasure.plan import Feed, Rapid, Run, _floor_feed, plan_axis, plan_machine
from ncmeasure.profile import ramp
from tests.conftest import example_data

Make = Callable[..., MachineConfig]


def test_windows_fit_with_runup_and_stop(make_config: Make) -> None:
    config = make_config()
    _schedule, plans = plan_machine(config)
    for plan in plans:
        axis, meas = plan.axis, plan.measurement
        low, high = plan.summary.usable_mm
        assert low == axis.travel_mm[0] + meas.margin_mm
        for w in plan.summary.windows:
            v = abs(w.velocity_mm_min)
            r = ramp(v, axis.max_acceleration_m_s2, axis.max_jerk_m_s3).distance_mm
            d = w.direction
            assert low <= min(w.start_mm, w.stop_mm) and max(w.start_mm, w.stop_mm) <= high
            assert d * (w.window_end_mm - w.window_start_mm) >= v / 60 * meas.window_duration_s
            runup = d * (w.window_start_mm - w.start_mm)
            assert runup >= r * meas.dynamics_safety + v / 60 * meas.settle_s - 1e-3
            assert d * (w.stop_mm - w.window_end_mm) >= r * meas.dynamics_safety - 1e-3
            assert v <= axis.max_velocity_mm_min
            assert w.t_start_s < w.t_window_start_s < w.t_window_end_s < w.t_stop_s
            assert w.t_window_end_s - w.t_window_start_s == pytest.approx(
                abs(w.window_end_mm - w.window_start_mm) / (v / 60), abs=1e-3
            )


def test_velocity_steps_are_geometric_and_fine_at_low_speed(make_config: Make) -> None:
    schedule, _ = plan_machine(make_config())
    v = schedule.axes[0].velocities_mm_min
    assert len(v) == 50
    assert v[0] == 10 and v[-1] == pytest.approx(15000, abs=0.001)
    ratios = [b / a for a, b in itertools.pairwise(v)]
    assert max(ratios) == pytest.approx(min(ratios), rel=1e-3)
    linear = plan_machine(make_config(spacing="linear"))[0].axes[0].velocities_mm_min
    assert linear[1] - linear[0] == pytest.approx(linear[-1] - linear[-2], abs=0.002)


def test_positions_spread_and_shift_inward_only_where_needed(make_config: Make) -> None:
    schedule, _ = plan_machine(make_config())
    x = schedule.axes[0]
    assert x.nominal_positions_mm == [5.0, 375.0, 745.0]
    assert x.shifted_positions_mm == [5.0, 745.0]
    slow = [w for w in x.windows if w.step == 0]
    assert all(abs(w.position_mm - w.nominal_position_mm) < 0.2 for w in slow)
    fast = [w for w in x.windows if w.step == 49 and w.position_index == 0]
    assert all(w.position_mm > 50 for w in fast)
    middle = [w for w in x.windows if w.position_index == 1]
    assert all(w.position_mm == 375.0 for w in middle)


def test_sweep_order_keeps_rapids_short(make_config: Make) -> None:
    config = make_config()
    _, plans = plan_machine(config)
    x = plans[0]
    step0 = [w for w in x.summary.windows if w.step == 0]
    assert [(w.direction, w.position_index) for w in step0] == [
        (1, 0),
        (1, 1),
        (1, 2),
        (-1, 2),
        (-1, 1),
        (-1, 0),
    ]
    position = x.axis.park_mm
    rapid_mm = 0.0
    for move in x.moves:
        if isinstance(move, Rapid):
            rapid_mm += abs(move.target_mm - position)
            position = move.target_mm
        elif isinstance(move, Run):
            position = move.stop_mm
        elif hasattr(move, "target_mm"):
            position = move.target_mm  # type: ignore[union-attr]
    usable = x.summary.usable_mm[1] - x.summary.usable_mm[0]
    # per step: a forward and a backward sweep, about two travels of rapids at most
    assert rapid_mm < 2.2 * usable * len(x.summary.velocities_mm_min)


def test_duration_is_far_below_full_travel(make_config: Make) -> None:
    schedule, plans = plan_machine(make_config())
    assert 0 < schedule.duration_s < schedule.full_travel_duration_s
    assert schedule.duration_s == pytest.approx(
        sum(p.summary.duration_s for p in plans) + plans[0].summary.t_start_s, rel=1e-6
    )
    # time of the windows alone is a lower bound of the program duration
    window_time = sum(
        w.t_window_end_s - w.t_window_start_s for p in plans for w in p.summary.windows
    )
    assert schedule.duration_s > window_time


def test_repetitions_and_one_direction(make_config: Make) -> None:
    base = len(plan_machine(make_config())[0].axes[0].windows)
    assert len(plan_machine(make_config(repetitions=2))[0].axes[0].windows) == 2 * base
    one = plan_machine(make_config(both_directions=False))[0].axes[0].windows
    assert len(one) == base // 2 and all(w.direction == 1 for w in one)


def test_step_that_cannot_fit_names_axis_velocity_and_lengths() -> None:
    data = example_data()
    data["axes"][0].update(travel_mm=[0.0, 120.0], park_mm=60.0)
    config = parse_machine(data)
    with pytest.raises(PlanError) as caught:
        plan_axis(config, config.axis("X"))
    message = str(caught.value)
    # the first step that does not fit, with what it needs and what there is
    assert "axis X: the step at 9585.98 mm/min needs 120.764 mm" in message
    assert "only 110 mm of travel" in message  # 120 mm minus 2 × 5 mm margin


def test_unfit_steps_can_be_dropped_with_a_warning() -> None:
    data = example_data()
    data["axes"][0].update(travel_mm=[0.0, 120.0], park_mm=60.0)
    data["measurement"]["unfit_steps"] = "drop"
    config = parse_machine(data)
    plan = plan_axis(config, config.axis("X"))
    assert plan.summary.dropped_velocities_mm_min
    assert max(plan.summary.velocities_mm_min) < min(plan.summary.dropped_velocities_mm_min)
    assert any("dropped" in w for w in plan.warnings)
    for w in plan.summary.windows:
        assert min(w.start_mm, w.stop_mm) >= 5.0 and max(w.start_mm, w.stop_mm) <= 115.0


def test_explicit_positions_are_used() -> None:
    data = example_data()
    data["axes"][0]["measurement"] = {"positions": [100.0, 650.0, 400.0]}
    schedule, _ = plan_machine(parse_machine(data))
    assert schedule.axes[0].nominal_positions_mm == [100.0, 400.0, 650.0]


@given(st.floats(min_value=0.01, max_value=1_000_000.0, allow_nan=False, allow_infinity=False))
def test_feeds_are_rounded_down_to_what_a_program_writes(value: float) -> None:
    """Never above the value (no float noise rounds up), never a whole 0.001 below it."""
    written = float(f"{_floor_feed(value):.3f}")  # what a control reads
    assert written <= value
    assert value - written < 0.001 + 1e-9 * value


@pytest.mark.parametrize("maximum", [1000.0009999999, 1000.001, 999.9999999999, 0.0109999999])
def test_no_feed_of_the_plan_exceeds_the_axis_maximum_as_written(maximum: float) -> None:
    data = example_data()
    data["axes"] = [data["axes"][0]]
    data["axes"][0]["max_velocity_mm_min"] = maximum
    data["measurement"].pop("max_velocity_mm_min", None)
    data["measurement"].update(
        velocity_steps=2,
        max_velocity_fraction=1,
        min_velocity_mm_min=0.01,
        positions=1,
        warmup_strokes=0,
    )
    data["limits"] = {"max_duration_h": 720}  # parking at 0.01 mm/min takes weeks
    schedule, plans = plan_machine(parse_machine(data))
    feeds = [m.feed_mm_min for m in plans[0].moves if isinstance(m, Run | Feed)]
    assert feeds and all(float(f"{f:.3f}") <= maximum for f in feeds), feeds
    assert max(schedule.axes[0].velocities_mm_min) <= maximum
