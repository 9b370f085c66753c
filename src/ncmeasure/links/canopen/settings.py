"""The settings of the CANopen link: the ``[link]`` table and each axis' ``link`` table.

Pydantic models, validated like the machine file: :class:`CanOpenSettings`
(the bus, SYNC, who owns NMT and SYNC, limits, the raw log),
:class:`CanOpenAxis` (a drive's node id, encoder, units, TPDO numbers) and
:class:`TpdoTable` (a TPDO as the controller configured it, for a link that
only listens). The simulated drives (:func:`ncmeasure.sim.cia402.serve`) take
the same models.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from ncmeasure.links.base import AxisLinkSettings, LinkSettings, PathSetting
from ncmeasure.links.canopen.objects import VelocityUnit

__all__ = [
    "HOST_CLOCK_INTERFACES",
    "NO_ECHO_INTERFACES",
    "CanOpenAxis",
    "CanOpenSettings",
    "TpdoTable",
]

_RAW_LOG_SUFFIXES = (".blf", ".asc", ".log", ".csv", ".trc")
NO_ECHO_INTERFACES = frozenset(
    {"slcan", "serial", "udp_multicast", "gs_usb", "robotell", "seeedstudio"}
)
"""python-can interfaces that do not return the frames a bus sent (receive_own_messages)."""
HOST_CLOCK_INTERFACES = frozenset({"slcan", "serial", "udp_multicast", "virtual", "socketcan"})
"""python-can interfaces whose frame time stamps are on the host's wall clock (time.time()):
python-can's own at reception, or the kernel's. Other adapters' clocks cannot be compared
with the host's SYNC send times, so the link stamps their frames itself on arrival."""
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
    sync_priority: int = Field(
        default=20,
        ge=0,
        le=99,
        description="Real-time priority of the link's SYNC thread (Linux SCHED_FIFO, 1-99), "
        "so that a busy host does not make it skip cycles; 0: normal scheduling. Needs root, "
        "CAP_SYS_NICE or an rtprio limit; where refused, an info event says so and the thread "
        "runs at normal priority.",
    )
    sync_echo: bool | None = Field(
        default=None,
        description="Whether the interface returns the link's own SYNC frames (python-can "
        "receive_own_messages): true gives each PDO to the SYNC before it in bus order; false "
        "to the SYNC by the host's send times and the frames' receive times "
        "(docs/canopen.md); empty decides by the interface (slcan, serial, udp_multicast, "
        "gs_usb, robotell and seeedstudio do not return them; another interface that does "
        "not is noticed at open).",
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

    def bus_kwargs(self) -> dict[str, Any]:
        """python-can's Bus arguments of these settings: bus_options, interface, bitrate."""
        kwargs: dict[str, Any] = dict(self.bus_options)
        if self.interface is not None:
            kwargs["interface"] = self.interface
        kwargs["bitrate"] = self.bitrate
        return kwargs

    @property
    def produces_sync(self) -> bool:
        """True when the link sends SYNC itself."""
        return self.sync_producer and not self.listen_only

    @property
    def echoes_sync(self) -> bool | None:
        """Whether the link's own SYNC comes back from the interface (None: see at open)."""
        if self.sync_echo is not None:
            return self.sync_echo
        if self.interface in NO_ECHO_INTERFACES:
            return False
        return None

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
    marker_input_bit: int | None = Field(
        default=None,
        ge=16,
        le=31,
        description="Bit of the drive's digital inputs 0x60FD (16-31, the manufacturer-"
        "specific inputs) wired to the controller's marker output: recorded as the axis' "
        "marker. Bits 0-15 are CiA 402's (limit and home switches, interlock, reserved).",
    )
    ready_output_bit: int | None = Field(
        default=None,
        ge=16,
        le=31,
        description="Bit of the drive's digital outputs 0x60FE:01 (16-31, the manufacturer-"
        "specific outputs) wired to the controller's ready input (machine.ready_input): the "
        "link sets it while it records. Bits 0-15 are CiA 402's (bit 0: brake).",
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
