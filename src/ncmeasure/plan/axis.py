"""The plan of one axis: its visits and runs in order, with rapids, dwells and window times."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

from ncmeasure.config import (
    AxisConfig,
    MachineConfig,
    Measurement,
    ceil_um,
    floor_um,
    to_um,
)
from ncmeasure.formats.schedule import AxisSummary, Window
from ncmeasure.plan.moves import (
    Clock,
    Comment,
    Move,
    Run,
    floor_feed,
    move_blocks,
    to_mm,
)
from ncmeasure.plan.runs import (
    RunGeometry,
    Steps,
    fitting_steps,
    full_travel_time_s,
    nominal_positions_um,
    run_time_s,
)
from ncmeasure.profile import move_time_s


@dataclass
class AxisPlan:
    """Everything planned for one axis: moves for the template, windows for the schedule."""

    axis: AxisConfig
    measurement: Measurement
    moves: list[Move]
    summary: AxisSummary
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Visit:
    """The runs at one measuring position and velocity step: one per measured direction."""

    repetition: int
    step: int
    velocity_mm_min: float
    index: int
    """Index of the nominal position (ascending)."""
    centre_um: int
    """Window centre: the nominal position, moved inward where the run-up does not fit."""
    geometry: RunGeometry

    def reach_um(self, both_directions: bool) -> tuple[int, int]:
        """The stretch of travel its runs cover at their shortest: lowest start to highest stop."""
        geo, half = self.geometry, self.geometry.window_um // 2
        high = geo.runup_um if both_directions else geo.runout_um
        return self.centre_um - half - geo.runup_um, self.centre_um + half + high


def plan_visits(meas: Measurement, steps: Steps, nominal: Sequence[int]) -> list[Visit]:
    """The visits of one axis, in the order ``meas.order`` asks for.

    The positions are swept alternately upward and downward, each sweep starting
    where the last one ended: in velocity order one sweep per velocity step, in
    position order one sweep per repetition with every step, ascending, at each
    position.
    """

    def visit(repetition: int, step: int, index: int) -> Visit:
        v = steps.velocities[step]
        geo = steps.geometry[v]
        half = geo.window_um // 2
        reach = geo.runup_um if meas.both_directions else max(geo.runup_um, geo.runout_um)
        c_min = steps.low_um + half + reach
        c_max = steps.high_um - half - (geo.runup_um if meas.both_directions else geo.runout_um)
        centre = min(max(nominal[index], c_min), c_max)
        return Visit(repetition, step, v, index, centre, geo)

    upward = list(range(len(nominal)))
    count = len(steps.velocities)
    visits: list[Visit] = []
    sweeps = 0
    for repetition in range(meas.repetitions):
        if meas.order == "position":
            for index in upward if repetition % 2 == 0 else upward[::-1]:
                visits += [visit(repetition, step, index) for step in range(count)]
            continue
        for step in range(count):
            sweep = upward if sweeps % 2 == 0 else upward[::-1]
            sweeps += 1
            visits += [visit(repetition, step, index) for index in sweep]
    return visits


@dataclass(frozen=True)
class _RunSpec:
    """One run of a visit, in µm, with its nearest stop (the run-out may reach further)."""

    visit: Visit
    direction: Literal[1, -1]
    start_um: int
    window_start_um: int
    window_end_um: int
    stop_um: int


def _run_spec(visit: Visit, direction: Literal[1, -1]) -> _RunSpec:
    geo, half = visit.geometry, visit.geometry.window_um // 2
    w_start = visit.centre_um - direction * half
    w_end = visit.centre_um + direction * half
    return _RunSpec(
        visit,
        direction,
        w_start - direction * geo.runup_um,
        w_start,
        w_end,
        w_end + direction * geo.runout_um,
    )


class Gaps:
    """The time from where a run stops to where the next one starts.

    Either a rapid, or, when the next run starts further along the way the run
    went and drives back (a reversal, so the axis stops in between anyway), a
    longer run-out at the run's feed, whichever is shorter: at high velocity the
    stop of one run becomes the run-up of the next without a block in between.
    """

    def __init__(self, axis: AxisConfig) -> None:
        self._rapid_s = functools.cache(
            lambda distance_um: move_time_s(
                to_mm(distance_um),
                axis.rapid_mm_min,
                axis.max_acceleration_m_s2,
                axis.max_jerk_m_s3,
            )
        )

    def rapid_s(self, distance_um: int) -> float:
        """A rest-to-rest rapid over ``distance_um``."""
        return float(self._rapid_s(abs(distance_um)))

    def cost(
        self, run: _RunSpec | None, here_um: int, start_um: int, direction: int
    ) -> tuple[float, bool]:
        """Seconds from ``here_um`` (``run``'s stop, if any) to ``start_um``, and whether
        ``run``'s run-out should reach on to it."""
        rapid = self.rapid_s(start_um - here_um)
        if run is None or direction != -run.direction:
            return rapid, False
        beyond_um = (start_um - run.stop_um) * run.direction
        if beyond_um <= 0:
            return rapid, False
        longer = to_mm(beyond_um) / (run.visit.velocity_mm_min / 60.0)
        return (longer, True) if longer <= rapid else (rapid, False)


def _runs(
    visits: Sequence[Visit], gaps: Gaps, both_directions: bool, here_um: int
) -> list[_RunSpec]:
    """The runs of the visits, each visit's in the orientation whose first start is
    reached soonest from where the last one stopped (positive run first on ties)."""
    orientations: tuple[tuple[Literal[1, -1], ...], ...] = (
        ((1, -1), (-1, 1)) if both_directions else ((1,),)
    )
    runs: list[_RunSpec] = []
    previous: _RunSpec | None = None
    for visit in visits:
        best: list[_RunSpec] = []
        best_s = math.inf
        for directions in orientations:
            chosen = [_run_spec(visit, d) for d in directions]
            first = chosen[0]
            reached_s = gaps.cost(previous, here_um, first.start_um, first.direction)[0]
            if reached_s < best_s:
                best, best_s = chosen, reached_s
        runs += best
        previous = best[-1]
        here_um = previous.stop_um
    return runs


def warmup_feed(meas: Measurement, axis: AxisConfig, velocities: Sequence[float]) -> float:
    return floor_feed(min(meas.warmup_velocity_mm_min or velocities[-1], axis.max_velocity_mm_min))


def plan_axis(config: MachineConfig, axis: AxisConfig, start_s: float = 0.0) -> AxisPlan:
    """Plan the subprogram of one axis, starting at its park position at time ``start_s``.

    Raises:
        PlanError: a velocity step cannot fit in the usable travel and
            ``unfit_steps`` is ``"error"``.
    """
    meas = config.measurement_for(axis)
    steps = fitting_steps(axis, meas)
    nominal = nominal_positions_um(meas, steps.low_um, steps.high_um)
    park_um = park_position_um(axis)
    gaps = Gaps(axis)
    clock = Clock(axis, start_s, to_mm(park_um), gaps.rapid_s)
    clock.moves.append(Comment(f"measurement of axis {axis.name}"))
    here_um = _warm_up(clock, meas, steps) if meas.warmup_strokes else park_um
    runs = _runs(plan_visits(meas, steps, nominal), gaps, meas.both_directions, here_um)
    windows, shifted = _drive(clock, runs, meas, nominal, gaps)
    clock.moves.append(Comment(f"axis {axis.name} back to its park position"))
    clock.rapid(park_um)
    summary = AxisSummary(
        name=axis.name,
        **axis.mechanics().model_dump(),
        usable_mm=(to_mm(steps.low_um), to_mm(steps.high_um)),
        park_mm=to_mm(park_um),
        retracts=axis.retracts,
        number=axis.control_number([a.name for a in config.axes].index(axis.name) + 1),
        max_velocity_mm_min=axis.max_velocity_mm_min,
        rapid_mm_min=axis.rapid_mm_min,
        nominal_positions_mm=[to_mm(p) for p in nominal],
        shifted_positions_mm=[to_mm(nominal[i]) for i in sorted(shifted)],
        velocities_mm_min=steps.velocities,
        dropped_velocities_mm_min=steps.dropped,
        runup_at_max_velocity_mm=to_mm(steps.geometry[steps.velocities[-1]].runup_um),
        window_s=meas.window_duration_s,
        settle_s=meas.settle_s,
        sample_period_ms=meas.sample_period_ms,
        warmup_strokes=meas.warmup_strokes,
        repetitions=meas.repetitions,
        both_directions=meas.both_directions,
        order=meas.order,
        t_start_s=round(start_s, 4),
        duration_s=round(clock.t_s - start_s, 3),
        full_travel_duration_s=round(_full_travel_s(axis, meas, steps), 3),
        blocks=move_blocks(clock.moves),
        windows=windows,
    )
    return AxisPlan(
        axis=axis, measurement=meas, moves=clock.moves, summary=summary, warnings=steps.warnings
    )


def _warm_up(clock: Clock, meas: Measurement, steps: Steps) -> int:
    """The warm-up strokes over the usable travel; returns where the axis then is (µm)."""
    strokes = meas.warmup_strokes
    feed = warmup_feed(meas, clock.axis, steps.velocities)
    clock.moves.append(
        Comment(f"warm-up: {strokes} stroke{'s' if strokes != 1 else ''} back and forth")
    )
    clock.rapid(steps.low_um)
    for _ in range(strokes):
        clock.feed(steps.high_um, feed)
        clock.feed(steps.low_um, feed)
    return steps.low_um


def _drive(
    clock: Clock, runs: Sequence[_RunSpec], meas: Measurement, nominal: Sequence[int], gaps: Gaps
) -> tuple[list[Window], set[int]]:
    """Every run in order, with its rapid and dwell; the windows, and the shifted positions."""
    axis = clock.axis
    windows: list[Window] = []
    shifted: set[int] = set()
    heading: tuple[int, int] | None = None
    for number, run in enumerate(runs, start=1):
        visit, direction = run.visit, run.direction
        geo, v = visit.geometry, visit.velocity_mm_min
        if visit.centre_um != nominal[visit.index]:
            shifted.add(visit.index)
        part = (visit.repetition, visit.index if meas.order == "position" else visit.step)
        if part != heading:
            heading = part
            clock.moves.append(Comment(_heading(meas, visit, nominal)))
        stop = run.stop_um
        if number < len(runs):
            following = runs[number]
            if gaps.cost(run, stop, following.start_um, following.direction)[1]:
                stop = following.start_um
        clock.rapid(run.start_um)
        clock.dwell(meas.dwell_s)
        t0 = clock.t_s
        t_ws, t_we, t_stop = run_time_s(geo, v, axis, abs(stop - run.window_end_um))
        clock.moves.append(
            Run(
                axis.name,
                to_mm(run.start_um),
                to_mm(run.window_start_um),
                to_mm(run.window_end_um),
                to_mm(stop),
                v,
                number,
            )
        )
        clock.position_mm = to_mm(stop)
        clock.t_s = t0 + t_stop
        windows.append(
            Window(
                id=number,
                axis=axis.name,
                repetition=visit.repetition,
                step=visit.step,
                velocity_mm_min=direction * v,
                direction=direction,
                position_index=visit.index,
                nominal_position_mm=to_mm(nominal[visit.index]),
                position_mm=to_mm(visit.centre_um),
                start_mm=to_mm(run.start_um),
                window_start_mm=to_mm(run.window_start_um),
                window_end_mm=to_mm(run.window_end_um),
                stop_mm=to_mm(stop),
                t_start_s=round(t0, 4),
                t_window_start_s=round(t0 + t_ws, 4),
                t_window_end_s=round(t0 + t_we, 4),
                t_stop_s=round(t0 + t_stop, 4),
            )
        )
    return windows, shifted


def _full_travel_s(axis: AxisConfig, meas: Measurement, steps: Steps) -> float:
    """The same measurement driving the full usable travel at every step, with warm-up."""
    a, j = axis.max_acceleration_m_s2, axis.max_jerk_m_s3
    low_um, high_um = steps.low_um, steps.high_um
    feed = warmup_feed(meas, axis, steps.velocities)
    warmup_s = meas.warmup_strokes * 2 * move_time_s(to_mm(high_um - low_um), feed, a, j)
    rapids_s = 2 * move_time_s(
        max(abs(axis.park_mm - to_mm(low_um)), abs(axis.park_mm - to_mm(high_um))),
        axis.rapid_mm_min,
        a,
        j,
    )
    return warmup_s + rapids_s + full_travel_time_s(axis, meas, steps.velocities, low_um, high_um)


def _heading(meas: Measurement, visit: Visit, nominal: Sequence[int]) -> str:
    """The comment before a velocity step's runs, or a position's."""
    if meas.order == "position":
        return (
            f"repetition {visit.repetition + 1}, position {visit.index + 1}: "
            f"{to_mm(nominal[visit.index]):g} mm, every step"
        )
    step = visit.step + 1
    return f"repetition {visit.repetition + 1}, step {step}: {visit.velocity_mm_min:g} mm/min"


def park_position_um(axis: AxisConfig) -> int:
    """The park position on the micrometre grid, never outside the travel."""
    low, high = ceil_um(axis.travel_mm[0]), floor_um(axis.travel_mm[1])
    return min(max(to_um(axis.park_mm), low), high)


def park_time_s(axis: AxisConfig) -> float:
    """Upper bound of the time to park an axis from anywhere in its travel."""
    distance = max(axis.park_mm - axis.travel_mm[0], axis.travel_mm[1] - axis.park_mm)
    return move_time_s(distance, axis.rapid_mm_min, axis.max_acceleration_m_s2, axis.max_jerk_m_s3)
