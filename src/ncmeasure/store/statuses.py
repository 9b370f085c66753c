"""Every machine's status for the lists, without judging the fleet machine by machine.

A status is the worst of two parts (:mod:`ncmeasure.analysis.judgement.status`):
what an axis shows by itself (its verdict, its change since the baseline, its
sibling axes) and its place in its type's fleet (an outlier, or a level
:data:`~ncmeasure.analysis.judgement.status.FLEET_FACTOR` from the median: a
warning). The first changes only when the machine gets a measurement: it is kept
per axis (:data:`~ncmeasure.store.schema.axis_statuses`, for the latest and
baseline pair and the diagnosis version it was judged for), judged where missing
by the first reader (and kept by a store open for writing; ``ncmeasure store
refresh`` judges every machine). The second moves with every measurement of the
type: it is computed for the whole fleet at once from one read of the latest
figures, as arrays (:func:`~ncmeasure.analysis.judgement.fleet.modified_z_leave_one_out`
per type, axis and characteristic), never as an object per machine.

The grid then judges in full (reasons, changes, places) only the machines of the
page it shows (:func:`judged_page`); the statuses equal those of
:func:`~ncmeasure.store.overview.fleet_overview` (``tests/store/test_statuses.py``).
"""

from __future__ import annotations

import itertools
import logging
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import Connection, and_, delete, insert, select

from ncmeasure.analysis.judgement.fleet import modified_z_leave_one_out
from ncmeasure.analysis.judgement.status import (
    CHARACTERISTICS,
    FLEET_FACTOR,
    FleetPlace,
    outliers_among,
)
from ncmeasure.formats.comparison import Limits, Status
from ncmeasure.store import schema as t
from ncmeasure.store.changes import (
    DIAGNOSIS_VERSION,
    StoredChange,
    current_change,
    stored_changes,
)
from ncmeasure.store.database import plain_rows
from ncmeasure.store.overview import (
    MachineOverview,
    Outlier,
    axis_rows_in,
    changes_of,
    fill_axes,
    judge,
    overviews_of,
    read_axes,
)
from ncmeasure.store.store import Store
from ncmeasure.store.summaries import fleet_version

__all__ = ["FleetStatuses", "fleet_statuses", "judged_page", "keep_own_statuses"]

_CHUNK = 500
_BATCH = 200  # machines judged per transaction where the statuses are missing
_log = logging.getLogger(__name__)

Group = tuple[str, str, str, str]
"""machine type, axis, unit, characteristic."""


@dataclass(frozen=True)
class _Places:
    """One group's places: by machine id (sorted), the latest value, the others' median and
    the z-score."""

    ids: NDArray[np.int64]
    values: NDArray[np.float64]
    medians: NDArray[np.float64]
    z: NDArray[np.float64]
    enough: bool


_APART = "\x00"
"""Between the texts of a machine that a search looks in."""
_LEVELS: tuple[Status, ...] = ("ok", "warning", "critical")
_LEVEL: dict[str, int] = {name: level for level, name in enumerate(_LEVELS)}


@dataclass
class FleetStatuses:
    """Every machine's status (default limits) in the fleet as it was read, as arrays: one
    entry per machine (by serial) and one per axis of each machine's latest measurement."""

    version: str
    """The fleet these statuses were judged in
    (:func:`~ncmeasure.store.summaries.fleet_version`)."""
    machine_ids: NDArray[np.int64]
    """Per machine, by serial."""
    serials: list[str]
    types: list[str]
    sites: list[str | None]
    levels: NDArray[np.int8]
    """Per machine: its status, 0 ok, 1 warning, 2 critical."""
    axis_machine: NDArray[np.intp]
    """Per axis: its machine (an index of the machine arrays)."""
    axis_levels: NDArray[np.int8]
    """Per axis: its status."""
    axis_names: list[str]
    """Every axis name in the fleet, sorted."""
    places: dict[Group, _Places] = field(default_factory=dict)
    searched: list[str] | None = field(default=None, repr=False, compare=False)
    """Per machine, the text a search looks in (:meth:`search_texts`, made by the first)."""
    read: _Read | None = field(default=None, repr=False, compare=False)
    """What was read, for the next reading (:func:`fleet_statuses`' ``previous``)."""

    def by_serial(self) -> dict[str, Status]:
        """Every machine's status by serial."""
        return {s: _LEVELS[int(v)] for s, v in zip(self.serials, self.levels, strict=True)}

    def matching(self, search: str | None = None, status: str | None = None) -> list[int]:
        """The machines (indexes, by serial) whose serial, type or site contains ``search``
        (any case) and whose status is ``status``."""
        chosen: list[int] = list(range(len(self.serials)))
        if status is not None:
            level = _LEVEL.get(status, -1)
            chosen = [int(i) for i in np.flatnonzero(self.levels == level)]
        if not search:
            return list(chosen)
        wanted = search.casefold()
        if _APART in wanted:  # the texts are held joined by it: field by field
            return [
                i
                for i in chosen
                if any(
                    wanted in (text or "").casefold()
                    for text in (self.serials[i], self.types[i], self.sites[i])
                )
            ]
        texts = self.search_texts()
        return [i for i in chosen if wanted in texts[i]]

    def search_texts(self) -> list[str]:
        """Per machine: its serial, type and site, case-folded, joined by a character no
        search holds (made by the first search: the statuses are cached per fleet
        version, the grid's first view needs none)."""
        if self.searched is None:
            self.searched = [
                _APART.join((serial.casefold(), kind.casefold(), (site or "").casefold()))
                for serial, kind, site in zip(self.serials, self.types, self.sites, strict=True)
            ]
        return self.searched

    def axis_counts(self, machines: Sequence[int]) -> dict[Status, int]:
        """The axes of these machines per status."""
        chosen = np.zeros(len(self.serials), dtype=bool)
        chosen[list(machines)] = True
        levels = self.axis_levels[chosen[self.axis_machine]]
        counts = np.bincount(levels, minlength=len(_LEVELS))
        return {name: int(counts[level]) for level, name in enumerate(_LEVELS)}

    def places_of(self, machine_id: int, machine_type: str) -> dict[str, list[FleetPlace]]:
        """The machine's place in its type's fleet, per axis, as
        :func:`~ncmeasure.analysis.judgement.status.machine_status` reads it."""
        found: dict[str, list[FleetPlace]] = defaultdict(list)
        for (kind, axis, _unit, name), group in self.places.items():
            if kind != machine_type:
                continue
            at = int(np.searchsorted(group.ids, machine_id))
            if at < group.ids.size and group.ids[at] == machine_id:
                z = float(group.z[at]) if group.enough else None
                found[axis].append(
                    FleetPlace(name, float(group.medians[at]), z, group.ids.size - 1)
                )
        return found

    def type_values(
        self, machine_id: int
    ) -> tuple[dict[tuple[str, str], dict[str, NDArray[np.float64]]], int] | None:
        """The latest figures of the other machines of the machine's type (name and
        configuration), as :func:`~ncmeasure.store.check.check_machine` compares with
        them: per (axis, unit) and characteristic the finite values, sorted; and how many
        machines they are. None when the machine is not among these statuses."""
        read = self.read
        if read is None or machine_id not in read.machines:
            return None
        own = read.machines[machine_id]
        kind = (own[2], own[6])
        present = set(read.machine.tolist())
        others = [
            i
            for i, m in read.machines.items()
            if (m[2], m[6]) == kind and i != machine_id and i in present
        ]
        chosen = np.isin(read.machine, np.array(others, dtype=np.int64))
        values: dict[tuple[str, str], dict[str, NDArray[np.float64]]] = {}
        for (machine_type, axis, unit), code in read.groups.items():
            if machine_type != kind[0]:
                continue
            members = chosen & (read.group == code)
            if not members.any():
                continue
            found: dict[str, NDArray[np.float64]] = {}
            for j, c in enumerate(CHARACTERISTICS):
                x = read.figures[members, j]
                x = x[np.isfinite(x)]
                if x.size:
                    found[c.name] = np.sort(x)
            values[(axis, unit)] = found
        return values, len(others)

    def outliers(self, limits: Limits | None = None) -> list[Outlier]:
        """Every outlier of the fleet (:func:`~ncmeasure.analysis.judgement.status.is_outlier`
        on the arrays), largest |modified z| first: those of
        :func:`~ncmeasure.store.overview.fleet_overview`."""
        limits = limits or Limits()
        by_name = {c.name: c for c in CHARACTERISTICS}
        serial_of = dict(zip(self.machine_ids.tolist(), self.serials, strict=True))
        found: list[Outlier] = []
        for (machine_type, axis, unit, name), group in self.places.items():
            if not group.enough:
                continue
            c = by_name[name]
            hit = outliers_among(c, group.values, group.medians, group.z, limits)
            shown = c.unit_of(unit)
            for i in np.flatnonzero(hit):
                found.append(
                    Outlier(
                        serial=serial_of[int(group.ids[i])],
                        machine_type=machine_type,
                        axis=axis,
                        characteristic=name,
                        unit=shown,
                        value=float(group.values[i]),
                        fleet_median=float(group.medians[i]),
                        modified_z=float(group.z[i]),
                        machines=int(group.ids.size) - 1,
                    )
                )
        found.sort(key=lambda o: (-abs(o.modified_z), o.serial, o.axis, o.characteristic))
        return found


_MachineRow = tuple[int, str, str, str | None, int, int, str]
"""A machine as the statuses read it: id, serial, type, site, latest and baseline
measurement id, the type's configuration hash."""


@dataclass
class _Read:
    """Every machine's latest axes as the statuses read them: one entry per axis row, as
    arrays, kept with the statuses so that the next reading reads again only the machines
    whose row (latest measurement, baseline, site) changed (:func:`fleet_statuses`)."""

    machines: dict[int, _MachineRow]
    machine: NDArray[np.int64]
    """Per axis row: its machine's id."""
    axes: list[str]
    group: NDArray[np.intp]
    """Per axis row: its (machine type, axis, unit) as a code of :attr:`groups`."""
    groups: dict[tuple[str, str, str], int]
    figures: NDArray[np.float64]
    """Per axis row: the characteristics' values (NaN where not determined)."""
    local: NDArray[np.int8]
    """Per axis row: its status without the fleet."""

    @classmethod
    def empty(cls) -> _Read:
        return cls(
            machines={},
            machine=np.zeros(0, dtype=np.int64),
            axes=[],
            group=np.zeros(0, dtype=np.intp),
            groups={},
            figures=np.zeros((0, len(CHARACTERISTICS))),
            local=np.zeros(0, dtype=np.int8),
        )

    def replaced(
        self,
        machines: Sequence[_MachineRow],
        gone: set[int],
        rows: Sequence[tuple[Any, ...]],
        store: Store,
    ) -> _Read:
        """These statuses with the machines as ``machines`` (all of them) say, the axes of
        the machines ``gone`` replaced by the axis ``rows`` (machine id, axis, unit, the
        characteristics, the kept status); a row's missing status judged now."""
        known = {m[0]: m for m in machines}
        rows = [r for r in rows if r[0] in known]  # a machine added between the two reads
        keep = ~np.isin(self.machine, np.fromiter(gone, dtype=np.int64, count=len(gone)))
        groups = dict(self.groups)
        count = len(rows)
        machine = np.fromiter((r[0] for r in rows), dtype=np.int64, count=count)
        group = np.fromiter(
            (groups.setdefault((known[r[0]][2], r[1], r[2]), len(groups)) for r in rows),
            dtype=np.intp,
            count=count,
        )
        width = len(CHARACTERISTICS)
        figures = np.array([r[3 : 3 + width] for r in rows], dtype=np.float64).reshape(
            count, width
        )  # None: NaN
        local = np.array([_LEVEL.get(r[3 + width], -1) for r in rows], dtype=np.int8)
        missing = np.flatnonzero(local < 0)
        if missing.size:
            judged = _judge_missing(store, sorted({int(machine[i]) for i in missing}))
            for i in missing:
                own = judged.get(int(machine[i]), {})
                status = own.get(rows[int(i)][1])
                # A writer that added a measurement between the two reads may have changed
                # the machine's axes: its newest judgement's worst stands for the axis read
                # before.
                if status is None:
                    local[i] = max((_LEVEL[other] for other in own.values()), default=0)
                else:
                    local[i] = _LEVEL[status]
        kept_axes = list(itertools.compress(self.axes, keep.tolist()))
        return _Read(
            machines=known,
            machine=np.concatenate((self.machine[keep], machine)),
            axes=kept_axes + [r[1] for r in rows],
            group=np.concatenate((self.group[keep], group)),
            groups=groups,
            figures=np.concatenate((self.figures[keep], figures)),
            local=np.concatenate((self.local[keep], local)),
        )


def fleet_statuses(store: Store, previous: FleetStatuses | None = None) -> FleetStatuses:
    """Every machine's status with the default limits: the kept statuses without the fleet
    (judged now where missing) and the fleet's part for all at once.

    Args:
        store: The store.
        previous: Statuses read before from the same store: only the machines whose
            latest measurement, baseline or site changed since are read again (their
            axes, figures and kept statuses); the fleet's part is judged again for all.

    Raises:
        StoreError: The database failed.
    """
    limits = Limits()
    s, a, st = t.machine_summaries, t.axis_results, t.axis_statuses
    kept = and_(
        st.c.machine_id == s.c.machine_id,
        st.c.axis == a.c.axis,
        st.c.latest_id == s.c.latest_id,
        st.c.baseline_id == s.c.baseline_id,
        st.c.diagnosis_version == DIAGNOSIS_VERSION,
    )
    machines_query = select(
        s.c.machine_id,
        s.c.serial,
        s.c.machine_type,
        s.c.site,
        s.c.latest_id,
        s.c.baseline_id,
        s.c.config_hash,
    ).where(s.c.latest_id.is_not(None))
    axes_query = (
        select(
            s.c.machine_id,
            a.c.axis,
            a.c.unit,
            *(a.c[c.name] for c in CHARACTERISTICS),
            st.c.status,
        )
        .join_from(s, a, a.c.measurement_id == s.c.latest_id)
        .outerjoin(st, kept)
    )
    before = previous.read if previous is not None else None
    with store.reading("read the fleet's statuses") as db:
        version = fleet_version(db)
        machines: list[_MachineRow] = plain_rows(db, machines_query)
        if before is None:
            before = _Read.empty()
            gone: set[int] = set()
            rows = plain_rows(db, axes_query)
        else:
            changed = sorted({m[0] for m in set(machines) - set(before.machines.values())})
            gone = set(changed) | (before.machines.keys() - {m[0] for m in machines})
            rows = [
                row
                for start in range(0, len(changed), _CHUNK)
                for row in plain_rows(
                    db, axes_query.where(s.c.machine_id.in_(changed[start : start + _CHUNK]))
                )
            ]
    read = before.replaced(machines, gone, rows, store)
    ids, inverse = np.unique(read.machine, return_inverse=True)
    info = [read.machines[i] for i in ids.tolist()]
    serials = [m[1] for m in info]
    by_serial = np.array(sorted(range(ids.size), key=serials.__getitem__), dtype=np.intp)
    place = np.empty(ids.size, dtype=np.intp)
    place[by_serial] = np.arange(ids.size)
    axis_machine = place[inverse] if read.machine.size else np.zeros(0, dtype=np.intp)
    places, flagged = _fleet(read, limits)
    axis_levels = np.where(flagged, np.maximum(read.local, 1), read.local).astype(np.int8)
    levels = np.zeros(ids.size, dtype=np.int8)
    np.maximum.at(levels, axis_machine, axis_levels)
    return FleetStatuses(
        version=version,
        machine_ids=ids[by_serial],
        serials=[serials[i] for i in by_serial],
        types=[info[i][2] for i in by_serial],
        sites=[info[i][3] for i in by_serial],
        levels=levels,
        axis_machine=axis_machine,
        axis_levels=axis_levels,
        axis_names=sorted(set(read.axes)),
        places=places,
        read=read,
    )


def _fleet(read: _Read, limits: Limits) -> tuple[dict[Group, _Places], NDArray[np.bool_]]:
    """Per group: every member's modified z-score against the others and their median; and
    per row, whether its fleet makes the axis a warning: an outlier
    (:func:`~ncmeasure.analysis.judgement.status.is_outlier`), or a level
    :data:`FLEET_FACTOR` from the median. The tests of the judgement, on arrays."""
    places: dict[Group, _Places] = {}
    flagged = np.zeros(read.machine.size, dtype=bool)
    if not read.machine.size:
        return places, flagged
    present = np.unique(read.group)
    for j, c in enumerate(CHARACTERISTICS):
        column = read.figures[:, j]
        finite = np.isfinite(column)
        for (machine_type, axis, unit), code in sorted(read.groups.items(), key=lambda g: g[1]):
            if code not in present:
                continue
            members = np.flatnonzero((read.group == code) & finite)
            if members.size < 2:
                continue
            x = column[members]
            ids = read.machine[members]
            enough = x.size - 1 >= limits.outlier_min_runs
            z, median = modified_z_leave_one_out(x)
            hit = np.zeros(x.size, dtype=bool)
            if enough:
                hit |= outliers_among(c, x, median, z, limits)
            if c.relative:
                with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                    ratio = x / median
                far = (ratio > FLEET_FACTOR) | (ratio < 1.0 / FLEET_FACTOR)
                hit |= (median > 0) & (x > 0) & far
            flagged[members[hit]] = True
            order = np.argsort(ids, kind="stable")
            places[(machine_type, axis, unit, c.name)] = _Places(
                ids=ids[order],
                values=x[order],
                medians=median[order],
                z=z[order],
                enough=enough,
            )
    return places, flagged


def _judge_missing(store: Store, machine_ids: Sequence[int]) -> dict[int, dict[str, Status]]:
    """The statuses without the fleet of these machines, judged now; kept when the store
    is open for writing."""
    s = t.machine_summaries
    found: dict[int, dict[str, Status]] = {}
    for start in range(0, len(machine_ids), _BATCH):
        chunk = list(machine_ids[start : start + _BATCH])
        with store.reading("read the machines to judge") as db:
            machines = db.execute(select(s).where(s.c.machine_id.in_(chunk))).all()
        overviews = overviews_of(machines)
        baselines = read_axes(store, overviews)
        changes = changes_of(store, machines, overviews)
        judged: list[tuple[Any, MachineOverview]] = []
        for row, machine in zip(machines, overviews, strict=True):
            judge(machine, baselines, None, changes, Limits())
            found[int(row.machine_id)] = {n: a.status for n, a in machine.axes.items()}
            judged.append((row, machine))
        if store.write:
            with store.writing("keep the statuses without the fleet") as db:
                _keep(db, judged)
    if not store.write:
        _log.warning(
            "%d machine(s) without a current stored status: judged now on every reading; "
            "`ncmeasure store refresh` stores them",
            len(machine_ids),
        )
    return found


def keep_own_statuses(db: Connection, machine_ids: Sequence[int]) -> None:
    """Judge these machines' own statuses (without the fleet, default limits) and keep them,
    in the caller's transaction: what a writer adding their measurements leaves, so no reader
    judges them again. Their summary rows and changes since the baseline are current
    (:func:`~ncmeasure.store.summaries.update_summaries`,
    :func:`~ncmeasure.store.changes.record_changes`)."""
    s = t.machine_summaries
    for start in range(0, len(machine_ids), _CHUNK):
        chunk = list(machine_ids[start : start + _CHUNK])
        machines = db.execute(
            select(s).where(s.c.machine_id.in_(chunk), s.c.latest_id.is_not(None))
        ).all()
        overviews = overviews_of(machines)
        wanted = [i for m in overviews for i in (m.latest_id, m.baseline_id)]
        baselines = fill_axes(overviews, axis_rows_in(db, wanted))
        pairs = {
            int(row.machine_id): (int(row.latest_id), int(row.baseline_id))
            for row in machines
            if row.latest_id != row.baseline_id
        }
        stored = stored_changes(db, pairs.values())
        changes: dict[str, StoredChange] = {}
        for row in machines:
            pair = pairs.get(int(row.machine_id))
            if pair is None:
                continue
            if pair in stored:
                changes[row.serial] = stored[pair]
            elif (now := current_change(db, int(row.machine_id))) is not None:
                changes[row.serial] = StoredChange.of(now[2])
        judged: list[tuple[Any, MachineOverview]] = []
        for row, machine in zip(machines, overviews, strict=True):
            judge(machine, baselines, None, changes, Limits())
            judged.append((row, machine))
        _keep(db, judged)


def _keep(db: Connection, judged: Sequence[tuple[Any, MachineOverview]]) -> None:
    st = t.axis_statuses
    ids = [int(row.machine_id) for row, _ in judged]
    for start in range(0, len(ids), _CHUNK):
        db.execute(delete(st).where(st.c.machine_id.in_(ids[start : start + _CHUNK])))
    values = [
        {
            "machine_id": int(row.machine_id),
            "axis": name,
            "latest_id": int(row.latest_id),
            "baseline_id": int(row.baseline_id),
            "diagnosis_version": DIAGNOSIS_VERSION,
            "status": axis.status,
        }
        for row, machine in judged
        for name, axis in machine.axes.items()
    ]
    if values:
        db.execute(insert(st), values)


def judged_page(
    store: Store, statuses: FleetStatuses, machine_ids: Sequence[int]
) -> list[MachineOverview]:
    """These machines (by serial), judged in full as the fleet overview judges them: their
    axes, changes, reasons and places in the fleet (default limits).

    Raises:
        StoreError: The database failed.
    """
    s = t.machine_summaries
    if not machine_ids:
        return []
    with store.reading("read the machines") as db:
        machines = db.execute(
            select(s).where(s.c.machine_id.in_(list(machine_ids))).order_by(s.c.serial)
        ).all()
    overviews = overviews_of(machines)
    baselines = read_axes(store, overviews)
    changes = changes_of(store, machines, overviews)
    for row, machine in zip(machines, overviews, strict=True):
        places = statuses.places_of(int(row.machine_id), machine.machine_type)
        judge(machine, baselines, places, changes, Limits())
    return overviews
