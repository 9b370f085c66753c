"""What the fleet store takes and gives: one pydantic model per record.

The same models are the Python API (:class:`~ncmeasure.store.store.Store`), the
rows ``ncmeasure store`` prints and the REST API's bodies and responses
(:mod:`ncmeasure.web.api` returns them as they are), so a field and its
description are declared once. :class:`MeasurementInfo` checks what a user
gives (a serial, a label, a temperature) as it is built;
:func:`measurement_info` turns a refusal into one :class:`ConfigError` line per field.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic_core import PydanticCustomError

from ncmeasure.errors import ConfigError
from ncmeasure.formats.identity import (
    SERIAL_PATTERN,
    SERIAL_WORDS,
    check_serial,
    iso_utc,
    parse_utc,
)
from ncmeasure.formats.results import VerdictLevel
from ncmeasure.inputs import format_validation_error

__all__ = [
    "Added",
    "MachineDetail",
    "MachineSummary",
    "MeasurementInfo",
    "MeasurementSummary",
    "TrendPoint",
    "check_serial",
    "measurement_info",
    "utc_text",
]

LABEL_PATTERN = re.compile(r"[a-z0-9](?:[a-z0-9._-]{0,62})?")
"""A label such as ``delivery``, ``service``, ``after-repair``: lower case, digits, ``._-``."""
TEXT_LIMIT = 200
TEMPERATURE_RANGE_C = (-40.0, 120.0)
OPERATING_HOURS_MAX = 1_000_000.0
LOCATION_LIMIT = 4096

_LABEL_WORDS = "lower-case letters, digits and . _ - (1 to 64 characters, e.g. delivery)"


_REFUSAL = "store_value"


def _refuse(message: str) -> PydanticCustomError:
    return PydanticCustomError(_REFUSAL, message)


def utc_text(text: str | None, what: str) -> str:
    """An ISO 8601 time as UTC text with milliseconds; now for None.

    Raises:
        ConfigError: ``text`` is no ISO 8601 time (``what`` names it).
    """
    if text is None:
        return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError as exc:
        raise ConfigError(f"{what} {text!r}: not an ISO 8601 time") from exc
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.UTC)
    return when.astimezone(dt.UTC).isoformat(timespec="milliseconds")


class _Record(BaseModel):
    model_config = ConfigDict(frozen=True, from_attributes=True)


class MeasurementInfo(_Record):
    """What the store keeps about a measurement beside its results."""

    model_config = ConfigDict(extra="forbid")

    serial: str = Field(description="The machine's serial number.", examples=["M17"])
    label: str | None = Field(
        default=None, description="delivery, service, after-repair, ...", examples=["delivery"]
    )
    site: str | None = Field(default=None, description="Where the machine stands.")
    machine_type: str | None = Field(
        default=None,
        description="The type's name; default: the machine name in the results (a machine "
        "new to the store needs one of them).",
    )
    operator: str | None = Field(default=None, description="Who measured.")
    temperature_c: float | None = Field(
        default=None, description="Machine temperature during the measurement."
    )
    operating_hours: float | None = Field(default=None, description="The machine's hours.")
    recording_location: str | None = Field(
        default=None, description="Where the raw recording is kept (it stays a file)."
    )
    measured_utc: str | None = Field(
        default=None,
        description="When the machine was measured, ISO 8601 (UTC where no zone is given); "
        "default: the recording's start. Needed where that is unknown (an import whose "
        "data carry no date).",
    )

    @field_validator("serial")
    @classmethod
    def _check_serial(cls, value: str) -> str:
        if not SERIAL_PATTERN.fullmatch(value):
            raise _refuse(f"serial {value!r}: use {SERIAL_WORDS}")
        return value

    @field_validator("label")
    @classmethod
    def _check_label(cls, value: str | None) -> str | None:
        if value is not None and not LABEL_PATTERN.fullmatch(value):
            raise _refuse(f"label {value!r}: use {_LABEL_WORDS}")
        return value

    @field_validator("site", "machine_type", "operator")
    @classmethod
    def _check_text(cls, value: str | None, info: Any) -> str | None:
        if value is not None and (
            not value.strip() or len(value) > TEXT_LIMIT or not value.isprintable()
        ):
            what = str(info.field_name).replace("_", " ")
            raise _refuse(f"{what} {value!r}: printable text of 1 to {TEXT_LIMIT} characters")
        return value

    @field_validator("temperature_c", "operating_hours")
    @classmethod
    def _check_range(cls, value: float | None, info: Any) -> float | None:
        low, high, what = (
            (*TEMPERATURE_RANGE_C, "temperature")
            if info.field_name == "temperature_c"
            else (0.0, OPERATING_HOURS_MAX, "operating hours")
        )
        if value is not None and not (math.isfinite(value) and low <= value <= high):
            raise _refuse(f"{what} {value!r}: must lie within {low:g} to {high:g}")
        return value

    @field_validator("measured_utc")
    @classmethod
    def _check_time(cls, value: str | None) -> str | None:
        if value is None:
            return None
        try:
            return iso_utc(parse_utc(value, "measured time"))
        except ConfigError as exc:
            raise _refuse(exc.message) from exc

    @field_validator("recording_location")
    @classmethod
    def _check_location(cls, value: str | None) -> str | None:
        if value is not None and len(value) > LOCATION_LIMIT:
            raise _refuse(f"recording location: longer than {LOCATION_LIMIT} characters")
        return value


def measurement_info(**fields: Any) -> MeasurementInfo:
    """A :class:`MeasurementInfo`, or one :class:`ConfigError` naming every bad field.

    Raises:
        ConfigError: A field the store does not take (one ``field: why`` line each).
    """
    try:
        return MeasurementInfo(**fields)
    except ValidationError as exc:
        # The store's own refusals name their field in words; the rest as location: message.
        lines = [
            error["msg"] if error["type"] == _REFUSAL else line
            for error, line in zip(
                exc.errors(include_url=False), format_validation_error(exc), strict=False
            )
        ]
        if len(lines) == 1:
            raise ConfigError(lines[0]) from exc
        raise ConfigError("the measurement's information is not valid", lines) from exc


class Added(_Record):
    """The outcome of adding a measurement."""

    measurement_id: int
    serial: str
    new: bool = Field(description="False when the same results were stored before.")


class MeasurementSummary(_Record):
    """One stored measurement of a machine (its results: ``Store.results``)."""

    id: int
    measured_utc: str
    label: str | None = Field(description="delivery, service, after-repair, ...")
    operator: str | None
    temperature_c: float | None
    operating_hours: float | None
    link: str | None = Field(description="Where the data came from: canopen, modbus, a trace, ...")
    config_hash: str
    ncmeasure_version: str
    recording_location: str | None = Field(description="Where the raw recording is kept.")
    verdicts: dict[str, VerdictLevel] = Field(description="Per axis, the verdict.")


class MachineSummary(_Record):
    """One machine with its latest measurement's verdicts."""

    serial: str
    machine_type: str = Field(description="The machine type (one measurement program per type).")
    config_hash: str = Field(description="The hash of the type's machine file ('' if unknown).")
    site: str | None
    measurements: int = Field(description="Measurements stored.")
    latest_utc: str | None = Field(description="When the latest measurement was taken.")
    latest_label: str | None
    latest_verdicts: dict[str, VerdictLevel] = Field(
        description="Per axis, the latest measurement's verdict."
    )


class MachineDetail(_Record):
    """One machine and all its measurements, oldest first."""

    machine: MachineSummary
    measurements: list[MeasurementSummary]


class TrendPoint(_Record):
    """One axis' characteristics at one measurement."""

    measurement_id: int
    measured_utc: str
    label: str | None
    operating_hours: float | None
    unit: str = Field(description="Nm (with a torque constant) or A.")
    verdict: VerdictLevel
    coulomb: float | None = Field(description="Mean Coulomb friction over the positions.")
    coulomb_positive: float | None
    coulomb_negative: float | None
    viscous_per_m_min: float | None = Field(description="Mean viscous friction per m/min.")
    spread_percent: float | None = Field(description="Spread along the travel, (max − min)/mean.")
    signature: str | None = Field(description="The pattern along the travel.")
    offset: float | None = Field(description="Direction-independent part (gravity, bias).")

    def value(self, characteristic: str) -> float | None:
        """The value of a characteristic by its name (:data:`~.rows.CHARACTERISTICS`)."""
        found = getattr(self, characteristic)
        return float(found) if found is not None else None
