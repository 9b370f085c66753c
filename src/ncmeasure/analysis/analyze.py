"""The analysis of one recording: windows -> friction table -> fits -> diagnosis -> Results.

:func:`analyze` runs the whole method (method.md, "The analysis") on every
recorded axis::

    recording = read_recording("run1")
    results = analyze(recording, schedule=load_schedule("programs/schedule.json"),
                      machine=load_machine("machine.toml"))
    write_results(results, "run1.results.json")

Per axis: the constant-velocity windows (:mod:`~ncmeasure.analysis.segment`),
the friction table (:mod:`~ncmeasure.analysis.friction`), per position and
direction the Coulomb + viscous and Stribeck fits
(:func:`~ncmeasure.analysis.fit.fit_direction`), with both directions the
direction-independent offset (:func:`~ncmeasure.analysis.fit.separate_offset`),
and over positions × velocities the position dependency with its likely
assembly causes (:func:`~ncmeasure.analysis.diagnosis.position_dependency`).

What the recording's ``meta.json`` says about an axis (torque constant,
travel, fixed-bearing end, vertical, screw lead) wins; the machine file,
then the schedule, supply what it lacks. :func:`write_results` and
:func:`load_results` write and read ``results.json``.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ncmeasure.analysis.diagnosis import position_dependency
from ncmeasure.analysis.fit import fit_direction, separate_offset
from ncmeasure.analysis.friction import FrictionTable, friction_table
from ncmeasure.analysis.results import (
    RESULTS_FORMAT,
    RESULTS_FORMAT_VERSION,
    AxisResult,
    DirectionResult,
    OffsetResult,
    Point,
    PositionDependency,
    PositionResult,
    RecordingInfo,
    Results,
)
from ncmeasure.analysis.segment import Segmentation, SegmentSettings, windows_of
from ncmeasure.config import MachineConfig, format_validation_error
from ncmeasure.errors import ConfigError, OutputError, RecordingError
from ncmeasure.plan import AxisSummary, Schedule
from ncmeasure.recording import Recording

__all__ = [
    "AnalysisSettings",
    "AxisFacts",
    "analyze",
    "analyze_axis",
    "load_results",
    "write_results",
]

log = logging.getLogger(__name__)

Progress = Callable[[str, float], None]

_DEFAULT = SegmentSettings()
_DIRECTIONS: tuple[tuple[Literal[1, -1], Literal["positive", "negative"]], ...] = (
    (1, "positive"),
    (-1, "negative"),
)
#: Standard error of a median of normal samples, relative to std/√n.
_MEDIAN_SE_FACTOR = math.sqrt(math.pi / 2)


class AnalysisSettings(BaseModel):
    """How the analysis finds windows and which samples it keeps.

    The defaults suit ncmeasure's own programs (windows of 0.4 s, settle
    0.1 s, 1 to 4 ms sampling, lowest step about 10 mm/min). They are written
    into ``results.json`` (``settings``), so a result says how it was made.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    velocity_tolerance: float = Field(
        default=_DEFAULT.velocity_tolerance,
        gt=0,
        lt=1,
        description="A sample counts where |actual − commanded velocity| ≤ this fraction of "
        "the commanded one (or velocity_floor_mm_min, whichever is larger). Also the "
        "flatness a plateau must keep.",
    )
    velocity_floor_mm_min: float = Field(
        default=_DEFAULT.velocity_floor_mm_min,
        ge=0,
        description="Absolute floor of the velocity tolerance in mm/min: at low speed the "
        "relative tolerance would be smaller than the velocity signal's noise.",
    )
    settle_s: float = Field(
        default=_DEFAULT.settle_s,
        ge=0,
        description="Samples until this long after the actual velocity entered the "
        "tolerance band are cut from each window (acceleration transient, overshoot).",
    )
    min_window_samples: int = Field(
        default=_DEFAULT.min_window_samples,
        ge=2,
        description="A window with fewer samples after the cut is dropped.",
    )
    plateau_min_s: float = Field(
        default=_DEFAULT.plateau_min_s,
        gt=0,
        description="Shortest plateau of constant actual velocity that counts as a window "
        "(only without marker and commanded velocity).",
    )
    plateau_filter_s: float = Field(
        default=_DEFAULT.plateau_filter_s,
        ge=0,
        description="Width of the rolling median that smooths the actual velocity before "
        "plateaus and the end of transients are detected.",
    )
    standstill_mm_min: float = Field(
        default=_DEFAULT.standstill_mm_min,
        ge=0,
        description="Velocities below this are standstill, never a window.",
    )
    step_tolerance: float = Field(
        default=_DEFAULT.step_tolerance,
        gt=0,
        description="Without a schedule: windows whose velocities differ by less than this "
        "fraction (or step_floor_mm_min) belong to the same velocity step.",
    )
    step_floor_mm_min: float = Field(
        default=_DEFAULT.step_floor_mm_min,
        ge=0,
        description="Absolute floor of step_tolerance in mm/min.",
    )
    position_gap_mm: float = Field(
        default=_DEFAULT.position_gap_mm,
        gt=0,
        description="Without a schedule: window centres further apart than this (or "
        "position_gap_fraction of their span) belong to different measuring positions.",
    )
    position_gap_fraction: float = Field(
        default=_DEFAULT.position_gap_fraction,
        ge=0,
        lt=1,
        description="Relative part of the position gap.",
    )
    max_velocity_mm_min: float | None = Field(
        default=_DEFAULT.max_velocity_mm_min,
        gt=0,
        description="Windows faster than this are rapid traverse. Default: the schedule's "
        "top step; without a schedule, rapids are recognised by their count and duration.",
    )
    duration_outlier_factor: float = Field(
        default=_DEFAULT.duration_outlier_factor,
        gt=1,
        description="Without a schedule: windows lasting this many times longer than the "
        "trend of window duration over velocity are traverses or warm-up strokes.",
    )
    rapid_count_factor: float = Field(
        default=_DEFAULT.rapid_count_factor,
        gt=1,
        description="Without a schedule: the fastest velocity level is rapid traverse when "
        "it holds this many times more windows than a typical level.",
    )
    window_method: Literal["auto", "marker", "command", "plateau"] = Field(
        default=_DEFAULT.method,
        description="auto: marker, else commanded velocity, else plateaus. The others force "
        "one way.",
    )

    def segment_settings(self) -> SegmentSettings:
        """The same settings as :mod:`~ncmeasure.analysis.segment` takes them."""
        data = self.model_dump()
        data["method"] = data.pop("window_method")
        return SegmentSettings(**data)


@dataclass
class AxisFacts:
    """What the analysis knows about an axis besides its samples, and from where."""

    name: str
    torque_constant_nm_per_a: float | None = None
    screw_lead_mm: float | None = None
    travel_mm: tuple[float, float] | None = None
    fixed_bearing_end: Literal["min", "max"] | None = None
    vertical: bool | None = None
    warnings: list[str] = field(default_factory=list)


def _quiet(stage: str, fraction: float) -> None:
    """The progress callback that reports nothing."""


def _axis_facts(
    name: str,
    recording: Recording,
    machine: MachineConfig | None,
    summary: AxisSummary | None,
) -> AxisFacts:
    """Merge the axis data: recording first, then machine file, then schedule."""
    facts = AxisFacts(name)
    sources: list[tuple[str, Mapping[str, Any]]] = []
    for entry in recording.meta.axes:
        if entry.get("name") == name:
            sources.append(("the recording", entry))
    if machine is not None:
        for axis in machine.axes:
            if axis.name == name:
                sources.append(("the machine file", axis.model_dump()))
    if summary is not None:
        sources.append(("the schedule", summary.model_dump()))
    keys = (
        "torque_constant_nm_per_a",
        "screw_lead_mm",
        "travel_mm",
        "fixed_bearing_end",
        "vertical",
    )
    for key in keys:
        found: list[tuple[str, Any]] = [
            (where, data[key]) for where, data in sources if data.get(key) is not None
        ]
        if not found:
            continue
        where, value = found[0]
        if key == "travel_mm":
            value = (float(value[0]), float(value[1]))
        setattr(facts, key, value)
        for other, other_value in found[1:]:
            if key == "travel_mm":
                other_value = (float(other_value[0]), float(other_value[1]))
            if other_value != value:
                facts.warnings.append(
                    f"{key} is {value} in {where} but {other_value} in {other}: {where} is used"
                )
    return facts


def _combine_offsets(
    per_position: list[tuple[float, OffsetResult]], vertical: bool | None
) -> OffsetResult | None:
    """One offset for the axis from the offsets of its positions."""
    if not per_position:
        return None
    if len(per_position) == 1:
        return per_position[0][1]
    values = np.array([o.value for _, o in per_position])
    errors = np.array([o.stderr if o.stderr else np.nan for _, o in per_position])
    if np.all(np.isfinite(errors) & (errors > 0)):
        weight = 1.0 / errors**2
        value = float(np.sum(weight * values) / np.sum(weight))
        stderr: float | None = float(1.0 / math.sqrt(float(np.sum(weight))))
        how = "weighted by their standard errors"
    else:
        value = float(values.mean())
        stderr = float(values.std(ddof=1) / math.sqrt(len(values)))
        how = "plain mean"
    listing = ", ".join(f"{x:g} mm: {o.value:.4g}" for x, o in per_position)
    where = (
        "On this vertical axis it is mainly gravity (the weight's torque on the screw)."
        if vertical
        else "On a vertical axis this is gravity; on a horizontal axis a bias of the torque or "
        "current signal, or friction that differs between the directions."
    )
    explanation = (
        f"Direction-independent part o = (T₊ + T₋)/2 = {value:.4g}"
        + (f" ± {stderr:.3g}" if stderr is not None else "")
        + f", mean over {len(per_position)} positions ({how}; {listing}). {where} "
        "Friction per direction is the half difference (T₊ − T₋)/2."
    )
    return OffsetResult(value=value, stderr=stderr, explanation=explanation)


def _dependency(
    table: FrictionTable,
    segmentation: Segmentation,
    facts: AxisFacts,
    position_mm: dict[int, float],
) -> PositionDependency | None:
    """Position dependency over positions × velocity steps of friction magnitudes."""
    positions = sorted(position_mm)
    steps = sorted({int(s) for s in table.step})
    if len(positions) < 2 or not steps:
        return None
    pos_col = {p: k for k, p in enumerate(positions)}
    step_row = {s: k for k, s in enumerate(steps)}
    shape = (len(steps), len(positions))
    median = {1: np.full(shape, np.nan), -1: np.full(shape, np.nan)}
    error = {1: np.full(shape, np.nan), -1: np.full(shape, np.nan)}
    for i in range(len(table)):
        j = step_row[int(table.step[i])]
        k = pos_col[int(table.position_index[i])]
        sign = int(table.direction[i])
        median[sign][j, k] = table.median[i]
        n = max(int(table.n[i]), 1)
        std = table.std[i] if np.isfinite(table.std[i]) else np.nan
        error[sign][j, k] = _MEDIAN_SE_FACTOR * std / math.sqrt(n)
    both = np.isfinite(median[1]) & np.isfinite(median[-1])
    # Both directions: the half difference, free of any offset; else the magnitude.
    values = np.where(
        both,
        (median[1] - median[-1]) / 2,
        np.where(np.isfinite(median[1]), median[1], -median[-1]),
    )
    noise = np.where(
        both,
        0.5 * np.sqrt(error[1] ** 2 + error[-1] ** 2),
        np.where(np.isfinite(median[1]), error[1], error[-1]),
    )
    velocities = []
    for s in steps:
        speeds = np.abs(table.velocity_mm_min[table.step == s])
        velocities.append(float(np.median(speeds)))
    travel = facts.travel_mm
    if travel is None:
        centres = [c.centre for c in segmentation.positions]
        travel = (min(centres), max(centres))
    noise_arg = noise if np.isfinite(noise[np.isfinite(values)]).all() else None
    return position_dependency(
        [position_mm[p] for p in positions],
        velocities,
        values,
        travel_mm=travel,
        fixed_bearing_end=facts.fixed_bearing_end or "min",
        noise=noise_arg,
    )


def analyze_axis(
    recording: Recording,
    axis: str,
    *,
    schedule: Schedule | None = None,
    machine: MachineConfig | None = None,
    settings: AnalysisSettings | None = None,
    progress: Progress | None = None,
) -> AxisResult:
    """Analyse one axis of a recording; see :func:`analyze`.

    ``progress`` is called with (stage, fraction of this axis done).

    Raises:
        RecordingError: The axis lacks current or velocity, or no window was found.
    """
    settings = settings or AnalysisSettings()
    report: Progress = progress or _quiet
    channels = recording.channel_names
    missing = [
        f"{axis}_{signal}"
        for signal in ("current_a", "velocity_mm_min")
        if f"{axis}_{signal}" not in channels
    ]
    if missing:
        raise RecordingError(
            f"{recording.directory}: axis {axis} cannot be analysed without "
            f"{' and '.join(missing)}; the friction analysis needs the motor current and "
            f"the actual velocity of every axis (recorded: {', '.join(channels)})"
        )
    summary = None
    if schedule is not None:
        summary = next((a for a in schedule.axes if a.name == axis), None)
    facts = _axis_facts(axis, recording, machine, summary)
    report(f"axis {axis}: windows", 0.0)
    try:
        segmentation = windows_of(
            recording, axis, schedule=schedule, settings=settings.segment_settings()
        )
    except RecordingError as exc:
        raise RecordingError(f"{recording.directory}: {exc.message}", exc.problems) from exc
    report(f"axis {axis}: friction table", 0.1)
    table = friction_table(
        axis,
        recording.column(f"{axis}_current_a"),
        segmentation.windows,
        velocity_mm_min=recording.column(f"{axis}_velocity_mm_min"),
        velocity_tolerance=settings.velocity_tolerance,
        velocity_floor_mm_min=settings.velocity_floor_mm_min,
        torque_constant_nm_per_a=facts.torque_constant_nm_per_a,
    )
    if len(table) == 0:
        raise RecordingError(
            f"{recording.directory}: axis {axis}: {len(segmentation.windows)} windows found, "
            "but no sample in them has a finite current and a velocity within the tolerance"
        )
    warnings = [*segmentation.warnings, *facts.warnings]
    if facts.torque_constant_nm_per_a is None:
        warnings.append("no torque constant (recording, machine file or schedule): friction in A")
    if facts.fixed_bearing_end is None:
        warnings.append("fixed-bearing end unknown: taken as the min end of the travel")
    if facts.travel_mm is None:
        warnings.append("travel unknown: taken as the span of the measuring positions")

    position_mm = {c.index: c.centre for c in segmentation.positions}
    positions: list[PositionResult] = []
    offsets: list[tuple[float, OffsetResult]] = []
    for number, index in enumerate(sorted(position_mm)):
        report(
            f"axis {axis}: fits at {position_mm[index]:g} mm",
            0.15 + 0.8 * number / len(position_mm),
        )
        directions: dict[Literal["positive", "negative"], DirectionResult | None] = {}
        points: dict[int, list[Point]] = {}
        for sign, key in _DIRECTIONS:
            points[sign] = table.points(index, sign)
            if not points[sign]:
                directions[key] = None
                continue
            linear, stribeck, extended = fit_direction(points[sign], sign)
            directions[key] = DirectionResult(
                points=points[sign], fit=linear, stribeck=stribeck, extended=extended
            )
        if not points[1] and not points[-1]:
            continue
        if points[1] and points[-1]:
            offset = separate_offset(points[1], points[-1])
            if offset is not None:
                offsets.append((position_mm[index], offset))
        positions.append(
            PositionResult(
                position_mm=position_mm[index], position_index=index, directions=directions
            )
        )
    offset = _combine_offsets(offsets, facts.vertical)
    if facts.vertical and offset is None:
        warnings.append(
            "vertical axis measured in one direction only: gravity is not separated from "
            "friction (measure both directions)"
        )
    report(f"axis {axis}: position dependency", 0.95)
    dependency = _dependency(table, segmentation, facts, position_mm)
    if dependency is None:
        warnings.append("a single measuring position: no position dependency")
    return AxisResult(
        quantity=table.quantity,
        unit=table.unit,
        torque_constant_nm_per_a=facts.torque_constant_nm_per_a,
        travel_mm=facts.travel_mm,
        fixed_bearing_end=facts.fixed_bearing_end,
        vertical=facts.vertical,
        screw_lead_mm=facts.screw_lead_mm,
        window_source=segmentation.source,
        windows=len(segmentation.windows),
        samples_used=table.samples,
        positions=positions,
        offset=offset,
        position_dependency=dependency,
        warnings=list(dict.fromkeys(warnings)),
    )


def analyze(
    recording: Recording,
    *,
    schedule: Schedule | None = None,
    machine: MachineConfig | None = None,
    settings: AnalysisSettings | None = None,
    progress: Progress | None = None,
) -> Results:
    """Analyse every axis of a recording: friction per position, direction and velocity.

    Args:
        recording: The recording (recorded, imported or synthetic).
        schedule: The schedule.json of the program that ran: labels every
            window with its step, position and direction, and tells rapids
            from windows. Without it, steps and positions are clustered.
        machine: The machine file: torque constant, screw lead, travel,
            fixed-bearing end and vertical axes where the recording lacks them.
        settings: How windows are found; :class:`AnalysisSettings` defaults.
        progress: Called with (stage, fraction done in 0..1).

    Returns:
        The results, ready for :func:`write_results`.

    Raises:
        RecordingError: The recording has no axis with current and velocity,
            an axis lacks one of them, or no window is found on an axis (the
            message says what was tried).
    """
    settings = settings or AnalysisSettings()
    axes = recording.axes
    if not axes:
        raise RecordingError(f"{recording.directory}: the recording has no channels")
    report: Progress = progress or _quiet
    common: list[str] = []
    if (
        schedule is not None
        and recording.meta.config_hash is not None
        and schedule.config_hash != recording.meta.config_hash
    ):
        common.append(
            f"the schedule belongs to another program (config hash {schedule.config_hash}, "
            f"the recording's {recording.meta.config_hash})"
        )
    if schedule is not None:
        planned = {a.name for a in schedule.axes}
        for name in axes:
            if name not in planned:
                common.append(f"axis {name} is not in the schedule")
    results: dict[str, AxisResult] = {}
    for number, name in enumerate(axes):
        log.info("analysing axis %s of %s", name, recording.directory)

        def axis_progress(stage: str, fraction: float, number: int = number) -> None:
            report(stage, (number + fraction) / len(axes))

        result = analyze_axis(
            recording,
            name,
            schedule=schedule,
            machine=machine,
            settings=settings,
            progress=axis_progress,
        )
        if common:
            result = result.model_copy(update={"warnings": [*common, *result.warnings]})
        results[name] = result
    report("done", 1.0)
    meta = recording.meta
    return Results(
        created_utc=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        recording=RecordingInfo(
            directory=str(recording.directory),
            machine=meta.machine,
            start_utc=meta.start_utc,
            config_hash=meta.config_hash,
            source=meta.source,
        ),
        settings=settings.model_dump(),
        axes=results,
    )


def write_results(results: Results, path: str | os.PathLike[str]) -> Path:
    """Write ``results.json`` atomically: a reader sees the old file or the new one, whole.

    Raises:
        OutputError: The file cannot be written.
    """
    target = Path(path)
    tmp = target.with_name(f".{target.name}.tmp")
    text = results.model_dump_json(indent=2)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with tmp.open("w", encoding="utf-8") as file:
            file.write(text + "\n")
            file.flush()
            os.fsync(file.fileno())
        tmp.replace(target)
    except OSError as exc:
        with_tmp = tmp.exists()
        if with_tmp:
            tmp.unlink(missing_ok=True)
        raise OutputError(f"{target}: cannot be written ({exc.strerror or exc})") from exc
    log.info("wrote %s", target)
    return target


def load_results(path: str | os.PathLike[str]) -> Results:
    """Read a ``results.json`` written by :func:`write_results`.

    Raises:
        ConfigError: The file is missing, not JSON, not an ncmeasure results
            file, of another format version, or not valid (one line per problem).
    """
    source = Path(path)
    try:
        data = json.loads(source.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{source}: no such results file") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{source}: cannot be read ({exc})") from exc
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{source}: not a results file (not valid JSON: {exc})") from exc
    if not isinstance(data, dict) or data.get("format") != RESULTS_FORMAT:
        found = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise ConfigError(
            f"{source}: not an ncmeasure results file (format is {found!r}, expected "
            f"{RESULTS_FORMAT!r}; `ncmeasure analyze` writes one)"
        )
    version = data.get("format_version")
    if version != RESULTS_FORMAT_VERSION:
        hint = (
            "update ncmeasure"
            if isinstance(version, int) and version > RESULTS_FORMAT_VERSION
            else "analyse the recording again"
        )
        raise ConfigError(
            f"{source}: results format_version {version!r}, this ncmeasure reads "
            f"{RESULTS_FORMAT_VERSION}; {hint}"
        )
    try:
        return Results.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(
            f"{source}: not a valid results file", format_validation_error(exc)
        ) from exc
