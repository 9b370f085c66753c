"""The fleet store: adding results, and reading machines, measurements and trends back."""

from __future__ import annotations

import datetime as dt
import math
import re
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Connection, Engine, and_, func, insert, or_, select, update
from sqlalchemy.exc import SQLAlchemyError

from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results
from ncmeasure.store import schema as t
from ncmeasure.store.database import connect, display_url, translate, write_begin
from ncmeasure.store.rows import (
    canonical_json,
    compress,
    decompress,
    results_digest,
    rows_of_axis,
)

__all__ = [
    "Added",
    "MachineSummary",
    "MeasurementInfo",
    "MeasurementSummary",
    "Store",
    "TrendPoint",
    "open_store",
]

SERIAL_PATTERN = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9 ._+#-]{0,62}[A-Za-z0-9._+#-])?")
"""A serial: letters, digits, space and ``. _ + # -``, 1–64 characters, no space at an end."""
LABEL_PATTERN = re.compile(r"[a-z0-9](?:[a-z0-9._-]{0,62})?")
"""A label such as ``delivery``, ``service``, ``after-repair``: lower case, digits, ``._-``."""
TEXT_LIMIT = 200
TEMPERATURE_RANGE_C = (-40.0, 120.0)
OPERATING_HOURS_MAX = 1_000_000.0


def _check_text(value: str | None, what: str, pattern: re.Pattern[str] | None) -> str | None:
    if value is None:
        return None
    if pattern is not None and not pattern.fullmatch(value):
        allowed = (
            "letters, digits, space and . _ + # - (1 to 64 characters)"
            if pattern is SERIAL_PATTERN
            else "lower-case letters, digits and . _ - (1 to 64 characters, e.g. delivery)"
        )
        raise ConfigError(f"{what} {value!r}: use {allowed}")
    if pattern is None and (
        not value.strip() or len(value) > TEXT_LIMIT or not value.isprintable()
    ):
        raise ConfigError(f"{what} {value!r}: printable text of 1 to {TEXT_LIMIT} characters")
    return value


def check_serial(serial: str) -> str:
    """``serial`` if it is one the store takes, else a :class:`ConfigError` in words."""
    return _check_text(serial, "serial", SERIAL_PATTERN) or ""


def _utc(text: str | None, what: str) -> str:
    if text is None:
        return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError as exc:
        raise ConfigError(f"{what} {text!r}: not an ISO 8601 time") from exc
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.UTC)
    return when.astimezone(dt.UTC).isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class MeasurementInfo:
    """What the store keeps about a measurement beside its results.

    Attributes:
        serial: The machine's serial number (letters, digits, space, ``._+#-``).
        label: ``delivery``, ``service``, ``after-repair``, ... (lower case).
        site: Where the machine stands (updates the machine's site).
        machine_type: The type's name; default: the machine name in the results.
        operator: Who measured.
        temperature_c: Machine temperature during the measurement.
        operating_hours: The machine's operating hours.
        recording_location: Where the raw recording is kept (it stays a file).
        measured_utc: When it was measured; default: the recording's start.
    """

    serial: str
    label: str | None = None
    site: str | None = None
    machine_type: str | None = None
    operator: str | None = None
    temperature_c: float | None = None
    operating_hours: float | None = None
    recording_location: str | None = None
    measured_utc: str | None = None

    def checked(self) -> MeasurementInfo:
        """This info if every field is valid, else a :class:`ConfigError` naming the field."""
        check_serial(self.serial)
        _check_text(self.label, "label", LABEL_PATTERN)
        _check_text(self.site, "site", None)
        _check_text(self.machine_type, "machine type", None)
        _check_text(self.operator, "operator", None)
        for name, value, low, high in (
            ("temperature", self.temperature_c, *TEMPERATURE_RANGE_C),
            ("operating hours", self.operating_hours, 0.0, OPERATING_HOURS_MAX),
        ):
            if value is not None and not (math.isfinite(value) and low <= value <= high):
                raise ConfigError(f"{name} {value!r}: must lie within {low:g} to {high:g}")
        if self.recording_location is not None and len(self.recording_location) > 4096:
            raise ConfigError("recording location: longer than 4096 characters")
        return self


@dataclass(frozen=True)
class Added:
    """The outcome of :meth:`Store.add`."""

    measurement_id: int
    serial: str
    new: bool
    """False when the same results were stored before (nothing was added)."""


@dataclass(frozen=True)
class MeasurementSummary:
    """One measurement of a machine, as ``store show`` lists it."""

    id: int
    measured_utc: str
    label: str | None
    operator: str | None
    temperature_c: float | None
    operating_hours: float | None
    link: str | None
    config_hash: str
    ncmeasure_version: str
    recording_location: str | None
    verdicts: dict[str, str]


@dataclass(frozen=True)
class MachineSummary:
    """One machine, as ``store list`` lists it."""

    serial: str
    machine_type: str
    config_hash: str
    site: str | None
    measurements: int
    latest_utc: str | None
    latest_label: str | None
    latest_verdicts: dict[str, str]


@dataclass(frozen=True)
class TrendPoint:
    """One axis' characteristics at one measurement."""

    measurement_id: int
    measured_utc: str
    label: str | None
    operating_hours: float | None
    unit: str
    verdict: str
    coulomb: float | None
    coulomb_positive: float | None
    coulomb_negative: float | None
    viscous_per_m_min: float | None
    spread_percent: float | None
    signature: str | None
    offset: float | None

    def value(self, characteristic: str) -> float | None:
        """The value of a characteristic by its name (:data:`~.rows.CHARACTERISTICS`)."""
        found = getattr(self, characteristic)
        return float(found) if found is not None else None


class Store:
    """A fleet store opened on a URL; use :func:`open_store`."""

    def __init__(self, engine: Engine, url: str) -> None:
        self.engine = engine
        self.url = url

    @property
    def where(self) -> str:
        """The store's URL without a password."""
        return display_url(self.url)

    @contextmanager
    def reading(self, doing: str) -> Iterator[Connection]:
        """A connection for reading; database errors become :class:`StoreError` saying
        what was being done (``doing``: "list the machines")."""
        try:
            with self.engine.connect() as connection:
                yield connection
        except SQLAlchemyError as exc:
            raise translate(exc, self.url, doing) from exc

    @contextmanager
    def _writing(self, doing: str) -> Iterator[Connection]:
        try:
            with write_begin(self.engine) as connection:
                yield connection
        except SQLAlchemyError as exc:
            raise translate(exc, self.url, doing) from exc

    # ----------------------------------------------------------------------- adding

    def add(self, results: Results, info: MeasurementInfo) -> Added:
        """Store one measurement: its results as rows and as lossless JSON.

        The same results (byte for byte, as canonical JSON) are stored once: adding
        them again to the same machine changes nothing; to another machine is refused.

        Raises:
            ConfigError: Invalid info, or these results belong to another machine.
            StoreError: The database failed; nothing of this measurement is stored.
        """
        return self.add_many([(results, info)])[0]

    def add_many(self, measurements: Iterable[tuple[Results, MeasurementInfo]]) -> list[Added]:
        """Store several measurements in one transaction: all of them or none.

        For loading many at once (a script filling a store): one commit instead of one
        per measurement. Each is stored as :meth:`add` stores it.

        Raises:
            ConfigError: Invalid info, or results of another machine (nothing stored).
            StoreError: The database failed; nothing of these measurements is stored.
        """
        prepared = []
        for results, info in measurements:
            info.checked()
            if not results.axes:
                raise ConfigError("these results hold no analysed axis; there is nothing to store")
            canonical = canonical_json(results)
            prepared.append((results, info, canonical, results_digest(canonical)))
        with self._writing(
            "add the measurement" if len(prepared) == 1 else "add measurements"
        ) as db:
            return [self._add(db, *one) for one in prepared]

    def _existing(self, db: Connection, digest: str, serial: str) -> Added | None:
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
        return Added(found.id, serial, new=False)

    def _get_or_create(
        self, db: Connection, table: Any, key: dict[str, Any], extra: dict[str, Any]
    ) -> Any:
        where = and_(*(table.c[name] == value for name, value in key.items()))
        row = db.execute(select(table).where(where)).first()
        if row is not None:
            return row
        db.execute(_insert_ignore(db, table).values(**key, **extra))
        return db.execute(select(table).where(where)).one()

    def _add(
        self, db: Connection, results: Results, info: MeasurementInfo, canonical: bytes, digest: str
    ) -> Added:
        existing = self._existing(db, digest, info.serial)
        if existing is not None:
            return existing
        now = _utc(None, "now")
        config_hash = results.recording.config_hash or ""
        type_name = info.machine_type or results.recording.machine or "(unnamed)"
        machine = self._find_machine(db, info.serial)
        if machine is not None and info.machine_type and machine.type_name != info.machine_type:
            raise ConfigError(
                f"machine {info.serial!r} is of type {machine.type_name!r}, "
                f"not {info.machine_type!r}"
            )
        if machine is None:
            kind = self._get_or_create(
                db,
                t.machine_types,
                {"name": type_name, "config_hash": config_hash},
                {"created_utc": now},
            )
            self._get_or_create(
                db,
                t.machines,
                {"serial": info.serial},
                {"type_id": kind.id, "site": info.site, "created_utc": now},
            )
            machine = self._find_machine(db, info.serial)
            assert machine is not None
        if info.site is not None and machine.site != info.site:
            db.execute(
                update(t.machines).where(t.machines.c.id == machine.id).values(site=info.site)
            )
        measured = _utc(
            info.measured_utc or results.recording.start_utc or results.created_utc, "measured time"
        )
        kind = self._get_or_create(
            db,
            t.machine_types,
            {"name": machine.type_name, "config_hash": config_hash},
            {"created_utc": now},
        )
        inserted = db.execute(
            _insert_ignore(db, t.measurements)
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
            again = self._existing(db, digest, info.serial)
            assert again is not None
            return again
        measurement_id = int(inserted.id)
        self._add_axes(db, machine.id, measurement_id, results)
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
        return Added(measurement_id, info.serial, new=True)

    def _add_axes(
        self, db: Connection, machine_id: int, measurement_id: int, results: Results
    ) -> None:
        """Every axis' rows of one measurement, table by table (a few statements in all)."""
        names = list(results.axes)
        axis_ids = self._axis_ids(db, machine_id, names)
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

    @staticmethod
    def _axis_ids(db: Connection, machine_id: int, names: list[str]) -> dict[str, int]:
        """The ids of the machine's axes of these names; the missing ones are created."""
        where = and_(t.axes.c.machine_id == machine_id, t.axes.c.name.in_(names))
        found = {row.name: row.id for row in db.execute(select(t.axes).where(where))}
        missing = [name for name in names if name not in found]
        if missing:
            db.execute(
                _insert_ignore(db, t.axes), [{"machine_id": machine_id, "name": n} for n in missing]
            )
            found = {row.name: row.id for row in db.execute(select(t.axes).where(where))}
        return found

    # ----------------------------------------------------------------------- reading

    @staticmethod
    def _find_machine(db: Connection, serial: str) -> Any:
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

    def machine_row(self, db: Connection, serial: str) -> Any:
        """The machine's row (id, serial, site, type_id, latest_measurement_id, type_name,
        config_hash); a :class:`ConfigError` when there is no such machine."""
        row = self._find_machine(db, serial)
        if row is None:
            raise ConfigError(
                f"no machine {serial!r} in the store {self.where} (ncmeasure store list shows "
                "the machines)"
            )
        return row

    def _verdicts(
        self, db: Connection, measurement_ids: Sequence[int]
    ) -> dict[int, dict[str, str]]:
        found: dict[int, dict[str, str]] = {m: {} for m in measurement_ids}
        if not measurement_ids:
            return found
        for row in db.execute(
            select(t.axis_results.c.measurement_id, t.axis_results.c.axis, t.axis_results.c.verdict)
            .where(t.axis_results.c.measurement_id.in_(list(measurement_ids)))
            .order_by(t.axis_results.c.axis)
        ):
            found[row.measurement_id][row.axis] = row.verdict
        return found

    def machines(self) -> list[MachineSummary]:
        """Every machine, by serial."""
        counts = (
            select(t.measurements.c.machine_id, func.count().label("n"))
            .group_by(t.measurements.c.machine_id)
            .subquery()
        )
        latest = t.measurements.alias("latest")
        with self.reading("list the machines") as db:
            rows = db.execute(
                select(
                    t.machines.c.serial,
                    t.machines.c.site,
                    t.machine_types.c.name,
                    t.machine_types.c.config_hash,
                    func.coalesce(counts.c.n, 0).label("n"),
                    latest.c.id.label("latest_id"),
                    latest.c.measured_utc,
                    latest.c.label,
                )
                .join(t.machine_types, t.machine_types.c.id == t.machines.c.type_id)
                .outerjoin(counts, counts.c.machine_id == t.machines.c.id)
                .outerjoin(latest, latest.c.id == t.machines.c.latest_measurement_id)
                .order_by(t.machines.c.serial)
            ).all()
            verdicts = self._verdicts(db, [r.latest_id for r in rows if r.latest_id is not None])
        return [
            MachineSummary(
                serial=r.serial,
                machine_type=r.name,
                config_hash=r.config_hash,
                site=r.site,
                measurements=int(r.n),
                latest_utc=r.measured_utc,
                latest_label=r.label,
                latest_verdicts=verdicts.get(r.latest_id, {}) if r.latest_id else {},
            )
            for r in rows
        ]

    def machine(self, serial: str) -> tuple[MachineSummary, list[MeasurementSummary]]:
        """One machine and its measurements, oldest first."""
        check_serial(serial)
        with self.reading("read the machine") as db:
            machine = self.machine_row(db, serial)
            rows = db.execute(
                select(
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
                .where(t.measurements.c.machine_id == machine.id)
                .order_by(t.measurements.c.measured_utc, t.measurements.c.id)
            ).all()
            verdicts = self._verdicts(db, [r.id for r in rows])
        measurements = [
            MeasurementSummary(
                id=r.id,
                measured_utc=r.measured_utc,
                label=r.label,
                operator=r.operator,
                temperature_c=r.temperature_c,
                operating_hours=r.operating_hours,
                link=r.link,
                config_hash=r.config_hash,
                ncmeasure_version=r.ncmeasure_version,
                recording_location=r.recording_location,
                verdicts=verdicts[r.id],
            )
            for r in rows
        ]
        latest = next((m for m in measurements if m.id == machine.latest_measurement_id), None)
        summary = MachineSummary(
            serial=machine.serial,
            machine_type=machine.type_name,
            config_hash=machine.config_hash,
            site=machine.site,
            measurements=len(measurements),
            latest_utc=latest.measured_utc if latest else None,
            latest_label=latest.label if latest else None,
            latest_verdicts=latest.verdicts if latest else {},
        )
        return summary, measurements

    def results(self, measurement_id: int) -> Results:
        """The stored results of a measurement, exactly as they were added."""
        with self.reading("read the results") as db:
            stored = db.execute(
                select(t.measurements.c.results_json).where(t.measurements.c.id == measurement_id)
            ).scalar_one_or_none()
        if stored is None:
            raise ConfigError(f"no measurement {measurement_id} in the store {self.where}")
        return decompress(stored)

    def trend(self, serial: str, axis: str) -> list[TrendPoint]:
        """One axis' characteristics at every measurement of a machine, oldest first."""
        check_serial(serial)
        a = t.axis_results
        with self.reading("read the trend") as db:
            machine = self.machine_row(db, serial)
            rows = db.execute(
                select(
                    t.measurements.c.id,
                    t.measurements.c.measured_utc,
                    t.measurements.c.label,
                    t.measurements.c.operating_hours,
                    a.c.unit,
                    a.c.verdict,
                    a.c.coulomb,
                    a.c.coulomb_positive,
                    a.c.coulomb_negative,
                    a.c.viscous_per_m_min,
                    a.c.spread_percent,
                    a.c.signature,
                    a.c.offset,
                )
                .join(a, a.c.measurement_id == t.measurements.c.id)
                .where(t.measurements.c.machine_id == machine.id, a.c.axis == axis)
                .order_by(t.measurements.c.measured_utc, t.measurements.c.id)
            ).all()
            if not rows:
                names = (
                    db.execute(
                        select(t.axes.c.name)
                        .where(t.axes.c.machine_id == machine.id)
                        .order_by(t.axes.c.name)
                    )
                    .scalars()
                    .all()
                )
                raise ConfigError(
                    f"machine {serial!r} has no axis {axis!r} in the store (it has "
                    f"{', '.join(names) or 'none'})"
                )
        return [
            TrendPoint(
                measurement_id=r.id,
                measured_utc=r.measured_utc,
                label=r.label,
                operating_hours=r.operating_hours,
                unit=r.unit,
                verdict=r.verdict,
                coulomb=r.coulomb,
                coulomb_positive=r.coulomb_positive,
                coulomb_negative=r.coulomb_negative,
                viscous_per_m_min=r.viscous_per_m_min,
                spread_percent=r.spread_percent,
                signature=r.signature,
                offset=r.offset,
            )
            for r in rows
        ]


def _insert_ignore(db: Connection, table: Any) -> Any:
    """INSERT that does nothing where a unique key exists (both dialects)."""
    if db.dialect.name == "postgresql":
        from sqlalchemy.dialects.postgresql import insert as pg_insert

        return pg_insert(table).on_conflict_do_nothing()
    from sqlalchemy.dialects.sqlite import insert as sqlite_insert

    return sqlite_insert(table).on_conflict_do_nothing()


@contextmanager
def open_store(url: str, *, write: bool = False) -> Iterator[Store]:
    """The store at ``url``, its schema current; closed on exit.

    Raises:
        ConfigError: Not a store URL.
        StoreError: Cannot be reached, opened or written; of a newer schema.
    """
    with connect(url, write=write) as engine:
        yield Store(engine, url)
