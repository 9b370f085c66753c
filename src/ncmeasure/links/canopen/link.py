"""CANopen CiA 402 drive link: motor current, velocity and position over PDOs on SYNC.

How it works, in the order :meth:`CanOpenLink.open` does it:

1. The TPDO layout (which objects of which node travel in which PDO, from an
   *object map*, ``objectmaps/*.toml``) gives the bus load of one SYNC cycle;
   a layout above ``max_bus_load`` is refused before the bus is touched
   (:func:`bus_load`).
2. Every node is put pre-operational and its objects are read once over SDO
   (the drive proves it has them; a missing current object falls back to the
   map's fallback, e.g. torque 0x6077). The rated current is read from 0x6075
   when the machine file does not give it.
3. The TPDOs are written over SDO (disable, transmission type 1 = on every
   SYNC, mapping, enable) and the node goes operational. A drive that aborts
   the mapping makes the whole link fall back to SDO polling of the same
   objects, reported as an ``info`` event.
4. The link produces SYNC at ``sync_hz`` (or counts the SYNC of another
   master). A row of samples is complete when every PDO of every node for one
   SYNC cycle has arrived; ``time_s`` is the cycle number × period.

Cycles are told apart in bus order (:mod:`.sync`): the link receives its own
SYNC back through the receive stream (python-can's ``receive_own_messages``)
and gives every PDO frame to the SYNC received before it, so a frame the host
receives late still counts in its own cycle. A row holds the values of one SYNC
cycle only; a cycle whose frames cannot be told apart is dropped as lost.

The SYNC producer keeps time by the link's :class:`~ncmeasure.samples.LinkClock`.
Real time for real drives: SYNC ``k`` goes out at ``k × period`` (``1 / sync_hz``
rounded to whole microseconds, the unit of the communication cycle period
0x1006 it writes to the drives); when the host wakes so late that the next
cycle is due already, it skips the missed cycles instead of sending them in a
burst, counts them (``statistics()["sync_skipped"]``) and reports them as a
gap (:func:`~.sync.run_sync_schedule`). With
ncmeasure's own simulated drives (:mod:`ncmeasure.sim.cia402`) it runs on a
:class:`~ncmeasure.samples.SimulatedClock`, in lockstep: SYNC ``k`` goes out
at simulated time ``k × period``, the drives answer with the machine state of
that time, and SYNC ``k + 1`` waits until the link has received all they sent,
however slow the computer is.

PDO frames go from the first listener of the receive thread straight into a
:class:`~.sync.CycleAssembler` keyed by SYNC cycle (a dict from COB-ID to slot, not
canopen's PDO objects, so no frame is lost to a PDO map holding only its last
frame); their bytes are decoded in bulk, a block at a time, and the reader is
woken per block of ``READ_BLOCK_S`` of rows, not per row. Cycles that stay
incomplete are dropped, never filled with invented or NaN values, and reported
as ``gap`` events with ``lost_samples``; EMCY messages, reboots (boot-up, after
which the node's PDOs are configured again), SDO fallbacks and drive faults are
events too. Without a complete cycle for ``max_outage_s`` the link gives up; a
failing bus or an outage raises :class:`~ncmeasure.errors.LinkError` from
:meth:`~CanOpenLink.read`.

The link is composed of canopen's services, one module each: the settings
(:mod:`.settings`), the TPDO layout (:mod:`.layout`), the SDO/NMT configuration
of a node (:mod:`.configure`), SYNC and the cycle assembler (:mod:`.sync`), and
what is received (:mod:`.receive`: the receiver, the raw log, decoding). This
module keeps open, read and close, and the accounting of the rows and gaps.
"""

from __future__ import annotations

import collections
import functools
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal, cast

import can
import canopen
from canopen.emcy import EmcyError
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError, OutputError
from ncmeasure.links.base import AxisBinding, AxisLinkSettings, DriveLink, LinkSettings
from ncmeasure.links.canopen.bus import open_bus, shut_down
from ncmeasure.links.canopen.busload import BusLoad
from ncmeasure.links.canopen.configure import (
    DriveNode,
    Reconfigurer,
    configure_drives,
    prepare_offline,
)
from ncmeasure.links.canopen.layout import Layout, LinkAxis
from ncmeasure.links.canopen.objects import load_object_map
from ncmeasure.links.canopen.receive import (
    LogReplay,
    RawLog,
    Receiver,
    RowDecoder,
    SdoPoller,
    emcy_event,
)
from ncmeasure.links.canopen.settings import HOST_CLOCK_INTERFACES, CanOpenAxis, CanOpenSettings
from ncmeasure.links.canopen.sync import (
    CycleAssembler,
    ForeignSync,
    LostCycle,
    SyncProducer,
    TimedAssembler,
    no_echo_error,
)
from ncmeasure.samples import Channel, LinkEvent, SampleBlock

__all__ = [
    "CanOpenAxis",
    "CanOpenLink",
    "CanOpenSettings",
]

log = logging.getLogger(__name__)


class CanOpenLink(DriveLink):
    """Reads CiA 402 drives over CANopen: TPDOs on SYNC, SDO for configuration.

    See the module docstring and ``docs/canopen.md``.
    """

    name: ClassVar[str] = "canopen"
    settings_model: ClassVar[type[LinkSettings]] = CanOpenSettings
    axis_settings_model: ClassVar[type[AxisLinkSettings]] = CanOpenAxis

    #: A gap event covers at most this much link time; longer outages give several.
    GAP_REPORT_S: ClassVar[float] = 1.0
    #: The reader is woken when this much link time of rows is ready (real time, PDOs):
    #: rows are handed out in blocks, not one per call. A read's timeout still ends it.
    READ_BLOCK_S: ClassVar[float] = 0.05
    #: How long the link waits for its first own SYNC to come back through the receive stream.
    ECHO_TIMEOUT_S: ClassVar[float] = 5.0
    #: Without own SYNCs in the receive stream: how long (wall clock) an incomplete cycle
    #: waits for late frames (at least 2 SYNC cycles), see :class:`~.sync.TimedAssembler`.
    LATE_WINDOW_S: ClassVar[float] = 0.02
    #: Without own SYNCs: the reader finalises cycles whose SYNC went out this long ago
    #: even when no frame arrives (all drives silent), so their loss is reported.
    QUIET_FINAL_S: ClassVar[float] = 0.5
    #: Lockstep: the longest (wall-clock) wait for the simulated drives to answer one SYNC.
    #: It guards against a simulator that is not there; it plays no part in the simulation.
    STEP_TIMEOUT_S: ClassVar[float] = 60.0
    #: Lockstep: rows the link may hold before the SYNC waits for the reader.
    MAX_READY_ROWS: ClassVar[int] = 20_000

    settings: CanOpenSettings

    def __init__(self, settings: LinkSettings, axes: Sequence[AxisBinding]) -> None:
        super().__init__(settings, axes)
        if not isinstance(settings, CanOpenSettings):
            raise ConfigError("the canopen link needs CanOpenSettings")
        self.settings = settings
        #: SYNC period in whole µs, as written to 0x1006.
        self._period_us = max(1, round(1e6 / settings.sync_hz))
        #: Cycles per second on the link clock: the produced rate, or the other master's.
        self._rate_hz = 1e6 / self._period_us if settings.produces_sync else settings.sync_hz
        self._period = 1.0 / self._rate_hz
        self._layout = Layout(settings, self.axes, load_object_map(settings.object_map))
        self._nodes = [
            DriveNode(axis, self._layout, self._period_us, self._event)
            for axis in self._layout.axes
        ]
        # run-time state
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._bus: can.BusABC | None = None
        self._network: canopen.Network | None = None
        self._threads: list[threading.Thread] = []
        self._cycles = _Cycles(
            self._layout,
            self._period,
            max(1, math.ceil(self.GAP_REPORT_S * self._rate_hz)),
            self._cond,
            self._event,
        )
        self._worker = Reconfigurer(
            self._stop, self._cond, self._cycles.pdo, self._cycles.time, self._event
        )
        self._decoder = RowDecoder(self._layout, self._rate_hz, self._event)
        self._receiver: Receiver | None = None
        self._sync: SyncProducer | None = None
        self._poller: SdoPoller | None = None
        self._t0 = 0.0
        """Clock time of SYNC cycle 0."""
        self._offline = False
        self._foreign_sync = ForeignSync()
        self._failure: LinkError | None = None
        self._streaming = False

    # --- the DriveLink contract ------------------------------------------------------

    @property
    def channels(self) -> tuple[Channel, ...]:
        return self._layout.channels

    @property
    def nominal_period_s(self) -> float:
        return self._period

    def now_s(self) -> float | None:
        """The link time now: the newest SYNC's (lockstep), else the clock since streaming."""
        if not self._streaming:
            return None
        if self.clock.lockstep:
            sent = self._sync.sent_cycle if self._sync is not None else -1
            return max(sent, 0) * self._period
        return self.clock.now() - self._t0

    @property
    def mode(self) -> str:
        """``pdo`` (TPDOs on SYNC) or ``sdo_polling`` (the fallback)."""
        return self._cycles.mode

    def planned_bus_load(self) -> BusLoad:
        """Bus load of the TPDO layout plus SYNC (whoever produces it) at ``sync_hz``."""
        return self._layout.bus_load()

    def statistics(self) -> dict[str, int]:
        """Counters since open: PDO frames, SYNC cycles, rows, lost rows, SDO polls, ...

        ``lost_rows`` counts every cycle without a row; ``lost_no_sync`` those of them
        that had no SYNC on the bus (skipped by the producer, ``sync_skipped``, once
        their next SYNC was seen; or missed polls).
        """
        with self._lock:
            stats = dict(self._cycles.stats)
            stats["pdo_frames"] = self._receiver.pdo_frames if self._receiver else 0
            timed = self._cycles.timed
            stats["early_frames"] = (timed or self._cycles.assembler).early_frames
            if timed is not None:
                stats["stale_frames"] = timed.stale_frames
        return stats

    def describe(self) -> dict[str, Any]:
        info = super().describe()
        info["mode"] = self._cycles.mode
        info.update(self._layout.describe())  # object map, bus load, scales
        return info

    # --- the recorder's ready signal -----------------------------------------------------

    #: CiA 402 digital outputs: sub 1 the physical outputs, sub 2 the bit mask that
    #: enables them (UNSIGNED32 each).
    DIGITAL_OUTPUTS: ClassVar[int] = 0x60FE

    def _ready_drive(self) -> DriveNode | None:
        for drive in self._nodes:
            if drive.axis.settings.ready_output_bit is not None:
                return drive
        return None

    @property
    def signals_ready(self) -> bool:
        """True when an axis names ``ready_output_bit`` (a bit of its drive's 0x60FE:01)."""
        return self._ready_drive() is not None

    def _set_ready(self, on: bool) -> None:
        """Read, change and write back the one bit of 0x60FE:01 (SDO); switching on, also
        the bit of the enable mask 0x60FE:02 where the drive has one."""
        drive = self._ready_drive()
        assert drive is not None  # signals_ready
        bit = drive.axis.settings.ready_output_bit
        assert bit is not None
        mask = 1 << bit
        if on:
            self._enable_output(drive, mask)
        what = f"setting the ready output (0x{self.DIGITAL_OUTPUTS:04X}:01 bit {bit})"
        try:
            old = int.from_bytes(drive.upload(self.DIGITAL_OUTPUTS, 1)[:4], "little")
            new = old | mask if on else old & ~mask
            if new != old:
                drive.download(self.DIGITAL_OUTPUTS, 1, new.to_bytes(4, "little"))
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise drive.failure(what, exc) from exc
        log.info("%s: ready output bit %d %s", drive.axis.who, bit, "on" if on else "off")

    def _enable_output(self, drive: DriveNode, mask: int) -> None:
        """Set the output's bit in the enable mask 0x60FE:02, where the drive has it."""
        try:
            enabled = int.from_bytes(drive.upload(self.DIGITAL_OUTPUTS, 2)[:4], "little")
            if not enabled & mask:
                drive.download(self.DIGITAL_OUTPUTS, 2, (enabled | mask).to_bytes(4, "little"))
        except SdoAbortedError as exc:  # no mask, or a fixed one: the output is the drive's
            log.info("%s: 0x60FE:02 not changed (%s)", drive.axis.who, exc)
        except SdoCommunicationError as exc:
            raise drive.failure("enabling the ready output (0x60FE:02)", exc) from exc

    # --- open ------------------------------------------------------------------------

    def _open(self) -> None:
        if not self.settings.listen_only:  # listening, the controller's layout is what it is
            self._layout.check_load()
        self._cycles.new_assembler()
        self._bus = self._make_bus()
        network = canopen.Network(self._bus)
        network.NOTIFIER_CYCLE = 0.1  # bounds how long close() waits for the receive thread
        self._network = network
        if self.settings.raw_log is not None:
            writer = self._make_logger(self.settings.raw_log)
            raw_log = RawLog(
                writer, self.settings.raw_log, self.clock, self._event, self._cycles.time
            )
            network.listeners.append(cast(Any, raw_log))
        receiver = self._receiver = self._new_receiver(network.listeners[0])
        receiver.host_clock = self.settings.interface in HOST_CLOCK_INTERFACES
        network.listeners[0] = cast(Any, receiver)  # PDOs and own SYNCs first, the rest to canopen
        network.connect()
        self._start_thread(self._worker.run, "canopen-link-worker")
        for drive in self._nodes:
            node = drive.attach(network)
            node.emcy.add_callback(functools.partial(self._on_emcy, drive.axis))
            node.nmt.add_heartbeat_callback(functools.partial(self._on_heartbeat, drive))
        if self.settings.listen_only:
            for drive in self._nodes:
                drive.report_notes()
        else:
            fallback = configure_drives(self._nodes, self._layout, self._cycles.new_assembler)
            if fallback is not None:
                self._cycles.mode = "sdo_polling"
                self._event(fallback)
        pdo = self._cycles.pdo()
        if pdo:
            receiver.pdos = {s.cob_id: (i, s.size) for i, s in enumerate(self._layout.slots)}
            receiver.frame = self._cycles.assembler.frame
        echo = self.settings.echoes_sync
        if pdo and not self.clock.lockstep:
            self._cycles.wake_rows = max(1, round(self.READ_BLOCK_S * self._rate_hz))
        else:  # lockstep and SDO polling wait for every cycle
            self._cycles.wake_rows = 0
        self._t0 = self.clock.now()
        self._streaming = True
        if not pdo:
            poller = self._poller = SdoPoller(self._layout, self._nodes, self.settings)
            poll = functools.partial(
                poller.run, self._stop, self._cond, self._cycles.newest, self._cycles.polled
            )
            self._start_thread(poll, "canopen-link-poll")
        if self.settings.produces_sync:
            self._sync = SyncProducer(
                network,
                self.clock,
                self._period,
                self._stop,
                cond=self._cond,
                cycle_received=self._cycle_received,
                skipped=self._cycles.sync_skipped,
                started=self._started,
                failed=self._fail,
                step_timeout_s=self.STEP_TIMEOUT_S,
                priority=self.settings.sync_priority,
                noted=lambda text: self._event(LinkEvent(self._cycles.time(), "info", text)),
            )
            if echo is False:
                self._use_send_times()
            self._start_thread(self._sync.run, "canopen-link-sync")
            if echo is not False:
                self._await_own_sync(fall_back=echo is None)
        else:
            network.subscribe(0x80, self._on_sync_frame)

    def _new_receiver(self, canopen_listener: can.Listener | None) -> Receiver:
        return Receiver(
            canopen_listener,
            frame=self._cycles.assembler.frame,
            cond=self._cond,
            lockstep=self.clock.lockstep,
            own_sync=self._on_own_sync,
            bad_frame=self._cycles.bad_frame,
            failed=self._fail,
        )

    def _await_own_sync(self, fall_back: bool) -> None:
        """The first own SYNC should come back through the receive stream (bus order).

        If it does not within ``ECHO_TIMEOUT_S``: with ``fall_back`` the link gives PDOs to
        their SYNC by send and receive times from then on (an ``info`` event); else (the
        machine file says the interface returns them) it is a LinkError.
        """
        with self._cond:
            seen = self._cond.wait_for(
                lambda: self._cycles.cycle >= 0 or self._failure is not None,
                self.ECHO_TIMEOUT_S,
            )
        self._check_failure()
        if seen:
            return
        if not fall_back:
            raise no_echo_error(self.settings.interface)
        self._use_send_times()
        interface = self.settings.interface or "(python-can config)"
        self._event(
            LinkEvent(
                0.0,
                "info",
                f"the CAN interface {interface} does not return the link's own SYNC frames "
                "(python-can receive_own_messages); PDOs go to their SYNC cycle by the SYNC "
                "send times and the frames' receive times (set link.sync_echo = false to "
                "skip this wait)",
            )
        )

    def _use_send_times(self) -> None:
        """No own SYNC in the receive stream: assign PDOs by SYNC send and receive times."""
        sync, receiver = self._sync, self._receiver
        assert sync is not None and receiver is not None
        hold = max(2, math.ceil(self.LATE_WINDOW_S * self._rate_hz))
        with self._cond:
            sync.sent.clear()
            self._cycles.use_send_times(sync.send_times, hold)
            receiver.timed = self._cycles.timed_frame if self._cycles.pdo() else None
            sync.timed = True  # the send times are kept from the next SYNC on

    def _start_thread(self, target: Callable[[], None], name: str) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    def _make_bus(self) -> can.BusABC:
        s = self.settings
        kwargs = s.bus_kwargs()
        if s.echoes_sync is not False and (s.produces_sync or s.raw_log is not None):
            # Own SYNCs come back in bus order among the PDOs (and the log shows them).
            kwargs["receive_own_messages"] = True
        return open_bus(s.channel, kwargs, "link.interface")

    @staticmethod
    def _make_logger(path: Path) -> can.Listener:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            return cast(can.Listener, can.Logger(str(path)))
        except (OSError, ValueError) as exc:
            raise OutputError(f"{path}: cannot write the raw CAN log ({exc})") from exc

    # --- callbacks (notifier thread) ---------------------------------------------------

    def _on_emcy(self, axis: LinkAxis, entry: EmcyError) -> None:
        self._event(emcy_event(axis, entry, self._cycles.time()))

    def _on_heartbeat(self, drive: DriveNode, state: int) -> None:
        if state == 0 and self._streaming:
            configure = not (self.settings.listen_only or self._offline)
            self._worker.rebooted(drive, configure)

    def _on_sync_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """SYNC of another master: count cycles, notice missing ones by their timestamps."""
        wall_period = self.clock.wall(self._period)  # frame timestamps are wall-clock
        with self._cond:
            step = self._foreign_sync.step(timestamp, wall_period)
            self._cycles.advance(self._cycles.cycle + step)

    def _on_own_sync(self) -> None:
        """An own SYNC came back through the receive stream: its cycle starts now, in bus order."""
        with self._lock:  # the condition's lock
            cycle = self._sync.seen() if self._sync is not None else None
            if cycle is not None:
                self._cycles.advance(cycle)

    # --- SYNC producer (own thread) ------------------------------------------------------

    def _started(self, t0: float) -> None:
        self._t0 = t0

    def _cycle_received(self, cycle: int, sent: int) -> bool:
        """Lockstep: everything of ``cycle`` is in, and the next SYNC may go out."""
        if self._stop.is_set() or self._failure is not None:
            return True
        received = self._receiver.received if self._receiver is not None else 0
        polled = self._poller.polled_cycle if self._poller is not None else -1
        return (
            received >= sent
            and self._worker.pending == 0
            and self._cycles.complete(cycle, polled, self.MAX_READY_ROWS)
        )

    def _fail(self, error: LinkError) -> None:
        with self._cond:
            if self._failure is None:
                self._failure = error
            self._cond.notify_all()

    # --- offline: a CAN log ----------------------------------------------------------------

    def decode_frames(
        self, messages: Iterable[can.Message], block_rows: int = 20_000
    ) -> Iterator[tuple[SampleBlock, list[LinkEvent]]]:
        """Decode a CAN log the way this link reads the bus, without a bus: rows and events.

        Every SYNC in the log starts a cycle (missing ones are told by the frames' time
        stamps, as for the SYNC of another master); every PDO frame belongs to the SYNC
        before it. The TPDO layout is the one this link reads: the controller's (DCF or
        tpdo tables) when it only listens, else the layout it configures itself, on the
        predefined COB-IDs. Nothing is sent and no drive is asked, so the rated current
        comes from the machine file or the DCF.

        Yields:
            Blocks of at most ``block_rows`` rows, each with the events since the last.

        Raises:
            LinkError: the link is open.
            ConfigError: the rated current or a COB-ID cannot be known without SDO.
        """
        if self._state != "new":
            raise LinkError("decode_frames needs a canopen link that was never opened")
        prepare_offline(self._layout, self._nodes)
        self._cycles.new_assembler()
        self._offline = True
        self._streaming = True
        self._receiver = self._new_receiver(None)
        replay = LogReplay(
            self._receiver,
            self._layout,
            self._nodes,
            sync=self._on_sync_frame,
            emcy=self._on_emcy,
            boot=self._on_heartbeat,
        )
        for msg in messages:
            replay.feed(msg)
            if len(self._cycles.ready) >= block_rows:
                yield self._take_block(), self.events()
        with self._cond:
            self._cycles.settle()
            self._cycles.close_gap()
        yield self._take_block(), self.events()

    def _take_block(self) -> SampleBlock:
        with self._cond:
            rows = self._cycles.take()
        return self._decoder.decode(rows) if rows else self.empty_block()

    # --- read -------------------------------------------------------------------------

    def _read(self, timeout_s: float) -> SampleBlock | None:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                self._check_failure()
                if self._cycles.timed is not None:
                    self._cycles.timed_reach(time.time() - self.QUIET_FINAL_S)
                self._check_outage()
                if self._cycles.ready:
                    rows = self._cycles.take()
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return self.empty_block()
                self._cond.wait(min(remaining, 0.05))
        return self._decoder.decode(rows)

    def _check_outage(self) -> None:
        """Give up after ``max_outage_s`` of link time without a complete cycle (lock held)."""
        now = self.now_s()
        if now is None:
            return
        limit = self.settings.max_outage_s
        why = self._cycles.outage(now, limit)
        if why is None:
            return
        message = f"the canopen link gave up after {limit:g} s without a complete SYNC cycle{why}"
        self._event(LinkEvent(now, "fault", message))
        self._failure = LinkTimeoutError(message)
        raise self._failure

    def _check_failure(self) -> None:
        if self._failure is not None:
            raise self._failure
        network = self._network
        notifier = network.notifier if network is not None else None
        if notifier is not None and notifier.exception is not None:
            self._failure = LinkError(f"CAN bus error: {notifier.exception}")
            raise self._failure

    # --- close --------------------------------------------------------------------------

    def _close(self) -> None:
        self._stop.set()
        self._worker.close()
        with self._cond:
            self._cond.notify_all()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self._threads = []
        network = self._network
        if network is not None and network.bus is not None:
            for drive in self._nodes:
                try:
                    drive.nmt("PRE-OPERATIONAL")
                except Exception as exc:  # closing never raises
                    log.info("%s: NMT pre-operational not sent (%s)", drive.axis.who, exc)
        with self._cond:
            self._cycles.finish()
        shut_down(network, self._bus)
        self._network = None
        self._bus = None


@dataclass
class _GapRun:
    first: int
    last: int
    count: int = 0
    no_sync: int = 0
    doubled: int = 0
    axes: set[int] = field(default_factory=set)
    doubled_slots: set[int] = field(default_factory=set)
    reason: str = ""


class _Cycles:
    """The SYNC cycles seen on the bus: the rows ready for the reader, the lost ones as gaps.

    A SYNC seen on the bus finishes the cycle before it in the assembler; its
    complete cycles become rows, its incomplete ones are lost. Consecutive lost
    cycles of one reason make one ``gap`` event, of at most ``report_cycles``; a
    row ends a gap. The link's lock guards it: the methods are called with the lock
    held, but :meth:`bad_frame` and :meth:`sync_skipped` (they take it) and
    :meth:`pdo` and :meth:`time` (they read one value).

    Args:
        layout: The link's layout (which slot is whose).
        period_s: The SYNC period on the link clock.
        report_cycles: The most cycles one gap event covers.
        cond: The link's condition: notified when the reader has rows to take.
        event: Where the events go (the link's).
    """

    def __init__(
        self,
        layout: Layout,
        period_s: float,
        report_cycles: int,
        cond: threading.Condition,
        event: Callable[[LinkEvent], None],
    ) -> None:
        self._layout = layout
        self._period = period_s
        self._report_cycles = report_cycles
        self._produces_sync = layout.settings.produces_sync
        self._cond = cond
        self._event = event
        self.stats = {
            "sync_cycles": 0,
            "rows": 0,
            "lost_rows": 0,
            "lost_no_sync": 0,
            "bad_frames": 0,
            "sdo_polls": 0,
            "sync_skipped": 0,
        }
        """The link's counters (:meth:`CanOpenLink.statistics`)."""
        self._bad_slots: set[int] = set()
        self.mode: Literal["pdo", "sdo_polling"] = "pdo"
        self.assembler = CycleAssembler(1)
        self.timed: TimedAssembler | None = None
        """The assembler by send times, where no own SYNC comes back (else None)."""
        self._send_times: collections.deque[tuple[int, float]] | None = None
        self._hold_cycles = 2
        self.new_assembler()
        self.cycle = -1
        """The newest SYNC cycle seen on the bus (own SYNCs through the receive stream)."""
        self.wake_rows = 1
        """The reader is woken when this many rows are ready (set at open)."""
        self.ready: list[tuple[int, list[bytes]]] = []
        self.last_row = -1
        """The cycle of the newest row."""
        self.gap: _GapRun | None = None

    def new_assembler(self) -> None:
        """An assembler for the current slots; a node's slots keep their order."""
        slots = self._layout.slots
        groups = [slot.axis.position for slot in slots] or [0]
        self.assembler = CycleAssembler(max(1, len(slots)), groups)
        if self._send_times is not None:
            self.timed = TimedAssembler(
                max(1, len(slots)), groups, self._send_times, self._hold_cycles
            )

    def use_send_times(self, send_times: collections.deque[tuple[int, float]], hold: int) -> None:
        """From now on, assign PDOs by the producer's SYNC send times (no own SYNC returns)."""
        self._send_times = send_times
        self._hold_cycles = hold
        self.new_assembler()

    def timed_frame(self, slot: int, data: bytes, received_s: float) -> None:
        """A PDO frame and its receive time (receive thread; takes the lock)."""
        with self._cond:
            timed = self.timed
            if timed is None:
                return
            timed.frame(slot, data, received_s)
            self._timed_advance(timed)

    def timed_reach(self, now_s: float) -> None:
        """The host time ``now_s`` is reached without frames (lock held)."""
        timed = self.timed
        if timed is not None and self.mode == "pdo":
            timed.reach(now_s)
            self._timed_advance(timed)

    def _timed_advance(self, timed: TimedAssembler) -> None:
        newest = timed.newest
        if newest <= self.cycle:
            self.settle()
            if len(self.ready) >= max(1, self.wake_rows):
                self._cond.notify_all()
            return
        first = self.cycle < 0
        self.stats["sync_cycles"] = timed.syncs
        self.cycle = newest
        self.settle()
        if first or len(self.ready) >= self.wake_rows:
            self._cond.notify_all()

    def pdo(self) -> bool:
        """True while the rows come from TPDOs (not SDO polling)."""
        return self.mode == "pdo"

    def complete(self, cycle: int, polled: int, max_ready: int) -> bool:
        """Lockstep: ``cycle`` was seen (and polled), and the reader keeps up."""
        return (
            (self.cycle >= cycle or self.timed is not None)
            and (self.mode == "pdo" or polled >= cycle)
            and len(self.ready) < max_ready
        )

    def newest(self) -> int:
        """The newest SYNC cycle (lock held); SDO polling without own SYNCs: the newest sent."""
        send_times = self._send_times
        if send_times is not None and self.mode != "pdo":
            while send_times:
                self.advance(send_times.popleft()[0])
        return self.cycle

    def time(self) -> float:
        """The link time of the newest SYNC cycle."""
        return max(self.cycle, 0) * self._period

    def advance(self, cycle: int) -> None:
        """SYNC cycle ``cycle`` was seen on the bus."""
        skipped = cycle - self.cycle - 1
        if self.mode == "pdo":
            self.assembler.sync(cycle)
        elif skipped > 0 and self.cycle >= 0:
            self.lost_polls(self.cycle + 1, skipped, "")
        first = self.cycle < 0
        self.cycle = cycle
        self.stats["sync_cycles"] += 1
        self.settle()
        # The reader wakes per block of rows; lockstep and SDO polling wait for every cycle.
        if first or len(self.ready) >= self.wake_rows:
            self._cond.notify_all()

    def take(self) -> list[tuple[int, list[bytes]]]:
        """The rows ready, in cycle order, for the reader."""
        rows, self.ready = self.ready, []
        self.stats["rows"] += len(rows)
        return rows

    def polled(self, cycle: int, row: list[bytes] | None, reason: str) -> None:
        """SDO polling: the row of ``cycle``, or None and why the poll failed."""
        if row is None:
            self.lost_polls(cycle, 1, reason)
            return
        self.stats["sdo_polls"] += 1
        self.ready.append((cycle, row))
        self.last_row = cycle
        self.close_gap()

    def sync_skipped(self, first: int, count: int) -> None:
        """The producer skipped ``count`` cycles from ``first``; they become a gap (no_sync)."""
        with self._cond:
            self.stats["sync_skipped"] += count

    def settle(self) -> None:
        """Move final rows to the ready list, account lost cycles."""
        if self.mode != "pdo":
            return
        rows, lost = (self.timed or self.assembler).take()
        if not lost:  # the usual case: complete cycles only
            if rows:
                if self.gap is not None:
                    self.close_gap()
                self.ready.extend(rows)
                self.last_row = rows[-1][0]
            return
        events: list[tuple[int, list[bytes]] | LostCycle] = [*rows, *lost]
        events.sort(key=lambda item: item.cycle if isinstance(item, LostCycle) else item[0])
        for item in events:
            if isinstance(item, LostCycle):
                self.lose(item, "")
            else:
                self.close_gap()
                self.ready.append(item)
                self.last_row = item[0]

    def lose(self, lost: LostCycle, reason: str) -> None:
        gap = self.gap
        if gap is not None and (
            lost.cycle != gap.last + 1
            or gap.last - gap.first + 1 >= self._report_cycles
            or gap.reason != reason
        ):
            self.close_gap()
            gap = None
        if gap is None:
            gap = self.gap = _GapRun(first=lost.cycle, last=lost.cycle, reason=reason)
        gap.last = lost.cycle
        gap.count += 1
        slots = self._layout.slots
        axes = {slots[i].axis.position for i in lost.missing if i < len(slots)}
        if lost.reason == "no_sync":
            gap.no_sync += 1
            self.stats["lost_no_sync"] += 1
        elif lost.reason == "doubled":
            gap.doubled += 1
            gap.doubled_slots |= set(lost.missing)
        else:
            gap.axes |= axes
        self.stats["lost_rows"] += 1

    def bad_frame(self, index: int, length: int) -> None:
        """A frame of slot ``index`` too short for its mapping: dropped, reported once."""
        with self._cond:
            slot = self._layout.slots[index]
            self.stats["bad_frames"] += 1
            if index in self._bad_slots:
                return
            self._bad_slots.add(index)
            self._event(
                LinkEvent(
                    self.time(),
                    "fault",
                    f"{slot.axis.who}: TPDO{slot.number} (0x{slot.cob_id:03X}) carries "
                    f"{length} bytes, the mapping needs {slot.size}; such frames are dropped",
                    axis=slot.axis.name,
                )
            )

    def finish(self) -> None:
        """The link closes: the last rows final, the last gap reported."""
        try:
            self.settle()
        except Exception:
            log.exception("canopen link: settling at close failed")
        self.close_gap()

    def lost_polls(self, first: int, count: int, reason: str) -> None:
        everything = frozenset(range(len(self._layout.slots)))
        for cycle in range(first, first + count):
            self.lose(LostCycle(cycle, everything, "no_sync" if not reason else "missing"), reason)

    def outage(self, now: float, limit: float) -> str | None:
        """After ``limit`` s of link time without a row: why (the gap closed); else None."""
        since = max(self.last_row, 0) * self._period
        if now - since < limit:
            return None
        gap = self.gap
        why = ""
        if gap is not None and gap.axes:
            names = ", ".join(self._layout.axes[i].name for i in sorted(gap.axes))
            why = f": no PDOs from axis {names}"
        elif self.cycle < 0 or self.cycle * self._period < since + limit / 2:
            why = ": no SYNC seen on the bus"
        self.close_gap()
        return why

    def close_gap(self) -> None:
        gap, self.gap = self.gap, None
        if gap is None:
            return
        axes = [self._layout.axes[i] for i in sorted(gap.axes)]
        reasons = []
        if gap.reason:
            reasons.append(gap.reason)
        if axes:
            names = ", ".join(a.name for a in axes)
            nodes = ", ".join(str(a.node_id) for a in axes)
            plural = "s" if len(axes) > 1 else ""
            reasons.append(
                f"no PDOs from axis{'es' if plural else ''} {names} (node{plural} {nodes})"
            )
        if gap.doubled:
            slots = [self._layout.slots[i] for i in sorted(gap.doubled_slots)]
            late = ", ".join(f"{slot.axis.who} TPDO{slot.number}" for slot in slots)
            if self.timed is not None:
                reasons.append(
                    f"{gap.doubled} cycles whose frames cannot be told apart ({late} came "
                    "twice, or after the next SYNC was sent, or was missing beside one that "
                    "did: the interface returns no own SYNC to order them)"
                )
            else:
                reasons.append(
                    f"{gap.doubled} cycles with two frames of one TPDO ({late}: a drive "
                    "answered a cycle late), so their cycles cannot be told apart"
                )
        if gap.no_sync and self._produces_sync:
            reasons.append(f"{gap.no_sync} SYNC cycles not sent (the host fell behind)")
        elif gap.no_sync:
            reasons.append(f"{gap.no_sync} SYNC cycles missing on the bus")
        t0, t1 = gap.first * self._period, gap.last * self._period
        self._event(
            LinkEvent(
                t0,
                "gap",
                f"{gap.count} samples dropped between {t0:.3f} s and {t1:.3f} s: "
                f"{'; '.join(reasons)}",
                axis=axes[0].name if len(axes) == 1 else None,
                lost_samples=gap.count,
                details={
                    "first_cycle": gap.first,
                    "last_cycle": gap.last,
                    "axes": [a.name for a in axes],
                    "nodes": [a.node_id for a in axes],
                    "missing_sync": gap.no_sync,
                    "skipped_cycles": gap.no_sync if self._produces_sync else 0,
                    "doubled": gap.doubled,
                },
            )
        )
