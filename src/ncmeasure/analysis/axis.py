"""One axis: what is known about it besides its samples, the checks, its result from its windows.

What the recording's ``meta.json`` says about an axis (torque constant,
travel, fixed-bearing end, vertical, screw lead) wins; the machine file, then
the schedule, supply what it lacks (:func:`axis_facts`). :func:`finish_axis`
turns the windows found and their current into the axis' result: the
friction table (:mod:`~ncmeasure.analysis.friction.table`), per position and
direction the Coulomb + viscous and Stribeck fits
(:func:`~ncmeasure.analysis.friction.fit.fit_direction`), with both directions
the direction-independent offset
(:func:`~ncmeasure.analysis.friction.fit.separate_offset`), over positions ×
velocities the position dependency with its likely assembly causes
(:func:`~ncmeasure.analysis.judgement.diagnosis.position_dependency`), and the
verdict.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from ncmeasure.analysis.friction.fit import fit_direction, separate_offset
from ncmeasure.analysis.friction.table import FrictionTable, window_table
from ncmeasure.analysis.judgement.diagnosis import position_dependency
from ncmeasure.analysis.judgement.verdict import axis_verdict
from ncmeasure.analysis.windows.model import Segmentation
from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordedAxis, RecordingMeta
from ncmeasure.formats.results import (
    AxisResult,
    DirectionResult,
    OffsetResult,
    Point,
    PooledFit,
    PositionDependency,
    PositionResult,
    Verdict,
)
from ncmeasure.formats.schedule import AxisSummary, Schedule
from ncmeasure.recording import Recording, RecordingHead
from ncmeasure.validity import Implausible

__all__ = [
    "AxisFacts",
    "AxisFound",
    "Progress",
    "axis_facts",
    "axis_summary",
    "check_channels",
    "check_velocity",
    "dead_channel",
    "dead_range",
    "finish_axis",
    "implausible_checker",
    "implausible_lines",
]

Progress = Callable[[str, float], None]

FloatArray = NDArray[np.float64]

POOL_BELOW_SPEEDS = 3
"""A direction at a position needs this many speeds for a line (Coulomb + viscous) of its
own; where no position holds that many, the positions are pooled per direction."""

_DIRECTIONS: tuple[tuple[Literal[1, -1], Literal["positive", "negative"]], ...] = (
    (1, "positive"),
    (-1, "negative"),
)


class AxisFacts(RecordedAxis):
    """What the analysis knows about an axis besides its samples: its mechanics and
    velocity limits as the recording, the machine file and the schedule state them,
    and where they disagree."""

    warnings: list[str] = Field(default_factory=list)


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


def axis_facts(
    name: str,
    recording: Recording | RecordingHead,
    machine: MachineConfig | None,
    summary: AxisSummary | None,
) -> AxisFacts:
    """Merge the axis data: recording first, then machine file, then schedule."""
    known: dict[str, Any] = {}
    warnings: list[str] = []
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
        known[key] = value
        if key in ("rated_current_a", "max_velocity_mm_min", "rapid_velocity_mm_min"):
            continue  # limits for plausibility only: the first source is enough
        for other, other_value in found[1:]:
            if key == "travel_mm":
                other_value = (float(other_value[0]), float(other_value[1]))
            if other_value != value:
                warnings.append(
                    f"{key} is {value} in {where} but {other_value} in {other}: {where} is used"
                )
    return AxisFacts(name=name, **known, warnings=warnings)


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
    # Positions compare only at matching speed and matching direction: one row per
    # step and kind of cell (both directions, positive only, negative only).
    kinds = np.where(both, 0, np.where(single_pos, 1, np.where(single_neg, -1, 2)))
    keep = np.isfinite(values)
    rows: list[tuple[int, int]] = [
        (j, kind)
        for j in range(len(steps))
        for kind in (0, 1, -1)
        if (keep[j] & (kinds[j] == kind)).any()
    ]
    grouped = np.full((len(rows), len(positions)), np.nan)
    grouped_noise = np.full((len(rows), len(positions)), np.nan)
    velocities = []
    for r, (j, kind) in enumerate(rows):
        cells = keep[j] & (kinds[j] == kind)
        grouped[r, cells] = values[j, cells]
        grouped_noise[r, cells] = noise[j, cells]
        speeds = np.abs(table.velocity_mm_min[table.step == steps[j]])
        velocities.append(float(np.median(speeds)))
    values, noise = grouped, grouped_noise
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


def implausible_checker(channel_names: Sequence[str], axis: str, facts: AxisFacts) -> Implausible:
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


def implausible_lines(
    checker: Implausible, meta: RecordingMeta
) -> tuple[dict[str, int], list[str]]:
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


def dead_channel(axis: str, signal: str, values: FloatArray, unit: str) -> str | None:
    """Why a channel holds no information (all NaN, or one value in every row), else None."""
    finite = values[np.isfinite(values)]
    if len(finite) == 0:
        return dead_range(axis, signal, len(values), 0, math.nan, math.nan, unit)
    return dead_range(
        axis, signal, len(values), len(finite), float(finite.min()), float(finite.max()), unit
    )


def dead_range(
    axis: str, signal: str, rows: int, finite: int, low: float, high: float, unit: str
) -> str | None:
    """:func:`dead_channel` from the count and range of the finite values."""
    name = f"{axis}_{signal}"
    if finite == 0:
        return f"{name} holds no valid value: the channel is empty"
    if rows > 1 and low == high:
        return (
            f"{name} is {low:g} {unit} in every row: a dead channel (the drive "
            "does not report it, or the wrong object or register is read)"
        )
    return None


def check_channels(axis: str, channels: Sequence[str]) -> None:
    """An axis needs its current and its actual velocity."""
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


def axis_summary(schedule: Schedule | None, axis: str) -> AxisSummary | None:
    """The axis' part of the schedule, if any."""
    if schedule is None:
        return None
    return next((a for a in schedule.axes if a.name == axis), None)


def check_velocity(axis: str, dead: str | None, moving: bool, first: float | None) -> None:
    """A dead velocity channel stops the axis, unless it reads 0 and nothing moves."""
    if dead is not None and (moving or first is None or first != 0.0):
        raise RecordingError(dead)


@dataclass
class AxisFound:
    """What the reading of a recording found for one axis: the inputs of :func:`finish_axis`.

    Attributes:
        segmentation: The windows.
        window_current: The current of every window (``stop − start`` samples each).
        window_times: (first, last) sample time of every window.
        current_dead: Why the current channel holds no information, else None.
        current_quantum_a: One count of the current (0: continuous).
        implausible_counts: Values left out per channel.
        implausible_lines: One sentence per channel with values left out.
    """

    segmentation: Segmentation
    window_current: list[FloatArray]
    window_times: list[tuple[float, float]]
    current_dead: str | None
    current_quantum_a: float
    implausible_counts: dict[str, int]
    implausible_lines: list[str]


def _check_current(axis: str, found: AxisFound) -> None:
    """A current dead in every row, or in every window, stops the axis."""
    dead = found.current_dead
    if dead is None and found.segmentation.windows:
        in_windows = np.concatenate(found.window_current)
        dead = dead_channel(axis, "current_a", in_windows, "A")
        if dead is not None:
            dead = dead.replace("in every row", "in every window")
    if dead is not None:
        raise RecordingError(dead)


def _table(axis: str, facts: AxisFacts, found: AxisFound) -> FrictionTable:
    """The friction table of the axis' windows (at least one row)."""
    segmentation = found.segmentation
    table = window_table(
        axis,
        found.window_current,
        segmentation.windows,
        torque_constant_nm_per_a=facts.torque_constant_nm_per_a,
        current_quantum_a=found.current_quantum_a,
    )
    if len(table) == 0:
        raise RecordingError(
            f"axis {axis}: {len(segmentation.windows)} windows found, but no finite current "
            "in any of them"
        )
    return table


def _what_is_missing(facts: AxisFacts) -> list[str]:
    """Warnings for the axis data that no source gave."""
    warnings = []
    if facts.torque_constant_nm_per_a is None:
        warnings.append("no torque constant (recording, machine file or schedule): friction in A")
    if facts.fixed_bearing_end is None:
        warnings.append("fixed-bearing end unknown: taken as the min end of the travel")
    if facts.travel_mm is None:
        warnings.append("travel unknown: taken as the span of the measuring positions")
    return warnings


@dataclass
class _Positions:
    """The fits of every position of an axis, and the offsets they rest on."""

    position_mm: dict[int, float]
    empty: list[float]
    own: dict[int, OffsetResult]
    offset: OffsetResult | None
    results: list[PositionResult]
    pooled: PooledFit | None


def _fit_positions(
    axis: str,
    table: FrictionTable,
    segmentation: Segmentation,
    facts: AxisFacts,
    warnings: list[str],
    report: Progress,
) -> _Positions:
    """Per position the offset where both directions were measured, and both directions' fits."""
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
    sparse = _too_few_speeds(points)
    if offset is None and sparse:
        # No position holds both directions at one speed: pair the speeds across positions.
        offset = _pooled_offset(points)
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
    pooled = None
    if sparse:
        pooled = _pooled_fit(points, position_mm, offset, segmentation.coarse)
        if pooled is not None:
            warnings.append(pooled.note)
    return _Positions(position_mm, empty, own, offset, positions, pooled)


def _speeds(found: Sequence[Point]) -> int:
    return len({abs(p.velocity_mm_min) for p in found})


def _too_few_speeds(points: Mapping[int, Mapping[int, list[Point]]]) -> bool:
    """No position holds enough speeds in one direction for a line of its own."""
    most = max(
        (_speeds(found) for by_sign in points.values() for found in by_sign.values()), default=0
    )
    return 0 < most < POOL_BELOW_SPEEDS and len(points) > 1


def _pooled(points: Mapping[int, Mapping[int, list[Point]]], sign: int) -> list[Point]:
    return [p for by_sign in points.values() for p in by_sign[sign]]


def _pooled_offset(points: Mapping[int, Mapping[int, list[Point]]]) -> OffsetResult | None:
    """The offset from speeds measured in both directions, at whichever positions."""
    found = separate_offset(_pooled(points, 1), _pooled(points, -1))
    if found is None:
        return None
    return found.model_copy(
        update={
            "explanation": "Positions pooled (no position holds both directions at one speed): "
            + found.explanation
        }
    )


def _pooled_fit(
    points: Mapping[int, Mapping[int, list[Point]]],
    position_mm: Mapping[int, float],
    offset: OffsetResult | None,
    coarse: bool,
) -> PooledFit | None:
    """Both directions' fits over every position's points; None where they hold no line."""
    directions: dict[Literal["positive", "negative"], DirectionResult | None] = {}
    for sign, key in _DIRECTIONS:
        found = _pooled(points, sign)
        directions[key] = (
            fit_direction(found, sign, offset=offset, coarse=coarse)
            if _speeds(found) >= POOL_BELOW_SPEEDS
            else None
        )
    if all(d is None for d in directions.values()):
        return None
    most = max(_speeds(found) for by_sign in points.values() for found in by_sign.values())
    note = (
        f"every position holds at most {most} speed(s) per direction, too few for a friction "
        f"line of its own: Coulomb and viscous friction come from the {len(points)} positions "
        "pooled per direction (friction taken as the same along the travel)"
    )
    return PooledFit(
        positions_mm=[position_mm[i] for i in points], directions=directions, note=note
    )


def finish_axis(
    axis: str,
    facts: AxisFacts,
    summary: AxisSummary | None,
    found: AxisFound,
    *,
    report: Progress,
    gap_share: float,
) -> AxisResult:
    """An axis' result from its windows and their current: table, fits, dependency, verdict.

    Raises:
        RecordingError: The current is dead (in every row or every window), or
            no window holds a finite current.
    """
    segmentation = found.segmentation
    _check_current(axis, found)
    report(f"axis {axis}: friction table", 0.1)
    table = _table(axis, facts, found)
    warnings = [*segmentation.warnings, *found.implausible_lines, *facts.warnings]
    warnings.extend(_what_is_missing(facts))
    fitted = _fit_positions(axis, table, segmentation, facts, warnings, report)
    report(f"axis {axis}: position dependency", 0.95)
    dependency, notes = _dependency(
        table, segmentation, facts, fitted.position_mm, fitted.offset, fitted.own
    )
    warnings.extend(notes)
    if dependency is None:
        warnings.append("a single measuring position: no position dependency")
    result = AxisResult(
        verdict=Verdict(level="ok", reason="", action=""),
        quantity=table.quantity,
        unit=table.unit,
        **facts.mechanics().model_dump(),
        window_source=segmentation.source,
        windows=len(segmentation.windows),
        samples_used=table.samples,
        sample_period_s=segmentation.sample_period_s,
        velocity_quantum_mm_min=segmentation.velocity_quantum_mm_min,
        current_quantum_a=found.current_quantum_a,
        coarse=segmentation.coarse,
        implausible_values=found.implausible_counts,
        positions=fitted.results,
        offset=fitted.offset,
        pooled=fitted.pooled,
        position_dependency=dependency,
        warnings=list(dict.fromkeys(warnings)),
    )
    planned = len(summary.windows) if summary is not None else None
    verdict = axis_verdict(
        result, planned_windows=planned, gap_share=gap_share, empty_positions=fitted.empty
    )
    return result.model_copy(update={"verdict": verdict})
