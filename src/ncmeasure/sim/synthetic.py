"""Synthetic recordings with known friction, for tests and benchmarks of the analysis.

A :class:`SyntheticAxis` describes an axis and its friction; :func:`simulate`
drives it through a measurement program of its own (velocity by velocity, as
:mod:`ncmeasure.plan` plans by default, but simpler: at every velocity step the
axis sweeps the positions forward in positive direction and back in negative
direction) and
returns the signals a drive would report. :func:`synthetic_recording` writes
them as a real recording with :class:`~ncmeasure.recording.RecordingWriter`
and returns the matching :class:`~ncmeasure.plan.Schedule`.

The program is built here rather than planned from a machine file so that a
test states positions and velocities directly and every window is exactly
where the spec says (the planner may drop or shift steps); its geometry is
the planner's (:func:`ncmeasure.plan.run_lengths` with the measurement
defaults of the machine file for the safety factor and the margin, and
trapezoidal ramps), and windows are shifted inward where the run-up would
leave the travel (as the planner shifts them).

The physics, per sample:

* the controller commands a trapezoidal velocity profile (acceleration
  limit ``acceleration_m_s2``): warm-up strokes over the travel, then for
  each run a rapid (``rapid_mm_min``) to its start, a dwell, and the run;
* the axis follows through a second-order servo loop (``servo_frequency_hz``,
  ``servo_damping``), so it lags during ramps and overshoots after them: the
  acceleration transient the analysis must cut;
* the motor torque is friction + offset + inertia × acceleration + cogging
  ripple: friction ``sign(v)·(T_C + (T_S − T_C)·exp(−(|v|/v_S)^δ)) + b·v``
  with per-position parameters (each position's values hold over the
  stretches half-way to its neighbours), offset direction-independent
  (gravity on a vertical axis), cogging ``A·sin(2π x / period)``;
* the current is torque / k_T, plus Gaussian noise and rare outliers; the
  reported velocity carries Gaussian noise too;
* as real drives do, the velocity fluctuation can be real motion the speed
  controller counters (``velocity_coupling``: torque falls as the velocity
  rises above its command), and velocity and current can be reported in
  counts (``velocity_quantum_mm_min``, ``current_quantum``).

Everything is seeded: the same spec and seed give the same samples.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.config import AxisConfig, MachineConfig, MachineSection, Measurement
from ncmeasure.formats.axis import StatedMechanics
from ncmeasure.formats.schedule import AxisSummary, Schedule, Window
from ncmeasure.plan import RunLengths, run_lengths
from ncmeasure.recording import Recording, RecordingWriter
from ncmeasure.samples import SIGNAL_UNITS, Channel, SampleBlock
from ncmeasure.sim.rig import RIG_MECHANICS
from ncmeasure.sim.servo import follow, servo

__all__ = [
    "SyntheticAxis",
    "SyntheticData",
    "geometric_velocities",
    "machine_config",
    "simulate",
    "synthetic_recording",
]

FloatArray = NDArray[np.float64]
PerPosition = float | tuple[float, ...]

_ROWS_PER_BLOCK = 200_000


def geometric_velocities(low: float, high: float, count: int) -> tuple[float, ...]:
    """``count`` velocities from ``low`` to ``high`` mm/min, geometrically spaced."""
    if count == 1:
        return (float(high),)
    ratio = high / low
    return tuple(round(low * ratio ** (k / (count - 1)), 3) for k in range(count))


@dataclass(frozen=True)
class SyntheticAxis:
    """One simulated axis: its measurement program, its friction and its disturbances.

    Friction parameters are in ``unit`` (Nm with a torque constant, else A);
    a tuple gives one value per position, a number the same everywhere.

    Attributes:
        name: Axis name.
        mechanics: The axis' mechanical facts (default: the method's test rig,
            :data:`~ncmeasure.sim.rig.RIG_MECHANICS`): its travel (soft limits),
            fixed-bearing end, ``vertical`` (metadata only; the gravity is
            ``offset``), torque constant k_T (required when ``unit`` is Nm) and
            lead (metadata). The recording's files state no rated current: the
            current is in A or Nm, never in parts of it.
        positions_mm: Measuring positions (window centres), ascending.
        velocities_mm_min: Velocity steps (magnitudes), ascending.
        both_directions: Measure in negative direction too.
        repetitions: How often the whole program of the axis is repeated.
        unit: Unit of the friction parameters.
        coulomb: Coulomb friction T_C.
        viscous_per_mm_min: Viscous coefficient b per mm/min.
        stribeck: Extra static friction at standstill, T_S − T_C.
        stribeck_velocity_mm_min: Stribeck velocity v_S.
        stribeck_exponent: Exponent δ of the Stribeck term.
        offset: Direction-independent torque/current (gravity, bias).
        noise: Standard deviation of the current noise (in ``unit``).
        velocity_noise_mm_min: Standard deviation of the reported velocity's noise.
        inertia_per_m_s2: Torque (in ``unit``) per m/s² of axis acceleration.
        cogging_amplitude: Amplitude of the position-periodic ripple.
        cogging_period_mm: Its period along the travel (default: 18 periods per
            revolution of the rig's 20 mm lead).
        velocity_coupling: Torque (in ``unit``) the speed controller takes off per
            mm/min the velocity fluctuates above its command (0: the velocity
            noise is measurement noise only).
        velocity_quantum_mm_min: One count of the reported velocity (0: continuous).
        current_quantum: One count of the reported current, in A (0: continuous).
        outlier_fraction: Share of samples with a current spike.
        outlier_amplitude: Size of a spike (random sign).
        acceleration_m_s2: Acceleration limit of the commanded profile.
        servo_frequency_hz: Natural frequency of the velocity-following loop.
        servo_damping: Its damping ratio (< 1: overshoot after ramps).
        rapid_mm_min: Rapid traverse velocity between runs.
        window_s: Duration of each window at constant velocity.
        settle_s: Constant velocity before the window (in the run-up).
        dwell_s: Standstill before each run.
        warmup_strokes: Strokes back and forth over the travel at the top
            velocity before measuring.
    """

    name: str = "X"
    mechanics: StatedMechanics = RIG_MECHANICS
    positions_mm: tuple[float, ...] = (50.0, 375.0, 700.0)
    velocities_mm_min: tuple[float, ...] = field(
        default_factory=lambda: geometric_velocities(10.0, 15000.0, 12)
    )
    both_directions: bool = True
    repetitions: int = 1
    unit: Literal["Nm", "A"] = "Nm"
    coulomb: PerPosition = 2.0
    viscous_per_mm_min: PerPosition = 2e-4
    stribeck: PerPosition = 0.8
    stribeck_velocity_mm_min: float = 60.0
    stribeck_exponent: float = 1.0
    offset: float = 0.0
    noise: float = 0.05
    velocity_noise_mm_min: float = 0.3
    inertia_per_m_s2: float = 1.5
    cogging_amplitude: float = 0.02
    cogging_period_mm: float = 20.0 / 18.0
    velocity_coupling: float = 0.0
    velocity_quantum_mm_min: float = 0.0
    current_quantum: float = 0.0
    outlier_fraction: float = 0.002
    outlier_amplitude: float = 3.0
    acceleration_m_s2: float = 2.0
    servo_frequency_hz: float = 15.0
    servo_damping: float = 0.5
    rapid_mm_min: float = 30000.0
    window_s: float = 0.4
    settle_s: float = 0.1
    dwell_s: float = 0.1
    warmup_strokes: int = 1

    def __post_init__(self) -> None:
        if self.unit == "Nm" and self.mechanics.torque_constant_nm_per_a is None:
            raise ValueError(f"axis {self.name}: friction in Nm needs torque_constant_nm_per_a")
        if list(self.positions_mm) != sorted(self.positions_mm) or not self.positions_mm:
            raise ValueError(f"axis {self.name}: positions_mm must be ascending and not empty")
        if (
            list(self.velocities_mm_min) != sorted(self.velocities_mm_min)
            or min(self.velocities_mm_min, default=0.0) <= 0
        ):
            raise ValueError(f"axis {self.name}: velocities_mm_min must be positive, ascending")
        for name in ("coulomb", "viscous_per_mm_min", "stribeck"):
            value = getattr(self, name)
            if isinstance(value, tuple) and len(value) != len(self.positions_mm):
                raise ValueError(
                    f"axis {self.name}: {name} has {len(value)} values for "
                    f"{len(self.positions_mm)} positions"
                )

    def parameter(self, name: str, position_index: int) -> float:
        """``coulomb``, ``viscous_per_mm_min`` or ``stribeck`` at a position."""
        value: PerPosition = getattr(self, name)
        return float(value[position_index]) if isinstance(value, tuple) else float(value)

    def _per_sample(self, name: str, position_mm: FloatArray) -> FloatArray:
        value: PerPosition = getattr(self, name)
        if not isinstance(value, tuple):
            return np.full(position_mm.shape, float(value))
        centres = np.asarray(self.positions_mm)
        edges = (centres[1:] + centres[:-1]) / 2
        return np.asarray(value, dtype=np.float64)[np.searchsorted(edges, position_mm)]

    def friction(self, velocity_mm_min: FloatArray, position_mm: FloatArray) -> FloatArray:
        """Friction (signed, in ``unit``) at the given velocities and positions."""
        v = np.asarray(velocity_mm_min, dtype=np.float64)
        x = np.asarray(position_mm, dtype=np.float64)
        coulomb = self._per_sample("coulomb", x)
        viscous = self._per_sample("viscous_per_mm_min", x)
        stribeck = self._per_sample("stribeck", x)
        speed = np.abs(v)
        static = coulomb + stribeck * np.exp(
            -((speed / self.stribeck_velocity_mm_min) ** self.stribeck_exponent)
        )
        # tanh instead of sign: no friction torque at exact standstill.
        result: FloatArray = np.tanh(v / 0.05) * static + viscous * v
        return result

    def expected(self, velocity_mm_min: float, position_index: int) -> float:
        """The measured value the analysis should find: friction at a position, plus offset."""
        x = np.array([self.positions_mm[position_index]])
        return float(self.friction(np.array([velocity_mm_min]), x)[0]) + self.offset

    def axis_config(self) -> AxisConfig:
        """The axis as a machine file would describe it."""
        low, high = self.mechanics.travel_mm
        return AxisConfig(
            **self._file_mechanics().model_dump(),
            name=self.name,
            park_mm=(low + high) / 2,
            max_velocity_mm_min=max(self.rapid_mm_min, max(self.velocities_mm_min)),
            rapid_velocity_mm_min=self.rapid_mm_min,
            max_acceleration_m_s2=self.acceleration_m_s2,
            max_jerk_m_s3=100.0,
        )

    def _file_mechanics(self) -> StatedMechanics:
        """The mechanics as the recording's files state them: without a rated current."""
        return self.mechanics.model_copy(update={"rated_current_a": None})


def machine_config(axes: Sequence[SyntheticAxis], name: str = "synthetic") -> MachineConfig:
    """A machine file for the synthetic axes (what ``--machine`` would supply)."""
    return MachineConfig(
        machine=MachineSection(name=name, controller="linuxcnc"),
        axes=[a.axis_config() for a in axes],
    )


@dataclass(frozen=True)
class SyntheticData:
    """The simulated samples of all axes, in recording layout."""

    time_s: FloatArray
    channels: tuple[Channel, ...]
    values: FloatArray
    schedule: Schedule


# --- motion ----------------------------------------------------------------------------


@dataclass
class _Program:
    """Collects the commanded motion of one axis, sample by sample, move by move."""

    dt: float
    accel_mm_s2: float
    t_s: float
    x_mm: float
    position: list[FloatArray] = field(default_factory=list)
    velocity: list[FloatArray] = field(default_factory=list)
    marker: list[FloatArray] = field(default_factory=list)
    next_index: int = 0

    def _grid(self, duration_s: float) -> FloatArray:
        """Local times of the samples falling into the next ``duration_s``."""
        end = math.ceil((self.t_s + duration_s) / self.dt - 1e-9)
        local = np.arange(self.next_index, end, dtype=np.float64) * self.dt - self.t_s
        self.next_index = max(self.next_index, end)
        return local

    def dwell(self, duration_s: float) -> None:
        local = self._grid(duration_s)
        self.position.append(np.full(local.shape, self.x_mm))
        self.velocity.append(np.zeros(local.shape))
        self.marker.append(np.zeros(local.shape))
        self.t_s += duration_s

    def profile(self, distance_mm: float, speed_mm_min: float) -> tuple[float, float, float]:
        """Ramp time, constant time and peak speed (mm/s) of a rest-to-rest move."""
        v = speed_mm_min / 60.0
        a = self.accel_mm_s2
        if v * v / a > distance_mm:  # never reaches the speed: triangle
            v = math.sqrt(distance_mm * a)
            return v / a, 0.0, v
        return v / a, (distance_mm - v * v / a) / v, v

    def move(
        self,
        target_mm: float,
        speed_mm_min: float,
        marker: float = 0.0,
        marked: tuple[float, float] | None = None,
    ) -> float:
        """Move to ``target_mm``; returns the time the move started.

        ``marked``: the commanded-position range in which the marker is set
        (the whole move when None and ``marker`` > 0).
        """
        start = self.t_s
        distance = abs(target_mm - self.x_mm)
        if distance == 0.0:
            return start
        sign = 1.0 if target_mm > self.x_mm else -1.0
        t_ramp, t_const, v = self.profile(distance, speed_mm_min)
        total = 2 * t_ramp + t_const
        tau = self._grid(total)
        a = self.accel_mm_s2
        s = np.where(
            tau < t_ramp,
            0.5 * a * tau**2,
            np.where(
                tau < t_ramp + t_const,
                0.5 * a * t_ramp**2 + v * (tau - t_ramp),
                distance - 0.5 * a * np.maximum(total - tau, 0.0) ** 2,
            ),
        )
        speed = np.where(
            tau < t_ramp,
            a * tau,
            np.where(tau < t_ramp + t_const, v, a * np.maximum(total - tau, 0.0)),
        )
        x = self.x_mm + sign * s
        values = np.zeros(tau.shape)
        if marker > 0:
            if marked is None:
                values[:] = marker
            else:
                lo, hi = min(marked), max(marked)
                values[(x >= lo) & (x <= hi)] = marker
        self.position.append(x)
        self.velocity.append(sign * speed * 60.0)
        self.marker.append(values)
        self.x_mm = target_mm
        self.t_s += total
        return start

    def time_at(self, start_s: float, start_mm: float, at_mm: float, speed_mm_min: float) -> float:
        """When a move that began at ``start_s`` passes ``at_mm`` in its constant phase."""
        t_ramp, _, v = self.profile(1e12, speed_mm_min)  # the ramp of an unlimited move
        covered = abs(at_mm - start_mm)
        return start_s + t_ramp + (covered - 0.5 * v * t_ramp) / v


def _measurement(spec: SyntheticAxis) -> Measurement:
    """The machine file's measurement defaults with the spec's window and settle time."""
    return Measurement(window_s=spec.window_s, settle_s=spec.settle_s)


def _lengths(spec: SyntheticAxis, speed_mm_min: float) -> RunLengths:
    """The planner's run at ``speed_mm_min``, with the spec's trapezoidal (jerk-free) ramps."""
    return run_lengths(speed_mm_min, spec.acceleration_m_s2, math.inf, _measurement(spec))


def _plan_axis(
    spec: SyntheticAxis,
    program: _Program,
    *,
    marker_scope: Literal["window", "run"],
    marker_values: Literal["window_id", "flag"],
) -> list[Window]:
    """Drive one axis through its measurement program; return its scheduled windows."""
    meas = _measurement(spec)
    low = spec.mechanics.travel_mm[0] + meas.margin_mm
    high = spec.mechanics.travel_mm[1] - meas.margin_mm
    top = max(spec.velocities_mm_min)
    for _ in range(spec.warmup_strokes):
        program.move(low, spec.rapid_mm_min)
        program.move(high, top)
        program.move(low, top)
    windows: list[Window] = []
    directions: tuple[Literal[1, -1], ...] = (1, -1) if spec.both_directions else (1,)
    for repetition in range(spec.repetitions):
        for step, speed in enumerate(spec.velocities_mm_min):
            lengths = _lengths(spec, speed)
            runout, runup, half = lengths.runout_mm, lengths.runup_mm, lengths.window_mm / 2
            c_min, c_max = low + half + runup, high - half - runup
            if c_min > c_max:
                raise ValueError(
                    f"axis {spec.name}: the step at {speed:g} mm/min does not fit in the travel"
                )
            for direction in directions:
                order = range(len(spec.positions_mm))
                for index in order if direction > 0 else reversed(order):
                    centre = min(max(spec.positions_mm[index], c_min), c_max)
                    w_start, w_end = centre - direction * half, centre + direction * half
                    start = w_start - direction * runup
                    stop = w_end + direction * runout
                    program.move(start, spec.rapid_mm_min)
                    program.dwell(spec.dwell_s)
                    number = len(windows) + 1
                    value = float(number) if marker_values == "window_id" else 1.0
                    marked = (w_start, w_end) if marker_scope == "window" else None
                    t0 = program.move(stop, speed, marker=value, marked=marked)
                    windows.append(
                        Window(
                            id=number,
                            axis=spec.name,
                            repetition=repetition,
                            step=step,
                            velocity_mm_min=direction * speed,
                            direction=direction,
                            position_index=index,
                            nominal_position_mm=spec.positions_mm[index],
                            position_mm=centre,
                            start_mm=start,
                            window_start_mm=w_start,
                            window_end_mm=w_end,
                            stop_mm=stop,
                            t_start_s=round(t0, 4),
                            t_window_start_s=round(program.time_at(t0, start, w_start, speed), 4),
                            t_window_end_s=round(program.time_at(t0, start, w_end, speed), 4),
                            t_stop_s=round(program.t_s, 4),
                        )
                    )
    return windows


def _signals(
    spec: SyntheticAxis,
    position_cmd: FloatArray,
    velocity_cmd: FloatArray,
    dt: float,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Actual position, reported velocity and current of one axis."""
    b, a = servo(dt, spec.servo_frequency_hz, spec.servo_damping)
    position = follow(b, a, position_cmd)
    velocity = follow(b, a, velocity_cmd)
    acceleration_m_s2 = (
        np.gradient(velocity, dt) / 60_000.0 if len(velocity) > 1 else np.zeros_like(velocity)
    )
    torque = (
        spec.friction(velocity, position)
        + spec.offset
        + spec.inertia_per_m_s2 * acceleration_m_s2
        + spec.cogging_amplitude * np.sin(2 * np.pi * position / spec.cogging_period_mm)
        + rng.normal(0.0, spec.noise, len(velocity))
    )
    spikes = rng.random(len(velocity)) < spec.outlier_fraction
    torque[spikes] += spec.outlier_amplitude * rng.choice([-1.0, 1.0], int(spikes.sum()))
    fluctuation = rng.normal(0.0, spec.velocity_noise_mm_min, len(velocity))
    torque -= spec.velocity_coupling * fluctuation
    scale = spec.mechanics.torque_constant_nm_per_a if spec.unit == "Nm" else None
    current = torque / scale if scale else torque
    reported = velocity + fluctuation
    if spec.velocity_quantum_mm_min > 0:
        reported = np.round(reported / spec.velocity_quantum_mm_min) * spec.velocity_quantum_mm_min
    if spec.current_quantum > 0:
        current = np.round(current / spec.current_quantum) * spec.current_quantum
    return position, reported, current


def simulate(
    axes: Sequence[SyntheticAxis],
    *,
    with_marker: bool = True,
    with_command: bool = True,
    sample_period_s: float = 0.004,
    seed: int = 0,
    marker_scope: Literal["window", "run"] = "window",
    marker_values: Literal["window_id", "flag"] = "window_id",
) -> SyntheticData:
    """Simulate the measurement of ``axes``, one after the other, in memory.

    While one axis is measured the others stand still at the middle of their
    travel (their current is offset plus noise).

    Args:
        axes: The axes, measured in this order.
        with_marker: Record ``<AXIS>_marker``.
        with_command: Record ``<AXIS>_velocity_cmd_mm_min``.
        sample_period_s: The sample period.
        seed: Seed of the noise, spikes and velocity noise.
        marker_scope: ``"window"``: the marker is set while the commanded
            position is inside the window; ``"run"``: during the whole run.
        marker_values: ``"window_id"``: the marker is the window id; ``"flag"``: 1.

    Returns:
        The samples in recording layout and the schedule of the program (its
        ``marker_scope`` is ``"none"`` without ``with_marker``: the program
        writes no marker then).
    """
    if not axes:
        raise ValueError("simulate needs at least one axis")
    names = [a.name for a in axes]
    if len(set(names)) != len(names):
        raise ValueError(f"axis names repeat: {', '.join(names)}")
    dt = float(sample_period_s)
    rng = np.random.default_rng(seed)
    programs, schedules, starts, first_rows = _programs(axes, dt, marker_scope, marker_values)
    t_s = programs[-1].t_s
    total = programs[-1].next_index
    time_s = np.arange(total, dtype=np.float64) * dt

    signals = ["current_a", "velocity_mm_min", "position_mm"]
    if with_command:
        signals.append("velocity_cmd_mm_min")
    if with_marker:
        signals.append("marker")
    channels = tuple(Channel(a.name, s, SIGNAL_UNITS[s]) for a in axes for s in signals)
    values = np.empty((total, len(channels)), dtype=np.float64)
    column = 0
    for spec, program, begin in zip(axes, programs, first_rows, strict=True):
        per_axis = _axis_signals(spec, program, begin, total, dt, rng)
        for signal in signals:
            values[:, column] = per_axis[signal]
            column += 1

    summaries = [
        _summary(spec, windows, program, start, dt)
        for spec, windows, program, start in zip(axes, schedules, programs, starts, strict=True)
    ]
    schedule = Schedule(
        config_hash="synthetic",
        machine="synthetic",
        controller="linuxcnc",
        program="FRICTION",
        duration_s=round(t_s, 3),
        full_travel_duration_s=round(t_s, 3),
        warnings=[],
        marker_scope=marker_scope if with_marker else "none",
        marker_values=marker_values,
        axes=summaries,
    )
    return SyntheticData(time_s=time_s, channels=channels, values=values, schedule=schedule)


def _programs(
    axes: Sequence[SyntheticAxis],
    dt: float,
    marker_scope: Literal["window", "run"],
    marker_values: Literal["window_id", "flag"],
) -> tuple[list[_Program], list[list[Window]], list[float], list[int]]:
    """The commanded motion of the axes, one after the other, each from and back to its middle.

    Returns:
        Per axis: its program, its windows, the time and the row it starts at.
    """
    programs: list[_Program] = []
    schedules: list[list[Window]] = []
    t_s = 0.0
    next_index = 0
    starts: list[float] = []
    first_rows: list[int] = []
    for spec in axes:
        low, high = spec.mechanics.travel_mm
        middle = (low + high) / 2
        program = _Program(dt, spec.acceleration_m_s2 * 1000.0, t_s, middle, next_index=next_index)
        starts.append(t_s)
        first_rows.append(next_index)
        program.dwell(0.5)
        windows = _plan_axis(spec, program, marker_scope=marker_scope, marker_values=marker_values)
        program.move(middle, spec.rapid_mm_min)
        program.dwell(0.5)
        programs.append(program)
        schedules.append(windows)
        t_s = program.t_s
        next_index = program.next_index
    return programs, schedules, starts, first_rows


def _axis_signals(
    spec: SyntheticAxis,
    program: _Program,
    begin: int,
    total: int,
    dt: float,
    rng: np.random.Generator,
) -> dict[str, FloatArray]:
    """Every signal of one axis over all ``total`` rows; it stands at its middle outside its run.

    Its program occupies the rows from ``begin``.
    """
    low, high = spec.mechanics.travel_mm
    middle = (low + high) / 2
    own = np.concatenate(program.position)
    end = begin + len(own)
    position_cmd = np.full(total, middle)
    velocity_cmd = np.zeros(total)
    marker = np.zeros(total)
    position_cmd[begin:end] = own
    velocity_cmd[begin:end] = np.concatenate(program.velocity)
    marker[begin:end] = np.concatenate(program.marker)
    position, velocity, current = _signals(spec, position_cmd, velocity_cmd, dt, rng)
    return {
        "current_a": current,
        "velocity_mm_min": velocity,
        "position_mm": position,
        "velocity_cmd_mm_min": velocity_cmd,
        "marker": marker,
    }


def _summary(
    spec: SyntheticAxis, windows: list[Window], program: _Program, start_s: float, dt: float
) -> AxisSummary:
    top = max(spec.velocities_mm_min)
    runup = _lengths(spec, top).runup_mm
    margin = _measurement(spec).margin_mm
    shifted = sorted(
        {w.nominal_position_mm for w in windows if w.position_mm != w.nominal_position_mm}
    )
    low, high = spec.mechanics.travel_mm
    return AxisSummary(
        **spec._file_mechanics().model_dump(),
        name=spec.name,
        usable_mm=(low + margin, high - margin),
        park_mm=(low + high) / 2,
        max_velocity_mm_min=max(spec.rapid_mm_min, top),
        nominal_positions_mm=list(spec.positions_mm),
        shifted_positions_mm=shifted,
        velocities_mm_min=list(spec.velocities_mm_min),
        dropped_velocities_mm_min=[],
        runup_at_max_velocity_mm=round(runup, 3),
        window_s=spec.window_s,
        settle_s=spec.settle_s,
        sample_period_ms=dt * 1000.0,
        warmup_strokes=spec.warmup_strokes,
        repetitions=spec.repetitions,
        both_directions=spec.both_directions,
        t_start_s=round(start_s, 4),
        duration_s=round(program.t_s - start_s, 3),
        full_travel_duration_s=round(program.t_s - start_s, 3),
        windows=windows,
    )


def synthetic_recording(
    directory: str | os.PathLike[str],
    axes: Sequence[SyntheticAxis],
    *,
    with_marker: bool = True,
    with_command: bool = True,
    sample_period_s: float = 0.004,
    seed: int = 0,
    schedule: bool = True,
    marker_scope: Literal["window", "run"] = "window",
    marker_values: Literal["window_id", "flag"] = "window_id",
    axis_metadata: bool = True,
) -> tuple[Recording, Schedule | None]:
    """Simulate ``axes`` (see :func:`simulate`) and write a real recording.

    Args:
        directory: The new recording (must not exist or be empty).
        axes: The axes, measured one after the other.
        with_marker: Record the marker channels.
        with_command: Record the commanded velocity channels.
        sample_period_s: The sample period.
        seed: Seed of all randomness.
        schedule: Return the program's schedule (else None).
        marker_scope: What the marker brackets: ``"window"`` or ``"run"``.
        marker_values: ``"window_id"`` or ``"flag"``.
        axis_metadata: Put the axes' data (torque constant, travel, bearing
            end, ...) into ``meta.json``, as a recording made with a machine
            file has it; False leaves it to the analysis' machine file.

    Returns:
        The recording, read back from disk, and the schedule (or None).
    """
    data = simulate(
        axes,
        with_marker=with_marker,
        with_command=with_command,
        sample_period_s=sample_period_s,
        seed=seed,
        marker_scope=marker_scope,
        marker_values=marker_values,
    )
    with RecordingWriter.create(
        Path(directory),
        data.channels,
        nominal_period_s=sample_period_s,
        machine=machine_config(axes) if axis_metadata else None,
        config_hash=data.schedule.config_hash,
        source="synthetic",
        notes=f"ncmeasure.sim.synthetic, seed {seed}",
        faster_than_real_time=True,
    ) as writer:
        for begin in range(0, len(data.time_s), _ROWS_PER_BLOCK):
            end = begin + _ROWS_PER_BLOCK
            writer.append(SampleBlock(data.time_s[begin:end], data.values[begin:end]))
    return Recording.open(directory), data.schedule if schedule else None
