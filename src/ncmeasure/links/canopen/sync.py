"""SYNC: the link's own SYNC production, and rows from PDO frames cycle by SYNC cycle.

The producer (:class:`SyncProducer`) keeps time by the link's
:class:`~ncmeasure.samples.LinkClock`. Real time for real drives: SYNC ``k``
goes out at ``k × period`` (:func:`run_sync_schedule`); when the host wakes so
late that the next cycle is due already, it skips the missed cycles instead of
sending them in a burst, and counts them. With ncmeasure's own simulated drives
on a :class:`~ncmeasure.samples.SimulatedClock` it runs in lockstep: SYNC ``k``
goes out at simulated time ``k × period``, the drives answer with the machine
state of that time, and SYNC ``k + 1`` waits until the link has received all
they sent, however slow the computer is.

The assembler (:class:`CycleAssembler`) makes rows from PDO frames: which SYNC
cycle a frame belongs to, and which cycles are lost. A drive samples its values
when it sees SYNC and sends its synchronous TPDOs before the next SYNC. So, in
the order frames travel on the bus, a PDO frame belongs to the SYNC that came
before it. The link therefore feeds the assembler in bus order: every frame as
it is received, and every SYNC as it is *seen on the bus* (its own SYNC comes
back through the receive stream, python-can's ``receive_own_messages``), never
as it is sent. A frame that the host receives late still counts in its own
cycle, because the next SYNC is behind it in the same stream.

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

import collections
import functools
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal, cast

import can
import canopen

from ncmeasure.errors import LinkError
from ncmeasure.samples import LinkClock, SimulatedClock

log = logging.getLogger(__name__)

__all__ = [
    "CycleAssembler",
    "ForeignSync",
    "LossReason",
    "LostCycle",
    "SyncProducer",
    "TimedAssembler",
    "no_echo_error",
    "raise_priority",
    "run_sync_schedule",
]

LossReason = Literal["missing", "no_sync", "doubled"]


def _slot_groups(slots: int, groups: Sequence[int] | None) -> list[int]:
    """The node of every PDO slot (each its own without ``groups``), checked."""
    if slots < 1:
        raise ValueError("slots must be positive")
    found = list(groups) if groups is not None else list(range(slots))
    if len(found) != slots:
        raise ValueError("one group per slot")
    return found


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
        self.slots = slots
        self._groups = _slot_groups(slots, groups)
        self.newest = -1
        """The cycle of the newest SYNC seen (-1 before the first)."""
        self.early_frames = 0
        """Frames that came before the first SYNC (they belong to no cycle of this link)."""
        self._group_index = [sorted(set(self._groups)).index(g) for g in self._groups]
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
        self._order = _learned_order(self._arrival, self._groups, self._group_index)


class _OpenCycle:
    """A cycle of :class:`TimedAssembler` that is not final yet."""

    __slots__ = ("arrival", "cycle", "doubted", "filled", "last", "row", "sent_s")

    def __init__(self, cycle: int, sent_s: float, slots: int, groups: int) -> None:
        self.cycle = cycle
        self.sent_s = sent_s
        self.row: list[bytes | None] = [None] * slots
        self.filled = 0
        self.doubted: set[int] = set()
        self.last = [-1] * groups
        self.arrival: list[int] = []


class TimedAssembler:
    """Collect PDO frames into rows by SYNC send times, where the interface returns no own SYNC.

    The producer notes the host's wall-clock time just *before* it writes each SYNC
    (``sent``: ``(cycle, time)``, appended by the SYNC thread); every frame comes with
    its receive time on the same clock (python-can's time stamp where the interface
    stamps with the host clock, else the time the link got it). A drive answers a SYNC
    only after it is on the bus, so a frame received before SYNC ``k + 1`` was sent
    belongs to cycle ``k`` or an earlier one; it may be a frame of an earlier cycle that
    the adapter, the USB or the host delivered late. What tells them apart is that each
    PDO comes once per cycle, in the drive's usual order:

    * a frame received after SYNC ``k`` was sent goes to cycle ``k`` when every cycle
      still open before ``k`` already has that PDO; if one of them lacks it, the frame is
      that cycle's late answer or ``k``'s own, which nothing can tell: both are doubted
      (so a missing frame costs its cycle and the next);
    * a second frame of a PDO in one cycle, or a frame before one it usually follows
      (the order learned from the first complete cycle), doubts the cycle, as
      :class:`CycleAssembler` does;
    * a cycle is final once it is complete and every cycle before it is final, or
      ``hold_cycles`` newer SYNCs were sent and answered: a frame later than that is not
      waited for.

    A doubted cycle is lost (``doubled``), as is an incomplete one (``missing``); a
    cycle number the producer skipped had no SYNC (``no_sync``). So a row holds the
    frames of one SYNC cycle only. Not thread-safe: the link calls it under its lock.

    Args:
        slots: Number of PDO slots (every TPDO of every node).
        groups: The node (any label) of every slot; slots of one node keep an order.
        sent: The producer's ``(cycle, send time)`` of every SYNC, oldest first.
        hold_cycles: How many newer SYNCs an incomplete cycle waits for its late frames.
    """

    def __init__(
        self,
        slots: int,
        groups: Sequence[int] | None,
        sent: collections.deque[tuple[int, float]],
        hold_cycles: int = 2,
    ) -> None:
        self.slots = slots
        self._groups = _slot_groups(slots, groups)
        self._group_index = [sorted(set(self._groups)).index(g) for g in self._groups]
        self._n_groups = max(self._group_index) + 1
        self._sent = sent
        self._hold = max(1, hold_cycles)
        self.newest = -1
        """The newest cycle whose SYNC was sent before a frame or time reached (-1: none)."""
        self.early_frames = 0
        """Frames received before the first SYNC was sent."""
        self.stale_frames = 0
        """Frames received for a cycle that was final already (dropped)."""
        self.syncs = 0
        """SYNCs sent and reached."""
        self._open: list[_OpenCycle] = []
        self._order: list[tuple[int, int]] | None = None
        self._rows: list[tuple[int, list[bytes]]] = []
        self._lost: list[LostCycle] = []

    def frame(self, slot: int, data: bytes, received_s: float) -> None:
        """A frame of PDO ``slot``, received at ``received_s`` (host wall clock)."""
        self.reach(received_s)
        open_ = self._open
        if not open_:
            if self.newest < 0:
                self.early_frames += 1
            else:
                self.stale_frames += 1
            return
        # The cycle of the newest SYNC sent before the frame (frames may be handled late).
        at = len(open_) - 1
        while open_[at].sent_s > received_s:
            at -= 1
            if at < 0:
                self.stale_frames += 1
                return
        cycle = open_[at]
        ambiguous = False
        for older in open_[:at]:
            if older.row[slot] is None:
                older.doubted.add(slot)  # its late frame, or the newer cycle's own
                ambiguous = True
        if ambiguous:
            # Both are lost. The newer cycle counts the slot as come, so that its next
            # frame is not taken for this cycle's own: one late or missing frame costs
            # two cycles, not every cycle after it.
            cycle.doubted.add(slot)
            if cycle.row[slot] is None:
                cycle.row[slot] = data
                cycle.filled += 1
            return
        self._put(cycle, slot, data)
        if at == 0 and cycle.filled == self.slots and len(open_) > 1:
            self._finish_ready()

    def reach(self, now_s: float) -> None:
        """Host time ``now_s`` is reached: the SYNCs sent before it open their cycles."""
        sent = self._sent
        opened = False
        while sent and sent[0][1] <= now_s:
            cycle, sent_s = sent.popleft()
            if cycle <= self.newest:
                continue
            if self.newest >= 0 and cycle > self.newest + 1:
                self._finish_all()  # a cycle the producer skipped: nothing before it waits
                everything = frozenset(range(self.slots))
                self._lost.extend(
                    LostCycle(skipped, everything, "no_sync")
                    for skipped in range(self.newest + 1, cycle)
                )
            self.newest = cycle
            self.syncs += 1
            self._open.append(_OpenCycle(cycle, sent_s, self.slots, self._n_groups))
            opened = True
        if opened:
            self._finish_ready()

    def finish(self) -> None:
        """Everything open becomes final (the link closes)."""
        self._finish_all()

    def take(self) -> tuple[list[tuple[int, list[bytes]]], list[LostCycle]]:
        """The rows and lost cycles that became final since the last call, each in cycle order."""
        rows, self._rows = self._rows, []
        lost, self._lost = self._lost, []
        return rows, lost

    def _put(self, cycle: _OpenCycle, slot: int, data: bytes) -> None:
        row = cycle.row
        if self._order is None:
            cycle.arrival.append(slot)
            if row[slot] is not None:
                cycle.doubted.add(slot)
                return
        else:
            group, rank = self._order[slot]
            if row[slot] is not None or rank < cycle.last[group]:
                cycle.doubted.add(slot)
                if row[slot] is not None:
                    return
            else:
                cycle.last[group] = rank
        row[slot] = data
        cycle.filled += 1

    def _finish_ready(self) -> None:
        """Final, oldest first: complete cycles, and those ``hold_cycles`` behind the newest."""
        open_ = self._open
        done = 0
        for cycle in open_[:-1]:
            if cycle.filled < self.slots and cycle.cycle > self.newest - self._hold:
                break
            self._final(cycle)
            done += 1
        if done:
            del open_[:done]

    def _finish_all(self) -> None:
        for cycle in self._open:
            self._final(cycle)
        self._open = []

    def _final(self, cycle: _OpenCycle) -> None:
        if cycle.doubted:
            self._lost.append(LostCycle(cycle.cycle, frozenset(cycle.doubted), "doubled"))
        elif cycle.filled == self.slots:
            self._rows.append((cycle.cycle, cast(list[bytes], cycle.row)))
            if self._order is None:
                self._order = _learned_order(cycle.arrival, self._groups, self._group_index)
        else:
            missing = frozenset(i for i, data in enumerate(cycle.row) if data is None)
            self._lost.append(LostCycle(cycle.cycle, missing))


def _learned_order(
    arrival: Sequence[int], groups: Sequence[int], group_index: Sequence[int]
) -> list[tuple[int, int]]:
    """Per slot, its node's index and its position among the node's frames of one cycle."""
    order: dict[int, dict[int, int]] = {}
    for slot in arrival:
        positions = order.setdefault(groups[slot], {})
        positions.setdefault(slot, len(positions))
    return [(group_index[slot], order[groups[slot]][slot]) for slot in range(len(groups))]


def raise_priority(priority: int, period_s: float) -> tuple[str | None, Callable[[], None]]:
    """Give the calling thread (the SYNC producer) the host's attention for its period.

    On a busy host an ordinary thread wakes late and SYNC cycles are skipped: two
    busy loops on a 2-core PC made a 1 kHz producer skip 40 to 75 % of its cycles
    (``benchmarks/acquisition_canopen.py --busy``). Two things keep it on time, and
    neither helps alone: the thread runs under the real-time policy ``SCHED_FIFO``
    at ``priority`` (Linux; it wakes before any ordinary process), and the
    interpreter hands the GIL over within half a period (``sys.setswitchinterval``;
    5 ms by default, five 1 kHz cycles), so the woken thread does not wait for a
    Python thread that holds it.

    The switch interval is only ever lowered, and the returned function restores it
    unless something else changed it meanwhile.

    Args:
        priority: The ``SCHED_FIFO`` priority (1–99); 0 leaves the thread as it is.
        period_s: The SYNC period (wall clock).

    Returns:
        Why the priority could not be raised (None: raised, or 0 asked), and the
        function that undoes the switch interval.
    """

    def nothing() -> None:
        return None

    if priority <= 0:
        return None, nothing
    setscheduler = getattr(os, "sched_setscheduler", None)
    if setscheduler is None:
        return "real-time scheduling is not available on this system", nothing
    try:
        setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))  # 0: this thread
    except OSError as exc:
        return (
            f"real-time priority {priority} refused ({exc.strerror or exc}); allow it "
            "with an rtprio limit (limits.conf) or CAP_SYS_NICE, or set link.sync_priority "
            "= 0"
        ), nothing
    before = sys.getswitchinterval()
    wanted = min(before, period_s / 2)
    if wanted >= before:
        return None, nothing
    sys.setswitchinterval(wanted)
    set_to = sys.getswitchinterval()

    def restore() -> None:
        if sys.getswitchinterval() == set_to:
            sys.setswitchinterval(before)

    return None, restore


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


class SyncProducer:
    """The link's own SYNC: cycle ``k`` at ``k × period`` of the link clock, until stopped.

    Args:
        network: The link's network (its bus and send lock).
        clock: The link clock: real time, or a :class:`~ncmeasure.samples.SimulatedClock`
            for lockstep with simulated drives.
        period_s: The SYNC period on that clock.
        stop: Set when the link closes.
        cond: The link's condition; lockstep waits on it for ``cycle_received``.
        cycle_received: Lockstep: called with a cycle and the drives' frame count
            (``cond`` held), true once the next SYNC may go out.
        skipped: Called with the first skipped cycle and how many were skipped.
        started: Called with the clock time of cycle 0 (real time).
        failed: Called with the error that ends the production.
        step_timeout_s: Lockstep: the longest wall-clock wait for the drives' answer.
        priority: Real time: the thread's ``SCHED_FIFO`` priority (:func:`raise_priority`;
            0: none).
        noted: Called with a sentence worth an ``info`` event (a priority refused).
    """

    def __init__(
        self,
        network: canopen.Network,
        clock: LinkClock,
        period_s: float,
        stop: threading.Event,
        *,
        cond: threading.Condition,
        cycle_received: Callable[[int, int], bool],
        skipped: Callable[[int, int], None],
        started: Callable[[float], None],
        failed: Callable[[LinkError], None],
        step_timeout_s: float,
        priority: int = 0,
        noted: Callable[[str], None] | None = None,
    ) -> None:
        self._network = network
        self._clock = clock
        self._period = period_s
        self._stop = stop
        self._cond = cond
        self._cycle_received = cycle_received
        self._skipped = skipped
        self._started = started
        self._failed = failed
        self._step_timeout_s = step_timeout_s
        self._priority = priority
        self._noted = noted
        self._message = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        self.sent: collections.deque[int] = collections.deque()
        """Cycles of own SYNCs sent and not yet seen back, in order."""
        self.timed = False
        """True where the interface returns no own SYNC: :attr:`send_times` are kept."""
        self.send_times: collections.deque[tuple[int, float]] = collections.deque()
        """``(cycle, host wall-clock time just before the SYNC was written)``, oldest first
        (:class:`TimedAssembler` takes them)."""
        self.sent_cycle = -1
        """The newest cycle sent."""

    def run(self) -> None:
        """Send SYNC cycle k at ``k × period`` on the link clock (real time or lockstep).

        A SYNC that cannot be sent, or (lockstep) drives that do not answer, end it
        with a LinkError for ``failed``.
        """
        try:
            if self._clock.lockstep:
                self._produce_in_lockstep()
            else:
                self._produce_in_real_time()
        except LinkError as exc:
            self._failed(exc)

    def seen(self) -> int | None:
        """An own SYNC came back through the receive stream: its cycle (None: not ours)."""
        return self.sent.popleft() if self.sent else None

    def _send(self, cycle: int) -> None:
        network = self._network
        assert network.bus is not None
        # Not under the link's lock: the receive thread holds it while it assembles
        # frames, and on a busy host a SYNC waiting for it came late and was skipped.
        # A deque's append is atomic, and it comes before the send, so the receive
        # thread finds the cycle when it sees the SYNC.
        if self.timed:
            # Before the write: no drive can answer this SYNC before this time.
            self.send_times.append((cycle, time.time()))
        else:
            self.sent.append(cycle)
        self.sent_cycle = cycle
        try:
            with network.send_lock:  # SDO transfers of the worker share the bus
                network.bus.send(self._message)
        except Exception as exc:
            raise LinkError(f"cannot send SYNC: {exc}") from exc

    def _produce_in_real_time(self) -> None:
        """SYNC k at ``k × period`` of the clock; a stall skips cycles (counted), never a burst.

        The skipped cycles have no SYNC on the bus, so they come out as a ``gap`` event
        ("SYNC cycles not sent (the host fell behind)") with their number.
        """
        clock = self._clock
        refused, restore = raise_priority(self._priority, clock.wall(self._period))
        if refused is not None:
            log.info("SYNC producer at normal priority: %s", refused)
            if self._noted is not None:
                self._noted(
                    f"the SYNC thread runs at normal priority: {refused}; on a busy host it "
                    "skips cycles (counted as gaps)"
                )
        try:
            self._started(clock.now())
            run_sync_schedule(
                self._period,
                clock.now,
                lambda delay: self._stop.wait(clock.wall(delay)),
                self._send,
                self._skipped,
            )
        finally:
            restore()

    def _produce_in_lockstep(self) -> None:
        """SYNC k at simulated time k × period; SYNC k + 1 once all of cycle k is received.

        The simulated drives report each SYNC answered and how many frames they sent
        (:meth:`~ncmeasure.samples.SimulatedClock.step_done`); the next SYNC waits until
        the link has received them all, until no drive is being configured again, and
        until the reader has taken the rows, so the recording does not depend on how fast
        the threads run.
        """
        clock = cast(SimulatedClock, self._clock)
        cycle = 0
        while not self._stop.is_set():
            clock.advance_to(cycle * self._period)
            self._send(cycle)
            sent = self._wait_for_drives(clock, cycle)
            if sent is None:
                return
            with self._cond:
                ready = self._cond.wait_for(
                    functools.partial(self._cycle_received, cycle, sent), self._step_timeout_s
                )
            if not ready:
                raise LinkError(
                    f"SYNC cycle {cycle}: the simulated drives' frames did not arrive within "
                    f"{self._step_timeout_s:g} s"
                )
            cycle += 1

    def _wait_for_drives(self, clock: SimulatedClock, cycle: int) -> int | None:
        """The simulated drives' frame count after answering ``cycle``; None when stopping."""
        deadline = time.monotonic() + self._step_timeout_s
        while not self._stop.is_set():
            sent = clock.wait_step(cycle, 0.1)
            if sent is not None:
                return sent
            if time.monotonic() > deadline:
                raise LinkError(
                    f"the simulated drives did not answer SYNC cycle {cycle} within "
                    f"{self._step_timeout_s:g} s; a link on a SimulatedClock needs simulated "
                    "drives on the same clock (SimulatedDrives.start(..., clock=clock))"
                )
        return None


def no_echo_error(interface: str | None) -> LinkError:
    """The link's own SYNC did not come back through the receive stream."""
    return LinkError(
        f"the CAN interface {interface or '(python-can config)'} does not "
        "return the link's own SYNC frames (python-can receive_own_messages); the link "
        "needs them to give every PDO to its SYNC cycle. Use an interface that does "
        "(socketcan, pcan, kvaser, vector, ixxat, virtual, ...), or let the controller "
        "produce SYNC (link.sync_producer = false)"
    )


class ForeignSync:
    """SYNC of another master: cycles counted, missing ones noticed by the frames' time stamps."""

    def __init__(self) -> None:
        self._last: float | None = None

    def step(self, timestamp: float, wall_period_s: float) -> int:
        """How many cycles on from the previous SYNC this one is (1: none missing).

        Args:
            timestamp: The frame's time stamp (wall clock).
            wall_period_s: The SYNC period on the wall clock.
        """
        previous, self._last = self._last, timestamp
        if previous is None:
            return 1
        return max(1, round((timestamp - previous) / wall_period_s))
