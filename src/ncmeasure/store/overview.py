"""The fleet at a glance: every machine × every axis from the stored rows, in a few queries.

What ``store report`` and the dashboard's fleet grid show. For each machine and
axis: the latest verdict (ok / check / fault: an assembly fault), the change of each
characteristic (:data:`~ncmeasure.store.rows.CHARACTERISTICS`) since the
machine's baseline (the first measurement labelled ``delivery``, else the
first), and whether the latest value is an outlier of the machine's type. The
outliers are those of ``store check`` (the same modified z against the other
machines' latest measurements, the same floor): computed for the whole fleet
at once (:func:`~ncmeasure.analysis.judgement.fleet.modified_z_leave_one_out`), so a
fleet of ten thousand machines takes seconds, not ten thousand checks.

The change since the baseline here is that of the characteristics (a relative
change of the friction levels, a change in percentage points of the spread
along the travel) against the warning and critical limits, and the diagnosis
of the change along the travel that ``store check`` makes: stored when a
measurement is added (:mod:`ncmeasure.store.changes`), read here for every
machine in a few queries. Where a store lacks it (or holds it of another
:data:`~ncmeasure.store.changes.DIAGNOSIS_VERSION`) it is compared on reading,
logged, and kept when the store is open for writing; ``ncmeasure store refresh``
stores it for the whole fleet. ``store check SERIAL`` shows the comparison point
by point.
"""

from __future__ import annotations

import logging
import math
from collections import defaultdict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy import Connection, select

from ncmeasure.analysis.judgement.fleet import modified_z_leave_one_out
from ncmeasure.analysis.judgement.status import (
    CHARACTERISTICS,
    AxisFigures,
    AxisStatus,
    Change,
    FleetPlace,
    change_status,
    is_outlier,
    machine_status,
)
from ncmeasure.formats.comparison import Limits, Status, worst_status
from ncmeasure.store import schema as t
from ncmeasure.store.changes import (
    BaselineChange,
    StoredChange,
    current_change,
    store_change,
    stored_changes,
)
from ncmeasure.store.store import Store
from ncmeasure.store.summaries import fleet_version, keep_statuses

__all__ = [
    "AxisOverview",
    "Change",
    "FleetOverview",
    "MachineOverview",
    "Outlier",
    "axis_rows_in",
    "change_status",
    "changes_of",
    "fill_axes",
    "fleet_overview",
    "is_outlier",
    "judge",
    "overviews_of",
    "read_axes",
]
# change_status, is_outlier and Change are the judgement's (judgement.status), named
# here too for the overview's readers.

_CHUNK = 500  # ids per IN (...) query: far below every database's parameter limit
_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Outlier:
    """A characteristic of a machine's latest measurement far from the rest of its type."""

    serial: str
    machine_type: str
    axis: str
    characteristic: str
    unit: str
    value: float
    fleet_median: float
    modified_z: float
    machines: int
    """Other machines of the type the value was compared with."""


@dataclass
class AxisOverview:
    """One axis of one machine."""

    axis: str
    unit: str
    verdict: str
    """The latest measurement's verdict: ok, check or fault."""
    latest: dict[str, float | None]
    signature: str | None = None
    """The latest measurement's pattern along the travel."""
    changes: list[Change] = field(default_factory=list)
    outliers: list[Outlier] = field(default_factory=list)
    judged: AxisStatus | None = None
    """The one rule's answer (:func:`~ncmeasure.analysis.judgement.status.machine_status`)."""

    @property
    def status(self) -> Status:
        """The light: the status of :func:`~ncmeasure.analysis.judgement.status.machine_status`
        (the verdict, the changes since the baseline, the fleet, the sibling axes)."""
        return self.judged.status if self.judged is not None else "ok"

    @property
    def reasons(self) -> tuple[str, ...]:
        """Why the status is not ok, in words."""
        return self.judged.reasons if self.judged is not None else ()

    @property
    def notes(self) -> tuple[str, ...]:
        """Findings that lifted the verdict (its pattern unchanged since the baseline), in
        words."""
        return self.judged.notes if self.judged is not None else ()

    def explained(self) -> list[str]:
        """Why the status is what it is, in words without the ``axis X:`` each begins with:
        the reasons, then the notes."""
        prefix = f"axis {self.axis}: "
        return [t.removeprefix(prefix) for t in (*self.reasons, *self.notes)]

    def verdict_shown(self, baseline_label: str | None) -> str:
        """The verdict as a surface shows it: ``check``, or ``check · fingerprint since
        delivery`` where it does not count (its pattern unchanged since the baseline)."""
        if self.verdict_counts or self.verdict == "ok":
            return self.verdict
        return f"{self.verdict} · fingerprint since {baseline_label or 'the baseline'}"

    @property
    def verdict_counts(self) -> bool:
        """The axis' own verdict enters its status: not a pattern along the travel that is
        the machine's fingerprint, unchanged since the baseline."""
        return self.judged is None or not self.judged.notes

    def figures(self) -> AxisFigures:
        """The axis as the judgement reads it."""
        return AxisFigures(self.axis, self.unit, self.verdict, self.latest, self.signature)


@dataclass
class MachineOverview:
    """One machine: its latest measurement, its baseline, its axes."""

    serial: str
    machine_type: str
    site: str | None
    measurements: int
    latest_id: int
    latest_utc: str
    latest_label: str | None
    baseline_id: int
    baseline_utc: str
    baseline_label: str | None
    axes: dict[str, AxisOverview] = field(default_factory=dict)

    @property
    def status(self) -> Status:
        """The worst of the axes (ok when only the baseline is stored)."""
        return worst_status(a.status for a in self.axes.values())


@dataclass(frozen=True)
class FleetOverview:
    """:func:`fleet_overview`'s answer."""

    machines: list[MachineOverview]
    """Every machine with a measurement, by serial."""
    axes: list[str]
    """Every axis name in the fleet, sorted."""
    outliers: list[Outlier]
    """Largest |modified z| first."""
    types: dict[str, int]
    """Machines per machine type."""
    limits: Limits

    def count(self, status: Status) -> int:
        """Machines of that status."""
        return sum(m.status == status for m in self.machines)


def _chunks(ids: Sequence[int]) -> Iterator[list[int]]:
    for start in range(0, len(ids), _CHUNK):
        yield list(ids[start : start + _CHUNK])


def _axis_rows(store: Store, measurement_ids: Sequence[int]) -> dict[int, list[Any]]:
    with store.reading("read the fleet") as db:
        return axis_rows_in(db, measurement_ids)


def axis_rows_in(db: Connection, measurement_ids: Sequence[int]) -> dict[int, list[Any]]:
    """The axis rows of these measurements by measurement id (in the caller's connection)."""
    a = t.axis_results
    found: dict[int, list[Any]] = defaultdict(list)
    columns = [a.c.measurement_id, a.c.axis, a.c.unit, a.c.verdict, a.c.signature]
    columns += [a.c[c.name] for c in CHARACTERISTICS]
    for ids in _chunks(sorted(set(measurement_ids))):
        for row in db.execute(select(*columns).where(a.c.measurement_id.in_(ids))):
            found[row.measurement_id].append(row)
    return found


def _finite(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def fleet_overview(store: Store, limits: Limits | None = None) -> FleetOverview:
    """Every machine of the store × every axis: latest verdict, change, outliers.

    Raises:
        StoreError: The database failed.
    """
    limits = limits or Limits()
    s = t.machine_summaries
    with store.reading("read the fleet") as db:
        version = fleet_version(db)
        machines = db.execute(
            select(s).where(s.c.latest_id.is_not(None)).order_by(s.c.serial)
        ).all()
    overviews = overviews_of(machines)
    baselines = read_axes(store, overviews)
    # per (type, axis, unit, characteristic): the machines' latest values
    fleet: dict[tuple[str, str, str, str], list[tuple[AxisOverview, MachineOverview, float]]]
    fleet = defaultdict(list)
    for machine in overviews:
        for axis in machine.axes.values():
            for c in CHARACTERISTICS:
                value = axis.latest[c.name]
                if value is not None:
                    fleet[(machine.machine_type, axis.axis, axis.unit, c.name)].append(
                        (axis, machine, value)
                    )
    places: dict[tuple[str, str], dict[str, list[FleetPlace]]] = defaultdict(
        lambda: defaultdict(list)
    )
    outliers = _outliers(fleet, limits, places)
    changes = _changes(store, machines, overviews)
    for machine in overviews:
        judge(machine, baselines, places[(machine.serial, machine.machine_type)], changes, limits)
    types: dict[str, int] = defaultdict(int)
    for machine in overviews:
        types[machine.machine_type] += 1
    if store.write and limits == Limits():
        with store.writing("keep the statuses") as db:
            keep_statuses(db, {m.serial: m.status for m in overviews}, version)
    return FleetOverview(
        machines=overviews,
        axes=sorted({a for machine in overviews for a in machine.axes}),
        outliers=outliers,
        types=dict(sorted(types.items())),
        limits=limits,
    )


def overviews_of(machines: Sequence[Any]) -> list[MachineOverview]:
    """The machines of these summary rows (:data:`~ncmeasure.store.schema.machine_summaries`,
    with a latest measurement), their axes not yet read (:func:`read_axes`)."""
    return [
        MachineOverview(
            serial=found.serial,
            machine_type=found.machine_type,
            site=found.site,
            measurements=int(found.measurements),
            latest_id=int(found.latest_id),
            latest_utc=found.latest_utc,
            latest_label=found.latest_label,
            baseline_id=int(found.baseline_id),
            baseline_utc=found.baseline_utc,
            baseline_label=found.baseline_label,
        )
        for found in machines
    ]


def read_axes(
    store: Store, overviews: Sequence[MachineOverview]
) -> dict[str, dict[str, AxisFigures]]:
    """Fill in each machine's axes (its latest measurement's); returns the baselines'
    figures per serial, of the machines whose baseline is not their latest."""
    wanted = [i for m in overviews for i in (m.latest_id, m.baseline_id)]
    return fill_axes(overviews, _axis_rows(store, wanted))


def fill_axes(
    overviews: Sequence[MachineOverview], rows: dict[int, list[Any]]
) -> dict[str, dict[str, AxisFigures]]:
    """:func:`read_axes` of these axis rows (:func:`axis_rows_in` of the machines' latest
    and baseline measurements)."""
    baselines: dict[str, dict[str, AxisFigures]] = {}
    for machine in overviews:
        if machine.baseline_id != machine.latest_id:
            baselines[machine.serial] = {r.axis: _figures(r) for r in rows[machine.baseline_id]}
        for row in sorted(rows[machine.latest_id], key=lambda r: r.axis):
            machine.axes[row.axis] = AxisOverview(
                axis=row.axis,
                unit=row.unit,
                verdict=row.verdict,
                latest={c.name: _finite(getattr(row, c.name)) for c in CHARACTERISTICS},
                signature=row.signature,
            )
    return baselines


def judge(
    machine: MachineOverview,
    baselines: dict[str, dict[str, AxisFigures]],
    places: dict[str, list[FleetPlace]] | None,
    changes: dict[str, StoredChange],
    limits: Limits,
) -> None:
    """Judge the machine (:func:`~ncmeasure.analysis.judgement.status.machine_status`):
    each axis' status, reasons and changes; ``places`` None judges it without its fleet."""
    met = changes.get(machine.serial)
    judged = machine_status(
        {name: axis.figures() for name, axis in machine.axes.items()},
        baseline=baselines.get(machine.serial) if met is None or met.baseline_counts else None,
        fleet=places,
        limits=limits,
        changes=None if met is None else met.changes,
    )
    for name, axis in machine.axes.items():
        axis.judged = judged.axes[name]
        axis.changes = list(judged.axes[name].changes)


def changes_of(
    store: Store, machines: Sequence[Any], overviews: Sequence[MachineOverview]
) -> dict[str, StoredChange]:
    """Per serial: the stored change since the baseline (:func:`_changes`)."""
    return _changes(store, machines, overviews)


def _figures(row: Any) -> AxisFigures:
    return AxisFigures(
        row.axis,
        row.unit,
        row.verdict,
        {c.name: _finite(getattr(row, c.name)) for c in CHARACTERISTICS},
        row.signature,
    )


def _changes(
    store: Store, machines: Sequence[Any], overviews: Sequence[MachineOverview]
) -> dict[str, StoredChange]:
    """Per serial (with a baseline): the stored change since the baseline; where none is
    stored (a store filled by an older ncmeasure, or of another diagnosis version),
    compared now, and kept when the store is open for writing."""
    ids = {found.serial: found.machine_id for found in machines}
    pairs = {
        m.serial: (m.latest_id, m.baseline_id) for m in overviews if m.latest_id != m.baseline_id
    }
    computed: list[tuple[int, int, BaselineChange]] = []
    with store.reading("read the changes since the baselines") as db:
        stored = stored_changes(db, pairs.values())
        missing = [serial for serial, pair in pairs.items() if pair not in stored]
        found = {serial: stored[pair] for serial, pair in pairs.items() if pair in stored}
        for serial in missing:
            now = current_change(db, ids[serial])
            if now is not None:
                found[serial] = StoredChange.of(now[2])
                computed.append(now)
    if not missing:
        return found
    if store.write:
        with store.writing("store the changes since the baselines") as db:
            for latest_id, baseline_id, change in computed:
                store_change(db, latest_id, baseline_id, change)
        _log.warning(
            "%d machine(s) without a current stored change since their baseline (none "
            "stored, or of another diagnosis version): compared now and stored",
            len(missing),
        )
    else:
        _log.warning(
            "%d machine(s) without a current stored change since their baseline (none "
            "stored, or of another diagnosis version): compared now on every reading, which "
            "is slower; `ncmeasure store refresh` stores them",
            len(missing),
        )
    return found


def _outliers(
    fleet: dict[tuple[str, str, str, str], list[tuple[AxisOverview, MachineOverview, float]]],
    limits: Limits,
    places: dict[tuple[str, str], dict[str, list[FleetPlace]]],
) -> list[Outlier]:
    """The outliers of the fleet, all at once; ``places`` gets every axis' place in it."""
    by_name = {c.name: c for c in CHARACTERISTICS}
    found: list[Outlier] = []
    for (machine_type, axis_name, unit, name), members in fleet.items():
        others = len(members) - 1
        if others < 1:
            continue
        values = np.array([value for _, _, value in members])
        enough = others >= limits.outlier_min_runs
        z, medians = modified_z_leave_one_out(values)
        c = by_name[name]
        shown = c.unit_of(unit)
        for (axis, machine, value), zi, median in zip(members, z, medians, strict=True):
            places[(machine.serial, machine_type)][axis.axis].append(
                FleetPlace(name, float(median), float(zi) if enough else None, others)
            )
            if enough and is_outlier(c, value, float(median), float(zi), limits):
                outlier = Outlier(
                    serial=machine.serial,
                    machine_type=machine_type,
                    axis=axis_name,
                    characteristic=name,
                    unit=shown,
                    value=value,
                    fleet_median=float(median),
                    modified_z=float(zi),
                    machines=others,
                )
                axis.outliers.append(outlier)
                found.append(outlier)
    found.sort(key=lambda o: (-abs(o.modified_z), o.serial, o.axis, o.characteristic))
    return found
