"""How long the measurement program runs: against its lower bound, and against full travel.

For the example machine of ``ncmeasure init`` (3 axes, 3 positions, 50
velocity steps, both directions) this prints, for each order of the runs
(``measurement.order``):

* the planned program duration (the plan's own estimate: every move a
  jerk-limited rest-to-rest move at the axis limits, parking included);
* its lower bound, computed in the same run by
  :func:`ncmeasure.plan.duration_bound`: parking and warm-up as planned, every
  run at its shortest (run-up, window, stop), the turn between a position's two
  runs, the dwells, and the minimal rapids the order requires (between
  consecutive visits of a position at a step, only the gap between the stretches
  their runs cover, in one rapid or at the faster feed, whichever is shorter);
* the ratio planned / bound and the goal (at most 1.10);
* the time spent in rapids, planned and in the bound.

Then, as before, the planned duration against driving the whole usable travel
at every velocity step (the saving of measuring in short windows, method:
thesis figure 5.5), and how that saving grows with the number of steps.

All figures are computed from the plan (deterministic), none is a timing of
this computer. Run: python benchmarks/program_duration.py
"""

from __future__ import annotations

import tomllib
from typing import Any

from ncmeasure.config import parse_machine
from ncmeasure.examples import example_machine
from ncmeasure.plan import AxisPlan, Feed, Rapid, Run, duration_bound, plan_machine
from ncmeasure.profile import move_time_s

GOAL = 1.10
"""Planned duration at most this many times the bound of its order."""


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:8.1f} min"


def planned_rapids_s(plan: AxisPlan) -> float:
    """Time of the plan's rapids, with the plan's motion model."""
    axis = plan.axis
    position = plan.summary.park_mm
    total = 0.0
    for move in plan.moves:
        if isinstance(move, Rapid):
            total += move_time_s(
                move.target_mm - position,
                axis.rapid_mm_min,
                axis.max_acceleration_m_s2,
                axis.max_jerk_m_s3,
            )
            position = move.target_mm
        elif isinstance(move, Feed):
            position = move.target_mm
        elif isinstance(move, Run):
            position = move.stop_mm
    return total


def against_bound(data: dict[str, Any]) -> None:
    print(
        f"{'order':>9} {'axis':>5} {'planned':>12} {'bound':>12} {'ratio':>7} "
        f"{'rapids':>10} {'in bound':>10}"
    )
    for order in ("velocity", "position"):
        data["measurement"]["order"] = order
        config = parse_machine(data)
        schedule, plans = plan_machine(config)
        bound = duration_bound(config)
        for plan, axis in zip(plans, bound.axes, strict=True):
            print(
                f"{order:>9} {axis.axis:>5} {_minutes(plan.summary.duration_s)} "
                f"{_minutes(axis.total_s)} {plan.summary.duration_s / axis.total_s:7.3f} "
                f"{planned_rapids_s(plan):8.1f} s {axis.rapids_s:8.1f} s"
            )
        ratio = schedule.duration_s / bound.total_s
        rapids = sum(planned_rapids_s(plan) for plan in plans)
        bound_rapids = sum(axis.rapids_s for axis in bound.axes)
        print(
            f"{order:>9} {'all':>5} {_minutes(schedule.duration_s)} {_minutes(bound.total_s)} "
            f"{ratio:7.3f} {rapids:8.1f} s {bound_rapids:8.1f} s"
        )
        print(
            f"order={order} planned_s={schedule.duration_s:.1f} bound_s={bound.total_s:.1f} "
            f"ratio={ratio:.3f} goal<={GOAL:.2f} {'met' if ratio <= GOAL else 'NOT MET'} "
            f"rapids_s={rapids:.1f} bound_rapids_s={bound_rapids:.1f}"
        )
    data["measurement"].pop("order")


def against_full_travel(data: dict[str, Any]) -> None:
    schedule, _ = plan_machine(parse_machine(data))
    print(f"{'axis':>6} {'planned':>12} {'full travel':>12} {'ratio':>7}")
    for axis in schedule.axes:
        ratio = axis.duration_s / axis.full_travel_duration_s
        print(
            f"{axis.name:>6} {_minutes(axis.duration_s)} "
            f"{_minutes(axis.full_travel_duration_s)} {ratio:7.3f}"
        )
    ratio = schedule.duration_s / schedule.full_travel_duration_s
    print(
        f"{'total':>6} {_minutes(schedule.duration_s)} "
        f"{_minutes(schedule.full_travel_duration_s)} {ratio:7.3f}"
    )
    print(
        f"planned_duration_s={schedule.duration_s:.1f} "
        f"full_travel_duration_s={schedule.full_travel_duration_s:.1f} ratio={ratio:.4f}"
    )
    print("\nsaving against the number of velocity steps (same machine)")
    print(f"{'steps':>6} {'planned':>12} {'full travel':>12} {'ratio':>7}")
    for steps in (5, 10, 20, 50, 100):
        data["measurement"]["velocity_steps"] = steps
        s, _ = plan_machine(parse_machine(data))
        print(
            f"{steps:>6} {_minutes(s.duration_s)} {_minutes(s.full_travel_duration_s)} "
            f"{s.duration_s / s.full_travel_duration_s:7.3f}"
        )


def main() -> None:
    data = tomllib.loads(example_machine("sinumerik-840d"))
    print("example machine: 3 positions, 50 velocity steps, both directions")
    print(f"\nplanned duration against the least its order allows (goal: ratio <= {GOAL:.2f})")
    against_bound(data)
    print("\nplanned duration against driving the full travel at every step (velocity order)")
    against_full_travel(data)


if __name__ == "__main__":
    main()
