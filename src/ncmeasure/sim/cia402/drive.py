"""One simulated CiA 402 drive: NMT, TPDOs on SYNC, the SDO server, fault switches.

A :class:`SimulatedDrive` has an object dictionary
(:class:`~ncmeasure.sim.cia402.dictionary.Dictionary`, from an EDS/DCF file or
the built-in CiA 402 defaults) and:

- answers SDO uploads and downloads (:class:`~ncmeasure.sim.cia402.sdo.SdoServer`);
- follows NMT (start, stop, pre-operational, reset node/communication with a
  boot-up message);
- on every SYNC, while operational, sends its valid synchronous TPDOs
  (transmission type 1..240) with values of a :class:`~ncmeasure.sim.signals.SignalSource`
  at time = SYNC index × period, encoded like a real drive (:class:`DriveScaling`).

The drives of a machine run on one bus in :class:`~ncmeasure.sim.cia402.drives.SimulatedDrives`.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from canopen.objectdictionary import ObjectDictionary, ODRecord, ODVariable

from ncmeasure.errors import ConfigError
from ncmeasure.formats.axis import StatedMechanics
from ncmeasure.links.canopen.objects import (
    SIGNAL_BY_ROLE,
    MapObject,
    ObjectMap,
    build_dictionary,
    load_eds,
    position_scale_mm,
    velocity_scale_mm_min,
)
from ncmeasure.sim.cia402.dictionary import INT_FORMATS, Dictionary, Entry, TpdoConfig, clamp
from ncmeasure.sim.cia402.sdo import ABORT_GENERAL, AbortRule, SdoServer
from ncmeasure.sim.rig import RIG_MECHANICS
from ncmeasure.sim.signals import AxisState, SignalSource

if TYPE_CHECKING:
    from ncmeasure.sim.cia402.drives import SimulatedDrives

__all__ = ["OPERATION_ENABLED", "DriveScaling", "SimulatedDrive"]

#: Statusword of a drive in "operation enabled" (ready, switched on, enabled,
#: voltage enabled, quick stop off, remote).
OPERATION_ENABLED = 0x0237
_FAULT_BIT = 0x0008

_PRE_OPERATIONAL, _OPERATIONAL, _STOPPED, _INITIALISING = 127, 5, 4, 0
_NMT_NAMES = {0: "INITIALISING", 4: "STOPPED", 5: "OPERATIONAL", 127: "PRE-OPERATIONAL"}


@dataclass(frozen=True)
class DriveScaling:
    """How a simulated drive turns an axis state into drive units.

    Attributes:
        mechanics: The axis the drive moves (default: the method's test rig,
            :data:`~ncmeasure.sim.rig.RIG_MECHANICS`); its lead and rated
            current must be stated.
        increments_per_rev: Encoder increments per motor revolution.
        gear_ratio: Motor revolutions per screw revolution.
        velocity_unit: The unit of the velocity objects (an object map unit).
        marker_input_bit: The bit of the digital inputs 0x60FD the program's
            marker (:attr:`AxisState.marker <ncmeasure.sim.signals.AxisState>`) is
            wired to: set while the marker is; None: nothing wired, all inputs 0.

    Raises:
        ConfigError: the mechanics state no lead or no rated current.
    """

    mechanics: StatedMechanics = RIG_MECHANICS
    increments_per_rev: int = 10_000
    gear_ratio: float = 1.0
    velocity_unit: str = "inc_per_s"
    marker_input_bit: int | None = None

    def __post_init__(self) -> None:
        missing = [
            f"{name}: a simulated CiA 402 drive needs it"
            for name in ("screw_lead_mm", "rated_current_a")
            if getattr(self.mechanics, name) is None
        ]
        if missing:
            raise ConfigError("invalid drive scaling", missing)

    @property
    def screw_lead_mm(self) -> float:
        """The mechanics' lead."""
        value = self.mechanics.screw_lead_mm
        assert value is not None  # stated: __post_init__ refuses None
        return value

    @property
    def rated_current_a(self) -> float:
        """The mechanics' rated current."""
        value = self.mechanics.rated_current_a
        assert value is not None  # stated: __post_init__ refuses None
        return value


@dataclass
class _Dynamic:
    """An object whose value comes from the signal source."""

    role: str
    unit: str
    fmt: str
    encode: Callable[[AxisState], float]
    """Value in drive units, before rounding and clamping to the type."""


@dataclass
class _Plan:
    """A valid synchronous TPDO, ready to pack."""

    cob_id: int
    every: int
    parts: list[_Part]
    counter: int = 0


@dataclass(frozen=True)
class _Part:
    """One mapped object of a TPDO: a value of the signal source, or the object's bytes."""

    key: tuple[int, int]
    size: int
    """Bytes in the TPDO."""
    code: str | None = None
    """The struct code of a value of the signal source (None: the object's bytes)."""
    encode: Callable[[AxisState], float] | None = None
    packer: struct.Struct | None = None


def _digital_outputs() -> ODRecord:
    """CiA 402 0x60FE digital outputs: sub 1 physical outputs, sub 2 bit mask."""
    record = ODRecord("digital outputs", 0x60FE)
    for subindex, name, data_type in (
        (0, "highest sub-index supported", 0x05),  # UNSIGNED8
        (1, "physical outputs", 0x07),  # UNSIGNED32
        (2, "bit mask", 0x07),
    ):
        var = ODVariable(name, 0x60FE, subindex)
        var.data_type = data_type
        var.access_type = "ro" if subindex == 0 else "rw"
        var.default = 2 if subindex == 0 else 0
        var.pdo_mappable = subindex == 1
        record.add_member(var)
    return record


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
        self._od = Dictionary(dictionary)
        self._set_rated_current(object_map.rated_current)
        self._dynamic = self._dynamic_objects()
        # The server writes through self._write, looked up at each write (tests wrap it).
        self._sdo = SdoServer(
            self._od.find, self._upload_data, lambda i, s, data: self._write(i, s, data)
        )
        self._nmt = _PRE_OPERATIONAL
        self._answering = True
        self._down_until = 0.0
        self._slow_s = 0.0
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
        ``ncmeasure apply-compensation`` writes, and the digital outputs 0x60FE (sub 1
        physical outputs, sub 2 bit mask; UNSIGNED32, read-write, 0), which hold the
        recorder's ready output a link writes (:meth:`value`).
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
        if 0x60FE not in od:
            od.add_object(_digital_outputs())
        return cls(node_id, axis, od, object_map, scaling)

    def _set_rated_current(self, obj: MapObject | None) -> None:
        milliamps = round(self.scaling.rated_current_a * 1000)
        for key in [(0x6075, 0)] + ([(obj.index, obj.subindex)] if obj else []):
            self._od.set_default(key, milliamps)

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
            ("digital_inputs", "bits"): self._digital_inputs,
        }
        dynamic: dict[tuple[int, int], _Dynamic] = {}
        for role in (*SIGNAL_BY_ROLE, "statusword"):
            obj = self.object_map.role(role)
            while obj is not None:
                key = (obj.index, obj.subindex)
                entry = self._od.defaults.get(key)
                code = INT_FORMATS.get(entry.data_type) if entry else None
                if entry is not None and code is not None and key not in dynamic:
                    if role == "statusword":
                        dynamic[key] = _Dynamic(role, obj.unit, code, self._statusword)
                    else:
                        dynamic[key] = _Dynamic(role, obj.unit, code, encoders[(role, obj.unit)])
                obj = obj.fallback
        return dynamic

    def _statusword(self, state: AxisState) -> float:
        return self._status

    def _digital_inputs(self, state: AxisState) -> float:
        bit = self.scaling.marker_input_bit
        return float(1 << bit) if bit is not None and state.marker > 0 else 0.0

    # --- fault switches ---------------------------------------------------------------

    def stop_answering(self) -> None:
        """Go silent: no SDO answers, no PDOs, NMT ignored (SYNC is still counted)."""
        with self._lock:
            self._answering = False

    def resume(self) -> None:
        """Answer again, and clear :meth:`abort_sdo` rules and :meth:`slow`."""
        with self._lock:
            self._answering = True
            self._sdo.rules.clear()
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
            self._sdo.rules.append(AbortRule(index, subindex, code, upload, download))

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
            return self._od.entries[(index, subindex)].data

    def tpdos(self) -> list[TpdoConfig]:
        """The TPDOs of the dictionary as they are now."""
        with self._lock:
            return self._od.tpdos()

    # --- internals (called with the host's thread) --------------------------------------

    def _reset(self, communication_only: bool) -> None:
        self._od.reset(communication_only)
        self._sdo.reset()
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
        cycle_us = self._od.int_value(0x1006, 0, 0)
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
            entries = self._od.entries
            for plan in due:
                parts = []
                for part in plan.parts:
                    if part.encode is not None and part.packer is not None and part.code:
                        parts.append(part.packer.pack(clamp(part.encode(state), part.code)))
                    else:
                        parts.append(entries[part.key].data[: part.size].ljust(part.size, b"\0"))
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
            parts: list[_Part] = []
            for index, sub, bits in config.mapping:
                entry = self._od.entries.get((index, sub))
                code = INT_FORMATS.get(entry.data_type) if entry else None
                size = bits // 8
                if code is not None and struct.calcsize("<" + code) != size:
                    code = None
                dyn = self._dynamic.get((index, sub))
                if dyn is not None and code is not None:
                    packer = struct.Struct("<" + code)
                    parts.append(_Part((index, sub), size, code, dyn.encode, packer))
                else:
                    parts.append(_Part((index, sub), size))
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
            response = self._sdo.answer(request)
            delay = self._slow_s
        if response is not None and self._host is not None:
            self._host._send(0x580 + self.node_id, response, delay)

    def _upload_data(self, index: int, subindex: int, entry: Entry) -> bytes:
        """What an upload returns: a dynamic object's value now, else the stored bytes."""
        dyn = self._dynamic.get((index, subindex))
        if dyn is None:
            return entry.data
        return struct.pack("<" + dyn.fmt, clamp(dyn.encode(self._state_now()), dyn.fmt))

    def _write(self, index: int, subindex: int, data: bytes) -> None:
        """An SDO download: the dictionary's rules, then the TPDOs planned again."""
        self._od.write(index, subindex, data)
        self.sdo_writes += 1
        if 0x1800 <= index <= 0x1BFF:
            self._plans = None
