"""Simulated CiA 402 servo drives on a python-can bus: SDO server, NMT, TPDOs on SYNC.

A frame-level responder, lean enough for 1 kHz SYNC with several drives in
one Python process (``canopen.LocalNode`` does not transmit mapped TPDOs on
SYNC by itself). Each :class:`SimulatedDrive` has an object dictionary, from
an EDS/DCF file (the real fixtures work, quirks included) or from the
built-in CiA 402 defaults, and:

- answers SDO uploads and downloads (expedited and segmented) like a drive:
  access rights, sizes, and the CiA 301 rules for changing a TPDO (mapping
  only while the PDO is disabled and its entry count is 0, mapped objects
  must exist, be mappable and fit 64 bits);
- follows NMT (start, stop, pre-operational, reset node/communication with a
  boot-up message);
- on every SYNC, while operational, sends its valid synchronous TPDOs
  (transmission type 1..240) with values of a :class:`~ncmeasure.sim.signals.SignalSource`
  at time = SYNC index × period, encoded like a real drive: int32
  increments, int32 velocity units, int16 per mille of the rated current,
  statusword 0x0237 "operation enabled". The period is the communication
  cycle period 0x1006 the master writes, else ``period_s``.

The SYNC index counts the SYNC messages from 0, so it equals the cycle number
of the CANopen link that produces them, and the sample of link time ``t`` is
the source's state at ``t``. A SYNC with a one-byte counter (1..240, CiA 301
0x1019) sets the index to the next one that is congruent to ``counter - 1``
modulo 240: cycles the producer skipped are skipped here too.

On python-can's ``virtual`` bus the drives can also answer SYNC *on the bus*
(``answer="on_send"``): within the sender's ``send`` call, right after the
SYNC reached every other bus and before that call returns, as a drive
answers in its synchronous window whatever the host does. The frames are
then behind their SYNC and ahead of the next one, however late the host runs
any thread. (The drives' thread still serves NMT and SDO.) The
time spent answering is the sender's thread's; :attr:`SimulatedDrives.answer_cpu_s`
says how much, for a benchmark that must not count it.

In lockstep with a link on a :class:`~ncmeasure.samples.SimulatedClock`
(``clock``), the drives report every SYNC answered, with the number of frames
they have sent, and the link sends the next SYNC only when it has received
them: the recording is the same on an idle and on a loaded computer.

Fault switches for tests, all thread-safe: :meth:`SimulatedDrive.stop_answering`,
:meth:`~SimulatedDrive.resume`, :meth:`~SimulatedDrive.abort_sdo`,
:meth:`~SimulatedDrive.slow`, :meth:`~SimulatedDrive.reboot`,
:meth:`~SimulatedDrive.send_emcy`, :meth:`~SimulatedDrive.set_fault`. A test
that needs one at a given moment schedules it by SYNC index
(:meth:`SimulatedDrives.at_sync`), an event in simulated time, not a sleep.

:class:`SimulatedDrives` runs the drives of a machine on one bus in one
thread; :func:`serve` is the blocking form for ``ncmeasure simulate-drive``.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import queue
import struct
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, Self

import can
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable

from ncmeasure.links.canopen.bus import open_bus
from ncmeasure.links.canopen.objects import (
    MapObject,
    ObjectMap,
    build_dictionary,
    load_eds,
    load_object_map,
    position_scale_mm,
    velocity_scale_mm_min,
)
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.signals import AxisState, PatternSource, SignalSource

__all__ = [
    "OPERATION_ENABLED",
    "DriveScaling",
    "SimulatedDrive",
    "SimulatedDrives",
    "TpdoConfig",
    "serve",
]

log = logging.getLogger(__name__)

#: Statusword of a drive in "operation enabled" (ready, switched on, enabled,
#: voltage enabled, quick stop off, remote).
OPERATION_ENABLED = 0x0237
_FAULT_BIT = 0x0008

_PRE_OPERATIONAL, _OPERATIONAL, _STOPPED, _INITIALISING = 127, 5, 4, 0
#: The SYNC counter runs 1.._SYNC_COUNTER_MAX (the largest overflow value of CiA 301 0x1019).
_SYNC_COUNTER_MAX = 240
_NMT_NAMES = {0: "INITIALISING", 4: "STOPPED", 5: "OPERATIONAL", 127: "PRE-OPERATIONAL"}

# SDO abort codes (CiA 301) the server uses.
ABORT_TOGGLE = 0x05030000
ABORT_COMMAND = 0x05040001
ABORT_UNSUPPORTED = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_INCOMPATIBLE = 0x06040043
ABORT_LENGTH_HIGH = 0x06070012
ABORT_LENGTH_LOW = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_GENERAL = 0x08000000
ABORT_NO_DATA = 0x08000024

_INT_FORMATS = {
    0x01: "B",
    0x02: "b",
    0x03: "h",
    0x04: "i",
    0x05: "B",
    0x06: "H",
    0x07: "I",
    0x08: "f",
    0x11: "d",
    0x15: "q",
    0x1B: "Q",
}


@dataclass(frozen=True)
class DriveScaling:
    """How a simulated drive turns an axis state into drive units."""

    increments_per_rev: int = 10_000
    screw_lead_mm: float = 20.0
    gear_ratio: float = 1.0
    rated_current_a: float = 17.7
    velocity_unit: str = "inc_per_s"


@dataclass(frozen=True)
class TpdoConfig:
    """A TPDO as the drive currently has it."""

    number: int
    cob_id: int
    valid: bool
    transmission_type: int
    mapping: tuple[tuple[int, int, int], ...]
    """(index, subindex, bits) per mapped object."""


@dataclass
class _Entry:
    name: str
    data_type: int
    access: str
    data: bytes
    mappable: bool

    @property
    def readable(self) -> bool:
        return "r" in self.access or self.access == "const"

    @property
    def writable(self) -> bool:
        return "w" in self.access

    @property
    def fixed_size(self) -> int | None:
        code = _INT_FORMATS.get(self.data_type)
        return struct.calcsize("<" + code) if code else None


@dataclass
class _Dynamic:
    """An object whose value comes from the signal source."""

    role: str
    unit: str
    fmt: str
    encode: Callable[[AxisState], float]
    """Value in drive units, before rounding and clamping to the type."""


@dataclass
class _Transfer:
    """A segmented SDO transfer in progress."""

    index: int
    subindex: int
    upload: bool
    data: bytearray = field(default_factory=bytearray)
    size: int | None = None
    toggle: int = 0


@dataclass
class _SdoAbortErrorRule:
    index: int | None
    subindex: int | None
    code: int
    upload: bool
    download: bool


@dataclass
class _Plan:
    """A valid synchronous TPDO, ready to pack."""

    cob_id: int
    every: int
    parts: list[tuple[tuple[int, int], str | None, int]]  # key, struct code or None, bytes
    counter: int = 0


def _entries_of(od: ObjectDictionary) -> dict[tuple[int, int], _Entry]:
    entries: dict[tuple[int, int], _Entry] = {}

    def add(var: ODVariable) -> None:
        value: Any = var.value if var.value is not None else var.default
        data_type = var.data_type or 0
        code = _INT_FORMATS.get(data_type)
        if value is None:
            value = 0 if code else b""
        if code is not None:
            try:
                data = struct.pack("<" + code, value)
            except (struct.error, TypeError):  # an EDS value the type does not take
                data = struct.pack("<" + code, 0)
        elif isinstance(value, bytes):
            data = value
        else:
            data = str(value).encode("utf-8")
        entries[(var.index, var.subindex)] = _Entry(
            var.name, data_type, var.access_type or "rw", data, bool(var.pdo_mappable)
        )

    for index in sorted(od.indices):
        obj = od.indices[index]
        if isinstance(obj, ODVariable):
            add(obj)
        elif isinstance(obj, (ODRecord, ODArray)):
            for var in obj.subindices.values():
                if isinstance(var, ODVariable):
                    add(var)
    return entries


def _clamp(value: float, fmt: str) -> int:
    bits = 8 * struct.calcsize("<" + fmt)
    if fmt.islower():
        low, high = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    else:
        low, high = 0, (1 << bits) - 1
    if not math.isfinite(value):
        return 0
    return int(min(max(round(value), low), high))


class SimulatedDrive:
    """One simulated CiA 402 drive (a CANopen node). Attach it to :class:`SimulatedDrives`.

    Args:
        node_id: CANopen node id, 1..127.
        axis: Index of the axis in the signal source (0-based).
        dictionary: Its object dictionary (EDS/DCF or :func:`build_dictionary`).
        object_map: Which objects carry which value (to encode them).
        scaling: Encoder, lead, rated current and velocity unit.
    """

    def __init__(
        self,
        node_id: int,
        axis: int,
        dictionary: ObjectDictionary,
        object_map: ObjectMap,
        scaling: DriveScaling = DriveScaling(),
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id must be 1..127, not {node_id}")
        self.node_id = node_id
        self.axis = axis
        self.scaling = scaling
        self.object_map = object_map
        self._lock = threading.RLock()
        self._host: SimulatedDrives | None = None
        self._defaults = _entries_of(dictionary)
        self._set_rated_current(object_map.rated_current)
        self._entries = {
            k: _Entry(e.name, e.data_type, e.access, e.data, e.mappable)
            for k, e in self._defaults.items()
        }
        self._dynamic = self._dynamic_objects()
        self._nmt = _PRE_OPERATIONAL
        self._answering = True
        self._down_until = 0.0
        self._slow_s = 0.0
        self._aborts: list[_SdoAbortErrorRule] = []
        self._transfer: _Transfer | None = None
        self._plans: list[_Plan] | None = None
        self._status = OPERATION_ENABLED
        self._late_cob_id: int | None = None
        self._held: tuple[int, bytes] | None = None
        self.sdo_requests = 0
        self.sdo_writes = 0
        self.boots = 0

    @classmethod
    def from_eds(
        cls,
        path: str | Path,
        node_id: int,
        axis: int,
        object_map: ObjectMap,
        scaling: DriveScaling = DriveScaling(),
    ) -> SimulatedDrive:
        """A drive whose dictionary is an EDS/DCF file (ConfigError names a bad file)."""
        return cls(node_id, axis, load_eds(Path(path), node_id), object_map, scaling)

    @classmethod
    def builtin(
        cls, node_id: int, axis: int, object_map: ObjectMap, scaling: DriveScaling = DriveScaling()
    ) -> SimulatedDrive:
        """A drive with the built-in CiA 402 dictionary of ``object_map``.

        It also has the torque offset 0x60B2:00 (INTEGER16, read-write, 0), which
        ``ncmeasure apply-compensation`` writes.
        """
        od = build_dictionary(
            object_map, node_id, rated_current_ma=round(scaling.rated_current_a * 1000)
        )
        if 0x60B2 not in od:
            offset = ODVariable("torque offset", 0x60B2, 0)
            offset.data_type = 0x03  # INTEGER16
            offset.access_type = "rw"
            offset.default = 0
            offset.pdo_mappable = True
            od.add_object(offset)
        return cls(node_id, axis, od, object_map, scaling)

    def _set_rated_current(self, obj: MapObject | None) -> None:
        milliamps = round(self.scaling.rated_current_a * 1000)
        for key in [(0x6075, 0)] + ([(obj.index, obj.subindex)] if obj else []):
            entry = self._defaults.get(key)
            code = _INT_FORMATS.get(entry.data_type) if entry else None
            if entry is not None and code is not None:
                entry.data = struct.pack("<" + code, _clamp(milliamps, code))

    def _dynamic_objects(self) -> dict[tuple[int, int], _Dynamic]:
        s = self.scaling
        per_inc = position_scale_mm(s.increments_per_rev, s.screw_lead_mm, s.gear_ratio)
        per_vel = velocity_scale_mm_min(
            s.velocity_unit, s.increments_per_rev, s.screw_lead_mm, s.gear_ratio
        )
        rated = s.rated_current_a
        encoders: dict[tuple[str, str], Callable[[AxisState], float]] = {
            ("position", "inc"): lambda st: st.position_mm / per_inc,
            ("velocity", "velocity"): lambda st: st.velocity_mm_min / per_vel,
            ("velocity_demand", "velocity"): lambda st: st.velocity_cmd_mm_min / per_vel,
            ("current", "permille_rated_current"): lambda st: st.current_a / rated * 1000,
            ("current", "permille_rated_torque"): lambda st: st.current_a / rated * 1000,
            ("current", "mA"): lambda st: st.current_a * 1000,
        }
        dynamic: dict[tuple[int, int], _Dynamic] = {}
        for role in ("statusword", "position", "velocity", "velocity_demand", "current"):
            obj = self.object_map.role(role)
            while obj is not None:
                key = (obj.index, obj.subindex)
                entry = self._defaults.get(key)
                code = _INT_FORMATS.get(entry.data_type) if entry else None
                if entry is not None and code is not None and key not in dynamic:
                    if role == "statusword":
                        dynamic[key] = _Dynamic(role, obj.unit, code, self._statusword)
                    else:
                        dynamic[key] = _Dynamic(role, obj.unit, code, encoders[(role, obj.unit)])
                obj = obj.fallback
        return dynamic

    def _statusword(self, state: AxisState) -> float:
        return self._status

    # --- fault switches ---------------------------------------------------------------

    def stop_answering(self) -> None:
        """Go silent: no SDO answers, no PDOs, NMT ignored (SYNC is still counted)."""
        with self._lock:
            self._answering = False

    def resume(self) -> None:
        """Answer again, and clear :meth:`abort_sdo` rules and :meth:`slow`."""
        with self._lock:
            self._answering = True
            self._aborts.clear()
            self._slow_s = 0.0

    def abort_sdo(
        self,
        index: int | None = None,
        code: int = ABORT_GENERAL,
        *,
        subindex: int | None = None,
        upload: bool = True,
        download: bool = True,
    ) -> None:
        """Abort SDO transfers of ``index`` (all objects when None) with abort ``code``."""
        with self._lock:
            self._aborts.append(_SdoAbortErrorRule(index, subindex, code, upload, download))

    def slow(self, seconds: float) -> None:
        """Answer SDO requests ``seconds`` late (0 = at once)."""
        with self._lock:
            self._slow_s = max(0.0, seconds)

    def reboot(self, downtime_s: float = 0.0) -> None:
        """Reset: silent for ``downtime_s``, then boot-up (0x700 + id, 0x00), pre-operational.

        The PDO configuration and every other written value return to the defaults.
        """
        with self._lock:
            self._reset(communication_only=False)
            self._nmt = _INITIALISING
            self._down_until = time.monotonic() + downtime_s
        host = self._host
        if host is None:
            return
        if downtime_s > 0:
            host._schedule(downtime_s, self._boot)
        else:
            self._boot()  # at once, in the same SYNC cycle as the reset

    def send_emcy(self, code: int, register: int = 0x01, data: bytes = b"") -> None:
        """Send an EMCY message (0x80 + id): error code, error register, 5 bytes of data."""
        host = self._host
        if host is None:
            raise RuntimeError("the drive is not attached to a bus")
        payload = struct.pack("<HB5s", code, register, data[:5])
        host._send(0x80 + self.node_id, payload)

    def set_fault(self, active: bool = True) -> None:
        """Set or clear the fault bit (3) of the statusword."""
        with self._lock:
            self._status = (
                (OPERATION_ENABLED & ~0x0007 | _FAULT_BIT) if active else OPERATION_ENABLED
            )

    def send_late(self, cob_id: int | None) -> None:
        """Send the TPDO ``cob_id`` one cycle late, after the next SYNC (None: on time again).

        A drive too slow for its SYNC period: the frame of cycle k goes out after
        SYNC k + 1, before the frames of k + 1, so on the bus it sits in the wrong
        cycle. When the drive is on time again the held frame still goes out first.
        """
        with self._lock:
            self._late_cob_id = cob_id

    # --- state for tests ----------------------------------------------------------------

    @property
    def nmt_state(self) -> str:
        """INITIALISING, PRE-OPERATIONAL, OPERATIONAL or STOPPED."""
        with self._lock:
            return _NMT_NAMES[self._nmt]

    def value(self, index: int, subindex: int = 0) -> bytes:
        """The stored bytes of an object (dynamic objects: their last stored value)."""
        with self._lock:
            return self._entries[(index, subindex)].data

    def tpdos(self) -> list[TpdoConfig]:
        """The TPDOs of the dictionary as they are now."""
        with self._lock:
            configs = []
            for number in range(512):
                comm = self._entries.get((0x1800 + number, 1))
                if comm is None:
                    continue
                cob = struct.unpack("<I", comm.data.ljust(4, b"\0"))[0]
                trans = self._int(0x1800 + number, 2, 255)
                count = self._int(0x1A00 + number, 0, 0)
                mapping = []
                for sub in range(1, count + 1):
                    entry = self._int(0x1A00 + number, sub, 0)
                    mapping.append((entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF))
                configs.append(
                    TpdoConfig(number + 1, cob & 0x7FF, not cob & 0x80000000, trans, tuple(mapping))
                )
            return configs

    # --- internals (called with the host's thread) --------------------------------------

    def _int(self, index: int, subindex: int, default: int) -> int:
        entry = self._entries.get((index, subindex))
        code = _INT_FORMATS.get(entry.data_type) if entry else None
        if entry is None or code is None or len(entry.data) != struct.calcsize("<" + code):
            return default
        return int(struct.unpack("<" + code, entry.data)[0])

    def _reset(self, communication_only: bool) -> None:
        for key, default in self._defaults.items():
            if not communication_only or 0x1000 <= key[0] <= 0x1FFF:
                entry = self._entries[key]
                entry.data = default.data
        self._transfer = None
        self._plans = None

    def _boot(self) -> None:
        with self._lock:
            self._nmt = _PRE_OPERATIONAL
            self._down_until = 0.0
            self.boots += 1
        if self._host is not None:
            self._host._send(0x700 + self.node_id, b"\x00")

    def _silent(self) -> bool:
        return (
            not self._answering
            or (self._down_until > 0.0 and time.monotonic() < self._down_until)
            or self._nmt == _INITIALISING
        )

    def _period_s(self) -> float:
        cycle_us = self._int(0x1006, 0, 0)
        if cycle_us > 0:
            return cycle_us / 1e6
        assert self._host is not None
        return self._host.period_s

    def _on_nmt(self, command: int) -> None:
        with self._lock:
            if self._silent():
                return
            if command == 0x01:
                self._nmt = _OPERATIONAL
            elif command == 0x02:
                self._nmt = _STOPPED
            elif command == 0x80:
                self._nmt = _PRE_OPERATIONAL
            elif command in (0x81, 0x82):
                self._reset(communication_only=command == 0x82)
                self._nmt = _INITIALISING
        if command in (0x81, 0x82):
            self._boot()

    def _on_sync(self, index: int, source: SignalSource) -> list[tuple[int, bytes]]:
        with self._lock:
            if self._nmt != _OPERATIONAL or self._silent():
                return []
            if self._plans is None:
                self._plans = self._make_plans()
            due = []
            for plan in self._plans:
                plan.counter += 1
                if plan.counter >= plan.every:
                    plan.counter = 0
                    due.append(plan)
            if not due:
                return []
            state = source.state(self.axis, index * self._period_s())
            frames = [self._held] if self._held is not None else []
            self._held = None
            for plan in due:
                parts = []
                for key, code, size in plan.parts:
                    dyn = self._dynamic.get(key)
                    if dyn is not None and code is not None:
                        parts.append(struct.pack("<" + code, _clamp(dyn.encode(state), code)))
                    else:
                        parts.append(self._entries[key].data[:size].ljust(size, b"\0"))
                frame = (plan.cob_id, b"".join(parts))
                if plan.cob_id == self._late_cob_id:
                    self._held = frame
                else:
                    frames.append(frame)
            return frames

    def _make_plans(self) -> list[_Plan]:
        plans = []
        for config in self.tpdos():
            if not config.valid or not 1 <= config.transmission_type <= 240:
                continue
            parts: list[tuple[tuple[int, int], str | None, int]] = []
            for index, sub, bits in config.mapping:
                entry = self._entries.get((index, sub))
                code = _INT_FORMATS.get(entry.data_type) if entry else None
                size = bits // 8
                if code is not None and struct.calcsize("<" + code) != size:
                    code = None
                parts.append(((index, sub), code, size))
            if parts:
                plans.append(_Plan(config.cob_id, config.transmission_type, parts))
        return plans

    def _state_now(self) -> AxisState:
        host = self._host
        assert host is not None
        index = host.sync_index
        t = index * self._period_s() if index >= 0 else time.monotonic() - host.started
        return host.source.state(self.axis, t)

    # --- SDO server -------------------------------------------------------------------------

    def _on_sdo(self, request: bytes) -> None:
        with self._lock:
            if self._silent() or self._nmt == _STOPPED:
                return
            self.sdo_requests += 1
            request = request.ljust(8, b"\0")
            response = self._sdo(request)
            delay = self._slow_s
        if response is not None and self._host is not None:
            self._host._send(0x580 + self.node_id, response, delay)

    def _sdo(self, req: bytes) -> bytes | None:
        command = req[0]
        ccs = command >> 5
        index, subindex = struct.unpack_from("<HB", req, 1)
        try:
            if ccs == 1:
                return self._initiate_download(command, index, subindex, req)
            if ccs == 0:
                return self._download_segment(command, req)
            if ccs == 2:
                return self._initiate_upload(index, subindex)
            if ccs == 3:
                return self._upload_segment(command)
            if ccs == 4:
                self._transfer = None
                return None
            raise _SdoAbortError(ABORT_COMMAND)
        except _SdoAbortError as abort:
            if ccs in (0, 3) and self._transfer is not None:
                index, subindex = self._transfer.index, self._transfer.subindex
            self._transfer = None
            return struct.pack("<BHBI", 0x80, index, subindex, abort.code)

    def _check_rules(self, index: int, subindex: int, upload: bool) -> None:
        for rule in self._aborts:
            if (
                rule.index in (None, index)
                and rule.subindex in (None, subindex)
                and (rule.upload if upload else rule.download)
            ):
                raise _SdoAbortError(rule.code)

    def _find(self, index: int, subindex: int) -> _Entry:
        entry = self._entries.get((index, subindex))
        if entry is None:
            if any(k[0] == index for k in self._entries):
                raise _SdoAbortError(ABORT_NO_SUBINDEX)
            raise _SdoAbortError(ABORT_NO_OBJECT)
        return entry

    def _initiate_download(self, command: int, index: int, subindex: int, req: bytes) -> bytes:
        self._check_rules(index, subindex, upload=False)
        self._find(index, subindex)
        if command & 0x02:  # expedited
            size = 4 - ((command >> 2) & 0x3) if command & 0x01 else 4
            self._write(index, subindex, req[4 : 4 + size])
        else:
            size_known = struct.unpack_from("<I", req, 4)[0] if command & 0x01 else None
            self._transfer = _Transfer(index, subindex, upload=False, size=size_known)
        return struct.pack("<BHB4x", 0x60, index, subindex)

    def _download_segment(self, command: int, req: bytes) -> bytes:
        transfer = self._transfer
        if transfer is None or transfer.upload:
            raise _SdoAbortError(ABORT_COMMAND)
        toggle = (command >> 4) & 1
        if toggle != transfer.toggle:
            raise _SdoAbortError(ABORT_TOGGLE)
        unused = (command >> 1) & 0x7
        transfer.data += req[1 : 8 - unused]
        transfer.toggle ^= 1
        if command & 0x01:  # last segment
            self._transfer = None
            if transfer.size is not None and transfer.size != len(transfer.data):
                raise _SdoAbortError(
                    ABORT_LENGTH_LOW if len(transfer.data) < transfer.size else ABORT_LENGTH_HIGH
                )
            self._write(transfer.index, transfer.subindex, bytes(transfer.data))
        return struct.pack("<B7x", 0x20 | toggle << 4)

    def _initiate_upload(self, index: int, subindex: int) -> bytes:
        self._check_rules(index, subindex, upload=True)
        entry = self._find(index, subindex)
        if not entry.readable:
            raise _SdoAbortError(ABORT_WRITE_ONLY)
        dyn = self._dynamic.get((index, subindex))
        data = (
            struct.pack("<" + dyn.fmt, _clamp(dyn.encode(self._state_now()), dyn.fmt))
            if dyn is not None
            else entry.data
        )
        if not data:
            raise _SdoAbortError(ABORT_NO_DATA)
        if len(data) <= 4:
            command = 0x43 | (4 - len(data)) << 2
            return struct.pack("<BHB", command, index, subindex) + data.ljust(4, b"\0")
        self._transfer = _Transfer(index, subindex, upload=True, data=bytearray(data))
        return struct.pack("<BHBI", 0x41, index, subindex, len(data))

    def _upload_segment(self, command: int) -> bytes:
        transfer = self._transfer
        if transfer is None or not transfer.upload:
            raise _SdoAbortError(ABORT_COMMAND)
        toggle = (command >> 4) & 1
        if toggle != transfer.toggle:
            raise _SdoAbortError(ABORT_TOGGLE)
        chunk, transfer.data = transfer.data[:7], transfer.data[7:]
        transfer.toggle ^= 1
        last = not transfer.data
        if last:
            self._transfer = None
        head = toggle << 4 | (7 - len(chunk)) << 1 | int(last)
        return bytes([head]) + bytes(chunk).ljust(7, b"\0")

    def _write(self, index: int, subindex: int, data: bytes) -> None:
        entry = self._find(index, subindex)
        if not entry.writable:
            raise _SdoAbortError(ABORT_READ_ONLY)
        size = entry.fixed_size
        if size is not None and len(data) != size:
            raise _SdoAbortError(ABORT_LENGTH_HIGH if len(data) > size else ABORT_LENGTH_LOW)
        if 0x1800 <= index <= 0x19FF and subindex == 1:
            old = self._int(index, 1, 0)
            new = struct.unpack("<I", data)[0]
            if not old & 0x80000000 and not new & 0x80000000 and (old ^ new) & 0x1FFFFFFF:
                raise _SdoAbortError(ABORT_VALUE_RANGE)  # a valid PDO keeps its COB-ID
        if 0x1A00 <= index <= 0x1BFF:
            self._check_mapping(index, subindex, data)
        entry.data = bytes(data)
        self.sdo_writes += 1
        if 0x1800 <= index <= 0x1BFF:
            self._plans = None

    def _check_mapping(self, index: int, subindex: int, data: bytes) -> None:
        cob = self._int(index - 0x200, 1, 0x80000000)
        if not cob & 0x80000000:
            raise _SdoAbortError(ABORT_UNSUPPORTED)  # change the mapping of a disabled PDO only
        if subindex != 0:
            if self._int(index, 0, 0) != 0:
                raise _SdoAbortError(ABORT_UNSUPPORTED)  # entries change while the count is 0
            return
        count = data[0]
        if count > 8:
            raise _SdoAbortError(ABORT_VALUE_RANGE)
        bits = 0
        for sub in range(1, count + 1):
            value = self._int(index, sub, 0)
            key = (value >> 16, (value >> 8) & 0xFF)
            target = self._entries.get(key)
            if target is None:
                raise _SdoAbortError(ABORT_NO_OBJECT)
            if not target.mappable:
                raise _SdoAbortError(ABORT_NOT_MAPPABLE)
            size = target.fixed_size
            if size is None or 8 * size != value & 0xFF:
                raise _SdoAbortError(ABORT_INCOMPATIBLE)
            bits += value & 0xFF
        if bits > 64:
            raise _SdoAbortError(ABORT_PDO_LENGTH)


class _SdoAbortError(Exception):
    def __init__(self, code: int) -> None:
        super().__init__(f"SDO abort 0x{code:08X}")
        self.code = code


def _make_drive(
    node_id: int, axis: int, object_map: ObjectMap, scaling: DriveScaling, eds: Path | None
) -> SimulatedDrive:
    if eds is not None:
        return SimulatedDrive.from_eds(eds, node_id, axis, object_map, scaling)
    return SimulatedDrive.builtin(node_id, axis, object_map, scaling)


class _AnsweringQueue(queue.Queue[can.Message]):
    """The drives' receive queue on python-can's virtual bus, answering SYNC as it is put.

    The virtual bus delivers a frame by putting a copy into every other bus'
    queue, one after the other, in the sender's thread. Kept behind every other
    queue of the channel (:class:`_DrivesLast`), this one receives the SYNC
    last and answers it at once: the answers reach the others after the SYNC
    and before the sender's next frame.
    """

    def __init__(self, host: SimulatedDrives) -> None:
        super().__init__()
        self.host = host

    def put(self, item: can.Message, block: bool = True, timeout: float | None = None) -> None:
        if (
            item.arbitration_id == 0x080
            and not item.is_extended_id
            and not item.is_remote_frame
            and not item.is_error_frame
        ):
            self.host._answer_on_send(item)
            return
        super().put(item, block, timeout)


class _DrivesLast(list[Any]):
    """A virtual channel's queues, with the drives' answering queues always last."""

    def append(self, item: Any) -> None:
        hooks = sum(isinstance(q, _AnsweringQueue) for q in self)
        self.insert(len(self) - hooks, item)


def _answer_on_the_bus(bus: can.BusABC, host: SimulatedDrives) -> None:
    """Give the drives' virtual bus a queue that answers SYNC as it is put (see above).

    Raises:
        ValueError: Not python-can's virtual bus, or other buses joined the channel
            first (their frames could not be kept ahead of the answers).
    """
    from can.interfaces import virtual

    if not isinstance(bus, virtual.VirtualBus):
        raise ValueError(
            "answering SYNC on the bus needs python-can's virtual bus; "
            f"this is {type(bus).__name__}"
        )
    with virtual.channels_lock:
        channel = bus.channel
        if len(channel) != 1 or channel[0] is not bus.queue:
            raise ValueError(
                "answering SYNC on the bus needs the drives to open the virtual channel "
                f"{bus.channel_id!r} first, before any other bus"
            )
        hook = _AnsweringQueue(host)
        ordered = _DrivesLast([hook])
        virtual.channels[bus.channel_id] = ordered
        bus.channel = ordered
        bus.queue = hook


class SimulatedDrives:
    """The simulated drives of a machine on one bus, served by one thread.

    Use :meth:`start` (a context manager) or :func:`serve`::

        with SimulatedDrives.start("test-bus", {0: 1, 1: 2}, PatternSource()) as drives:
            drives[1].stop_answering()

    Args:
        bus: The bus to serve on.
        drives: The drives, each with its own node id.
        source: Values of the axes.
        period_s: SYNC period used until the master writes 0x1006.
        own_bus: Shut the bus down on :meth:`stop`.
        clock: The link's :class:`~ncmeasure.samples.SimulatedClock`: answer in
            lockstep with it (every SYNC reported done). ``None``: real time.
        answer: ``thread``: the drives' thread answers SYNC as it receives it;
            ``on_send``: the SYNC's sender answers it within its ``send``
            (python-can's virtual bus only, the drives first on the channel).
    """

    def __init__(
        self,
        bus: can.BusABC,
        drives: Sequence[SimulatedDrive],
        source: SignalSource,
        *,
        period_s: float = 0.004,
        own_bus: bool = False,
        clock: SimulatedClock | None = None,
        answer: Literal["thread", "on_send"] = "thread",
    ) -> None:
        if not drives:
            raise ValueError("no drives to simulate")
        if answer == "on_send" and clock is not None:
            raise ValueError("answering SYNC on the bus is for real time, not lockstep")
        ids = [d.node_id for d in drives]
        if len(set(ids)) != len(ids):
            raise ValueError(f"node ids repeat: {ids}")
        self.bus = bus
        self.drives = tuple(drives)
        self.source = source
        self.period_s = period_s
        self.clock = clock
        self.frames_sent = 0
        """Frames sent on the bus so far (all kinds)."""
        self.late_answers = 0
        """SYNCs answered (their TPDOs sent) after the next SYNC was sent, by the time
        stamps python-can gives the frames: the host ran the drives' thread too late, as a
        real drive never is. The master then sees the frames after the next SYNC and drops
        that cycle (and may doubt the next): a stall of the host, not a fault of the master."""
        self._answered_at: float | None = None
        self.answer_cpu_s = 0.0
        """CPU time the senders' threads spent answering SYNC (``answer="on_send"``)."""
        self._answer = answer
        self._at_sync: dict[int, list[Callable[[], None]]] = {}
        self.started = time.monotonic()
        self._own_bus = own_bus
        self._by_node = {d.node_id: d for d in drives}
        self._sync_count = 0
        self._sync_index = -1
        self._sync_cond = threading.Condition()
        self._stop = threading.Event()
        self._send_lock = threading.Lock()
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._timer_ids = itertools.count()
        self._timer_lock = threading.Lock()
        for drive in drives:
            drive._host = self
        self._thread = threading.Thread(
            target=self._run, name="simulated-cia402-drives", daemon=True
        )

    @classmethod
    def start(
        cls,
        bus_or_channel: can.BusABC | str,
        nodes: Mapping[int, int],
        source: SignalSource | None = None,
        *,
        interface: str | None = "virtual",
        period_s: float = 0.004,
        eds: str | Path | Mapping[int, str | Path] | None = None,
        object_map: str | ObjectMap = "cia402",
        scaling: DriveScaling | Mapping[int, DriveScaling] | None = None,
        bus_options: Mapping[str, Any] | None = None,
        clock: SimulatedClock | None = None,
        answer: Literal["thread", "on_send"] = "thread",
    ) -> SimulatedDrives:
        """Create the drives, open the bus if a channel name is given, and start serving.

        Args:
            bus_or_channel: A python-can bus, or a channel name to open with ``interface``.
            nodes: ``{axis index: node id}``.
            source: Values of the axes (default :class:`PatternSource`).
            interface: python-can interface for a channel name.
            period_s: SYNC period until the master writes 0x1006.
            eds: EDS/DCF file for all drives, or per axis index; None = built-in CiA 402.
            object_map: Object map name/path, or a loaded map.
            scaling: For all drives, or per axis index.
            bus_options: Extra python-can arguments for a channel name.
            clock: The link's :class:`~ncmeasure.samples.SimulatedClock` (lockstep).
            answer: Who answers SYNC (see the class): ``thread`` or ``on_send``.
        """
        the_map = object_map if isinstance(object_map, ObjectMap) else load_object_map(object_map)
        drives = []
        for axis, node_id in nodes.items():
            axis_scaling = (
                scaling.get(axis, DriveScaling())
                if isinstance(scaling, Mapping)
                else (scaling or DriveScaling())
            )
            axis_eds = eds.get(axis) if isinstance(eds, Mapping) else eds
            drives.append(
                _make_drive(
                    node_id,
                    axis,
                    the_map,
                    axis_scaling,
                    Path(axis_eds) if axis_eds is not None else None,
                )
            )
        own = not isinstance(bus_or_channel, can.BusABC)
        if isinstance(bus_or_channel, can.BusABC):
            bus = bus_or_channel
        else:
            kwargs: dict[str, Any] = dict(bus_options or {})
            if interface is not None:
                kwargs["interface"] = interface
            bus = can.Bus(channel=bus_or_channel, **kwargs)
        drives_host = cls(
            bus,
            drives,
            source or PatternSource(),
            period_s=period_s,
            own_bus=own,
            clock=clock,
            answer=answer,
        )
        try:
            drives_host.run()
        except ValueError:
            if own:
                bus.shutdown()
            raise
        return drives_host

    def run(self) -> None:
        """Start serving in the background thread."""
        filters: list[can.typechecking.CanFilter] = [
            {"can_id": 0x000, "can_mask": 0x7FF, "extended": False},
            {"can_id": 0x080, "can_mask": 0x7FF, "extended": False},
            {"can_id": 0x600, "can_mask": 0x780, "extended": False},
        ]
        self.bus.set_filters(filters)
        if self._answer == "on_send":
            _answer_on_the_bus(self.bus, self)
        self._thread.start()

    def __getitem__(self, axis: int) -> SimulatedDrive:
        for drive in self.drives:
            if drive.axis == axis:
                return drive
        raise KeyError(axis)

    def node(self, node_id: int) -> SimulatedDrive:
        """The drive with node id ``node_id``."""
        return self._by_node[node_id]

    @property
    def sync_count(self) -> int:
        """SYNC messages seen since start."""
        return self._sync_count

    @property
    def sync_index(self) -> int:
        """Index of the newest SYNC (its sample time is index × period); -1 before the first."""
        return self._sync_index

    def at_sync(self, index: int, action: Callable[[], None]) -> None:
        """Run ``action`` when SYNC ``index`` arrives, before the drives answer it.

        A fault at a moment of simulated time, e.g.
        ``drives.at_sync(100, drives[1].stop_answering)``.
        """
        with self._sync_cond:
            self._at_sync.setdefault(index, []).append(action)

    def wait_for_sync(self, count: int, timeout_s: float) -> bool:
        """Wait until ``count`` SYNC messages were seen; False on timeout."""
        with self._sync_cond:
            return self._sync_cond.wait_for(lambda: self._sync_count >= count, timeout_s)

    def stop(self) -> None:
        """Stop serving (and shut the bus down if it was opened here). Idempotent."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        if self._own_bus:
            self._own_bus = False
            self.bus.shutdown()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # --- internals --------------------------------------------------------------------

    def _schedule(self, delay_s: float, action: Callable[[], None]) -> None:
        with self._timer_lock:
            heapq.heappush(
                self._timers, (time.monotonic() + delay_s, next(self._timer_ids), action)
            )

    def _send(self, can_id: int, data: bytes, delay_s: float = 0.0) -> None:
        if delay_s > 0:
            self._schedule(delay_s, lambda: self._send(can_id, data))
            return
        message = can.Message(arbitration_id=can_id, data=data, is_extended_id=False)
        try:
            with self._send_lock:
                self.bus.send(message)
                self.frames_sent += 1
        except can.CanError as exc:
            if not self._stop.is_set():
                log.warning("simulated drives: cannot send 0x%03X: %s", can_id, exc)

    def _run_timers(self) -> float:
        """Run due timers; return the time until the next one (at most 50 ms)."""
        while True:
            with self._timer_lock:
                if not self._timers:
                    return 0.05
                due, _, action = self._timers[0]
                wait = due - time.monotonic()
                if wait > 0:
                    return min(wait, 0.05)
                heapq.heappop(self._timers)
            action()

    def _run(self) -> None:
        while not self._stop.is_set():
            wait = self._run_timers()
            try:
                msg = self.bus.recv(wait)
            except (can.CanError, ValueError, OSError):
                if not self._stop.is_set():
                    log.exception("simulated drives: bus failed")
                return
            if msg is None or msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                continue
            can_id = msg.arbitration_id
            try:
                if can_id == 0x080:
                    answered = self._answered_at
                    if answered is not None and msg.timestamp and msg.timestamp < answered:
                        self.late_answers += 1  # the previous SYNC's answer came after this one
                    self._on_sync(bytes(msg.data))
                    self._answered_at = time.time()
                elif can_id == 0x000 and len(msg.data) >= 2:
                    for drive in self.drives:
                        if msg.data[1] in (0, drive.node_id):
                            drive._on_nmt(msg.data[0])
                elif 0x600 < can_id < 0x680:
                    target = self._by_node.get(can_id - 0x600)
                    if target is not None:
                        target._on_sdo(bytes(msg.data))
            except Exception:  # a simulator bug must not kill the bus for the others
                log.exception("simulated drives: frame 0x%03X not handled", can_id)

    def _answer_on_send(self, message: can.Message) -> None:
        """Answer a SYNC in its sender's thread (``answer="on_send"``)."""
        if self._stop.is_set():
            return
        start = time.thread_time()
        try:
            self._on_sync(bytes(message.data))
        except Exception:  # a simulator bug must not break the sender's send
            log.exception("simulated drives: SYNC not answered")
        self.answer_cpu_s += time.thread_time() - start

    def _on_sync(self, data: bytes = b"") -> None:
        with self._sync_cond:
            index = self._sync_index + 1
            if data and 1 <= data[0] <= _SYNC_COUNTER_MAX:
                index += (data[0] - 1 - index) % _SYNC_COUNTER_MAX
            self._sync_index = index
            self._sync_count += 1
            actions = self._at_sync.pop(index, [])
            self._sync_cond.notify_all()
        for action in actions:
            action()
        frames: list[tuple[int, bytes]] = []
        for drive in self.drives:
            frames += drive._on_sync(index, self.source)
        for can_id, data in frames:
            self._send(can_id, data)
        if self.clock is not None:
            with self._send_lock:
                sent = self.frames_sent
            self.clock.step_done(index, sent)


VIRTUAL_BUS_REACH = (
    "python-can's virtual bus reaches only this process: a `ncmeasure record` in another "
    "terminal cannot see these drives. For two processes use an interface that crosses them, "
    "e.g. --interface socketcan --channel vcan0 (a vcan device: `ip link add dev vcan0 type "
    "vcan && ip link set up vcan0`, as root) or --interface udp_multicast (needs msgpack)"
)
"""What to say when simulated drives serve on python-can's in-process ``virtual`` bus."""


def serve(
    *,
    channel: str | None,
    interface: str | None = "virtual",
    nodes: Sequence[int] | Mapping[int, int] = (1,),
    source: SignalSource | None = None,
    period_s: float = 0.004,
    eds: str | Path | None = None,
    object_map: str = "cia402",
    scaling: DriveScaling | None = None,
    bitrate: int | None = None,
    bus_options: Mapping[str, Any] | None = None,
    duration_s: float | None = None,
    stop: threading.Event | None = None,
    on_ready: Callable[[SimulatedDrives], None] | None = None,
) -> int:
    """Simulate drives on a bus until ``duration_s`` passed, ``stop`` is set or Ctrl-C.

    This is what ``ncmeasure simulate-drive --link canopen --interface I --channel C
    --node 1 --node 2 ...`` runs.

    Args:
        channel: python-can channel (``can0``, a virtual channel name, ...).
        interface: python-can interface; None lets python-can's configuration decide.
        nodes: Node ids, axis 0, 1, ... in order; or ``{axis index: node id}``.
        source: Values of the axes (default :class:`PatternSource`).
        period_s: SYNC period until the master writes 0x1006.
        eds: EDS/DCF file of the drives; None = built-in CiA 402 dictionary.
        object_map: Object map name or TOML path.
        scaling: Encoder, lead, rated current, velocity unit of every drive.
        bitrate: Bitrate for real interfaces.
        bus_options: Extra python-can arguments.
        duration_s: Stop after this long; None = until stopped.
        stop: Event that ends serving when set.
        on_ready: Called with the running drives (to print their node ids, ...).

    Returns:
        The number of SYNC messages served.

    Raises:
        ConfigError: python-can knows no such interface.
        LinkError: The interface cannot be opened.
    """
    mapping = dict(nodes) if isinstance(nodes, Mapping) else dict(enumerate(nodes))
    kwargs: dict[str, Any] = dict(bus_options or {})
    if interface is not None:
        kwargs["interface"] = interface
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    bus = open_bus(channel, kwargs, "--interface")
    try:
        drives = SimulatedDrives.start(
            bus, mapping, source, period_s=period_s, eds=eds, object_map=object_map, scaling=scaling
        )
    except BaseException:
        bus.shutdown()
        raise
    stop = stop or threading.Event()
    deadline = None if duration_s is None else time.monotonic() + duration_s
    try:
        if on_ready is not None:
            on_ready(drives)
        while not stop.is_set():
            remaining = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
            if remaining <= 0:
                break
            stop.wait(remaining)
    except KeyboardInterrupt:
        pass
    finally:
        drives.stop()
        bus.shutdown()
    return drives.sync_count
