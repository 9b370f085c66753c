"""The object dictionary of a simulated CiA 402 drive: values, defaults and CiA 301 rules.

A :class:`Dictionary` holds every object of an EDS/DCF or of a built-in
dictionary as bytes (:class:`Entry`: data type, access, PDO-mappable), the
defaults a reset returns to, and the rules of a write like a drive keeps them:
access rights and sizes; a valid PDO keeps its COB-ID; a TPDO's mapping changes
only while the PDO is disabled and its entry count is 0, and maps objects that
exist, are mappable and fit 64 bits. A broken rule is an
:class:`~ncmeasure.sim.cia402.sdo.SdoAbortError` with its abort code.
"""

from __future__ import annotations

import functools
import math
import struct
from dataclasses import dataclass
from typing import Any

from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable

from ncmeasure.sim.cia402.sdo import (
    ABORT_INCOMPATIBLE,
    ABORT_LENGTH_HIGH,
    ABORT_LENGTH_LOW,
    ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX,
    ABORT_NOT_MAPPABLE,
    ABORT_PDO_LENGTH,
    ABORT_READ_ONLY,
    ABORT_UNSUPPORTED,
    ABORT_VALUE_RANGE,
    SdoAbortError,
)

__all__ = ["INT_FORMATS", "Dictionary", "Entry", "TpdoConfig", "clamp"]

INT_FORMATS = {
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
"""struct codes of the CiA 301 data types the drive packs and unpacks."""


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
class Entry:
    """One object (or sub-index) of the dictionary."""

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
        code = INT_FORMATS.get(self.data_type)
        return struct.calcsize("<" + code) if code else None


def _entries_of(od: ObjectDictionary) -> dict[tuple[int, int], Entry]:
    entries: dict[tuple[int, int], Entry] = {}

    def add(var: ODVariable) -> None:
        value: Any = var.value if var.value is not None else var.default
        data_type = var.data_type or 0
        code = INT_FORMATS.get(data_type)
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
        entries[(var.index, var.subindex)] = Entry(
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


@functools.cache
def _bounds(fmt: str) -> tuple[int, int]:
    """The least and the greatest value of the integer type of struct code ``fmt``."""
    bits = 8 * struct.calcsize("<" + fmt)
    if fmt.islower():
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def clamp(value: float, fmt: str) -> int:
    """``value`` rounded and clamped to the integer type of struct code ``fmt``."""
    if not math.isfinite(value):
        return 0
    low, high = _bounds(fmt)
    return int(min(max(round(value), low), high))


class Dictionary:
    """A simulated drive's objects as bytes: the values written, the defaults, the rules.

    Not thread-safe: the drive calls it under its lock.
    """

    def __init__(self, od: ObjectDictionary) -> None:
        self.defaults = _entries_of(od)
        self.entries = {
            k: Entry(e.name, e.data_type, e.access, e.data, e.mappable)
            for k, e in self.defaults.items()
        }

    def set_default(self, key: tuple[int, int], value: int) -> None:
        """An integer object's default (and value), clamped to its type; nothing if absent."""
        entry = self.defaults.get(key)
        code = INT_FORMATS.get(entry.data_type) if entry else None
        if entry is not None and code is not None:
            entry.data = struct.pack("<" + code, clamp(value, code))
            self.entries[key].data = entry.data

    def int_value(self, index: int, subindex: int, default: int) -> int:
        """An integer object's value; ``default`` when there is none of that type and size."""
        entry = self.entries.get((index, subindex))
        code = INT_FORMATS.get(entry.data_type) if entry else None
        if entry is None or code is None or len(entry.data) != struct.calcsize("<" + code):
            return default
        return int(struct.unpack("<" + code, entry.data)[0])

    def reset(self, communication_only: bool) -> None:
        """Back to the defaults: every object, or the communication area 0x1000-0x1FFF."""
        for key, default in self.defaults.items():
            if not communication_only or 0x1000 <= key[0] <= 0x1FFF:
                entry = self.entries[key]
                entry.data = default.data

    def tpdos(self) -> list[TpdoConfig]:
        """The TPDOs of the dictionary as they are now."""
        configs = []
        for number in range(512):
            comm = self.entries.get((0x1800 + number, 1))
            if comm is None:
                continue
            cob = struct.unpack("<I", comm.data.ljust(4, b"\0"))[0]
            trans = self.int_value(0x1800 + number, 2, 255)
            count = self.int_value(0x1A00 + number, 0, 0)
            mapping = []
            for sub in range(1, count + 1):
                entry = self.int_value(0x1A00 + number, sub, 0)
                mapping.append((entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF))
            configs.append(
                TpdoConfig(number + 1, cob & 0x7FF, not cob & 0x80000000, trans, tuple(mapping))
            )
        return configs

    def find(self, index: int, subindex: int) -> Entry:
        """The entry of an object.

        Raises:
            SdoAbortError: No such object, or no such sub-index.
        """
        entry = self.entries.get((index, subindex))
        if entry is None:
            if any(k[0] == index for k in self.entries):
                raise SdoAbortError(ABORT_NO_SUBINDEX)
            raise SdoAbortError(ABORT_NO_OBJECT)
        return entry

    def write(self, index: int, subindex: int, data: bytes) -> None:
        """Write an object as a drive does (access, size, the PDO rules of CiA 301).

        Raises:
            SdoAbortError: The drive refuses, with the abort code it answers.
        """
        entry = self.find(index, subindex)
        if not entry.writable:
            raise SdoAbortError(ABORT_READ_ONLY)
        size = entry.fixed_size
        if size is not None and len(data) != size:
            raise SdoAbortError(ABORT_LENGTH_HIGH if len(data) > size else ABORT_LENGTH_LOW)
        if 0x1800 <= index <= 0x19FF and subindex == 1:
            old = self.int_value(index, 1, 0)
            new = struct.unpack("<I", data)[0]
            if not old & 0x80000000 and not new & 0x80000000 and (old ^ new) & 0x1FFFFFFF:
                raise SdoAbortError(ABORT_VALUE_RANGE)  # a valid PDO keeps its COB-ID
        if 0x1A00 <= index <= 0x1BFF:
            self._check_mapping(index, subindex, data)
        entry.data = bytes(data)

    def _check_mapping(self, index: int, subindex: int, data: bytes) -> None:
        cob = self.int_value(index - 0x200, 1, 0x80000000)
        if not cob & 0x80000000:
            raise SdoAbortError(ABORT_UNSUPPORTED)  # change the mapping of a disabled PDO only
        if subindex != 0:
            if self.int_value(index, 0, 0) != 0:
                raise SdoAbortError(ABORT_UNSUPPORTED)  # entries change while the count is 0
            return
        count = data[0]
        if count > 8:
            raise SdoAbortError(ABORT_VALUE_RANGE)
        bits = 0
        for sub in range(1, count + 1):
            value = self.int_value(index, sub, 0)
            key = (value >> 16, (value >> 8) & 0xFF)
            target = self.entries.get(key)
            if target is None:
                raise SdoAbortError(ABORT_NO_OBJECT)
            if not target.mappable:
                raise SdoAbortError(ABORT_NOT_MAPPABLE)
            size = target.fixed_size
            if size is None or 8 * size != value & 0xFF:
                raise SdoAbortError(ABORT_INCOMPATIBLE)
            bits += value & 0xFF
        if bits > 64:
            raise SdoAbortError(ABORT_PDO_LENGTH)
