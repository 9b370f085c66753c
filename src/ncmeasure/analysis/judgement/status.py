"""One judgement of a machine: the status of each axis and of the machine, decided once.

Every surface that shows a machine's status (``ncmeasure compare``, ``store
check``, ``store report``, the dashboard's fleet grid and machine page, the
MQTT message, the OPC UA DeviceHealth, ``ncmeasure measure``'s exit status)
shows the answer of :func:`machine_status`. The overview of a whole fleet
computes the same inputs in bulk (the fleet's modified z-scores at once), then
asks the same function.

The inputs are the figures of each axis (:class:`AxisFigures`: the axis' own
verdict, and the headline's Coulomb friction, viscous friction and spread along
the travel, :func:`~ncmeasure.analysis.judgement.summary.axis_headline`), the
same figures of the baseline, and the axis' place in its type's fleet
(:class:`FleetPlace`). An axis' status is the worst of:

* its own verdict: ``check`` is a warning, ``fault`` critical; but where a
  baseline exists and the diagnosis of the change since it (:class:`ChangeFigures`)
  is flat, a verdict from the axis' pattern along the travel is the machine's own
  fingerprint, unchanged: a ``check`` does not count, a ``fault`` is a warning
  (not a change, but a pattern to confirm it was accepted at the baseline);
* a local change since the baseline (the change's pattern along the travel names
  a bearing, the nut, a rail or a cover): a warning, critical from
  :data:`~ncmeasure.analysis.judgement.verdict.FAULT_SPREAD_PERCENT`;
* the change since the baseline of each judged characteristic
  (:data:`CHARACTERISTICS`: Coulomb friction in percent, the spread along the
  travel in percentage points) against ``Limits.warning_percent`` and
  ``Limits.critical_percent``. Viscous friction is shown, not judged: it follows
  the lubricant's temperature by several percent per kelvin. Where a baseline
  exists but the latest or the baseline has no Coulomb friction for the axis (no
  friction line), the change cannot be judged: a warning, never a silent ok;
* an outlier of its type (the modified z-score rule, :func:`is_outlier`): a
  warning;
* absolute sanity, at least a warning even without a baseline or a fleet large
  enough for z-scores: Coulomb friction more than :data:`SIBLING_FACTOR` times
  the median of the machine's other axes (same quantity), or a friction level
  more than :data:`FLEET_FACTOR` times above (or below a :data:`FLEET_FACTOR`-th
  of) its type's fleet median.

A machine's status is the worst of its axes (``ok`` without axes). docs/fleet.md
gives the defaults and where their numbers come from.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final, Literal

from ncmeasure.analysis.judgement.diagnosis import FLAT_THRESHOLD_PERCENT
from ncmeasure.analysis.judgement.summary import axis_headline
from ncmeasure.analysis.judgement.verdict import ChangeFigures, fingerprint_unchanged
from ncmeasure.formats.comparison import Limits, Status, worst_status
from ncmeasure.formats.results import AxisResult, Results

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

__all__ = [
    "CHARACTERISTICS",
    "FLEET_FACTOR",
    "SIBLING_FACTOR",
    "VERDICT_STATUS",
    "AxisFigures",
    "AxisStatus",
    "Change",
    "ChangeFigures",
    "Characteristic",
    "FleetPlace",
    "MachineStatus",
    "axis_status",
    "change_status",
    "figures_of",
    "is_outlier",
    "machine_status",
    "outliers_among",
]

VERDICT_STATUS: Final[Mapping[str, Status]] = {"ok": "ok", "check": "warning", "fault": "critical"}
"""An axis' own verdict as a status."""

SIBLING_FACTOR: Final = 3.0
"""An axis with more than this times the median Coulomb friction of the machine's other
axes is at least a warning: axes of one machine differ by their load and size, rarely by
half of this (the virtual machine's X and vertical Z differ by 1.1×)."""

FLEET_FACTOR: Final = 3.0
"""A friction level more than this factor from its type's fleet median is at least a
warning, with any number of other machines: new identical machines spread by ~50 %."""


@dataclass(frozen=True)
class Characteristic:
    """One figure of an axis that the store trends and the status follows."""

    name: str
    title: str
    unit: Literal["quantity", "%", "quantity per m/min"]
    relative: bool = True
    """Compared as a relative change (friction levels), else in points (spread in %)."""
    judged: bool = True
    """Its change since the baseline enters the status (else it is only shown)."""

    def unit_of(self, quantity_unit: str) -> str:
        """The unit of its values for an axis measured in ``quantity_unit`` (Nm or A)."""
        return self.unit.replace("quantity", quantity_unit)


CHARACTERISTICS: Final = (
    Characteristic("coulomb", "Coulomb friction", "quantity"),
    Characteristic("viscous_per_m_min", "viscous friction", "quantity per m/min", judged=False),
    Characteristic("spread_percent", "spread along the travel", "%", relative=False),
)
"""What ``store trend`` and ``store check`` follow over a machine's life and its fleet."""

_BY_NAME: Final = {c.name: c for c in CHARACTERISTICS}


def _finite(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


@dataclass(frozen=True)
class AxisFigures:
    """What the judgement reads of one axis of one measurement (the store keeps the same)."""

    axis: str
    unit: str
    verdict: str
    """The axis' own verdict: ok, check or fault."""
    values: Mapping[str, float | None]
    """Per characteristic name: its value (None when not determined)."""
    signature: str | None = None
    """The axis' own pattern along the travel (None when unknown)."""

    @classmethod
    def of(cls, name: str, result: AxisResult) -> AxisFigures:
        """The figures of an analysed axis (the headline's, as the store's rows hold them)."""
        headline = axis_headline(result)
        values = {
            "coulomb": _finite(headline.coulomb),
            "viscous_per_m_min": _finite(headline.viscous_per_m_min),
            "spread_percent": _finite(headline.spread_percent),
        }
        return cls(name, result.unit, result.verdict.level, values, headline.signature)


def figures_of(results: Results) -> dict[str, AxisFigures]:
    """:meth:`AxisFigures.of` for every axis of ``results``."""
    return {name: AxisFigures.of(name, axis) for name, axis in results.axes.items()}


@dataclass(frozen=True)
class FleetPlace:
    """One characteristic of an axis against the latest of the other machines of its type."""

    characteristic: str
    median: float
    modified_z: float | None
    """None when the fleet is too small for z-scores."""
    machines: int


@dataclass(frozen=True)
class Change:
    """One characteristic of an axis: the latest value against the baseline's."""

    characteristic: str
    baseline: float
    latest: float
    change: float
    """Percent of the baseline (friction levels), or percentage points (the spread)."""
    status: Status
    """Against the limits; ``ok`` for a characteristic that is shown, not judged."""


@dataclass(frozen=True)
class AxisStatus:
    """The status of one axis and why."""

    axis: str
    status: Status
    changes: tuple[Change, ...] = ()
    outliers: tuple[str, ...] = ()
    """Characteristics that are outliers of the type (modified z)."""
    reasons: tuple[str, ...] = ()
    """Every finding that is not ok, in words."""
    notes: tuple[str, ...] = ()
    """Findings that lifted a verdict (a pattern unchanged since the baseline: a check does not
    count, a fault is a warning), in words."""
    limit_status: Status = "ok"
    """The judged characteristics' changes against the limits alone (a warning where the change
    cannot be judged); ok without a baseline."""
    change_status: Status = "ok"
    """The change since the baseline alone (without the axis' own verdict, its siblings and
    its fleet): the worst judged change, a warning where it cannot be judged; ok without a
    baseline. What a comparison with a reference adds to the axis' own verdict."""


@dataclass(frozen=True)
class MachineStatus:
    """The status of a machine: the worst of its axes."""

    axes: dict[str, AxisStatus] = field(default_factory=dict)

    @property
    def status(self) -> Status:
        """The worst axis' status (ok without axes)."""
        return worst_status(a.status for a in self.axes.values())

    @property
    def reasons(self) -> list[str]:
        """Every axis' reasons, axis by axis."""
        return [r for name in sorted(self.axes) for r in self.axes[name].reasons]


def change_status(change: float, limits: Limits) -> Status:
    """A change (percent, or points of the spread) against the warning and critical limits."""
    size = abs(change)
    if size >= limits.critical_percent:
        return "critical"
    if size >= limits.warning_percent:
        return "warning"
    return "ok"


def is_outlier(
    characteristic: Characteristic, value: float, median: float, z: float | None, limits: Limits
) -> bool:
    """The outlier rule of the fleet: a modified z beyond ``limits.outlier_z``, and a
    difference from the fleet's median that matters.

    That difference is the warning limit of a friction level (relative), or the
    spread a healthy axis keeps (:data:`FLAT_THRESHOLD_PERCENT` points): a fleet
    that hardly scatters would otherwise make any difference a large z.
    """
    if z is None or abs(z) <= limits.outlier_z:
        return False
    floor = (
        abs(median) * limits.warning_percent / 100.0
        if characteristic.relative
        else FLAT_THRESHOLD_PERCENT
    )
    return abs(value - median) > floor


def outliers_among(
    characteristic: Characteristic,
    values: NDArray[np.float64],
    medians: NDArray[np.float64],
    z: NDArray[np.float64],
    limits: Limits,
) -> NDArray[np.bool_]:
    """:func:`is_outlier` of every value of an array at once (a NaN z, as None, is none)."""
    floor = (
        abs(medians) * limits.warning_percent / 100.0
        if characteristic.relative
        else FLAT_THRESHOLD_PERCENT
    )
    found: NDArray[np.bool_] = (abs(z) > limits.outlier_z) & (abs(values - medians) > floor)
    return found


def _change(c: Characteristic, before: float, after: float, limits: Limits) -> Change | None:
    if c.relative:
        if before == 0:
            return None
        change = (after - before) / abs(before) * 100.0
    else:
        change = after - before
    return Change(
        c.name, before, after, change, change_status(change, limits) if c.judged else "ok"
    )


def _changes(latest: AxisFigures, base: AxisFigures, limits: Limits) -> list[Change]:
    found = []
    for c in CHARACTERISTICS:
        before, after = base.values.get(c.name), latest.values.get(c.name)
        if before is None or after is None:
            continue
        change = _change(c, before, after, limits)
        if change is not None:
            found.append(change)
    return found


def _change_text(change: Change) -> str:
    unit = " pt" if change.characteristic == "spread_percent" else " %"
    return f"{_BY_NAME[change.characteristic].title} {change.change:+.1f}{unit} since the baseline"


def _unjudged_reason(latest: AxisFigures, base: AxisFigures) -> str | None:
    """Why the change since the baseline cannot be judged: a side without Coulomb friction.

    Coulomb friction is what the change is judged on; without it on either side
    the axis is at least a warning, never a silent ok.
    """
    missing = [
        which
        for which, figures in (("the latest", latest), ("the baseline", base))
        if figures.values.get("coulomb") is None
    ]
    if not missing:
        return None
    return (
        f"no friction line in {' and '.join(missing)} measurement: the change since the "
        "baseline cannot be judged"
    )


def _sibling_reason(axis: AxisFigures, others: Sequence[AxisFigures]) -> str | None:
    own = axis.values.get("coulomb")
    peers = [
        v
        for o in others
        if o.unit == axis.unit and (v := o.values.get("coulomb")) is not None and v > 0
    ]
    if own is None or not peers:
        return None
    median = statistics.median(peers)
    if own > SIBLING_FACTOR * median:
        return (
            f"Coulomb friction {own:.4g} {axis.unit} is {own / median:.1f} × the median of the "
            f"machine's other axes ({median:.4g} {axis.unit}): check the axis before keeping "
            "these results as its reference"
        )
    return None


def axis_status(
    axis: AxisFigures,
    *,
    baseline: AxisFigures | None = None,
    siblings: Sequence[AxisFigures] = (),
    fleet: Iterable[FleetPlace] = (),
    limits: Limits | None = None,
    change: ChangeFigures | None = None,
) -> AxisStatus:
    """The status of one axis (the rule of the module docstring).

    Args:
        axis: The latest measurement's figures of the axis.
        baseline: The baseline's figures of the axis (None: nothing to compare with;
            another quantity, Nm against A, is not compared).
        siblings: The figures of the machine's other axes in the same measurement.
        fleet: The axis' characteristics against the other machines of its type.
        limits: The warning and critical limits, the outlier rule.
        change: The diagnosis of the change since the baseline (with ``baseline``).
    """
    limits = limits or Limits()
    statuses: list[Status] = []
    reasons: list[str] = []
    notes: list[str] = []
    compared = baseline is not None and baseline.unit == axis.unit
    unchanged = compared and fingerprint_unchanged(axis.verdict, axis.signature, change)
    if unchanged and axis.verdict == "check":
        notes.append(
            f"axis {axis.axis}: verdict check from its pattern along the travel, unchanged "
            "since the baseline (the machine's own fingerprint)"
        )
    elif unchanged:
        # a fault-sized pattern that the baseline had too: no change, but not a healthy axis
        statuses.append("warning")
        notes.append(
            f"axis {axis.axis}: verdict fault from its pattern along the travel, unchanged "
            "since the baseline: a warning, not a fault"
        )
        reasons.append(
            f"axis {axis.axis}: verdict fault from its pattern along the travel, unchanged since "
            "the baseline: confirm it was accepted there"
        )
    else:
        statuses.append(VERDICT_STATUS.get(axis.verdict, "ok"))
        if axis.verdict in ("check", "fault"):
            reasons.append(f"axis {axis.axis}: verdict {axis.verdict}")
    changes: list[Change] = []
    since_baseline: list[Status] = []
    against_limits: list[Status] = []
    if baseline is not None and compared:
        if change is not None and change.local:
            local = VERDICT_STATUS[change.level]
            since_baseline.append(local)
            reasons.append(f"axis {axis.axis}: since the baseline, {change.text()} ({local})")
        changes = _changes(axis, baseline, limits)
        for found in changes:
            against_limits.append(found.status)
            if found.status != "ok":
                reasons.append(f"axis {axis.axis}: {_change_text(found)} ({found.status})")
        unjudged = _unjudged_reason(axis, baseline)
        if unjudged is not None:
            against_limits.append("warning")
            reasons.append(f"axis {axis.axis}: {unjudged}")
    since_baseline.extend(against_limits)
    statuses.extend(since_baseline)
    sibling = _sibling_reason(axis, siblings)
    if sibling is not None:
        statuses.append("warning")
        reasons.append(f"axis {axis.axis}: {sibling}")
    outliers: list[str] = []
    for place in fleet:
        c = _BY_NAME.get(place.characteristic)
        value = axis.values.get(place.characteristic)
        if c is None or value is None:
            continue
        if is_outlier(c, value, place.median, place.modified_z, limits):
            outliers.append(c.name)
            statuses.append("warning")
            reasons.append(
                f"axis {axis.axis}: {c.title} {value:.4g} {c.unit_of(axis.unit)} is an outlier "
                f"of its type (fleet median {place.median:.4g}, modified z "
                f"{place.modified_z:+.1f} over {place.machines} machines)"
            )
        elif c.relative and place.median > 0 and value > 0:
            ratio = value / place.median
            if ratio > FLEET_FACTOR or ratio < 1.0 / FLEET_FACTOR:
                statuses.append("warning")
                reasons.append(
                    f"axis {axis.axis}: {c.title} {value:.4g} {c.unit_of(axis.unit)} is "
                    f"{ratio:.2g} × its type's fleet median ({place.median:.4g} over "
                    f"{place.machines} machines)"
                )
    return AxisStatus(
        axis=axis.axis,
        status=worst_status(statuses),
        changes=tuple(changes),
        outliers=tuple(outliers),
        reasons=tuple(reasons),
        notes=tuple(notes),
        limit_status=worst_status(against_limits),
        change_status=worst_status(since_baseline),
    )


def machine_status(
    latest: Mapping[str, AxisFigures],
    *,
    baseline: Mapping[str, AxisFigures] | None = None,
    fleet: Mapping[str, Sequence[FleetPlace]] | None = None,
    limits: Limits | None = None,
    changes: Mapping[str, ChangeFigures] | None = None,
) -> MachineStatus:
    """The status of a machine and of each of its axes: the one rule every surface shows.

    Args:
        latest: The latest measurement's figures per axis (:func:`figures_of`).
        baseline: The baseline's figures per axis (None: only one measurement, or
            the two cannot be compared).
        fleet: Per axis, its characteristics against its type's fleet.
        limits: The warning and critical limits, the outlier rule.
        changes: Per axis, the diagnosis of the change since the baseline (where the
            caller compared the two: ``compare``, ``store check``, the store's summary).
    """
    limits = limits or Limits()
    axes = {}
    for name, figures in sorted(latest.items()):
        siblings = [f for other, f in latest.items() if other != name]
        axes[name] = axis_status(
            figures,
            baseline=None if baseline is None else baseline.get(name),
            siblings=siblings,
            fleet=() if fleet is None else fleet.get(name, ()),
            limits=limits,
            change=None if changes is None else changes.get(name),
        )
    return MachineStatus(axes)
