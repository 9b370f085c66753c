"""Rows from PDO frames: which SYNC cycle a frame belongs to, and which cycles are lost."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import cast

__all__ = [
    "CycleAssembler",
    "LostCycle",
]

log = logging.getLogger(__name__)

# --- assembling rows from PDOs ------------------------------------------------------------


@dataclass(frozen=True)
class LostCycle:
    """A SYNC cycle that will not become a row."""

    cycle: int
    missing: frozenset[int]
    """PDO slots without data (all when no SYNC was sent)."""
    no_sync: bool = False


class CycleAssembler:
    """Collect PDO frames into rows keyed by SYNC cycle. Not thread-safe: lock around it.

    A frame belongs to the newest SYNC cycle (a drive samples on SYNC and
    answers before the next one). A second frame of the same PDO within one
    cycle proves the drive lags behind (a busy host): the earlier frames of
    that PDO move back one cycle each, into the first earlier cycle that lacks
    it, which keeps every frame at or after its true cycle. Cycles that are
    still incomplete ``hold_cycles`` after the newest SYNC are lost.
    """

    def __init__(self, slots: int, hold_cycles: int) -> None:
        if slots < 1 or hold_cycles < 1:
            raise ValueError("slots and hold_cycles must be positive")
        self.slots = slots
        self.hold_cycles = hold_cycles
        self.newest = -1
        self.next_cycle = 0
        self.late_frames = 0
        self._rows: dict[int, list[bytes | None]] = {}
        self._filled: dict[int, int] = {}
        self._no_sync: set[int] = set()

    def sync(self, cycle: int) -> None:
        """A SYNC of ``cycle`` was sent or seen (cycles only grow)."""
        if cycle <= self.newest:
            raise ValueError(f"SYNC cycle {cycle} after {self.newest}")
        self.newest = cycle

    def skip(self, first: int, count: int) -> None:
        """Cycles ``first .. first + count - 1`` had no SYNC on the bus."""
        self._no_sync.update(range(first, first + count))

    def _row(self, cycle: int) -> list[bytes | None]:
        row = self._rows.get(cycle)
        if row is None:
            row = self._rows[cycle] = [None] * self.slots
            self._filled[cycle] = 0
        return row

    def _previous(self, cycle: int) -> int:
        cycle -= 1
        while cycle in self._no_sync:
            cycle -= 1
        return cycle

    def frame(self, slot: int, data: bytes) -> None:
        """A frame of PDO ``slot`` arrived."""
        newest = self.newest
        if newest < self.next_cycle:
            self.late_frames += 1  # before the first SYNC
            return
        row = self._row(newest)
        if row[slot] is None:
            row[slot] = data
            self._filled[newest] += 1
            return
        start = newest
        while True:
            before = self._previous(start)
            if before < self.next_cycle:
                break
            prev = self._rows.get(before)
            if prev is None or prev[slot] is None:
                break
            start = before
        carried: bytes | None = data
        cycle = newest
        while cycle >= start:
            row_c = self._rows[cycle]
            row_c[slot], carried = carried, row_c[slot]
            if cycle == start:
                break
            cycle = self._previous(cycle)
        target = self._previous(start)
        if target >= self.next_cycle:
            self._row(target)[slot] = carried
            self._filled[target] += 1
        else:
            self.late_frames += 1  # the lag reaches back beyond the open cycles

    def settle(self, final: bool = False) -> tuple[list[tuple[int, list[bytes]]], list[LostCycle]]:
        """Complete rows in cycle order, and the cycles given up (``final``: all but the newest)."""
        rows: list[tuple[int, list[bytes]]] = []
        lost: list[LostCycle] = []
        limit = self.newest - (1 if final else self.hold_cycles)
        everything = frozenset(range(self.slots))
        while self.next_cycle <= self.newest:
            cycle = self.next_cycle
            if cycle in self._no_sync:
                self._no_sync.discard(cycle)
                self._rows.pop(cycle, None)
                self._filled.pop(cycle, None)
                lost.append(LostCycle(cycle, everything, no_sync=True))
            elif self._filled.get(cycle) == self.slots:
                rows.append((cycle, cast(list[bytes], self._rows.pop(cycle))))
                del self._filled[cycle]
            elif cycle <= limit:
                row = self._rows.pop(cycle, None)
                self._filled.pop(cycle, None)
                missing = (
                    everything
                    if row is None
                    else frozenset(i for i, value in enumerate(row) if value is None)
                )
                lost.append(LostCycle(cycle, missing))
            else:
                break
            self.next_cycle += 1
        return rows, lost
