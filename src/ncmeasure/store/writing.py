"""Adding a measurement to the store: its machine, type, axes and rows, in one transaction.

:meth:`~ncmeasure.store.store.Store.add_many` opens the transaction and calls
:func:`add_measurement` for each measurement; the functions here work on that
connection and never commit.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import Connection, and_, insert, or_, select, update

from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results
from ncmeasure.store import schema as t
from ncmeasure.store.records import Added, MeasurementInfo, utc_text
from ncmeasure.store.rows import compress, rows_of_axis

__all__ = ["add_measurement", "find_machine", "insert_ignore"]


def find_machine(db: Connection, serial: str) -> Any:
    """The machine's row with its type (see :meth:`machine_row`), None when absent."""
    return db.execute(
        select(
            t.machines.c.id,
            t.machines.c.serial,
            t.machines.c.site,
            t.machines.c.type_id,
            t.machines.c.latest_measurement_id,
            t.machine_types.c.name.label("type_name"),
            t.machine_types.c.config_hash,
        )
        .join(t.machine_types, t.machine_types.c.id == t.machines.c.type_id)
        .where(t.machines.c.serial == serial)
    ).first()


def _existing(db: Connection, digest: str, serial: str) -> Added | None:
    found = db.execute(
        select(t.measurements.c.id, t.machines.c.serial)
        .join(t.machines, t.machines.c.id == t.measurements.c.machine_id)
        .where(t.measurements.c.results_sha256 == digest)
    ).first()
    if found is None:
        return None
    if found.serial != serial:
        raise ConfigError(
            f"these results are already stored as measurement {found.id} of machine "
            f"{found.serial!r}, not {serial!r}; one measurement belongs to one machine"
        )
    return Added(measurement_id=found.id, serial=serial, new=False)


def _get_or_create(db: Connection, table: Any, key: dict[str, Any], extra: dict[str, Any]) -> Any:
    where = and_(*(table.c[name] == value for name, value in key.items()))
    row = db.execute(select(table).where(where)).first()
    if row is not None:
        return row
    db.execute(insert_ignore(db, table).values(**key, **extra))
    return db.execute(select(table).where(where)).one()


def add_measurement(
    db: Connection, results: Results, info: MeasurementInfo, canonical: bytes, digest: str
) -> Added:
    recorded = results.recording
    if recorded.serial is not None and recorded.serial != info.serial:
        raise ConfigError(
            f"these results are of machine {recorded.serial!r} (recording.serial), "
            f"not {info.serial!r}: store them under {recorded.serial!r}"
        )
    existing = _existing(db, digest, info.serial)
    if existing is not None:
        return existing
    now = utc_text(None, "now")
    config_hash = recorded.config_hash or ""
    measured_text = info.measured_utc or recorded.start_utc
    if measured_text is None:
        raise ConfigError(
            f"measurement of {info.serial!r}: the measurement's time is unknown (the import "
            "found no date): store it with --measured-at"
        )
    measured = utc_text(measured_text, "measured time")
    machine = find_machine(db, info.serial)
    type_name = info.machine_type or recorded.machine
    if machine is None and type_name is None:
        raise ConfigError(
            f"machine {info.serial!r} is new to the store and the results name no machine "
            "type: name the machine type: --type TYPE, or analyse with --machine FILE"
        )
    if machine is not None and info.machine_type and machine.type_name != info.machine_type:
        raise ConfigError(
            f"machine {info.serial!r} is of type {machine.type_name!r}, not {info.machine_type!r}"
        )
    if machine is None:
        assert type_name is not None
        kind = _get_or_create(
            db,
            t.machine_types,
            {"name": type_name, "config_hash": config_hash},
            {"created_utc": now},
        )
        _get_or_create(
            db,
            t.machines,
            {"serial": info.serial},
            {"type_id": kind.id, "site": info.site, "created_utc": now},
        )
        machine = find_machine(db, info.serial)
        assert machine is not None
    if info.site is not None and machine.site != info.site:
        db.execute(update(t.machines).where(t.machines.c.id == machine.id).values(site=info.site))
    kind = _get_or_create(
        db,
        t.machine_types,
        {"name": machine.type_name, "config_hash": config_hash},
        {"created_utc": now},
    )
    inserted = db.execute(
        insert_ignore(db, t.measurements)
        .values(
            machine_id=machine.id,
            type_id=kind.id,
            measured_utc=measured,
            added_utc=now,
            label=info.label,
            operator=info.operator,
            temperature_c=info.temperature_c,
            operating_hours=info.operating_hours,
            link=results.recording.source,
            config_hash=config_hash,
            ncmeasure_version=results.ncmeasure_version,
            results_format_version=results.format_version,
            recording_location=info.recording_location or results.recording.directory,
            results_sha256=digest,
            results_json=compress(canonical),
        )
        .returning(t.measurements.c.id)
    ).first()
    if inserted is None:  # another writer stored the same results meanwhile
        again = _existing(db, digest, info.serial)
        assert again is not None
        return again
    measurement_id = int(inserted.id)
    _add_axes(db, machine.id, measurement_id, results)
    latest = (
        select(t.measurements.c.measured_utc)
        .where(t.measurements.c.id == t.machines.c.latest_measurement_id)
        .scalar_subquery()
    )
    db.execute(
        update(t.machines)
        .where(t.machines.c.id == machine.id)
        .where(or_(t.machines.c.latest_measurement_id.is_(None), latest <= measured))
        .values(latest_measurement_id=measurement_id)
    )
    return Added(measurement_id=measurement_id, serial=info.serial, new=True)


def _add_axes(db: Connection, machine_id: int, measurement_id: int, results: Results) -> None:
    """Every axis' rows of one measurement, table by table (a few statements in all)."""
    names = list(results.axes)
    axis_ids = _axis_ids(db, machine_id, names)
    rows = [rows_of_axis(name, axis) for name, axis in results.axes.items()]
    result_ids = (
        db.execute(
            insert(t.axis_results).returning(t.axis_results.c.id, sort_by_parameter_order=True),
            [
                {"measurement_id": measurement_id, "axis_id": axis_ids[name], **r.axis}
                for name, r in zip(names, rows, strict=True)
            ],
        )
        .scalars()
        .all()
    )
    owned = list(zip(result_ids, rows, strict=True))
    points = [{**p, "axis_result_id": rid} for rid, r in owned for p in r.points]
    if points:
        db.execute(insert(t.points), points)
    fits = [(rid, fit, params) for rid, r in owned for fit, params in r.fits]
    if fits:
        fit_ids = (
            db.execute(
                insert(t.fits).returning(t.fits.c.id, sort_by_parameter_order=True),
                [{**fit, "axis_result_id": rid} for rid, fit, _ in fits],
            )
            .scalars()
            .all()
        )
        parameters = [
            {**p, "fit_id": fit_id}
            for fit_id, (_, _, params) in zip(fit_ids, fits, strict=True)
            for p in params
        ]
        if parameters:
            db.execute(insert(t.fit_parameters), parameters)
    causes = [{**c, "axis_result_id": rid} for rid, r in owned for c in r.causes]
    if causes:
        db.execute(insert(t.causes), causes)


def _axis_ids(db: Connection, machine_id: int, names: list[str]) -> dict[str, int]:
    """The ids of the machine's axes of these names; the missing ones are created."""
    where = and_(t.axes.c.machine_id == machine_id, t.axes.c.name.in_(names))
    found = {row.name: row.id for row in db.execute(select(t.axes).where(where))}
    missing = [name for name in names if name not in found]
    if missing:
        db.execute(
            insert_ignore(db, t.axes), [{"machine_id": machine_id, "name": n} for n in missing]
        )
        found = {row.name: row.id for row in db.execute(select(t.axes).where(where))}
    return found


def insert_ignore(db: Connection, table: Any) -> Any:
    """INSERT that does nothing where a unique key exists (both dialects)."""
    if db.dialect.name == "postgresql":
        from sqlalchemy.dialects.postgresql import insert as pg_insert

        return pg_insert(table).on_conflict_do_nothing()
    from sqlalchemy.dialects.sqlite import insert as sqlite_insert

    return sqlite_insert(table).on_conflict_do_nothing()
