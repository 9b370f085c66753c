"""The measurement planner: machine config -> schedule. Pure, no I/O.

For every axis the planner chooses the velocity steps and measuring
positions, and for every (repetition, step, position, direction) a *run*:
the axis starts at rest, accelerates over the run-up, holds the velocity
through a settle time and the measuring *window*, and stops over the run-out.
Run-up and run-out are the distances of a jerk-limited profile
(:mod:`ncmeasure.profile`) times a safety factor, so the controller reaches
the velocity before the window and can stop after it, inside the usable
travel (soft limits minus the margin).

All positions are planned in integer micrometres and all feeds are rounded
down to 0.001 mm/min, so what the templates print is exactly what was
checked: no rounding can push a block over a limit.

The runs come in *visits*: a position at a velocity step, with its run in
each direction one after the other. ``measurement.order`` chooses the order of
the visits: ``"velocity"`` (one step at every position, then the next step) or
``"position"`` (every step at one position, then the next position); either
way the positions are swept alternately upward and downward, so each sweep
starts where the last ended. Between two runs the axis takes a rapid, or, where
the next run starts further along and drives back, the run-out goes on to it
at the run's feed when that is quicker. :func:`duration_bound` computes the
least time the chosen order allows, to hold the plan against.
The result is a :class:`Schedule`: the moves each subprogram makes
(:class:`Rapid`, :class:`Feed`, :class:`Run`, :class:`Dwell`) and the windows the analysis
will cut out of the recording, with their expected times.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

from ncmeasure.config import (
    MAX_WINDOWS,
    AxisConfig,
    MachineConfig,
    Measurement,
    ceil_um,
    config_hash,
    floor_um,
    to_um,
    usable_um,
)
from ncmeasure.errors import PlanError
from ncmeasure.formats.schedule import AxisSummary, Schedule, Window
from ncmeasure.profile import move_time_s, ramp

__all__ = [
    "SMALLER",
    "AxisBound",
    "AxisPlan",
    "Comment",
    "DurationBound",
    "Dwell",
    "Feed",
    "Move",
    "Rapid",
    "Run",
    "RunLengths",
    "SizeLimit",
    "axis_duration_bound",
    "duration_bound",
    "move_blocks",
    "plan_axis",
    "plan_machine",
    "run_lengths",
    "velocity_steps",
]


def _mm(value_um: int) -> float:
    return value_um / 1000.0


def _floor_feed(value_mm_min: float) -> float:
    """Largest feed on the 0.001 mm/min grid not above ``value_mm_min`` as a control reads it.

    The result is compared as written with three decimals (``f"{feed:.3f}"`` read
    back), so no float noise can put a written feed above the value.
    """
    count = math.floor(value_mm_min * 1000.0 + 1e-6)  # exact values stay (1.9 is 1.9)
    while count > 0 and float(f"{count / 1000.0:.3f}") > value_mm_min:
        count -= 1
    return count / 1000.0


@dataclass(frozen=True)
class Rapid:
    """Rapid traverse (G0) of one axis to ``target_mm``."""

    axis: str
    target_mm: float
    kind: Literal["rapid"] = "rapid"


@dataclass(frozen=True)
class Feed:
    """Linear feed (G1) of one axis to ``target_mm`` at ``feed_mm_min`` (warm-up)."""

    axis: str
    target_mm: float
    feed_mm_min: float
    kind: Literal["feed"] = "feed"


@dataclass(frozen=True)
class Run:
    """One measuring run, from rest at the current position to rest at ``stop_mm``.

    Three collinear feed blocks at the same feed: run-up to ``window_start_mm``,
    the window to ``window_end_mm`` (marker = ``window_id``), run-out to
    ``stop_mm`` (marker back to 0). How the marker is written is the dialect's
    business.
    """

    axis: str
    start_mm: float
    window_start_mm: float
    window_end_mm: float
    stop_mm: float
    feed_mm_min: float
    window_id: int
    kind: Literal["run"] = "run"


@dataclass(frozen=True)
class Dwell:
    """Standstill for ``seconds``."""

    seconds: float
    kind: Literal["dwell"] = "dwell"


@dataclass(frozen=True)
class Comment:
    """A comment line in the program (dialects without comments drop it)."""

    text: str
    kind: Literal["comment"] = "comment"


Move = Rapid | Feed | Run | Dwell | Comment


@dataclass
class AxisPlan:
    """Everything planned for one axis: moves for the template, windows for the schedule."""

    axis: AxisConfig
    measurement: Measurement
    moves: list[Move]
    summary: AxisSummary
    warnings: list[str] = field(default_factory=list)


def velocity_steps(meas: Measurement, axis: AxisConfig) -> list[float]:
    """The measured velocities of ``axis`` in mm/min, ascending, rounded down to 0.001."""
    top = meas.max_velocity_mm_min
    if top is None:
        top = meas.max_velocity_fraction * axis.max_velocity_mm_min
    top = min(top, axis.max_velocity_mm_min)
    low, count = meas.min_velocity_mm_min, meas.velocity_steps
    if count == 1:
        values = [top]
    elif meas.spacing == "geometric":
        ratio = top / low
        values = [low * ratio ** (k / (count - 1)) for k in range(count)]
    else:
        values = [low + (top - low) * k / (count - 1) for k in range(count)]
    return sorted({_floor_feed(v) for v in values})


def nominal_positions_um(meas: Measurement, low_um: int, high_um: int) -> list[int]:
    """Measuring positions in µm: explicit ones, or a count spread over [low, high]."""
    if isinstance(meas.positions, list):
        return [to_um(p) for p in meas.positions]
    count = meas.positions
    if count == 1:
        return [(low_um + high_um) // 2]
    return [low_um + round((high_um - low_um) * i / (count - 1)) for i in range(count)]


@dataclass(frozen=True)
class RunLengths:
    """The lengths of one run at one velocity, in mm (exact; programs round them to µm).

    A run accelerates from rest (the jerk-limited ramp, times ``dynamics_safety``),
    keeps the velocity ``settle_s`` before the window and the window's duration,
    and stops with the same ramp. :func:`ncmeasure.sim.synthetic.simulate` uses
    the same lengths for its own programs.
    """

    runout_mm: float
    """Window end to rest: ramp distance × dynamics_safety."""
    settle_mm: float
    """Constant velocity before the window: v × settle_s."""
    window_mm: float
    """v × the window duration."""
    ramp_time_s: float

    @property
    def runup_mm(self) -> float:
        """Rest to window start: run-out plus the settle distance."""
        return self.runout_mm + self.settle_mm


def run_lengths(
    velocity_mm_min: float, acceleration_m_s2: float, jerk_m_s3: float, meas: Measurement
) -> RunLengths:
    """The lengths of a run at ``velocity_mm_min`` (jerk may be ``math.inf``: trapezoidal)."""
    r = ramp(velocity_mm_min, acceleration_m_s2, jerk_m_s3)
    v_mm_s = abs(velocity_mm_min) / 60.0
    return RunLengths(
        runout_mm=r.distance_mm * meas.dynamics_safety,
        settle_mm=v_mm_s * meas.settle_s,
        window_mm=v_mm_s * meas.window_duration_s,
        ramp_time_s=r.time_s,
    )


@dataclass(frozen=True)
class _RunGeometry:
    """Lengths of one run at one velocity, in µm (as the programs write them)."""

    runup_um: int  # rest to window start: ramp × safety + settle distance
    window_um: int
    runout_um: int  # window end to rest: ramp × safety
    ramp_time_s: float


def _geometry(v_mm_min: float, axis: AxisConfig, meas: Measurement) -> _RunGeometry:
    lengths = run_lengths(v_mm_min, axis.max_acceleration_m_s2, axis.max_jerk_m_s3, meas)
    runout = ceil_um(lengths.runout_mm)
    runup = runout + ceil_um(lengths.settle_mm)
    window = ceil_um(lengths.window_mm)
    window += window % 2  # even, so the window centres exactly on its position
    return _RunGeometry(runup, window, runout, lengths.ramp_time_s)


def _run_time_s(
    geo: _RunGeometry, v_mm_min: float, axis: AxisConfig, runout_um: int | None = None
) -> tuple[float, float, float]:
    """Times from the start of a run to window start, window end and stop.

    ``runout_um``: a run-out longer than the geometry's, where the stop of the run is
    the start of the next.
    """
    # The whole run is one rest-to-rest move at feed v: the ramp takes ramp_time_s,
    # the rest of the run-up and run-out is covered at constant velocity.
    v_mm_s = v_mm_min / 60.0
    ramp_mm = ramp(v_mm_min, axis.max_acceleration_m_s2, axis.max_jerk_m_s3).distance_mm
    t_window_start = geo.ramp_time_s + (_mm(geo.runup_um) - ramp_mm) / v_mm_s
    t_window_end = t_window_start + _mm(geo.window_um) / v_mm_s
    runout_mm = _mm(geo.runout_um if runout_um is None else runout_um)
    t_stop = t_window_end + (runout_mm - ramp_mm) / v_mm_s + geo.ramp_time_s
    return t_window_start, t_window_end, t_stop


class _Clock:
    """Accumulates the expected program time while moves are appended."""

    def __init__(
        self,
        axis: AxisConfig,
        start_s: float,
        position_mm: float,
        rapid_s: Callable[[int], float],
    ) -> None:
        self.axis = axis
        self.t_s = start_s
        self.position_mm = position_mm
        self.moves: list[Move] = []
        self._rapid_s = rapid_s

    def rapid(self, target_um: int) -> None:
        target = _mm(target_um)
        if target == self.position_mm:
            return
        # every position lies on the micrometre grid
        self.t_s += self._rapid_s(round(abs(target - self.position_mm) * 1000.0))
        self.position_mm = target
        self.moves.append(Rapid(self.axis.name, target))

    def feed(self, target_um: int, feed_mm_min: float) -> None:
        target = _mm(target_um)
        self.t_s += move_time_s(
            target - self.position_mm,
            feed_mm_min,
            self.axis.max_acceleration_m_s2,
            self.axis.max_jerk_m_s3,
        )
        self.position_mm = target
        self.moves.append(Feed(self.axis.name, target, feed_mm_min))

    def dwell(self, seconds: float) -> None:
        seconds = round(seconds, 3)  # what the program writes: whole milliseconds
        if seconds > 0:
            self.t_s += seconds
            self.moves.append(Dwell(seconds))


def _full_travel_time_s(
    axis: AxisConfig, meas: Measurement, velocities: Sequence[float], low_um: int, high_um: int
) -> float:
    """Duration of the same measurement driving the whole usable travel at every step."""
    length = _mm(high_um - low_um)
    a, j = axis.max_acceleration_m_s2, axis.max_jerk_m_s3
    total = 0.0
    for v in velocities:
        feed = move_time_s(length, v, a, j)
        back = feed if meas.both_directions else move_time_s(length, axis.rapid_mm_min, a, j)
        total += feed + back + 2 * meas.dwell_s
    return total * meas.repetitions


@dataclass
class _Steps:
    """The velocity steps of one axis that fit its usable travel, and their geometry."""

    low_um: int
    high_um: int
    velocities: list[float]
    dropped: list[float]
    geometry: dict[float, _RunGeometry]
    warnings: list[str]


def _fitting_steps(axis: AxisConfig, meas: Measurement) -> _Steps:
    low_um, high_um = usable_um(axis, meas)
    available_um = high_um - low_um
    warnings: list[str] = []
    steps = velocity_steps(meas, axis)
    if len(steps) < meas.velocity_steps:
        warnings.append(
            f"axis {axis.name}: {meas.velocity_steps} velocity steps between "
            f"{steps[0]:g} and {steps[-1]:g} mm/min are closer than the 0.001 mm/min a "
            f"program can write; {len(steps)} distinct steps remain"
        )
    velocities: list[float] = []
    dropped: list[float] = []
    geometry: dict[float, _RunGeometry] = {}
    for v in steps:
        geo = _geometry(v, axis, meas)
        needed = geo.window_um + (
            2 * geo.runup_um if meas.both_directions else geo.runup_um + geo.runout_um
        )
        if needed > available_um:
            if meas.both_directions:
                parts = (
                    f"window {_mm(geo.window_um):g} mm plus {_mm(geo.runup_um):g} mm of run-up "
                    "on both sides, as both directions are measured"
                )
            else:
                parts = (
                    f"run-up {_mm(geo.runup_um):g} mm, window {_mm(geo.window_um):g} mm, "
                    f"stop {_mm(geo.runout_um):g} mm"
                )
            message = (
                f"axis {axis.name}: the step at {v:g} mm/min needs {_mm(needed):g} mm "
                f"({parts}) but only {_mm(available_um):g} mm of travel are usable"
            )
            if meas.unfit_steps == "error":
                raise PlanError(
                    message,
                    [
                        "lower the highest velocity (measurement.max_velocity_mm_min), "
                        "shorten the window (measurement.window_s / window_samples), or set "
                        'measurement.unfit_steps = "drop"'
                    ],
                )
            warnings.append(message + "; step dropped")
            dropped.append(v)
            continue
        velocities.append(v)
        geometry[v] = geo
    if not velocities:
        raise PlanError(f"axis {axis.name}: no velocity step fits in the usable travel")

    return _Steps(low_um, high_um, velocities, dropped, geometry, warnings)


@dataclass(frozen=True)
class _Visit:
    """The runs at one measuring position and velocity step: one per measured direction."""

    repetition: int
    step: int
    velocity_mm_min: float
    index: int
    """Index of the nominal position (ascending)."""
    centre_um: int
    """Window centre: the nominal position, moved inward where the run-up does not fit."""
    geometry: _RunGeometry

    def reach_um(self, both_directions: bool) -> tuple[int, int]:
        """The stretch of travel its runs cover at their shortest: lowest start to highest stop."""
        geo, half = self.geometry, self.geometry.window_um // 2
        high = geo.runup_um if both_directions else geo.runout_um
        return self.centre_um - half - geo.runup_um, self.centre_um + half + high


def _visits(meas: Measurement, steps: _Steps, nominal: Sequence[int]) -> list[_Visit]:
    """The visits of one axis, in the order ``meas.order`` asks for.

    The positions are swept alternately upward and downward, each sweep starting
    where the last one ended: in velocity order one sweep per velocity step, in
    position order one sweep per repetition with every step, ascending, at each
    position.
    """

    def visit(repetition: int, step: int, index: int) -> _Visit:
        v = steps.velocities[step]
        geo = steps.geometry[v]
        half = geo.window_um // 2
        reach = geo.runup_um if meas.both_directions else max(geo.runup_um, geo.runout_um)
        c_min = steps.low_um + half + reach
        c_max = steps.high_um - half - (geo.runup_um if meas.both_directions else geo.runout_um)
        centre = min(max(nominal[index], c_min), c_max)
        return _Visit(repetition, step, v, index, centre, geo)

    upward = list(range(len(nominal)))
    count = len(steps.velocities)
    visits: list[_Visit] = []
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

    visit: _Visit
    direction: Literal[1, -1]
    start_um: int
    window_start_um: int
    window_end_um: int
    stop_um: int


def _run_spec(visit: _Visit, direction: Literal[1, -1]) -> _RunSpec:
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


class _Gaps:
    """The time from where a run stops to where the next one starts.

    Either a rapid, or, when the next run starts further along the way the run
    went and drives back (a reversal, so the axis stops in between anyway), a
    longer run-out at the run's feed, whichever is shorter: at high velocity the
    stop of one run becomes the run-up of the next without a block in between.
    """

    def __init__(self, axis: AxisConfig) -> None:
        self._rapid_s = functools.cache(
            lambda distance_um: move_time_s(
                _mm(distance_um),
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
        longer = _mm(beyond_um) / (run.visit.velocity_mm_min / 60.0)
        return (longer, True) if longer <= rapid else (rapid, False)


def _runs(
    visits: Sequence[_Visit], gaps: _Gaps, both_directions: bool, here_um: int
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


def _warmup_feed(meas: Measurement, axis: AxisConfig, velocities: Sequence[float]) -> float:
    return _floor_feed(min(meas.warmup_velocity_mm_min or velocities[-1], axis.max_velocity_mm_min))


def plan_axis(config: MachineConfig, axis: AxisConfig, start_s: float = 0.0) -> AxisPlan:
    """Plan the subprogram of one axis, starting at its park position at time ``start_s``.

    Raises:
        PlanError: a velocity step cannot fit in the usable travel and
            ``unfit_steps`` is ``"error"``.
    """
    meas = config.measurement_for(axis)
    steps = _fitting_steps(axis, meas)
    warnings = steps.warnings
    low_um, high_um = steps.low_um, steps.high_um
    available_um = high_um - low_um
    velocities, dropped, geometry = steps.velocities, steps.dropped, steps.geometry
    nominal = nominal_positions_um(meas, low_um, high_um)

    park_um = park_position_um(axis)
    gaps = _Gaps(axis)
    clock = _Clock(axis, start_s, _mm(park_um), gaps.rapid_s)
    clock.moves.append(Comment(f"measurement of axis {axis.name}"))
    warm_feed = _warmup_feed(meas, axis, velocities)
    here_um = park_um
    if meas.warmup_strokes:
        strokes = meas.warmup_strokes
        clock.moves.append(
            Comment(f"warm-up: {strokes} stroke{'s' if strokes != 1 else ''} back and forth")
        )
        clock.rapid(low_um)
        for _ in range(meas.warmup_strokes):
            clock.feed(high_um, warm_feed)
            clock.feed(low_um, warm_feed)
        here_um = low_um

    runs = _runs(_visits(meas, steps, nominal), gaps, meas.both_directions, here_um)
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
        t_ws, t_we, t_stop = _run_time_s(geo, v, axis, abs(stop - run.window_end_um))
        clock.moves.append(
            Run(
                axis.name,
                _mm(run.start_um),
                _mm(run.window_start_um),
                _mm(run.window_end_um),
                _mm(stop),
                v,
                number,
            )
        )
        clock.position_mm = _mm(stop)
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
                nominal_position_mm=_mm(nominal[visit.index]),
                position_mm=_mm(visit.centre_um),
                start_mm=_mm(run.start_um),
                window_start_mm=_mm(run.window_start_um),
                window_end_mm=_mm(run.window_end_um),
                stop_mm=_mm(stop),
                t_start_s=round(t0, 4),
                t_window_start_s=round(t0 + t_ws, 4),
                t_window_end_s=round(t0 + t_we, 4),
                t_stop_s=round(t0 + t_stop, 4),
            )
        )
    clock.moves.append(Comment(f"axis {axis.name} back to its park position"))
    clock.rapid(park_um)

    a, j = axis.max_acceleration_m_s2, axis.max_jerk_m_s3
    warmup_s = meas.warmup_strokes * 2 * move_time_s(_mm(available_um), warm_feed, a, j)
    rapids_s = 2 * move_time_s(
        max(abs(axis.park_mm - _mm(low_um)), abs(axis.park_mm - _mm(high_um))),
        axis.rapid_mm_min,
        a,
        j,
    )
    full_s = warmup_s + rapids_s + _full_travel_time_s(axis, meas, velocities, low_um, high_um)
    top = velocities[-1]
    summary = AxisSummary(
        name=axis.name,
        travel_mm=axis.travel_mm,
        usable_mm=(_mm(low_um), _mm(high_um)),
        park_mm=_mm(park_um),
        max_velocity_mm_min=axis.max_velocity_mm_min,
        vertical=axis.vertical,
        fixed_bearing_end=axis.fixed_bearing_end,
        torque_constant_nm_per_a=axis.torque_constant_nm_per_a,
        rated_current_a=axis.rated_current_a,
        screw_lead_mm=axis.screw_lead_mm,
        nominal_positions_mm=[_mm(p) for p in nominal],
        shifted_positions_mm=[_mm(nominal[i]) for i in sorted(shifted)],
        velocities_mm_min=velocities,
        dropped_velocities_mm_min=dropped,
        runup_at_max_velocity_mm=_mm(geometry[top].runup_um),
        window_s=meas.window_duration_s,
        settle_s=meas.settle_s,
        sample_period_ms=meas.sample_period_ms,
        warmup_strokes=meas.warmup_strokes,
        repetitions=meas.repetitions,
        both_directions=meas.both_directions,
        order=meas.order,
        t_start_s=round(start_s, 4),
        duration_s=round(clock.t_s - start_s, 3),
        full_travel_duration_s=round(full_s, 3),
        blocks=move_blocks(clock.moves),
        windows=windows,
    )
    return AxisPlan(
        axis=axis, measurement=meas, moves=clock.moves, summary=summary, warnings=warnings
    )


def _heading(meas: Measurement, visit: _Visit, nominal: Sequence[int]) -> str:
    """The comment before a velocity step's runs, or a position's."""
    if meas.order == "position":
        return (
            f"repetition {visit.repetition + 1}, position {visit.index + 1}: "
            f"{_mm(nominal[visit.index]):g} mm, every step"
        )
    step = visit.step + 1
    return f"repetition {visit.repetition + 1}, step {step}: {visit.velocity_mm_min:g} mm/min"


@dataclass(frozen=True)
class AxisBound:
    """The least time the measurement of one axis takes in its order, in parts (seconds)."""

    axis: str
    order: Literal["velocity", "position"]
    warmup_s: float
    """The warm-up strokes."""
    runs_s: float
    """Every run at its shortest: run-up, window, stop."""
    reversals_s: float
    """The turns between a visit's two runs (one run-up beyond the window end)."""
    dwell_s: float
    rapids_s: float
    """The minimal rapids between the visits, to the first and back to park."""

    @property
    def total_s(self) -> float:
        """The bound: warm-up, runs, reversals, dwells and the minimal rapids."""
        return self.warmup_s + self.runs_s + self.reversals_s + self.dwell_s + self.rapids_s


@dataclass(frozen=True)
class DurationBound:
    """The least time a machine's measurement program takes in its order (seconds)."""

    parking_s: float
    axes: tuple[AxisBound, ...]

    @property
    def total_s(self) -> float:
        """Parking and every axis' bound: comparable with :attr:`Schedule.duration_s`."""
        return self.parking_s + sum(axis.total_s for axis in self.axes)


def axis_duration_bound(config: MachineConfig, axis: AxisConfig) -> AxisBound:
    """The least time the measurement of ``axis`` can take in the order it is measured in.

    The plan's own motion model (jerk-limited rest-to-rest moves at the axis'
    limits), with nothing the order does not force:

    * the warm-up strokes as planned;
    * every run at its shortest: from rest over the run-up (ramp × dynamics_safety
      + settle distance), the window and the stop (ramp × dynamics_safety) to rest;
    * with both directions, the turn between a visit's two runs: the run that ends
      at the window must go on to where the other's run-up begins (the settle distance
      further than its stop), at its feed or in one rapid, whichever is shorter;
    * the dwells the machine file asks for, one before each run;
    * the *minimal rapids*. The order fixes which visit (a position at a velocity
      step, with its run in each direction) follows which: in velocity order each
      step sweeps the positions, alternately upward and downward; in position order
      each position is visited once per repetition, with every step ascending. Between
      two consecutive visits the axis must at least cross the gap between the stretches
      of travel their runs cover; that gap costs the shorter of one rest-to-rest rapid
      over it (rapid velocity, the axis' acceleration and jerk) and driving it at the
      faster of the two visits' feeds; overlapping stretches cost nothing. Likewise
      from the park position to the lower end of the usable travel where the warm-up
      starts, from there (or from the park position) to the first visit, and from the
      last visit back to park.

    Nothing else: no other gap between runs, no rapid longer than the gap. Any plan of
    the same visits therefore takes at least this long.
    """
    meas = config.measurement_for(axis)
    steps = _fitting_steps(axis, meas)
    nominal = nominal_positions_um(meas, steps.low_um, steps.high_um)
    a, j = axis.max_acceleration_m_s2, axis.max_jerk_m_s3
    park_um = park_position_um(axis)
    gaps = _Gaps(axis)
    here_um = park_um
    warmup_s = rapids_s = 0.0
    if meas.warmup_strokes:
        warm_feed = _warmup_feed(meas, axis, steps.velocities)
        stroke = _mm(steps.high_um - steps.low_um)
        warmup_s = meas.warmup_strokes * 2 * move_time_s(stroke, warm_feed, a, j)
        rapids_s = gaps.rapid_s(park_um - steps.low_um)
        here_um = steps.low_um
    directions = 2 if meas.both_directions else 1
    visits = _visits(meas, steps, nominal)
    runs_s = directions * sum(_run_time_s(v.geometry, v.velocity_mm_min, axis)[2] for v in visits)
    reversals_s = 0.0
    if meas.both_directions:
        for visit in visits:
            settle_um = visit.geometry.runup_um - visit.geometry.runout_um
            at_feed_s = _mm(settle_um) / (visit.velocity_mm_min / 60.0)
            reversals_s += min(at_feed_s, gaps.rapid_s(settle_um))
    low, high = here_um, here_um
    fastest = 0.0
    for visit in visits:
        v_low, v_high = visit.reach_um(meas.both_directions)
        gap_um = max(v_low - high, low - v_high, 0)
        if gap_um:
            feed = max(fastest, visit.velocity_mm_min) / 60.0
            rapid = gaps.rapid_s(gap_um)
            rapids_s += min(rapid, _mm(gap_um) / feed) if fastest else rapid
        low, high, fastest = v_low, v_high, visit.velocity_mm_min
    rapids_s += gaps.rapid_s(max(park_um - high, low - park_um, 0))
    return AxisBound(
        axis=axis.name,
        order=meas.order,
        warmup_s=warmup_s,
        runs_s=runs_s,
        reversals_s=reversals_s,
        dwell_s=directions * len(visits) * round(meas.dwell_s, 3),
        rapids_s=rapids_s,
    )


def duration_bound(config: MachineConfig) -> DurationBound:
    """The least time the whole program takes: parking as planned, then every axis'
    :func:`axis_duration_bound`.

    Raises:
        PlanError: as :func:`plan_machine` (a step that does not fit).
    """
    parking_s = sum(park_time_s(axis) for axis in config.park_sequence())
    return DurationBound(
        parking_s=parking_s,
        axes=tuple(axis_duration_bound(config, axis) for axis in config.measure_sequence()),
    )


def move_blocks(moves: Sequence[Move]) -> int:
    """Blocks the moves take in a program: one per rapid, feed and dwell, three per run."""
    return sum(3 if move.kind == "run" else 0 if move.kind == "comment" else 1 for move in moves)


def park_position_um(axis: AxisConfig) -> int:
    """The park position on the micrometre grid, never outside the travel."""
    low, high = ceil_um(axis.travel_mm[0]), floor_um(axis.travel_mm[1])
    return min(max(to_um(axis.park_mm), low), high)


def park_time_s(axis: AxisConfig) -> float:
    """Upper bound of the time to park an axis from anywhere in its travel."""
    distance = max(axis.park_mm - axis.travel_mm[0], axis.travel_mm[1] - axis.park_mm)
    return move_time_s(distance, axis.rapid_mm_min, axis.max_acceleration_m_s2, axis.max_jerk_m_s3)


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
        steps = _fitting_steps(axis, meas)
        positions = len(meas.positions) if isinstance(meas.positions, list) else meas.positions
        runs = meas.repetitions * positions * (2 if meas.both_directions else 1)
        windows += runs * len(steps.velocities)
        blocks += 3 * runs * len(steps.velocities) + 2 * meas.warmup_strokes
        duration_s += runs * sum(
            _run_time_s(steps.geometry[v], v, axis)[2] for v in steps.velocities
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
