"""The plan of a whole machine: every axis in turn, refused before planning when it is too large."""

from __future__ import annotations

from dataclasses import dataclass

from ncmeasure.config import (
    MAX_WINDOWS,
    MachineConfig,
    config_hash,
)
from ncmeasure.errors import PlanError
from ncmeasure.formats.schedule import Schedule
from ncmeasure.plan.axis import AxisPlan, park_time_s, plan_axis
from ncmeasure.plan.runs import (
    fitting_steps,
    run_time_s,
)

SMALLER = (
    "measure fewer positions (measurement.positions), fewer velocity steps "
    "(measurement.velocity_steps), fewer repetitions or warm-up strokes; or raise the "
    "limit in the machine file's [limits] table if the control and the shift allow more"
)
"""What to change when a plan or its programs are too large."""


@dataclass(frozen=True)
class SizeLimit:
    """How large a plan may become: its duration, and the blocks the program memory holds."""

    max_duration_s: float
    max_blocks: int | None = None
    memory: str = ""
    """What bounds the blocks, for the message (``512 kB of program memory ...``)."""
    max_windows: int = MAX_WINDOWS


def _duration_text(seconds: float) -> str:
    hours = seconds / 3600
    if hours >= 48:
        return f"{hours / 24:.1f} days"
    return f"{hours:.1f} h" if hours >= 1 else f"{seconds / 60:.0f} min"


def _refuse_oversized(
    windows: int, blocks: int, duration_s: float, limit: SizeLimit, at_least: bool
) -> None:
    least = "at least " if at_least else ""
    problems = []
    if windows > limit.max_windows:
        problems.append(
            f"limits.max_windows: {windows} windows, more than {limit.max_windows} "
            f"(at most {MAX_WINDOWS}: each is a run of the programs and an entry of "
            "schedule.json)"
        )
    if duration_s > limit.max_duration_s:
        problems.append(
            f"limits.max_duration_h: the measurement would take {least}"
            f"{_duration_text(duration_s)}, more than {limit.max_duration_s / 3600:g} h"
        )
    if limit.max_blocks is not None and blocks > limit.max_blocks:
        problems.append(
            f"limits.max_program_kb: {least}{blocks} blocks, more than the "
            f"{limit.max_blocks} that {limit.memory} can hold"
        )
    if problems:
        raise PlanError(
            f"the plan is too large ({windows} windows, {least}{blocks} blocks, {least}"
            f"{_duration_text(duration_s)}); nothing was written",
            [*problems, SMALLER],
        )


def _lower_bounds(config: MachineConfig) -> tuple[int, int, float]:
    """Windows (exact), blocks and seconds (at least) of the plan, found without planning
    a single window."""
    windows, blocks, duration_s = 0, 0, 0.0
    for axis in config.axes:
        meas = config.measurement_for(axis)
        steps = fitting_steps(axis, meas)
        positions = len(meas.positions) if isinstance(meas.positions, list) else meas.positions
        runs = meas.repetitions * positions * (2 if meas.both_directions else 1)
        windows += runs * len(steps.velocities)
        blocks += 3 * runs * len(steps.velocities) + 2 * meas.warmup_strokes
        duration_s += runs * sum(
            run_time_s(steps.geometry[v], v, axis)[2] for v in steps.velocities
        )
    return windows, blocks, duration_s


def plan_machine(
    config: MachineConfig, limit: SizeLimit | None = None
) -> tuple[Schedule, list[AxisPlan]]:
    """Plan the whole measurement program of a machine.

    Args:
        config: The machine.
        limit: How long the plan may run and how many blocks it may have; default:
            the machine file's ``limits.max_duration_h`` and no block limit.

    Returns:
        The schedule (what schedule.json holds) and the per-axis plans the
        program renderer turns into subprograms.

    Raises:
        PlanError: a step does not fit, with the axis, velocity and lengths; or the
            plan is beyond the limits, with its size and what to change (checked
            first from lower bounds, before any window is planned).
    """
    limit = limit or SizeLimit(
        config.limits.max_duration_h * 3600, max_windows=config.limits.max_windows
    )
    _refuse_oversized(*_lower_bounds(config), limit, at_least=True)
    t_s = sum(park_time_s(axis) for axis in config.park_sequence())
    plans: list[AxisPlan] = []
    for axis in config.measure_sequence():
        plan = plan_axis(config, axis, start_s=t_s)
        t_s += plan.summary.duration_s
        plans.append(plan)
    park_s = sum(park_time_s(axis) for axis in config.park_sequence())
    full_s = park_s + sum(p.summary.full_travel_duration_s for p in plans)
    schedule = Schedule(
        config_hash=config_hash(config),
        machine=config.machine.name,
        controller=config.machine.controller,
        program=config.machine.program,
        duration_s=round(t_s, 3),
        full_travel_duration_s=round(full_s, 3),
        # parking, one call per axis, the axes' blocks
        blocks=2 * len(plans) + sum(p.summary.blocks for p in plans),
        warnings=[w for p in plans for w in p.warnings],
        axes=[p.summary for p in plans],
    )
    windows = sum(len(axis.windows) for axis in schedule.axes)
    _refuse_oversized(windows, schedule.blocks, schedule.duration_s, limit, at_least=False)
    return schedule, plans
