"""How long the measurement program runs, against driving the full travel at every step.

For the example machine of ``ncmeasure init`` (3 axes, 3 positions, 50
velocity steps, both directions) this prints the planned program duration,
the duration of the same measurement driving the whole usable travel at
every velocity step (the baseline, computed in the same run with the same
jerk-limited motion model), and their ratio. The saving is the point of
measuring in short windows (method: thesis figure 5.5); it grows with the
number of steps, which the second table shows.

Run: python benchmarks/program_duration.py
"""

from __future__ import annotations

import tomllib

from ncmeasure.config import parse_machine
from ncmeasure.examples import example_machine
from ncmeasure.plan import plan_machine


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:8.1f} min"


def main() -> None:
    data = tomllib.loads(example_machine("sinumerik-840d"))
    schedule, _ = plan_machine(parse_machine(data))
    print("example machine: 3 positions, 50 velocity steps, both directions")
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


if __name__ == "__main__":
    main()
