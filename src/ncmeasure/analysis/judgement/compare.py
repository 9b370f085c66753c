"""Compare friction results: a machine against its own earlier fingerprint, or a fleet.

Two modes, chosen from the input:

- ``lifetime``: one base and one other run of the same machine (machine
  names equal or unknown), e.g. the delivery state and a re-measurement at
  the customer;
- ``fleet``: several machines of one type (or two runs of different machines)
  against a base, plus statistics over all runs and robust outliers.

Points are matched by axis name, position (by index; by position within
1 mm when the counts differ), direction and velocity (|v| within 0.5 %).
Every mismatch is reported as one line in :attr:`Comparison.problems`;
nothing comparable at all raises :class:`ComparisonError`.

Per compared run and axis, :class:`AxisChange` diagnoses the *change*: the
ratio other/base per velocity and position goes through
:func:`~ncmeasure.analysis.judgement.diagnosis.position_dependency`, so the machine's
own position dependency cancels; a flat change beyond the warning limit is a
global offset (preload, guide carriage, lubricant).
The limits and why they are what they are: :class:`Limits`,
``docs/analysis-models.md``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from pathlib import PurePath
from typing import Literal, NamedTuple, Protocol, TypeVar

import numpy as np

from ncmeasure.analysis.judgement.diagnosis import (
    ALTERNATIVE_FACTOR,
    FLAT_THRESHOLD_PERCENT,
    position_dependency,
)
from ncmeasure.analysis.judgement.fleet import Cell, fleet_axes
from ncmeasure.errors import ComparisonError
from ncmeasure.formats.comparison import (
    AxisChange,
    Comparison,
    Direction,
    FleetAxis,
    GroupDeviation,
    Limits,
    PointDeviation,
    RunSummary,
    Status,
)
from ncmeasure.formats.results import (
    AxisResult,
    Cause,
    CauseName,
    DirectionResult,
    PositionDependency,
    PositionResult,
    Results,
    Signature,
)

__all__ = [
    "CHANGE_FLAT_PERCENT",
    "CHANGE_SHAPE",
    "GLOBAL_CHANGE_PERCENT",
    "GLOBAL_SCORE_AT_CRITICAL",
    "GLOBAL_SCORE_AT_WARNING",
    "ComparisonError",
    "change_diagnosis",
    "compare_results",
]

log = logging.getLogger(__name__)

VELOCITY_MATCH_TOLERANCE = 0.005
"""Velocities match when their |v| differ by at most 0.5 % of the larger."""

POSITION_MATCH_TOLERANCE_MM = 1.0
"""Positions matched by index are noted when they differ by more; matched by value within it."""

GLOBAL_CHANGE_PERCENT = FLAT_THRESHOLD_PERCENT
"""A flat change of the mean beyond this is a global offset worth a cause.

The same 5 % below which a profile along the travel counts as flat: above the
few-percent repeatability of runs (method.md) and independent of the warning
limit, which says whether the change matters, not what caused it.
"""

CHANGE_FLAT_PERCENT = 2.0
"""A change along the travel below this is flat (no local cause), however significant.

The machine's own profile divides out of a change, so what remains of a healthy
re-measurement is the noise of both runs and the drift of the profile between them:
0.3 to 0.7 % on the virtual machine's nominal axes, up to 1.7 % with its realistic
fingerprint, drift and drive noise (:class:`~ncmeasure.sim.realism.Realism`, 60 healthy
pairs). A loose bearing shifted by 50 µm changes the profile by 2.2 to 3.1 % (12 runs
of the nominal machine). docs/analysis-models.md, *Detection limits*. The single
measurement keeps :data:`~ncmeasure.analysis.judgement.diagnosis.FLAT_THRESHOLD_PERCENT`:
there, a healthy axis' own fingerprint is part of the profile.
"""

LEVEL_DOMINATES = 2.5
"""A change that moved every position by at least this many times its spread along the
travel is led by its global cause (preload, carriage, lubricant), the pattern second: a
local fault adds most near its place and less elsewhere (a 300 µm nut on the demo's X:
+5 % mid-travel, +18 % at the ends; on its shorter vertical Z, 500 µm: +21 % and +33 %,
2.4 times), a preload change lifts everything and follows the part's own variation along
the screw (×2.5 nut preload on a realistic machine: +11.6 to +16.6 %, 2.7 times)."""

GLOBAL_SCORE_AT_WARNING = 0.5
"""Score of ``preload_or_carriage`` for a flat change just beyond ``GLOBAL_CHANGE_PERCENT``."""

GLOBAL_SCORE_AT_CRITICAL = 0.9
"""Score of ``preload_or_carriage`` for a flat change at or beyond the critical limit."""

_SIGN: dict[Direction, int] = {"positive": 1, "negative": -1}


# --------------------------------------------------------------------------- matching


def _labels(base: Results, others: Sequence[Results], labels: Sequence[str] | None) -> list[str]:
    runs = [base, *others]
    defaults = [r.recording.machine or PurePath(r.recording.directory).name or "run" for r in runs]
    if len(set(defaults)) < len(defaults):
        defaults = [f"{name} @ {r.created_utc}" for name, r in zip(defaults, runs, strict=True)]
    if len(set(defaults)) < len(defaults):
        defaults = [f"{name} #{i}" for i, name in enumerate(defaults)]
    if labels is None:
        return defaults
    names = [str(label) for label in labels]
    if len(names) == len(others):
        base_name = defaults[0]
        if base_name in names:  # the base's default must not take a given label
            base_name = f"{base_name} (base)"
        names = [base_name, *names]
    if len(names) != len(runs):
        raise ComparisonError(
            f"{len(names)} labels for {len(runs)} results: give one label per other run, "
            "or one per result with the base first"
        )
    if len(set(names)) != len(names):
        raise ComparisonError(f"labels must be unique: {names}")
    return names


def _status(value: float, limits: Limits) -> Status:
    if abs(value) > limits.critical_percent:
        return "critical"
    if abs(value) > limits.warning_percent:
        return "warning"
    return "ok"


def _match_positions(
    axis: str, base: AxisResult, other: AxisResult, label: str, problems: list[str]
) -> list[tuple[PositionResult, PositionResult]]:
    if len(base.positions) == len(other.positions):
        pairs = list(zip(base.positions, other.positions, strict=True))
        for b, o in pairs:
            if abs(b.position_mm - o.position_mm) > POSITION_MATCH_TOLERANCE_MM:
                problems.append(
                    f"{label}: axis {axis} position {b.position_index + 1} is at "
                    f"{o.position_mm:g} mm, the base's at {b.position_mm:g} mm; compared by index"
                )
        return pairs
    pairs = []
    for b in base.positions:
        near = [
            o
            for o in other.positions
            if abs(o.position_mm - b.position_mm) <= POSITION_MATCH_TOLERANCE_MM
        ]
        if near:
            pairs.append((b, min(near, key=lambda o: abs(o.position_mm - b.position_mm))))
    problems.append(
        f"{label}: axis {axis} has {len(other.positions)} positions, the base "
        f"{len(base.positions)}; matched {len(pairs)} by position within "
        f"{POSITION_MATCH_TOLERANCE_MM:g} mm"
    )
    return pairs


def _gap(other: float, speed: float) -> float:
    """The relative gap of two speeds (not both zero)."""
    return abs(other - speed) / max(other, speed)


def _nearest(speeds: Sequence[float], used: Sequence[bool], speed: float) -> int:
    """The index of the unused speed nearest to ``speed`` (the first of equal gaps, the first
    NaN as numpy's argmin takes it); -1 when all are used."""
    best, best_gap = -1, math.inf
    for j, other in enumerate(speeds):
        if used[j]:
            continue
        gap = abs(other - speed) / max(other, speed)
        if gap != gap:  # NaN
            return j
        if best < 0 or gap < best_gap:
            best, best_gap = j, gap
    return best


def _match_points(
    where: str, b: DirectionResult, o: DirectionResult, problems: list[str]
) -> list[tuple[int, float, float, float]]:
    """(base point index, signed base velocity, base median, other median) per match.

    Each base point takes the nearest unused velocity of the other run (relative gap; the
    first of equal gaps). A dozen velocities: plain floats, not arrays (the same
    arithmetic, far less overhead per point).
    """
    speeds = [abs(float(p.velocity_mm_min)) for p in o.points]
    used = [False] * len(speeds)
    out = []
    missing = []
    for i, p in enumerate(b.points):
        speed = abs(p.velocity_mm_min)
        if speed == 0 or not speeds:
            missing.append(speed)
            continue
        j = _nearest(speeds, used, speed)
        if j < 0 or _gap(speeds[j], speed) > VELOCITY_MATCH_TOLERANCE:
            missing.append(speed)
            continue
        used[j] = True
        out.append((i, p.velocity_mm_min, p.median, o.points[j].median))
    if missing:
        shown = ", ".join(f"{v:g}" for v in missing[:5]) + (", ..." if len(missing) > 5 else "")
        problems.append(
            f"{where}: {len(missing)} of {len(b.points)} base velocities have no match within "
            f"{VELOCITY_MATCH_TOLERANCE * 100:g} % ({shown} mm/min)"
        )
    extra = used.count(False)
    if extra:
        noun = "velocity" if extra == 1 else "velocities"
        problems.append(f"{where}: {extra} {noun} of the other run not in the base")
    return out


def _offset(axis: AxisResult) -> float:
    """The direction-independent part of an axis' values (gravity on a vertical axis).

    Friction is what remains: ``sign · (median − offset)``. Without both
    directions there is no offset, and nothing is removed.
    """
    return axis.offset.value if axis.offset is not None else 0.0


class _Matched(Protocol):
    """What the change's diagnosis reads of a matched point (a :class:`PointDeviation`, or
    a :class:`_Deviation` where no comparison is built)."""

    @property
    def axis(self) -> str: ...
    @property
    def position_index(self) -> int: ...
    @property
    def position_mm(self) -> float: ...
    @property
    def direction(self) -> Direction: ...
    @property
    def velocity_mm_min(self) -> float: ...
    @property
    def base(self) -> float: ...
    @property
    def value(self) -> float: ...
    @property
    def deviation_percent(self) -> float: ...


class _Deviation(NamedTuple):
    """A :class:`PointDeviation`'s figures without the model (hundreds per comparison:
    validating each costs more than the whole diagnosis of the change reads)."""

    label: str
    axis: str
    position_index: int
    position_mm: float
    direction: Direction
    velocity_mm_min: float
    base: float
    value: float
    deviation_percent: float


_D = TypeVar("_D", bound=_Matched)


def _deviations(
    label: str, base: Results, other: Results, problems: list[str], record: Callable[..., _D]
) -> tuple[list[_D], dict[Cell, float], dict[Cell, float]]:
    """Point deviations of one run (each a ``record``) and the magnitudes of base and run
    per matched cell."""
    points: list[_D] = []
    base_mag: dict[Cell, float] = {}
    other_mag: dict[Cell, float] = {}
    for axis in base.axes.keys() - other.axes.keys():
        problems.append(f"{label}: axis {axis} of the base is missing")
    for axis in other.axes.keys() - base.axes.keys():
        problems.append(f"{label}: axis {axis} is not in the base")
    for axis in sorted(base.axes.keys() & other.axes.keys()):
        ba, oa = base.axes[axis], other.axes[axis]
        if ba.quantity != oa.quantity:
            problems.append(
                f"{label}: axis {axis} is in {oa.unit}, the base in {ba.unit} "
                "(torque constant missing on one side); axis not compared"
            )
            continue
        for bp, op in _match_positions(axis, ba, oa, label, problems):
            for direction in ("positive", "negative"):
                bd, od = bp.directions.get(direction), op.directions.get(direction)
                if bd is None or od is None:
                    if (bd is None) != (od is None):
                        problems.append(
                            f"{label}: axis {axis} position {bp.position_index + 1} {direction} "
                            f"direction measured in only one of the runs"
                        )
                    continue
                where = f"{label}: axis {axis} position {bp.position_index + 1} {direction}"
                sign = _SIGN[direction]
                b_off, o_off = _offset(ba), _offset(oa)
                skipped = 0
                for i, velocity, b_med, o_med in _match_points(where, bd, od, problems):
                    b_val, o_val = sign * (b_med - b_off), sign * (o_med - o_off)
                    if not (b_val > 0 and math.isfinite(o_val)):
                        skipped += 1
                        continue
                    cell: Cell = (axis, bp.position_index, direction, i)
                    base_mag[cell], other_mag[cell] = b_val, o_val
                    points.append(
                        record(
                            label=label,
                            axis=axis,
                            position_index=bp.position_index,
                            position_mm=bp.position_mm,
                            direction=direction,
                            velocity_mm_min=velocity,
                            base=b_val,
                            value=o_val,
                            deviation_percent=(o_val - b_val) / b_val * 100.0,
                        )
                    )
                if skipped:
                    problems.append(
                        f"{where}: {skipped} points skipped, base friction not positive"
                    )
    return points, base_mag, other_mag


def _groups(points: Sequence[PointDeviation], limits: Limits) -> list[GroupDeviation]:
    by_key: dict[tuple[str, int, str], list[PointDeviation]] = {}
    for p in points:
        by_key.setdefault((p.axis, p.position_index, p.direction), []).append(p)
    out = []
    for members in by_key.values():
        dev = np.array([p.deviation_percent for p in members])
        median = float(np.median(dev))
        first = members[0]
        out.append(
            GroupDeviation(
                label=first.label,
                axis=first.axis,
                position_index=first.position_index,
                position_mm=first.position_mm,
                direction=first.direction,
                points=len(members),
                median_deviation_percent=median,
                max_abs_point_deviation_percent=float(np.max(np.abs(dev))),
                status=_status(median, limits),
            )
        )
    return out


# --------------------------------------------------------------------------- change diagnosis


def _ratio_table(
    points: Sequence[_Matched],
) -> tuple[list[float], list[int], list[float], np.ndarray]:
    """Positions, their numbers, signed row velocities and the ratio table other/base of one axis.

    One row per direction and velocity: the directions stay separate rows, so
    each keeps its own level in the fit and their disagreement counts as
    scatter. Velocities of different positions share a row when their |v|
    agree within the matching tolerance.
    """
    columns = sorted({(p.position_index, p.position_mm) for p in points})
    column = {index: k for k, (index, _) in enumerate(columns)}
    rows: list[tuple[float, dict[int, float]]] = []
    for direction in ("positive", "negative"):
        first = len(rows)
        members = sorted(
            (p for p in points if p.direction == direction),
            key=lambda p: abs(p.velocity_mm_min),
        )
        for p in members:
            speed = abs(p.velocity_mm_min)
            k = column[p.position_index]
            for reference, cells in rows[first:]:
                if (
                    k not in cells
                    and abs(abs(reference) - speed) / max(abs(reference), speed)
                    <= VELOCITY_MATCH_TOLERANCE
                ):
                    cells[k] = p.value / p.base
                    break
            else:
                rows.append((p.velocity_mm_min, {k: p.value / p.base}))
    table = np.full((len(rows), len(columns)), np.nan)
    for j, (_, cells) in enumerate(rows):
        for k, ratio in cells.items():
            table[j, k] = ratio
    return [mm for _, mm in columns], [i + 1 for i, _ in columns], [v for v, _ in rows], table


def _global_score(change_percent: float, limits: Limits) -> float:
    """Grows from the warning score at ``GLOBAL_CHANGE_PERCENT`` to the critical score at the
    critical limit."""
    room = limits.critical_percent - GLOBAL_CHANGE_PERCENT
    excess = abs(change_percent) - GLOBAL_CHANGE_PERCENT
    share = 1.0 if room <= 0 else float(np.clip(excess / room, 0.0, 1.0))
    return GLOBAL_SCORE_AT_WARNING + (GLOBAL_SCORE_AT_CRITICAL - GLOBAL_SCORE_AT_WARNING) * share


def _global_causes(mean: float, spread: float, base_label: str, limits: Limits) -> list[Cause]:
    """A flat change beyond the warning limit: a global offset first, then the alternatives."""
    lead = round(_global_score(mean, limits), 3)
    head = (
        f"Friction changed by {mean:+.1f} % against {base_label!r}, alike at every position "
        f"(the change varies by {spread:.1f} % along the travel), beyond the "
        f"±{GLOBAL_CHANGE_PERCENT:g} % of run-to-run repeatability: a global offset"
    )
    if mean > 0:
        return [
            Cause(
                cause="preload_or_carriage",
                score=lead,
                evidence=head + ", as from more preload of the bearings or the ball-screw nut, "
                "a shifted or tilted guide carriage, or a change of lubricant.",
            ),
            Cause(
                cause="cover_or_seal",
                score=round(ALTERNATIVE_FACTOR * lead, 3),
                evidence="Covers, wiper seals or the cable chain dragging over the whole travel "
                "raise friction everywhere as well.",
            ),
        ]
    return [
        Cause(
            cause="preload_or_carriage",
            score=lead,
            evidence=head + ", as from preload loss of the ball-screw nut or the bearings "
            "(up to ~60 % over a screw's life), a loosened guide carriage, or a change of "
            "lubricant.",
        ),
        Cause(
            cause="cover_or_seal",
            score=round(ALTERNATIVE_FACTOR * lead, 3),
            evidence="Worn or removed wiper seals, or a cover or cable chain that no longer "
            "drags, lower friction everywhere as well.",
        ),
    ]


def _axis_change(
    label: str,
    base_label: str,
    axis: str,
    base_axis: AxisResult,
    points: Sequence[_Matched],
    limits: Limits,
) -> AxisChange:
    positions, numbers, velocities, table = _ratio_table(points)
    notes = []
    travel = base_axis.travel_mm
    if travel is None:
        travel = (min(positions), max(positions))
        notes.append(
            f"travel unknown in the base: taken as the span of the positions "
            f"({travel[0]:g} to {travel[1]:g} mm)"
        )
    fixed_end = base_axis.fixed_bearing_end
    if fixed_end is None:
        fixed_end = "min"
        notes.append("fixed-bearing end unknown in the base: taken as the min end of the travel")
    dependency = position_dependency(
        positions,
        velocities,
        table,
        travel_mm=travel,
        fixed_bearing_end=fixed_end,
        numbers=numbers,
        flat_threshold_percent=CHANGE_FLAT_PERCENT,
        velocity_profiles=False,  # the change keeps the average profile alone
    )
    mean = float(np.mean([p.deviation_percent for p in points]))
    average = next((p for p in dependency.profiles if p.velocity_mm_min is None), None)
    profile_mm = average.positions_mm if average else []
    change = [(value - 1.0) * 100.0 for value in average.values] if average else []
    return AxisChange(
        label=label,
        axis=axis,
        points=len(points),
        mean_change_percent=mean,
        positions_mm=profile_mm,
        change_percent=change,
        spread_percent=dependency.spread_percent,
        signature=dependency.signature,
        causes=_change_causes(label, base_label, dependency, mean, change, limits),
        notes=notes,
    )


def _change_causes(
    label: str,
    base_label: str,
    dependency: PositionDependency,
    mean: float,
    change: Sequence[float],
    limits: Limits,
) -> list[Cause]:
    """The causes of a change: a global offset, none, or the diagnosis of its profile."""
    spread = dependency.spread_percent
    within = abs(mean) <= GLOBAL_CHANGE_PERCENT
    prefix = (
        f"The change against {base_label!r} (ratio {label!r}/{base_label!r}, the machine's "
        "own position dependency divided out): "
    )
    causes: list[Cause]
    if dependency.signature == "flat" and not within:
        causes = _global_causes(mean, spread, base_label, limits)
    elif dependency.signature == "flat":
        share = abs(mean) / GLOBAL_CHANGE_PERCENT
        causes = [
            Cause(
                cause="none",
                score=round(0.9 - 0.4 * share, 3),
                evidence=f"Friction changed by {mean:+.1f} % against {base_label!r}, alike at "
                f"every position (the change varies by {spread:.1f} % along the travel), within "
                f"±{GLOBAL_CHANGE_PERCENT:g} % (run-to-run repeatability): no assembly change "
                "shows.",
            ),
            Cause(
                cause="preload_or_carriage",
                score=round(0.1 + 0.3 * share, 3),
                evidence="A change of preload, guide carriage or lubricant would shift friction "
                "alike at every position; this one stays within the repeatability.",
            ),
        ]
    else:
        causes = [c.model_copy(update={"evidence": prefix + c.evidence}) for c in dependency.causes]
        if dependency.signature == "insufficient_data" and not within:
            causes.insert(
                0,
                Cause(
                    cause="preload_or_carriage",
                    score=0.3,
                    evidence=f"Friction changed by {mean:+.1f} % against {base_label!r} on "
                    f"average, beyond ±{GLOBAL_CHANGE_PERCENT:g} % (run-to-run repeatability), but "
                    "with fewer than 3 positions a global offset (preload, guide carriage, "
                    "lubricant) cannot be told from a local fault.",
                ),
            )
        elif change and (
            min(change) > GLOBAL_CHANGE_PERCENT or max(change) < -GLOBAL_CHANGE_PERCENT
        ):
            # A local pattern on top of a level that moved beyond the limit everywhere.
            least = min(change, key=abs)
            level = _global_score(least, limits)
            if abs(least) >= LEVEL_DOMINATES * spread:
                # The level moved far more than the pattern varies: a global change whose
                # size follows the component's own friction along the travel (more nut
                # preload scales the nut's own variation along the screw), first.
                lead = Cause(
                    cause="preload_or_carriage",
                    score=round(level, 3),
                    evidence=f"Friction changed by at least {least:+.1f} % at every position, "
                    f"{abs(least) / spread:.1f} times as much as the change varies along the "
                    f"travel ({spread:.1f} %): the whole level moved (preload, guide carriage, "
                    "lubricant), by more where that part's own friction is higher.",
                )
                return [
                    lead,
                    *(c.model_copy(update={"score": min(c.score, lead.score)}) for c in causes),
                ]
            causes.insert(
                1,
                Cause(
                    cause="preload_or_carriage",
                    # below the local lead: the rule above decides, never the list order
                    score=round(max(0.0, min(level, causes[0].score - 0.001)), 3),
                    evidence=f"Besides the local pattern, friction changed by at least "
                    f"{least:+.1f} % at every position, beyond ±{GLOBAL_CHANGE_PERCENT:g} % "
                    "(run-to-run repeatability): the whole level moved too "
                    "(preload, guide carriage, lubricant).",
                ),
            )
    return causes


def _axis_changes(
    label: str,
    base_label: str,
    base: Results,
    points: Sequence[_Matched],
    limits: Limits,
) -> list[AxisChange]:
    by_axis: dict[str, list[_Matched]] = {}
    for p in points:
        by_axis.setdefault(p.axis, []).append(p)
    return [
        _axis_change(label, base_label, axis, base.axes[axis], members, limits)
        for axis, members in sorted(by_axis.items())
    ]


CHANGE_SHAPE: dict[Signature, str] = {
    "flat": "alike along the travel",
    "rising_to_loose_bearing": "rising towards the loose bearing",
    "rising_to_fixed_bearing": "rising towards the fixed bearing",
    "high_at_both_ends": "largest at both ends",
    "step": "a step along the travel",
    "irregular": "irregular along the travel",
    "insufficient_data": "shape unknown (too few positions)",
    "not_identifiable": "shape unknown (each speed at its own positions)",
}
"""How a change is spread along the travel, in a few words (findings, console, report)."""

_CAUSE_WORDS: dict[CauseName, str] = {
    "none": "no assembly change",
    "preload_or_carriage": "preload of bearings or ball-screw nut, guide carriage or lubricant",
    "loose_bearing": "loose bearing shifted or tilted",
    "fixed_bearing": "fixed bearing shifted or tilted",
    "screw_nut": "ball-screw nut shifted or tilted",
    "guide_rail": "guide rail misaligned",
    "cover_or_seal": "a sticking cover, wiper seal or cable chain",
}


def _change_line(change: AxisChange, base_label: str) -> str:
    lead = change.causes[0]
    words = _CAUSE_WORDS[lead.cause]
    if lead.cause == "preload_or_carriage" and change.mean_change_percent < 0:
        words = "preload loss of ball-screw nut or bearings, guide carriage or lubricant"
    return (
        f"{change.label!r} against {base_label!r}, axis {change.axis}: mean change "
        f"{change.mean_change_percent:+.1f} %, {CHANGE_SHAPE[change.signature]}; likely "
        f"cause: {words} ({lead.cause}, score {lead.score:.2f})."
    )


# --------------------------------------------------------------------------- public


def compare_results(
    base: Results,
    others: Sequence[Results],
    *,
    labels: Sequence[str] | None = None,
    limits: Limits | None = None,
) -> Comparison:
    """Compare runs against a base run.

    The mode is ``lifetime`` for exactly one other run whose machine name is
    the base's (or unknown on either side), else ``fleet``.

    Per matched point the deviation is (other − base)/base × 100 on friction
    magnitudes (the negative direction's sign removed). Per axis, position and
    direction the median over the velocities is compared with the limits;
    a run's status is that of its largest |median deviation|.

    In fleet mode, per axis and run the mean friction over the cells that all
    runs share gives the fleet mean, spread (max − min)/mean, sample standard
    deviation, and outliers by the modified z-score.

    Args:
        base: The reference run (delivery state, or the fleet's reference machine).
        others: The runs to compare with it (at least one).
        labels: One label per run in ``others``, or one per result with the base
            first; default (and for the base when only the others are labelled):
            the machine name (or the recording directory), made unique with the
            creation time.
        limits: Warning/critical limits and the outlier rule; default :class:`Limits`.

    Returns:
        The comparison.

    Raises:
        ComparisonError: No other run, labels that do not fit, or no point at
            all that could be matched between the base and a run.
    """
    limits = limits or Limits()
    if not others:
        raise ComparisonError("nothing to compare: give at least one result besides the base")
    names = _labels(base, others, labels)
    base_label, other_labels = names[0], names[1:]
    machines = {base.recording.machine, *(o.recording.machine for o in others)} - {None}
    mode: Literal["lifetime", "fleet"] = (
        "lifetime" if len(others) == 1 and len(machines) <= 1 else "fleet"
    )

    problems: list[str] = []
    deviations: list[PointDeviation] = []
    groups: list[GroupDeviation] = []
    runs: list[RunSummary] = []
    changes: list[AxisChange] = []
    base_cells: dict[Cell, float] = {}
    run_cells: list[dict[Cell, float]] = []
    empty = []
    for label, other in zip(other_labels, others, strict=True):
        points, b_mag, o_mag = _deviations(label, base, other, problems, PointDeviation)
        if not points:
            empty.append(label)
            continue
        base_cells.update(b_mag)
        run_cells.append(o_mag)
        run_groups = _groups(points, limits)
        deviations.extend(points)
        groups.extend(run_groups)
        changes.extend(_axis_changes(label, base_label, base, points, limits))
        run_changes = [c for c in changes if c.label == label]
        runs.append(_run_summary(label, base, other, points, run_groups, run_changes, limits))
    if empty:
        raise ComparisonError(
            "no point of "
            + ", ".join(repr(e) for e in empty)
            + f" matches the base {base_label!r} (axis, position, direction, velocity "
            f"within {VELOCITY_MATCH_TOLERANCE * 100:g} %)",
            problems,
        )

    fleet: list[FleetAxis] = []
    if mode == "fleet":
        fleet = fleet_axes(base, base_label, other_labels, base_cells, run_cells, limits, problems)

    findings = _findings(mode, base_label, runs, groups, changes, fleet, limits, problems)
    return Comparison(
        mode=mode,
        base=base_label,
        others=other_labels,
        limits=limits,
        deviations=deviations,
        groups=groups,
        runs=runs,
        fleet=fleet,
        problems=problems,
        findings=findings,
        changes=changes,
    )


def change_diagnosis(
    base: Results, other: Results, limits: Limits | None = None
) -> list[AxisChange]:
    """The diagnosis of each axis' change of ``other`` since ``base``: the ``changes`` of
    :func:`compare_results` (``base`` against ``[other]``), without the rest of the
    comparison (groups, run summaries, findings), for a caller that needs no more (the
    store's change since the baseline). The labels name only texts, not figures.

    Raises:
        ComparisonError: No point of ``other`` matches the base.
    """
    limits = limits or Limits()
    points, _, _ = _deviations("other", base, other, [], _Deviation)
    if not points:
        raise ComparisonError(
            "no point matches the base (axis, position, direction, velocity within "
            f"{VELOCITY_MATCH_TOLERANCE * 100:g} %)"
        )
    return _axis_changes("other", "base", base, points, limits)


def _run_summary(
    label: str,
    base: Results,
    other: Results,
    points: Sequence[PointDeviation],
    groups: Sequence[GroupDeviation],
    changes: Sequence[AxisChange],
    limits: Limits,
) -> RunSummary:
    """A run's largest median deviation, and its status by the one rule
    (:func:`~ncmeasure.analysis.judgement.status.machine_status`, the base as baseline)."""
    from ncmeasure.analysis.judgement.status import ChangeFigures, figures_of, machine_status

    worst = max(groups, key=lambda g: abs(g.median_deviation_percent))
    judged = machine_status(
        figures_of(other),
        baseline=figures_of(base),
        limits=limits,
        changes={c.axis: ChangeFigures.of(c) for c in changes},
    )
    return RunSummary(
        label=label,
        machine=other.recording.machine,
        points=len(points),
        max_abs_deviation_percent=abs(worst.median_deviation_percent),
        worst=(
            f"axis {worst.axis} position {worst.position_index + 1} "
            f"({worst.position_mm:g} mm) {worst.direction}: "
            f"{worst.median_deviation_percent:+.1f} % (median of {worst.points} "
            "velocities)"
        ),
        status=judged.status,
        axis_status={name: a.status for name, a in judged.axes.items()},
        change_status={name: a.change_status for name, a in judged.axes.items()},
        limit_status={name: a.limit_status for name, a in judged.axes.items()},
        reasons=judged.reasons,
    )


def _global_or_local(label: str, groups: Sequence[GroupDeviation], limits: Limits) -> list[str]:
    """Lifetime mode: per axis beyond the warning limit, whether the change is global."""
    lines = []
    for axis in sorted({g.axis for g in groups if g.label == label}):
        medians = [
            g.median_deviation_percent for g in groups if g.label == label and g.axis == axis
        ]
        low, high = min(medians), max(medians)
        if max(abs(low), abs(high)) <= limits.warning_percent:
            continue
        span = (
            f"{low:+.1f} %" if f"{low:.1f}" == f"{high:.1f}" else f"{low:+.1f} % to {high:+.1f} %"
        )
        if high < 0 and high - low <= limits.warning_percent:
            lines.append(
                f"Axis {axis}: friction lower at every position and direction "
                f"({span}): a global decrease, as from preload loss "
                "of the ball-screw nut or bearings (up to ~60 % over a screw's life) or a "
                "change of lubricant."
            )
        elif low > 0 and high - low <= limits.warning_percent:
            lines.append(
                f"Axis {axis}: friction higher at every position and direction "
                f"({span}): a global increase, as from more preload, "
                "a guide carriage, covers or lubrication."
            )
        else:
            lines.append(
                f"Axis {axis}: the change differs along the travel ({low:+.1f} % to "
                f"{high:+.1f} %): a local cause (the diagnosis of the change follows)."
            )
    return lines


def _findings(
    mode: str,
    base_label: str,
    runs: Sequence[RunSummary],
    groups: Sequence[GroupDeviation],
    changes: Sequence[AxisChange],
    fleet: Sequence[FleetAxis],
    limits: Limits,
    problems: Sequence[str],
) -> list[str]:
    lines = []
    band = (
        f"warning above {limits.warning_percent:g} %, critical above {limits.critical_percent:g} %"
    )
    for run in runs:
        if run.status == "ok":
            lines.append(
                f"{run.label!r} against {base_label!r}: ok ({band}; largest change of a "
                f"point {run.worst})."
            )
        else:
            lines.append(
                f"{run.label!r} against {base_label!r}: {run.status} ({band}): "
                + "; ".join(run.reasons)
                + f". Largest change of a point {run.worst}."
            )
        if mode == "lifetime":
            lines.extend(_global_or_local(run.label, groups, limits))
        lines.extend(_change_line(c, base_label) for c in changes if c.label == run.label)
    for stats_ in fleet:
        text = (
            f"Axis {stats_.axis}: mean friction {stats_.mean:.4g} {stats_.unit} over "
            f"{len(stats_.runs)} runs, spread {stats_.spread_percent:.1f} % "
            f"((max − min)/mean; new identical machines spread by ~50 %), "
            f"std {stats_.std:.3g} {stats_.unit}"
        )
        if stats_.outliers:
            z = dict(zip(stats_.runs, stats_.modified_z, strict=True))
            text += "; outlier: " + ", ".join(
                f"{label!r} (modified z-score {z[label]:+.1f})" for label in stats_.outliers
            )
        elif len(stats_.runs) < limits.outlier_min_runs:
            text += f"; outliers need at least {limits.outlier_min_runs} runs"
        else:
            text += "; no outlier"
        lines.append(text + ".")
    if problems:
        lines.append(
            f"{len(problems)} matching problem(s): not every point was compared (see problems)."
        )
    return lines
