"""One machine axis as the shop floor sees it: the latest fingerprint and its health.

Built from the store's fleet overview (:func:`~ncmeasure.store.overview.fleet_overview`),
so the verdict, the change since the baseline and the light are those of
``store report`` and the dashboard, never computed a second way. The MQTT
message is :meth:`AxisSummary.message`; the OPC UA server shows the same
fields as variables. docs/shop-floor.md lists every field with its unit.

The health state follows the OPC UA DI ``DeviceHealthEnumeration`` (OPC 10000-100,
4.5.4, Table 22: NORMAL 0, FAILURE 1, CHECK_FUNCTION 2, OFF_SPEC 3,
MAINTENANCE_REQUIRED 4; https://reference.opcfoundation.org/DI/docs/4.5.4/),
itself NAMUR NE 107's status signals. The mapping, worst first:

* FAILURE: the analysis found an assembly fault (verdict ``fault``; not a
  pattern along the travel unchanged since the baseline, the machine's own
  fingerprint, which does not count).
* OFF_SPEC: any other ``critical`` status (a change beyond the critical limit).
* MAINTENANCE_REQUIRED: the status ``warning`` (the verdict ``check``, a change
  beyond the warning limit, an outlier of the machine's type, friction far from
  the machine's other axes or from its type): the axis works, but wants attention.
* NORMAL: the status ``ok``.

The status is the one rule of every surface
(:func:`~ncmeasure.analysis.judgement.status.machine_status`); the health only
tells a fault from another critical status.

CHECK_FUNCTION ("functional checks are currently performed") says that work on
the device makes its values temporarily invalid; the store does not know of a
measurement in progress, so it is never set from the store.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Literal

from ncmeasure.formats.comparison import Limits, Status, worst_status
from ncmeasure.store.overview import AxisOverview, FleetOverview, MachineOverview

__all__ = [
    "DEVICE_HEALTH",
    "SUMMARY_SCHEMA",
    "AxisSummary",
    "Health",
    "axis_summaries",
    "device_health",
    "worst_health",
]

SUMMARY_SCHEMA = "ncmeasure-fingerprint/1"
"""The ``schema`` field of every message: its name and version (a new field keeps
the version; a renamed or removed one raises it)."""

Health = Literal["NORMAL", "FAILURE", "CHECK_FUNCTION", "OFF_SPEC", "MAINTENANCE_REQUIRED"]

DEVICE_HEALTH: dict[Health, int] = {
    "NORMAL": 0,
    "FAILURE": 1,
    "CHECK_FUNCTION": 2,
    "OFF_SPEC": 3,
    "MAINTENANCE_REQUIRED": 4,
}
"""The DI DeviceHealthEnumeration: name -> value (OPC 10000-100, Table 22)."""

_SEVERITY: tuple[Health, ...] = (
    "NORMAL",
    "MAINTENANCE_REQUIRED",
    "OFF_SPEC",
    "CHECK_FUNCTION",
    "FAILURE",
)
"""NE 107's order, least severe first (a machine shows its worst axis)."""


def device_health(axis: AxisOverview) -> Health:
    """The DI DeviceHealth of an axis (the mapping of the module docstring)."""
    status = axis.status
    if status == "critical" and axis.verdict == "fault" and axis.verdict_counts:
        return "FAILURE"
    if status == "critical":
        return "OFF_SPEC"
    if status == "warning":
        return "MAINTENANCE_REQUIRED"
    return "NORMAL"


def worst_health(healths: Iterable[Health]) -> Health:
    """The most severe of ``healths`` (NORMAL for none)."""
    return max(healths, key=_SEVERITY.index, default="NORMAL")


@dataclass(frozen=True)
class AxisSummary:
    """One axis of one machine at its latest measurement (docs/shop-floor.md, the message)."""

    machine: MachineOverview
    axis: AxisOverview
    limits: Limits = field(default_factory=Limits)
    """The warning and critical limits the changes were judged by (the overview's)."""

    @property
    def health(self) -> Health:
        """The DI DeviceHealth (:func:`device_health`)."""
        return device_health(self.axis)

    def change(self, characteristic: str) -> float | None:
        """The change since the baseline: percent, or points of the spread; None if none."""
        return next(
            (c.change for c in self.axis.changes if c.characteristic == characteristic), None
        )

    @property
    def change_status(self) -> Status | None:
        """The change since the baseline as the one rule judges it (the characteristics
        against the limits, and a local change along the travel); None when nothing was
        compared."""
        if not self.axis.changes:
            return None
        judged = self.axis.judged
        if judged is not None:
            return judged.change_status
        return worst_status(c.status for c in self.axis.changes)

    def message(self) -> dict[str, Any]:
        """The MQTT message: JSON-ready, field by field in docs/shop-floor.md."""
        machine, axis = self.machine, self.axis
        compared = machine.baseline_id != machine.latest_id and bool(axis.changes)
        return {
            "schema": SUMMARY_SCHEMA,
            "site": machine.site,
            "serial": machine.serial,
            "machine_type": machine.machine_type,
            "axis": axis.axis,
            "measurement_id": machine.latest_id,
            "measured_utc": machine.latest_utc,
            "label": machine.latest_label,
            "verdict": axis.verdict,
            "status": axis.status,
            "health": self.health,
            "health_code": DEVICE_HEALTH[self.health],
            "unit": axis.unit,
            "coulomb": axis.latest.get("coulomb"),
            "viscous_per_m_min": axis.latest.get("viscous_per_m_min"),
            "spread_percent": axis.latest.get("spread_percent"),
            "baseline_id": machine.baseline_id if compared else None,
            "baseline_utc": machine.baseline_utc if compared else None,
            "coulomb_change_percent": self.change("coulomb"),
            "viscous_change_percent": self.change("viscous_per_m_min"),
            "spread_change_points": self.change("spread_percent"),
            "change_status": self.change_status,
            "warning_percent": self.limits.warning_percent,
            "critical_percent": self.limits.critical_percent,
            "outliers": sorted(o.characteristic for o in axis.outliers),
            "verdict_counts": axis.verdict_counts,
            "explanation": axis.explained(),
        }


def axis_summaries(
    overview: FleetOverview, serials: Iterable[str] | None = None
) -> list[AxisSummary]:
    """Every axis of every machine of ``overview`` (or of those ``serials``), by serial and axis.

    Raises:
        ConfigError: A serial that has no measurement in the store.
    """
    machines = overview.machines
    if serials is not None:
        wanted = list(dict.fromkeys(serials))
        known = {m.serial for m in machines}
        missing = [s for s in wanted if s not in known]
        if missing:
            from ncmeasure.errors import ConfigError

            raise ConfigError(
                f"no measurement of {', '.join(repr(s) for s in missing)} in the store "
                "(ncmeasure store list shows the machines)"
            )
        machines = [m for m in machines if m.serial in set(wanted)]
    return [AxisSummary(m, a, overview.limits) for m in machines for a in m.axes.values()]
