"""One summary row per machine, kept current on adding: the lists read pages of it.

``store list``, the REST API's machine list and the dashboard's grid show a page
of machines at a time, sorted by serial and filtered in the database
(:func:`machine_page`: ``ORDER BY serial LIMIT n`` after a keyset cursor), instead
of counting every machine's measurements on every call. The row holds what the
lists show (type, site, measurements, the latest and the baseline measurement)
and is rebuilt for the machines of each batch that is added
(:func:`update_summaries`, in the adding transaction).

The status is judged against the whole fleet (its outliers move with every
measurement of the type), so a row's status is that of one fleet:
:func:`fleet_version` names it. A store open for writing keeps the statuses of
each fleet overview it computes (:func:`keep_statuses`), and ``ncmeasure store
refresh`` judges them at once; a status of another fleet version is not used.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass

from sqlalchemy import (
    ColumnElement,
    Connection,
    bindparam,
    case,
    delete,
    false,
    func,
    insert,
    select,
    update,
)

from ncmeasure.errors import ConfigError
from ncmeasure.store import schema as t
from ncmeasure.store.records import MachineSummary

__all__ = [
    "DEFAULT_PAGE",
    "MAX_PAGE",
    "MachinePage",
    "count_revision",
    "fill_search_texts",
    "fleet_version",
    "keep_statuses",
    "machine_page",
    "search_text",
    "statuses_current",
    "store_revision",
    "update_summaries",
]

DEFAULT_PAGE = 100
"""Machines per page unless asked for another number."""
MAX_PAGE = 1000
"""The most machines one page holds."""

_CHUNK = 500  # ids per IN (...) query: far below every database's parameter limit


def _chunks(ids: Sequence[int]) -> Iterator[list[int]]:
    for start in range(0, len(ids), _CHUNK):
        yield list(ids[start : start + _CHUNK])


def _rows(machine_ids: Sequence[int] | None) -> Iterator[object]:
    """The summary rows, as ``INSERT ... SELECT`` sources: one statement per chunk."""
    m, mt, ms = t.machines, t.machine_types, t.measurements
    x = ms.alias("x")
    latest = ms.alias("latest")
    base = ms.alias("base")
    count = select(func.count()).where(x.c.machine_id == m.c.id).scalar_subquery()
    first = (
        select(x.c.id)
        .where(x.c.machine_id == m.c.id)
        .order_by(case((x.c.label == "delivery", 0), else_=1), x.c.measured_utc, x.c.id)
        .limit(1)
        .scalar_subquery()
    )
    query = (
        select(
            m.c.id,
            m.c.serial,
            mt.c.name,
            mt.c.config_hash,
            m.c.site,
            count,
            m.c.latest_measurement_id,
            latest.c.measured_utc,
            latest.c.label,
            base.c.id,
            base.c.measured_utc,
            base.c.label,
        )
        .join(mt, mt.c.id == m.c.type_id)
        .outerjoin(latest, latest.c.id == m.c.latest_measurement_id)
        .outerjoin(base, base.c.id == first)
    )
    if machine_ids is None:
        yield query
        return
    for chunk in _chunks(sorted(set(machine_ids))):
        yield query.where(m.c.id.in_(chunk))


_COLUMNS = [
    "machine_id",
    "serial",
    "machine_type",
    "config_hash",
    "site",
    "measurements",
    "latest_id",
    "latest_utc",
    "latest_label",
    "baseline_id",
    "baseline_utc",
    "baseline_label",
]


def update_summaries(db: Connection, machine_ids: Sequence[int] | None = None) -> None:
    """Rebuild the summary rows of these machines (all: None) in the caller's transaction;
    their statuses are judged again by the next fleet overview of a writer."""
    s = t.machine_summaries
    if machine_ids is None:
        db.execute(delete(s))
    else:
        for chunk in _chunks(sorted(set(machine_ids))):
            db.execute(delete(s).where(s.c.machine_id.in_(chunk)))
    for query in _rows(machine_ids):
        db.execute(insert(s).from_select(_COLUMNS, query))  # type: ignore[arg-type]
    fill_search_texts(db, machine_ids)


def fill_search_texts(db: Connection, machine_ids: Sequence[int] | None = None) -> None:
    """Write the :func:`search_text` of these machines' summary rows (all: None)."""
    s = t.machine_summaries
    query = select(s.c.machine_id, s.c.serial, s.c.machine_type, s.c.site)
    chunks = [None] if machine_ids is None else list(_chunks(sorted(set(machine_ids))))
    for chunk in chunks:
        rows = db.execute(query if chunk is None else query.where(s.c.machine_id.in_(chunk)))
        texts = [{"id": r[0], "text": search_text(r[1], r[2], r[3])} for r in rows]
        if texts:
            db.execute(
                update(s)
                .where(s.c.machine_id == bindparam("id"))
                .values(search_text=bindparam("text")),
                texts,
            )


def store_revision(db: Connection) -> int:
    """The store's revision: one more with every transaction that added measurements or
    stored changes, in the order they committed (:data:`~ncmeasure.store.schema.store_state`)."""
    found = db.execute(select(t.store_state.c.revision).where(t.store_state.c.id == 1))
    return int(found.scalar_one_or_none() or 0)


def count_revision(db: Connection) -> None:
    """One more revision, in an adding transaction, as its last statement: the row stays
    locked until the commit, so a later add counts after this one has committed (on
    PostgreSQL two adds may take their measurement ids in the other order)."""
    db.execute(
        update(t.store_state)
        .where(t.store_state.c.id == 1)
        .values(revision=t.store_state.c.revision + 1)
    )


def fleet_version(db: Connection) -> str:
    """The fleet a status is judged in: every change adds measurements (a new
    :func:`store_revision`; nothing is deleted), and the diagnosis of the changes has a
    version."""
    from ncmeasure.store.changes import DIAGNOSIS_VERSION

    return f"{store_revision(db)}:{DIAGNOSIS_VERSION}"


def statuses_current(db: Connection, version: str | None = None) -> bool:
    """Every summary row's status is judged in the fleet as it is now."""
    version = version or fleet_version(db)
    s = t.machine_summaries
    stale = db.execute(
        select(s.c.machine_id)
        .where(s.c.latest_id.is_not(None))
        .where((s.c.fleet_version.is_(None)) | (s.c.fleet_version != version))
        .limit(1)
    ).first()
    return stale is None


def keep_statuses(db: Connection, statuses: Mapping[str, str], version: str) -> None:
    """Store each machine's status (by serial), judged in the fleet ``version``."""
    s = t.machine_summaries
    by_status: dict[str, list[str]] = {}
    for serial, status in statuses.items():
        by_status.setdefault(status, []).append(serial)
    for status, serials in sorted(by_status.items()):
        for start in range(0, len(serials), _CHUNK):
            db.execute(
                update(s)
                .where(s.c.serial.in_(serials[start : start + _CHUNK]))
                .values(status=status, fleet_version=version)
            )


@dataclass(frozen=True)
class MachinePage:
    """One page of machines, by serial."""

    machines: list[MachineSummary]
    total: int
    """Machines that match the filter, on every page."""
    next_cursor: str | None
    """The serial to continue after; None on the last page."""


def check_limit(limit: int) -> int:
    """A page size between 1 and :data:`MAX_PAGE`, else a :class:`ConfigError`."""
    if not 1 <= limit <= MAX_PAGE:
        raise ConfigError(f"limit {limit}: a page holds 1 to {MAX_PAGE} machines")
    return limit


SEARCH_APART = "\x1f"
"""Between the serial, type and site in :func:`search_text` (no search holds it)."""


def search_text(serial: str, machine_type: str, site: str | None) -> str:
    """What a search of the machine looks in: its serial, type and site case-folded as Python
    folds them (``WÜRZBURG`` and ``würzburg``, ``Straße`` and ``STRASSE`` alike), the
    same on SQLite and PostgreSQL whatever their locale, and as the dashboard's grid
    folds them (:meth:`~ncmeasure.store.statuses.FleetStatuses.matching`)."""
    return SEARCH_APART.join((serial.casefold(), machine_type.casefold(), (site or "").casefold()))


def _search(db: Connection, text: str) -> ColumnElement[bool]:
    """The machine's serial, type or site contains ``text`` in any case."""
    wanted = text.casefold()
    if SEARCH_APART in wanted or "\x00" in wanted:  # no field holds them (no text can)
        return false()
    column = t.machine_summaries.c.search_text
    position = func.instr if db.dialect.name == "sqlite" else func.strpos
    return position(column, wanted) > 0


def machine_page(
    db: Connection,
    *,
    limit: int = DEFAULT_PAGE,
    after: str | None = None,
    search: str | None = None,
    status: str | None = None,
    statuses: Mapping[str, str] | None = None,
) -> MachinePage:
    """Machines by serial after the cursor ``after``, at most ``limit``.

    Args:
        db: A connection.
        limit: The page size (1 to :data:`MAX_PAGE`).
        after: The serial the page starts after (the previous page's ``next_cursor``).
        search: Only machines whose serial, type or site contains this (any case).
        status: Only machines of this status (ok, warning, critical); the stored
            statuses must be current (:func:`statuses_current`) unless ``statuses``
            gives them.
        statuses: The statuses by serial, where the stored ones are not current.
    """
    check_limit(limit)
    s = t.machine_summaries
    where: list[ColumnElement[bool]] = [s.c.latest_id.is_not(None)]
    if search:
        where.append(_search(db, search))
    if status is not None:
        if statuses is None:
            where.append(s.c.status == status)
        else:
            chosen = sorted(serial for serial, found in statuses.items() if found == status)
            where.append(s.c.serial.in_(chosen) if chosen else s.c.machine_id.is_(None))
    total = int(db.execute(select(func.count()).select_from(s).where(*where)).scalar_one())
    if after is not None:
        where.append(s.c.serial > after)
    rows = db.execute(select(s).where(*where).order_by(s.c.serial).limit(limit + 1)).all()
    more = len(rows) > limit
    rows = rows[:limit]
    verdicts = _verdicts(db, [int(r.latest_id) for r in rows])
    return MachinePage(
        machines=[
            MachineSummary(
                serial=r.serial,
                machine_type=r.machine_type,
                config_hash=r.config_hash,
                site=r.site,
                measurements=int(r.measurements),
                latest_utc=r.latest_utc,
                latest_label=r.latest_label,
                latest_verdicts=verdicts.get(int(r.latest_id), {}),
            )
            for r in rows
        ],
        total=total,
        next_cursor=rows[-1].serial if more else None,
    )


def _verdicts(db: Connection, measurement_ids: Iterable[int]) -> dict[int, dict[str, str]]:
    from ncmeasure.store.changes import verdicts_of

    return verdicts_of(db, list(measurement_ids))
