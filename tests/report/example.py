"""A realistic example for the report: a simulated recording of two axes and its results.

Axis X (horizontal, travel 0–750 mm, fixed bearing at 0 mm) has a loose
bearing that is shifted, so friction rises towards 750 mm by about 30 %.
Axis Z (vertical, travel −500–0 mm, fixed bearing at 0 mm) carries a weight:
its points include a gravity offset, friction is flat along the travel.

Both axes follow a Stribeck curve (T_C ≈ 1.5 Nm, T_S ≈ 2.3 Nm, v_S ≈ 120 mm/min,
viscous ≈ 0.09 Nm per m/min) measured at 3 positions and 10 velocities in both
directions, sampled every 4 ms like a Sinumerik trace. The results are built
from the pydantic models; the fits come from :mod:`ncmeasure.analysis.friction.fit`.

:func:`healthy_recording` is the other side: a correctly assembled axis X
whose friction is the same along the travel (with a Stribeck hump at low
speed, which is friction and not a fault) and an axis Y whose current
channel is dead, so the analysis skips it.

``python -m tests.report.example OUT_DIR`` writes the example report (used for
``docs/report-screenshot.png``).
"""

from __future__ import annotations

import datetime as dt
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.analyze import AnalysisSettings
from ncmeasure.analysis.friction.fit import fit_direction, separate_offset
from ncmeasure.analysis.judgement.verdict import axis_verdict
from ncmeasure.analysis.reading import recording_gaps
from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.examples import example_machine
from ncmeasure.formats.results import (
    AxisResult,
    Cause,
    DirectionResult,
    Point,
    PositionDependency,
    PositionResult,
    RecordingInfo,
    Results,
    VelocityProfile,
    Verdict,
)
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RecordingWriter
from ncmeasure.samples import SampleBlock, channels_for
from ncmeasure.sim.synthetic import (
    SyntheticAxis,
    geometric_velocities,
    machine_config,
)
from ncmeasure.sim.synthetic import simulate as simulate_synthetic

FloatArray = NDArray[np.float64]

PERIOD_S = 0.004
TORQUE_CONSTANT = 2.1
VELOCITIES_MM_MIN = (20.0, 45.0, 90.0, 180.0, 400.0, 800.0, 1600.0, 3200.0, 6000.0, 10000.0)
ACCELERATION_MM_S2 = 1500.0
START = dt.datetime(2026, 1, 15, 8, 30, tzinfo=dt.UTC)
SIGNALS = ("current_a", "velocity_mm_min", "position_mm", "velocity_cmd_mm_min")


@dataclass(frozen=True)
class AxisModel:
    """The friction of one simulated axis."""

    name: str
    travel_mm: tuple[float, float]
    positions_mm: tuple[float, float, float]
    position_factor: tuple[float, float, float]
    gravity_nm: float
    fixed_bearing_end: Literal["min", "max"]

    def friction_nm(self, speed: FloatArray, position_mm: FloatArray) -> FloatArray:
        """Friction magnitude at speed |v| (mm/min) and position."""
        speed = np.abs(speed)
        stribeck = 1.5 + 0.8 * np.exp(-speed / 120.0) + 9e-5 * speed
        factor = np.interp(position_mm, self.positions_mm, self.position_factor)
        result: FloatArray = stribeck * factor
        return result


X = AxisModel("X", (0.0, 750.0), (60.0, 375.0, 690.0), (1.0, 1.09, 1.31), 0.0, "min")
Z = AxisModel("Z", (-500.0, 0.0), (-460.0, -250.0, -40.0), (1.02, 0.99, 1.0), 2.6, "max")
AXES = (X, Z)


@dataclass(frozen=True)
class Window:
    axis: str
    position_index: int
    velocity_mm_min: float
    start_s: float
    end_s: float


def _machine() -> MachineConfig:
    """The ``ncmeasure init`` example machine (X, Y, Z; Z vertical, fixed bearings as above)."""
    return parse_machine(tomllib.loads(example_machine("linuxcnc")))


def _move(velocity: float, hold_s: float) -> FloatArray:
    """Commanded velocity of one move: ramp, constant for ``hold_s``, ramp, 0.3 s standstill."""
    ramp_s = abs(velocity) / 60.0 / ACCELERATION_MM_S2
    ramp = np.linspace(0.0, velocity, max(2, int(ramp_s / PERIOD_S)))
    hold = np.full(int(hold_s / PERIOD_S), velocity)
    rest = np.zeros(int(0.3 / PERIOD_S))
    return np.concatenate([ramp, hold, ramp[::-1], rest])


def simulate(directory: Path) -> tuple[Recording, dict[str, list[Window]]]:
    """Record both axes, one after the other, into ``directory``."""
    rng = np.random.default_rng(17)
    machine = _machine()
    channels = channels_for([m.name for m in AXES], SIGNALS)
    windows: dict[str, list[Window]] = {m.name: [] for m in AXES}
    time_offset = 0.0
    blocks: list[tuple[FloatArray, FloatArray]] = []
    for axis_index, model in enumerate(AXES):
        start_mm = model.positions_mm[0]
        commands: list[FloatArray] = [np.zeros(int(0.5 / PERIOD_S))]
        places: list[FloatArray] = [np.full(len(commands[0]), start_mm)]
        marks: list[tuple[int, int, int, float]] = []
        count = len(commands[0])
        for position_index, position in enumerate(model.positions_mm):
            if position_index:  # rapid traverse to the next measuring position
                rapid = _move(12000.0, 0.0)
                commands.append(rapid)
                places.append(np.linspace(float(places[-1][-1]), position, len(rapid)))
                count += len(rapid)
            for velocity in VELOCITIES_MM_MIN:
                hold_s = float(np.clip(6.0 / velocity * 60.0, 0.5, 2.0))
                # first away from the nearer end of the travel, then back
                middle = sum(model.travel_mm) / 2
                for sign in (1.0, -1.0) if position < middle else (-1.0, 1.0):
                    move = _move(sign * velocity, hold_s)
                    ramp = max(2, int(velocity / 60.0 / ACCELERATION_MM_S2 / PERIOD_S))
                    first = count + ramp + int(0.05 / PERIOD_S)
                    last = count + ramp + int(hold_s / PERIOD_S) - int(0.02 / PERIOD_S)
                    marks.append((position_index, first, last, sign * velocity))
                    commands.append(move)
                    places.append(float(places[-1][-1]) + np.cumsum(move / 60.0 * PERIOD_S))
                    count += len(move)
        command = np.concatenate(commands)
        trace_mm = np.concatenate(places)
        n = len(command)
        time_s = np.asarray(time_offset + np.arange(n) * PERIOD_S, dtype=np.float64)
        actual = command + rng.normal(0.0, 0.004, n) * np.maximum(np.abs(command), 50.0)
        acceleration = np.gradient(command / 60.0, PERIOD_S)
        speed = np.abs(actual)
        roughness = 1.0 + 1.5 * np.exp(-speed / 60.0)
        friction = np.sign(actual) * model.friction_nm(speed, trace_mm)
        friction[np.abs(command) < 1e-9] = 0.0
        torque = friction + model.gravity_nm + 0.0022 * acceleration
        torque = torque + rng.normal(0.0, 0.05, n) * roughness
        current = torque / TORQUE_CONSTANT
        values = np.zeros((n, len(channels)))
        column = 4 * axis_index
        values[:, column] = current
        values[:, column + 1] = actual
        values[:, column + 2] = trace_mm
        values[:, column + 3] = command
        other = 4 * (1 - axis_index)  # the resting axis holds its place (and its weight)
        values[:, other] = (AXES[1 - axis_index].gravity_nm / TORQUE_CONSTANT) + rng.normal(
            0.0, 0.01, n
        )
        values[:, other + 2] = machine.axis(AXES[1 - axis_index].name).park_mm
        blocks.append((time_s, values))
        for position_index, first, last, velocity in marks:
            windows[model.name].append(
                Window(model.name, position_index, velocity, time_s[first], time_s[last])
            )
        time_offset = float(time_s[-1]) + PERIOD_S
    with RecordingWriter.create(
        directory,
        channels,
        nominal_period_s=PERIOD_S,
        machine=machine,
        source="simulation",
        start_utc=START,
    ) as writer:
        for time_s, values in blocks:
            for begin in range(0, len(time_s), 50_000):
                end = begin + 50_000
                writer.append(SampleBlock(time_s[begin:end], values[begin:end]))
    return Recording.open(directory), windows


def _points(recording: Recording, windows: list[Window], axis: str) -> list[list[Point]]:
    """Points per position (both directions together), from the window samples."""
    torque = recording.axis_signal(axis, "current_a") * TORQUE_CONSTANT
    per_position: dict[int, list[Point]] = {}
    for step, window in enumerate(windows):
        inside = (recording.time_s >= window.start_s) & (recording.time_s <= window.end_s)
        samples = torque[inside]
        per_position.setdefault(window.position_index, []).append(
            Point(
                velocity_mm_min=window.velocity_mm_min,
                median=float(np.median(samples)),
                mean=float(np.mean(samples)),
                std=float(np.std(samples, ddof=1)),
                n=int(samples.size),
                step=step // 2,
            )
        )
    return [per_position[i] for i in sorted(per_position)]


def _dependency(model: AxisModel, positions: list[PositionResult]) -> PositionDependency:
    profiles = []
    table = []
    for velocity in VELOCITIES_MM_MIN:
        values = []
        for position in positions:
            pair = [
                p.median
                for d in position.directions.values()
                if d is not None
                for p in d.points
                if abs(abs(p.velocity_mm_min) - velocity) < 1e-6
            ]
            # friction is half the difference of the directions: the offset cancels
            values.append(float((max(pair) - min(pair)) / 2))
        table.append(values)
        profiles.append(_profile(velocity, model.positions_mm, values))
    average = np.mean(np.array(table), axis=0).tolist()
    profiles.append(_profile(None, model.positions_mm, average))
    mean = float(np.mean(average))
    slope = float(np.polyfit(model.positions_mm, average, 1)[0])
    spread = profiles[-1].spread_percent
    if model.name == "X":
        signature = "rising_to_loose_bearing"
        causes = [
            Cause(
                cause="loose_bearing",
                score=0.81,
                evidence=(
                    f"Friction rises nearly linearly by {spread:.0f} % from the fixed bearing "
                    "(60 mm) to the loose bearing (690 mm); at every velocity the highest value "
                    "is at 690 mm."
                ),
            ),
            Cause(
                cause="guide_rail",
                score=0.12,
                evidence="A ramp along the travel can also come from a rail misalignment.",
            ),
            Cause(
                cause="preload_or_carriage",
                score=0.05,
                evidence="The mean level is within the usual range for this axis type.",
            ),
        ]
    else:
        signature = "flat"
        causes = [
            Cause(
                cause="none",
                score=0.9,
                evidence=f"Spread {spread:.0f} % is within the scatter of the points.",
            )
        ]
    return PositionDependency(
        spread_percent=spread,
        trend_per_100mm=slope * 100.0 / mean * 100.0,
        signature=signature,
        profiles=profiles,
        causes=causes,
    )


def _profile(
    velocity: float | None, positions: tuple[float, ...], values: list[float]
) -> VelocityProfile:
    mean = float(np.mean(values))
    return VelocityProfile(
        velocity_mm_min=velocity,
        positions_mm=list(positions),
        values=values,
        spread_percent=(max(values) - min(values)) / mean * 100.0,
    )


def build_results(
    recording: Recording, windows: dict[str, list[Window]], machine: str | None = None
) -> Results:
    """Results of both axes, from the recording's window samples."""
    axes: dict[str, AxisResult] = {}
    for model in AXES:
        per_position = _points(recording, windows[model.name], model.name)
        positions = []
        all_positive: list[Point] = []
        all_negative: list[Point] = []
        for points in per_position:
            for p in points:
                (all_positive if p.velocity_mm_min > 0 else all_negative).append(p)
        offset = separate_offset(all_positive, all_negative)
        for index, points in enumerate(per_position):
            directions: dict[Literal["positive", "negative"], DirectionResult | None] = {}
            for name, sign in (("positive", 1), ("negative", -1)):
                chosen = [p for p in points if np.sign(p.velocity_mm_min) == sign]
                directions["positive" if name == "positive" else "negative"] = fit_direction(
                    chosen, 1 if sign > 0 else -1, offset=offset
                )
            positions.append(
                PositionResult(
                    position_mm=model.positions_mm[index],
                    position_index=index,
                    directions=directions,
                )
            )
        warnings = []
        if model.name == "Z":
            warnings.append(
                "vertical axis: the points include the weight's torque (see the offset)"
            )
        result = AxisResult(
            verdict=Verdict(level="ok", reason="", action=""),
            quantity="torque_nm",
            unit="Nm",
            torque_constant_nm_per_a=TORQUE_CONSTANT,
            window_source="command",
            windows=len(windows[model.name]),
            samples_used=sum(p.n for pos in per_position for p in pos),
            positions=positions,
            offset=offset,
            position_dependency=_dependency(model, positions),
            warnings=warnings,
        )
        axes[model.name] = result.model_copy(update={"verdict": axis_verdict(result)})
    gaps, lost, events = recording_gaps(recording)
    return Results(
        created_utc="2026-01-15T09:05:00.000+00:00",
        recording=RecordingInfo(
            directory=str(recording.directory.name),
            machine=machine if machine is not None else recording.meta.machine,
            start_utc=recording.meta.start_utc,
            config_hash="3f9c2a41d7e0",
            source=recording.meta.source,
            status=recording.meta.status,
            samples=len(recording),
            duration_s=float(recording.time_s[-1] - recording.time_s[0]),
            gaps=gaps,
            gap_samples=lost,
            gap_share=lost / (len(recording) + lost),
            gap_events=events,
        ),
        settings=AnalysisSettings().model_dump(),
        axes=axes,
    )


HEALTHY_X = SyntheticAxis(
    name="X",
    positions_mm=(50.0, 375.0, 700.0),
    coulomb=2.0,
    stribeck=0.8,
    velocities_mm_min=geometric_velocities(10.0, 15000.0, 20),
)
DEAD_Y = SyntheticAxis(
    name="Y",
    positions_mm=(50.0, 375.0, 700.0),
    velocities_mm_min=geometric_velocities(100.0, 5000.0, 3),
)
DEAD_Y_REASON = "Y_current_a is 0 A in every row: a dead channel"


def healthy_recording(directory: Path, seed: int = 0) -> tuple[Recording, Schedule]:
    """A correctly assembled X (flat along the travel) and a Y with a dead current channel.

    Returns:
        The recording written to ``directory`` and the schedule of its program.
    """
    axes = [HEALTHY_X, DEAD_Y]
    data = simulate_synthetic(axes, seed=seed)
    names = [c.name for c in data.channels]
    values = data.values.copy()
    values[:, names.index("Y_current_a")] = 0.0  # the drive does not report it
    with RecordingWriter.create(
        directory,
        data.channels,
        nominal_period_s=PERIOD_S,
        machine=machine_config(axes, name="healthy machine"),
        config_hash=data.schedule.config_hash,
        source="synthetic",
        faster_than_real_time=True,
    ) as writer:
        writer.append(SampleBlock(data.time_s, values))
    return Recording.open(directory), data.schedule


def cut_windows(windows: dict[str, list[Window]]) -> dict[str, list[tuple[float, float]]]:
    """The windows in the form write_report takes."""
    return {axis: [(w.start_s, w.end_s) for w in found] for axis, found in windows.items()}


def main(argv: list[str]) -> int:
    from ncmeasure.report import write_report

    out = Path(argv[0] if argv else "report-example")
    recording, windows = simulate(out / "recording")
    results = build_results(recording, windows)
    path = write_report(results, out / "report.html", recording=recording,
                        windows=cut_windows(windows))  # fmt: skip
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))


def scaled_axis(axis: AxisResult, factor: float) -> AxisResult:
    """The axis with all friction ``factor`` times as high (points, fits, offset)."""
    positions = []
    for position in axis.positions:
        directions = {}
        for name, found in position.directions.items():
            if found is None:
                directions[name] = None
                continue
            fit = found.fit
            if fit is not None:
                fit = fit.model_copy(
                    update={
                        "coulomb": None if fit.coulomb is None else fit.coulomb * factor,
                        "viscous_per_mm_min": None
                        if fit.viscous_per_mm_min is None
                        else fit.viscous_per_mm_min * factor,
                    }
                )
            points = [p.model_copy(update={"median": p.median * factor}) for p in found.points]
            directions[name] = found.model_copy(update={"points": points, "fit": fit})
        positions.append(position.model_copy(update={"directions": directions}))
    offset = axis.offset
    if offset is not None:
        offset = offset.model_copy(update={"value": offset.value * factor})
    return axis.model_copy(update={"positions": positions, "offset": offset})
