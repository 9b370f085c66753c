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

The SYNC producer keeps time by the link's :class:`~ncmeasure.samples.LinkClock`:
real time for real drives, or the clock of a virtual machine running faster
than real time with simulated drives (:mod:`ncmeasure.sim.cia402`). Its
period is ``1 / sync_hz`` rounded to whole microseconds, the unit of the
communication cycle period 0x1006 it writes to the drives, so the link and
the drives agree on it exactly. Faster than real time, every SYNC carries a
one-byte counter, the cycle number modulo 240 plus 1, so the simulated drives
follow the link's cycle numbering across cycles the host skipped.

Values are taken inside the PDO callbacks into a :class:`CycleAssembler`
keyed by SYNC cycle, so no frame is lost to a PDO map holding only its last
frame. Cycles that stay incomplete are dropped, never filled with invented or
NaN values, and reported as ``gap`` events with ``lost_samples``; EMCY
messages, reboots (boot-up, after which the node's PDOs are configured
again), SDO fallbacks and drive faults are events too. A failing bus raises
:class:`~ncmeasure.errors.LinkError` from :meth:`~CanOpenLink.read`.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import queue
import re
import struct
import threading
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar, Literal, cast

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from numpy.typing import NDArray
from pydantic import BaseModel as _BaseModel
from pydantic import ConfigDict as _ConfigDict
from pydantic import Field, ValidationError, field_validator, model_validator

from ncmeasure.config import format_validation_error
from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError, OutputError
from ncmeasure.links.base import AxisBinding, AxisLinkSettings, DriveLink, LinkSettings
from ncmeasure.samples import SIGNAL_UNITS, Channel, LinkEvent, SampleBlock

__all__ = [
    "DATA_TYPES",
    "VELOCITY_UNITS",
    "BusLoad",
    "CanOpenAxis",
    "CanOpenLink",
    "CanOpenSettings",
    "CycleAssembler",
    "LostCycle",
    "MapObject",
    "ObjectMap",
    "available_object_maps",
    "build_dictionary",
    "bus_load",
    "emcy_text",
    "frame_bits",
    "load_eds",
    "load_object_map",
    "position_scale_mm",
    "sdo_error_text",
    "velocity_scale_mm_min",
]

log = logging.getLogger(__name__)

# --- data types, units ----------------------------------------------------------------

DataTypeName = Literal["int8", "int16", "int32", "uint8", "uint16", "uint32"]

#: Object data types a map may use: name -> (CiA 301 data type code, struct code).
DATA_TYPES: Mapping[str, tuple[int, str]] = {
    "int8": (0x02, "b"),
    "int16": (0x03, "h"),
    "int32": (0x04, "i"),
    "uint8": (0x05, "B"),
    "uint16": (0x06, "H"),
    "uint32": (0x07, "I"),
}
_TYPE_BY_CODE = {code: name for name, (code, _) in DATA_TYPES.items()}

VelocityUnit = Literal["inc_per_s", "rpm", "0.1rpm", "0.01rpm", "0.001rpm"]

#: Velocity units of 0x606C/0x606B the link converts, with their meaning.
VELOCITY_UNITS: Mapping[str, str] = {
    "inc_per_s": "position increments per second (CiA 402 default without a factor group)",
    "rpm": "motor revolutions per minute",
    "0.1rpm": "0.1 motor revolutions per minute",
    "0.01rpm": "0.01 motor revolutions per minute",
    "0.001rpm": "0.001 motor revolutions per minute",
}
_RPM_FACTOR = {"rpm": 1.0, "0.1rpm": 0.1, "0.01rpm": 0.01, "0.001rpm": 0.001}

ObjectUnit = Literal[
    "inc", "velocity", "permille_rated_current", "permille_rated_torque", "mA", "bits"
]
Role = Literal["statusword", "position", "velocity", "velocity_demand", "current"]
_UNITS_BY_ROLE: Mapping[str, frozenset[str]] = {
    "statusword": frozenset({"bits"}),
    "position": frozenset({"inc"}),
    "velocity": frozenset({"velocity"}),
    "velocity_demand": frozenset({"velocity"}),
    "current": frozenset({"permille_rated_current", "permille_rated_torque", "mA"}),
    "rated_current": frozenset({"mA"}),
}
#: Role -> signal column it fills (the statusword fills none).
_SIGNAL_BY_ROLE: Mapping[str, str] = {
    "position": "position_mm",
    "velocity": "velocity_mm_min",
    "velocity_demand": "velocity_cmd_mm_min",
    "current": "current_a",
}


def position_scale_mm(
    increments_per_rev: int, screw_lead_mm: float, gear_ratio: float = 1.0
) -> float:
    """Millimetres per position increment.

    Args:
        increments_per_rev: Encoder increments per motor revolution.
        screw_lead_mm: Ball-screw lead (mm per screw revolution).
        gear_ratio: Motor revolutions per screw revolution.
    """
    return screw_lead_mm / (increments_per_rev * gear_ratio)


def velocity_scale_mm_min(
    unit: str, increments_per_rev: int, screw_lead_mm: float, gear_ratio: float = 1.0
) -> float:
    """Millimetres per minute per unit of the drive's velocity objects."""
    if unit == "inc_per_s":
        return 60.0 * position_scale_mm(increments_per_rev, screw_lead_mm, gear_ratio)
    if unit in _RPM_FACTOR:
        return _RPM_FACTOR[unit] * screw_lead_mm / gear_ratio
    raise ValueError(f"unknown velocity unit {unit!r}; known: {', '.join(VELOCITY_UNITS)}")


# --- object maps ------------------------------------------------------------------------

_MAP_PACKAGE = "ncmeasure.links"
_MAP_FOLDER = "objectmaps"


class _Model(_BaseModel):
    model_config = _ConfigDict(extra="forbid", frozen=True)


class MapObject(_Model):
    """One object of a drive's dictionary that carries a value the link reads."""

    name: str = Field(description="Name of the object, for messages.")
    index: int = Field(ge=0x1000, le=0xFFFF, description="Object index.")
    subindex: int = Field(default=0, ge=0, le=0xFF, description="Sub-index.")
    type: DataTypeName = Field(description="Data type as the drive encodes it.")
    unit: ObjectUnit = Field(description="Unit of the raw value (see the cia402 map).")
    fallback: MapObject | None = Field(
        default=None, description="Object to read instead when the drive lacks this one."
    )
    note: str = ""

    @property
    def size(self) -> int:
        """Size in bytes."""
        return struct.calcsize("<" + DATA_TYPES[self.type][1])

    @property
    def label(self) -> str:
        """``current actual value 0x6078:00`` for messages."""
        return f"{self.name} 0x{self.index:04X}:{self.subindex:02X}"

    def with_type(self, type_name: DataTypeName) -> MapObject:
        """The same object with another data type (an EDS that says otherwise)."""
        return self.model_copy(update={"type": type_name})


class TpdoLayout(_Model):
    """How the link packs the roles into TPDOs."""

    layout: list[list[Role]] = Field(min_length=1, max_length=8)


class ObjectMap(_Model):
    """Which object carries which value on a kind of drive, and the TPDO layout."""

    name: str
    description: str = ""
    sources: list[str] = Field(default_factory=list)
    velocity_unit: VelocityUnit = "inc_per_s"
    statusword: MapObject | None = None
    position: MapObject
    velocity: MapObject
    current: MapObject
    velocity_demand: MapObject | None = None
    rated_current: MapObject | None = None
    tpdo: TpdoLayout

    @model_validator(mode="after")
    def _check(self) -> ObjectMap:
        for role, units in _UNITS_BY_ROLE.items():
            obj = cast(MapObject | None, getattr(self, role))
            while obj is not None:
                if obj.unit not in units:
                    raise ValueError(
                        f"{role}: unit {obj.unit!r} does not fit; use one of {sorted(units)}"
                    )
                obj = obj.fallback
        seen: set[str] = set()
        for group in self.tpdo.layout:
            for role in group:
                if role in seen:
                    raise ValueError(f"tpdo.layout: {role} appears twice")
                seen.add(role)
                if getattr(self, role) is None:
                    raise ValueError(f"tpdo.layout: {role} is not defined in this map")
            size = sum(_max_size(cast(MapObject, getattr(self, role))) for role in group)
            if size > 8:
                raise ValueError(f"tpdo.layout: {group} needs {size} bytes, a PDO holds 8")
        missing = {"position", "velocity", "current"} - seen
        if missing:
            raise ValueError(f"tpdo.layout: must contain {', '.join(sorted(missing))}")
        return self

    def role(self, name: str) -> MapObject | None:
        """The object of a role (``position``, ``current``, ...), or None."""
        return cast(MapObject | None, getattr(self, name, None))


def _max_size(obj: MapObject) -> int:
    size = obj.size
    while obj.fallback is not None:
        obj = obj.fallback
        size = max(size, obj.size)
    return size


def available_object_maps() -> list[str]:
    """Names of the built-in object maps."""
    folder = resources.files(_MAP_PACKAGE).joinpath(_MAP_FOLDER)
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_object_map(spec: str | Path) -> ObjectMap:
    """A built-in object map by name (``cia402``, ``maxon_epos4``) or one from a TOML file.

    Raises:
        ConfigError: unknown name, unreadable file, or an invalid map.
    """
    text: str
    where: str
    if isinstance(spec, str) and re.fullmatch(r"[a-z0-9_]+", spec):
        resource = resources.files(_MAP_PACKAGE).joinpath(_MAP_FOLDER, f"{spec}.toml")
        if not resource.is_file():
            raise ConfigError(
                f"unknown object map {spec!r}; built-in maps: "
                f"{', '.join(available_object_maps())}, or give the path of a .toml map"
            )
        text, where = resource.read_text(encoding="utf-8"), f"object map {spec}"
    else:
        path = Path(spec).expanduser()
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError as exc:
            raise ConfigError(
                f"{path}: no such object map file (built-in maps: "
                f"{', '.join(available_object_maps())})"
            ) from exc
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: cannot read the object map ({exc})") from exc
        where = str(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where}: invalid TOML: {exc}") from exc
    try:
        return ObjectMap.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(
            f"{where} is not a valid object map", format_validation_error(exc)
        ) from exc


# --- bus load ---------------------------------------------------------------------------


def frame_bits(data_bytes: int, *, worst_case: bool = False) -> int:
    """Bits on the wire of one classical CAN data frame with an 11-bit identifier.

    Nominal: 47 + 8n (start of frame to interframe space). Worst case adds the
    stuff bits: at most one per 4 bits of the 34 + 8n stuffed bits, i.e.
    floor((34 + 8n - 1) / 4); an 8-byte frame is 111 bits nominal, 135 worst.
    """
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"a CAN frame carries 0 to 8 bytes, not {data_bytes}")
    bits = 47 + 8 * data_bytes
    if worst_case:
        bits += (34 + 8 * data_bytes - 1) // 4
    return bits


@dataclass(frozen=True)
class BusLoad:
    """Bus load of one SYNC cycle repeated at ``sync_hz``."""

    frames_per_cycle: int
    bits_per_cycle: int
    worst_bits_per_cycle: int
    sync_hz: float
    bitrate: int

    @property
    def load(self) -> float:
        """Fraction of the bitrate used, nominal frame lengths."""
        return self.bits_per_cycle * self.sync_hz / self.bitrate

    @property
    def worst_load(self) -> float:
        """Fraction of the bitrate used with worst-case bit stuffing."""
        return self.worst_bits_per_cycle * self.sync_hz / self.bitrate

    def max_sync_hz(self, max_load: float) -> float:
        """The highest SYNC rate whose worst-case load stays at ``max_load``."""
        return max_load * self.bitrate / self.worst_bits_per_cycle

    def describe(self) -> str:
        """One line with the numbers."""
        return (
            f"{self.frames_per_cycle} frames per SYNC cycle, {self.bits_per_cycle} bits "
            f"({self.worst_bits_per_cycle} with worst-case bit stuffing) at "
            f"{self.sync_hz:g} Hz on {self.bitrate / 1000:g} kbit/s = "
            f"{100 * self.load:.1f} % ({100 * self.worst_load:.1f} % worst case)"
        )


def bus_load(
    pdo_bytes: Sequence[int], sync_hz: float, bitrate: int, *, sync_frame: bool = True
) -> BusLoad:
    """Bus load of a SYNC frame plus the given PDOs per cycle.

    Args:
        pdo_bytes: Data length of every PDO sent per SYNC cycle (all nodes).
        sync_hz: SYNC frequency.
        bitrate: Bus bitrate in bit/s.
        sync_frame: Count the (empty) SYNC frame itself.

    Example: one 8-byte PDO with SYNC at 1 kHz on 1 Mbit/s is 47 + 111 = 158
    bits per cycle, a load of 0.158 (0.190 worst case: 55 + 135 bits).
    """
    if sync_hz <= 0 or bitrate <= 0:
        raise ValueError("sync_hz and bitrate must be positive")
    sizes = [*([0] if sync_frame else []), *pdo_bytes]
    return BusLoad(
        frames_per_cycle=len(sizes),
        bits_per_cycle=sum(frame_bits(n) for n in sizes),
        worst_bits_per_cycle=sum(frame_bits(n, worst_case=True) for n in sizes),
        sync_hz=sync_hz,
        bitrate=bitrate,
    )


# --- readable texts ---------------------------------------------------------------------

#: EMCY error codes of CiA 301 (communication) and CiA 402 / IEC 61800-7-201 (drives).
_EMCY_CODES: Mapping[int, str] = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2110: "short circuit or earth leakage (input)",
    0x2220: "continuous over-current inside the device",
    0x2310: "continuous over-current (motor side)",
    0x2311: "continuous over-current no. 1 (motor side)",
    0x2312: "continuous over-current no. 2 (motor side)",
    0x2320: "short circuit or earth leakage (motor side)",
    0x2330: "earth leakage (motor side)",
    0x2340: "short circuit (motor side)",
    0x3110: "mains over-voltage",
    0x3120: "mains under-voltage",
    0x3130: "phase failure",
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x3230: "load error",
    0x3310: "output over-voltage",
    0x4110: "ambient temperature too high",
    0x4210: "excess temperature of the device",
    0x4220: "temperature of the device too low",
    0x4310: "excess temperature of the drive (motor)",
    0x4320: "temperature of the drive (motor) too low",
    0x5110: "supply low voltage",
    0x5210: "measurement circuit",
    0x5400: "power section",
    0x5410: "output stages",
    0x5530: "EEPROM",
    0x6010: "software reset (watchdog)",
    0x6310: "loss of parameters",
    0x6320: "parameter error",
    0x7110: "brake chopper",
    0x7120: "motor",
    0x7121: "motor blocked",
    0x7122: "motor error or commutation malfunction",
    0x7300: "sensor",
    0x7301: "tacho fault",
    0x7303: "resolver 1 fault",
    0x7305: "incremental sensor 1 fault",
    0x7306: "incremental sensor 2 fault",
    0x7310: "speed",
    0x7320: "position",
    0x7500: "communication",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
    0x8311: "excess torque",
    0x8312: "difficult start-up",
    0x8313: "standstill torque",
    0x8321: "insufficient torque",
    0x8331: "torque fault",
    0x8400: "velocity (speed) controller",
    0x8500: "position controller",
    0x8611: "following error",
    0x8612: "reference limit",
    0x8A00: "control",
    0x9000: "external error",
    0xF001: "deceleration",
    0xF002: "sub-synchronous run",
    0xF003: "stroke operation",
    0xF004: "control",
}


def emcy_text(code: int) -> str:
    """Readable meaning of an EMCY error code (CiA 301 / CiA 402), e.g. ``motor blocked``."""
    if code in _EMCY_CODES:
        return _EMCY_CODES[code]
    if code & 0xFF00 == 0xFF00:
        return "device-specific error (see the drive manual)"
    group = EmcyError(code, 0, b"", 0.0).get_desc()
    return f"{group.lower()} error" if group else "unknown error code"


def sdo_error_text(exc: BaseException, timeout_s: float | None = None) -> str:
    """Readable text of a canopen SDO error: abort code with its CiA 301 meaning, or timeout."""
    if isinstance(exc, SdoAbortedError):
        meaning = SdoAbortedError.CODES.get(exc.code, "unknown abort code")
        return f"SDO abort 0x{exc.code:08X} ({meaning})"
    if isinstance(exc, SdoCommunicationError):
        within = f" within {timeout_s:g} s" if timeout_s is not None else ""
        return f"no SDO answer{within} ({exc})"
    return f"{type(exc).__name__}: {exc}"


# --- object dictionaries ----------------------------------------------------------------


def _variable(
    name: str,
    index: int,
    subindex: int,
    type_code: int,
    access: str,
    default: int | None,
    mappable: bool = False,
) -> ODVariable:
    var = ODVariable(name, index, subindex)
    var.data_type = type_code
    var.access_type = access
    var.default = default
    var.pdo_mappable = mappable
    return var


def _add_record(od: ObjectDictionary, name: str, index: int, members: Sequence[ODVariable]) -> None:
    record = ODRecord(name, index)
    for member in members:
        record.add_member(member)
    od.add_object(record)


def build_dictionary(
    object_map: ObjectMap, node_id: int = 1, tpdos: int = 4, rated_current_ma: int = 0
) -> ObjectDictionary:
    """A CiA 402 object dictionary for a drive without EDS: communication objects + the map.

    Holds 0x1000, 0x1001, 0x1006, 0x1008, 0x1017, 0x1018, ``tpdos`` TPDOs (0x1800/0x1A00
    onwards, predefined COB-IDs, event-driven, nothing mapped) and every object
    of the map including fallbacks and the rated current.
    """
    u8, u16, u32 = DATA_TYPES["uint8"][0], DATA_TYPES["uint16"][0], DATA_TYPES["uint32"][0]
    od = ObjectDictionary()  # type: ignore[no-untyped-call]
    od.node_id = node_id
    od.add_object(_variable("device type", 0x1000, 0, u32, "ro", 0x00020192))
    od.add_object(_variable("error register", 0x1001, 0, u8, "ro", 0))
    od.add_object(_variable("communication cycle period", 0x1006, 0, u32, "rw", 0))
    device_name = _variable("manufacturer device name", 0x1008, 0, 0x09, "const", None)
    cast(Any, device_name).default = "ncmeasure CiA 402 drive"  # a string, not an int
    od.add_object(device_name)
    od.add_object(_variable("producer heartbeat time", 0x1017, 0, u16, "rw", 0))
    _add_record(
        od,
        "identity",
        0x1018,
        [
            _variable("highest sub-index", 0x1018, 0, u8, "const", 4),
            _variable("vendor id", 0x1018, 1, u32, "ro", 0),
            _variable("product code", 0x1018, 2, u32, "ro", 0),
            _variable("revision number", 0x1018, 3, u32, "ro", 0),
            _variable("serial number", 0x1018, 4, u32, "ro", 0),
        ],
    )
    for number in range(tpdos):
        comm, mapping = 0x1800 + number, 0x1A00 + number
        cob_id = (0x180 + 0x100 * number + node_id) if number < 4 else 0x80000000
        _add_record(
            od,
            f"TPDO{number + 1} communication parameter",
            comm,
            [
                _variable("highest sub-index", comm, 0, u8, "const", 5),
                _variable("COB-ID", comm, 1, u32, "rw", cob_id),
                _variable("transmission type", comm, 2, u8, "rw", 255),
                _variable("inhibit time", comm, 3, u16, "rw", 0),
                _variable("event timer", comm, 5, u16, "rw", 0),
            ],
        )
        _add_record(
            od,
            f"TPDO{number + 1} mapping parameter",
            mapping,
            [
                _variable("number of mapped objects", mapping, 0, u8, "rw", 0),
                *(_variable(f"mapped object {k}", mapping, k, u32, "rw", 0) for k in range(1, 9)),
            ],
        )
    objects: list[MapObject] = []
    for role in (
        "statusword",
        "position",
        "velocity",
        "velocity_demand",
        "current",
        "rated_current",
    ):
        obj = object_map.role(role)
        while obj is not None:
            objects.append(obj)
            obj = obj.fallback
    by_index: dict[int, list[MapObject]] = {}
    for obj in objects:
        by_index.setdefault(obj.index, [])
        if all(o.subindex != obj.subindex for o in by_index[obj.index]):
            by_index[obj.index].append(obj)

    def make(obj: MapObject) -> ODVariable:
        rated = obj is object_map.rated_current
        return _variable(
            obj.name,
            obj.index,
            obj.subindex,
            DATA_TYPES[obj.type][0],
            "rw" if rated else "ro",
            rated_current_ma if rated else 0,
            mappable=not rated,
        )

    for index, group in sorted(by_index.items()):
        if len(group) == 1 and group[0].subindex == 0:
            od.add_object(make(group[0]))
        else:
            highest = max(o.subindex for o in group)
            _add_record(
                od,
                group[0].name,
                index,
                [
                    _variable("highest sub-index", index, 0, u8, "const", highest),
                    *(make(o) for o in sorted(group, key=lambda o: o.subindex)),
                ],
            )
    return od


def _od_variable(od: ObjectDictionary, index: int, subindex: int) -> ODVariable | None:
    if index not in od:
        return None
    obj = od[index]
    if isinstance(obj, ODVariable):
        return obj if subindex == 0 else None
    if isinstance(obj, (ODRecord, ODArray)):
        var = obj.subindices.get(subindex)
        return var if isinstance(var, ODVariable) else None
    return None


def load_eds(path: Path, node_id: int) -> ObjectDictionary:
    """Parse an EDS/DCF file for node ``node_id``.

    Raises:
        ConfigError: the file is missing or cannot be parsed; the message names it.
    """
    if not path.is_file():
        raise ConfigError(f"{path}: no such EDS/DCF file")
    if path.suffix.lower() not in (".eds", ".dcf"):
        raise ConfigError(f"{path}: an EDS or DCF file must end in .eds or .dcf")
    try:
        od = canopen.import_od(str(path), node_id)
    except Exception as exc:  # configparser, ValueError, KeyError... all mean "unreadable"
        reason = " ".join(str(exc).split())  # parser messages span several lines
        raise ConfigError(f"{path}: not a readable EDS/DCF file ({reason})") from exc
    if len(od) == 0:
        raise ConfigError(f"{path}: not a readable EDS/DCF file (no objects found)")
    return od


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
    eds: Path | None = Field(
        default=None, description="EDS/DCF file describing the drives (all nodes)."
    )
    object_map: str = Field(
        default="cia402",
        description="Built-in object map (cia402, maxon_epos4) or the path of a TOML map.",
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
    max_bus_load: float = Field(
        default=0.9,
        gt=0,
        le=10,
        description="Refuse a TPDO layout whose worst-case bus load exceeds this fraction.",
    )
    raw_log: Path | None = Field(
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
    eds: Path | None = Field(default=None, description="EDS/DCF of this node (overrides link.eds).")
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


# --- the link ----------------------------------------------------------------------------

_COB_INVALID = 0x80000000
_COB_NO_RTR = 0x40000000
_COB_EXTENDED = 0x20000000
_ABSENT_CODES = frozenset({0x06020000, 0x06090011})  # object / sub-index does not exist
_STATUS_FAULT = 0x0008


@dataclass
class _Field:
    role: str
    obj: MapObject
    column: int  # -1: statusword


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
        return sum(f.obj.size for f in self.fields)

    def update_dtype(self) -> None:
        self.dtype = np.dtype(
            {
                "names": [f"f{k}" for k in range(len(self.fields))],
                "formats": [_NP_TYPES[f.obj.type] for f in self.fields],
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
    axes: set[int] = field(default_factory=set)
    reason: str = ""


class CanOpenLink(DriveLink):
    """Reads CiA 402 drives over CANopen: TPDOs on SYNC, SDO for configuration.

    See the module docstring and ``docs/canopen.md``.
    """

    name: ClassVar[str] = "canopen"
    settings_model: ClassVar[type[LinkSettings]] = CanOpenSettings
    axis_settings_model: ClassVar[type[AxisLinkSettings]] = CanOpenAxis

    #: How long (wall-clock) an incomplete SYNC cycle may wait for its PDOs before it is lost.
    HOLD_S: ClassVar[float] = 0.1
    #: A gap event covers at most this much link time; longer outages give several.
    GAP_REPORT_S: ClassVar[float] = 1.0
    #: The SYNC producer skips (and reports) cycles when it is this late (wall-clock).
    MAX_SYNC_LATE_S: ClassVar[float] = 0.005
    #: Faster than real time, the SYNC counter runs 1..SYNC_COUNTER_MAX (CiA 301 0x1019 at most).
    SYNC_COUNTER_MAX: ClassVar[int] = 240

    settings: CanOpenSettings

    def __init__(self, settings: LinkSettings, axes: Sequence[AxisBinding]) -> None:
        super().__init__(settings, axes)
        if not isinstance(settings, CanOpenSettings):
            raise ConfigError("the canopen link needs CanOpenSettings")
        self.settings = settings
        #: SYNC period in whole µs, as written to 0x1006.
        self._period_us = max(1, round(1e6 / settings.sync_hz))
        #: Cycles per second on the link clock: the produced rate, or the other master's.
        self._rate_hz = 1e6 / self._period_us if settings.sync_producer else settings.sync_hz
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
        self._assembler = CycleAssembler(len(self._slots), self._hold_cycles())
        self._cycle = -1
        self._last_sync_time: float | None = None
        self._ready: list[tuple[int, list[bytes]]] = []
        self._gap: _GapRun | None = None
        self._failure: LinkError | None = None
        self._mode: Literal["pdo", "sdo_polling"] = "pdo"
        self._streaming = False
        self._stats = {
            "pdo_frames": 0,
            "sync_cycles": 0,
            "rows": 0,
            "lost_rows": 0,
            "bad_frames": 0,
            "sdo_polls": 0,
        }
        self._bad_slots: set[int] = set()

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
            var = _od_variable(od, obj.index, obj.subindex)
            if var is not None:
                chosen = obj
                type_name = _TYPE_BY_CODE.get(var.data_type or 0)
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
                _Field(r, axis.objects[r], axis.columns.get(_SIGNAL_BY_ROLE.get(r, ""), -1))
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

    def _hold_cycles(self) -> int:
        """Cycles an incomplete row waits: ``HOLD_S`` of wall-clock time, at least 8."""
        return max(8, math.ceil(self.HOLD_S / self.clock.wall(self._period)))

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
        """Counters since open: PDO frames, SYNC cycles, rows, lost rows, SDO polls, ..."""
        with self._lock:
            stats = dict(self._stats)
            stats["late_frames"] = self._assembler.late_frames
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
        load = self.planned_bus_load()
        self._check_load(load)
        self._assembler = CycleAssembler(len(self._slots), self._hold_cycles())
        self._bus = self._make_bus()
        network = canopen.Network(self._bus)
        network.NOTIFIER_CYCLE = 0.1  # bounds how long close() waits for the receive thread
        self._network = network
        if self.settings.raw_log is not None:
            writer = self._make_logger(self.settings.raw_log)
            network.listeners.append(cast(Any, _RawLog(self, writer, self.settings.raw_log)))
        network.listeners.append(cast(Any, _BusWatch(self)))
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
        for axis in self._axes:
            self._prepare(axis)
        load = self.planned_bus_load()  # objects may have changed to fallbacks
        self._check_load(load)
        for axis in self._axes:
            try:
                self._map_tpdos(axis)
            except SdoAbortedError as exc:
                self._fall_back_to_polling(axis, exc)
                break
        for axis in self._axes:
            self._start_node(axis)
        if self._mode == "pdo":
            for index, slot in enumerate(self._slots):
                network.subscribe(slot.cob_id, self._pdo_callback(index, slot))
        self._streaming = True
        if self.settings.sync_producer:
            self._start_thread(self._produce_sync, "canopen-link-sync")
        else:
            network.subscribe(0x80, self._on_sync_frame)
        if self._mode == "sdo_polling":
            self._start_thread(self._poll, "canopen-link-poll")

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
        if s.channel is not None:
            kwargs["channel"] = s.channel
        kwargs["bitrate"] = s.bitrate
        if s.raw_log is not None:
            kwargs["receive_own_messages"] = True  # the log shows SYNC and SDO requests too
        try:
            return can.Bus(**kwargs)
        except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
            raise LinkError(
                f"cannot open the CAN interface {s.interface or '(python-can config)'} "
                f"channel {s.channel or '(default)'}: {exc}"
            ) from exc

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
        if self.settings.nmt_control and axis.node is not None:
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
        self._assembler = CycleAssembler(len(self._slots), self._assembler.hold_cycles)
        self._read_rated_current(axis)
        self._set_scales(axis)
        if self.settings.sync_producer:
            try:  # lets the drive monitor the SYNC; optional for the measurement
                self._sdo_down(axis, 0x1006, 0, struct.pack("<I", self._period_us))
            except (SdoAbortedError, SdoCommunicationError) as exc:
                log.info("%s: 0x1006 not written (%s)", axis.who, sdo_error_text(exc))
        for note in axis.notes:
            self._event(LinkEvent(0.0, "info", f"{axis.who}: {note}", axis=axis.name))

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

    def _pdo_callback(self, index: int, slot: _Slot) -> Callable[[int, bytearray, float], None]:
        size = slot.size

        def on_pdo(can_id: int, data: bytearray, timestamp: float) -> None:
            with self._lock:
                self._stats["pdo_frames"] += 1
                if len(data) < size:
                    self._bad_frame(index, slot, len(data))
                    return
                self._assembler.frame(index, bytes(data[:size]))

        return on_pdo

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
        self._event(
            LinkEvent(
                self._cycle_time(),
                "reboot",
                f"{axis.who} rebooted (boot-up message): its PDO configuration is lost; "
                "configuring it again, the cycles until then are reported as a gap",
                axis=axis.name,
            )
        )
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

    def _advance(self, cycle: int) -> None:
        """Publish SYNC cycle ``cycle``; caller holds the lock."""
        skipped = cycle - self._cycle - 1
        if self._mode == "pdo":
            if skipped > 0:
                self._assembler.skip(self._cycle + 1, skipped)
            self._assembler.sync(cycle)
        elif skipped > 0:
            self._lost_polls(self._cycle + 1, skipped, "no SYNC on the bus")
        self._cycle = cycle
        self._stats["sync_cycles"] += 1
        self._settle()
        self._cond.notify_all()

    def _cycle_time(self) -> float:
        return max(self._cycle, 0) * self._period

    # --- SYNC producer, polling, worker (own threads) ------------------------------------

    def _produce_sync(self) -> None:
        """Send SYNC cycle k at ``start + k × period`` on the link clock."""
        assert self._network is not None
        clock = self.clock
        counted = not clock.real_time  # simulated drives: they follow the counter
        period = self._period
        # Late by MAX_SYNC_LATE_S of wall-clock time: a host hiccup. Simulated drives number
        # their samples by the SYNC counter, so a late SYNC still samples its own cycle.
        max_late = max(2, math.ceil(self.MAX_SYNC_LATE_S / clock.wall(period)))
        start = clock.now()
        cycle = 0
        while not self._stop.is_set():
            due = start + cycle * period
            delay = due - clock.now()
            if delay > 0 and self._stop.wait(clock.wall(delay)):
                break
            late = int((clock.now() - due) / period)
            if late >= max_late:
                cycle += late  # sending them now would stamp the samples wrongly
            with self._cond:
                self._advance(cycle)
            data = bytes([cycle % self.SYNC_COUNTER_MAX + 1]) if counted else b""
            try:
                self._network.send_message(0x80, data)
            except Exception as exc:
                self._fail(LinkError(f"cannot send SYNC: {exc}"))
                return
            cycle += 1

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
                    b"".join(self._poll_object(slot.axis, f.obj) for f in slot.fields)
                    for slot in self._slots
                ]
            except (SdoAbortedError, SdoCommunicationError) as exc:
                with self._cond:
                    self._lost_polls(
                        cycle,
                        1,
                        f"SDO polling failed: {sdo_error_text(exc, self.settings.sdo_timeout_s)}",
                    )
                continue
            with self._cond:
                self._stats["sdo_polls"] += 1
                self._ready.append((cycle, row))
                self._close_gap()
                self._cond.notify_all()

    def _new_cycle(self, last: int) -> bool:
        return self._cycle != last or self._stop.is_set()

    def _poll_object(self, axis: _Axis, obj: MapObject) -> bytes:
        raw = self._sdo_up(axis, obj.index, obj.subindex)
        return _fit(raw, obj)

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
        if self._stop.is_set():
            return
        errors: list[str] = []
        for _attempt in range(3):
            try:
                if self._mode == "pdo":
                    self._map_tpdos(axis)
                if self.settings.sync_producer:
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

    # --- rows, gaps -------------------------------------------------------------------

    def _settle(self, final: bool = False) -> None:
        """Move complete rows to the ready list, account lost cycles; caller holds the lock."""
        if self._mode != "pdo":
            return
        rows, lost = self._assembler.settle(final)
        events: list[tuple[int, list[bytes]] | LostCycle] = [*rows, *lost]
        events.sort(key=lambda item: item.cycle if isinstance(item, LostCycle) else item[0])
        for item in events:
            if isinstance(item, LostCycle):
                axes = {self._slots[i].axis.position for i in item.missing}
                self._lose(item.cycle, axes, item.no_sync, "")
            else:
                self._close_gap()
                self._ready.append(item)

    def _lose(self, cycle: int, axes: set[int], no_sync: bool, reason: str) -> None:
        gap = self._gap
        report_cycles = max(1, math.ceil(self.GAP_REPORT_S * self._rate_hz))
        if gap is not None and (
            cycle != gap.last + 1
            or gap.last - gap.first + 1 >= report_cycles
            or gap.reason != reason
        ):
            self._close_gap()
            gap = None
        if gap is None:
            gap = self._gap = _GapRun(first=cycle, last=cycle, reason=reason)
        gap.last = cycle
        gap.count += 1
        gap.no_sync += no_sync
        if not no_sync:
            gap.axes |= axes
        self._stats["lost_rows"] += 1

    def _lost_polls(self, first: int, count: int, reason: str) -> None:
        for cycle in range(first, first + count):
            self._lose(cycle, set(), False, reason)

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
        if gap.no_sync and self.settings.sync_producer:
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
                },
            )
        )

    def _read(self, timeout_s: float) -> SampleBlock | None:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                self._check_failure()
                self._settle()
                if self._ready:
                    rows, self._ready = self._ready, []
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return self.empty_block()
                self._cond.wait(min(remaining, 0.05))
            self._stats["rows"] += len(rows)
        return self._decode(rows)

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
        for index, slot in enumerate(self._slots):
            raw = np.frombuffer(b"".join(r[index] for _, r in rows), dtype=slot.dtype)
            for k, f in enumerate(slot.fields):
                column = raw[f"f{k}"]
                if f.column >= 0:
                    values[:, f.column] = column * slot.axis.scales[f.role]
                else:
                    self._check_status(slot.axis, column, time_s)
        return SampleBlock(time_s, values)

    def _check_status(
        self, axis: _Axis, statusword: NDArray[Any], time_s: NDArray[np.float64]
    ) -> None:
        fault = (statusword & _STATUS_FAULT) != 0
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
                self._settle(final=True)
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


class _RawLog(can.Listener):
    """The raw frame log; a writer that fails stops logging, never the measurement."""

    def __init__(self, link: CanOpenLink, writer: can.Listener, path: Path) -> None:
        self._link = link
        self._writer = writer
        self._path = path
        self._failed = False

    def on_message_received(self, msg: can.Message) -> None:
        if self._failed:
            return
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
        self._writer.stop()


class _BusWatch(can.Listener):
    """Turns a failing bus (the notifier's receive error) into a LinkError for read()."""

    def __init__(self, link: CanOpenLink) -> None:
        self._link = link

    def on_message_received(self, msg: can.Message) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        self._link._fail(LinkError(f"CAN bus error: {exc}"))


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
