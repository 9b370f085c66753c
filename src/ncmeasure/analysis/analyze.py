"""The analysis of one recording: windows -> friction table -> fits -> diagnosis -> Results.

:func:`analyze` runs the whole method (method.md, "The analysis") on every
recorded axis::

    recording = read_recording("run1")
    results = analyze(recording, schedule=load_schedule("programs/schedule.json"),
                      machine=load_machine("machine.toml"))
    write_results(results, "run1.results.json")

Per axis: the constant-velocity windows (:mod:`~ncmeasure.analysis.windows.finder`),
the friction table (:mod:`~ncmeasure.analysis.friction.table`), per position and
direction the Coulomb + viscous and Stribeck fits
(:func:`~ncmeasure.analysis.friction.fit.fit_direction`), with both directions the
direction-independent offset (:func:`~ncmeasure.analysis.friction.fit.separate_offset`),
and over positions × velocities the position dependency with its likely
assembly causes (:func:`~ncmeasure.analysis.judgement.diagnosis.position_dependency`).

What the recording's ``meta.json`` says about an axis (torque constant,
travel, fixed-bearing end, vertical, screw lead) wins; the machine file,
then the schedule, supply what it lacks.
:func:`~ncmeasure.formats.results.write_results` and
:func:`~ncmeasure.formats.results.load_results` write and read ``results.json``.
"""

from __future__ import annotations

import datetime as dt
import functools
import logging
import math
import os
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.friction.fit import fit_direction, separate_offset
from ncmeasure.analysis.friction.table import FrictionTable, window_table
from ncmeasure.analysis.judgement.diagnosis import position_dependency
from ncmeasure.analysis.judgement.verdict import axis_verdict
from ncmeasure.analysis.windows.chunked import SlicedFinder
from ncmeasure.analysis.windows.finder import Segmentation, SegmentSettings, find_windows, quantum
from ncmeasure.analysis.windows.scan import axes_statistics
from ncmeasure.analysis.windows.streaming import run_tasks
from ncmeasure.analysis.windows.watch import AxisWindows, OnWindows, Reader, Watchers
from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.formats.results import (
    AxisResult,
    DirectionResult,
    OffsetResult,
    Point,
    PositionDependency,
    PositionResult,
    RecordingInfo,
    Results,
    Verdict,
)
from ncmeasure.formats.schedule import AxisSummary, Schedule
from ncmeasure.recording import SAMPLES_FILE, Recording, RecordingHead, RowChunk, iter_chunks
from ncmeasure.samples import LinkEvent
from ncmeasure.validity import Implausible

__all__ = [
    "AnalysisSettings",
    "AxisFacts",
    "analyze",
    "analyze_axis",
]

log = logging.getLogger(__name__)

Progress = Callable[[str, float], None]

CHUNK_ROWS = 1 << 16
"""Rows per chunk where a recording is read chunk by chunk (about 0.5 MiB per channel)."""

FloatArray = NDArray[np.float64]
_DIRECTIONS: tuple[tuple[Literal[1, -1], Literal["positive", "negative"]], ...] = (
    (1, "positive"),
    (-1, "negative"),
)
#: Standard error of a median of normal samples, relative to std/√n.


class AnalysisSettings(SegmentSettings):
    """How the analysis finds windows: every setting of :class:`SegmentSettings`.

    The defaults suit ncmeasure's own programs and foreign recordings from 1 to
    100 ms per sample. They are written into ``results.json`` (``settings``),
    so a result says how it was made. ``ncmeasure analyze --set key=value``
    sets any of them by the same names.
    """


@dataclass
class AxisFacts:
    """What the analysis knows about an axis besides its samples, and from where."""

    name: str
    torque_constant_nm_per_a: float | None = None
    screw_lead_mm: float | None = None
    travel_mm: tuple[float, float] | None = None
    fixed_bearing_end: Literal["min", "max"] | None = None
    vertical: bool | None = None
    rated_current_a: float | None = None
    max_velocity_mm_min: float | None = None
    rapid_velocity_mm_min: float | None = None
    warnings: list[str] = field(default_factory=list)


def _quiet(stage: str, fraction: float) -> None:
    """The progress callback that reports nothing."""


_FACT_KEYS = (
    "torque_constant_nm_per_a",
    "screw_lead_mm",
    "travel_mm",
    "fixed_bearing_end",
    "vertical",
    "rated_current_a",
    "max_velocity_mm_min",
    "rapid_velocity_mm_min",
)


def _axis_facts(
    name: str,
    recording: Recording | RecordingHead,
    machine: MachineConfig | None,
    summary: AxisSummary | None,
) -> AxisFacts:
    """Merge the axis data: recording first, then machine file, then schedule."""
    facts = AxisFacts(name)
    sources: list[tuple[str, Mapping[str, Any]]] = []
    for entry in recording.meta.axes:
        if entry.name == name:
            sources.append(("the recording", entry.model_dump()))
    if machine is not None:
        for axis in machine.axes:
            if axis.name == name:
                sources.append(
                    (
                        "the machine file",
                        {**axis.model_dump(), "rapid_velocity_mm_min": axis.rapid_mm_min},
                    )
                )
    if summary is not None:
        sources.append(("the schedule", summary.model_dump()))
    for key in _FACT_KEYS:
        found: list[tuple[str, Any]] = [
            (where, data[key]) for where, data in sources if data.get(key) is not None
        ]
        if not found:
            continue
        where, value = found[0]
        if key == "travel_mm":
            value = (float(value[0]), float(value[1]))
        setattr(facts, key, value)
        if key in ("rated_current_a", "max_velocity_mm_min", "rapid_velocity_mm_min"):
            continue  # limits for plausibility only: the first source is enough
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
        # Positions scattering more than their errors say widen the error accordingly.
        chi2 = float(np.sum(weight * (values - value) ** 2)) / (len(values) - 1)
        stderr: float | None = float(math.sqrt(max(1.0, chi2) / float(np.sum(weight))))
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
    offset: OffsetResult | None,
    own: Mapping[int, OffsetResult],
) -> tuple[PositionDependency | None, list[str]]:
    """Position dependency over positions × velocity steps of friction magnitudes.

    Every cell is friction, free of the offset: the half difference
    (T₊ − T₋)/2 where both directions were measured, else the one direction's
    magnitude with the offset taken out, direction × (T − o): the position's own
    offset where it was measured in both directions at other speeds, else the
    axis' offset. Without an
    offset a cell of one direction is left out when other cells have both (it
    would mix gravity into some cells only) or the axis is vertical (gravity
    would pass for friction); it is kept only where no cell has both directions
    on a horizontal axis, all cells then of one kind.
    """
    notes: list[str] = []
    positions = sorted(position_mm)
    steps = sorted({int(s) for s in table.step})
    if len(positions) < 2 or not steps:
        return None, notes
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
        error[sign][j, k] = table.stderr[i] if np.isfinite(table.stderr[i]) else np.nan
    both = np.isfinite(median[1]) & np.isfinite(median[-1])
    single_pos = np.isfinite(median[1]) & ~both
    single_neg = np.isfinite(median[-1]) & ~both
    values = np.where(both, (median[1] - median[-1]) / 2, np.nan)
    noise = np.where(both, 0.5 * np.sqrt(error[1] ** 2 + error[-1] ** 2), np.nan)
    singles = int(np.count_nonzero(single_pos | single_neg))
    if offset is not None:
        chosen = [own.get(p, offset) for p in positions]
        shift = np.array([o.value for o in chosen])[None, :]
        shift_se = np.array([o.stderr or 0.0 for o in chosen])[None, :]
        values = np.where(single_pos, median[1] - shift, values)
        values = np.where(single_neg, shift - median[-1], values)
        noise = np.where(single_pos, np.hypot(error[1], shift_se), noise)
        noise = np.where(single_neg, np.hypot(error[-1], shift_se), noise)
        if singles and both.any():
            notes.append(
                f"{singles} cell(s) measured in one direction only: the offset "
                f"({offset.value:.4g}) taken out of them for the position dependency"
            )
    elif facts.vertical and singles:
        notes.append(
            f"{singles} cell(s) measured in one direction only on a vertical axis without a "
            "separated offset: left out of the position dependency (gravity)"
        )
    elif both.any() and singles:
        notes.append(
            f"{singles} cell(s) measured in one direction only: left out of the position "
            "dependency (without an offset they would not compare with the others)"
        )
    elif singles:
        values = np.where(single_pos, median[1], np.where(single_neg, -median[-1], values))
        noise = np.where(single_pos, error[1], np.where(single_neg, error[-1], noise))
    velocities = []
    for s in steps:
        speeds = np.abs(table.velocity_mm_min[table.step == s])
        velocities.append(float(np.median(speeds)))
    travel = facts.travel_mm
    if travel is None:
        centres = [c.centre for c in segmentation.positions]
        travel = (min(centres), max(centres))
    noise_arg = noise if np.isfinite(noise[np.isfinite(values)]).all() else None
    dependency = position_dependency(
        [position_mm[p] for p in positions],
        velocities,
        values,
        travel_mm=travel,
        fixed_bearing_end=facts.fixed_bearing_end or "min",
        noise=noise_arg,
        numbers=[p + 1 for p in positions],
    )
    return dependency, notes


_SIGNALS_CHECKED = ("current_a", "velocity_mm_min", "position_mm", "velocity_cmd_mm_min")


def _checker(channel_names: Sequence[str], axis: str, facts: AxisFacts) -> Implausible:
    """The implausibility check of the axis' channels (no-value codes, beyond its range)."""
    names = {
        f"{axis}_{signal}": signal
        for signal in (*_SIGNALS_CHECKED, "marker")
        if f"{axis}_{signal}" in channel_names
    }
    limits = {"rated_current_a": facts.rated_current_a, "max_velocity_mm_min": None}
    if facts.max_velocity_mm_min is not None:
        limits["max_velocity_mm_min"] = facts.max_velocity_mm_min
    return Implausible.for_channels(names, dict.fromkeys(names, limits))


def _implausible(checker: Implausible, meta: RecordingMeta) -> tuple[dict[str, int], list[str]]:
    """Counts and lines of the values left out, with those an import left out (meta.json)."""
    counts = dict(checker.counts)
    lines = checker.lines()
    # An import already left such values out (NaN): its count travels in meta.json.
    imported = meta.link.get("implausible")
    if isinstance(imported, dict):
        for name, count in imported.items():
            if name in checker.limits and isinstance(count, int) and count > 0:
                counts[name] = counts.get(name, 0) + count
                lines.append(
                    f"{name}: {count} value(s) left out at the import as not physically "
                    "possible (a 'no value' code such as -999999, or beyond the axis' range)"
                )
    return counts, lines


def _signals(
    recording: Recording, axis: str, facts: AxisFacts
) -> tuple[dict[str, FloatArray], dict[str, int], list[str]]:
    """The axis' channels with the values no drive can report (no-value codes) as NaN."""
    checker = _checker(recording.channel_names, axis, facts)
    cleaned = {
        name.removeprefix(f"{axis}_"): checker.clean(name, recording.time_s, recording.column(name))
        for name in checker.limits
    }
    counts, lines = _implausible(checker, recording.meta)
    return cleaned, counts, lines


def _creep_mm_min(time_s: FloatArray, position_mm: FloatArray) -> float:
    """How fast the position's whole span would be covered over the recording, in mm/min."""
    finite = np.isfinite(position_mm)
    duration = float(time_s[-1] - time_s[0]) if len(time_s) > 1 else 0.0
    if duration <= 0 or not finite.any():
        return 0.0
    return float(np.ptp(position_mm[finite])) / duration * 60.0


def _dead_channel(axis: str, signal: str, values: FloatArray, unit: str) -> str | None:
    """Why a channel holds no information (all NaN, or one value in every row), else None."""
    finite = values[np.isfinite(values)]
    if len(finite) == 0:
        return _dead_range(axis, signal, len(values), 0, math.nan, math.nan, unit)
    return _dead_range(
        axis, signal, len(values), len(finite), float(finite.min()), float(finite.max()), unit
    )


def _dead_range(
    axis: str, signal: str, rows: int, finite: int, low: float, high: float, unit: str
) -> str | None:
    """:func:`_dead_channel` from the count and range of the finite values."""
    name = f"{axis}_{signal}"
    if finite == 0:
        return f"{name} holds no valid value: the channel is empty"
    if rows > 1 and low == high:
        return (
            f"{name} is {low:g} {unit} in every row: a dead channel (the drive "
            "does not report it, or the wrong object or register is read)"
        )
    return None


def _check_channels(axis: str, channels: Sequence[str]) -> None:
    missing = [
        f"{axis}_{signal}"
        for signal in ("current_a", "velocity_mm_min")
        if f"{axis}_{signal}" not in channels
    ]
    if missing:
        raise RecordingError(
            f"axis {axis} cannot be analysed without {' and '.join(missing)}; the friction "
            "analysis needs the motor current and the actual velocity of every axis "
            f"(recorded: {', '.join(channels)})"
        )


def _summary(schedule: Schedule | None, axis: str) -> AxisSummary | None:
    if schedule is None:
        return None
    return next((a for a in schedule.axes if a.name == axis), None)


def _check_velocity(axis: str, dead: str | None, moving: bool, first: float | None) -> None:
    """A dead velocity channel stops the axis, unless it reads 0 and nothing moves."""
    if dead is not None and (moving or first is None or first != 0.0):
        raise RecordingError(dead)


def analyze_axis(
    recording: Recording,
    axis: str,
    *,
    schedule: Schedule | None = None,
    machine: MachineConfig | None = None,
    settings: AnalysisSettings | None = None,
    progress: Progress | None = None,
    gap_share: float = 0.0,
) -> AxisResult:
    """Analyse one axis of a recording in memory; see :func:`analyze`.

    ``progress`` is called with (stage, fraction of this axis done).

    Raises:
        RecordingError: The axis cannot be analysed: it lacks current or
            velocity, a channel is dead (one value in every row), it did not
            move, or no window was found. The message says why in words.
    """
    return _analyze_axis(
        recording,
        axis,
        schedule=schedule,
        machine=machine,
        settings=settings,
        progress=progress,
        gap_share=gap_share,
    )[0]


def _analyze_axis(
    recording: Recording,
    axis: str,
    *,
    schedule: Schedule | None = None,
    machine: MachineConfig | None = None,
    settings: AnalysisSettings | None = None,
    progress: Progress | None = None,
    gap_share: float = 0.0,
) -> tuple[AxisResult, list[tuple[float, float]]]:
    """:func:`analyze_axis`, and the (first, last) sample time of every window used."""
    settings = settings or AnalysisSettings()
    report: Progress = progress or _quiet
    _check_channels(axis, recording.channel_names)
    summary = _summary(schedule, axis)
    facts = _axis_facts(axis, recording, machine, summary)
    signals, implausible_counts, implausible_lines = _signals(recording, axis, facts)
    current = signals["current_a"]
    velocity = signals["velocity_mm_min"]
    position = signals.get("position_mm")
    finite = velocity[np.isfinite(velocity)]
    _check_velocity(
        axis,
        _dead_channel(axis, "velocity_mm_min", velocity, "mm/min"),
        position is not None
        and _creep_mm_min(recording.time_s, position) > settings.standstill_mm_min,
        float(finite[0]) if len(finite) else None,
    )
    report(f"axis {axis}: windows", 0.0)
    segmentation = find_windows(
        axis,
        recording.time_s,
        velocity,
        position_mm=position,
        command_mm_min=signals.get("velocity_cmd_mm_min"),
        marker=signals.get("marker"),
        schedule=schedule,
        settings=settings,
        rapid_mm_min=facts.rapid_velocity_mm_min,
    )
    result = _finish_axis(
        axis,
        facts,
        summary,
        segmentation,
        [current[w.start : w.stop] for w in segmentation.windows],
        current_dead=_dead_channel(axis, "current_a", current, "A"),
        current_quantum=quantum(current),
        implausible_counts=implausible_counts,
        implausible_lines=implausible_lines,
        report=report,
        gap_share=gap_share,
    )
    time_s = recording.time_s
    return result, [
        (float(time_s[w.start]), float(time_s[w.stop - 1])) for w in segmentation.windows
    ]


def _finish_axis(
    axis: str,
    facts: AxisFacts,
    summary: AxisSummary | None,
    segmentation: Segmentation,
    window_current: Sequence[FloatArray],
    *,
    current_dead: str | None,
    current_quantum: float,
    implausible_counts: dict[str, int],
    implausible_lines: list[str],
    report: Progress,
    gap_share: float,
) -> AxisResult:
    """An axis' result from its windows and their current: table, fits, dependency, verdict."""
    dead = current_dead
    if dead is None and segmentation.windows:
        in_windows = np.concatenate(window_current)
        dead = _dead_channel(axis, "current_a", in_windows, "A")
        if dead is not None:
            dead = dead.replace("in every row", "in every window")
    if dead is not None:
        raise RecordingError(dead)
    report(f"axis {axis}: friction table", 0.1)
    table = window_table(
        axis,
        window_current,
        segmentation.windows,
        torque_constant_nm_per_a=facts.torque_constant_nm_per_a,
        current_quantum_a=current_quantum,
    )
    if len(table) == 0:
        raise RecordingError(
            f"axis {axis}: {len(segmentation.windows)} windows found, but no finite current "
            "in any of them"
        )
    warnings = [*segmentation.warnings, *implausible_lines, *facts.warnings]
    if facts.torque_constant_nm_per_a is None:
        warnings.append("no torque constant (recording, machine file or schedule): friction in A")
    if facts.fixed_bearing_end is None:
        warnings.append("fixed-bearing end unknown: taken as the min end of the travel")
    if facts.travel_mm is None:
        warnings.append("travel unknown: taken as the span of the measuring positions")

    position_mm = {c.index: c.centre for c in segmentation.positions if c.windows > 0}
    empty = [c.centre for c in segmentation.positions if c.windows == 0]
    points: dict[int, dict[int, list[Point]]] = {
        index: {sign: table.points(index, sign) for sign, _ in _DIRECTIONS}
        for index in sorted(position_mm)
    }
    own: dict[int, OffsetResult] = {}
    for index, by_sign in points.items():
        if by_sign[1] and by_sign[-1]:
            found = separate_offset(by_sign[1], by_sign[-1])
            if found is not None:
                own[index] = found
    offset = _combine_offsets([(position_mm[i], o) for i, o in own.items()], facts.vertical)
    if facts.vertical and offset is None:
        warnings.append(
            "vertical axis measured in one direction only: gravity is not separated from "
            "friction (measure both directions)"
        )
    positions: list[PositionResult] = []
    for number, (index, by_sign) in enumerate(points.items()):
        report(
            f"axis {axis}: fits at {position_mm[index]:g} mm",
            0.15 + 0.8 * number / len(points),
        )
        if not by_sign[1] and not by_sign[-1]:
            empty.append(position_mm[index])
            continue
        # A position's own offset where both directions were measured there (gravity of
        # a counterbalanced axis may change along the stroke), else the axis' offset.
        here = own.get(index, offset)
        directions: dict[Literal["positive", "negative"], DirectionResult | None] = {
            key: fit_direction(by_sign[sign], sign, offset=here, coarse=segmentation.coarse)
            if by_sign[sign]
            else None
            for sign, key in _DIRECTIONS
        }
        positions.append(
            PositionResult(
                position_mm=position_mm[index], position_index=index, directions=directions
            )
        )
    report(f"axis {axis}: position dependency", 0.95)
    dependency, notes = _dependency(table, segmentation, facts, position_mm, offset, own)
    warnings.extend(notes)
    if dependency is None:
        warnings.append("a single measuring position: no position dependency")
    result = AxisResult(
        verdict=Verdict(level="ok", reason="", action=""),
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
        sample_period_s=segmentation.sample_period_s,
        velocity_quantum_mm_min=segmentation.velocity_quantum_mm_min,
        current_quantum_a=current_quantum,
        coarse=segmentation.coarse,
        implausible_values=implausible_counts,
        positions=positions,
        offset=offset,
        position_dependency=dependency,
        warnings=list(dict.fromkeys(warnings)),
    )
    planned = len(summary.windows) if summary is not None else None
    verdict = axis_verdict(
        result, planned_windows=planned, gap_share=gap_share, empty_positions=empty
    )
    return result.model_copy(update={"verdict": verdict})


def recording_gaps(recording: Recording) -> tuple[int, int, int]:
    """Gaps of a recording: holes in its time axis, samples lost in them, gap events.

    A hole is a time step longer than 1.5 nominal periods; it lost
    round(step / period) − 1 samples. Where the link reported more lost samples
    in its gap events than the time axis shows (a gap at the very end), the
    larger count is taken.
    """
    period = recording.meta.nominal_period_s
    steps = np.diff(recording.time_s)
    holes = steps > 1.5 * period
    lost = int(np.sum(np.round(steps[holes] / period) - 1)) if holes.any() else 0
    return _with_events(int(np.count_nonzero(holes)), lost, recording.events)


def _with_events(holes: int, lost: int, events: Sequence[LinkEvent]) -> tuple[int, int, int]:
    gap_events = [e for e in events if e.kind == "gap"]
    reported = sum(e.lost_samples for e in gap_events)
    return max(holes, len(gap_events)), max(lost, reported), len(gap_events)


def _holes_task(period: float) -> Generator[Callable[[RowChunk], None], None, tuple[int, int]]:
    """Holes of the time axis and the samples lost in them, chunk by chunk (as recording_gaps)."""
    found = {"holes": 0, "lost": 0}
    last: list[float] = []

    def feed(chunk: RowChunk) -> None:
        times = chunk.time_s
        if len(times) == 0:
            return
        steps = np.diff(np.concatenate((last[-1:], times)))
        holes = steps > 1.5 * period
        if holes.any():
            found["holes"] += int(np.count_nonzero(holes))
            found["lost"] += int(np.sum(np.round(steps[holes] / period) - 1))
        last[:] = [float(times[-1])]

    yield feed
    return found["holes"], found["lost"]


class _Streamed:
    """The axes of a recording analysed chunk by chunk, memory bounded by their windows.

    The constructor reads the recording in a few passes shared by all axes
    (:mod:`~ncmeasure.analysis.windows.scan`, then :mod:`~ncmeasure.analysis.windows.chunked`);
    :meth:`axis` then reads the slices of each axis' windows and gives the same
    result as :func:`analyze_axis` on the whole recording. What stops an axis
    early is kept and raised by :meth:`axis`, in the order analyze_axis meets it.
    """

    def __init__(
        self,
        head: RecordingHead,
        axes: Sequence[str],
        schedule: Schedule | None,
        machine: MachineConfig | None,
        settings: AnalysisSettings,
        rows: int,
        progress: Progress,
    ) -> None:
        self.head = head
        self.settings = settings
        self.errors: dict[str, Exception] = {}
        self.facts: dict[str, AxisFacts] = {}
        self.summary: dict[str, AxisSummary | None] = {}
        self.checker: dict[str, Implausible] = {}
        self.finders: dict[str, SlicedFinder] = {}
        names = head.channel_names
        ready: list[str] = []
        for axis in axes:
            try:
                _check_channels(axis, names)
            except RecordingError as exc:
                self.errors[axis] = exc
                continue
            self.summary[axis] = _summary(schedule, axis)
            self.facts[axis] = _axis_facts(axis, head, machine, self.summary[axis])
            self.checker[axis] = _checker(names, axis, self.facts[axis])
            ready.append(axis)
        bounds = {n: b for c in self.checker.values() for n, b in c.limits.items()}
        channels = tuple(bounds)
        column = {name: k for k, name in enumerate(channels)}
        problems: list[list[str]] = [[]]
        verified: set[int] = set()  # large frames checked once for all passes
        # Tasks of on_windows ride along the readings after their axis' windows are found.
        self.watchers = Watchers(column)

        # Progress while reading: the pass and the share of its rows read so far.
        samples_bytes = (head.directory / SAMPLES_FILE).stat().st_size
        expected = max(1, samples_bytes // (8 * (1 + len(head.channels))))
        passes = [0]

        chunk_times: dict[int, float] = {}  # first row -> its time, of every chunk read

        def seen(chunk: RowChunk) -> None:
            if chunk.first == 0:
                passes[0] += 1
            if len(chunk.time_s):
                chunk_times[chunk.first] = float(chunk.time_s[0])
            done = (chunk.first + len(chunk.time_s)) / expected
            progress(f"reading the recording, pass {passes[0]}", min(1.0, done))

        def read() -> Iterator[RowChunk]:
            problems[0] = []
            for chunk in self.watchers.reading(
                iter_chunks(head.directory, rows, channels, problems=problems[0], verified=verified)
            ):
                seen(chunk)
                yield chunk

        def read_channels(
            wanted: tuple[str, ...], between_s: tuple[float, float] | None
        ) -> Iterator[RowChunk]:
            # With a stretch of time: from the last chunk that began before it (its
            # first row as the passes noted it; the frames before are not read) up
            # to the one that holds its end. Times increase strictly.
            first_row = 0
            if between_s is not None:
                begun = [row for row, t in chunk_times.items() if t < between_s[0]]
                first_row = max(begun, default=0)
            for chunk in iter_chunks(
                head.directory, rows, wanted, verified=verified, first_row=first_row
            ):
                if between_s is not None and len(chunk.time_s) and chunk.time_s[0] > between_s[1]:
                    return
                done = (chunk.first + len(chunk.time_s)) / expected
                progress("reading the recording once more", min(1.0, done))
                yield chunk

        self.read_channels = read_channels

        self.statistics = (
            axes_statistics(
                head.directory,
                ready,
                names,
                limits=bounds,
                rows=rows,
                verified=verified,
                on_chunk=seen,
            )
            if ready
            else {}
        )
        for axis in ready:
            try:
                self.finders[axis] = self._finder(axis, read, column, schedule)
            except (RecordingError, ValueError, IndexError, ArithmeticError) as exc:
                self.errors[axis] = exc
        agreeing = {a: f.agreement_task() for a, f in self.finders.items() if f.needs_agreement}
        if agreeing:
            run_tasks(read, agreeing)
        tasks: dict[str, Generator[Callable[[RowChunk], None], None, Any]] = {
            a: f.sweep_task() for a, f in self.finders.items()
        }
        tasks[""] = _holes_task(head.meta.nominal_period_s)
        found = run_tasks(read, tasks)
        holes, lost = found[""]
        first = next(iter(self.statistics.values()), None)
        if first is not None:
            self.rows, self.start_s, self.end_s = first.rows, first.start_s, first.end_s
        else:
            self.rows, self.start_s, self.end_s = _row_span(read)
        self.gaps = _with_events(holes, lost, head.events)
        head.samples_read(self.rows, problems[0])

    def _finder(
        self,
        axis: str,
        read: Callable[[], Iterator[RowChunk]],
        column: Mapping[str, int],
        schedule: Schedule | None,
    ) -> SlicedFinder:
        stats = self.statistics[axis]
        finite = stats.finite.get("velocity_mm_min", 0)
        low, high = stats.low["velocity_mm_min"], stats.high["velocity_mm_min"]
        moving = False
        if "position_mm" in stats.finite:
            duration = stats.end_s - stats.start_s if stats.rows > 1 else 0.0
            if duration > 0 and stats.finite["position_mm"]:
                span = stats.high["position_mm"] - stats.low["position_mm"]
                moving = span / duration * 60.0 > self.settings.standstill_mm_min
        _check_velocity(
            axis,
            _dead_range(axis, "velocity_mm_min", stats.rows, finite, low, high, "mm/min"),
            moving,
            low if finite else None,
        )
        return SlicedFinder(
            axis,
            stats,
            self.head.channel_names,
            self.checker[axis].limits,
            read,
            column,
            schedule,
            self.settings,
            self.facts[axis].rapid_velocity_mm_min,
        )

    def axis(
        self, axis: str, progress: Progress, gap_share: float
    ) -> tuple[AxisResult, list[tuple[float, float]]]:
        """The axis' result and window times, as :func:`_analyze_axis` gives them in memory."""
        if axis in self.errors:
            raise self.errors[axis]
        stats = self.statistics[axis]
        finder = self.finders[axis]
        progress(f"axis {axis}: windows", 0.0)
        try:
            segmentation = finder.run()
        except RecordingError:
            finder.release()
            raise
        checker = self.checker[axis]
        scanned = stats.implausible
        if scanned is not None:
            # In the channel order of the whole-array check, whatever order the chunks met them.
            checker.counts = {n: scanned.counts[n] for n in checker.limits if n in scanned.counts}
            checker.first = {n: scanned.first[n] for n in checker.limits if n in scanned.first}
        counts, lines = _implausible(checker, self.head.meta)
        window_current = [finder.window_current(w.start, w.stop) for w in segmentation.windows]
        times = [finder.window_times(w.start, w.stop) for w in segmentation.windows]
        finder.release()
        result = _finish_axis(
            axis,
            self.facts[axis],
            self.summary[axis],
            segmentation,
            window_current,
            current_dead=_dead_range(
                axis,
                "current_a",
                stats.rows,
                stats.finite.get("current_a", 0),
                stats.low.get("current_a", math.nan),
                stats.high.get("current_a", math.nan),
                "A",
            ),
            current_quantum=stats.current_quantum_a,
            implausible_counts=counts,
            implausible_lines=lines,
            report=progress,
            gap_share=gap_share,
        )
        return result, times


def _row_span(read: Callable[[], Iterator[RowChunk]]) -> tuple[int, float, float]:
    """Rows, first and last time of a recording (one pass)."""
    rows, start, end = 0, math.nan, math.nan
    for chunk in read():
        if len(chunk.time_s):
            if rows == 0:
                start = float(chunk.time_s[0])
            end = float(chunk.time_s[-1])
        rows += len(chunk.time_s)
    return rows, start, end


def analyze(
    recording: Recording | RecordingHead | str | os.PathLike[str],
    *,
    schedule: Schedule | None = None,
    machine: MachineConfig | None = None,
    settings: AnalysisSettings | None = None,
    axes: Sequence[str] | None = None,
    progress: Progress | None = None,
    rows: int = CHUNK_ROWS,
    window_times: dict[str, list[tuple[float, float]]] | None = None,
    on_windows: OnWindows | None = None,
) -> Results:
    """Analyse every axis of a recording: friction per position, direction and velocity.

    An axis that cannot be analysed (a missing or dead channel, an axis that
    did not move, no window) does not stop the others: it is listed in
    ``skipped`` with the reason.

    A recording given by its directory (or a :class:`RecordingHead`) is read
    chunk by chunk (``rows`` rows each) and never held whole: memory grows with
    the windows, not with the length (``ncmeasure analyze`` reads it so). A
    :class:`Recording` already in memory is analysed as it is. Both give the
    same results.

    Args:
        recording: The recording (recorded, imported or synthetic), or its directory.
        schedule: The schedule.json of the program that ran: labels every
            window with its step, position and direction, and tells rapids
            from windows. Without it, steps and positions are clustered.
        machine: The machine file: torque constant, screw lead, travel,
            fixed-bearing end and vertical axes where the recording lacks them.
        settings: How windows are found; :class:`AnalysisSettings` defaults.
        axes: Analyse only these axes (default: every recorded axis).
        progress: Called with (stage, fraction done in 0..1); while a recording
            is read chunk by chunk, with ``reading the recording, pass N`` and
            the share of that pass read.
        rows: Rows per chunk when the recording is read chunk by chunk.
        window_times: Receives, per analysed axis, the (first, last) sample time
            of every window the friction values come from (for the report's
            raw data, :func:`~ncmeasure.report.write_report`'s ``windows``).
        on_windows: Called with every analysed axis' windows; the task it
            returns is fed the recording's rows on the readings that follow
            (:mod:`~ncmeasure.analysis.windows.watch`; the report's
            :class:`~ncmeasure.report.traces.RawTraces`). Where no reading
            follows, the recording is read once more, only the channels the
            tasks need; a recording in memory is handed over whole.

    Returns:
        The results, ready for :func:`~ncmeasure.formats.results.write_results`.

    Raises:
        RecordingError: No axis could be analysed (the message lists why, axis
            by axis), or ``axes`` names an axis that was not recorded.
    """
    settings = settings or AnalysisSettings()
    head = (
        recording
        if isinstance(recording, Recording | RecordingHead)
        else RecordingHead.open(recording)
    )
    recorded = head.axes
    if not recorded:
        raise RecordingError(f"{head.directory}: the recording has no channels")
    if axes is not None:
        unknown = [a for a in axes if a not in recorded]
        if unknown:
            raise RecordingError(
                f"{head.directory}: axis {', '.join(unknown)} not recorded "
                f"(recorded: {', '.join(recorded)})"
            )
    chosen = tuple(dict.fromkeys(axes)) if axes is not None else recorded
    report: Progress = progress or _quiet
    common: list[str] = []
    if (
        schedule is not None
        and head.meta.config_hash is not None
        and schedule.config_hash != head.meta.config_hash
    ):
        common.append(
            f"the schedule belongs to another program (config hash {schedule.config_hash}, "
            f"the recording's {head.meta.config_hash})"
        )
    if schedule is not None:
        planned = {a.name for a in schedule.axes}
        for name in chosen:
            if name not in planned:
                common.append(f"axis {name} is not in the schedule")
    analyse: Callable[[str, Progress, float], tuple[AxisResult, list[tuple[float, float]]]]
    read_channels: Reader
    if isinstance(head, Recording):
        whole = head
        gaps, gap_samples, gap_events = recording_gaps(whole)
        samples = len(whole)
        start_s = float(whole.time_s[0]) if samples else math.nan
        end_s = float(whole.time_s[-1]) if samples else math.nan
        duration = end_s - start_s if samples else 0.0
        watchers = Watchers({})

        def read_channels(
            wanted: tuple[str, ...], between_s: tuple[float, float] | None
        ) -> Iterable[RowChunk]:
            index = [whole.channel_names.index(name) for name in wanted]
            return [RowChunk(0, whole.time_s, whole.values[:, index])]

        def analyse(
            name: str, axis_progress: Progress, gap_share: float
        ) -> tuple[AxisResult, list[tuple[float, float]]]:
            return _analyze_axis(
                whole,
                name,
                schedule=schedule,
                machine=machine,
                settings=settings,
                progress=axis_progress,
                gap_share=gap_share,
            )

    else:
        streamed = _Streamed(head, chosen, schedule, machine, settings, rows, report)
        gaps, gap_samples, gap_events = streamed.gaps
        samples = streamed.rows
        start_s, end_s = streamed.start_s, streamed.end_s
        duration = end_s - start_s if samples else 0.0
        analyse = streamed.axis
        watchers, read_channels = streamed.watchers, streamed.read_channels
    total = samples + gap_samples
    gap_share = gap_samples / total if total else 0.0
    if gaps:
        common.append(
            f"{gap_samples} samples lost in {gaps} gap(s) ({gap_share * 100:.2g} % of the "
            "recording): windows in them are shorter or missing"
        )
    results: dict[str, AxisResult] = {}
    skipped: dict[str, str] = {}
    details: list[str] = []
    for number, name in enumerate(chosen):
        log.info("analysing axis %s of %s", name, head.directory)

        def axis_progress(stage: str, fraction: float, number: int = number) -> None:
            report(stage, (number + fraction) / len(chosen))

        try:
            result, times = analyse(name, axis_progress, gap_share)
        except RecordingError as exc:
            reason = exc.message.removeprefix(f"axis {name}: ")
            skipped[name] = reason
            details.append(f"axis {name}: {reason}")
            details.extend(f"  {line}" for line in exc.problems)
            log.info("axis %s not analysed: %s", name, reason)
            continue
        except (ValueError, IndexError, ArithmeticError) as exc:
            # Data this analysis did not foresee must not take the other axes with it.
            log.debug("axis %s failed", name, exc_info=True)
            reason = (
                f"the analysis failed on this axis' data ({type(exc).__name__}: {exc}); "
                "please report it with the recording (--debug shows where)"
            )
            skipped[name] = reason
            details.append(f"axis {name}: {reason}")
            continue
        if common:
            result = result.model_copy(update={"warnings": [*common, *result.warnings]})
        results[name] = result
        if window_times is not None:
            window_times[name] = times
        if on_windows is not None:
            found = AxisWindows(name, tuple(times), samples, start_s, end_s)
            watchers.add(functools.partial(on_windows, found))
    if not results:
        raise RecordingError(f"{head.directory}: no axis could be analysed", details)
    watchers.finish(read_channels)
    report("done", 1.0)
    meta = head.meta
    return Results(
        created_utc=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        recording=RecordingInfo(
            directory=str(head.directory),
            machine=meta.machine,
            start_utc=meta.start_utc,
            config_hash=meta.config_hash,
            source=meta.source,
            status=meta.status,
            samples=samples,
            duration_s=duration,
            gaps=gaps,
            gap_samples=gap_samples,
            gap_share=gap_share,
            gap_events=gap_events,
        ),
        settings=settings.model_dump(),
        axes=results,
        skipped=skipped,
    )
