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

from ncmeasure.plan.axis import AxisPlan, park_position_um, park_time_s, plan_axis
from ncmeasure.plan.duration import AxisBound, DurationBound, axis_duration_bound, duration_bound
from ncmeasure.plan.machine import SMALLER, SizeLimit, plan_machine
from ncmeasure.plan.moves import Comment, Dwell, Feed, Move, Rapid, Run, move_blocks
from ncmeasure.plan.runs import RunLengths, run_lengths, velocity_steps

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
    "park_position_um",
    "park_time_s",
    "plan_axis",
    "plan_machine",
    "run_lengths",
    "velocity_steps",
]
