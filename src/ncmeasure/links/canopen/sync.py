"""Rows from PDO frames: which SYNC cycle a frame belongs to, and which cycles are lost.

A drive samples its values when it sees SYNC and sends its synchronous TPDOs
before the next SYNC. So, in the order frames travel on the bus, a PDO frame
belongs to the SYNC that came before it. The link therefore feeds the
assembler in bus order: every frame as it is received, and every SYNC as it
is *seen on the bus* (its own SYNC comes back through the receive stream,
python-can's ``receive_own_messages``), never as it is sent. A frame that the
host receives late still counts in its own cycle, because the next SYNC is
behind it in the same stream.

A row holds the values of one SYNC cycle only. A cycle is final when the next
SYNC is seen: complete, it becomes a row; otherwise it is lost. Where the cycle
of a frame cannot be told, the cycle is dropped and counted as lost, never
shifted or filled:

* a second frame of the same PDO before the next SYNC (the first one was a
  cycle late);
* a drive's frames out of their usual order: a drive sends its TPDOs in the
  same order every cycle (the lower COB-ID wins the bus), so a frame that comes
  before one it usually follows was sent for the cycle before, after its SYNC.
  That is how a drive that answers one TPDO late, cycle after cycle, shows:
  each cycle would otherwise look complete with one value a cycle old. The
  usual order is learned from the first complete cycle.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

__all__ = ["CycleAssembler", "LossReason", "LostCycle", "run_sync_schedule"]

LossReason = Literal["missing", "no_sync", "doubled"]


@dataclass(frozen=True)
class LostCycle:
    """A SYNC cycle that will not become a row."""

    cycle: int
    missing: frozenset[int]
    """PDO slots without data (all when no SYNC was seen), or the slots whose cycle
    could not be told."""
    reason: LossReason = "missing"
    """``missing``: slots without a frame; ``no_sync``: no SYNC for this cycle on the bus;
    ``doubled``: frames whose cycle cannot be told (twice, or out of their order)."""

    @property
    def no_sync(self) -> bool:
        """True when the cycle had no SYNC on the bus."""
        return self.reason == "no_sync"


class CycleAssembler:
    """Collect PDO frames, in bus order, into rows keyed by SYNC cycle.

    Args:
        slots: Number of PDO slots (every TPDO of every node).
        groups: The node (any label) of every slot; slots of one node keep an order.

    Not thread-safe: the link calls it under its lock, from the thread that
    receives the bus (frames and SYNCs in the order they were received).
    """

    def __init__(self, slots: int, groups: Sequence[int] | None = None) -> None:
        if slots < 1:
            raise ValueError("slots must be positive")
        groups = list(groups) if groups is not None else list(range(slots))
        if len(groups) != slots:
            raise ValueError("one group per slot")
        self.slots = slots
        self._groups = groups
        self.newest = -1
        """The cycle of the newest SYNC seen (-1 before the first)."""
        self.early_frames = 0
        """Frames that came before the first SYNC (they belong to no cycle of this link)."""
        self._group_index = [sorted(set(groups)).index(g) for g in groups]
        self._order: list[tuple[int, int]] | None = None
        """Per slot, its node's index and its usual position among the node's frames
        (learned from the first complete cycle); None before."""
        self._arrival: list[int] = []
        self._row: list[bytes | None] = [None] * slots
        self._filled = 0
        self._doubted: set[int] = set()
        self._last = [-1] * (max(self._group_index) + 1)
        self._rows: list[tuple[int, list[bytes]]] = []
        self._lost: list[LostCycle] = []

    def sync(self, cycle: int) -> None:
        """The SYNC of ``cycle`` was seen on the bus: the cycle before it is final.

        Cycles between the previous SYNC and this one had no SYNC on the bus.

        Raises:
            ValueError: ``cycle`` is not later than the newest SYNC.
        """
        if cycle <= self.newest:
            raise ValueError(f"SYNC cycle {cycle} after {self.newest}")
        if self.newest >= 0:
            self._finish_newest()
            if cycle > self.newest + 1:
                everything = frozenset(range(self.slots))
                self._lost.extend(
                    LostCycle(skipped, everything, "no_sync")
                    for skipped in range(self.newest + 1, cycle)
                )
        self.newest = cycle

    def frame(self, slot: int, data: bytes) -> None:
        """A frame of PDO ``slot`` was received: it belongs to the newest SYNC's cycle."""
        if self.newest < 0:
            self.early_frames += 1
            return
        row = self._row
        order = self._order
        if order is None:  # the order is not learned yet
            self._arrival.append(slot)
            if row[slot] is not None:
                self._doubted.add(slot)  # twice in one cycle
                return
        else:
            group, rank = order[slot]
            last = self._last
            if row[slot] is not None or rank < last[group]:
                # twice in one cycle, or before a frame it usually follows: a cycle late
                self._doubted.add(slot)
                if row[slot] is not None:
                    return
            else:
                last[group] = rank
        row[slot] = data
        self._filled += 1

    def take(self) -> tuple[list[tuple[int, list[bytes]]], list[LostCycle]]:
        """The rows and lost cycles that became final since the last call, each in cycle order."""
        rows, self._rows = self._rows, []
        lost, self._lost = self._lost, []
        return rows, lost

    def _finish_newest(self) -> None:
        cycle = self.newest
        if self._doubted:
            self._lost.append(LostCycle(cycle, frozenset(self._doubted), "doubled"))
        elif self._filled == self.slots:
            self._rows.append((cycle, self._row))  # type: ignore[arg-type]  # all filled
            self._learn_order()
        else:
            missing = frozenset(i for i, data in enumerate(self._row) if data is None)
            self._lost.append(LostCycle(cycle, missing))
        self._row = [None] * self.slots
        self._filled = 0
        if self._doubted:
            self._doubted = set()
        self._last = [-1] * len(self._last)
        self._arrival = []

    def _learn_order(self) -> None:
        """The first complete cycle shows each node's order of frames."""
        if self._order is not None:
            return
        order: dict[int, dict[int, int]] = {}
        for slot in self._arrival:
            positions = order.setdefault(self._groups[slot], {})
            positions.setdefault(slot, len(positions))
        self._order = [
            (self._group_index[slot], order[self._groups[slot]][slot]) for slot in range(self.slots)
        ]


def run_sync_schedule(
    period_s: float,
    now: Callable[[], float],
    wait: Callable[[float], bool],
    send: Callable[[int], None],
    skip: Callable[[int, int], None],
) -> None:
    """Produce SYNC cycle ``k`` at ``start + k × period_s``, never in a burst, until stopped.

    The schedule is absolute, so the period holds on average however late a
    wake-up is. When the producer wakes so late that the next cycle is due
    already (a host stall), it does not send the missed cycles one after the
    other to catch up: the drives sample on SYNC, and a burst would stamp
    their samples wrongly. It skips them and sends the newest due cycle.

    Args:
        period_s: The SYNC period on the clock of ``now``.
        now: The clock.
        wait: Waits that long; True when the producer must stop.
        send: Sends the SYNC of a cycle (the first is cycle 0, at ``now()`` on entry).
        skip: Called with the first skipped cycle and how many were skipped.
    """
    start = now()
    cycle = 0
    while True:
        delay = start + cycle * period_s - now()
        if delay > 0 and wait(delay):
            return
        newest = int((now() - start) / period_s)
        if newest > cycle:  # the next cycle is due already: skip, never a burst
            skip(cycle, newest - cycle)
            cycle = newest
        send(cycle)
        cycle += 1
        if delay <= 0 and wait(0.0):
            return
