"""Adding a measurement to the store: its machine, type, axes and rows, in one transaction.

:meth:`~ncmeasure.store.store.Store.add_many` opens the transaction and calls
:func:`add_measurements` for the batch; the functions here work on that connection
and never commit. A batch costs a few statements per table, not one per row: what
is stored is looked up for the whole batch at once, and the rows of every axis of
every measurement go in with one ``executemany`` per table.
"""

from __future__ import annotations

import itertools
import sqlite3
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from operator import itemgetter
from typing import Any

from sqlalchemy import Connection, and_, func, or_, select, update

from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results
from ncmeasure.store import schema as t
from ncmeasure.store.records import Added, MeasurementInfo, utc_text
from ncmeasure.store.rows import POINT_COLUMNS, compress, rows_of_axis

__all__ = ["add_measurements", "find_machine", "insert_ignore", "machine_ids"]

_CHUNK = 500  # values per IN (...) query: far below every database's parameter limit
_ROWS_PER_INSERT = 500  # rows per multi-row INSERT on SQLite


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


def _get_or_create(db: Connection, table: Any, key: dict[str, Any], extra: dict[str, Any]) -> Any:
    where = and_(*(table.c[name] == value for name, value in key.items()))
    row = db.execute(select(table).where(where)).first()
    if row is not None:
        return row
    db.execute(insert_ignore(db, table).values(**key, **extra))
    return db.execute(select(table).where(where)).one()


@dataclass
class _Machine:
    """What adding needs of a machine; kept current through a batch."""

    id: int
    type_name: str
    site: str | None


def machine_ids(db: Connection, serials: Sequence[str]) -> list[int]:
    """The ids of the machines of these serials (those in the store), sorted."""
    return sorted(
        int(i)
        for chunk in _chunks(sorted(set(serials)))
        for i in db.execute(select(t.machines.c.id).where(t.machines.c.serial.in_(chunk))).scalars()
    )


def _stored(db: Connection, digests: Sequence[str]) -> dict[str, tuple[int, str]]:
    """Per digest already stored: (measurement id, serial)."""
    found: dict[str, tuple[int, str]] = {}
    for chunk in _chunks(sorted(set(digests))):
        for row in db.execute(
            select(t.measurements.c.id, t.measurements.c.results_sha256, t.machines.c.serial)
            .join(t.machines, t.machines.c.id == t.measurements.c.machine_id)
            .where(t.measurements.c.results_sha256.in_(chunk))
        ):
            found[row.results_sha256] = (int(row.id), row.serial)
    return found


def _machines(db: Connection, serials: Sequence[str]) -> dict[str, _Machine]:
    found: dict[str, _Machine] = {}
    for chunk in _chunks(sorted(set(serials))):
        for row in db.execute(
            select(
                t.machines.c.id,
                t.machines.c.serial,
                t.machines.c.site,
                t.machine_types.c.name,
            )
            .join(t.machine_types, t.machine_types.c.id == t.machines.c.type_id)
            .where(t.machines.c.serial.in_(chunk))
        ):
            found[row.serial] = _Machine(int(row.id), row.name, row.site)
    return found


def _chunks(values: Sequence[Any]) -> Iterator[list[Any]]:
    for start in range(0, len(values), _CHUNK):
        yield list(values[start : start + _CHUNK])


def add_measurements(
    db: Connection, prepared: Sequence[tuple[Results, MeasurementInfo, bytes, str]]
) -> tuple[list[Added], dict[int, Results]]:
    """Store measurements (results, info, canonical JSON, its digest) in the caller's
    transaction, in a few statements per batch rather than per row.

    Each is checked and stored as one :meth:`~ncmeasure.store.store.Store.add` would,
    in order: the first bad one raises (the caller's transaction then stores none).

    Returns:
        The outcome of each, and the results of the new ones by measurement id.
    """
    now = utc_text(None, "now")
    stored = _stored(db, [p[3] for p in prepared])
    machines = _machines(db, [p[1].serial for p in prepared])
    kinds: dict[tuple[str, str], int] = {}
    added: list[Added] = []
    fresh: dict[int, Results] = {}
    owners: dict[int, int] = {}
    latest: dict[int, tuple[str, int]] = {}
    for results, info, canonical, digest in prepared:
        recorded = results.recording
        if recorded.serial is not None and recorded.serial != info.serial:
            raise ConfigError(
                f"these results are of machine {recorded.serial!r} (recording.serial), "
                f"not {info.serial!r}: store them under {recorded.serial!r}"
            )
        existing = _existing_of(stored, digest, info.serial)
        if existing is not None:
            added.append(existing)
            continue
        config_hash = recorded.config_hash or ""
        measured_text = info.measured_utc or recorded.start_utc
        if measured_text is None:
            raise ConfigError(
                f"measurement of {info.serial!r}: the measurement's time is unknown (the import "
                "found no date): store it with --measured-at"
            )
        measured = utc_text(measured_text, "measured time")
        machine = machines.get(info.serial)
        type_name = info.machine_type or recorded.machine
        if machine is None and type_name is None:
            raise ConfigError(
                f"machine {info.serial!r} is new to the store and the results name no machine "
                "type: name the machine type: --type TYPE, or analyse with --machine FILE"
            )
        if machine is not None and info.machine_type and machine.type_name != info.machine_type:
            raise ConfigError(
                f"machine {info.serial!r} is of type {machine.type_name!r}, "
                f"not {info.machine_type!r}"
            )
        if machine is None:
            assert type_name is not None
            machine = _new_machine(db, info, type_name, config_hash, now, kinds)
            machines[info.serial] = machine
        if info.site is not None and machine.site != info.site:
            db.execute(
                update(t.machines).where(t.machines.c.id == machine.id).values(site=info.site)
            )
            machine.site = info.site
        kind = _kind(db, machine.type_name, config_hash, now, kinds)
        inserted = db.execute(
            insert_ignore(db, t.measurements)
            .values(
                machine_id=machine.id,
                type_id=kind,
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
            stored.update(_stored(db, [digest]))
            again = _existing_of(stored, digest, info.serial)
            assert again is not None
            added.append(again)
            continue
        measurement_id = int(inserted.id)
        stored[digest] = (measurement_id, info.serial)
        fresh[measurement_id] = results
        owners[measurement_id] = machine.id
        # the latest as one UPDATE per machine would leave it: the last of the latest time
        if machine.id not in latest or latest[machine.id][0] <= measured:
            latest[machine.id] = (measured, measurement_id)
        added.append(Added(measurement_id=measurement_id, serial=info.serial, new=True))
    _add_axes(db, owners, fresh)
    _set_latest(db, latest)
    return added, fresh


def _existing_of(stored: dict[str, tuple[int, str]], digest: str, serial: str) -> Added | None:
    found = stored.get(digest)
    if found is None:
        return None
    if found[1] != serial:
        raise ConfigError(
            f"these results are already stored as measurement {found[0]} of machine "
            f"{found[1]!r}, not {serial!r}; one measurement belongs to one machine"
        )
    return Added(measurement_id=found[0], serial=serial, new=False)


def _kind(
    db: Connection, name: str, config_hash: str, now: str, kinds: dict[tuple[str, str], int]
) -> int:
    key = (name, config_hash)
    if key not in kinds:
        kinds[key] = int(
            _get_or_create(
                db,
                t.machine_types,
                {"name": name, "config_hash": config_hash},
                {"created_utc": now},
            ).id
        )
    return kinds[key]


def _new_machine(
    db: Connection,
    info: MeasurementInfo,
    type_name: str,
    config_hash: str,
    now: str,
    kinds: dict[tuple[str, str], int],
) -> _Machine:
    kind = _kind(db, type_name, config_hash, now, kinds)
    _get_or_create(
        db,
        t.machines,
        {"serial": info.serial},
        {"type_id": kind, "site": info.site, "created_utc": now},
    )
    found = find_machine(db, info.serial)
    assert found is not None
    return _Machine(int(found.id), found.type_name, found.site)


def _set_latest(db: Connection, latest: dict[int, tuple[str, int]]) -> None:
    """Each machine's latest measurement: the new one where it is not older."""
    current = (
        select(t.measurements.c.measured_utc)
        .where(t.measurements.c.id == t.machines.c.latest_measurement_id)
        .scalar_subquery()
    )
    for machine_id, (measured, measurement_id) in latest.items():
        db.execute(
            update(t.machines)
            .where(t.machines.c.id == machine_id)
            .where(or_(t.machines.c.latest_measurement_id.is_(None), current <= measured))
            .values(latest_measurement_id=measurement_id)
        )


def _add_axes(db: Connection, owners: dict[int, int], fresh: dict[int, Results]) -> None:
    """Every axis' rows of the new measurements, table by table (a few statements in all)."""
    if not fresh:
        return
    axis_ids = _axis_ids(db, {owners[m]: set(results.axes) for m, results in fresh.items()})
    owned_rows = [
        (measurement_id, name, rows_of_axis(name, axis))
        for measurement_id, results in fresh.items()
        for name, axis in results.axes.items()
    ]
    result_ids = _new_ids(db, t.axis_results, len(owned_rows))
    _insert_rows(
        db,
        t.axis_results,
        [
            {
                "id": rid,
                "measurement_id": measurement_id,
                "axis_id": axis_ids[(owners[measurement_id], name)],
                **r.axis,
            }
            for rid, (measurement_id, name, r) in zip(result_ids, owned_rows, strict=True)
        ],
    )
    owned = [(rid, r) for rid, (_, _, r) in zip(result_ids, owned_rows, strict=True)]
    _insert_values(
        db,
        t.points,
        ("axis_result_id", *POINT_COLUMNS),
        [(rid, *p) for rid, r in owned for p in r.points],
    )
    fits = [(rid, fit, params) for rid, r in owned for fit, params in r.fits]
    if fits:
        fit_ids = _new_ids(db, t.fits, len(fits))
        _insert_rows(
            db,
            t.fits,
            [
                {"id": fit_id, **fit, "axis_result_id": rid}
                for fit_id, (rid, fit, _) in zip(fit_ids, fits, strict=True)
            ],
        )
        _insert_rows(
            db,
            t.fit_parameters,
            [
                {**p, "fit_id": fit_id}
                for fit_id, (_, _, params) in zip(fit_ids, fits, strict=True)
                for p in params
            ],
        )
    _insert_rows(db, t.causes, [{**c, "axis_result_id": rid} for rid, r in owned for c in r.causes])


def _new_ids(db: Connection, table: Any, count: int) -> list[int]:
    """Ids for ``count`` new rows of ``table``, so that the rows that refer to them go in
    with them (RETURNING of a multi-row INSERT keeps no order on SQLite). PostgreSQL: from
    the table's sequence; SQLite: after the largest, as its writer holds the write lock."""
    if db.dialect.name == "postgresql":
        return [
            int(i)
            for i in db.exec_driver_sql(
                f"SELECT nextval(pg_get_serial_sequence('{table.name}', 'id')) "
                "FROM generate_series(1, %s)",
                (count,),
            ).scalars()
        ]
    top = db.execute(select(func.max(table.c.id))).scalar_one()
    return list(range((top or 0) + 1, (top or 0) + 1 + count))


def _insert_rows(db: Connection, table: Any, rows: list[dict[str, Any]]) -> None:
    """Many rows of the same keys in one statement of the driver: SQLAlchemy's per-row
    parameter processing costs more than the database's work for these plain values.
    SQLite: one executemany; PostgreSQL: COPY (an executemany there is a round trip of
    the protocol per row, several times the database's work)."""
    if not rows:
        return
    names = list(rows[0])
    values = (
        list(map(itemgetter(*names), rows)) if len(names) > 1 else [(r[names[0]],) for r in rows]
    )
    _insert_values(db, table, names, values)


def _insert_values(
    db: Connection, table: Any, names: Sequence[str], values: Sequence[Sequence[Any]]
) -> None:
    """Rows as tuples in the order of ``names``: see :func:`_insert_rows`."""
    if not values:
        return
    columns = ", ".join(f'"{table.c[name].name}"' for name in names)
    if db.dialect.name == "postgresql":
        driver = db.connection.driver_connection
        assert driver is not None
        with (
            driver.cursor() as cursor,
            cursor.copy(f"COPY {table.name} ({columns}) FROM STDIN") as copy,
        ):
            for row in values:
                copy.write_row(row)
        return
    # SQLite: rows of up to _ROWS_PER_INSERT in one INSERT ... VALUES (...), (...): a third
    # less time per row than an executemany of one row per step
    mark = "?" if db.dialect.paramstyle == "qmark" else "%s"
    one = f"({', '.join([mark] * len(names))})"
    head = f"INSERT INTO {table.name} ({columns}) VALUES "
    driver = db.connection.driver_connection
    limit = driver.getlimit(sqlite3.SQLITE_LIMIT_VARIABLE_NUMBER) if driver is not None else 999
    per = max(1, min(_ROWS_PER_INSERT, limit // len(names)))
    for start in range(0, len(values), per):
        chunk = values[start : start + per]
        db.exec_driver_sql(
            head + ", ".join([one] * len(chunk)), tuple(itertools.chain.from_iterable(chunk))
        )


def _axis_ids(db: Connection, wanted: dict[int, set[str]]) -> dict[tuple[int, str], int]:
    """Per (machine id, axis name): the axis' id; the missing axes are created."""

    def found() -> dict[tuple[int, str], int]:
        ids: dict[tuple[int, str], int] = {}
        for chunk in _chunks(sorted(wanted)):
            for row in db.execute(select(t.axes).where(t.axes.c.machine_id.in_(chunk))):
                ids[(row.machine_id, row.name)] = row.id
        return ids

    ids = found()
    missing = [
        {"machine_id": machine_id, "name": name}
        for machine_id, names in sorted(wanted.items())
        for name in sorted(names)
        if (machine_id, name) not in ids
    ]
    if missing:
        db.execute(insert_ignore(db, t.axes), missing)
        ids = found()
    return ids


def insert_ignore(db: Connection, table: Any) -> Any:
    """INSERT that does nothing where a unique key exists (both dialects)."""
    if db.dialect.name == "postgresql":
        from sqlalchemy.dialects.postgresql import insert as pg_insert

        return pg_insert(table).on_conflict_do_nothing()
    from sqlalchemy.dialects.sqlite import insert as sqlite_insert

    return sqlite_insert(table).on_conflict_do_nothing()
