"""The settings of a Modbus link: the ``[link]`` table and each axis' ``link`` table.

Pydantic models, strict like the machine file. The link polls with them, and
the simulated drive (:mod:`ncmeasure.sim.modbus_drive`) serves with the same
models: the endpoint, the serial line and the register maps of a server are
those of the link that reads it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from ncmeasure.config import format_validation_error
from ncmeasure.errors import ConfigError
from ncmeasure.links.base import AxisLinkSettings, LinkSettings

__all__ = [
    "ModbusAxis",
    "ModbusMarker",
    "ModbusReady",
    "ModbusSettings",
    "settings_from_tables",
]


class ModbusSettings(LinkSettings):
    """The ``[link]`` table of a Modbus link."""

    type: Literal["modbus"] = "modbus"
    mode: Literal["tcp", "rtu"] = Field(
        default="tcp",
        description="Modbus TCP (Ethernet, gateway) or Modbus RTU (serial line); "
        "default: rtu when a serial_port is given, else tcp.",
    )
    host: str = Field(default="127.0.0.1", min_length=1, description="TCP: drive or gateway.")
    port: Annotated[int, Field(ge=1, le=65535)] = Field(default=502, description="TCP port.")
    serial_port: str | None = Field(
        default=None,
        validate_default=True,
        description="RTU: device path (/dev/ttyUSB0, COM3) or pyserial URL.",
    )
    baudrate: Annotated[int, Field(ge=300, le=4_000_000)] = 19200
    parity: Literal["N", "E", "O"] = "E"
    stopbits: Literal[1, 2] = 1
    bytesize: Literal[7, 8] = 8
    register_map: str = Field(
        min_length=1, description="Built-in register map name or path of a TOML map."
    )
    poll_hz: Annotated[float, Field(gt=0, le=10_000)] = Field(
        default=100.0, description="Poll cycles per second (rows per second)."
    )
    timeout_s: Annotated[float, Field(gt=0, le=60)] = Field(
        default=0.5, description="How long to wait for an answer."
    )
    retries: Annotated[int, Field(ge=0, le=10)] = Field(
        default=1, description="Repetitions of an unanswered request within a cycle."
    )
    reconnect_delay_s: Annotated[float, Field(ge=0, le=60)] = Field(
        default=0.5, description="Wait before re-opening a lost connection or port."
    )
    max_outage_s: Annotated[float, Field(gt=0, le=3600)] = Field(
        default=10.0, description="Give up after this long without a complete poll cycle."
    )

    @model_validator(mode="before")
    @classmethod
    def _serial_port_means_rtu(cls, data: Any) -> Any:
        # A serial port given without a mode is a serial line: never poll TCP instead.
        if isinstance(data, dict) and "mode" not in data and data.get("serial_port"):
            return {**data, "mode": "rtu"}
        return data

    @field_validator("serial_port")
    @classmethod
    def _check_serial_port(cls, value: str | None, info: ValidationInfo) -> str | None:
        mode = info.data.get("mode")
        if mode == "rtu" and not value:
            raise PydanticCustomError("serial_port", "required when mode is 'rtu'")
        if mode == "tcp" and value:
            raise PydanticCustomError(
                "serial_port",
                "a serial port is for mode 'rtu', but mode is 'tcp': set mode = 'rtu' (or "
                "leave mode out) to use the serial line, or leave serial_port out for TCP",
            )
        return value


class ModbusMarker(BaseModel):
    """Where the controller's marker output reaches the bus: one bit of a drive or a PLC."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    function: Literal["discrete", "coil", "holding", "input"] = Field(
        description="discrete input (read with 02), coil (01), or a bit of a holding (03) "
        "or input (04) register."
    )
    address: Annotated[int, Field(ge=0, le=65535)] = Field(
        description="Address of the input, coil or register, 0-based as sent in the request."
    )
    bit: Annotated[int, Field(ge=0, le=15)] | None = Field(
        default=None, description="Registers: the bit (0 = least significant) that is the marker."
    )
    unit_id: Annotated[int, Field(ge=1, le=247)] | None = Field(
        default=None,
        description="The unit that has the input (a PLC); default: the axis' drive.",
    )

    @model_validator(mode="after")
    def _check_bit(self) -> ModbusMarker:
        register = self.function in ("holding", "input")
        if register and self.bit is None:
            raise PydanticCustomError(
                "marker_bit", "a register marker needs the bit that carries it: bit = 0..15"
            )
        if not register and self.bit is not None:
            raise PydanticCustomError(
                "marker_bit",
                "bit is for a register; a discrete input or a coil is one bit already",
            )
        return self


class ModbusReady(BaseModel):
    """Where the recorder's ready signal leaves the bus: a coil, or a bit of a holding
    register, of a drive or a PLC, wired to the controller's ``machine.ready_input``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    function: Literal["coil", "holding"] = Field(
        description="coil (written with 05) or a bit of a holding register (read with 03, "
        "written with 06: the other bits stay as they are)."
    )
    address: Annotated[int, Field(ge=0, le=65535)] = Field(
        description="Address of the coil or register, 0-based as sent in the request."
    )
    bit: Annotated[int, Field(ge=0, le=15)] | None = Field(
        default=None, description="Holding register: the bit (0 = least significant)."
    )
    unit_id: Annotated[int, Field(ge=1, le=247)] | None = Field(
        default=None, description="The unit that has the output (a PLC); default: the axis' drive."
    )

    @model_validator(mode="after")
    def _check_bit(self) -> ModbusReady:
        if self.function == "holding" and self.bit is None:
            raise PydanticCustomError(
                "ready_bit", "a register output needs the bit that carries it: bit = 0..15"
            )
        if self.function == "coil" and self.bit is not None:
            raise PydanticCustomError("ready_bit", "bit is for a register; a coil is one bit")
        return self


class ModbusAxis(AxisLinkSettings):
    """The ``link`` table of an axis on a Modbus link."""

    unit_id: Annotated[int, Field(ge=1, le=247)] = Field(
        description="Modbus unit (slave) id of the axis' drive."
    )
    register_map: str | None = Field(
        default=None, min_length=1, description="Register map of this axis' drive."
    )
    counts_per_rev: Annotated[int, Field(gt=0)] | None = Field(
        default=None, description="Encoder counts per motor revolution ('counts' units)."
    )
    scales: dict[
        Literal["current_a", "velocity_mm_min", "position_mm", "velocity_cmd_mm_min"], float
    ] = Field(default_factory=dict, description="Per-signal scale replacing the map's scale.")
    marker: ModbusMarker | None = Field(
        default=None,
        description="The input wired to the controller's marker output, recorded as the "
        "axis' marker (0 or 1).",
    )
    ready: ModbusReady | None = Field(
        default=None,
        description="The output wired to the controller's ready input (machine.ready_input): "
        "the link sets it while it records.",
    )

    @field_validator("scales")
    @classmethod
    def _check_scales(cls, value: dict[str, float]) -> dict[str, float]:
        for number in value.values():
            if not math.isfinite(number) or number == 0:
                raise PydanticCustomError("scale", "scales must be finite numbers other than 0")
        return value


def settings_from_tables(
    link_table: Mapping[str, Any], axis_tables: Mapping[str, Mapping[str, Any]]
) -> tuple[ModbusSettings, dict[str, ModbusAxis]]:
    """A ``[link]`` table and the ``link`` tables of named axes, validated.

    What :meth:`~ncmeasure.links.base.DriveLink.from_tables` does for a link,
    for a caller that has no machine file (the simulated drive's command line).

    Args:
        link_table: The ``[link]`` keys (``type`` may be left out).
        axis_tables: Axis name -> its ``link`` keys, in axis order.

    Raises:
        ConfigError: one ``location: message`` line per problem (``link.port``,
            ``axes[1].link.unit_id``).
    """
    problems: list[str] = []
    settings: ModbusSettings | None = None
    try:
        settings = ModbusSettings.model_validate({"type": "modbus", **link_table})
    except ValidationError as exc:
        problems += format_validation_error(exc, "link")
    axes: dict[str, ModbusAxis] = {}
    for index, (name, table) in enumerate(axis_tables.items()):
        try:
            axes[name] = ModbusAxis.model_validate(table)
        except ValidationError as exc:
            problems += format_validation_error(exc, f"axes[{index}].link")
    if problems or settings is None:
        raise ConfigError("the settings of the modbus link are not valid", problems)
    return settings, axes
