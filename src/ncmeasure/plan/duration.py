"""The least time a measurement can take in its order: what a plan is held against."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ncmeasure.config import (
    AxisConfig,
    MachineConfig,
)
from ncmeasure.plan.axis import Gaps, park_position_um, park_time_s, plan_visits, warmup_feed
from ncmeasure.plan.moves import (
    to_mm,
)
from ncmeasure.plan.runs import (
    fitting_steps,
    nominal_positions_um,
    run_time_s,
)
from ncmeasure.profile import move_time_s


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
    steps = fitting_steps(axis, meas)
    nominal = nominal_positions_um(meas, steps.low_um, steps.high_um)
    a, j = axis.max_acceleration_m_s2, axis.max_jerk_m_s3
    park_um = park_position_um(axis)
    gaps = Gaps(axis)
    here_um = park_um
    warmup_s = rapids_s = 0.0
    if meas.warmup_strokes:
        warm_feed = warmup_feed(meas, axis, steps.velocities)
        stroke = to_mm(steps.high_um - steps.low_um)
        warmup_s = meas.warmup_strokes * 2 * move_time_s(stroke, warm_feed, a, j)
        rapids_s = gaps.rapid_s(park_um - steps.low_um)
        here_um = steps.low_um
    directions = 2 if meas.both_directions else 1
    visits = plan_visits(meas, steps, nominal)
    runs_s = directions * sum(run_time_s(v.geometry, v.velocity_mm_min, axis)[2] for v in visits)
    reversals_s = 0.0
    if meas.both_directions:
        for visit in visits:
            settle_um = visit.geometry.runup_um - visit.geometry.runout_um
            at_feed_s = to_mm(settle_um) / (visit.velocity_mm_min / 60.0)
            reversals_s += min(at_feed_s, gaps.rapid_s(settle_um))
    low, high = here_um, here_um
    fastest = 0.0
    for visit in visits:
        v_low, v_high = visit.reach_um(meas.both_directions)
        gap_um = max(v_low - high, low - v_high, 0)
        if gap_um:
            feed = max(fastest, visit.velocity_mm_min) / 60.0
            rapid = gaps.rapid_s(gap_um)
            rapids_s += min(rapid, to_mm(gap_um) / feed) if fastest else rapid
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
