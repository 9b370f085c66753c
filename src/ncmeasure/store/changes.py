"""The change of a machine's latest measurement since its baseline, computed once and stored.

``store check`` compares the two measurements (:func:`compare_with_baseline`:
the comparability rules, then
:func:`~ncmeasure.analysis.judgement.compare.compare_results`); the diagnosis of
each axis' change (:class:`~ncmeasure.analysis.judgement.status.ChangeFigures`)
enters the machine's status. Every other surface (``store report``, the
dashboard, the REST API, MQTT, OPC UA) reads the same diagnosis from the store
instead of comparing again: :func:`record_changes` stores it when a measurement
is added, for the machine's pair (latest, baseline), and :func:`stored_changes`
reads it back for many machines in a few queries.

The baseline is the first measurement labelled ``delivery``, else the first
(:func:`baseline_of`). A stored diagnosis is that of one
:data:`DIAGNOSIS_VERSION`: a row of another (or none, in a store filled before
these rows existed) is not trusted. The fleet overview computes it again when it
reads it (:func:`current_change`), which is right but slower, and keeps it when
the store is open for writing; ``ncmeasure store refresh`` recomputes every such
row at once (:func:`stale_machines`, :func:`refresh_machine`).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Mapping, MutableMapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol, TypeVar

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import Connection, and_, delete, insert, select, tuple_

from ncmeasure.analysis.judgement.compare import (
    POSITION_MATCH_TOLERANCE_MM,
    change_diagnosis,
    compare_results,
)
from ncmeasure.analysis.judgement.status import ChangeFigures
from ncmeasure.errors import ComparisonError
from ncmeasure.formats.comparison import Comparison, Limits
from ncmeasure.formats.results import Results
from ncmeasure.store import schema as t
from ncmeasure.store.records import MeasurementSummary
from ncmeasure.store.rows import decompress
from ncmeasure.store.writing import insert_ignore

__all__ = [
    "DIAGNOSIS_VERSION",
    "TEMPERATURE_WARNING_K",
    "BaselineChange",
    "Comparability",
    "Outcome",
    "StoredChange",
    "baseline_of",
    "comparability",
    "compare_with_baseline",
    "current_change",
    "diagnose_with_baseline",
    "measurement_summaries",
    "record_changes",
    "refresh_machine",
    "stale_machines",
    "store_change",
    "stored_changes",
    "verdicts_of",
]

DIAGNOSIS_VERSION = 1
"""The version of the stored diagnoses of the change since the baseline: a row of another
is computed again. Bump it whenever the change diagnosis (``judgement.compare``,
``judgement.diagnosis``, :func:`compare_with_baseline`, the comparability rules) or the
status rules (``judgement.status``, ``judgement.verdict``) change what a stored row means;
not tied to ``__version__``, which stays the same while such code changes in development
and changes for releases that leave the rows valid."""

Outcome = Literal["compared", "refused", "failed"]
"""How the latest measurement met its baseline: compared; refused by the comparability
rules (the baseline does not count); or no point matched (the baseline's figures count,
there is no diagnosis of the change)."""

_CHUNK = 500  # pairs per query: far below every database's parameter limit

_KEPT = 64
"""Results read back that :func:`record_changes` keeps for the next batch (baselines)."""

TEMPERATURE_WARNING_K = 5.0
"""Temperatures further apart than this make a comparison doubtful: the lubricant's
viscosity, and with it viscous friction, changes by several percent per kelvin."""


class Comparability(BaseModel):
    """What differs between two measurements, and whether that invalidates comparing them."""

    model_config = ConfigDict(frozen=True)

    differences: list[str] = Field(
        default_factory=list, description="Differences that weaken the comparison."
    )
    refused: str | None = Field(default=None, description="Why the two cannot be compared at all.")


def _positions(results: Results, axis: str) -> list[float]:
    return [p.position_mm for p in results.axes[axis].positions]


def _speeds(results: Results, axis: str) -> set[float]:
    return {
        round(abs(point.velocity_mm_min), 1)
        for position in results.axes[axis].positions
        for found in position.directions.values()
        if found is not None
        for point in found.points
    }


def comparability(
    base: MeasurementSummary,
    base_results: Results,
    other: MeasurementSummary,
    other_results: Results,
) -> Comparability:
    """What differs between two measurements of one machine (docs/fleet.md, the rules).

    Refused: no axis in common, or an axis measured in another quantity (Nm
    against A). Warnings: another program (config hash), other positions or
    velocities, temperatures more than :data:`TEMPERATURE_WARNING_K` apart (or
    one unknown), another link.
    """
    differences: list[str] = []
    common = sorted(set(base_results.axes) & set(other_results.axes))
    if not common:
        return Comparability(
            refused=f"no axis in common ({', '.join(base_results.axes)} against "
            f"{', '.join(other_results.axes)})"
        )
    for axis in common:
        b, o = base_results.axes[axis], other_results.axes[axis]
        if b.quantity != o.quantity:
            return Comparability(
                refused=f"axis {axis} is in {b.unit} in one and {o.unit} in the other "
                "measurement (a torque constant was given only once); analyse both alike"
            )
    if base.config_hash != other.config_hash:
        differences.append(
            f"another program: config {base.config_hash or '(none)'} against "
            f"{other.config_hash or '(none)'}; only the points both measured are compared"
        )
    for axis in common:
        bp, op = _positions(base_results, axis), _positions(other_results, axis)
        matched = sum(any(abs(x - y) <= POSITION_MATCH_TOLERANCE_MM for y in op) for x in bp)
        if matched < len(bp) or len(op) != len(bp):
            differences.append(
                f"axis {axis}: positions differ ({matched} of {len(bp)} within "
                f"{POSITION_MATCH_TOLERANCE_MM:g} mm)"
            )
        bs, os_ = _speeds(base_results, axis), _speeds(other_results, axis)
        if bs != os_:
            shared = len(bs & os_)
            differences.append(
                f"axis {axis}: velocities differ ({shared} of {len(bs)} velocity steps in common)"
            )
    temperatures = (base.temperature_c, other.temperature_c)
    if None in temperatures:
        if temperatures != (None, None):
            differences.append(
                "temperature known for only one measurement: a warm machine has less friction"
            )
    else:
        t_base, t_other = temperatures
        assert t_base is not None and t_other is not None
        if abs(t_base - t_other) > TEMPERATURE_WARNING_K:
            differences.append(
                f"temperatures differ by {abs(t_base - t_other):.1f} K ({t_base:g} °C against "
                f"{t_other:g} °C): "
                "friction falls as the machine warms; measure at a similar temperature"
            )
    if base.link != other.link:
        differences.append(
            f"measured through another link ({base.link} against {other.link}): current "
            "scaling and filtering may differ"
        )
    return Comparability(differences=differences)


class _Labelled(Protocol):
    @property
    def label(self) -> str | None: ...


_M = TypeVar("_M", bound=_Labelled)


def baseline_of(measurements: Sequence[_M]) -> _M:
    """The baseline among a machine's measurements (oldest first): the first labelled
    ``delivery``, else the first."""
    return next((m for m in measurements if m.label == "delivery"), measurements[0])


@dataclass(frozen=True)
class BaselineChange:
    """The latest measurement against its baseline: :func:`compare_with_baseline`'s answer."""

    outcome: Outcome
    rules: Comparability
    """What differs; ``refused`` says why they were not compared (also when no point matched)."""
    comparison: Comparison | None
    findings: tuple[str, ...]
    """What ``store check`` says of it: the comparison's findings, or why not compared."""

    @property
    def baseline_counts(self) -> bool:
        """The baseline's figures enter the status (not when the rules refused the pair)."""
        return self.outcome != "refused"

    @property
    def changes(self) -> dict[str, ChangeFigures] | None:
        """Per axis, the diagnosis of the change (None when not compared)."""
        if self.comparison is None:
            return None
        return {c.axis: ChangeFigures.of(c) for c in self.comparison.changes}


def compare_with_baseline(
    baseline: MeasurementSummary,
    base_results: Results,
    latest: MeasurementSummary,
    latest_results: Results,
    limits: Limits | None = None,
) -> BaselineChange:
    """The comparability rules, then the comparison of ``latest`` with ``baseline``.

    The labels are the measurements' labels (``measurement ID`` without one; the
    latest's date added when both are alike). The diagnosis of the change
    (:attr:`BaselineChange.changes`) does not depend on ``limits``: only the
    comparison's statuses and findings do.
    """
    rules = comparability(baseline, base_results, latest, latest_results)
    if rules.refused is not None:
        return BaselineChange(
            "refused", rules, None, (f"not compared with the baseline: {rules.refused}",)
        )
    base_label = baseline.label or f"measurement {baseline.id}"
    other_label = latest.label or f"measurement {latest.id}"
    if other_label == base_label:
        other_label = f"{other_label} ({latest.measured_utc[:10]})"
    try:
        comparison = compare_results(
            base_results, [latest_results], labels=[base_label, other_label], limits=limits
        )
    except ComparisonError as exc:
        failed = Comparability(differences=rules.differences, refused=exc.message)
        return BaselineChange(
            "failed", failed, None, (f"not compared with the baseline: {exc.message}",)
        )
    return BaselineChange("compared", rules, comparison, tuple(comparison.findings))


@dataclass(frozen=True)
class StoredChange:
    """What the status needs of a (latest, baseline) pair: whether the baseline counts, and
    per axis the diagnosis of the change (None when not compared)."""

    baseline_counts: bool
    changes: Mapping[str, ChangeFigures] | None

    @classmethod
    def of(cls, found: BaselineChange) -> StoredChange:
        """The stored form of a comparison with the baseline."""
        return cls(found.baseline_counts, found.changes)


# ------------------------------------------------------------------------ rows


def verdicts_of(db: Connection, measurement_ids: Sequence[int]) -> dict[int, dict[str, str]]:
    """Per measurement: each axis' verdict."""
    found: dict[int, dict[str, str]] = {m: {} for m in measurement_ids}
    if not measurement_ids:
        return found
    a = t.axis_results
    for row in db.execute(
        select(a.c.measurement_id, a.c.axis, a.c.verdict)
        .where(a.c.measurement_id.in_(list(measurement_ids)))
        .order_by(a.c.axis)
    ):
        found[row.measurement_id][row.axis] = row.verdict
    return found


_SUMMARY_COLUMNS = (
    t.measurements.c.id,
    t.measurements.c.measured_utc,
    t.measurements.c.label,
    t.measurements.c.operator,
    t.measurements.c.temperature_c,
    t.measurements.c.operating_hours,
    t.measurements.c.link,
    t.measurements.c.config_hash,
    t.measurements.c.ncmeasure_version,
    t.measurements.c.recording_location,
)


def _summary(row: Any, verdicts: Mapping[int, dict[str, str]]) -> MeasurementSummary:
    return MeasurementSummary(
        id=row.id,
        measured_utc=row.measured_utc,
        label=row.label,
        operator=row.operator,
        temperature_c=row.temperature_c,
        operating_hours=row.operating_hours,
        link=row.link,
        config_hash=row.config_hash,
        ncmeasure_version=row.ncmeasure_version,
        recording_location=row.recording_location,
        verdicts=verdicts[row.id],
    )


def measurement_summaries(db: Connection, machine_id: int) -> list[MeasurementSummary]:
    """A machine's measurements, oldest first (by time, then id)."""
    m = t.measurements
    rows = db.execute(
        select(*_SUMMARY_COLUMNS)
        .where(m.c.machine_id == machine_id)
        .order_by(m.c.measured_utc, m.c.id)
    ).all()
    verdicts = verdicts_of(db, [r.id for r in rows])
    return [_summary(r, verdicts) for r in rows]


def _results(db: Connection, measurement_id: int) -> Results:
    stored = db.execute(
        select(t.measurements.c.results_json).where(t.measurements.c.id == measurement_id)
    ).scalar_one()
    return decompress(stored)


def current_change(db: Connection, machine_id: int) -> tuple[int, int, BaselineChange] | None:
    """The machine's (latest, baseline) pair and their comparison, computed now; None when
    the latest is the baseline (or the machine has no measurement)."""
    latest_id = db.execute(
        select(t.machines.c.latest_measurement_id).where(t.machines.c.id == machine_id)
    ).scalar_one_or_none()
    measured = measurement_summaries(db, machine_id)
    if latest_id is None or not measured:
        return None
    baseline = baseline_of(measured)
    if baseline.id == latest_id:
        return None
    latest = next(m for m in measured if m.id == latest_id)
    found = compare_with_baseline(
        baseline, _results(db, baseline.id), latest, _results(db, latest_id)
    )
    return latest_id, baseline.id, found


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def store_change(db: Connection, latest_id: int, baseline_id: int, found: BaselineChange) -> None:
    """Store the comparison of a (latest, baseline) pair as of :data:`DIAGNOSIS_VERSION`,
    replacing a row of another version (in the caller's transaction)."""
    _store_diagnosis(db, latest_id, baseline_id, found.outcome, found.changes)


def diagnose_with_baseline(
    baseline: MeasurementSummary,
    base_results: Results,
    latest: MeasurementSummary,
    latest_results: Results,
) -> tuple[Outcome, dict[str, ChangeFigures] | None]:
    """What :func:`store_change` keeps of :func:`compare_with_baseline`'s answer (the
    outcome and the diagnosis of each axis' change), without the rest of the comparison
    (its statuses, groups and findings, which only ``store check`` shows)."""
    rules = comparability(baseline, base_results, latest, latest_results)
    if rules.refused is not None:
        return "refused", None
    try:
        found = change_diagnosis(base_results, latest_results)
    except ComparisonError:
        return "failed", None
    return "compared", {c.axis: ChangeFigures.of(c) for c in found}


def _store_diagnosis(
    db: Connection,
    latest_id: int,
    baseline_id: int,
    outcome: Outcome,
    changes: Mapping[str, ChangeFigures] | None,
) -> None:
    pair = and_(
        t.baseline_changes.c.measurement_id == latest_id,
        t.baseline_changes.c.baseline_id == baseline_id,
    )
    db.execute(
        delete(t.axis_changes).where(
            t.axis_changes.c.measurement_id == latest_id,
            t.axis_changes.c.baseline_id == baseline_id,
        )
    )
    db.execute(delete(t.baseline_changes).where(pair))  # another version's
    stored = db.execute(
        insert_ignore(db, t.baseline_changes)
        .values(
            measurement_id=latest_id,
            baseline_id=baseline_id,
            outcome=outcome,
            diagnosis_version=DIAGNOSIS_VERSION,
        )
        .returning(t.baseline_changes.c.measurement_id)
    ).first()
    if stored is None or not changes:  # another writer stored the pair meanwhile
        return
    db.execute(
        insert(t.axis_changes),
        [
            {
                "measurement_id": latest_id,
                "baseline_id": baseline_id,
                "axis": axis,
                "signature": change.signature,
                "cause": change.cause,
                "spread_percent": _finite(change.spread_percent),
                "mean_percent": _finite(change.mean_percent),
            }
            for axis, change in sorted(changes.items())
        ],
    )


def record_changes(
    db: Connection,
    serials: Iterable[str],
    known: Mapping[int, Results] | None = None,
    kept: MutableMapping[int, Results] | None = None,
) -> int:
    """Store the change since the baseline of these machines' current (latest, baseline)
    pair where it is not stored as of :data:`DIAGNOSIS_VERSION` (in the caller's transaction).

    One pass for the batch: the machines' histories, the stored pairs and the verdicts in a
    few queries, then one comparison per machine whose pair is new (a batch of a machine's
    ten measurements compares once, its latest with its baseline).

    Args:
        db: The transaction.
        serials: The machines.
        known: Results at hand by measurement id (those just added): not read back.
        kept: Results read back by measurement id (committed ones: the baselines),
            filled and reused across batches.

    Returns:
        The pairs compared.
    """
    ids = sorted(
        int(i)
        for chunk in _chunks_of(sorted(set(serials)))
        for i in db.execute(select(t.machines.c.id).where(t.machines.c.serial.in_(chunk)))
        .scalars()
        .all()
    )
    if not ids:
        return 0
    m = t.measurements
    latest: dict[int, int] = {}
    history: dict[int, list[Any]] = {}
    for chunk in _chunks_of(ids):
        for found in db.execute(
            select(t.machines.c.id, t.machines.c.latest_measurement_id).where(
                t.machines.c.id.in_(chunk), t.machines.c.latest_measurement_id.is_not(None)
            )
        ):
            latest[int(found.id)] = int(found.latest_measurement_id)
        for row in db.execute(
            select(*_SUMMARY_COLUMNS, m.c.machine_id)
            .where(m.c.machine_id.in_(chunk))
            .order_by(m.c.machine_id, m.c.measured_utc, m.c.id)
        ):
            history.setdefault(int(row.machine_id), []).append(row)
    pairs: dict[tuple[int, int], tuple[Any, Any]] = {}
    for machine_id, latest_id in latest.items():
        measured = history.get(machine_id)
        if not measured:
            continue
        baseline = baseline_of(measured)
        if baseline.id != latest_id:
            newest = next(r for r in measured if r.id == latest_id)
            pairs[(latest_id, int(baseline.id))] = (newest, baseline)
    todo = sorted(set(pairs) - _versioned(db, sorted(pairs)))
    if not todo:
        return 0
    verdicts = verdicts_of(db, sorted({i for pair in todo for i in pair}))
    known = known or {}
    kept = kept if kept is not None else {}

    def results(measurement_id: int) -> Results:
        if measurement_id in known:
            return known[measurement_id]
        if measurement_id not in kept:
            if len(kept) >= _KEPT:
                del kept[next(iter(kept))]
            kept[measurement_id] = _results(db, measurement_id)
        return kept[measurement_id]

    for latest_id, baseline_id in todo:
        newest, baseline = pairs[(latest_id, baseline_id)]
        outcome, changes = diagnose_with_baseline(
            _summary(baseline, verdicts),
            results(baseline_id),
            _summary(newest, verdicts),
            results(latest_id),
        )
        _store_diagnosis(db, latest_id, baseline_id, outcome, changes)
    return len(todo)


def refresh_machine(db: Connection, machine_id: int) -> bool:
    """Compare the machine's current (latest, baseline) pair again and store it (in the
    caller's transaction), whatever is stored; False when it has no such pair."""
    found = current_change(db, machine_id)
    if found is None:
        return False
    store_change(db, *found)
    return True


def stale_machines(db: Connection) -> list[int]:
    """The ids of the machines whose current (latest, baseline) pair has no stored change of
    :data:`DIAGNOSIS_VERSION` (none yet, or of another version), by id; in a few queries."""
    m, ms = t.machines, t.measurements
    latest = {
        int(row.id): int(row.latest_measurement_id)
        for row in db.execute(
            select(m.c.id, m.c.latest_measurement_id).where(m.c.latest_measurement_id.is_not(None))
        )
    }
    history: dict[int, list[Any]] = {}
    for row in db.execute(
        select(ms.c.id, ms.c.machine_id, ms.c.label).order_by(
            ms.c.machine_id, ms.c.measured_utc, ms.c.id
        )
    ):
        history.setdefault(int(row.machine_id), []).append(row)
    pairs: dict[tuple[int, int], int] = {}
    for machine_id, latest_id in latest.items():
        measured = history.get(machine_id)
        if not measured:
            continue
        baseline = int(baseline_of(measured).id)
        if baseline != latest_id:
            pairs[(latest_id, baseline)] = machine_id
    current = _versioned(db, sorted(pairs))
    return sorted(machine_id for pair, machine_id in pairs.items() if pair not in current)


def _chunks_of(values: Sequence[Any]) -> Iterable[list[Any]]:
    for start in range(0, len(values), _CHUNK):
        yield list(values[start : start + _CHUNK])


def _chunks(pairs: Sequence[tuple[int, int]]) -> Iterable[list[tuple[int, int]]]:
    for start in range(0, len(pairs), _CHUNK):
        yield list(pairs[start : start + _CHUNK])


def _versioned(db: Connection, pairs: Sequence[tuple[int, int]]) -> set[tuple[int, int]]:
    """The pairs whose change is stored as of :data:`DIAGNOSIS_VERSION`."""
    b = t.baseline_changes
    found: set[tuple[int, int]] = set()
    for chunk in _chunks(pairs):
        for row in db.execute(
            select(b.c.measurement_id, b.c.baseline_id).where(
                tuple_(b.c.measurement_id, b.c.baseline_id).in_(chunk),
                b.c.diagnosis_version == DIAGNOSIS_VERSION,
            )
        ):
            found.add((row.measurement_id, row.baseline_id))
    return found


def _figures(row: Any) -> ChangeFigures:
    def number(value: float | None) -> float:
        return float(value) if value is not None else math.nan

    return ChangeFigures(
        row.signature, row.cause, number(row.spread_percent), number(row.mean_percent)
    )


def stored_changes(
    db: Connection, pairs: Collection[tuple[int, int]]
) -> dict[tuple[int, int], StoredChange]:
    """The stored change of each (latest, baseline) pair, as of :data:`DIAGNOSIS_VERSION`;
    the others (none stored, or of another version) are missing."""
    wanted = sorted(set(pairs))
    b, a = t.baseline_changes, t.axis_changes
    outcomes: dict[tuple[int, int], str] = {}
    axes: dict[tuple[int, int], dict[str, ChangeFigures]] = {}
    for chunk in _chunks(wanted):
        latest = sorted({pair[0] for pair in chunk})  # lets SQLite use the primary key
        for row in db.execute(
            select(b.c.measurement_id, b.c.baseline_id, b.c.outcome).where(
                b.c.measurement_id.in_(latest),
                tuple_(b.c.measurement_id, b.c.baseline_id).in_(chunk),
                b.c.diagnosis_version == DIAGNOSIS_VERSION,
            )
        ):
            outcomes[(row.measurement_id, row.baseline_id)] = row.outcome
        for row in db.execute(
            select(a).where(
                a.c.measurement_id.in_(latest),
                tuple_(a.c.measurement_id, a.c.baseline_id).in_(chunk),
            )
        ):
            axes.setdefault((row.measurement_id, row.baseline_id), {})[row.axis] = _figures(row)
    return {
        pair: StoredChange(
            outcome != "refused", axes.get(pair, {}) if outcome == "compared" else None
        )
        for pair, outcome in outcomes.items()
    }
