"""The virtual machine: runs a generated NC program on simulated feed axes.

:class:`VirtualMachine` reads the main program and its subprograms with
ncmeasure's own program reader (:func:`~ncmeasure.program.reader.read_programs`,
the same reader ``ncmeasure check`` uses), in the dialect named in the
folder's ``schedule.json``, and drives every axis the way a controller in
continuous-path mode would:

* consecutive moves of the same kind (rapid or feed), the same feed and the
  same direction form one *path segment*: the axis does not stop between the
  run-up, the window and the run-out blocks;
* every path segment is a jerk-limited rest-to-rest move
  (:func:`~ncmeasure.profile.s_curve`) at the programmed feed (G1) or the
  rapid velocity (G0, the axis' maximum velocity), with the axis' maximum
  acceleration and jerk; a move of several axes is interpolated linearly,
  limited by the axis that reaches its limit first;
* a direction reversal, a change of feed or of kind, and a dwell stop the
  axes (exact stop); so does any other step the reader reports (a programmed
  stop, for instance: nobody needs to press start on a virtual machine).

A block that leaves an axis' travel stops the virtual machine with a
:class:`~ncmeasure.errors.ProgramError`, and a feed above an axis' maximum
velocity is driven at that maximum, as a controller would do
(``beyond_limits="stop"``). A dry run (``beyond_limits="follow"``) lets the
machine follow the program wherever it goes instead, and lists each such
block in :attr:`VirtualMachine.excursions`: what the machine reached
(:meth:`MachineRun.extremes`) then shows how far the program goes.

The commanded position and velocity run through a second-order servo loop
(natural frequency ``servo_frequency_hz``, damping ``servo_damping``), so
the actual velocity lags during ramps and overshoots after them. The motor
current comes from the axis' :class:`~ncmeasure.sim.axis.AxisModel`
(friction per component and assembly variation, inertia, gravity, cogging,
noise, outliers). A wrong program therefore shows up as wrong data.

With a :class:`~ncmeasure.sim.realism.Realism` (off by default) each axis
also gets what a real one has: a healthy fingerprint along the travel, drawn
from ``machine_seed`` and the same in every run of the machine, a run-to-run
drift of its friction and of the drive's torque gain, drawn from ``seed``,
and the drives' own noise (the current's ADC steps and noise, the speed
loop's answer to the encoder, the velocity as the encoder's position
difference). :attr:`VirtualMachine.realised` says what was drawn, and each
axis' model (:attr:`VirtualMachine.models`) is then the run's true friction.

Everything is computed once, on a uniform time grid (``dt_s``, default
1 ms), and seeded, so a run is reproducible. The result, a
:class:`MachineRun`, is a :class:`~ncmeasure.sim.signals.SignalSource` that
the simulated drives (CANopen :class:`~ncmeasure.sim.cia402.SimulatedDrives`,
Modbus :mod:`~ncmeasure.sim.modbus_drive`) serve to the real links. Its time
is *machine time*: 0 is the start of the recording, the program starts
after ``lead_in_s``, and the machine stands still at the end after
``duration_s``. The links record machine time too, so the virtual machine
may run faster than real time (the recording says so in its metadata).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, ProgramError
from ncmeasure.profile import SCurve, s_curve, times_at
from ncmeasure.program.check import read_generated
from ncmeasure.program.reader import Dwell, Motion, ProgramTrace, ReadyWait, Stop
from ncmeasure.samples import Channel, SampleBlock, channels_for
from ncmeasure.sim.axis import AxisModel, Variation
from ncmeasure.sim.realism import AxisRealism, Realism, with_tolerance
from ncmeasure.sim.servo import follow, servo
from ncmeasure.sim.signals import AxisState

__all__ = [
    "AxisExtremes",
    "BeyondLimits",
    "MachineRun",
    "MarkedSpan",
    "VirtualMachine",
    "one_after_another",
]

FloatArray = NDArray[np.float64]

_DIRECTION_TOLERANCE = 1e-9

BeyondLimits = Literal["stop", "follow"]
"""What the virtual machine does with a block beyond an axis' limits (see the module)."""


@dataclass(frozen=True)
class MarkedSpan:
    """A stretch of machine time during which the program's marker was set."""

    marker: float
    start_s: float
    end_s: float
    axis: str
    """The axis moving in the span (empty during a dwell)."""
    velocity_mm_min: float
    """Signed commanded velocity of that axis (0 during a dwell)."""


@dataclass(frozen=True)
class AxisExtremes:
    """How far one axis went in a run: the extremes of its motion.

    ``velocity_mm_min`` and ``acceleration_m_s2`` are magnitudes (the largest
    in either direction).
    """

    min_position_mm: float
    max_position_mm: float
    velocity_mm_min: float
    acceleration_m_s2: float


@dataclass(frozen=True)
class _Segment:
    """One path segment: straight, rest to rest."""

    start: FloatArray  # every axis, mm
    unit: FloatArray  # direction per axis (zero for axes that do not move)
    curve: SCurve
    kind: str
    marks: tuple[tuple[float, float], ...]  # (path position where a block ends, marker)


@dataclass(frozen=True)
class _Pause:
    position: FloatArray
    seconds: float
    marker: float


@dataclass
class _Chain:
    kind: str
    feed: float | None
    start: FloatArray
    end: FloatArray
    unit: FloatArray
    marks: list[tuple[float, float]] = field(default_factory=list)


@dataclass(frozen=True)
class MachineRun:
    """The simulated signals of every axis on a uniform time grid.

    A :class:`~ncmeasure.sim.signals.SignalSource`: :meth:`state` looks the
    signals up at the nearest grid point (before the start and after the end
    the machine stands still). Plain numpy arrays only, so it pickles (the
    Modbus drive server runs in another process).
    """

    axes: tuple[str, ...]
    dt_s: float
    position_mm: FloatArray
    """Actual position, shape (axes, samples)."""
    velocity_mm_min: FloatArray
    """Actual velocity as the drive reports it (with measurement noise)."""
    velocity_cmd_mm_min: FloatArray
    """Commanded velocity (the interpolator's setpoint)."""
    position_cmd_mm: FloatArray
    """Commanded position (the interpolator's setpoint)."""
    acceleration_m_s2: FloatArray
    """Actual acceleration (the servo loop's response to the commanded one)."""
    acceleration_cmd_m_s2: FloatArray
    """Commanded acceleration (the interpolator's setpoint)."""
    current_a: FloatArray
    """Motor current."""
    marker: FloatArray
    """The program's marker, shape (samples,)."""
    spans: tuple[MarkedSpan, ...]
    program_start_s: float
    program_end_s: float

    @property
    def duration_s(self) -> float:
        """Machine time covered: lead-in, program and lead-out."""
        return (self.marker.size - 1) * self.dt_s

    def state(self, axis: int, time_s: float) -> AxisState:
        """The state of axis ``axis`` (0-based, machine-file order) at ``time_s``."""
        i = min(max(round(time_s / self.dt_s), 0), self.marker.size - 1)
        return AxisState(
            position_mm=float(self.position_mm[axis, i]),
            velocity_mm_min=float(self.velocity_mm_min[axis, i]),
            current_a=float(self.current_a[axis, i]),
            velocity_cmd_mm_min=float(self.velocity_cmd_mm_min[axis, i]),
            marker=float(self.marker[i]),
        )

    def extremes(self, commanded: bool = False) -> dict[str, AxisExtremes]:
        """Per axis name: the extremes of its actual motion, or of the commanded one.

        The actual velocity is the one the drive reports (with its measurement noise).
        """
        position = self.position_cmd_mm if commanded else self.position_mm
        velocity = self.velocity_cmd_mm_min if commanded else self.velocity_mm_min
        acceleration = self.acceleration_cmd_m_s2 if commanded else self.acceleration_m_s2
        return {
            name: AxisExtremes(
                min_position_mm=float(position[i].min()),
                max_position_mm=float(position[i].max()),
                velocity_mm_min=float(np.abs(velocity[i]).max()),
                acceleration_m_s2=float(np.abs(acceleration[i]).max()),
            )
            for i, name in enumerate(self.axes)
        }

    def time_s(self) -> FloatArray:
        """The grid's machine times."""
        return np.arange(self.marker.size, dtype=np.float64) * self.dt_s

    def sample(self, period_s: float) -> tuple[tuple[Channel, ...], SampleBlock]:
        """Every signal sampled every ``period_s`` (no link), marker included.

        The channels are those a link delivers (``X_current_a``, ...), plus the
        commanded velocity and the program's marker per axis.
        """
        signals = ("current_a", "velocity_mm_min", "position_mm", "velocity_cmd_mm_min", "marker")
        channels = channels_for(self.axes, signals)
        index = np.round(np.arange(0.0, self.duration_s + 1e-9, period_s) / self.dt_s).astype(int)
        index = index[index < self.marker.size]
        columns = []
        for i in range(len(self.axes)):
            columns += [
                self.current_a[i, index],
                self.velocity_mm_min[i, index],
                self.position_mm[i, index],
                self.velocity_cmd_mm_min[i, index],
                self.marker[index],
            ]
        return channels, SampleBlock(index * self.dt_s, np.column_stack(columns))


def one_after_another(runs: Sequence[MachineRun]) -> MachineRun:
    """Runs one after another on one time grid: a program started again and again (a series).

    Each run keeps its lead-in and lead-out (the standstill between two program starts);
    the marked spans move to their place. The program's start is the first run's, its end
    the last run's.

    Raises:
        ValueError: no runs, or runs of other axes or another time step.
    """
    if not runs:
        raise ValueError("one_after_another needs at least one run")
    first = runs[0]
    if any(r.axes != first.axes or r.dt_s != first.dt_s for r in runs):
        raise ValueError("runs of other axes or another time step cannot follow one another")
    shifts: list[float] = []
    samples = 0
    for r in runs:
        shifts.append(samples * first.dt_s)
        samples += r.marker.size
    spans = tuple(
        dataclasses.replace(span, start_s=span.start_s + shift, end_s=span.end_s + shift)
        for r, shift in zip(runs, shifts, strict=True)
        for span in r.spans
    )

    def joined(name: str) -> FloatArray:
        return np.concatenate([getattr(r, name) for r in runs], axis=-1)

    return MachineRun(
        axes=first.axes,
        dt_s=first.dt_s,
        position_mm=joined("position_mm"),
        velocity_mm_min=joined("velocity_mm_min"),
        velocity_cmd_mm_min=joined("velocity_cmd_mm_min"),
        position_cmd_mm=joined("position_cmd_mm"),
        acceleration_m_s2=joined("acceleration_m_s2"),
        acceleration_cmd_m_s2=joined("acceleration_cmd_m_s2"),
        current_a=joined("current_a"),
        marker=joined("marker"),
        spans=spans,
        program_start_s=first.program_start_s,
        program_end_s=runs[-1].program_end_s + shifts[-1],
    )


class VirtualMachine:
    """A machine tool whose feed axes follow an NC program.

    Args:
        config: The machine (axis limits, drive data, bearing layout).
        trace: The program as read by :func:`~ncmeasure.program.reader.read_programs`.
        variations: Assembly variations by axis name (default: every axis nominal).
        seed: Seed of the current and velocity noise, and of the run's drift (with
            ``realism``).
        dt_s: Time step of the simulation grid.
        lead_in_s: Standstill before the program starts.
        lead_out_s: Standstill after the program ends.
        servo_frequency_hz: Natural frequency of the position loop.
        servo_damping: Its damping ratio.
        velocity_noise_mm_min: Standard deviation of the reported velocity's noise
            (without ``realism``; with it the velocity is the encoder's).
        start_mm: Where axes stand when the program starts (default: at their parks), e.g.
            a vertical axis left low by the operator.
        beyond_limits: ``stop``: a block beyond an axis' travel raises ProgramError, a
            feed above an axis' maximum velocity is driven at the maximum (a controller's
            soft limits and feed limit); ``follow``: the machine follows the program there,
            and :attr:`excursions` lists each such block (a dry run).
        realism: Fingerprint, drift and the drives' noise (default: none, an ideal
            machine; see :mod:`ncmeasure.sim.realism`).
        machine_seed: Seed of the machine's fingerprint (with ``realism``): the same
            machine seed is the same machine, whatever the run's ``seed``.

    Raises:
        ConfigError: a variation names an axis the machine lacks, or is invalid for it;
            a negative seed with ``realism``.
        ProgramError: the program moves an axis the machine lacks, or (``stop``) outside
            its travel.
    """

    def __init__(
        self,
        config: MachineConfig,
        trace: ProgramTrace,
        *,
        variations: Mapping[str, Variation] | None = None,
        seed: int = 0,
        dt_s: float = 0.001,
        lead_in_s: float = 0.5,
        lead_out_s: float = 0.5,
        servo_frequency_hz: float = 20.0,
        servo_damping: float = 0.7,
        velocity_noise_mm_min: float = 0.2,
        start_mm: Mapping[str, float] | None = None,
        beyond_limits: BeyondLimits = "stop",
        realism: Realism | None = None,
        machine_seed: int = 0,
    ) -> None:
        if not dt_s > 0:
            raise ValueError("dt_s must be > 0")
        if beyond_limits not in ("stop", "follow"):
            raise ValueError("beyond_limits must be 'stop' or 'follow'")
        self.config = config
        self.trace = trace
        names = [axis.name for axis in config.axes]
        unknown = sorted(set(variations or {}) - set(names))
        if unknown:
            raise ConfigError(
                "invalid assembly variation",
                [
                    f"axis {name}: the machine has no such axis (axes: {', '.join(names)})"
                    for name in unknown
                ],
            )
        self.variations: dict[str, Variation] = dict(variations or {})
        self.models: dict[str, AxisModel] = {
            axis.name: AxisModel(axis, variation=self.variations.get(axis.name))
            for axis in config.axes
        }
        self.realism = realism
        self.machine_seed = machine_seed
        self.realised: dict[str, AxisRealism] = {}
        """Per axis: the fingerprint, drift and noise figures drawn (empty without realism)."""
        if realism is not None:
            self._realise(realism, seed, machine_seed, dt_s)
        self.seed = seed
        self.dt_s = dt_s
        self.lead_in_s = lead_in_s
        self.lead_out_s = lead_out_s
        self.servo_frequency_hz = servo_frequency_hz
        self.servo_damping = servo_damping
        self.velocity_noise_mm_min = velocity_noise_mm_min
        self.start_mm = dict(start_mm or {})
        self.beyond_limits: BeyondLimits = beyond_limits
        self.excursions: list[str] = []
        """``file:line: what``, per block that takes an axis beyond its travel or above its
        maximum velocity (only with ``beyond_limits="follow"``; ``stop`` raises instead)."""
        self._segments = self._plan()

    def _realise(self, realism: Realism, seed: int, machine_seed: int, dt_s: float) -> None:
        """Draw each axis' fingerprint (machine seed) and drift (run seed)."""
        if seed < 0 or machine_seed < 0:
            raise ConfigError(
                "invalid realism", [f"seed {seed}, machine_seed {machine_seed}: must be >= 0"]
            )
        for i, axis in enumerate(self.config.axes):
            fingerprint = realism.fingerprint(np.random.default_rng([machine_seed, i, 0]))
            drift = realism.drift(np.random.default_rng([seed, i, 1]))
            fault = self.variations.get(axis.name, Variation())
            nominal = AxisModel(axis, variation=with_tolerance(fault, fingerprint.variation))
            realised = realism.for_axis(nominal, fingerprint, drift, dt_s)
            self.realised[axis.name] = realised
            self.models[axis.name] = AxisModel(
                axis, variation=nominal.variation, condition=realised.condition()
            )

    @classmethod
    def from_programs(
        cls,
        config: MachineConfig,
        directory: str | Path,
        *,
        controllers_dirs: Sequence[Path] = (),
        **options: object,
    ) -> VirtualMachine:
        """Read the programs generated into ``directory`` (with its schedule.json).

        Keyword options are those of :class:`VirtualMachine`.

        Raises:
            ProgramError: no schedule or a program that cannot be read.
            DialectError: the schedule's controller is unknown.
        """
        _, _, trace = read_generated(directory, tuple(controllers_dirs))
        return cls(config, trace, **options)  # type: ignore[arg-type]

    # --- planning -----------------------------------------------------------------------

    def _initial(self) -> FloatArray:
        """Where the axes stand before the program: ``start_mm``, else at their parks."""
        return np.array(
            [self.start_mm.get(axis.name, axis.park_mm) for axis in self.config.axes],
            dtype=np.float64,
        )

    def _plan(self) -> list[_Segment | _Pause]:
        axes = [axis.name for axis in self.config.axes]
        index = {name: i for i, name in enumerate(axes)}
        position = self._initial()
        plan: list[_Segment | _Pause] = []
        chain: _Chain | None = None

        def close() -> None:
            nonlocal chain
            if chain is not None:
                plan.append(self._segment(chain))
                chain = None

        for step in self.trace.steps:
            if isinstance(step, Dwell):
                close()
                plan.append(_Pause(position.copy(), step.seconds, step.marker))
                continue
            if isinstance(step, Stop):
                close()  # the virtual operator presses cycle start at once
                continue
            if isinstance(step, ReadyWait):
                close()  # the simulated recorder is always ready: the wait passes at once
                continue
            target = position.copy()
            for name, value in step.target.items():
                if name not in index:
                    raise ProgramError(
                        f"{step.file or step.program}:{step.line}: moves axis {name}, which the "
                        f"machine lacks (axes: {', '.join(axes)})"
                    )
                target[index[name]] = value
            self._check_travel(step, target)
            delta = target - position
            length = float(np.linalg.norm(delta))
            if length == 0.0:
                continue
            unit = delta / length
            feed = step.feed_mm_min if step.kind == "feed" else None
            if feed is not None:
                self._check_feed(step, unit, feed)
            if (
                chain is None
                or chain.kind != step.kind
                or chain.feed != feed
                or float(np.dot(chain.unit, unit)) < 1.0 - _DIRECTION_TOLERANCE
            ):
                close()
                chain = _Chain(step.kind, feed, position.copy(), position.copy(), unit)
            chain.end = target.copy()
            chain.marks.append((float(np.linalg.norm(target - chain.start)), step.marker))
            position = target
        close()
        return plan

    def _check_travel(self, step: Motion, target: FloatArray) -> None:
        for axis, value in zip(self.config.axes, target, strict=True):
            low, high = axis.travel_mm
            if not low - 1e-6 <= value <= high + 1e-6:
                where = f"{step.file or step.program}:{step.line}"
                if self.beyond_limits == "follow":
                    self.excursions.append(
                        f"{where}: axis {axis.name} to {value:g} mm, outside its travel "
                        f"[{low:g}, {high:g}] mm"
                    )
                    continue
                raise ProgramError(
                    f"{where}: axis {axis.name} would move to {value:g} mm, "
                    f"outside its travel [{low:g}, {high:g}] mm; the virtual machine stops"
                )

    def _check_feed(self, step: Motion, unit: FloatArray, feed: float) -> None:
        """Note a feed that drives an axis above its maximum velocity (``follow`` only:
        ``stop`` drives it at the maximum, see :meth:`_segment`)."""
        if self.beyond_limits != "follow":
            return
        for axis, share in zip(self.config.axes, np.abs(unit), strict=True):
            velocity = float(share) * feed
            if velocity > axis.max_velocity_mm_min * (1 + 1e-9):
                self.excursions.append(
                    f"{step.file or step.program}:{step.line}: axis {axis.name} at "
                    f"{velocity:g} mm/min, above its maximum velocity "
                    f"{axis.max_velocity_mm_min:g} mm/min"
                )

    def _segment(self, chain: _Chain) -> _Segment:
        unit = np.abs(chain.unit)
        moving = unit > 0
        limits = self.config.axes
        velocity = min(limits[i].max_velocity_mm_min / unit[i] for i in np.flatnonzero(moving))
        if chain.kind == "feed" and chain.feed is not None:
            # a controller drives a feed above the maximum at the maximum; a dry run as written
            velocity = chain.feed if self.beyond_limits == "follow" else min(velocity, chain.feed)
        acceleration = min(
            limits[i].max_acceleration_m_s2 / unit[i] for i in np.flatnonzero(moving)
        )
        jerk = min(limits[i].max_jerk_m_s3 / unit[i] for i in np.flatnonzero(moving))
        length = float(np.linalg.norm(chain.end - chain.start))
        return _Segment(
            start=chain.start,
            unit=chain.unit,
            curve=s_curve(length, velocity, acceleration, jerk),
            kind=chain.kind,
            marks=tuple(chain.marks),
        )

    # --- running ------------------------------------------------------------------------

    @property
    def program_duration_s(self) -> float:
        """Machine time the program takes, from its first block to its end."""
        return sum(
            p.seconds if isinstance(p, _Pause) else p.curve.duration_s for p in self._segments
        )

    @property
    def duration_s(self) -> float:
        """Lead-in, program and lead-out."""
        return self.lead_in_s + self.program_duration_s + self.lead_out_s

    def run(self) -> MachineRun:
        """Simulate the whole program; the signals of every axis."""
        dt = self.dt_s
        n = math.ceil(self.duration_s / dt) + 1
        axes = self.config.axes
        names = tuple(axis.name for axis in axes)
        position = np.empty((len(axes), n))
        velocity = np.zeros((len(axes), n))
        acceleration = np.zeros((len(axes), n))
        marker = np.zeros(n)
        spans: list[MarkedSpan] = []
        bisect: list[tuple[SCurve, float]] = []  # (move, distance) of a span's edges
        bisected: list[int] = []  # the spans whose edges those are
        initial = self._initial()
        position[:, :] = initial[:, None]
        t = self.lead_in_s
        for part in self._segments:
            duration = part.seconds if isinstance(part, _Pause) else part.curve.duration_s
            first = math.ceil(t / dt - 1e-9)
            last = min(math.ceil((t + duration) / dt - 1e-9), n)
            grid = np.arange(first, last) * dt - t
            if isinstance(part, _Pause):
                position[:, first:] = part.position[:, None]
                marker[first:last] = part.marker
                if part.marker:
                    spans.append(MarkedSpan(part.marker, t, t + duration, "", 0.0))
            else:
                s, v, a = part.curve.at(grid)
                end = part.start + part.unit * part.curve.distance_mm
                position[:, first:] = end[:, None]
                position[:, first:last] = part.start[:, None] + part.unit[:, None] * s
                velocity[:, first:last] = part.unit[:, None] * v
                acceleration[:, first:last] = part.unit[:, None] * a
                edges = np.array([m[0] for m in part.marks])
                values = np.array([m[1] for m in part.marks])
                which = np.minimum(np.searchsorted(edges, s, side="left"), len(edges) - 1)
                marker[first:last] = values[which]
                moving = int(np.argmax(np.abs(part.unit)))
                begin = 0.0
                for edge, value in part.marks:
                    if value:
                        # its start and end are found below, every span's at once
                        bisect += [(part.curve, begin), (part.curve, edge)]
                        bisected.append(len(spans))
                        spans.append(
                            MarkedSpan(
                                value,
                                t,
                                t,
                                names[moving],
                                float(part.unit[moving] * part.curve.peak_velocity_mm_min),
                            )
                        )
                    begin = edge
            t += duration
        if bisect:
            curves, distances = zip(*bisect, strict=True)
            edges_s = times_at(curves, distances).reshape(-1, 2)
            for i, (t0, t1) in zip(bisected, edges_s, strict=True):
                span = spans[i]
                spans[i] = dataclasses.replace(
                    span, start_s=float(span.start_s + t0), end_s=float(span.end_s + t1)
                )
        rng = np.random.default_rng(self.seed)
        b, a_coef = servo(dt, self.servo_frequency_hz, self.servo_damping)
        actual_position = np.empty_like(position)
        actual_velocity = np.empty_like(velocity)
        actual_acceleration = np.empty_like(acceleration)
        current = np.empty_like(position)
        for i, axis in enumerate(axes):
            actual_position[i] = follow(b, a_coef, position[i])
            followed = follow(b, a_coef, velocity[i])
            actual_acceleration[i] = follow(b, a_coef, acceleration[i])
            realised = self.realised.get(axis.name)
            if realised is None:
                current[i] = self.models[axis.name].motor_current_a(
                    actual_position[i], followed, actual_acceleration[i], rng=rng
                )
                actual_velocity[i] = followed + rng.normal(0.0, self.velocity_noise_mm_min, n)
                continue
            current[i], actual_velocity[i] = self._as_the_drive_reports(
                self.models[axis.name],
                realised,
                actual_position[i],
                followed,
                actual_acceleration[i],
                rng,
            )
        return MachineRun(
            axes=names,
            dt_s=dt,
            position_mm=actual_position,
            velocity_mm_min=actual_velocity,
            velocity_cmd_mm_min=velocity,
            position_cmd_mm=position,
            acceleration_m_s2=actual_acceleration,
            acceleration_cmd_m_s2=acceleration,
            current_a=current,
            marker=marker,
            spans=tuple(spans),
            program_start_s=self.lead_in_s,
            program_end_s=self.lead_in_s + self.program_duration_s,
        )

    def _as_the_drive_reports(
        self,
        model: AxisModel,
        realised: AxisRealism,
        position_mm: FloatArray,
        velocity_mm_min: FloatArray,
        acceleration_m_s2: FloatArray,
        rng: np.random.Generator,
    ) -> tuple[FloatArray, FloatArray]:
        """Current and velocity as a real drive reports them (with realism).

        The velocity is the encoder's position difference over
        ``velocity_average_samples`` grid steps, in whole increments. The speed
        loop answers its quantisation error with torque (``−K_p · error``), which
        the motor really draws; the drive measures the current with its gain error,
        its ADC's noise and steps, and rare outliers.
        """
        ax = model.axis
        increment = realised.position_increment_mm
        steps = realised.velocity_average_samples
        counts = np.floor(position_mm / increment)
        earlier = np.concatenate([np.full(steps, counts[0]), counts[:-steps]])
        reported = (counts - earlier) * increment / (steps * self.dt_s) * 60.0
        error_rad_s = 2.0 * math.pi * (reported - velocity_mm_min) / (60.0 * ax.screw_lead_mm)
        loop_a = -realised.speed_loop_gain_nms_rad * error_rad_s / ax.torque_constant_nm_per_a
        clean = model.motor_current_a(position_mm, velocity_mm_min, acceleration_m_s2)
        current = realised.drift.gain * (clean + loop_a)
        current = current + rng.normal(0.0, realised.current_noise_a, current.shape)
        hit = rng.random(current.shape) < ax.outlier_rate
        signs = rng.choice(np.array([-1.0, 1.0]), size=current.shape)
        current = current + np.where(hit, signs * ax.outlier_a, 0.0)
        lsb = realised.current_lsb_a
        return np.round(current / lsb) * lsb, reported
