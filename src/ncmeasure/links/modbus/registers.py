"""Modbus register maps and the register codec: where a drive keeps its values, and how.

A *register map* is a TOML file per drive type (``registermaps/*.toml``) that
says where current, velocity and position live (address, holding or input
register, data type, word order) and how a raw value becomes A, mm/min or mm.
:func:`load_register_map` validates a map strictly: overlapping registers,
32-bit values running past 65535, unknown types or units are a
:class:`~ncmeasure.errors.ConfigError` naming the file and the entry.
:func:`decode_words` / :func:`encode_value` turn registers into values and
back; the link (:mod:`.link`) and the simulated drive
(:mod:`ncmeasure.sim.modbus_drive`) share them, and the Modbus exception
texts.
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic_core import PydanticCustomError

from ncmeasure.config import format_validation_error
from ncmeasure.errors import ConfigError
from ncmeasure.inputs import MAX_TOML_BYTES, parse_toml, read_text
from ncmeasure.samples import SIGNAL_UNITS

__all__ = [
    "EXCEPTION_MEANINGS",
    "FUNCTION_NAMES",
    "MAP_SIGNALS",
    "STRUCT",
    "DataType",
    "MapSource",
    "RegisterMap",
    "SignalRegister",
    "builtin_register_maps",
    "decode_words",
    "encode_value",
    "exception_text",
    "load_register_map",
    "signal_factor",
]

log = logging.getLogger(__name__)

#: The signals a register map may describe, in channel order.
MAP_SIGNALS: tuple[str, ...] = (
    "current_a",
    "velocity_mm_min",
    "position_mm",
    "velocity_cmd_mm_min",
)
_REQUIRED = ("current_a", "velocity_mm_min", "position_mm")

#: What a Modbus exception code means (Modbus Application Protocol V1.1b3, 7).
EXCEPTION_MEANINGS: Mapping[int, str] = {
    1: "illegal function: the drive does not support this read function; "
    "holding or input registers in the register map?",
    2: "illegal data address: a register in the requested range does not exist "
    "on the drive; wrong register map?",
    3: "illegal data value: the drive refuses the request, e.g. its register count",
    4: "server device failure: the drive failed while answering",
    5: "acknowledge: the drive accepted the request but needs long to process it",
    6: "server device busy: the drive is processing a long command",
    7: "negative acknowledge: the drive cannot perform the request",
    8: "memory parity error in the drive",
    10: "gateway path unavailable: the gateway has no path to this unit id",
    11: "gateway target device failed to respond: no drive answered at this unit id "
    "behind the gateway",
}

FUNCTION_NAMES: Mapping[str, str] = {
    "holding": "read holding registers (03)",
    "input": "read input registers (04)",
    "discrete": "read discrete inputs (02)",
    "coil": "read coils (01)",
}
_MAX_REGISTERS_PER_REQUEST = 125  # Modbus limit of function 03/04

DataType = Literal["int16", "uint16", "int32", "uint32", "float32"]
_WORDS: Mapping[str, int] = {"int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "float32": 2}
STRUCT: Mapping[str, str] = {
    "int16": ">h",
    "uint16": ">H",
    "int32": ">i",
    "uint32": ">I",
    "float32": ">f",
}
_LIMITS: Mapping[str, tuple[int, int]] = {
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
}

#: Units a map may give per signal; other than the signal's own unit they need
#: axis data (screw lead, encoder counts per revolution, rated current).
_ALLOWED_UNITS: Mapping[str, tuple[str, ...]] = {
    "current_a": ("A", "rated"),
    "velocity_mm_min": ("mm/min", "mm/s", "rpm"),
    "position_mm": ("mm", "rev", "counts"),
    "velocity_cmd_mm_min": ("mm/min", "mm/s", "rpm"),
}


def exception_text(code: int) -> str:
    """``exception 2 (illegal data address: ...)`` for a Modbus exception code."""
    return f"exception {code} ({EXCEPTION_MEANINGS.get(code, 'unknown exception code')})"


# --- register maps --------------------------------------------------------------------


class _MapModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class MapSource(_MapModel):
    """Where a register map comes from: the drive documentation it follows."""

    title: str = Field(min_length=1, description="Document title.")
    section: str = Field(default="", description="Section, table and page.")
    url: str = Field(default="", description="Where the document can be read.")
    notes: str = Field(default="", description="What the document leaves open.")


class SignalRegister(_MapModel):
    """Where one signal lives and how its raw value becomes a physical value.

    ``value = raw × scale`` in ``unit``; units other than the signal's own are
    converted with the axis' data (see :func:`signal_factor`).
    """

    address: Annotated[int, Field(ge=0, le=65535)]
    function: Literal["holding", "input"]
    type: DataType
    word_order: Literal["big", "little"] = "big"
    scale: float = 1.0
    unit: str

    @field_validator("scale")
    @classmethod
    def _check_scale(cls, value: float) -> float:
        if not math.isfinite(value) or value == 0:
            raise PydanticCustomError("scale", "must be a finite number other than 0")
        return value

    @property
    def words(self) -> int:
        """Number of 16-bit registers the value occupies."""
        return _WORDS[self.type]

    @property
    def last_address(self) -> int:
        """Address of the value's last register."""
        return self.address + self.words - 1


class RegisterMap(_MapModel):
    """A validated register map (one TOML file): drive, source, signals."""

    name: str = Field(min_length=1)
    drive: str = Field(min_length=1)
    source: MapSource
    counts_per_rev: Annotated[int, Field(gt=0)] | None = Field(
        default=None,
        description="Encoder counts per motor revolution for 'counts' units, if the "
        "drive fixes it; otherwise set link.counts_per_rev per axis.",
    )
    signals: dict[
        Literal["current_a", "velocity_mm_min", "position_mm", "velocity_cmd_mm_min"],
        SignalRegister,
    ]

    def ordered_signals(self) -> list[tuple[str, SignalRegister]]:
        """The map's signals in channel order."""
        order = {name: index for index, name in enumerate(MAP_SIGNALS)}
        return [
            (str(name), entry)
            for name, entry in sorted(self.signals.items(), key=lambda item: order[item[0]])
        ]

    def describe(self) -> dict[str, Any]:
        """The map as plain data for a recording's metadata."""
        return self.model_dump(mode="json")


def _map_problems(reg_map: RegisterMap) -> list[str]:
    """Checks across entries of a map, as ``location: message`` lines."""
    problems: list[str] = []
    for name in _REQUIRED:
        if name not in reg_map.signals:
            problems.append(f"signals.{name}: required signal is missing")
    entries = reg_map.ordered_signals()
    for name, entry in entries:
        if entry.last_address > 65535:
            problems.append(
                f"signals.{name}.address: a {entry.type} at {entry.address} needs registers "
                f"{entry.address}..{entry.last_address}, past the last address 65535"
            )
        if entry.unit not in _ALLOWED_UNITS[name]:
            allowed = ", ".join(repr(u) for u in _ALLOWED_UNITS[name])
            problems.append(f"signals.{name}.unit: {entry.unit!r} is not one of {allowed}")
    for index, (name, entry) in enumerate(entries):
        for other_name, other in entries[:index]:
            if other.function != entry.function:
                continue
            if entry.address <= other.last_address and other.address <= entry.last_address:
                problems.append(
                    f"signals.{name}: {entry.function} registers "
                    f"{entry.address}..{entry.last_address} overlap signals.{other_name} "
                    f"({other.address}..{other.last_address})"
                )
    for function in ("holding", "input"):
        used = [e for _, e in entries if e.function == function]
        if used:
            low = min(e.address for e in used)
            high = max(e.last_address for e in used)
            if high - low + 1 > _MAX_REGISTERS_PER_REQUEST:
                problems.append(
                    f"signals: the {function} registers span {low}..{high} "
                    f"({high - low + 1} registers), more than the "
                    f"{_MAX_REGISTERS_PER_REQUEST} one Modbus request can read"
                )
    return problems


def _maps_dir() -> Any:
    return resources.files("ncmeasure.links.modbus").joinpath("registermaps")


def builtin_register_maps() -> list[str]:
    """Names of the register maps that ship with ncmeasure."""
    return sorted(
        entry.name.removesuffix(".toml")
        for entry in _maps_dir().iterdir()
        if entry.name.endswith(".toml")
    )


def load_register_map(name_or_path: str | Path) -> RegisterMap:
    """Read and validate a register map.

    Args:
        name_or_path: A built-in map name (``generic``, ``kinetix3``, ...) or
            the path of a TOML file (anything with a ``/`` or ending ``.toml``).

    Raises:
        ConfigError: unknown name, unreadable file, invalid TOML, or an invalid
            map; one ``file: location: message`` line per problem.
    """
    text_name = str(name_or_path)
    if isinstance(name_or_path, Path) or "/" in text_name or text_name.endswith(".toml"):
        path = Path(name_or_path)
        where = str(path)
        text = read_text(
            path,
            "a register map (.toml)",
            MAX_TOML_BYTES,
            missing=f"register map {where}: no such file",
        )
    else:
        resource = _maps_dir().joinpath(f"{text_name}.toml")
        if not resource.is_file():
            known = ", ".join(builtin_register_maps())
            raise ConfigError(
                f"unknown register map {text_name!r}; built-in maps: {known} "
                "(or give the path of a .toml file)"
            )
        where = f"built-in register map {text_name}"
        text = resource.read_text(encoding="utf-8")
    data = parse_toml(text, where)
    try:
        reg_map = RegisterMap.model_validate(data)
    except ValidationError as exc:
        lines = [f"{where}: {line}" for line in format_validation_error(exc)]
        raise ConfigError(f"{where} is not a valid register map", lines) from exc
    problems = _map_problems(reg_map)
    if problems:
        raise ConfigError(
            f"{where} is not a valid register map", [f"{where}: {line}" for line in problems]
        )
    return reg_map


def signal_factor(
    signal: str,
    entry: SignalRegister,
    *,
    screw_lead_mm: float | None = None,
    rated_current_a: float | None = None,
    counts_per_rev: int | None = None,
    scale: float | None = None,
) -> float:
    """The factor from a raw register value to the signal's unit (A, mm/min, mm).

    ``value = raw × factor`` with ``factor = scale × k`` and ``k`` by unit:
    the signal's own unit 1; ``mm/s`` 60; ``rpm`` and ``rev`` the screw lead in
    mm; ``counts`` screw lead / counts per revolution; ``rated`` the rated
    current in A.

    Raises:
        ValueError: the unit needs axis data that is missing (the message says which).
    """
    k: float
    unit = entry.unit
    if unit == SIGNAL_UNITS[signal]:
        k = 1.0
    elif unit == "mm/s":
        k = 60.0
    elif unit in ("rpm", "rev", "counts"):
        if screw_lead_mm is None:
            raise ValueError(
                f"screw_lead_mm: the register map gives {signal} in {unit}; "
                "set the axis' screw lead to convert it"
            )
        k = screw_lead_mm
        if unit == "counts":
            if counts_per_rev is None:
                raise ValueError(
                    f"counts_per_rev: the register map gives {signal} in encoder "
                    "counts; set link.counts_per_rev for the axis"
                )
            k = screw_lead_mm / counts_per_rev
    elif unit == "rated":
        if rated_current_a is None:
            raise ValueError(
                f"rated_current_a: the register map gives {signal} in parts of the "
                "rated current; set the axis' rated current"
            )
        k = rated_current_a
    else:  # excluded by validation; kept for maps built in code
        raise ValueError(f"unit {unit!r} of {signal} is not supported")
    return (entry.scale if scale is None else scale) * k


def decode_words(words: Sequence[int], data_type: str, word_order: str = "big") -> float:
    """The raw value of a data type from its registers (16-bit words)."""
    ordered = list(reversed(words)) if word_order == "little" else list(words)
    data = b"".join(int(w).to_bytes(2, "big") for w in ordered)
    return float(struct.unpack(STRUCT[data_type], data)[0])


def encode_value(raw: float, data_type: str, word_order: str = "big") -> list[int]:
    """The registers holding ``raw``; integers are rounded and saturate at their range."""
    if data_type == "float32":
        data = struct.pack(">f", raw)
    else:
        low, high = _LIMITS[data_type]
        number = round(raw) if math.isfinite(raw) else 0
        data = struct.pack(STRUCT[data_type], min(max(number, low), high))
    words = [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]
    return list(reversed(words)) if word_order == "little" else words
