"""The poll plan of a Modbus link: which registers a poll cycle reads, how they become a row.

Built once from the settings and the register maps (:func:`build_plan`): per
axis, one read request per register type covering all of that axis' signals
of the type, each signal with its place in the answer, its data type, word
order and the factor from raw value to A, mm/min or mm. The plan decodes an
answer into the row's columns (:meth:`PollPlan.decode`) and says how long a
cycle takes on an RTU line, so a poll rate the line cannot carry is refused
or lowered (:func:`poll_rate`).
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from ncmeasure.errors import ConfigError
from ncmeasure.links.base import AxisBinding
from ncmeasure.links.modbus.registers import (
    FUNCTION_NAMES,
    STRUCT,
    RegisterMap,
    load_register_map,
    signal_factor,
)
from ncmeasure.links.modbus.settings import ModbusAxis, ModbusSettings
from ncmeasure.samples import SIGNAL_UNITS, Channel

__all__ = [
    "RTU_MARGIN",
    "FieldPlan",
    "PollPlan",
    "Request",
    "build_plan",
    "poll_rate",
    "rtu_char_s",
    "rtu_silence_s",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FieldPlan:
    """One signal in a request's answer: its column in the row and how to decode it."""

    column: int
    offset: int
    words: int
    fmt: str
    little: bool
    factor: float
    bit: int | None = None
    """The marker: this bit of the register (0 for an input or coil) is the value."""


@dataclass(frozen=True)
class Request:
    """One read request of a poll cycle: an axis' registers of one type."""

    axis: str
    unit_id: int
    function: Literal["holding", "input", "discrete", "coil"]
    address: int
    count: int
    fields: tuple[FieldPlan, ...]

    def describe(self) -> str:
        last = self.address + self.count - 1
        return (
            f"{FUNCTION_NAMES[self.function]} {self.address}..{last} from unit "
            f"{self.unit_id} (axis {self.axis})"
        )


@dataclass(frozen=True)
class PollPlan:
    """What a poll cycle reads and the row it makes."""

    channels: tuple[Channel, ...]
    requests: tuple[Request, ...]
    maps: Mapping[str, RegisterMap]
    """Axis name -> its register map."""
    factors: Mapping[str, Mapping[str, float]]
    """Axis name -> signal -> factor from raw value to the signal's unit."""

    @staticmethod
    def decode(request: Request, registers: Sequence[int], row: list[float]) -> None:
        """Write the signals of ``request``'s answer into their columns of ``row``."""
        for plan in request.fields:
            if plan.bit is not None:
                row[plan.column] = float((registers[plan.offset] >> plan.bit) & 1)
                continue
            words = list(registers[plan.offset : plan.offset + plan.words])
            if plan.little:
                words.reverse()
            data = b"".join(w.to_bytes(2, "big") for w in words)
            row[plan.column] = struct.unpack(plan.fmt, data)[0] * plan.factor

    def describe_maps(self, axes: Sequence[AxisBinding]) -> dict[str, Any]:
        """Each axis' register map, its source and every signal's factor (for describe())."""
        maps: dict[str, Any] = {}
        for binding in axes:
            reg_map = self.maps[binding.name]
            maps[binding.name] = {
                "name": reg_map.name,
                "drive": reg_map.drive,
                "source": reg_map.source.model_dump(mode="json"),
                "signals": {
                    signal: {
                        **entry.model_dump(mode="json"),
                        "factor": self.factors[binding.name][signal],
                    }
                    for signal, entry in reg_map.ordered_signals()
                },
            }
        return maps


def build_plan(settings: ModbusSettings, axes: Sequence[AxisBinding]) -> PollPlan:
    """The poll plan of ``axes`` with their register maps.

    Raises:
        ConfigError: a unit id twice, an unknown or invalid register map, axis
            data the map needs (screw lead, counts per revolution) missing, a
            scale for a signal the map has not; one located line per problem.
    """
    problems: list[str] = []
    loaded: dict[str, RegisterMap] = {}
    maps: dict[str, RegisterMap] = {}
    factors: dict[str, dict[str, float]] = {}
    used_units: dict[int, str] = {}
    channels: list[Channel] = []
    requests: list[Request] = []
    for index, binding in enumerate(axes):
        axis_settings = binding.settings
        if not isinstance(axis_settings, ModbusAxis):
            raise ConfigError(f"axes[{index}].link: not Modbus axis settings")
        if axis_settings.unit_id in used_units:
            problems.append(
                f"axes[{index}].link.unit_id: unit {axis_settings.unit_id} is already "
                f"used by axis {used_units[axis_settings.unit_id]}"
            )
        used_units[axis_settings.unit_id] = binding.name
        map_name = axis_settings.register_map or settings.register_map
        where = (
            f"axes[{index}].link.register_map"
            if axis_settings.register_map
            else "link.register_map"
        )
        try:
            if map_name not in loaded:
                loaded[map_name] = load_register_map(map_name)
        except ConfigError as exc:
            problems.append(f"{where}: {exc.message}")
            problems += [f"  {line}" for line in exc.problems]
            continue
        reg_map = loaded[map_name]
        maps[binding.name] = reg_map
        factors[binding.name] = _factors(index, binding, axis_settings, reg_map, problems)
        first_column = len(channels)
        signals = [s for s, _ in reg_map.ordered_signals()]
        channels += [Channel(binding.name, s, SIGNAL_UNITS[s]) for s in signals]
        requests += _requests(
            binding.name, axis_settings.unit_id, reg_map, first_column, factors[binding.name]
        )
        marker = axis_settings.marker
        if marker is not None:
            channels.append(Channel(binding.name, "marker", SIGNAL_UNITS["marker"]))
            field = FieldPlan(len(channels) - 1, 0, 1, ">H", False, 1.0, bit=marker.bit or 0)
            unit = marker.unit_id or axis_settings.unit_id
            requests.append(
                Request(binding.name, unit, marker.function, marker.address, 1, (field,))
            )
    if problems:
        raise ConfigError("the settings of the modbus link are not valid", problems)
    return PollPlan(tuple(channels), tuple(requests), maps, factors)


def _factors(
    index: int,
    binding: AxisBinding,
    axis_settings: ModbusAxis,
    reg_map: RegisterMap,
    problems: list[str],
) -> dict[str, float]:
    """Raw value -> unit factor of each signal of the axis' map; problems appended."""
    factors: dict[str, float] = {}
    counts = axis_settings.counts_per_rev or reg_map.counts_per_rev
    for signal, entry in reg_map.ordered_signals():
        try:
            factors[signal] = signal_factor(
                signal,
                entry,
                screw_lead_mm=binding.axis.screw_lead_mm,
                rated_current_a=binding.axis.rated_current_a,
                counts_per_rev=counts,
                scale=axis_settings.scales.get(signal),  # type: ignore[call-overload]
            )
        except ValueError as exc:
            key, _, message = str(exc).partition(": ")
            loc = f"axes[{index}].link.{key}" if key == "counts_per_rev" else f"axes[{index}].{key}"
            problems.append(f"{loc}: {message} ({reg_map.name})")
    for signal in axis_settings.scales:
        if signal not in reg_map.signals:
            problems.append(
                f"axes[{index}].link.scales.{signal}: register map {reg_map.name} has no {signal}"
            )
    return factors


def _requests(
    axis: str,
    unit_id: int,
    reg_map: RegisterMap,
    first_column: int,
    factors: Mapping[str, float],
) -> list[Request]:
    """One request per register type the axis' map uses, covering all its signals of it."""
    requests: list[Request] = []
    for function in ("holding", "input"):
        entries = [
            (first_column + i, s, e)
            for i, (s, e) in enumerate(reg_map.ordered_signals())
            if e.function == function
        ]
        if not entries:
            continue
        low = min(e.address for _, _, e in entries)
        high = max(e.last_address for _, _, e in entries)
        fields = tuple(
            FieldPlan(
                column,
                e.address - low,
                e.words,
                STRUCT[e.type],
                e.word_order == "little",
                factors.get(s, e.scale),
            )
            for column, s, e in entries
        )
        requests.append(Request(axis, unit_id, function, low, high - low + 1, fields))
    return requests


# --- timing on an RTU line -------------------------------------------------------------


def rtu_char_s(settings: ModbusSettings) -> float:
    """Time of one character on the serial line."""
    bits = 1 + settings.bytesize + (0 if settings.parity == "N" else 1) + settings.stopbits
    return bits / settings.baudrate


def rtu_silence_s(settings: ModbusSettings) -> float:
    """The silent interval the line needs between two frames."""
    # Modbus over serial line V1.02, 2.5.1.1: 3.5 characters, fixed 1.75 ms above 19200 baud.
    return 3.5 * rtu_char_s(settings) if settings.baudrate <= 19200 else 0.00175


#: Margin on the bare RTU frame times for the drives' own answer delay.
RTU_MARGIN = 1.25


def rtu_cycle_s(settings: ModbusSettings, requests: Sequence[Request]) -> float:
    """Shortest RTU poll cycle: request and answer frames plus silent intervals."""
    char_s = rtu_char_s(settings)
    silence = rtu_silence_s(settings)
    total = 0.0
    for request in requests:
        chars = 8 + 5 + 2 * request.count  # request frame + answer frame
        total += chars * char_s + 2 * silence
    return total * RTU_MARGIN


def poll_rate(settings: ModbusSettings, requests: Sequence[Request]) -> float:
    """The poll rate to use: ``poll_hz``, or the default lowered to what an RTU line carries.

    Raises:
        ConfigError: a ``poll_hz`` given that the RTU line cannot carry, or a
            line that does not carry one cycle per second.
    """
    if settings.mode != "rtu":
        return settings.poll_hz
    cycle_s = rtu_cycle_s(settings, requests)
    max_hz = 1.0 / cycle_s
    if settings.poll_hz <= max_hz:
        return settings.poll_hz
    why = (
        f"{len(requests)} request(s) per cycle at {settings.baudrate} baud need "
        f"{cycle_s * 1000:.1f} ms per cycle (frames, 3.5-character silences and "
        f"{RTU_MARGIN:g}x margin), so at most {max_hz:.1f} Hz"
    )
    if "poll_hz" in settings.model_fields_set or max_hz < 1.0:
        raise ConfigError(
            "the modbus link cannot poll that fast",
            [
                f"link.poll_hz: {settings.poll_hz:g} Hz is too fast: {why}; "
                "lower poll_hz or raise the baud rate"
            ],
        )
    adjusted = math.floor(max_hz * 10) / 10 if max_hz < 10 else math.floor(max_hz)
    log.warning(
        "modbus link: poll rate lowered from the default %g Hz to %g Hz: %s",
        settings.poll_hz,
        adjusted,
        why,
    )
    return float(adjusted)
