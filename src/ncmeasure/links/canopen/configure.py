"""SDO and NMT configuration of one drive by the CANopen link (the master's part).

:class:`DriveNode` is one axis' drive as a CANopen node: its SDO client (one
transfer at a time), its NMT state, and the steps the link takes with it:

1. :meth:`~DriveNode.prepare`: pre-operational; every object read once over SDO
   (the drive proves it has it; a missing object falls back to the map's
   fallback, e.g. torque 0x6077); the slots packed again; the rated current
   read from 0x6075 when the machine file does not give it; the SYNC period
   written to 0x1006;
2. :meth:`~DriveNode.map_tpdos`: the TPDOs written in CiA 301 order (disable,
   transmission type 1 = on every SYNC, mapping, enable); a drive that aborts
   makes the link fall back to SDO polling (:meth:`~DriveNode.disable_tpdos`);
3. :meth:`~DriveNode.start`: operational;
4. after a reboot (boot-up message): :meth:`~DriveNode.configure_again`, on the
   link's worker thread (:class:`Reconfigurer`), while the cycles until then are a gap.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import struct
import threading
from collections.abc import Callable, Sequence

import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError
from ncmeasure.links.canopen.layout import (
    COB_INVALID,
    Layout,
    LinkAxis,
    Slot,
    pack_slots,
    unit_text,
)
from ncmeasure.links.canopen.objects import DATA_TYPES, MapObject, sdo_error_text
from ncmeasure.links.canopen.settings import CanOpenSettings
from ncmeasure.samples import LinkEvent

__all__ = [
    "DriveNode",
    "Reconfigurer",
    "configure_drives",
    "decode_int",
    "fall_back_to_polling",
    "fit",
    "prepare_offline",
]

log = logging.getLogger(__name__)

_COB_NO_RTR = 0x40000000
_COB_EXTENDED = 0x20000000
_ABSENT_CODES = frozenset({0x06020000, 0x06090011})  # object / sub-index does not exist


class DriveNode:
    """One axis' drive as a CANopen node: SDO client, NMT, and its configuration.

    Args:
        axis: What the link knows of the drive (objects, slots, scales).
        layout: The link's layout: the object map and every slot (COB-IDs taken).
        period_us: The SYNC period written to 0x1006, in µs.
        event: Where the node's events go (the link's).
    """

    def __init__(
        self,
        axis: LinkAxis,
        layout: Layout,
        period_us: int,
        event: Callable[[LinkEvent], None],
    ) -> None:
        self.axis = axis
        self.node: canopen.RemoteNode | None = None
        self._layout = layout
        self._settings: CanOpenSettings = layout.settings
        self._period_us = period_us
        self._event = event
        self._sdo_lock = threading.Lock()

    def attach(self, network: canopen.Network) -> canopen.RemoteNode:
        """Add the node to the network (its SDO client, EMCY and heartbeat consumers)."""
        node = canopen.RemoteNode(self.axis.node_id, self.axis.od)
        node.sdo.RESPONSE_TIMEOUT = self._settings.sdo_timeout_s
        network.add_node(node)
        self.node = node
        return node

    # --- SDO, NMT -------------------------------------------------------------------------

    def upload(self, obj_index: int, subindex: int) -> bytes:
        assert self.node is not None
        with self._sdo_lock:
            return bytes(self.node.sdo.upload(obj_index, subindex))

    def download(self, obj_index: int, subindex: int, data: bytes) -> None:
        assert self.node is not None
        with self._sdo_lock:
            self.node.sdo.download(obj_index, subindex, data)

    def failure(self, what: str, exc: Exception) -> LinkError:
        """The error of a failed SDO transfer, in one line."""
        text = (
            f"{self.axis.who}: {what} failed: {sdo_error_text(exc, self._settings.sdo_timeout_s)}"
        )
        if isinstance(exc, SdoCommunicationError):
            return LinkTimeoutError(text + "; check the node id, bitrate and wiring")
        return LinkError(text)

    def nmt(self, state: str) -> None:
        if self._settings.controls_nmt and self.node is not None:
            self.node.nmt.state = state

    def report_notes(self) -> None:
        """What the link noticed about the drive (fallbacks, EDS types), as info events."""
        axis = self.axis
        for note in axis.notes:
            self._event(LinkEvent(0.0, "info", f"{axis.who}: {note}", axis=axis.name))

    # --- configuration ----------------------------------------------------------------------

    def prepare(self) -> None:
        """Pre-operational, read every object once (fallbacks), rated current, cycle period."""
        axis = self.axis
        self.nmt("PRE-OPERATIONAL")
        for role in list(axis.objects):
            obj = self._readable(role, axis.objects[role])
            if obj is None:
                del axis.objects[role]
            else:
                axis.objects[role] = obj
        pack_slots(axis, self._layout.map)
        self._layout.collect()
        self.read_rated_current()
        axis.set_scales()
        if self._settings.produces_sync:
            try:  # lets the drive monitor the SYNC; optional for the measurement
                self.download(0x1006, 0, struct.pack("<I", self._period_us))
            except (SdoAbortedError, SdoCommunicationError) as exc:
                log.info("%s: 0x1006 not written (%s)", axis.who, sdo_error_text(exc))
        self.report_notes()

    def _readable(self, role: str, obj: MapObject | None) -> MapObject | None:
        """The object of ``role`` the drive has: ``obj`` or a fallback (None: no statusword)."""
        axis = self.axis
        while obj is not None:
            try:
                self.upload(obj.index, obj.subindex)
            except SdoAbortedError as exc:
                if exc.code in _ABSENT_CODES and obj.fallback is not None:
                    axis.notes.append(
                        f"drive has no {obj.label} ({sdo_error_text(exc)}): reading "
                        f"{obj.fallback.label} instead ({unit_text(obj.fallback.unit)})"
                    )
                    obj = obj.fallback
                    continue
                if role == "statusword":
                    axis.notes.append(
                        f"cannot read {obj.label} ({sdo_error_text(exc)}): "
                        "drive faults are reported by EMCY only"
                    )
                    return None
                raise self.failure(f"reading {obj.label}", exc) from exc
            except SdoCommunicationError as exc:
                raise self.failure(f"reading {obj.label}", exc) from exc
            break
        return obj

    def read_rated_current(self) -> None:
        axis = self.axis
        needs = any(o.unit.startswith("permille") for o in axis.objects.values())
        axis.rated_current_a = axis.configured_rated_current_a
        if not needs or axis.rated_current_a is not None:
            return
        obj = self._layout.map.rated_current
        if obj is None:
            raise LinkError(
                f"{axis.who}: the current is in per mille of the rated current; "
                f"set axes[{axis.position}].link.rated_current_a (object map "
                f"{self._layout.map.name} names no rated current object)"
            )
        try:
            raw = self.upload(obj.index, obj.subindex)
        except (SdoAbortedError, SdoCommunicationError) as exc:
            error = self.failure(f"reading the {obj.label}", exc)
            raise type(error)(f"{error}; set axes[{axis.position}].link.rated_current_a") from exc
        value = decode_int(raw, obj.type)
        if value <= 0:
            raise LinkError(
                f"{axis.who}: the drive reports a rated current of {value} mA in "
                f"{obj.label}; set axes[{axis.position}].link.rated_current_a"
            )
        axis.rated_current_a = value / 1000.0
        self._event(
            LinkEvent(
                0.0,
                "info",
                f"{axis.who}: rated current {value / 1000:g} A read from {obj.label}",
                axis=axis.name,
            )
        )

    def _tpdo_cob_id(self, slot: Slot) -> tuple[int, int]:
        """COB-ID to use (from the drive, else the predefined one) and the RTR bit."""
        comm = 0x1800 + slot.number - 1
        raw = decode_int(self.upload(comm, 1), "uint32")
        cob_id = raw & 0x7FF
        taken = {s.cob_id for s in self._layout.slots if s is not slot and s.cob_id}
        if raw & _COB_EXTENDED or not 0x180 <= cob_id <= 0x57F or cob_id in taken:
            if slot.number > 4:
                raise LinkError(
                    f"{self.axis.who}: TPDO{slot.number} has no usable COB-ID "
                    f"(0x{raw:08X}); set one in the drive or lower first_tpdo"
                )
            cob_id = 0x180 + 0x100 * (slot.number - 1) + self.axis.node_id
        return cob_id, raw & _COB_NO_RTR

    def map_tpdos(self) -> None:
        """Write the TPDO configuration (CiA 301 order: disable, type, map, enable).

        Raises:
            SdoAbortedError: The drive refused (a note names the node and TPDO): the
                link falls back to SDO polling.
            LinkError: The drive did not answer, or has no usable COB-ID.
        """
        who = self.axis.who
        for slot in self.axis.slots:
            comm, mapping = 0x1800 + slot.number - 1, 0x1A00 + slot.number - 1
            try:
                cob_id, rtr = self._tpdo_cob_id(slot)
                cob_id = slot.cob_id or cob_id  # after a reboot: the COB-ID subscribed to
                self.download(comm, 1, struct.pack("<I", cob_id | rtr | COB_INVALID))
                self.download(comm, 2, struct.pack("<B", 1))
                # the inhibit time is optional and irrelevant for synchronous PDOs
                with contextlib.suppress(SdoAbortedError):
                    self.download(comm, 3, struct.pack("<H", 0))
                self.download(mapping, 0, struct.pack("<B", 0))
                for k, f in enumerate(slot.fields, start=1):
                    assert f.obj is not None  # the link's own layout reads every byte
                    entry = f.obj.index << 16 | f.obj.subindex << 8 | 8 * f.obj.size
                    self.download(mapping, k, struct.pack("<I", entry))
                self.download(mapping, 0, struct.pack("<B", len(slot.fields)))
                self.download(comm, 1, struct.pack("<I", cob_id | rtr))
            except SdoCommunicationError as exc:
                raise self.failure(f"configuring TPDO{slot.number}", exc) from exc
            except SdoAbortedError as exc:
                exc.add_note(f"{who}: configuring TPDO{slot.number}")
                raise
            slot.cob_id = cob_id

    def disable_tpdos(self) -> None:
        """Switch off the TPDOs already configured (the link falls back to SDO polling)."""
        for slot in self.axis.slots:
            if slot.cob_id:
                invalid = struct.pack("<I", slot.cob_id | COB_INVALID)
                with contextlib.suppress(SdoAbortedError, SdoCommunicationError):
                    self.download(0x1800 + slot.number - 1, 1, invalid)

    def start(self) -> None:
        self.nmt("OPERATIONAL")

    def configure_again(
        self, pdo: bool, stop: threading.Event, cycle_time: Callable[[], float]
    ) -> None:
        """After a reboot: the TPDOs (``pdo``), the SYNC period, operational; three tries.

        Args:
            pdo: The link reads TPDOs (not SDO polling): map them again.
            stop: Set when the link closes: no more tries.
            cycle_time: The link time now, for the events.
        """
        if stop.is_set():
            return
        axis = self.axis
        errors: list[str] = []
        for _attempt in range(3):
            try:
                if pdo:
                    self.map_tpdos()
                if self._settings.produces_sync:
                    period_us = struct.pack("<I", self._period_us)
                    with contextlib.suppress(SdoAbortedError):
                        self.download(0x1006, 0, period_us)
                self.start()
            except (LinkError, SdoAbortedError, SdoCommunicationError) as exc:
                errors.append(sdo_error_text(exc) if not isinstance(exc, LinkError) else str(exc))
                if stop.wait(0.2):
                    return
                continue
            self._event(
                LinkEvent(
                    cycle_time(),
                    "info",
                    f"{axis.who}: configured again after the reboot; data continues",
                    axis=axis.name,
                )
            )
            return
        self._event(
            LinkEvent(
                cycle_time(),
                "fault",
                f"{axis.who}: cannot configure the drive again after its "
                f"reboot ({errors[-1]}); its data stays missing",
                axis=axis.name,
            )
        )


def configure_drives(
    nodes: Sequence[DriveNode], layout: Layout, prepared: Callable[[], None]
) -> LinkEvent | None:
    """The master's part: read the objects, map the TPDOs, start the nodes (SDO, NMT).

    Args:
        nodes: The drives, in the order of the layout's axes.
        layout: The link's layout (its bus load is checked again after the fallbacks).
        prepared: Called after each node is prepared (its slots may have changed).

    Returns:
        None when every TPDO is mapped; else the event of the fall back to SDO polling.

    Raises:
        ConfigError: The objects of the drives load the bus too much.
        LinkError: A drive does not answer or cannot be configured.
    """
    for node in nodes:
        node.prepare()
        prepared()
    layout.check_load()  # objects may have changed to fallbacks
    fallback = None
    for node in nodes:
        try:
            node.map_tpdos()
        except SdoAbortedError as exc:
            fallback = fall_back_to_polling(nodes, node.axis, exc, layout.settings.sync_hz)
            break
    for node in nodes:
        node.start()
    return fallback


def prepare_offline(layout: Layout, nodes: Sequence[DriveNode]) -> None:
    """For a CAN log: what the drives cannot be asked, from the settings; the notes reported.

    Raises:
        ConfigError: A rated current or a COB-ID cannot be known without SDO.
    """
    problems = layout.prepare_offline()
    for node in nodes:
        node.report_notes()
    if problems:
        raise ConfigError("the CAN log cannot be decoded with these link settings", problems)


def fall_back_to_polling(
    nodes: Sequence[DriveNode], failed: LinkAxis, exc: SdoAbortedError, sync_hz: float
) -> LinkEvent:
    """A drive refused the PDO mapping: switch off every TPDO configured; the event to report."""
    where = " ".join(getattr(exc, "__notes__", [])) or failed.who
    for node in nodes:  # switch off what was already configured
        node.disable_tpdos()
    return LinkEvent(
        0.0,
        "info",
        f"{where}: the drive refused the PDO mapping ({sdo_error_text(exc)}); falling "
        f"back to SDO polling of the same objects on all axes, at most one poll per "
        f"SYNC cycle ({sync_hz:g} Hz) and as fast as the drives answer",
        axis=failed.name,
        details={"abort_code": exc.code},
    )


class Reconfigurer:
    """The link's worker thread: a drive that rebooted is configured again, one at a time.

    Args:
        stop: Set when the link closes.
        cond: The link's condition: :attr:`pending` changes under it, notified.
        pdo: True while the link reads TPDOs (not SDO polling).
        cycle_time: The link time now, for the events.
        event: Where the events go (the link's).
    """

    def __init__(
        self,
        stop: threading.Event,
        cond: threading.Condition,
        pdo: Callable[[], bool],
        cycle_time: Callable[[], float],
        event: Callable[[LinkEvent], None],
    ) -> None:
        self._stop = stop
        self._cond = cond
        self._pdo = pdo
        self._cycle_time = cycle_time
        self._event = event
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue()
        self.pending = 0
        """Drives being configured again (lockstep: no SYNC until there are none)."""

    def run(self) -> None:
        """The worker thread: the jobs in order, until :meth:`close`."""
        while True:
            job = self._jobs.get()
            if job is None:
                return
            try:
                job()
            except Exception:
                log.exception("canopen link: background job failed")

    def close(self) -> None:
        self._jobs.put(None)

    def rebooted(self, node: DriveNode, configure: bool) -> None:
        """The node sent its boot-up message: report it, and configure it again (``configure``).

        A link that only listens (or decodes a log) does not configure: the controller does.
        """
        axis = node.axis
        if not configure:
            self._event(
                LinkEvent(
                    self._cycle_time(),
                    "reboot",
                    f"{axis.who} rebooted (boot-up message): its PDOs stop until the "
                    "controller configures it again; the cycles until then are a gap",
                    axis=axis.name,
                )
            )
            return
        self._event(
            LinkEvent(
                self._cycle_time(),
                "reboot",
                f"{axis.who} rebooted (boot-up message): its PDO configuration is lost; "
                "configuring it again, the cycles until then are reported as a gap",
                axis=axis.name,
            )
        )
        with self._cond:
            self.pending += 1  # lockstep: no SYNC until the drive is configured again
        self._jobs.put(lambda: self._reconfigure(node))

    def _reconfigure(self, node: DriveNode) -> None:
        try:
            node.configure_again(self._pdo(), self._stop, self._cycle_time)
        finally:
            with self._cond:
                self.pending -= 1
                self._cond.notify_all()


def decode_int(raw: bytes, type_name: str) -> int:
    """An SDO answer as the integer of ``type_name`` (short answers padded)."""
    code = DATA_TYPES[type_name][1]
    size = struct.calcsize("<" + code)
    return int(struct.unpack("<" + code, _pad(raw, size, code.islower()))[0])


def _pad(raw: bytes, size: int, signed: bool) -> bytes:
    if len(raw) >= size:
        return raw[:size]
    fill = b"\xff" if signed and raw and raw[-1] & 0x80 else b"\0"
    return raw + fill * (size - len(raw))


def fit(raw: bytes, obj: MapObject) -> bytes:
    """An SDO answer cut or sign-extended to the object's size."""
    return _pad(raw, obj.size, DATA_TYPES[obj.type][1].islower())
