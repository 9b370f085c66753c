"""The planner: windows inside the limits, run-up before, stop after, short rapids."""

from __future__ import annotations

import itertools
from collections.abc import Callable

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import ConfigError, PlanError
from ncmeasure.plan import (
    AxisPlan,
    Feed,
    Rapid,
    Run,
    duration_bound,
    plan_axis,
    plan_machine,
)
from ncmeasure.plan.moves import floor_feed
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


def _rapids_mm(plan: AxisPlan) -> list[float]:
    position = plan.axis.park_mm
    rapids_mm = []
    for move in plan.moves:
        if isinstance(move, Rapid):
            rapids_mm.append(abs(move.target_mm - position))
            position = move.target_mm
        elif isinstance(move, Run):
            position = move.stop_mm
        elif isinstance(move, Feed):
            position = move.target_mm
    return rapids_mm


def test_velocity_order_sweeps_the_positions_alternately_up_and_down(make_config: Make) -> None:
    config = make_config()
    _, plans = plan_machine(config)
    x = plans[0]
    assert x.summary.order == "velocity"
    windows = x.summary.windows
    # one step after the other, each at every position in both directions
    assert [w.step for w in windows] == sorted(w.step for w in windows)
    for step in range(len(x.summary.velocities_mm_min)):
        visits = [(w.position_index, w.direction) for w in windows if w.step == step]
        # both runs at a position follow each other (the turn between them is no rapid)
        assert [p for p, _ in visits[::2]] == [p for p, _ in visits[1::2]]
        assert all(d != e for (_, d), (_, e) in zip(visits[::2], visits[1::2], strict=True))
        upward = step % 2 == 0  # each sweep starts where the last one ended
        assert [p for p, _ in visits[::2]] == ([0, 1, 2] if upward else [2, 1, 0])
    usable = x.summary.usable_mm[1] - x.summary.usable_mm[0]
    # per step one sweep over the positions: about one travel of rapids, not two
    assert sum(_rapids_mm(x)) < 1.1 * usable * len(x.summary.velocities_mm_min)


def test_a_run_out_reaches_on_to_the_next_start_only_at_a_turn(make_config: Make) -> None:
    """Where a run stops short of the next run's start and that run drives back, the
    run-out may go on to it (the axis stops there anyway); never into a run the same way."""
    _, plans = plan_machine(make_config())
    for plan in plans:
        meas, axis = plan.measurement, plan.axis
        runs = [m for m in plan.moves if isinstance(m, Run)]
        longer = 0
        for run, following in itertools.pairwise(runs):
            d = 1 if run.window_end_mm > run.window_start_mm else -1
            r = ramp(run.feed_mm_min, axis.max_acceleration_m_s2, axis.max_jerk_m_s3)
            beyond = d * (run.stop_mm - run.window_end_mm) - r.distance_mm * meas.dynamics_safety
            if beyond > 0.002:  # longer than the rounded shortest run-out
                longer += 1
                assert run.stop_mm == following.start_mm
                assert (following.window_end_mm - following.window_start_mm) * d < 0
        assert longer > 0


@pytest.mark.parametrize("order", ["velocity", "position"])
def test_windows_fit_in_either_order(make_config: Make, order: str) -> None:
    _schedule, plans = plan_machine(make_config(order=order, repetitions=2))
    for plan in plans:
        axis, meas = plan.axis, plan.measurement
        low, high = plan.summary.usable_mm
        for move in plan.moves:
            if isinstance(move, Run):
                assert low <= min(move.start_mm, move.stop_mm) <= high
                assert low <= max(move.start_mm, move.stop_mm) <= high
                assert move.feed_mm_min <= axis.max_velocity_mm_min
            elif isinstance(move, Rapid | Feed):
                assert axis.travel_mm[0] <= move.target_mm <= axis.travel_mm[1]
        for w in plan.summary.windows:
            v = abs(w.velocity_mm_min)
            r = ramp(v, axis.max_acceleration_m_s2, axis.max_jerk_m_s3).distance_mm
            d = w.direction
            assert d * (w.window_start_mm - w.start_mm) >= r * meas.dynamics_safety - 1e-3
            assert d * (w.stop_mm - w.window_end_mm) >= r * meas.dynamics_safety - 1e-3
            assert w.t_start_s < w.t_window_start_s < w.t_window_end_s < w.t_stop_s
        times = [t for w in plan.summary.windows for t in (w.t_start_s, w.t_stop_s)]
        assert times == sorted(times)


def test_position_order_measures_everything_at_one_position_before_the_next(
    make_config: Make,
) -> None:
    schedule, plans = plan_machine(make_config(order="position", repetitions=2))
    velocity = plan_machine(make_config(repetitions=2))[0]
    for plan, other in zip(plans, velocity.axes, strict=True):
        summary = plan.summary
        assert summary.order == "position"
        steps = range(len(summary.velocities_mm_min))
        for repetition, upward in ((0, True), (1, False)):
            windows = [w for w in summary.windows if w.repetition == repetition]
            visited = [p for p, _ in itertools.groupby(w.position_index for w in windows)]
            # each position once, swept up in the first repetition and down in the next
            assert visited == ([0, 1, 2] if upward else [2, 1, 0])
            for index in visited:
                here = [w for w in windows if w.position_index == index]
                # every step in both directions, ascending
                assert sorted((w.step, w.direction) for w in here) == [
                    (s, d) for s in steps for d in (-1, 1)
                ]
                assert [w.step for w in here] == sorted(w.step for w in here)
        # the same windows as in velocity order, only in another order
        assert sorted(
            (w.repetition, w.step, w.position_index, w.velocity_mm_min, w.position_mm)
            for w in summary.windows
        ) == sorted(
            (w.repetition, w.step, w.position_index, w.velocity_mm_min, w.position_mm)
            for w in other.windows
        )
        # long rapids only from one position to the next, to the first and back to park
        longest_run = max(abs(w.stop_mm - w.start_mm) for w in summary.windows)
        long = [r for r in _rapids_mm(plan) if r > longest_run]
        assert len(long) <= 2 * (len(summary.nominal_positions_mm) - 1) + 2
    assert schedule.duration_s < velocity.duration_s


@pytest.mark.parametrize("order", ["velocity", "position"])
def test_the_example_plan_is_within_10_percent_of_its_bound(make_config: Make, order: str) -> None:
    """Computed, not measured: the planned duration against the least its order allows."""
    config = make_config(order=order)
    schedule, _ = plan_machine(config)
    bound = duration_bound(config)
    assert [b.order for b in bound.axes] == [order] * 3
    assert bound.total_s <= schedule.duration_s <= 1.10 * bound.total_s


@settings(max_examples=40, deadline=None)
@example(  # three axes whose durations, each rounded down, add up 1.4 ms short of the bound
    order="velocity",
    positions=2,
    steps=1,
    both=True,
    repetitions=2,
    warmup=0,
    dwell_s=0.0,
    settle_s=0.0,
    spacing="geometric",
)
@given(
    order=st.sampled_from(["velocity", "position"]),
    positions=st.integers(1, 5),
    steps=st.integers(1, 8),
    both=st.booleans(),
    repetitions=st.integers(1, 3),
    warmup=st.integers(0, 2),
    dwell_s=st.sampled_from([0.0, 0.25]),
    settle_s=st.sampled_from([0.0, 0.1, 0.5]),
    spacing=st.sampled_from(["geometric", "linear"]),
)
def test_no_plan_is_shorter_than_its_bound(
    order: str,
    positions: int,
    steps: int,
    both: bool,
    repetitions: int,
    warmup: int,
    dwell_s: float,
    settle_s: float,
    spacing: str,
) -> None:
    data = example_data()
    data["measurement"].update(
        order=order,
        positions=positions,
        velocity_steps=steps,
        both_directions=both,
        repetitions=repetitions,
        warmup_strokes=warmup,
        dwell_s=dwell_s,
        settle_s=settle_s,
        spacing=spacing,
    )
    config = parse_machine(data)
    schedule, plans = plan_machine(config)
    bound = duration_bound(config)
    for plan, axis_bound in zip(plans, bound.axes, strict=True):
        assert axis_bound.total_s <= plan.summary.duration_s + 1e-3
    # The schedule adds up the axes' durations as written, each rounded to the millisecond.
    rounding_s = 0.0005 * len(plans)
    assert bound.total_s <= schedule.duration_s + 1e-3 + rounding_s


def test_order_is_checked_with_its_location() -> None:
    data = example_data()
    data["measurement"]["order"] = "positions"
    with pytest.raises(ConfigError) as caught:
        parse_machine(data)
    assert "measurement.order" in str(caught.value)
    assert "'velocity'" in str(caught.value) and "'position'" in str(caught.value)
    data["measurement"]["order"] = "velocity"
    data["axes"][2]["measurement"] = {"order": "position"}
    config = parse_machine(data)
    schedule, _ = plan_machine(config)
    assert [a.order for a in schedule.axes] == ["velocity", "velocity", "position"]


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
    written = float(f"{floor_feed(value):.3f}")  # what a control reads
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
