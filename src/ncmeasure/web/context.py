"""What every page and endpoint shares: the open store and a cache of derived things.

The store's engine lives as long as the application (opened on startup,
disposed on shutdown). Checks and plots are derived from the store's content
and cost tens of milliseconds each; they are cached under the store's
*version* (the store's revision, counted by every adding transaction as it
commits, and the highest machine id), so a measurement added by ``ncmeasure store
add`` elsewhere shows on the next request, whatever order two adds commit in.
Reading it costs two index look-ups, not a count of the measurements. What
depends on one stored measurement alone (the friction figures of its axes) is
kept across versions (:meth:`Context.of_measurement`): a stored measurement never
changes.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from fastapi import Request
from sqlalchemy import func, select

from ncmeasure.store import Store
from ncmeasure.store import schema as t
from ncmeasure.store.check import StoreCheck, check_machine
from ncmeasure.store.statuses import FleetStatuses, fleet_statuses

__all__ = ["Context", "Version", "context"]

_T = TypeVar("_T")
_CACHE_LIMIT = 512
_KEPT_LIMIT = 128
"""Figures of single measurements kept (some 50 kB each)."""

Version = tuple[int, int]
"""The store's version: (its revision, the highest machine id); the revision moves with
every add as it commits (:func:`~ncmeasure.store.summaries.store_revision`)."""


@dataclass
class Context:
    """The store and the cache of one running application."""

    store: Store
    _cache: dict[tuple[Version, Hashable], Any] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _kept: OrderedDict[Hashable, Any] = field(default_factory=OrderedDict)
    _statuses: FleetStatuses | None = None

    def version(self) -> Version:
        """The store's version now; read it once per request, before reading the store."""
        with self.store.reading("read the store's version") as db:
            revision, machine = db.execute(
                select(
                    select(t.store_state.c.revision)
                    .where(t.store_state.c.id == 1)
                    .scalar_subquery(),
                    select(func.max(t.machines.c.id)).scalar_subquery(),
                )
            ).one()
        return int(revision or 0), int(machine or 0)

    def cached(self, version: Version, key: Hashable, compute: Callable[[], _T]) -> _T:
        """``compute()``, remembered under ``key`` for this version of the store.

        A value computed while the store changed is kept under the version read
        before, so it is never taken for the newer one. Entries of older
        versions are dropped.
        """
        with self._lock:
            if (version, key) in self._cache:
                found: _T = self._cache[(version, key)]
                return found
        value = compute()
        with self._lock:
            stale = [k for k in self._cache if k[0] != version]
            if stale or len(self._cache) >= _CACHE_LIMIT:
                self._cache.clear()
            self._cache[(version, key)] = value
        return value

    def of_measurement(self, measurement_id: int, key: Hashable, compute: Callable[[], _T]) -> _T:
        """``compute()`` of what depends on a stored measurement alone, remembered under
        its id and ``key`` across versions of the store (a measurement is never changed
        nor deleted), the most recently used :data:`_KEPT_LIMIT` of them."""
        whole = (measurement_id, key)
        with self._lock:
            if whole in self._kept:
                self._kept.move_to_end(whole)
                found: _T = self._kept[whole]
                return found
        value = compute()
        with self._lock:
            self._kept[whole] = value
            while len(self._kept) > _KEPT_LIMIT:
                self._kept.popitem(last=False)
        return value

    def statuses(self, version: Version) -> FleetStatuses:
        """Every machine's status (:func:`~ncmeasure.store.statuses.fleet_statuses`),
        cached for this version and read on from the last ones: after a change only the
        machines it touched are read again."""

        def read() -> FleetStatuses:
            found = fleet_statuses(self.store, self._statuses)
            with self._lock:
                self._statuses = found
            return found

        return self.cached(version, "statuses", read)

    def check(self, version: Version, serial: str) -> StoreCheck:
        """:func:`~ncmeasure.store.check.check_machine`, cached for this version; once the
        fleet's statuses have been read (the grid), the other machines' figures come from
        them, read on for this version, instead of from a read of the whole type."""

        def checked() -> StoreCheck:
            fleet = self.statuses(version) if self._statuses is not None else None
            return check_machine(self.store, serial, statuses=fleet)

        return self.cached(version, ("check", serial), checked)


def context(request: Request) -> Context:
    """The application's :class:`Context` (a FastAPI dependency)."""
    found: Context = request.app.state.context
    return found
