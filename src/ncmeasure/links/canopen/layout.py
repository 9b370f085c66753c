"""The TPDO layout of the CANopen link: which object of which node travels in which PDO.

Before the bus is touched, the link knows each axis' drive from the settings
alone: its object dictionary (an EDS/DCF file, or one built from the object
map), the objects it reads for each role (position, velocity, current,
statusword, velocity demand; a fallback where the EDS lacks one), the columns
of its signals and the TPDO *slots* the objects travel in:

- a link that configures the drives packs the objects into TPDOs following the
  object map's layout (:func:`pack_slots`), from ``first_tpdo`` on;
- a link that only listens takes the TPDOs as the controller configured them,
  from the axes' ``tpdo`` tables or the drives' DCF (:func:`dcf_tpdo`), and
  reads the objects they carry (:func:`roles_mapped`); bytes it does not read
  are skipped.

:class:`Layout` holds the axes and the slots of all of them, in order: a row
of the link is the bytes of every slot of one SYNC cycle.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
from canopen.objectdictionary import ObjectDictionary

from ncmeasure.errors import ConfigError
from ncmeasure.links.base import AxisBinding
from ncmeasure.links.canopen.busload import BusLoad, bus_load
from ncmeasure.links.canopen.objects import (
    DATA_TYPES,
    SIGNAL_BY_ROLE,
    TYPE_BY_CODE,
    DataTypeName,
    MapObject,
    ObjectMap,
    build_dictionary,
    load_eds,
    od_variable,
    position_scale_mm,
    velocity_scale_mm_min,
)
from ncmeasure.links.canopen.settings import CanOpenAxis, CanOpenSettings
from ncmeasure.samples import SIGNAL_UNITS, Channel

__all__ = [
    "COB_INVALID",
    "STATUS_COLUMN",
    "UNREAD",
    "ConfiguredTpdo",
    "Layout",
    "LinkAxis",
    "Slot",
    "SlotField",
    "dcf_tpdo",
    "pack_slots",
    "roles_mapped",
    "unit_text",
]

COB_INVALID = 0x80000000
"""Bit 31 of a PDO's COB-ID: the PDO is not valid (disabled)."""

STATUS_COLUMN = -1
"""The column of a field that holds the statusword (no signal: faults become events)."""
UNREAD = -2
"""The column of mapped bytes the link does not read."""

_NP_TYPES: Mapping[str, str] = {
    "int8": "<i1",
    "int16": "<i2",
    "int32": "<i4",
    "uint8": "<u1",
    "uint16": "<u2",
    "uint32": "<u4",
}


@dataclass
class SlotField:
    """One mapped object of a TPDO."""

    role: str
    """A role of the object map; empty for mapped bytes the link does not read."""
    obj: MapObject | None
    column: int  # STATUS_COLUMN: statusword; UNREAD: not read
    unread_bytes: int = 0
    bit: int | None = None
    """The one bit of the object that is the value (the marker's digital input), else None."""

    @property
    def size(self) -> int:
        return self.obj.size if self.obj is not None else self.unread_bytes

    @property
    def np_type(self) -> str:
        return _NP_TYPES[self.obj.type] if self.obj is not None else f"V{self.unread_bytes}"


@dataclass
class Slot:
    """One TPDO of one node."""

    axis: LinkAxis
    number: int  # TPDO number, 1-based
    fields: list[SlotField]
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


@dataclass
class LinkAxis:
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
    slots: list[Slot] = field(default_factory=list)
    rated_current_a: float | None = None
    scales: dict[str, float] = field(default_factory=dict)
    faulted: bool = False

    @property
    def node_id(self) -> int:
        return self.settings.node_id

    @property
    def who(self) -> str:
        return f"node {self.node_id} (axis {self.name})"

    def position_scale(self) -> float:
        return position_scale_mm(
            self.settings.increments_per_rev, self.screw_lead_mm, self.settings.gear_ratio
        )

    def velocity_scale(self) -> float:
        return velocity_scale_mm_min(
            self.velocity_unit,
            self.settings.increments_per_rev,
            self.screw_lead_mm,
            self.settings.gear_ratio,
        )

    def set_scales(self) -> None:
        """The factors from drive units to mm, mm/min and A (the rated current is known)."""
        self.scales = {
            "position": self.position_scale(),
            "velocity": self.velocity_scale(),
            "velocity_demand": self.velocity_scale(),
        }
        current = self.objects["current"]
        if current.unit == "mA":
            self.scales["current"] = 1e-3
        else:
            assert self.rated_current_a is not None
            self.scales["current"] = self.rated_current_a / 1000.0

    def describe(self) -> dict[str, Any]:
        """The axis' objects, TPDOs and scales, for a recording's metadata."""
        return {
            "node_id": self.node_id,
            "objects": {
                role: {
                    "index": f"0x{o.index:04X}",
                    "subindex": o.subindex,
                    "type": o.type,
                    "unit": o.unit,
                }
                for role, o in self.objects.items()
            },
            "tpdos": [
                {
                    "number": s.number,
                    "cob_id": f"0x{s.cob_id:03X}",
                    "roles": [f.role for f in s.fields],
                }
                for s in self.slots
            ],
            "velocity_unit": self.velocity_unit,
            "marker_input_bit": self.settings.marker_input_bit,
            "rated_current_a": self.rated_current_a,
            "position_mm_per_increment": self.position_scale(),
            "velocity_mm_min_per_unit": self.velocity_scale(),
            "current_a_per_unit": self.scales.get("current"),
        }


@dataclass(frozen=True)
class ConfiguredTpdo:
    """A TPDO as the controller configured it (listen_only)."""

    number: int
    cob_id: int
    transmission_type: int
    mapping: list[int]


class Layout:
    """The axes' drives, their objects and the TPDO slots the link reads, from the settings.

    Args:
        settings: The link's settings.
        bindings: The axes with their ``link`` tables, in machine-file order.
        object_map: The object map of the drives.

    Raises:
        ConfigError: One ``location: message`` line per problem of the settings.
    """

    def __init__(
        self, settings: CanOpenSettings, bindings: Sequence[AxisBinding], object_map: ObjectMap
    ) -> None:
        self.settings = settings
        self.map = object_map
        self.axes: list[LinkAxis] = []
        self.channels: tuple[Channel, ...] = ()
        self.slots: list[Slot] = []
        """The slots of every axis, in order: a row is their bytes."""
        self._resolve(bindings)
        self.collect()

    def collect(self) -> None:
        """Gather the axes' slots again (a new list, after an axis was packed anew)."""
        self.slots = [slot for axis in self.axes for slot in axis.slots]

    def describe(self) -> dict[str, Any]:
        """The object map, the bus load and each axis' objects and scales, for the metadata."""
        load = self.bus_load()
        return {
            "object_map": self.map.name,
            "bus_load": {
                "nominal": load.load,
                "worst_case": load.worst_load,
                "bits_per_cycle": load.bits_per_cycle,
                "worst_bits_per_cycle": load.worst_bits_per_cycle,
            },
            "scales": {axis.name: axis.describe() for axis in self.axes},
        }

    def bus_load(self) -> BusLoad:
        """Bus load of the TPDO layout plus SYNC (whoever produces it) at ``sync_hz``."""
        return bus_load(
            [slot.size for slot in self.slots], self.settings.sync_hz, self.settings.bitrate
        )

    def check_load(self) -> None:
        """Refuse a layout whose worst-case bus load is above ``max_bus_load``.

        Raises:
            ConfigError: It is, with the highest ``sync_hz`` that would do.
        """
        load = self.bus_load()
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

    # --- from the settings ------------------------------------------------------------

    def _resolve(self, bindings: Sequence[AxisBinding]) -> None:
        problems: list[str] = []
        used: dict[int, str] = {}
        channels: list[Channel] = []
        eds_cache: dict[tuple[Path, int], ObjectDictionary] = {}
        for position, binding in enumerate(bindings):
            node_id = cast(CanOpenAxis, binding.settings).node_id
            if node_id in used:
                problems.append(
                    f"axes[{position}].link.node_id: node {node_id} is "
                    f"already used by axis {used[node_id]}"
                )
            used[node_id] = binding.name
            axis = self._axis(position, binding, len(channels), eds_cache, problems)
            if axis is None:
                continue
            channels += [Channel(binding.name, s, SIGNAL_UNITS[s]) for s in axis.columns]
            self.axes.append(axis)
        if problems:
            raise ConfigError(
                "the settings of the canopen link are not valid", list(dict.fromkeys(problems))
            )
        self.channels = tuple(channels)

    def _axis(
        self,
        position: int,
        binding: AxisBinding,
        first_column: int,
        eds_cache: dict[tuple[Path, int], ObjectDictionary],
        problems: list[str],
    ) -> LinkAxis | None:
        """One axis' drive; None (with its problems) when it cannot be known."""
        axis_settings = cast(CanOpenAxis, binding.settings)
        where = f"axes[{position}]"
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
                od = build_dictionary(self.map, axis_settings.node_id)
        except ConfigError as exc:
            problems.append(f"{eds_where}: {exc}")
            return None
        roles = self._roles(axis_settings, where, problems)
        if roles is None:
            return None
        notes: list[str] = []
        objects = self._objects(roles, od, eds, eds_where, notes, problems)
        configured: list[ConfiguredTpdo] = []
        if self.settings.listen_only:
            configured = self._configured_tpdos(axis_settings, od, eds, where, problems)
            objects = roles_mapped(configured, self.map, od)
            if axis_settings.marker_input_bit is None:
                objects.pop("digital_inputs", None)
            wanted = ["position", "velocity", "current"]
            if axis_settings.marker_input_bit is not None:
                wanted.append("digital_inputs")
            missing = [r for r in wanted if r not in objects]
            if missing:
                problems.append(
                    f"{where}.link: the drive's TPDOs as configured "
                    f"({_tpdo_source(axis_settings, eds)}) carry no "
                    f"{', '.join(missing)} object; listen_only reads what the controller "
                    "maps and cannot map more"
                )
                return None
        signals = ["current_a", "velocity_mm_min", "position_mm"]
        if "velocity_demand" in objects:
            signals.append("velocity_cmd_mm_min")
        if "digital_inputs" in objects:
            signals.append("marker")
        axis = LinkAxis(
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
            velocity_unit=axis_settings.velocity_unit or self.map.velocity_unit,
            columns={s: first_column + k for k, s in enumerate(signals)},
            notes=notes,
        )
        if self.settings.listen_only:
            passive_slots(axis, configured)
            self.rated_current_without_sdo(axis, where, problems)
            return axis
        pack_slots(axis, self.map)
        for slot in axis.slots:
            comm, mapping = 0x1800 + slot.number - 1, 0x1A00 + slot.number - 1
            if eds is not None and (comm not in od or mapping not in od):
                problems.append(
                    f"{eds_where}: {eds} has no TPDO{slot.number} "
                    f"(0x{comm:04X}/0x{mapping:04X}); lower "
                    f"{where}.link.first_tpdo"
                )
        return axis

    def _roles(
        self, axis_settings: CanOpenAxis, where: str, problems: list[str]
    ) -> list[str] | None:
        """The roles the link reads of the axis' drive; None when one cannot be read."""
        roles: list[str] = ["position", "velocity", "current"]
        if self.map.statusword is not None:
            roles.insert(0, "statusword")
        if axis_settings.read_velocity_demand:
            if self.map.velocity_demand is None:
                problems.append(
                    f"{where}.link.read_velocity_demand: object map "
                    f"{self.map.name} has no velocity demand object"
                )
                return None
            roles.append("velocity_demand")
        if axis_settings.marker_input_bit is not None:
            if self.map.digital_inputs is None:
                problems.append(
                    f"{where}.link.marker_input_bit: object map "
                    f"{self.map.name} has no digital inputs object (0x60FD)"
                )
                return None
            roles.append("digital_inputs")
        return roles

    def _objects(
        self,
        roles: Sequence[str],
        od: ObjectDictionary,
        eds: Path | None,
        eds_where: str,
        notes: list[str],
        problems: list[str],
    ) -> dict[str, MapObject]:
        """The object of each role: the map's, or what the EDS has of it (a fallback, a type)."""
        objects: dict[str, MapObject] = {}
        for role in roles:
            wanted = cast(MapObject, self.map.role(role))
            chosen = wanted if eds is None else _from_eds(wanted, od, eds, notes)
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
        return objects

    def _configured_tpdos(
        self,
        axis_settings: CanOpenAxis,
        od: ObjectDictionary,
        eds: Path | None,
        where: str,
        problems: list[str],
    ) -> list[ConfiguredTpdo]:
        """listen_only: the TPDOs the controller configured, from the tpdo table or the DCF."""
        if axis_settings.tpdo is not None:
            return [
                ConfiguredTpdo(number, table.cob_id, 1, list(table.mapping))
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
            tpdo = dcf_tpdo(od, number)
            if tpdo is not None:
                found.append(tpdo)
        for tpdo in found:
            if roles_mapped([tpdo], self.map, od) and tpdo.transmission_type != 1:
                problems.append(
                    f"{where}.link.eds: {eds}: TPDO{tpdo.number} (0x{tpdo.cob_id:03X}) has "
                    f"transmission type {tpdo.transmission_type}; a row per SYNC needs 1 "
                    "(sent on every SYNC)"
                )
        return found

    def rated_current_without_sdo(self, axis: LinkAxis, where: str, problems: list[str]) -> None:
        """Rated current and scales when the drive cannot be asked: configured, else the DCF's."""
        axis.rated_current_a = axis.configured_rated_current_a
        needs = any(o.unit.startswith("permille") for o in axis.objects.values())
        if needs and axis.rated_current_a is None:
            obj = self.map.rated_current
            value = od_value(axis.od, obj.index, obj.subindex) if obj and axis.eds else None
            if obj is None or not value or value <= 0:
                label = f" or a DCF with its {obj.label}" if obj is not None else ""
                problems.append(
                    f"{where}.rated_current_a: the current comes in per mille of the rated "
                    f"current, and without SDO the drive cannot be asked: set it{label}"
                )
                return
            axis.rated_current_a = value / 1000.0
            axis.notes.append(f"rated current {value / 1000:g} A from {axis.eds} ({obj.label})")
        axis.set_scales()

    # --- a CAN log ----------------------------------------------------------------------

    def prepare_offline(self) -> list[str]:
        """For a CAN log: rated currents without SDO, the predefined COB-IDs.

        Returns:
            The problems: a rated current or a COB-ID that cannot be known without SDO.
        """
        problems: list[str] = []
        for axis in self.axes:
            where = f"axes[{axis.position}]"
            if axis.rated_current_a is None and not axis.scales:
                self.rated_current_without_sdo(axis, where, problems)
            for slot in axis.slots:
                if slot.cob_id:
                    continue
                if slot.number > 4:
                    problems.append(
                        f"{where}.link.first_tpdo: TPDO{slot.number} has no predefined COB-ID; "
                        "the log cannot tell which frames are its"
                    )
                slot.cob_id = 0x180 + 0x100 * (slot.number - 1) + axis.node_id
        return problems


def pack_slots(axis: LinkAxis, object_map: ObjectMap) -> None:
    """Pack the axis' objects into TPDOs following the map's layout."""
    groups: list[list[str]] = []
    placed = {r for group in object_map.tpdo.layout for r in group}
    # A map of one's own may define the digital inputs without placing them: a TPDO of its own.
    extra: list[list[str]] = [["digital_inputs"]] if "digital_inputs" not in placed else []
    layout: list[list[str]] = [list(group) for group in object_map.tpdo.layout]
    for group in [*layout, *extra]:
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
            SlotField(
                r,
                axis.objects[r],
                axis.columns.get(SIGNAL_BY_ROLE.get(r, ""), -1),
                bit=axis.settings.marker_input_bit if r == "digital_inputs" else None,
            )
            for r in slot_roles
        ]
        slot = Slot(axis, axis.settings.first_tpdo + k, fields)
        slot.update_dtype()
        axis.slots.append(slot)


def passive_slots(axis: LinkAxis, configured: list[ConfiguredTpdo]) -> None:
    """The slots of the TPDOs that carry an object the link reads, as configured."""
    axis.slots = []
    for tpdo in configured:
        fields: list[SlotField] = []
        for entry in tpdo.mapping:
            index, subindex, size = entry >> 16, (entry >> 8) & 0xFF, (entry & 0xFF) // 8
            role = next(
                (r for r, o in axis.objects.items() if (o.index, o.subindex) == (index, subindex)),
                "",
            )
            if role:
                obj = axis.objects[role]
                column = axis.columns.get(SIGNAL_BY_ROLE.get(role, ""), STATUS_COLUMN)
                bit = axis.settings.marker_input_bit if role == "digital_inputs" else None
                fields.append(SlotField(role, obj, column, bit=bit))
            else:
                fields.append(SlotField("", None, UNREAD, size))
        if any(f.role for f in fields):
            slot = Slot(axis, tpdo.number, fields, cob_id=tpdo.cob_id)
            slot.update_dtype()
            axis.slots.append(slot)


def _from_eds(
    wanted: MapObject, od: ObjectDictionary, eds: Path, notes: list[str]
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
                    f"({unit_text(obj.unit)})"
                )
            return chosen
        obj = obj.fallback
    return None


def od_value(od: ObjectDictionary, index: int, subindex: int) -> int | None:
    """A DCF's configured value (ParameterValue), else the EDS default; None when absent."""
    var = od_variable(od, index, subindex)
    if var is None:
        return None
    value = var.value if var.value is not None else var.default
    return value if isinstance(value, int) else None


def dcf_tpdo(od: ObjectDictionary, number: int) -> ConfiguredTpdo | None:
    """TPDO ``number`` of a DCF/EDS when it is valid and fully mapped, else None."""
    comm, mapping = 0x1800 + number - 1, 0x1A00 + number - 1
    cob_id = od_value(od, comm, 1)
    count = od_value(od, mapping, 0)
    if cob_id is None or cob_id & COB_INVALID or not count:
        return None
    entries = [od_value(od, mapping, k) for k in range(1, count + 1)]
    if any(entry is None for entry in entries):
        return None
    transmission = od_value(od, comm, 2)
    return ConfiguredTpdo(
        number,
        cob_id & 0x7FF,
        255 if transmission is None else transmission,
        entries,  # type: ignore[arg-type]
    )


def roles_mapped(
    configured: Sequence[ConfiguredTpdo], object_map: ObjectMap, od: ObjectDictionary
) -> dict[str, MapObject]:
    """The roles whose object (or a fallback) the TPDOs map, with the mapped size's type."""
    mapped = {
        (entry >> 16, (entry >> 8) & 0xFF): (entry & 0xFF) // 8
        for tpdo in configured
        for entry in tpdo.mapping
    }
    found: dict[str, MapObject] = {}
    roles = ("statusword", "position", "velocity", "velocity_demand", "current", "digital_inputs")
    for role in roles:
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


def unit_text(unit: str) -> str:
    """A unit of the object map in words, for notes."""
    return {
        "permille_rated_torque": "per mille of the rated torque, taken as per mille of the "
        "rated current (torque constant × rated current = rated torque)",
        "permille_rated_current": "per mille of the rated current",
        "mA": "mA",
    }.get(unit, unit)
