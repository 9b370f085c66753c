"""CiA 301 / CiA 402 protocol knowledge: data types, units, object maps, dictionaries, EDS, texts.

What a drive's objects mean and how they are encoded, shared by the link
(:mod:`.link`), the CAN log importer and the simulated drives
(:mod:`ncmeasure.sim.cia402`): the object data types, velocity units and
scale factors, the *object maps* (``objectmaps/*.toml``: which object carries
which value and how the TPDOs are laid out), object dictionaries built from
a map or read from an EDS/DCF file, and readable texts of EMCY codes
(``emcy.toml``) and SDO errors.
"""

from __future__ import annotations

import functools
import logging
import re
import struct
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any, Literal, cast

import canopen
from canopen.emcy import EmcyError
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from pydantic import BaseModel as _BaseModel
from pydantic import ConfigDict as _ConfigDict
from pydantic import Field, ValidationError, model_validator

from ncmeasure.config import format_validation_error
from ncmeasure.errors import ConfigError
from ncmeasure.inputs import MAX_TOML_BYTES, parse_toml, read_text

__all__ = [
    "DATA_TYPES",
    "SIGNAL_BY_ROLE",
    "TYPE_BY_CODE",
    "VELOCITY_UNITS",
    "DataTypeName",
    "MapObject",
    "ObjectMap",
    "ObjectUnit",
    "Role",
    "TpdoLayout",
    "VelocityUnit",
    "available_object_maps",
    "build_dictionary",
    "emcy_text",
    "load_eds",
    "load_object_map",
    "od_variable",
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
TYPE_BY_CODE = {code: name for name, (code, _) in DATA_TYPES.items()}

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
Role = Literal["statusword", "position", "velocity", "velocity_demand", "current", "digital_inputs"]
_UNITS_BY_ROLE: Mapping[str, frozenset[str]] = {
    "statusword": frozenset({"bits"}),
    "position": frozenset({"inc"}),
    "velocity": frozenset({"velocity"}),
    "velocity_demand": frozenset({"velocity"}),
    "current": frozenset({"permille_rated_current", "permille_rated_torque", "mA"}),
    "rated_current": frozenset({"mA"}),
    "digital_inputs": frozenset({"bits"}),
}
#: Role -> signal column it fills (the statusword fills none).
SIGNAL_BY_ROLE: Mapping[str, str] = {
    "position": "position_mm",
    "velocity": "velocity_mm_min",
    "velocity_demand": "velocity_cmd_mm_min",
    "current": "current_a",
    "digital_inputs": "marker",  # one bit of it: the axis' marker_input_bit
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

_MAP_PACKAGE = "ncmeasure.links.canopen"
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
    digital_inputs: MapObject | None = None
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
        text = read_text(
            path,
            "an object map (.toml)",
            MAX_TOML_BYTES,
            missing=f"{path}: no such object map file (built-in maps: "
            f"{', '.join(available_object_maps())})",
        )
        where = str(path)
    data = parse_toml(text, where)
    try:
        return ObjectMap.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(
            f"{where} is not a valid object map", format_validation_error(exc)
        ) from exc


# --- readable texts ---------------------------------------------------------------------


@functools.cache
def _emcy_codes() -> Mapping[int, str]:
    """The EMCY table of ``emcy.toml``: code -> meaning."""
    text = resources.files(_MAP_PACKAGE).joinpath("emcy.toml").read_text(encoding="utf-8")
    codes = parse_toml(text, "emcy.toml")["codes"]
    return {int(code, 16): meaning for code, meaning in codes.items()}


def emcy_text(code: int) -> str:
    """Readable meaning of an EMCY error code (CiA 301 / CiA 402), e.g. ``motor blocked``."""
    codes = _emcy_codes()
    if code in codes:
        return codes[code]
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
    od = ObjectDictionary()  # type: ignore[no-untyped-call]
    od.node_id = node_id
    _add_communication(od, node_id, tpdos)
    _add_map_objects(od, object_map, rated_current_ma)
    return od


def _add_communication(od: ObjectDictionary, node_id: int, tpdos: int) -> None:
    """0x1000, 0x1001, 0x1006, 0x1008, 0x1017, 0x1018 and ``tpdos`` TPDOs, nothing mapped."""
    u8, u16, u32 = DATA_TYPES["uint8"][0], DATA_TYPES["uint16"][0], DATA_TYPES["uint32"][0]
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


def _add_map_objects(od: ObjectDictionary, object_map: ObjectMap, rated_current_ma: int) -> None:
    """Every object of the map, fallbacks and the rated current included."""
    u8 = DATA_TYPES["uint8"][0]
    objects: list[MapObject] = []
    for role in (
        "statusword",
        "position",
        "velocity",
        "velocity_demand",
        "current",
        "rated_current",
        "digital_inputs",
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


def od_variable(od: ObjectDictionary, index: int, subindex: int) -> ODVariable | None:
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
