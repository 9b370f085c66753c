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
:class:`CycleAssembler` keyed by SYNC cycle (a dict from COB-ID to slot, not
canopen's PDO objects, so no frame is lost to a PDO map holding only its last
frame); their bytes are decoded in bulk, a block at a time, and the reader is
woken per block of ``READ_BLOCK_S`` of rows, not per row. Cycles that stay
incomplete are dropped, never filled with invented or NaN values, and reported
as ``gap`` events with ``lost_samples``; EMCY messages, reboots (boot-up, after
which the node's PDOs are configured again), SDO fallbacks and drive faults are
events too. Without a complete cycle for ``max_outage_s`` the link gives up; a
failing bus or an outage raises :class:`~ncmeasure.errors.LinkError` from
:meth:`~CanOpenLink.read`.
"""

from __future__ import annotations

import collections
import contextlib
import copy
import functools
import logging
import math
import queue
import struct
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal, cast

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError, OutputError
from ncmeasure.links.base import AxisBinding, AxisLinkSettings, DriveLink, LinkSettings, PathSetting
from ncmeasure.links.canopen.bus import open_bus
from ncmeasure.links.canopen.busload import BusLoad, bus_load
from ncmeasure.links.canopen.objects import (
    DATA_TYPES,
    SIGNAL_BY_ROLE,
    TYPE_BY_CODE,
    DataTypeName,
    MapObject,
    ObjectMap,
    VelocityUnit,
    build_dictionary,
    emcy_text,
    load_eds,
    load_object_map,
    od_variable,
    position_scale_mm,
    sdo_error_text,
    velocity_scale_mm_min,
)
from ncmeasure.links.canopen.sync import CycleAssembler, LostCycle, run_sync_schedule
from ncmeasure.samples import SIGNAL_UNITS, Channel, LinkEvent, SampleBlock, SimulatedClock

__all__ = [
    "CanOpenAxis",
    "CanOpenLink",
    "CanOpenSettings",
]

log = logging.getLogger(__name__)

# --- settings ---------------------------------------------------------------------------

_RAW_LOG_SUFFIXES = (".blf", ".asc", ".log", ".csv", ".trc")
_RESERVED_BUS_OPTIONS = {"interface", "channel", "bitrate", "receive_own_messages"}


class CanOpenSettings(LinkSettings):
    """The ``[link]`` table of a machine recorded over CANopen."""

    interface: str | None = Field(
        default="virtual",
        description="python-can interface (socketcan, pcan, kvaser, vector, virtual, ...); "
        "empty/None lets python-can's own configuration file decide.",
    )
    channel: str | None = Field(
        default=None, description="Interface channel, e.g. can0 or PCAN_USBBUS1."
    )
    bitrate: int = Field(default=1_000_000, gt=0, le=1_000_000, description="Bit/s.")
    sync_hz: float = Field(default=250.0, gt=0, le=10_000, description="SYNC rate in Hz.")
    eds: PathSetting | None = Field(
        default=None, description="EDS/DCF file describing the drives (all nodes)."
    )
    object_map: str = Field(
        default="cia402",
        description="Built-in object map (cia402, maxon_epos4) or the path of a TOML map.",
    )
    listen_only: bool = Field(
        default=False,
        description="Only listen: no SDO, NMT or SYNC of the link's own. The controller "
        "owns the bus and the drives' PDO mapping; the link takes the layout from the "
        "drives' DCF (link.eds) or the axes' tpdo tables, and a row per SYNC seen on the bus.",
    )
    sync_producer: bool = Field(
        default=True,
        description="Produce SYNC; false when the controller or another master produces it.",
    )
    nmt_control: bool = Field(
        default=True,
        description="Send NMT pre-operational/start to the nodes; false when another "
        "master owns their NMT state.",
    )
    sdo_timeout_s: float = Field(default=0.5, gt=0, le=30, description="SDO answer timeout.")
    max_outage_s: float = Field(
        default=10.0,
        gt=0,
        le=3600,
        description="Give up after this long (link time) without a complete SYNC cycle.",
    )
    max_bus_load: float = Field(
        default=0.9,
        gt=0,
        le=10,
        description="Refuse a TPDO layout whose worst-case bus load exceeds this fraction.",
    )
    raw_log: PathSetting | None = Field(
        default=None,
        description="Also log every CAN frame to this file (.blf, .asc, .log, .csv, .trc).",
    )
    bus_options: dict[str, Any] = Field(
        default_factory=dict, description="Extra keyword arguments for python-can's Bus."
    )

    @field_validator("interface")
    @classmethod
    def _empty_interface(cls, value: str | None) -> str | None:
        return value or None

    @field_validator("raw_log")
    @classmethod
    def _check_raw_log(cls, value: Path | None) -> Path | None:
        if value is not None and value.suffix.lower() not in _RAW_LOG_SUFFIXES:
            raise ValueError(f"must end in one of {', '.join(_RAW_LOG_SUFFIXES)}")
        return value

    @field_validator("bus_options")
    @classmethod
    def _check_bus_options(cls, value: dict[str, Any]) -> dict[str, Any]:
        clash = sorted(_RESERVED_BUS_OPTIONS & set(value))
        if clash:
            raise ValueError(f"set {', '.join(clash)} as link settings, not in bus_options")
        return value

    @model_validator(mode="after")
    def _check_listen_only(self) -> CanOpenSettings:
        if not self.listen_only:
            return self
        for key in ("sync_producer", "nmt_control"):
            if key in self.model_fields_set and getattr(self, key):
                raise ValueError(f"listen_only: the link sends nothing, so {key} must be false")
        return self

    @property
    def produces_sync(self) -> bool:
        """True when the link sends SYNC itself."""
        return self.sync_producer and not self.listen_only

    @property
    def controls_nmt(self) -> bool:
        """True when the link sends NMT commands."""
        return self.nmt_control and not self.listen_only


class TpdoTable(BaseModel):
    """One TPDO as the controller configured it: for a link that only listens."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    cob_id: int = Field(ge=0x181, le=0x7FF, description="COB-ID of the TPDO, e.g. 0x181.")
    mapping: list[int] = Field(
        min_length=1,
        max_length=8,
        description="The mapping entries as in the drive's 0x1A00+n: index << 16 | "
        "sub-index << 8 | bits, e.g. 0x60640020 for 0x6064:00, 32 bits.",
    )

    @field_validator("mapping")
    @classmethod
    def _check_mapping(cls, value: list[int]) -> list[int]:
        for entry in value:
            bits = entry & 0xFF
            if not 0 <= entry <= 0xFFFFFFFF or bits == 0 or bits % 8:
                raise ValueError(f"0x{entry:08X} is no mapping entry (index, sub-index, bits)")
        if sum((entry & 0xFF) // 8 for entry in value) > 8:
            raise ValueError("the entries need more than the 8 bytes of a PDO")
        return value


class CanOpenAxis(AxisLinkSettings):
    """The ``link`` table of an axis recorded over CANopen."""

    node_id: int = Field(ge=1, le=127, description="CANopen node id of the axis' drive.")
    increments_per_rev: int = Field(
        gt=0, description="Position increments per motor revolution (0x6064 units)."
    )
    gear_ratio: float = Field(
        default=1.0, gt=0, description="Motor revolutions per ball-screw revolution."
    )
    velocity_unit: VelocityUnit | None = Field(
        default=None,
        description="Unit of 0x606C/0x606B: inc_per_s, rpm, 0.1rpm, 0.01rpm, 0.001rpm. "
        "Default: the object map's (cia402: inc_per_s, maxon_epos4: rpm).",
    )
    rated_current_a: float | None = Field(
        default=None,
        gt=0,
        description="Motor rated current in A for per-mille currents. Default: the axis' "
        "rated_current_a, else read from the drive (0x6075).",
    )
    eds: PathSetting | None = Field(
        default=None, description="EDS/DCF of this node (overrides link.eds)."
    )
    read_velocity_demand: bool = Field(
        default=False, description="Also read the velocity demand value (0x606B)."
    )
    first_tpdo: int = Field(
        default=1,
        ge=1,
        le=508,
        description="First TPDO number the link may configure (1 = 0x1800/0x1A00); raise it "
        "when the controller uses the first TPDOs itself.",
    )
    tpdo: list[TpdoTable] | None = Field(
        default=None,
        max_length=512,
        description="listen_only: the drive's TPDOs as the controller configured them "
        "(default: from its DCF).",
    )


# --- the link ----------------------------------------------------------------------------

_COB_INVALID = 0x80000000
_COB_NO_RTR = 0x40000000
_COB_EXTENDED = 0x20000000
_ABSENT_CODES = frozenset({0x06020000, 0x06090011})  # object / sub-index does not exist
_STATUS_FAULT = 0x0008


_STATUS_COLUMN = -1
_UNREAD = -2


@dataclass
class _Field:
    role: str
    """A role of the object map; empty for mapped bytes the link does not read."""
    obj: MapObject | None
    column: int  # _STATUS_COLUMN: statusword; _UNREAD: not read
    unread_bytes: int = 0

    @property
    def size(self) -> int:
        return self.obj.size if self.obj is not None else self.unread_bytes

    @property
    def np_type(self) -> str:
        return _NP_TYPES[self.obj.type] if self.obj is not None else f"V{self.unread_bytes}"


@dataclass
class _Slot:
    """One TPDO of one node."""

    axis: _Axis
    number: int  # TPDO number, 1-based
    fields: list[_Field]
    cob_id: int = 0
    dtype: np.dtype[Any] = field(default_factory=lambda: np.dtype([]))

    @property
    def size(self) -> int:
        return sum(f.size for f in self.fields)

    def update_dtype(self) -> None:
        self.dtype = np.dtype(
            {
                "names": [f"f{k}" for k in range(len(self.fields))],
                "formats": [f.np_type for f in self.fields],
            }
        )


_NP_TYPES: Mapping[str, str] = {
    "int8": "<i1",
    "int16": "<i2",
    "int32": "<i4",
    "uint8": "<u1",
    "uint16": "<u2",
    "uint32": "<u4",
}


@dataclass
class _Axis:
    """Everything the link knows about one axis' drive."""

    position: int  # index in the machine file
    name: str
    settings: CanOpenAxis
    screw_lead_mm: float
    configured_rated_current_a: float | None
    eds: Path | None
    od: ObjectDictionary
    objects: dict[str, MapObject]
    velocity_unit: str
    columns: dict[str, int]
    notes: list[str] = field(default_factory=list)
    slots: list[_Slot] = field(default_factory=list)
    rated_current_a: float | None = None
    scales: dict[str, float] = field(default_factory=dict)
    node: canopen.RemoteNode | None = None
    sdo_lock: threading.Lock = field(default_factory=threading.Lock)
    faulted: bool = False

    @property
    def node_id(self) -> int:
        return self.settings.node_id

    @property
    def who(self) -> str:
        return f"node {self.node_id} (axis {self.name})"


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
        self._map = load_object_map(settings.object_map)
        self._axes: list[_Axis] = []
        self._channels: tuple[Channel, ...] = ()
        self._resolve_axes()
        self._slots = [slot for axis in self._axes for slot in axis.slots]
        # run-time state
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._bus: can.BusABC | None = None
        self._network: canopen.Network | None = None
        self._threads: list[threading.Thread] = []
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue()
        self._assembler = self._new_assembler()
        self._cycle = -1
        """The newest SYNC cycle seen on the bus (own SYNCs through the receive stream)."""
        self._sent: collections.deque[int] = collections.deque()
        """Cycles of own SYNCs sent and not yet seen back, in order."""
        self._sent_cycle = -1
        self._t0 = 0.0
        """Clock time of SYNC cycle 0."""
        self._received = 0
        """Frames of others received (lockstep: all the simulated drives sent must be here)."""
        self._reconfiguring = 0
        self._offline = False
        self._polled_cycle = -1
        self._last_row_cycle = -1
        self._last_sync_time: float | None = None
        self._ready: list[tuple[int, list[bytes]]] = []
        self._gap: _GapRun | None = None
        self._failure: LinkError | None = None
        self._mode: Literal["pdo", "sdo_polling"] = "pdo"
        self._streaming = False
        self._stats = {
            "sync_cycles": 0,
            "rows": 0,
            "lost_rows": 0,
            "lost_no_sync": 0,
            "bad_frames": 0,
            "sdo_polls": 0,
            "sync_skipped": 0,
        }
        self._bad_slots: set[int] = set()
        self._wake_rows = 1
        self._plan: tuple[list[_Slot], np.dtype[Any], list[tuple[str, _Axis, _Field]]] | None = None
        self._pdo_frames = 0
        """The reader is woken when this many rows are ready (set at open)."""
        self._sync_message = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)

    # --- configuration --------------------------------------------------------------

    def _resolve_axes(self) -> None:
        problems: list[str] = []
        used: dict[int, str] = {}
        channels: list[Channel] = []
        eds_cache: dict[tuple[Path, int], ObjectDictionary] = {}
        for position, binding in enumerate(self.axes):
            axis_settings = cast(CanOpenAxis, binding.settings)
            where = f"axes[{position}]"
            if axis_settings.node_id in used:
                problems.append(
                    f"{where}.link.node_id: node {axis_settings.node_id} is "
                    f"already used by axis {used[axis_settings.node_id]}"
                )
            used[axis_settings.node_id] = binding.name
            lead = binding.axis.screw_lead_mm
            if lead is None:
                problems.append(
                    f"{where}.screw_lead_mm: needed by the canopen link to convert increments to mm"
                )
                lead = 1.0
            eds = axis_settings.eds or self.settings.eds
            eds_where = f"{where}.link.eds" if axis_settings.eds else "link.eds"
            try:
                if eds is not None:
                    key = (eds, axis_settings.node_id)
                    if key not in eds_cache:
                        eds_cache[key] = load_eds(eds, axis_settings.node_id)
                    od = eds_cache[key]
                else:
                    od = build_dictionary(self._map, axis_settings.node_id)
            except ConfigError as exc:
                problems.append(f"{eds_where}: {exc}")
                continue
            roles: list[str] = ["position", "velocity", "current"]
            if self._map.statusword is not None:
                roles.insert(0, "statusword")
            if axis_settings.read_velocity_demand:
                if self._map.velocity_demand is None:
                    problems.append(
                        f"{where}.link.read_velocity_demand: object map "
                        f"{self._map.name} has no velocity demand object"
                    )
                    continue
                roles.append("velocity_demand")
            objects: dict[str, MapObject] = {}
            notes: list[str] = []
            for role in roles:
                wanted = cast(MapObject, self._map.role(role))
                chosen = wanted if eds is None else self._from_eds(wanted, od, eds, notes)
                if chosen is None:
                    if role == "statusword":
                        notes.append(
                            f"{eds} has no {wanted.label}: drive faults are reported by EMCY only"
                        )
                        continue
                    options = [wanted.label]
                    if wanted.fallback is not None:
                        options.append(wanted.fallback.label)
                    problems.append(
                        f"{eds_where}: {eds} has no {' and no '.join(options)}; "
                        "choose another object_map"
                    )
                    continue
                objects[role] = chosen
            configured: list[_ConfiguredTpdo] = []
            if self.settings.listen_only:
                configured = self._configured_tpdos(axis_settings, od, eds, where, problems)
                objects = _roles_mapped(configured, self._map, od)
                missing = [r for r in ("position", "velocity", "current") if r not in objects]
                if missing:
                    problems.append(
                        f"{where}.link: the drive's TPDOs as configured "
                        f"({_tpdo_source(axis_settings, eds)}) carry no "
                        f"{', '.join(missing)} object; listen_only reads what the controller "
                        "maps and cannot map more"
                    )
                    continue
            signals = ["current_a", "velocity_mm_min", "position_mm"]
            if "velocity_demand" in objects:
                signals.append("velocity_cmd_mm_min")
            columns = {s: len(channels) + k for k, s in enumerate(signals)}
            channels += [Channel(binding.name, s, SIGNAL_UNITS[s]) for s in signals]
            axis = _Axis(
                position=position,
                name=binding.name,
                settings=axis_settings,
                screw_lead_mm=lead,
                configured_rated_current_a=(
                    axis_settings.rated_current_a or binding.axis.rated_current_a
                ),
                eds=eds,
                od=od,
                objects=objects,
                velocity_unit=axis_settings.velocity_unit or self._map.velocity_unit,
                columns=columns,
                notes=notes,
            )
            if self.settings.listen_only:
                self._passive_layout(axis, configured)
                self._rated_current_without_sdo(axis, where, problems)
                self._axes.append(axis)
                continue
            self._layout(axis)
            for slot in axis.slots:
                comm, mapping = 0x1800 + slot.number - 1, 0x1A00 + slot.number - 1
                if eds is not None and (comm not in od or mapping not in od):
                    problems.append(
                        f"{eds_where}: {eds} has no TPDO{slot.number} "
                        f"(0x{comm:04X}/0x{mapping:04X}); lower "
                        f"{where}.link.first_tpdo"
                    )
            self._axes.append(axis)
        if problems:
            raise ConfigError(
                "the settings of the canopen link are not valid", list(dict.fromkeys(problems))
            )
        self._channels = tuple(channels)

    def _from_eds(
        self, wanted: MapObject, od: ObjectDictionary, eds: Path, notes: list[str]
    ) -> MapObject | None:
        obj: MapObject | None = wanted
        while obj is not None:
            var = od_variable(od, obj.index, obj.subindex)
            if var is not None:
                chosen = obj
                type_name = TYPE_BY_CODE.get(var.data_type or 0)
                if type_name is not None and type_name != obj.type:
                    notes.append(
                        f"{eds} gives {obj.label} as {type_name}, not {obj.type}; using the EDS"
                    )
                    chosen = obj.with_type(cast(DataTypeName, type_name))
                if obj is not wanted:
                    notes.append(
                        f"{eds} has no {wanted.label}: reading {obj.label} instead "
                        f"({_unit_text(obj.unit)})"
                    )
                return chosen
            obj = obj.fallback
        return None

    def _configured_tpdos(
        self,
        axis_settings: CanOpenAxis,
        od: ObjectDictionary,
        eds: Path | None,
        where: str,
        problems: list[str],
    ) -> list[_ConfiguredTpdo]:
        """listen_only: the TPDOs the controller configured, from the tpdo table or the DCF."""
        if axis_settings.tpdo is not None:
            return [
                _ConfiguredTpdo(number, table.cob_id, 1, list(table.mapping))
                for number, table in enumerate(axis_settings.tpdo, start=1)
            ]
        if eds is None:
            problems.append(
                f"{where}.link: listen_only needs the drive's TPDO layout as the controller "
                "configured it: its DCF (link.eds) or "
                f"{where}.link.tpdo = [{{ cob_id = 0x181, mapping = [0x60640020, ...] }}]"
            )
            return []
        found = []
        for number in range(1, 513):
            tpdo = _dcf_tpdo(od, number)
            if tpdo is not None:
                found.append(tpdo)
        for tpdo in found:
            if _roles_mapped([tpdo], self._map, od) and tpdo.transmission_type != 1:
                problems.append(
                    f"{where}.link.eds: {eds}: TPDO{tpdo.number} (0x{tpdo.cob_id:03X}) has "
                    f"transmission type {tpdo.transmission_type}; a row per SYNC needs 1 "
                    "(sent on every SYNC)"
                )
        return found

    def _rated_current_without_sdo(self, axis: _Axis, where: str, problems: list[str]) -> None:
        """Rated current and scales when the drive cannot be asked: configured, else the DCF's."""
        axis.rated_current_a = axis.configured_rated_current_a
        needs = any(o.unit.startswith("permille") for o in axis.objects.values())
        if needs and axis.rated_current_a is None:
            obj = self._map.rated_current
            value = _od_value(axis.od, obj.index, obj.subindex) if obj and axis.eds else None
            if obj is None or not value or value <= 0:
                label = f" or a DCF with its {obj.label}" if obj is not None else ""
                problems.append(
                    f"{where}.rated_current_a: the current comes in per mille of the rated "
                    f"current, and without SDO the drive cannot be asked: set it{label}"
                )
                return
            axis.rated_current_a = value / 1000.0
            axis.notes.append(f"rated current {value / 1000:g} A from {axis.eds} ({obj.label})")
        self._set_scales(axis)

    def _passive_layout(self, axis: _Axis, configured: list[_ConfiguredTpdo]) -> None:
        """The slots of the TPDOs that carry an object the link reads, as configured."""
        axis.slots = []
        for tpdo in configured:
            fields: list[_Field] = []
            for entry in tpdo.mapping:
                index, subindex, size = entry >> 16, (entry >> 8) & 0xFF, (entry & 0xFF) // 8
                role = next(
                    (
                        r
                        for r, o in axis.objects.items()
                        if (o.index, o.subindex) == (index, subindex)
                    ),
                    "",
                )
                if role:
                    obj = axis.objects[role]
                    column = axis.columns.get(SIGNAL_BY_ROLE.get(role, ""), _STATUS_COLUMN)
                    fields.append(_Field(role, obj, column))
                else:
                    fields.append(_Field("", None, _UNREAD, size))
            if any(f.role for f in fields):
                slot = _Slot(axis, tpdo.number, fields, cob_id=tpdo.cob_id)
                slot.update_dtype()
                axis.slots.append(slot)

    def _layout(self, axis: _Axis) -> None:
        """Pack the axis' objects into TPDOs following the map's layout."""
        groups: list[list[str]] = []
        for group in self._map.tpdo.layout:
            roles = [r for r in group if r in axis.objects]
            size = 0
            current: list[str] = []
            for role in roles:  # an EDS with larger types may need another PDO
                n = axis.objects[role].size
                if current and size + n > 8:
                    groups.append(current)
                    current, size = [], 0
                current.append(role)
                size += n
            if current:
                groups.append(current)
        axis.slots = []
        for k, slot_roles in enumerate(groups):
            fields = [
                _Field(r, axis.objects[r], axis.columns.get(SIGNAL_BY_ROLE.get(r, ""), -1))
                for r in slot_roles
            ]
            slot = _Slot(axis, axis.settings.first_tpdo + k, fields)
            slot.update_dtype()
            axis.slots.append(slot)

    # --- the DriveLink contract ------------------------------------------------------

    @property
    def channels(self) -> tuple[Channel, ...]:
        return self._channels

    @property
    def nominal_period_s(self) -> float:
        return self._period

    def _new_assembler(self) -> CycleAssembler:
        """An assembler for the current slots; a node's slots keep their order."""
        return CycleAssembler(
            max(1, len(self._slots)), [slot.axis.position for slot in self._slots] or [0]
        )

    def now_s(self) -> float | None:
        """The link time now: the newest SYNC's (lockstep), else the clock since streaming."""
        if not self._streaming:
            return None
        if self.clock.lockstep:
            return max(self._sent_cycle, 0) * self._period
        return self.clock.now() - self._t0

    @property
    def mode(self) -> str:
        """``pdo`` (TPDOs on SYNC) or ``sdo_polling`` (the fallback)."""
        return self._mode

    def planned_bus_load(self) -> BusLoad:
        """Bus load of the TPDO layout plus SYNC (whoever produces it) at ``sync_hz``."""
        return bus_load(
            [slot.size for slot in self._slots],
            self.settings.sync_hz,
            self.settings.bitrate,
        )

    def statistics(self) -> dict[str, int]:
        """Counters since open: PDO frames, SYNC cycles, rows, lost rows, SDO polls, ...

        ``lost_rows`` counts every cycle without a row; ``lost_no_sync`` those of them
        that had no SYNC on the bus (skipped by the producer, ``sync_skipped``, once
        their next SYNC was seen; or missed polls).
        """
        with self._lock:
            stats = dict(self._stats)
            stats["pdo_frames"] = self._pdo_frames
            stats["early_frames"] = self._assembler.early_frames
        return stats

    def describe(self) -> dict[str, Any]:
        info = super().describe()
        load = self.planned_bus_load()
        info["mode"] = self._mode
        info["object_map"] = self._map.name
        info["bus_load"] = {
            "nominal": load.load,
            "worst_case": load.worst_load,
            "bits_per_cycle": load.bits_per_cycle,
            "worst_bits_per_cycle": load.worst_bits_per_cycle,
        }
        scales: dict[str, Any] = {}
        for axis in self._axes:
            scales[axis.name] = {
                "node_id": axis.node_id,
                "objects": {
                    role: {
                        "index": f"0x{o.index:04X}",
                        "subindex": o.subindex,
                        "type": o.type,
                        "unit": o.unit,
                    }
                    for role, o in axis.objects.items()
                },
                "tpdos": [
                    {
                        "number": s.number,
                        "cob_id": f"0x{s.cob_id:03X}",
                        "roles": [f.role for f in s.fields],
                    }
                    for s in axis.slots
                ],
                "velocity_unit": axis.velocity_unit,
                "rated_current_a": axis.rated_current_a,
                "position_mm_per_increment": self._position_scale(axis),
                "velocity_mm_min_per_unit": self._velocity_scale(axis),
                "current_a_per_unit": axis.scales.get("current"),
            }
        info["scales"] = scales
        return info

    # --- open ------------------------------------------------------------------------

    def _open(self) -> None:
        if not self.settings.listen_only:  # listening, the controller's layout is what it is
            self._check_load(self.planned_bus_load())
        self._assembler = self._new_assembler()
        self._bus = self._make_bus()
        network = canopen.Network(self._bus)
        network.NOTIFIER_CYCLE = 0.1  # bounds how long close() waits for the receive thread
        self._network = network
        if self.settings.raw_log is not None:
            writer = self._make_logger(self.settings.raw_log)
            network.listeners.append(cast(Any, _RawLog(self, writer, self.settings.raw_log)))
        receiver = _Receiver(self, network.listeners[0])
        network.listeners[0] = cast(Any, receiver)  # PDOs and own SYNCs first, the rest to canopen
        network.connect()
        worker = threading.Thread(target=self._work, name="canopen-link-worker", daemon=True)
        worker.start()
        self._threads.append(worker)
        for axis in self._axes:
            node = canopen.RemoteNode(axis.node_id, axis.od)
            node.sdo.RESPONSE_TIMEOUT = self.settings.sdo_timeout_s
            network.add_node(node)
            axis.node = node
            node.emcy.add_callback(functools.partial(self._on_emcy, axis))
            node.nmt.add_heartbeat_callback(functools.partial(self._on_heartbeat, axis))
        if self.settings.listen_only:
            for axis in self._axes:
                self._report_notes(axis)
        else:
            self._configure_drives()
        if self._mode == "pdo":
            receiver.pdos = {slot.cob_id: (i, slot.size) for i, slot in enumerate(self._slots)}
            receiver.frame = self._assembler.frame
        if self._mode == "pdo" and not self.clock.lockstep:
            self._wake_rows = max(1, round(self.READ_BLOCK_S * self._rate_hz))
        else:  # lockstep and SDO polling wait for every cycle
            self._wake_rows = 0
        self._t0 = self.clock.now()
        self._streaming = True
        if self._mode == "sdo_polling":
            self._start_thread(self._poll, "canopen-link-poll")
        if self.settings.produces_sync:
            self._start_thread(self._produce_sync, "canopen-link-sync")
            self._await_own_sync()
        else:
            network.subscribe(0x80, self._on_sync_frame)

    def _configure_drives(self) -> None:
        """The master's part: read the objects, map the TPDOs, start the nodes (SDO, NMT)."""
        for axis in self._axes:
            self._prepare(axis)
        self._check_load(self.planned_bus_load())  # objects may have changed to fallbacks
        for axis in self._axes:
            try:
                self._map_tpdos(axis)
            except SdoAbortedError as exc:
                self._fall_back_to_polling(axis, exc)
                break
        for axis in self._axes:
            self._start_node(axis)

    def _report_notes(self, axis: _Axis) -> None:
        for note in axis.notes:
            self._event(LinkEvent(0.0, "info", f"{axis.who}: {note}", axis=axis.name))

    def _await_own_sync(self) -> None:
        """The first own SYNC must come back through the receive stream (bus order)."""
        with self._cond:
            seen = self._cond.wait_for(
                lambda: self._cycle >= 0 or self._failure is not None, self.ECHO_TIMEOUT_S
            )
        self._check_failure()
        if not seen:
            raise LinkError(
                f"the CAN interface {self.settings.interface or '(python-can config)'} does not "
                "return the link's own SYNC frames (python-can receive_own_messages); the link "
                "needs them to give every PDO to its SYNC cycle. Use an interface that does "
                "(socketcan, pcan, kvaser, vector, ixxat, virtual, ...), or let the controller "
                "produce SYNC (link.sync_producer = false)"
            )

    def _start_thread(self, target: Callable[[], None], name: str) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    def _check_load(self, load: BusLoad) -> None:
        limit = self.settings.max_bus_load
        if load.worst_load <= limit:
            return
        raise ConfigError(
            f"the TPDO layout would load the CAN bus too much: {load.describe()}, above "
            f"max_bus_load {100 * limit:g} %",
            [
                f"link.sync_hz: lower it to at most {math.floor(load.max_sync_hz(limit))} Hz, "
                "or read fewer objects (read_velocity_demand = false), or raise the bitrate"
            ],
        )

    def _make_bus(self) -> can.BusABC:
        s = self.settings
        kwargs: dict[str, Any] = dict(s.bus_options)
        if s.interface is not None:
            kwargs["interface"] = s.interface
        kwargs["bitrate"] = s.bitrate
        if s.produces_sync or s.raw_log is not None:
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

    def _sdo_up(self, axis: _Axis, obj_index: int, subindex: int) -> bytes:
        assert axis.node is not None
        with axis.sdo_lock:
            return bytes(axis.node.sdo.upload(obj_index, subindex))

    def _sdo_down(self, axis: _Axis, obj_index: int, subindex: int, data: bytes) -> None:
        assert axis.node is not None
        with axis.sdo_lock:
            axis.node.sdo.download(obj_index, subindex, data)

    def _sdo_failure(self, axis: _Axis, what: str, exc: Exception) -> LinkError:
        text = f"{axis.who}: {what} failed: {sdo_error_text(exc, self.settings.sdo_timeout_s)}"
        if isinstance(exc, SdoCommunicationError):
            return LinkTimeoutError(text + "; check the node id, bitrate and wiring")
        return LinkError(text)

    def _nmt(self, axis: _Axis, state: str) -> None:
        if self.settings.controls_nmt and axis.node is not None:
            axis.node.nmt.state = state

    def _prepare(self, axis: _Axis) -> None:
        """Pre-operational, read every object once (fallbacks), rated current, cycle period."""
        self._nmt(axis, "PRE-OPERATIONAL")
        for role in list(axis.objects):
            obj: MapObject | None = axis.objects[role]
            while obj is not None:
                try:
                    self._sdo_up(axis, obj.index, obj.subindex)
                except SdoAbortedError as exc:
                    if exc.code in _ABSENT_CODES and obj.fallback is not None:
                        axis.notes.append(
                            f"drive has no {obj.label} ({sdo_error_text(exc)}): reading "
                            f"{obj.fallback.label} instead ({_unit_text(obj.fallback.unit)})"
                        )
                        obj = obj.fallback
                        continue
                    if role == "statusword":
                        axis.notes.append(
                            f"cannot read {obj.label} ({sdo_error_text(exc)}): "
                            "drive faults are reported by EMCY only"
                        )
                        obj = None
                        break
                    raise self._sdo_failure(axis, f"reading {obj.label}", exc) from exc
                except SdoCommunicationError as exc:
                    raise self._sdo_failure(axis, f"reading {obj.label}", exc) from exc
                break
            if obj is None:
                del axis.objects[role]
            else:
                axis.objects[role] = obj
        self._layout(axis)
        self._slots = [slot for a in self._axes for slot in a.slots]
        self._assembler = self._new_assembler()
        self._read_rated_current(axis)
        self._set_scales(axis)
        if self.settings.produces_sync:
            try:  # lets the drive monitor the SYNC; optional for the measurement
                self._sdo_down(axis, 0x1006, 0, struct.pack("<I", self._period_us))
            except (SdoAbortedError, SdoCommunicationError) as exc:
                log.info("%s: 0x1006 not written (%s)", axis.who, sdo_error_text(exc))
        self._report_notes(axis)

    def _read_rated_current(self, axis: _Axis) -> None:
        needs = any(o.unit.startswith("permille") for o in axis.objects.values())
        axis.rated_current_a = axis.configured_rated_current_a
        if not needs or axis.rated_current_a is not None:
            return
        obj = self._map.rated_current
        if obj is None:
            raise LinkError(
                f"{axis.who}: the current is in per mille of the rated current; "
                f"set axes[{axis.position}].link.rated_current_a (object map "
                f"{self._map.name} names no rated current object)"
            )
        try:
            raw = self._sdo_up(axis, obj.index, obj.subindex)
        except (SdoAbortedError, SdoCommunicationError) as exc:
            error = self._sdo_failure(axis, f"reading the {obj.label}", exc)
            raise type(error)(f"{error}; set axes[{axis.position}].link.rated_current_a") from exc
        value = _decode_int(raw, obj.type)
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

    def _position_scale(self, axis: _Axis) -> float:
        return position_scale_mm(
            axis.settings.increments_per_rev, axis.screw_lead_mm, axis.settings.gear_ratio
        )

    def _velocity_scale(self, axis: _Axis) -> float:
        return velocity_scale_mm_min(
            axis.velocity_unit,
            axis.settings.increments_per_rev,
            axis.screw_lead_mm,
            axis.settings.gear_ratio,
        )

    def _set_scales(self, axis: _Axis) -> None:
        axis.scales = {
            "position": self._position_scale(axis),
            "velocity": self._velocity_scale(axis),
            "velocity_demand": self._velocity_scale(axis),
        }
        current = axis.objects["current"]
        if current.unit == "mA":
            axis.scales["current"] = 1e-3
        else:
            assert axis.rated_current_a is not None
            axis.scales["current"] = axis.rated_current_a / 1000.0

    def _tpdo_cob_id(self, axis: _Axis, slot: _Slot) -> tuple[int, int]:
        """COB-ID to use (from the drive, else the predefined one) and the RTR bit."""
        comm = 0x1800 + slot.number - 1
        raw = _decode_int(self._sdo_up(axis, comm, 1), "uint32")
        cob_id = raw & 0x7FF
        taken = {s.cob_id for s in self._slots if s is not slot and s.cob_id}
        if raw & _COB_EXTENDED or not 0x180 <= cob_id <= 0x57F or cob_id in taken:
            if slot.number > 4:
                raise LinkError(
                    f"{axis.who}: TPDO{slot.number} has no usable COB-ID "
                    f"(0x{raw:08X}); set one in the drive or lower first_tpdo"
                )
            cob_id = 0x180 + 0x100 * (slot.number - 1) + axis.node_id
        return cob_id, raw & _COB_NO_RTR

    def _map_tpdos(self, axis: _Axis) -> None:
        """Write the TPDO configuration (CiA 301 order: disable, type, map, enable)."""
        for slot in axis.slots:
            comm, mapping = 0x1800 + slot.number - 1, 0x1A00 + slot.number - 1
            try:
                cob_id, rtr = self._tpdo_cob_id(axis, slot)
                cob_id = slot.cob_id or cob_id  # after a reboot: the COB-ID subscribed to
                self._sdo_down(axis, comm, 1, struct.pack("<I", cob_id | rtr | _COB_INVALID))
                self._sdo_down(axis, comm, 2, struct.pack("<B", 1))
                # the inhibit time is optional and irrelevant for synchronous PDOs
                with contextlib.suppress(SdoAbortedError):
                    self._sdo_down(axis, comm, 3, struct.pack("<H", 0))
                self._sdo_down(axis, mapping, 0, struct.pack("<B", 0))
                for k, f in enumerate(slot.fields, start=1):
                    assert f.obj is not None  # the link's own layout reads every byte
                    entry = f.obj.index << 16 | f.obj.subindex << 8 | 8 * f.obj.size
                    self._sdo_down(axis, mapping, k, struct.pack("<I", entry))
                self._sdo_down(axis, mapping, 0, struct.pack("<B", len(slot.fields)))
                self._sdo_down(axis, comm, 1, struct.pack("<I", cob_id | rtr))
            except SdoCommunicationError as exc:
                raise self._sdo_failure(axis, f"configuring TPDO{slot.number}", exc) from exc
            except SdoAbortedError as exc:
                exc.add_note(f"{axis.who}: configuring TPDO{slot.number}")
                raise
            slot.cob_id = cob_id

    def _fall_back_to_polling(self, failed: _Axis, exc: SdoAbortedError) -> None:
        where = " ".join(getattr(exc, "__notes__", [])) or failed.who
        self._mode = "sdo_polling"
        for axis in self._axes:  # switch off what was already configured
            for slot in axis.slots:
                if slot.cob_id:
                    invalid = struct.pack("<I", slot.cob_id | _COB_INVALID)
                    with contextlib.suppress(SdoAbortedError, SdoCommunicationError):
                        self._sdo_down(axis, 0x1800 + slot.number - 1, 1, invalid)
        self._event(
            LinkEvent(
                0.0,
                "info",
                f"{where}: the drive refused the PDO mapping ({sdo_error_text(exc)}); falling "
                f"back to SDO polling of the same objects on all axes, at most one poll per "
                f"SYNC cycle ({self.settings.sync_hz:g} Hz) and as fast as the drives answer",
                axis=failed.name,
                details={"abort_code": exc.code},
            )
        )

    def _start_node(self, axis: _Axis) -> None:
        self._nmt(axis, "OPERATIONAL")

    # --- callbacks (notifier thread) ---------------------------------------------------

    def _on_pdo(self, index: int, size: int, data: bytearray) -> None:
        """A PDO frame of slot ``index``, in bus order (receive thread only, no lock).

        The frame's bytes are kept as they are and decoded in bulk, a block at a time
        (:meth:`_decode`). Frames go into the assembler without the lock: only the
        thread that receives the bus feeds it; rows leave it under the lock when a SYNC
        finishes a cycle (:meth:`_advance`).
        """
        self._pdo_frames += 1  # only this thread writes it
        if len(data) < size:
            with self._lock:
                self._bad_frame(index, self._slots[index], len(data))
            return
        self._assembler.frame(index, bytes(data) if len(data) == size else bytes(data[:size]))

    def _bad_frame(self, index: int, slot: _Slot, length: int) -> None:
        self._stats["bad_frames"] += 1
        if index not in self._bad_slots:
            self._bad_slots.add(index)
            self._event(
                LinkEvent(
                    self._cycle_time(),
                    "fault",
                    f"{slot.axis.who}: TPDO{slot.number} (0x{slot.cob_id:03X}) carries {length} "
                    f"bytes, the mapping needs {slot.size}; such frames are dropped",
                    axis=slot.axis.name,
                )
            )

    def _on_emcy(self, axis: _Axis, entry: EmcyError) -> None:
        data = bytes(entry.data).rstrip(b"\0")
        extra = f", data {data.hex(' ')}" if data else ""
        meaning = emcy_text(entry.code)
        self._event(
            LinkEvent(
                self._cycle_time(),
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
        )

    def _on_heartbeat(self, axis: _Axis, state: int) -> None:
        if state != 0 or not self._streaming:
            return
        if self.settings.listen_only or self._offline:
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
            self._reconfiguring += 1  # lockstep: no SYNC until the drive is configured again
        self._jobs.put(lambda: self._reconfigure(axis))

    def _on_sync_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """SYNC of another master: count cycles, notice missing ones by their timestamps."""
        wall_period = self.clock.wall(self._period)  # frame timestamps are wall-clock
        with self._cond:
            if self._last_sync_time is None:
                step = 1
            else:
                step = max(1, round((timestamp - self._last_sync_time) / wall_period))
            self._last_sync_time = timestamp
            self._advance(self._cycle + step)

    def _on_own_sync(self) -> None:
        """An own SYNC came back through the receive stream: its cycle starts now, in bus order."""
        with self._lock:  # the condition's lock
            if self._sent:
                self._advance(self._sent.popleft())

    def _advance(self, cycle: int) -> None:
        """SYNC cycle ``cycle`` was seen on the bus; caller holds the lock."""
        skipped = cycle - self._cycle - 1
        if self._mode == "pdo":
            self._assembler.sync(cycle)
        elif skipped > 0 and self._cycle >= 0:
            self._lost_polls(self._cycle + 1, skipped, "")
        first = self._cycle < 0
        self._cycle = cycle
        self._stats["sync_cycles"] += 1
        self._settle()
        # The reader wakes per block of rows; lockstep and SDO polling wait for every cycle.
        if first or len(self._ready) >= self._wake_rows:
            self._cond.notify_all()

    def _cycle_time(self) -> float:
        return max(self._cycle, 0) * self._period

    # --- SYNC producer, polling, worker (own threads) ------------------------------------

    def _produce_sync(self) -> None:
        """Send SYNC cycle k at ``k × period`` on the link clock (real time or lockstep)."""
        try:
            if self.clock.lockstep:
                self._produce_in_lockstep()
            else:
                self._produce_in_real_time()
        except LinkError as exc:
            self._fail(exc)

    def _send_sync(self, cycle: int) -> None:
        network = self._network
        assert network is not None and network.bus is not None
        # Not under the link's lock: the receive thread holds it while it assembles
        # frames, and on a busy host a SYNC waiting for it came late and was skipped.
        # A deque's append is atomic, and it comes before the send, so the receive
        # thread finds the cycle when it sees the SYNC.
        self._sent.append(cycle)
        self._sent_cycle = cycle
        try:
            with network.send_lock:  # SDO transfers of the worker share the bus
                network.bus.send(self._sync_message)
        except Exception as exc:
            raise LinkError(f"cannot send SYNC: {exc}") from exc

    def _skip_sync(self, first: int, count: int) -> None:
        """The producer skipped ``count`` cycles from ``first``; they become a gap (no_sync)."""
        with self._lock:
            self._stats["sync_skipped"] += count

    def _produce_in_real_time(self) -> None:
        """SYNC k at ``k × period`` of the clock; a stall skips cycles (counted), never a burst.

        The skipped cycles have no SYNC on the bus, so they come out as a ``gap`` event
        ("SYNC cycles not sent (the host fell behind)") with their number.
        """
        clock = self.clock
        self._t0 = clock.now()
        run_sync_schedule(
            self._period,
            clock.now,
            lambda delay: self._stop.wait(clock.wall(delay)),
            self._send_sync,
            self._skip_sync,
        )

    def _produce_in_lockstep(self) -> None:
        """SYNC k at simulated time k × period; SYNC k + 1 once all of cycle k is received.

        The simulated drives report each SYNC answered and how many frames they sent
        (:meth:`~ncmeasure.samples.SimulatedClock.step_done`); the next SYNC waits until
        the link has received them all, until no drive is being configured again, and
        until the reader has taken the rows, so the recording does not depend on how fast
        the threads run.
        """
        clock = cast(SimulatedClock, self.clock)
        cycle = 0
        while not self._stop.is_set():
            clock.advance_to(cycle * self._period)
            self._send_sync(cycle)
            sent = self._wait_for_drives(clock, cycle)
            if sent is None:
                return
            with self._cond:
                ready = self._cond.wait_for(
                    functools.partial(self._cycle_received, cycle, sent), self.STEP_TIMEOUT_S
                )
            if not ready:
                raise LinkError(
                    f"SYNC cycle {cycle}: the simulated drives' frames did not arrive within "
                    f"{self.STEP_TIMEOUT_S:g} s"
                )
            cycle += 1

    def _wait_for_drives(self, clock: SimulatedClock, cycle: int) -> int | None:
        """The simulated drives' frame count after answering ``cycle``; None when stopping."""
        deadline = time.monotonic() + self.STEP_TIMEOUT_S
        while not self._stop.is_set():
            sent = clock.wait_step(cycle, 0.1)
            if sent is not None:
                return sent
            if time.monotonic() > deadline:
                raise LinkError(
                    f"the simulated drives did not answer SYNC cycle {cycle} within "
                    f"{self.STEP_TIMEOUT_S:g} s; a link on a SimulatedClock needs simulated "
                    "drives on the same clock (SimulatedDrives.start(..., clock=clock))"
                )
        return None

    def _cycle_received(self, cycle: int, sent: int) -> bool:
        """Lockstep: everything of ``cycle`` is in, and the next SYNC may go out."""
        if self._stop.is_set() or self._failure is not None:
            return True
        return (
            self._cycle >= cycle
            and self._received >= sent
            and self._reconfiguring == 0
            and (self._mode == "pdo" or self._polled_cycle >= cycle)
            and len(self._ready) < self.MAX_READY_ROWS
        )

    def _poll(self) -> None:
        """The fallback: read every slot's objects over SDO once per SYNC cycle, at most."""
        last = -1
        while not self._stop.is_set():
            with self._cond:
                self._cond.wait_for(functools.partial(self._new_cycle, last), 0.2)
                cycle = self._cycle
            if self._stop.is_set():
                return
            if cycle == last or cycle < 0:
                continue
            last = cycle
            try:
                row = [
                    b"".join(self._poll_field(slot.axis, f) for f in slot.fields)
                    for slot in self._slots
                ]
            except (SdoAbortedError, SdoCommunicationError) as exc:
                with self._cond:
                    self._lost_polls(
                        cycle,
                        1,
                        f"SDO polling failed: {sdo_error_text(exc, self.settings.sdo_timeout_s)}",
                    )
                    self._polled_cycle = cycle
                    self._cond.notify_all()
                continue
            with self._cond:
                self._stats["sdo_polls"] += 1
                self._ready.append((cycle, row))
                self._last_row_cycle = cycle
                self._polled_cycle = cycle
                self._close_gap()
                self._cond.notify_all()

    def _new_cycle(self, last: int) -> bool:
        return self._cycle != last or self._stop.is_set()

    def _poll_field(self, axis: _Axis, f: _Field) -> bytes:
        if f.obj is None:
            return bytes(f.unread_bytes)
        raw = self._sdo_up(axis, f.obj.index, f.obj.subindex)
        return _fit(raw, f.obj)

    def _work(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            try:
                job()
            except Exception:
                log.exception("canopen link: background job failed")

    def _reconfigure(self, axis: _Axis) -> None:
        try:
            self._configure_again(axis)
        finally:
            with self._cond:
                self._reconfiguring -= 1
                self._cond.notify_all()

    def _configure_again(self, axis: _Axis) -> None:
        if self._stop.is_set():
            return
        errors: list[str] = []
        for _attempt in range(3):
            try:
                if self._mode == "pdo":
                    self._map_tpdos(axis)
                if self.settings.produces_sync:
                    period_us = struct.pack("<I", self._period_us)
                    with contextlib.suppress(SdoAbortedError):
                        self._sdo_down(axis, 0x1006, 0, period_us)
                self._start_node(axis)
            except (LinkError, SdoAbortedError, SdoCommunicationError) as exc:
                errors.append(sdo_error_text(exc) if not isinstance(exc, LinkError) else str(exc))
                if self._stop.wait(0.2):
                    return
                continue
            self._event(
                LinkEvent(
                    self._cycle_time(),
                    "info",
                    f"{axis.who}: configured again after the reboot; data continues",
                    axis=axis.name,
                )
            )
            return
        self._event(
            LinkEvent(
                self._cycle_time(),
                "fault",
                f"{axis.who}: cannot configure the drive again after its "
                f"reboot ({errors[-1]}); its data stays missing",
                axis=axis.name,
            )
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
        self._prepare_offline()
        handlers = {slot.cob_id: (i, slot.size) for i, slot in enumerate(self._slots)}
        nodes = {axis.node_id: axis for axis in self._axes}
        for msg in messages:
            if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                continue
            can_id, data = msg.arbitration_id, msg.data
            if can_id == 0x80:
                self._on_sync_frame(can_id, data, msg.timestamp)
            elif can_id in handlers:
                self._on_pdo(*handlers[can_id], data)
            elif 0x81 <= can_id <= 0xFF and can_id - 0x80 in nodes and len(data) >= 3:
                code, register = int.from_bytes(data[:2], "little"), data[2]
                entry = EmcyError(code, register, bytes(data[3:8]), msg.timestamp)
                self._on_emcy(nodes[can_id - 0x80], entry)
            elif 0x701 <= can_id <= 0x77F and can_id - 0x700 in nodes and data[:1] == b"\0":
                self._on_heartbeat(nodes[can_id - 0x700], 0)
            if len(self._ready) >= block_rows:
                yield self._take_block(), self.events()
        with self._cond:
            self._settle()
            self._close_gap()
        yield self._take_block(), self.events()

    def _prepare_offline(self) -> None:
        problems: list[str] = []
        for axis in self._axes:
            where = f"axes[{axis.position}]"
            if axis.rated_current_a is None and not axis.scales:
                self._rated_current_without_sdo(axis, where, problems)
            for slot in axis.slots:
                if slot.cob_id:
                    continue
                if slot.number > 4:
                    problems.append(
                        f"{where}.link.first_tpdo: TPDO{slot.number} has no predefined COB-ID; "
                        "the log cannot tell which frames are its"
                    )
                slot.cob_id = 0x180 + 0x100 * (slot.number - 1) + axis.node_id
            self._report_notes(axis)
        if problems:
            raise ConfigError("the CAN log cannot be decoded with these link settings", problems)
        self._assembler = self._new_assembler()
        self._offline = True
        self._streaming = True

    def _take_block(self) -> SampleBlock:
        with self._cond:
            rows, self._ready = self._ready, []
            self._stats["rows"] += len(rows)
        return self._decode(rows) if rows else self.empty_block()

    # --- rows, gaps -------------------------------------------------------------------

    def _settle(self) -> None:
        """Move final rows to the ready list, account lost cycles; caller holds the lock."""
        if self._mode != "pdo":
            return
        rows, lost = self._assembler.take()
        if not lost:  # the usual case: complete cycles only
            if rows:
                if self._gap is not None:
                    self._close_gap()
                self._ready.extend(rows)
                self._last_row_cycle = rows[-1][0]
            return
        events: list[tuple[int, list[bytes]] | LostCycle] = [*rows, *lost]
        events.sort(key=lambda item: item.cycle if isinstance(item, LostCycle) else item[0])
        for item in events:
            if isinstance(item, LostCycle):
                self._lose(item, "")
            else:
                self._close_gap()
                self._ready.append(item)
                self._last_row_cycle = item[0]

    def _lose(self, lost: LostCycle, reason: str) -> None:
        gap = self._gap
        report_cycles = max(1, math.ceil(self.GAP_REPORT_S * self._rate_hz))
        if gap is not None and (
            lost.cycle != gap.last + 1
            or gap.last - gap.first + 1 >= report_cycles
            or gap.reason != reason
        ):
            self._close_gap()
            gap = None
        if gap is None:
            gap = self._gap = _GapRun(first=lost.cycle, last=lost.cycle, reason=reason)
        gap.last = lost.cycle
        gap.count += 1
        axes = {self._slots[i].axis.position for i in lost.missing if i < len(self._slots)}
        if lost.reason == "no_sync":
            gap.no_sync += 1
            self._stats["lost_no_sync"] += 1
        elif lost.reason == "doubled":
            gap.doubled += 1
            gap.doubled_slots |= set(lost.missing)
        else:
            gap.axes |= axes
        self._stats["lost_rows"] += 1

    def _lost_polls(self, first: int, count: int, reason: str) -> None:
        everything = frozenset(range(len(self._slots)))
        for cycle in range(first, first + count):
            self._lose(LostCycle(cycle, everything, "no_sync" if not reason else "missing"), reason)

    def _close_gap(self) -> None:
        gap, self._gap = self._gap, None
        if gap is None:
            return
        axes = [self._axes[i] for i in sorted(gap.axes)]
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
            slots = [self._slots[i] for i in sorted(gap.doubled_slots)]
            late = ", ".join(f"{slot.axis.who} TPDO{slot.number}" for slot in slots)
            reasons.append(
                f"{gap.doubled} cycles with two frames of one TPDO ({late}: a drive answered "
                "a cycle late), so their cycles cannot be told apart"
            )
        if gap.no_sync and self.settings.produces_sync:
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
                    "doubled": gap.doubled,
                },
            )
        )

    def _read(self, timeout_s: float) -> SampleBlock | None:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                self._check_failure()
                self._check_outage()
                if self._ready:
                    rows, self._ready = self._ready, []
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return self.empty_block()
                self._cond.wait(min(remaining, 0.05))
            self._stats["rows"] += len(rows)
        return self._decode(rows)

    def _check_outage(self) -> None:
        """Give up after ``max_outage_s`` of link time without a complete cycle (lock held)."""
        now = self.now_s()
        if now is None:
            return
        since = max(self._last_row_cycle, 0) * self._period
        limit = self.settings.max_outage_s
        if now - since < limit:
            return
        gap = self._gap
        why = ""
        if gap is not None and gap.axes:
            names = ", ".join(self._axes[i].name for i in sorted(gap.axes))
            why = f": no PDOs from axis {names}"
        elif self._cycle < 0 or self._cycle * self._period < since + limit / 2:
            why = ": no SYNC seen on the bus"
        self._close_gap()
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

    def _decode(self, rows: list[tuple[int, list[bytes]]]) -> SampleBlock:
        n = len(rows)
        cycles = np.fromiter((c for c, _ in rows), dtype=np.float64, count=n)
        time_s = cycles / self._rate_hz
        values = np.empty((n, len(self._channels)), dtype=np.float64)
        row_dtype, fields = self._decode_plan()
        # One buffer and one structured view for the whole block: a row is its slots' bytes.
        block = np.frombuffer(b"".join([b"".join(r) for _, r in rows]), dtype=row_dtype)
        for name, axis, f in fields:
            if f.column >= 0:
                np.multiply(block[name], axis.scales[f.role], out=values[:, f.column])
            else:
                self._check_status(axis, block[name], time_s)
        return SampleBlock(time_s, values)

    def _decode_plan(self) -> tuple[np.dtype[Any], list[tuple[str, _Axis, _Field]]]:
        """The dtype of a row (all slots' bytes in order) and the fields to take from it."""
        if self._plan is not None and self._plan[0] is self._slots:
            return self._plan[1], self._plan[2]
        names: list[str] = []
        formats: list[str] = []
        offsets: list[int] = []
        fields: list[tuple[str, _Axis, _Field]] = []
        offset = 0
        for index, slot in enumerate(self._slots):
            for k, f in enumerate(slot.fields):
                name = f"s{index}f{k}"
                names.append(name)
                formats.append(f.np_type)
                offsets.append(offset)
                offset += f.size
                if f.column >= 0 or f.column == _STATUS_COLUMN:
                    fields.append((name, slot.axis, f))
        row_dtype: np.dtype[Any] = np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": offset}
        )
        self._plan = (self._slots, row_dtype, fields)
        return row_dtype, fields

    def _check_status(
        self, axis: _Axis, statusword: NDArray[Any], time_s: NDArray[np.float64]
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

    # --- close --------------------------------------------------------------------------

    def _close(self) -> None:
        self._stop.set()
        self._jobs.put(None)
        with self._cond:
            self._cond.notify_all()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self._threads = []
        network = self._network
        if network is not None and network.bus is not None:
            for axis in self._axes:
                try:
                    self._nmt(axis, "PRE-OPERATIONAL")
                except Exception as exc:  # closing never raises
                    log.info("%s: NMT pre-operational not sent (%s)", axis.who, exc)
        with self._cond:
            try:
                self._settle()
            except Exception:
                log.exception("canopen link: settling at close failed")
            self._close_gap()
        if network is not None:
            try:
                network.disconnect()
            except Exception as exc:
                log.info("canopen link: network shutdown: %s", exc)
        elif self._bus is not None:
            try:
                self._bus.shutdown()
            except Exception as exc:
                log.info("canopen link: bus shutdown: %s", exc)
        self._network = None
        self._bus = None


@dataclass(frozen=True)
class _ConfiguredTpdo:
    number: int
    cob_id: int
    transmission_type: int
    mapping: list[int]


def _od_value(od: ObjectDictionary, index: int, subindex: int) -> int | None:
    """A DCF's configured value (ParameterValue), else the EDS default; None when absent."""
    var = od_variable(od, index, subindex)
    if var is None:
        return None
    value = var.value if var.value is not None else var.default
    return value if isinstance(value, int) else None


def _dcf_tpdo(od: ObjectDictionary, number: int) -> _ConfiguredTpdo | None:
    """TPDO ``number`` of a DCF/EDS when it is valid and fully mapped, else None."""
    comm, mapping = 0x1800 + number - 1, 0x1A00 + number - 1
    cob_id = _od_value(od, comm, 1)
    count = _od_value(od, mapping, 0)
    if cob_id is None or cob_id & _COB_INVALID or not count:
        return None
    entries = [_od_value(od, mapping, k) for k in range(1, count + 1)]
    if any(entry is None for entry in entries):
        return None
    transmission = _od_value(od, comm, 2)
    return _ConfiguredTpdo(
        number,
        cob_id & 0x7FF,
        255 if transmission is None else transmission,
        entries,  # type: ignore[arg-type]
    )


def _roles_mapped(
    configured: Sequence[_ConfiguredTpdo], object_map: ObjectMap, od: ObjectDictionary
) -> dict[str, MapObject]:
    """The roles whose object (or a fallback) the TPDOs map, with the mapped size's type."""
    mapped = {
        (entry >> 16, (entry >> 8) & 0xFF): (entry & 0xFF) // 8
        for tpdo in configured
        for entry in tpdo.mapping
    }
    found: dict[str, MapObject] = {}
    for role in ("statusword", "position", "velocity", "velocity_demand", "current"):
        obj = object_map.role(role)
        while obj is not None:
            size = mapped.get((obj.index, obj.subindex))
            if size is not None:
                found[role] = obj if obj.size == size else obj.with_type(_sized(obj, size, od))
                break
            obj = obj.fallback
    return found


def _sized(obj: MapObject, size: int, od: ObjectDictionary) -> DataTypeName:
    """The object's type as the mapping says its size: the EDS's, else the map's signedness."""
    var = od_variable(od, obj.index, obj.subindex)
    eds_type = TYPE_BY_CODE.get(var.data_type or 0) if var is not None else None
    if (
        eds_type is not None
        and DATA_TYPES[eds_type][1]
        and struct.calcsize("<" + DATA_TYPES[eds_type][1]) == size
    ):
        return cast(DataTypeName, eds_type)
    signed = obj.type.startswith("int")
    return cast(DataTypeName, f"{'int' if signed else 'uint'}{8 * size}")


def _tpdo_source(axis_settings: CanOpenAxis, eds: Path | None) -> str:
    return "the link.tpdo table" if axis_settings.tpdo is not None else f"DCF {eds}"


def _log_channel(channel: Any) -> Any:
    """The channel as the log writers can store it: one bus, so a number only if it fits.

    python-can's writers number a channel by the last digits of its name (``can0`` is
    channel 0), and BLF keeps a 16-bit number: a name such as ``bus-90770`` would fail
    every frame. Such a channel is logged as the writer's default channel.
    """
    number = can.util.channel2int(channel)
    if number is None or 0 <= number < 0xFFFF:
        return channel
    return None


class _RawLog(can.Listener):
    """The raw frame log; a writer that fails stops logging, never the measurement.

    In lockstep the frames are stamped with the simulated time (from the wall-clock
    time the log started): the log is of the simulated bus, in the machine's time, so
    that a SYNC every period shows as one, as on a real bus.
    """

    def __init__(self, link: CanOpenLink, writer: can.Listener, path: Path) -> None:
        self._link = link
        self._writer = writer
        self._path = path
        self._failed = False
        self._epoch = time.time()

    def on_message_received(self, msg: can.Message) -> None:
        if self._failed:
            return
        clock = self._link.clock
        msg = copy.copy(msg)
        msg.channel = _log_channel(msg.channel)
        if clock.lockstep:
            msg.timestamp = self._epoch + clock.now()
        try:
            self._writer.on_message_received(msg)
        except Exception as exc:  # python-can writers raise struct.error, OSError, ...
            self._failed = True
            self._link._event(
                LinkEvent(
                    self._link._cycle_time(),
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


class _Receiver(can.Listener):
    """The first listener of the receive thread: PDOs and own SYNCs here, the rest to canopen.

    PDO frames go straight to the link's cycle assembler (a dict from COB-ID to
    slot, no canopen PDO machinery per frame); an own SYNC starts its cycle
    exactly between the PDOs received before and after it (bus order). Every
    other frame (SDO, EMCY, heartbeat, another master's SYNC) goes on to
    canopen's own listener. Frames of others are counted (lockstep: all the
    simulated drives sent must be in), and a failing bus becomes a LinkError
    for read().
    """

    def __init__(self, link: CanOpenLink, canopen_listener: can.Listener) -> None:
        self._link = link
        self._canopen = canopen_listener
        self._lockstep = link.clock.lockstep  # the clock cannot change while the link is open
        self.pdos: dict[int, tuple[int, int]] = {}
        """COB-ID -> (slot index, mapped bytes); set once the TPDOs are configured."""
        self.frame: Callable[[int, bytes], None] = link._assembler.frame
        """The assembler's frame method (set with :attr:`pdos`)."""

    def on_message_received(self, msg: can.Message) -> None:
        # This runs for 9000 PDOs a second and more: the usual frame is handled inline.
        link = self._link
        if msg.is_rx:
            slot = self.pdos.get(msg.arbitration_id)
            if slot is not None and not (
                msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame
            ):
                data = msg.data
                if len(data) == slot[1]:
                    link._pdo_frames += 1  # only this thread writes it
                    self.frame(slot[0], bytes(data))
                else:
                    link._on_pdo(slot[0], slot[1], data)
            else:
                self._canopen.on_message_received(msg)
            if self._lockstep:  # all the simulated drives sent must be in before the next SYNC
                with link._cond:
                    link._received += 1
                    link._cond.notify_all()
            return
        if msg.arbitration_id == 0x80 and not msg.is_extended_id:
            link._on_own_sync()  # nothing of canopen's listens to the master's own SYNC
            return
        self._canopen.on_message_received(msg)

    def on_error(self, exc: Exception) -> None:
        self._link._fail(LinkError(f"CAN bus error: {exc}"))

    def stop(self) -> None:
        self._canopen.stop()


def _decode_int(raw: bytes, type_name: str) -> int:
    code = DATA_TYPES[type_name][1]
    size = struct.calcsize("<" + code)
    return int(struct.unpack("<" + code, _pad(raw, size, code.islower()))[0])


def _pad(raw: bytes, size: int, signed: bool) -> bytes:
    if len(raw) >= size:
        return raw[:size]
    fill = b"\xff" if signed and raw and raw[-1] & 0x80 else b"\0"
    return raw + fill * (size - len(raw))


def _fit(raw: bytes, obj: MapObject) -> bytes:
    """An SDO answer cut or sign-extended to the object's size."""
    return _pad(raw, obj.size, DATA_TYPES[obj.type][1].islower())


def _unit_text(unit: str) -> str:
    return {
        "permille_rated_torque": "per mille of the rated torque, taken as per mille of the "
        "rated current (torque constant × rated current = rated torque)",
        "permille_rated_current": "per mille of the rated current",
        "mA": "mA",
    }.get(unit, unit)
