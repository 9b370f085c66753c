"""A recording's metadata (``meta.json``) and its event lines (``events.jsonl``).

A recording is a directory of three files (``docs/recording-format.md``)::

    meta.json      what was recorded: machine, serial, axes, link, channels, status (RecordingMeta)
    samples.bin    append-only frames of float64 rows: time_s, then one column per channel
    events.jsonl   one LinkEvent per line: gaps, faults, reboots, reconnects (EventRecord)

The models of the two text files are here; the frames of ``samples.bin`` and the
writer and reader of all three are :mod:`ncmeasure.recording`.
"""

from __future__ import annotations

from typing import Any, ClassVar, Final, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator

from ncmeasure.formats.axis import AxisMechanics
from ncmeasure.formats.header import FileHeader
from ncmeasure.formats.identity import Serial
from ncmeasure.samples import Channel, EventKind, LinkEvent

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "ChannelMeta",
    "EventRecord",
    "RecordedAxis",
    "RecordingMeta",
    "RecordingStatus",
]

FORMAT_NAME: Final = "ncmeasure-recording"
FORMAT_VERSION: Final = 1

RecordingStatus = Literal[
    "recording", "complete", "incomplete", "interrupted", "link_lost", "failed"
]
"""How a recording ended. ``complete``: as planned and without a gap; ``incomplete``: as
planned, but samples were lost (``gaps``, ``lost_samples`` and the gap events say where)."""


class ChannelMeta(BaseModel):
    """One sample column in ``meta.json``: its name, axis, signal and unit."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    axis: str = Field(min_length=1)
    signal: str = Field(min_length=1)
    unit: str

    @model_validator(mode="after")
    def _check_name(self) -> Self:
        if self.name != f"{self.axis}_{self.signal}":
            raise ValueError(
                f"name {self.name!r} must be <axis>_<signal> ({self.axis}_{self.signal})"
            )
        return self

    @classmethod
    def from_channel(cls, channel: Channel) -> ChannelMeta:
        """The metadata entry of a link channel."""
        return cls(name=channel.name, axis=channel.axis, signal=channel.signal, unit=channel.unit)

    def to_channel(self) -> Channel:
        """The link channel this entry describes."""
        return Channel(self.axis, self.signal, self.unit)


class RecordedAxis(AxisMechanics):
    """One entry of ``meta.json``'s ``axes``: an axis' mechanics and its velocity limits."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    max_velocity_mm_min: float | None = None
    rapid_velocity_mm_min: float | None = None
    """With the maximum velocity: what tells rapids and impossible values apart."""


class RecordingMeta(FileHeader):
    """The contents of ``meta.json``: what was recorded, how, and how it ended."""

    model_config = ConfigDict(extra="forbid")

    FORMAT: ClassVar[str] = FORMAT_NAME
    FORMAT_VERSION: ClassVar[int] = FORMAT_VERSION

    machine: str | None = None
    """The machine file's ``[machine] name``: the machine type."""
    serial: Serial | None = None
    """The serial number of the machine measured, where it was given (``--serial``)."""
    axes: list[RecordedAxis] = Field(default_factory=list)
    link: dict[str, Any] = Field(default_factory=dict)
    channels: list[ChannelMeta] = Field(min_length=1)
    nominal_period_s: float = Field(gt=0, allow_inf_nan=False)
    start_utc: str | None
    """When the first sample was taken (ISO 8601, UTC); null when unknown: an import
    whose data carry no date and that was given none (``--measured-at``)."""
    config_hash: str | None = None
    notes: str = ""
    source: str = ""
    faster_than_real_time: bool = False
    time_scale: float = Field(default=1.0, ge=0, allow_inf_nan=False)
    """Seconds of ``time_s`` per wall-clock second while recording: the link clock's
    speed or the replay speed (0: a replay as fast as possible); 1 is real time."""
    status: RecordingStatus = "recording"
    end_utc: str | None = None
    samples: int | None = Field(default=None, ge=0)
    gaps: int | None = Field(default=None, ge=0)
    """Gap events in ``events.jsonl`` (written at close)."""
    lost_samples: int | None = Field(default=None, ge=0)
    """Samples the gap events say were lost (written at close)."""
    skipped_cycles: int | None = Field(default=None, ge=0)
    """Of ``lost_samples``, the cycles the link skipped because the host fell behind (a
    CANopen SYNC producer that woke too late, a Modbus link behind its schedule; the gap
    events' ``skipped_cycles``)."""
    skipped_share: float | None = Field(default=None, ge=0, le=1, allow_inf_nan=False)
    """``skipped_cycles`` as a share of the cycles due (``samples + lost_samples``): the
    link recorded at ``(1 - skipped_share) / nominal_period_s`` instead of its rate."""

    @model_validator(mode="after")
    def _check_unique_channels(self) -> Self:
        names = [c.name for c in self.channels]
        doubled = sorted({n for n in names if names.count(n) > 1})
        if doubled:
            raise ValueError(f"channels appear twice: {', '.join(doubled)}")
        return self


class EventRecord(BaseModel):
    """One line of ``events.jsonl`` (unknown keys from newer writers are ignored)."""

    model_config = ConfigDict(extra="ignore")

    time_s: float
    kind: EventKind
    message: str
    axis: str | None = None
    lost_samples: int = 0
    details: dict[str, Any] = Field(default_factory=dict)

    def to_event(self) -> LinkEvent:
        return LinkEvent(
            time_s=self.time_s,
            kind=self.kind,
            message=self.message,
            axis=self.axis,
            lost_samples=self.lost_samples,
            details=self.details,
        )
