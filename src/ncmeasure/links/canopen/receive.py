"""What the CANopen link receives: the receive stream, the raw log, and rows decoded.

- :class:`Receiver`, the first listener of the receive thread: PDO frames
  straight into the cycle assembler (a dict from COB-ID to slot, not
  canopen's PDO objects, so no frame is lost to a PDO map holding only its
  last frame), own SYNCs to the link in bus order, the rest to canopen;
- :class:`RawLog`, every frame into a log file (BLF, ASC, ...), which never
  stops the measurement;
- :class:`RowDecoder`: the bytes of a block of rows decoded in bulk (one
  structured numpy view) and scaled to A, mm/min and mm; a statusword with its
  fault bit becomes an event;
- :class:`SdoPoller`: the fallback, a row read object by object over SDO once
  per SYNC cycle;
- :func:`emcy_event`: an EMCY message as the link reports it;
- :class:`LogReplay`: the frames of a CAN log, fed as the receive thread would.
"""

from __future__ import annotations

import copy
import functools
import logging
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import can
import numpy as np
from canopen.emcy import EmcyError
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from numpy.typing import NDArray

from ncmeasure.errors import LinkError
from ncmeasure.links.canopen.configure import DriveNode, fit
from ncmeasure.links.canopen.layout import STATUS_COLUMN, Layout, LinkAxis, SlotField
from ncmeasure.links.canopen.objects import emcy_text, sdo_error_text
from ncmeasure.links.canopen.settings import CanOpenSettings
from ncmeasure.samples import LinkClock, LinkEvent, SampleBlock

__all__ = [
    "LogReplay",
    "RawLog",
    "Receiver",
    "RowDecoder",
    "SdoPoller",
    "emcy_event",
    "log_channel",
]

log = logging.getLogger(__name__)

_STATUS_FAULT = 0x0008


class Receiver(can.Listener):
    """The first listener of the receive thread: PDOs and own SYNCs here, the rest to canopen.

    PDO frames go straight to the link's cycle assembler (a dict from COB-ID to
    slot, no canopen PDO machinery per frame); an own SYNC starts its cycle
    exactly between the PDOs received before and after it (bus order). Every
    other frame (SDO, EMCY, heartbeat, another master's SYNC) goes on to
    canopen's own listener. Frames of others are counted (lockstep: all the
    simulated drives sent must be in), and a failing bus becomes a LinkError
    for read().

    Args:
        canopen_listener: canopen's own listener (None: a CAN log, no bus).
        frame: The assembler's frame method.
        cond: The link's condition, notified per frame counted (lockstep).
        lockstep: Count the frames of others (the link runs on a simulated clock).
        own_sync: Called when an own SYNC comes back.
        bad_frame: Called with a slot and the length of a frame too short for it.
        failed: Called with the error of a failing bus.
    """

    def __init__(
        self,
        canopen_listener: can.Listener | None,
        *,
        frame: Callable[[int, bytes], None],
        cond: threading.Condition,
        lockstep: bool,
        own_sync: Callable[[], None],
        bad_frame: Callable[[int, int], None],
        failed: Callable[[LinkError], None],
    ) -> None:
        self._canopen = canopen_listener
        self._cond = cond
        self._lockstep = lockstep  # the clock cannot change while the link is open
        self._own_sync = own_sync
        self._bad_frame = bad_frame
        self._failed = failed
        self.pdos: dict[int, tuple[int, int]] = {}
        """COB-ID -> (slot index, mapped bytes); set once the TPDOs are configured."""
        self.frame = frame
        """The assembler's frame method (set with :attr:`pdos`)."""
        self.pdo_frames = 0
        """PDO frames received (only the receive thread writes it)."""
        self.received = 0
        """Frames of others received (lockstep: all the simulated drives sent must be here)."""
        self.timed: Callable[[int, bytes, float], None] | None = None
        """Set where the interface returns no own SYNC: PDO frames go here with their
        receive time on the host's wall clock (the link assigns them by SYNC send times)."""
        self.host_clock = False
        """The interface stamps frames with the host's wall clock (else: stamped on arrival)."""

    def on_message_received(self, msg: can.Message) -> None:
        # This runs for 9000 PDOs a second and more: the usual frame is handled inline.
        if msg.is_rx:
            slot = self.pdos.get(msg.arbitration_id)
            if slot is not None and not (
                msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame
            ):
                data = msg.data
                if self.timed is not None:
                    self._timed_pdo(slot[0], slot[1], data, msg.timestamp)
                elif len(data) == slot[1]:
                    self.pdo_frames += 1  # only this thread writes it
                    self.frame(slot[0], bytes(data))
                else:
                    self.pdo(slot[0], slot[1], data)
            elif self.timed is not None and msg.arbitration_id == 0x80:
                return  # the own SYNC, looped back as received (udp_multicast): not a frame
            else:
                assert self._canopen is not None
                self._canopen.on_message_received(msg)
            if self._lockstep:  # all the simulated drives sent must be in before the next SYNC
                with self._cond:
                    self.received += 1
                    self._cond.notify_all()
            return
        if msg.arbitration_id == 0x80 and not msg.is_extended_id:
            self._own_sync()  # nothing of canopen's listens to the master's own SYNC
            return
        assert self._canopen is not None
        self._canopen.on_message_received(msg)

    def pdo(self, index: int, size: int, data: bytearray) -> None:
        """A PDO frame of slot ``index``, in bus order (receive thread only, no lock).

        The frame's bytes are kept as they are and decoded in bulk, a block at a time
        (:class:`RowDecoder`). Frames go into the assembler without the lock: only the
        thread that receives the bus feeds it; rows leave it under the lock when a SYNC
        finishes a cycle.
        """
        self.pdo_frames += 1  # only this thread writes it
        if len(data) < size:
            self._bad_frame(index, len(data))
            return
        self.frame(index, bytes(data) if len(data) == size else bytes(data[:size]))

    def _timed_pdo(self, index: int, size: int, data: bytearray, timestamp: float) -> None:
        """A PDO frame without own SYNCs in the stream: its slot, bytes and receive time.

        The receive time is python-can's time stamp where the interface stamps on the
        host's wall clock (never later than now), else the time it is handled here:
        never earlier than the frame really arrived, so never before its SYNC was sent.
        """
        now = time.time()
        received = min(timestamp, now) if self.host_clock and timestamp > 0 else now
        self.pdo_frames += 1  # only this thread writes it
        if len(data) < size:
            self._bad_frame(index, len(data))
            return
        timed = self.timed
        assert timed is not None
        timed(index, bytes(data) if len(data) == size else bytes(data[:size]), received)

    def on_error(self, exc: Exception) -> None:
        self._failed(LinkError(f"CAN bus error: {exc}"))

    def stop(self) -> None:
        if self._canopen is not None:
            self._canopen.stop()


def log_channel(channel: Any) -> Any:
    """The channel as the log writers can store it: one bus, so a number only if it fits.

    python-can's writers number a channel by the last digits of its name (``can0`` is
    channel 0), and BLF keeps a 16-bit number: a name such as ``bus-90770`` would fail
    every frame. Such a channel is logged as the writer's default channel.
    """
    number = can.util.channel2int(channel)
    if number is None or 0 <= number < 0xFFFF:
        return channel
    return None


class RawLog(can.Listener):
    """The raw frame log; a writer that fails stops logging, never the measurement.

    In lockstep the frames are stamped with the simulated time (from the wall-clock
    time the log started): the log is of the simulated bus, in the machine's time, so
    that a SYNC every period shows as one, as on a real bus.

    Args:
        writer: python-can's writer of the file.
        path: The file.
        clock: The link clock.
        event: Where a failing writer is reported (the link's events).
        cycle_time: The link time now, for that event.
    """

    def __init__(
        self,
        writer: can.Listener,
        path: Path,
        clock: LinkClock,
        event: Callable[[LinkEvent], None],
        cycle_time: Callable[[], float],
    ) -> None:
        self._writer = writer
        self._path = path
        self._clock = clock
        self._event = event
        self._cycle_time = cycle_time
        self._failed = False
        self._epoch = time.time()

    def on_message_received(self, msg: can.Message) -> None:
        if self._failed:
            return
        clock = self._clock
        msg = copy.copy(msg)
        msg.channel = log_channel(msg.channel)
        if clock.lockstep:
            msg.timestamp = self._epoch + clock.now()
        try:
            self._writer.on_message_received(msg)
        except Exception as exc:  # python-can writers raise struct.error, OSError, ...
            self._failed = True
            self._event(
                LinkEvent(
                    self._cycle_time(),
                    "fault",
                    f"the raw CAN log {self._path} stopped ({type(exc).__name__}: {exc}); "
                    "the measurement goes on",
                )
            )

    def stop(self) -> None:
        try:
            self._writer.stop()
        except Exception as exc:  # a full disk fails the last write too; the bus still closes
            if not self._failed:
                log.warning(
                    "the raw CAN log %s was not completed (%s: %s)",
                    self._path,
                    type(exc).__name__,
                    exc,
                )


class RowDecoder:
    """Rows of slot bytes -> a :class:`~ncmeasure.samples.SampleBlock` in A, mm/min, mm.

    Args:
        layout: The link's layout (its slots may be packed anew while configuring).
        rate_hz: SYNC cycles per second on the link clock: ``time_s`` = cycle / rate.
        event: Where drive faults (statusword) are reported.
    """

    def __init__(self, layout: Layout, rate_hz: float, event: Callable[[LinkEvent], None]) -> None:
        self._layout = layout
        self._rate_hz = rate_hz
        self._event = event
        self._plan: (
            tuple[list[Any], np.dtype[Any], list[tuple[str, LinkAxis, SlotField]]] | None
        ) = None

    def decode(self, rows: list[tuple[int, list[bytes]]]) -> SampleBlock:
        n = len(rows)
        cycles = np.fromiter((c for c, _ in rows), dtype=np.float64, count=n)
        time_s = cycles / self._rate_hz
        values = np.empty((n, len(self._layout.channels)), dtype=np.float64)
        row_dtype, fields = self._decode_plan()
        # One buffer and one structured view for the whole block: a row is its slots' bytes.
        block = np.frombuffer(b"".join([b"".join(r) for _, r in rows]), dtype=row_dtype)
        for name, axis, f in fields:
            if f.column >= 0 and f.bit is not None:  # the marker: one digital input
                values[:, f.column] = (block[name] >> f.bit) & 1
            elif f.column >= 0:
                np.multiply(block[name], axis.scales[f.role], out=values[:, f.column])
            else:
                self._check_status(axis, block[name], time_s)
        return SampleBlock(time_s, values)

    def _decode_plan(self) -> tuple[np.dtype[Any], list[tuple[str, LinkAxis, SlotField]]]:
        """The dtype of a row (all slots' bytes in order) and the fields to take from it."""
        slots = self._layout.slots
        if self._plan is not None and self._plan[0] is slots:
            return self._plan[1], self._plan[2]
        names: list[str] = []
        formats: list[str] = []
        offsets: list[int] = []
        fields: list[tuple[str, LinkAxis, SlotField]] = []
        offset = 0
        for index, slot in enumerate(slots):
            for k, f in enumerate(slot.fields):
                name = f"s{index}f{k}"
                names.append(name)
                formats.append(f.np_type)
                offsets.append(offset)
                offset += f.size
                if f.column >= 0 or f.column == STATUS_COLUMN:
                    fields.append((name, slot.axis, f))
        row_dtype: np.dtype[Any] = np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": offset}
        )
        self._plan = (slots, row_dtype, fields)
        return row_dtype, fields

    def _check_status(
        self, axis: LinkAxis, statusword: NDArray[Any], time_s: NDArray[np.float64]
    ) -> None:
        fault = (statusword & _STATUS_FAULT) != 0
        if not axis.faulted and not fault.any():  # the usual block: nothing to report
            return
        flags = np.concatenate(([axis.faulted], fault)).astype(np.int8)
        changes = np.flatnonzero(np.diff(flags))
        for i in changes:
            axis.faulted = bool(fault[i])
            word = int(statusword[i])
            if axis.faulted:
                self._event(
                    LinkEvent(
                        float(time_s[i]),
                        "fault",
                        f"{axis.who} reports a fault (statusword 0x{word:04X})",
                        axis=axis.name,
                        details={"statusword": word},
                    )
                )
            else:
                self._event(
                    LinkEvent(
                        float(time_s[i]),
                        "info",
                        f"{axis.who}: fault cleared (statusword 0x{word:04X})",
                        axis=axis.name,
                        details={"statusword": word},
                    )
                )


class SdoPoller:
    """The fallback: every slot's objects read over SDO, once per SYNC cycle at most.

    Args:
        layout: The link's layout: the slots, as their TPDOs would carry them.
        nodes: The drives, to ask.
        settings: The link's settings (SDO time-out, for the failure's text).
    """

    def __init__(
        self, layout: Layout, nodes: Sequence[DriveNode], settings: CanOpenSettings
    ) -> None:
        self._layout = layout
        self._nodes = {node.axis.node_id: node for node in nodes}
        self._settings = settings
        self.polled_cycle = -1
        """The newest cycle polled (a row, or a failed poll)."""

    def run(
        self,
        stop: threading.Event,
        cond: threading.Condition,
        cycle: Callable[[], int],
        polled: Callable[[int, list[bytes] | None, str], None],
    ) -> None:
        """Poll on every new SYNC cycle until ``stop`` is set (the link's poll thread).

        Args:
            stop: Set when the link closes.
            cond: The link's condition: notified when a cycle begins; ``polled`` is
                called with it held, and it is notified after.
            cycle: The newest SYNC cycle (``cond`` held).
            polled: Called with the cycle and its row, or None and why it failed.
        """
        last = -1
        while not stop.is_set():
            with cond:
                cond.wait_for(functools.partial(_new_cycle, cycle, last, stop), 0.2)
                now = cycle()
            if stop.is_set():
                return
            if now == last or now < 0:
                continue
            last = now
            try:
                row: list[bytes] | None = self.row()
                reason = ""
            except (SdoAbortedError, SdoCommunicationError) as exc:
                row = None
                reason = f"SDO polling failed: {sdo_error_text(exc, self._settings.sdo_timeout_s)}"
            with cond:
                polled(now, row, reason)
                self.polled_cycle = now
                cond.notify_all()

    def row(self) -> list[bytes]:
        """One row: the slots' bytes as their TPDOs would carry them.

        Raises:
            SdoAbortedError, SdoCommunicationError: A drive did not answer as asked.
        """
        return [
            b"".join(self._field(self._nodes[slot.axis.node_id], f) for f in slot.fields)
            for slot in self._layout.slots
        ]

    @staticmethod
    def _field(node: DriveNode, f: SlotField) -> bytes:
        if f.obj is None:
            return bytes(f.unread_bytes)
        return fit(node.upload(f.obj.index, f.obj.subindex), f.obj)


def _new_cycle(cycle: Callable[[], int], last: int, stop: threading.Event) -> bool:
    return cycle() != last or stop.is_set()


def emcy_event(axis: LinkAxis, entry: EmcyError, time_s: float) -> LinkEvent:
    """An EMCY message of the axis' drive as the link reports it."""
    data = bytes(entry.data).rstrip(b"\0")
    extra = f", data {data.hex(' ')}" if data else ""
    meaning = emcy_text(entry.code)
    return LinkEvent(
        time_s,
        "emcy",
        f"EMCY from {axis.who}: 0x{entry.code:04X} {meaning} (error register "
        f"0x{entry.register:02X}{extra})",
        axis=axis.name,
        details={
            "code": entry.code,
            "meaning": meaning,
            "register": entry.register,
            "data": bytes(entry.data).hex(),
        },
    )


class LogReplay:
    """The frames of a CAN log, fed to the link as its receive thread would, without a bus.

    Every SYNC goes to ``sync`` with its time stamp (the cycles of another master);
    the PDOs of the layout's slots to the receiver; EMCY and boot-up messages of the
    axes' nodes to ``emcy`` and ``boot``. Error, remote and extended frames are skipped.

    Args:
        receiver: The link's receiver (its assembler).
        layout: The link's layout: the slots and their COB-IDs.
        nodes: The axes' drives.
        sync: Called with the COB-ID, data and time stamp of a SYNC.
        emcy: Called with the axis and the EMCY of its drive.
        boot: Called with the drive and 0 (its boot-up message).
    """

    def __init__(
        self,
        receiver: Receiver,
        layout: Layout,
        nodes: Sequence[DriveNode],
        *,
        sync: Callable[[int, bytearray, float], None],
        emcy: Callable[[LinkAxis, EmcyError], None],
        boot: Callable[[DriveNode, int], None],
    ) -> None:
        self._receiver = receiver
        self._handlers = {slot.cob_id: (i, slot.size) for i, slot in enumerate(layout.slots)}
        self._nodes = {node.axis.node_id: node for node in nodes}
        self._sync = sync
        self._emcy = emcy
        self._boot = boot

    def feed(self, msg: can.Message) -> None:
        """One frame of the log."""
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        can_id, data, nodes = msg.arbitration_id, msg.data, self._nodes
        if can_id == 0x80:
            self._sync(can_id, data, msg.timestamp)
        elif can_id in self._handlers:
            self._receiver.pdo(*self._handlers[can_id], data)
        elif 0x81 <= can_id <= 0xFF and can_id - 0x80 in nodes and len(data) >= 3:
            code, register = int.from_bytes(data[:2], "little"), data[2]
            entry = EmcyError(code, register, bytes(data[3:8]), msg.timestamp)
            self._emcy(nodes[can_id - 0x80].axis, entry)
        elif 0x701 <= can_id <= 0x77F and can_id - 0x700 in nodes and data[:1] == b"\0":
            self._boot(nodes[can_id - 0x700], 0)
