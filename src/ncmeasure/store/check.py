"""``store check``: a machine's latest measurement against its delivery baseline and its fleet.

Against the baseline (the first measurement labelled ``delivery``, else the
first), the comparison is :func:`~ncmeasure.analysis.judgement.compare.compare_results`,
with its limits and exit status, after the comparability rules
(:func:`~ncmeasure.store.changes.comparability`) have said what differs between the
two measurements: :func:`~ncmeasure.store.changes.compare_with_baseline`, the function
that also stores the change for the other surfaces (the fleet overview).

Against the fleet (the latest measurement of every other machine of its type),
each characteristic (:data:`~ncmeasure.store.rows.CHARACTERISTICS`) of each
axis gets the fleet's median, its spread (MAD) and the machine's robust
modified z-score; beyond the outlier limit (3.5) the machine is an outlier of
its type, a warning. Fewer than ``Limits.outlier_min_runs`` other machines
name no outlier.
"""

from __future__ import annotations

import json
import os
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import func, select

from ncmeasure.analysis.judgement.fleet import modified_z_against
from ncmeasure.analysis.judgement.status import (
    CHARACTERISTICS,
    AxisFigures,
    FleetPlace,
    figures_of,
    is_outlier,
    machine_status,
)
from ncmeasure.files import write_whole
from ncmeasure.formats.comparison import Comparison, Limits, Status
from ncmeasure.formats.results import Results
from ncmeasure.store import schema as t
from ncmeasure.store.changes import (
    BaselineChange,
    Comparability,
    baseline_of,
    compare_with_baseline,
)
from ncmeasure.store.database import plain_columns
from ncmeasure.store.records import MeasurementSummary, check_serial
from ncmeasure.store.store import Store

if TYPE_CHECKING:
    from ncmeasure.store.statuses import FleetStatuses

__all__ = [
    "FleetFigure",
    "StoreCheck",
    "check_json",
    "check_machine",
    "write_check",
]


class FleetFigure(BaseModel):
    """One characteristic of one axis against the other machines of the type."""

    model_config = ConfigDict(frozen=True)

    axis: str
    characteristic: str
    unit: str
    value: float
    fleet_median: float
    fleet_low: float
    fleet_high: float
    machines: int
    modified_z: float | None = Field(description="None when the fleet is too small.")
    outlier: bool


class StoreCheck(BaseModel):
    """A machine's latest measurement against its delivery baseline and its fleet."""

    model_config = ConfigDict(frozen=True)

    serial: str
    machine_type: str
    latest: MeasurementSummary
    baseline: MeasurementSummary | None = Field(
        description="The first measurement labelled delivery, else the first; None if only one."
    )
    comparability: Comparability | None
    comparison: Comparison | None = Field(description="The comparison with the baseline.")
    fleet: list[FleetFigure]
    fleet_machines: int = Field(description="Other machines of the type with a measurement.")
    findings: list[str]
    status: Status = Field(
        description="ok, warning or critical: the one rule of ncmeasure.analysis.judgement.status."
    )
    axis_status: dict[str, Status] = Field(
        default_factory=dict, description="Per axis: its status by the same rule."
    )


@dataclass(frozen=True)
class _Reference:
    """One characteristic of one axis over the other machines of the type: their finite
    values, sorted (the figures do not hang on the order the database returns them in)."""

    values: NDArray[np.float64]

    def figures(self, value: float, enough: bool) -> tuple[float | None, float, float, float]:
        """The value's modified z (None unless ``enough`` others), the others' median, low
        and high."""
        x = self.values
        return (
            modified_z_against(value, x) if enough else None,
            float(np.median(x)),
            float(x[0]),
            float(x[-1]),
        )


def _fleet_values(
    store: Store, type_id: int, machine_id: int
) -> dict[tuple[str, str], dict[str, _Reference]]:
    """Per (axis, unit) and characteristic: the finite values of the other machines' latest
    measurements.

    One query, answered from two indexes alone (``ix_machines_type_latest``,
    ``ix_axis_results_figures``), read as columns of the driver's plain values
    (:func:`~ncmeasure.store.database.plain_columns`; ten thousand machines are some
    40,000 rows).
    """
    a, m = t.axis_results, t.machines
    columns = [a.c[c.name] for c in CHARACTERISTICS]
    with store.reading("read the fleet") as db:
        read = plain_columns(
            db,
            select(a.c.axis, a.c.unit, *columns)
            .join(m, m.c.latest_measurement_id == a.c.measurement_id)
            .where(m.c.type_id == type_id, m.c.id != machine_id),
        )
    if not read:
        return {}
    names, units, *figures = read
    groups: dict[tuple[str, str], int] = {}
    codes = np.fromiter(
        (groups.setdefault(key, len(groups)) for key in zip(names, units, strict=True)),
        dtype=np.intp,
        count=len(names),
    )
    table = [np.array(f, dtype=np.float64) for f in figures]  # None becomes NaN
    values: dict[tuple[str, str], dict[str, _Reference]] = {}
    for key, code in groups.items():
        members = codes == code
        found: dict[str, _Reference] = {}
        for c, column in zip(CHARACTERISTICS, table, strict=True):
            x = column[members]
            x = x[np.isfinite(x)]
            if x.size:
                found[c.name] = _Reference(np.sort(x))
        values[key] = found
    return values


def _fleet(
    store: Store,
    machine_type_id: int,
    machine_id: int,
    latest: Results,
    limits: Limits,
    statuses: FleetStatuses | None,
) -> tuple[list[FleetFigure], int]:
    kept = statuses.type_values(machine_id) if statuses is not None else None
    if kept is not None:
        values = {
            key: {name: _Reference(x) for name, x in found.items()}
            for key, found in kept[0].items()
        }
        machines = kept[1]
    else:
        values = _fleet_values(store, machine_type_id, machine_id)
        with store.reading("read the fleet") as db:
            machines = db.execute(
                select(func.count()).where(
                    t.machines.c.type_id == machine_type_id,
                    t.machines.c.id != machine_id,
                    t.machines.c.latest_measurement_id.is_not(None),
                )
            ).scalar_one()
    from ncmeasure.store.rows import rows_of_axis

    figures: list[FleetFigure] = []
    for name, axis in sorted(latest.axes.items()):
        own = rows_of_axis(name, axis).axis
        for c in CHARACTERISTICS:
            value = own[c.name]
            reference = values.get((name, axis.unit), {}).get(c.name)
            if value is None or reference is None:
                continue
            count = int(reference.values.size)
            z, median, low, high = reference.figures(value, count >= limits.outlier_min_runs)
            unit = c.unit_of(axis.unit)
            figures.append(
                FleetFigure(
                    axis=name,
                    characteristic=c.name,
                    unit=unit,
                    value=value,
                    fleet_median=median,
                    fleet_low=low,
                    fleet_high=high,
                    machines=count,
                    modified_z=z,
                    outlier=is_outlier(c, value, median, z, limits),
                )
            )
    return figures, int(machines)


def check_machine(
    store: Store,
    serial: str,
    limits: Limits | None = None,
    statuses: FleetStatuses | None = None,
) -> StoreCheck:
    """A machine's latest measurement against its baseline and its fleet.

    Args:
        store: The store.
        serial: The machine.
        limits: The limits (default: :class:`~ncmeasure.formats.comparison.Limits`).
        statuses: The fleet's statuses as read for the store as it is now
            (:func:`~ncmeasure.store.statuses.fleet_statuses`): the other machines'
            figures are taken from them instead of read again.

    Raises:
        ConfigError: No such machine, or it has no measurement.
        StoreError: The database failed.
    """
    limits = limits or Limits()
    check_serial(serial)
    summary, measurements = store.machine(serial)
    with store.reading("read the machine") as db:
        machine = store.machine_row(db, serial)
    latest = next(m for m in measurements if m.id == machine.latest_measurement_id)
    latest_results = store.results(latest.id)
    findings: list[str] = []
    first = baseline_of(measurements)
    baseline = first if first.id != latest.id else None
    met: BaselineChange | None = None
    base_figures: dict[str, AxisFigures] | None = None
    if baseline is None:
        findings.append("only the baseline is stored: nothing to compare over the machine's life")
    else:
        base_results = store.results(baseline.id)
        met = compare_with_baseline(baseline, base_results, latest, latest_results, limits)
        findings.extend(met.findings)
        if met.baseline_counts:
            base_figures = figures_of(base_results)
    fleet, fleet_machines = _fleet(
        store, machine.type_id, machine.id, latest_results, limits, statuses
    )
    if fleet_machines < limits.outlier_min_runs:
        findings.append(
            f"{fleet_machines} other machine(s) of type {summary.machine_type!r} in the store: "
            f"at least {limits.outlier_min_runs} are needed to name outliers"
        )
    places: dict[str, list[FleetPlace]] = defaultdict(list)
    for figure in fleet:
        places[figure.axis].append(
            FleetPlace(
                figure.characteristic, figure.fleet_median, figure.modified_z, figure.machines
            )
        )
    judged = machine_status(
        figures_of(latest_results),
        baseline=base_figures,
        fleet=places,
        limits=limits,
        changes=None if met is None else met.changes,
    )
    findings.extend(judged.reasons)
    status = judged.status
    return StoreCheck(
        serial=serial,
        machine_type=summary.machine_type,
        latest=latest,
        baseline=baseline,
        comparability=None if met is None else met.rules,
        comparison=None if met is None else met.comparison,
        fleet=fleet,
        fleet_machines=fleet_machines,
        findings=findings,
        status=status,
        axis_status={name: a.status for name, a in judged.axes.items()},
    )


def check_json(check: StoreCheck) -> dict[str, Any]:
    """The check as a JSON object (``store check -o``, the REST API)."""
    return {"format": "ncmeasure-store-check", "format_version": 1, **check.model_dump(mode="json")}


def write_check(check: StoreCheck, path: str | os.PathLike[str]) -> Path:
    """Write :func:`check_json` to ``path`` (replaced whole, never half written).

    Raises:
        OutputError: The file cannot be written.
    """
    return write_whole(path, json.dumps(check_json(check), indent=2, allow_nan=False) + "\n")
