"""The fleet store: adding results, and reading machines, measurements and trends back."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from sqlalchemy import Connection, Engine, select
from sqlalchemy.exc import SQLAlchemyError

from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results
from ncmeasure.store import schema as t
from ncmeasure.store.changes import (
    measurement_summaries,
    record_changes,
    refresh_machine,
    stale_machines,
)
from ncmeasure.store.database import connect, display_url, translate, write_begin
from ncmeasure.store.records import (
    Added,
    MachineSummary,
    MeasurementInfo,
    MeasurementSummary,
    TrendPoint,
    check_serial,
)
from ncmeasure.store.rows import (
    canonical_json,
    decompress,
    results_digest,
)
from ncmeasure.store.summaries import (
    DEFAULT_PAGE,
    MachinePage,
    count_revision,
    machine_page,
    update_summaries,
)
from ncmeasure.store.writing import add_measurements, find_machine, machine_ids

__all__ = ["REFRESH_BATCH", "Store", "open_store"]

REFRESH_BATCH = 50
"""Machines per transaction of :meth:`Store.refresh_changes`."""


class Store:
    """A fleet store opened on a URL; use :func:`open_store`."""

    def __init__(self, engine: Engine, url: str, *, write: bool = False) -> None:
        self.engine = engine
        self.url = url
        self.write = write
        """Opened for writing: reading may keep what it computed (the overview's changes)."""
        self._kept_results: dict[int, Results] = {}
        """Stored results read back while adding (baselines), for the next batch."""

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
    def writing(self, doing: str) -> Iterator[Connection]:
        """A transaction under the store's write lock; database errors become
        :class:`StoreError` saying what was being done. Only on a store opened for writing."""
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
        The machine's latest measurement is compared with its baseline and the change
        stored (:func:`~ncmeasure.store.changes.record_changes`), for every surface to read.

        Raises:
            ConfigError: Invalid info, or these results belong to another machine.
            StoreError: The database failed; nothing of this measurement is stored.
        """
        return self.add_many([(results, info)])[0]

    def add_many(self, measurements: Iterable[tuple[Results, MeasurementInfo]]) -> list[Added]:
        """Store several measurements in one transaction: all of them or none.

        For loading many at once (a script filling a store, ``store import``): one commit
        instead of one per measurement, a few statements per table for the whole batch.
        Each is stored as :meth:`add` stores it; then, once per machine, its change since
        its baseline (:func:`~ncmeasure.store.changes.record_changes`), its summary and its
        own status (:func:`~ncmeasure.store.statuses.keep_own_statuses`).

        Raises:
            ConfigError: Invalid info, or results of another machine (nothing stored).
            StoreError: The database failed; nothing of these measurements is stored.
        """
        prepared = []
        for results, info in measurements:
            if not results.axes:
                raise ConfigError("these results hold no analysed axis; there is nothing to store")
            canonical = canonical_json(results)
            prepared.append((results, info, canonical, results_digest(canonical)))
        with self.writing(
            "add the measurement" if len(prepared) == 1 else "add measurements"
        ) as db:
            added, fresh = add_measurements(db, prepared)
            serials = sorted({a.serial for a in added})
            record_changes(db, serials, fresh, self._kept_results)
            if fresh:
                from ncmeasure.store.statuses import keep_own_statuses

                ids = machine_ids(db, serials)
                update_summaries(db, ids)
                keep_own_statuses(db, ids)  # no reader judges them again
                count_revision(db)  # last: locked until the commit
            return added

    def refresh_changes(
        self, *, every: bool = False, progress: Callable[[int, int], None] | None = None
    ) -> int:
        """Compare each machine's latest measurement with its baseline again and store the
        change, where it is not stored as of
        :data:`~ncmeasure.store.changes.DIAGNOSIS_VERSION` (``every``: for every machine).

        One transaction per :data:`REFRESH_BATCH` machines: an interrupted refresh keeps
        what it did, and the next one goes on from there.

        Args:
            every: Recompute every machine's pair, stored or not.
            progress: Called with (done, total) after each batch.

        Returns:
            The machines whose change was stored.

        Raises:
            StoreError: The database failed (the batches before are kept).
        """
        with self.reading("find the machines to refresh") as db:
            if every:
                wanted = list(
                    db.execute(
                        select(t.machines.c.id)
                        .where(t.machines.c.latest_measurement_id.is_not(None))
                        .order_by(t.machines.c.id)
                    ).scalars()
                )
            else:
                wanted = stale_machines(db)
        done = 0
        for start in range(0, len(wanted), REFRESH_BATCH):
            with self.writing("store the changes since the baselines") as db:
                stored = sum(
                    refresh_machine(db, machine_id)
                    for machine_id in wanted[start : start + REFRESH_BATCH]
                )
                if stored:  # what the statuses and a running dashboard show changed
                    count_revision(db)
                done += stored
            if progress is not None:
                progress(min(start + REFRESH_BATCH, len(wanted)), len(wanted))
        return done

    def refresh_summaries(self) -> int:
        """Rebuild every machine's summary row and judge every machine's status in the fleet
        as it is now (:mod:`ncmeasure.store.summaries`), for the lists to read.

        Returns:
            The machines summarised.

        Raises:
            StoreError: The database failed (the rows before stay).
        """
        from ncmeasure.store.overview import fleet_overview
        from ncmeasure.store.statuses import fleet_statuses

        with self.writing("rebuild the machines' summaries") as db:
            update_summaries(db)
        fleet_statuses(self)  # judges and keeps each machine's status without the fleet
        return len(fleet_overview(self).machines)  # keeps the statuses: open for writing

    # ----------------------------------------------------------------------- reading

    def machine_row(self, db: Connection, serial: str) -> Any:
        """The machine's row (id, serial, site, type_id, latest_measurement_id, type_name,
        config_hash); a :class:`ConfigError` when there is no such machine."""
        row = find_machine(db, serial)
        if row is None:
            raise ConfigError(
                f"no machine {serial!r} in the store {self.where} (ncmeasure store list shows "
                "the machines)"
            )
        return row

    def machines(self) -> list[MachineSummary]:
        """Every machine, by serial (a page at a time: :meth:`machine_page`)."""
        found: list[MachineSummary] = []
        after: str | None = None
        while True:
            page = self.machine_page(limit=1000, after=after)
            found += page.machines
            if page.next_cursor is None:
                return found
            after = page.next_cursor

    def machine_page(
        self,
        *,
        limit: int = DEFAULT_PAGE,
        after: str | None = None,
        search: str | None = None,
        status: str | None = None,
        statuses: Mapping[str, str] | None = None,
    ) -> MachinePage:
        """A page of machines by serial, filtered and cut in the database
        (:func:`~ncmeasure.store.summaries.machine_page`: the arguments).

        Raises:
            ConfigError: A limit out of range.
            StoreError: The database failed.
        """
        with self.reading("list the machines") as db:
            return machine_page(
                db, limit=limit, after=after, search=search, status=status, statuses=statuses
            )

    def machine(self, serial: str) -> tuple[MachineSummary, list[MeasurementSummary]]:
        """One machine and its measurements, oldest first."""
        check_serial(serial)
        with self.reading("read the machine") as db:
            machine = self.machine_row(db, serial)
            measurements = measurement_summaries(db, machine.id)
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


@contextmanager
def open_store(url: str, *, write: bool = False) -> Iterator[Store]:
    """The store at ``url``, its schema current; closed on exit.

    Raises:
        ConfigError: Not a store URL.
        StoreError: Cannot be reached, opened or written; of a newer schema.
    """
    with connect(url, write=write) as engine:
        yield Store(engine, url, write=write)
