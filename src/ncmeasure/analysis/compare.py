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
The limits and why they are what they are: :class:`Limits`,
``docs/analysis-models.md``.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
from collections.abc import Sequence
from pathlib import PurePath
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from ncmeasure import __version__
from ncmeasure.analysis.results import AxisResult, DirectionResult, PositionResult, Results
from ncmeasure.errors import ComparisonError

__all__ = [
    "COMPARISON_FORMAT",
    "COMPARISON_FORMAT_VERSION",
    "Comparison",
    "ComparisonError",
    "FleetAxis",
    "GroupDeviation",
    "Limits",
    "PointDeviation",
    "RunSummary",
    "compare_results",
    "comparison_exit_code",
]

log = logging.getLogger(__name__)

COMPARISON_FORMAT: Literal["ncmeasure-comparison"] = "ncmeasure-comparison"
COMPARISON_FORMAT_VERSION = 1

VELOCITY_MATCH_TOLERANCE = 0.005
"""Velocities match when their |v| differ by at most 0.5 % of the larger."""

POSITION_MATCH_TOLERANCE_MM = 1.0
"""Positions matched by index are noted when they differ by more; matched by value within it."""

_MAD_TO_SIGMA = 0.6745
"""Iglewicz & Hoaglin: modified z = 0.6745·(x − median)/MAD."""

_MEAN_AD_TO_SIGMA = 0.7979
"""Fallback when MAD = 0: modified z = 0.7979·(x − median)/mean |x − median|."""

Direction = Literal["positive", "negative"]
Status = Literal["ok", "warning", "critical"]
_SIGN: dict[Direction, int] = {"positive": 1, "negative": -1}


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Limits(_Model):
    """When a change of friction is worth a warning, and when it is critical.

    Defaults, from method.md's reference numbers:

    - friction varies by ~40 % along the travel of one healthy industrial
      axis, new identical machines spread by ~50 %, and a ball screw loses up
      to ~60 % over its life through preload loss. A change of the whole
      friction level by 40 % is therefore of the size of a full preload loss
      or a machine at the far end of its type's spread: **critical 40 %**.
    - half of that, **warning 20 %**, is well above run-to-run repeatability
      (three runs 20 min apart agreed) and matches the ~20 % step a single
      sticking telescopic cover produced: a change a technician should look at.

    The figures compared with the limits are medians over the velocities of
    one (axis, position, direction), so a single noisy velocity step does not
    trip them.

    Outliers in a fleet use the robust modified z-score of Iglewicz & Hoaglin,
    0.6745·(x − median)/MAD, against ``outlier_z`` (3.5, their recommendation);
    with fewer than ``outlier_min_runs`` runs no outlier is named.
    """

    warning_percent: float = Field(default=20.0, gt=0)
    critical_percent: float = Field(default=40.0, gt=0)
    outlier_z: float = Field(default=3.5, gt=0, description="Modified z-score threshold.")
    outlier_min_runs: int = Field(default=3, ge=3)

    @model_validator(mode="after")
    def _ordered(self) -> Limits:
        if self.critical_percent < self.warning_percent:
            raise ValueError(
                f"critical_percent ({self.critical_percent:g}) must not be below "
                f"warning_percent ({self.warning_percent:g})"
            )
        return self


class PointDeviation(_Model):
    """One matched velocity step: the other run's friction against the base's."""

    label: str
    axis: str
    position_index: int = Field(description="Index of the position in the base.")
    position_mm: float = Field(description="Position in the base.")
    direction: Direction
    velocity_mm_min: float = Field(description="Signed velocity of the base point.")
    base: float = Field(description="Friction magnitude of the base.")
    value: float = Field(description="Friction magnitude of the other run.")
    deviation_percent: float = Field(description="(value − base) / base × 100.")


class GroupDeviation(_Model):
    """All matched velocities of one axis, position and direction."""

    label: str
    axis: str
    position_index: int
    position_mm: float
    direction: Direction
    points: int
    median_deviation_percent: float = Field(description="Median over the velocities.")
    max_abs_point_deviation_percent: float
    status: Status


class RunSummary(_Model):
    """One compared run against the base."""

    label: str
    machine: str | None
    points: int = Field(description="Matched velocity steps.")
    max_abs_deviation_percent: float = Field(
        description="Largest |median deviation| of any axis, position and direction."
    )
    worst: str | None = Field(description="Where that largest deviation is.")
    status: Status


class FleetAxis(_Model):
    """Statistics of one axis over all runs of a fleet comparison (the base included)."""

    axis: str
    unit: Literal["Nm", "A"]
    runs: list[str]
    mean_friction: list[float] = Field(
        description="Per run: mean friction magnitude over the points common to all runs."
    )
    common_points: int
    mean: float
    spread_percent: float = Field(description="(max − min) / mean × 100 of mean_friction.")
    std: float = Field(description="Sample standard deviation of mean_friction.")
    modified_z: list[float]
    outliers: list[str]


class Comparison(_Model):
    """The result of ``compare_results``: the comparison.json."""

    format: Literal["ncmeasure-comparison"] = COMPARISON_FORMAT
    format_version: int = COMPARISON_FORMAT_VERSION
    ncmeasure_version: str = __version__
    created_utc: str = Field(
        default_factory=lambda: dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    )
    mode: Literal["lifetime", "fleet"]
    base: str = Field(description="Label of the base run.")
    others: list[str]
    limits: Limits
    deviations: list[PointDeviation]
    groups: list[GroupDeviation]
    runs: list[RunSummary]
    fleet: list[FleetAxis]
    problems: list[str] = Field(description="Everything that could not be matched.")
    findings: list[str] = Field(description="What the comparison shows, in words.")


# --------------------------------------------------------------------------- matching

_Cell = tuple[str, int, Direction, int]  # axis, base position index, direction, base point index


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
        names = [defaults[0], *names]
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
        for i, (b, o) in enumerate(pairs):
            if abs(b.position_mm - o.position_mm) > POSITION_MATCH_TOLERANCE_MM:
                problems.append(
                    f"{label}: axis {axis} position {i} is at {o.position_mm:g} mm, the base's "
                    f"at {b.position_mm:g} mm; compared by index"
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


def _match_points(
    where: str, b: DirectionResult, o: DirectionResult, problems: list[str]
) -> list[tuple[int, float, float, float]]:
    """(base point index, signed base velocity, base median, other median) per match."""
    speeds = np.array([abs(p.velocity_mm_min) for p in o.points], dtype=np.float64)
    used = np.zeros(speeds.size, dtype=bool)
    out = []
    missing = []
    for i, p in enumerate(b.points):
        speed = abs(p.velocity_mm_min)
        if speed == 0 or speeds.size == 0:
            missing.append(speed)
            continue
        gap = np.where(used, np.inf, np.abs(speeds - speed) / np.maximum(speeds, speed))
        j = int(np.argmin(gap))
        if gap[j] > VELOCITY_MATCH_TOLERANCE:
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
    extra = int(np.count_nonzero(~used))
    if extra:
        noun = "velocity" if extra == 1 else "velocities"
        problems.append(f"{where}: {extra} {noun} of the other run not in the base")
    return out


def _deviations(
    label: str, base: Results, other: Results, problems: list[str]
) -> tuple[list[PointDeviation], dict[_Cell, float], dict[_Cell, float]]:
    """Point deviations of one run and the magnitudes of base and run per matched cell."""
    points: list[PointDeviation] = []
    base_mag: dict[_Cell, float] = {}
    other_mag: dict[_Cell, float] = {}
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
                            f"{label}: axis {axis} position {bp.position_index} {direction} "
                            f"direction measured in only one of the runs"
                        )
                    continue
                where = f"{label}: axis {axis} position {bp.position_index} {direction}"
                sign = _SIGN[direction]
                skipped = 0
                for i, velocity, b_med, o_med in _match_points(where, bd, od, problems):
                    b_val, o_val = sign * b_med, sign * o_med
                    if not (b_val > 0 and math.isfinite(o_val)):
                        skipped += 1
                        continue
                    cell: _Cell = (axis, bp.position_index, direction, i)
                    base_mag[cell], other_mag[cell] = b_val, o_val
                    points.append(
                        PointDeviation(
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


def _modified_z(values: Sequence[float]) -> list[float]:
    x = np.asarray(values, dtype=np.float64)
    centre = float(np.median(x))
    mad = float(np.median(np.abs(x - centre)))
    if mad > 0:
        return [float(z) for z in _MAD_TO_SIGMA * (x - centre) / mad]
    mean_ad = float(np.mean(np.abs(x - centre)))
    if mean_ad > 0:
        return [float(z) for z in _MEAN_AD_TO_SIGMA * (x - centre) / mean_ad]
    return [0.0] * x.size


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
    base_cells: dict[_Cell, float] = {}
    run_cells: list[dict[_Cell, float]] = []
    empty = []
    for label, other in zip(other_labels, others, strict=True):
        points, b_mag, o_mag = _deviations(label, base, other, problems)
        if not points:
            empty.append(label)
            continue
        base_cells.update(b_mag)
        run_cells.append(o_mag)
        run_groups = _groups(points, limits)
        worst = max(run_groups, key=lambda g: abs(g.median_deviation_percent))
        deviations.extend(points)
        groups.extend(run_groups)
        runs.append(
            RunSummary(
                label=label,
                machine=other.recording.machine,
                points=len(points),
                max_abs_deviation_percent=abs(worst.median_deviation_percent),
                worst=(
                    f"axis {worst.axis} position {worst.position_index} "
                    f"({worst.position_mm:g} mm) {worst.direction}: "
                    f"{worst.median_deviation_percent:+.1f} % (median of {worst.points} "
                    "velocities)"
                ),
                status=_status(worst.median_deviation_percent, limits),
            )
        )
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
        fleet = _fleet(base, base_label, other_labels, base_cells, run_cells, limits, problems)

    findings = _findings(mode, base_label, runs, groups, fleet, limits, problems)
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
    )


def _fleet(
    base: Results,
    base_label: str,
    other_labels: Sequence[str],
    base_cells: dict[_Cell, float],
    run_cells: Sequence[dict[_Cell, float]],
    limits: Limits,
    problems: list[str],
) -> list[FleetAxis]:
    out = []
    labels = [base_label, *other_labels]
    for axis in sorted({cell[0] for cell in base_cells}):
        common = [
            cell
            for cell in base_cells
            if cell[0] == axis and all(cell in cells for cells in run_cells)
        ]
        if not common:
            problems.append(f"fleet: axis {axis} has no point measured in every run")
            continue
        means = [float(np.mean([base_cells[c] for c in common]))]
        means += [float(np.mean([cells[c] for c in common])) for cells in run_cells]
        values = np.array(means)
        mean = float(values.mean())
        z = _modified_z(means)
        enough = len(means) >= limits.outlier_min_runs
        out.append(
            FleetAxis(
                axis=axis,
                unit=base.axes[axis].unit,
                runs=labels,
                mean_friction=means,
                common_points=len(common),
                mean=mean,
                spread_percent=float(np.ptp(values) / mean * 100.0) if mean > 0 else 0.0,
                std=float(values.std(ddof=1)) if values.size > 1 else 0.0,
                modified_z=z,
                outliers=[
                    label
                    for label, score in zip(labels, z, strict=True)
                    if enough and abs(score) > limits.outlier_z
                ],
            )
        )
    return out


def _findings(
    mode: str,
    base_label: str,
    runs: Sequence[RunSummary],
    groups: Sequence[GroupDeviation],
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
                f"{run.label!r} against {base_label!r}: every change within "
                f"±{limits.warning_percent:g} % (largest {run.worst}); ok."
            )
        else:
            lines.append(
                f"{run.label!r} against {base_label!r}: largest change {run.worst}; "
                f"{run.status} ({band})."
            )
        if mode != "lifetime":
            continue
        for axis in sorted({g.axis for g in groups if g.label == run.label}):
            medians = [
                g.median_deviation_percent
                for g in groups
                if g.label == run.label and g.axis == axis
            ]
            low, high = min(medians), max(medians)
            if max(abs(low), abs(high)) <= limits.warning_percent:
                continue
            span = (
                f"{low:+.1f} %"
                if f"{low:.1f}" == f"{high:.1f}"
                else f"{low:+.1f} % to {high:+.1f} %"
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
                    f"{high:+.1f} %): a local cause; compare the position dependency of "
                    "both runs."
                )
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


def comparison_exit_code(comparison: Comparison) -> int:
    """Exit code of a comparison for the command line.

    0: every run within the warning limit; 1: a warning limit crossed (none
    critical); 3: a critical limit crossed. 2 is reserved for bad input
    (:class:`ComparisonError` and other :class:`~ncmeasure.errors.NcMeasureError`).
    Fleet outliers and matching problems are findings, not exit codes.
    """
    statuses = {run.status for run in comparison.runs}
    if "critical" in statuses:
        return 3
    if "warning" in statuses:
        return 1
    return 0
