"""The velocity steps and positions of an axis; the lengths and times of one run at one velocity."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ncmeasure.config import (
    AxisConfig,
    Measurement,
    ceil_um,
    to_um,
    usable_um,
)
from ncmeasure.errors import PlanError
from ncmeasure.plan.moves import (
    floor_feed,
    to_mm,
)
from ncmeasure.profile import move_time_s, ramp


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
    return sorted({floor_feed(v) for v in values})


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
class RunGeometry:
    """Lengths of one run at one velocity, in µm (as the programs write them)."""

    runup_um: int  # rest to window start: ramp × safety + settle distance
    window_um: int
    runout_um: int  # window end to rest: ramp × safety
    ramp_time_s: float


def run_geometry(v_mm_min: float, axis: AxisConfig, meas: Measurement) -> RunGeometry:
    lengths = run_lengths(v_mm_min, axis.max_acceleration_m_s2, axis.max_jerk_m_s3, meas)
    runout = ceil_um(lengths.runout_mm)
    runup = runout + ceil_um(lengths.settle_mm)
    window = ceil_um(lengths.window_mm)
    window += window % 2  # even, so the window centres exactly on its position
    return RunGeometry(runup, window, runout, lengths.ramp_time_s)


def run_time_s(
    geo: RunGeometry, v_mm_min: float, axis: AxisConfig, runout_um: int | None = None
) -> tuple[float, float, float]:
    """Times from the start of a run to window start, window end and stop.

    ``runout_um``: a run-out longer than the geometry's, where the stop of the run is
    the start of the next.
    """
    # The whole run is one rest-to-rest move at feed v: the ramp takes ramp_time_s,
    # the rest of the run-up and run-out is covered at constant velocity.
    v_mm_s = v_mm_min / 60.0
    ramp_mm = ramp(v_mm_min, axis.max_acceleration_m_s2, axis.max_jerk_m_s3).distance_mm
    t_window_start = geo.ramp_time_s + (to_mm(geo.runup_um) - ramp_mm) / v_mm_s
    t_window_end = t_window_start + to_mm(geo.window_um) / v_mm_s
    runout_mm = to_mm(geo.runout_um if runout_um is None else runout_um)
    t_stop = t_window_end + (runout_mm - ramp_mm) / v_mm_s + geo.ramp_time_s
    return t_window_start, t_window_end, t_stop


def full_travel_time_s(
    axis: AxisConfig, meas: Measurement, velocities: Sequence[float], low_um: int, high_um: int
) -> float:
    """Duration of the same measurement driving the whole usable travel at every step."""
    length = to_mm(high_um - low_um)
    a, j = axis.max_acceleration_m_s2, axis.max_jerk_m_s3
    total = 0.0
    for v in velocities:
        feed = move_time_s(length, v, a, j)
        back = feed if meas.both_directions else move_time_s(length, axis.rapid_mm_min, a, j)
        total += feed + back + 2 * meas.dwell_s
    return total * meas.repetitions


@dataclass
class Steps:
    """The velocity steps of one axis that fit its usable travel, and their geometry."""

    low_um: int
    high_um: int
    velocities: list[float]
    dropped: list[float]
    geometry: dict[float, RunGeometry]
    warnings: list[str]


def fitting_steps(axis: AxisConfig, meas: Measurement) -> Steps:
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
    geometry: dict[float, RunGeometry] = {}
    for v in steps:
        geo = run_geometry(v, axis, meas)
        needed = geo.window_um + (
            2 * geo.runup_um if meas.both_directions else geo.runup_um + geo.runout_um
        )
        if needed > available_um:
            if meas.both_directions:
                parts = (
                    f"window {to_mm(geo.window_um):g} mm plus {to_mm(geo.runup_um):g} mm of run-up "
                    "on both sides, as both directions are measured"
                )
            else:
                parts = (
                    f"run-up {to_mm(geo.runup_um):g} mm, window {to_mm(geo.window_um):g} mm, "
                    f"stop {to_mm(geo.runout_um):g} mm"
                )
            message = (
                f"axis {axis.name}: the step at {v:g} mm/min needs {to_mm(needed):g} mm "
                f"({parts}) but only {to_mm(available_um):g} mm of travel are usable"
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

    return Steps(low_um, high_um, velocities, dropped, geometry, warnings)
