"""A comparison of friction results (``comparison.json``): what changed, how much, and why.

Written by ``ncmeasure compare`` (:func:`~ncmeasure.analysis.judgement.compare.compare_results`
computes it); read by the report, the store and the dashboard. The
:class:`Limits` say when a change is worth a warning and when it is critical;
:data:`Status` is the verdict of a run against its base.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
from collections.abc import Iterable
from pathlib import Path
from typing import ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from ncmeasure.files import write_whole
from ncmeasure.formats.header import FileHeader
from ncmeasure.formats.results import Cause, Signature

__all__ = [
    "COMPARISON_FORMAT",
    "COMPARISON_FORMAT_VERSION",
    "AxisChange",
    "Comparison",
    "Direction",
    "FleetAxis",
    "GroupDeviation",
    "Limits",
    "PointDeviation",
    "RunSummary",
    "Status",
    "worst_status",
    "write_comparison",
]

log = logging.getLogger(__name__)

COMPARISON_FORMAT = "ncmeasure-comparison"
COMPARISON_FORMAT_VERSION = 1

Direction = Literal["positive", "negative"]
Status = Literal["ok", "warning", "critical"]

_STATUS_ORDER: dict[Status, int] = {"ok": 0, "warning": 1, "critical": 2}


def worst_status(statuses: Iterable[Status]) -> Status:
    """The worst of the statuses: ``critical``, else ``warning``, else ``ok`` (also for none)."""
    return max(statuses, key=_STATUS_ORDER.__getitem__, default="ok")


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Limits(_Model):
    """When a change of friction is worth a warning, and when it is critical.

    Defaults, from the method's physics and the measurement's own uncertainty
    (docs/fleet.md, "The limits"; the numbers are the virtual machine's axis
    model, ``ncmeasure.sim.axis``):

    - a healthy re-measurement changes Coulomb friction by the torque accuracy
      of the drive (about ±1.5 %, so up to 3 % between two measurements)
      plus the run-to-run scatter (0.02–0.2 % between seeds of the virtual
      machine): **warning 10 %** is three times that, and a ball-screw nut one
      preload class too high (+19 % Coulomb friction in the model; the
      carriages' preload doubled: +12 %) passes it;
    - **critical 25 %**: beyond any single preload change the model knows (a
      full loss of the nut's preload is −13 %, every preload −60 % is −20 %),
      so critical means more than one component, or a fault of its own.

    They apply to the change of Coulomb friction (percent) and of the spread
    along the travel (percentage points) since the baseline; every surface
    decides a machine's status with them in one place,
    :func:`~ncmeasure.analysis.judgement.status.machine_status`.

    ``compare`` also shows the change point by point (medians over the
    velocities of one axis, position and direction, with their own status
    against the same limits): where the change is, not the machine's status.

    Outliers in a fleet use the robust modified z-score of Iglewicz & Hoaglin,
    0.6745·(x − median)/MAD, against ``outlier_z`` (3.5, their recommendation);
    with fewer than ``outlier_min_runs`` runs no outlier is named.
    """

    warning_percent: float = Field(default=10.0, gt=0)
    critical_percent: float = Field(default=25.0, gt=0)
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
    status: Status = Field(description="The machine's status against the base (one rule).")
    axis_status: dict[str, Status] = Field(
        default_factory=dict, description="Per axis: its status against the base."
    )
    reasons: list[str] = Field(default_factory=list, description="Why the status is not ok.")
    change_status: dict[str, Status] = Field(
        default_factory=dict,
        description="Per axis: the status of its change since the base alone, without its own "
        "verdict (what the comparison adds to the verdict).",
    )
    limit_status: dict[str, Status] = Field(
        default_factory=dict,
        description="Per axis: its characteristics' changes against the warning and critical "
        "limits alone (change_status without a local change along the travel).",
    )


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


class AxisChange(_Model):
    """The change of one axis of one run against the base, and its likely assembly cause.

    The change profile comes from the ratio other/base per (direction,
    velocity) and position, reduced to one relative profile by
    :func:`~ncmeasure.analysis.judgement.diagnosis.position_dependency`; the rules that
    turn it into causes are in ``docs/analysis-models.md``.
    """

    label: str
    axis: str
    points: int = Field(description="Matched velocity steps of the axis, both directions.")
    mean_change_percent: float = Field(
        description="Mean of (other − base)/base × 100 over the matched points."
    )
    positions_mm: list[float] = Field(description="Positions of the change profile (base).")
    change_percent: list[float] = Field(
        description="Change along the travel, averaged over velocities and directions."
    )
    spread_percent: float = Field(description="(max − min)/mean × 100 of the ratio profile.")
    signature: Signature = Field(description="Shape of the change along the travel.")
    causes: list[Cause] = Field(description="Likely causes of the change, best first.")
    notes: list[str] = Field(
        default_factory=list, description="Assumptions made (travel, fixed-bearing end)."
    )


class Comparison(FileHeader):
    """The result of ``compare_results``: the comparison.json."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    FORMAT: ClassVar[str] = COMPARISON_FORMAT
    FORMAT_VERSION: ClassVar[int] = COMPARISON_FORMAT_VERSION
    WRITTEN_BY: ClassVar[str] = "ncmeasure compare"

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
    changes: list[AxisChange] = Field(
        default_factory=list,
        description="Per compared run and axis: the change along the travel and its cause.",
    )

    @property
    def status(self) -> Status:
        """The worst run's status: ``critical``, ``warning`` or ``ok``.

        Fleet outliers and matching problems are findings, not a status.
        """
        return worst_status(run.status for run in self.runs)


def write_comparison(comparison: Comparison, path: str | os.PathLike[str]) -> Path:
    """Write a comparison as JSON, whole (its folder is created when missing).

    Raises:
        OutputError: The file or its folder cannot be written.
    """
    target = write_whole(
        path, comparison.model_dump_json(indent=2) + "\n", fsync=True, parents=True
    )
    log.info("wrote %s", target)
    return target
