"""The torque offsets of ``compensation --controller cia402``: the file, and reading it back.

``ncmeasure compensation --controller cia402`` writes a list of SDO writes
(``[[sdo_write]]``, TOML) for the user to review. :func:`read_offset_file`
takes that file apart and refuses anything but the torque offset 0x60B2:00 as
INTEGER16: the only object ncmeasure writes. ``ncmeasure apply-compensation``
then writes the entries over CANopen
(:func:`ncmeasure.links.canopen.offsets.apply_offsets`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ncmeasure.errors import ConfigError
from ncmeasure.inputs import MAX_TOML_BYTES, parse_toml, read_text

__all__ = ["TORQUE_OFFSET", "OffsetWrite", "read_offset_file"]

TORQUE_OFFSET = (0x60B2, 0)
"""CiA 402 torque offset, sub-index 0: INTEGER16, per mille of the rated torque."""


@dataclass(frozen=True)
class OffsetWrite:
    """One ``[[sdo_write]]`` of the file: the torque offset of one axis' drive."""

    axis: str
    node_id: int
    value: int
    """Per mille of the rated torque (0x6076)."""


INT16 = (-32768, 32767)
MAX_OFFSET_PER_MILLE = 1000
"""The largest torque offset written: the rated torque. More holds no axis up; it is a typo."""
_KEYS = {"axis", "node_id", "index", "subindex", "data_type", "value"}


def read_offset_file(path: Path) -> list[OffsetWrite]:
    """The torque offsets of a ``compensation --controller cia402`` file.

    Raises:
        ConfigError: Not such a file; an entry that writes another object, another
            data type or a value outside INTEGER16; an axis or node id twice.
    """
    tables = parse_toml(
        read_text(path, "a cia402 compensation file (.toml)", MAX_TOML_BYTES), str(path)
    )
    entries = tables.get("sdo_write")
    if set(tables) != {"sdo_write"} or not isinstance(entries, list) or not entries:
        raise ConfigError(
            f"{path}: not a cia402 compensation file (one [[sdo_write]] table per axis, "
            "from ncmeasure compensation --controller cia402)"
        )
    writes: list[OffsetWrite] = []
    for number, entry in enumerate(entries, start=1):
        where = f"{path}: [[sdo_write]] {number}"
        if not isinstance(entry, dict) or set(entry) != _KEYS:
            raise ConfigError(f"{where}: expected the keys {', '.join(sorted(_KEYS))}")
        if (entry["index"], entry["subindex"]) != TORQUE_OFFSET:
            raise ConfigError(
                f"{where}: writes {_object(entry['index'], entry['subindex'])}; ncmeasure writes "
                "only the torque offset 0x60B2:00"
            )
        if entry["data_type"] != "INTEGER16":
            raise ConfigError(f"{where}: 0x60B2 is INTEGER16, not {entry['data_type']!r}")
        axis, node_id, value = entry["axis"], entry["node_id"], entry["value"]
        if not isinstance(axis, str) or not axis:
            raise ConfigError(f"{where}: axis must be the axis name")
        if not _is_int(node_id) or not 1 <= node_id <= 127:
            raise ConfigError(f"{where}: node_id must be 1…127, not {node_id!r}")
        if not _is_int(value) or not INT16[0] <= value <= INT16[1]:
            raise ConfigError(f"{where}: value must be an INTEGER16, not {value!r}")
        if abs(value) > MAX_OFFSET_PER_MILLE:
            raise ConfigError(
                f"{where}: value {value} is {value / 10:g} % of the rated torque; a gravity "
                f"compensation stays within ±{MAX_OFFSET_PER_MILLE} (the rated torque): "
                "check the file"
            )
        writes.append(OffsetWrite(axis, node_id, value))
    for field in ("axis", "node_id"):
        seen = [getattr(w, field) for w in writes]
        twice = sorted({str(v) for v in seen if seen.count(v) > 1})
        if twice:
            raise ConfigError(f"{path}: {field} {', '.join(twice)} more than once")
    return writes


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _object(index: Any, subindex: Any) -> str:
    if _is_int(index) and _is_int(subindex):
        return f"0x{index:04X}:{subindex:02X}"
    return f"{index!r}:{subindex!r}"
