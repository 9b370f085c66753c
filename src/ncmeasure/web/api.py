"""The JSON REST API under ``/api/v1``: machines, measurements, results, checks, trends.

Every response has a pydantic model, so ``/openapi.json`` (and the docs at
``/docs``) describe the API completely. Errors are ``{"detail": "one line"}``:
404 for a machine, measurement or axis the store does not have, 422 for bad
input, 401 without the token, 503 when the database fails.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Response, status
from fastapi.security import HTTPBearer
from pydantic import BaseModel, ConfigDict, Field

from ncmeasure.errors import ConfigError
from ncmeasure.formats.comparison import Comparison, Status
from ncmeasure.formats.results import RESULTS_FORMAT_VERSION, Results, VerdictLevel
from ncmeasure.store import MeasurementInfo
from ncmeasure.store.rows import canonical_json
from ncmeasure.web.context import Context, context

__all__ = [
    "AddedOut",
    "ComparabilityOut",
    "ErrorOut",
    "FleetFigureOut",
    "MachineDetailOut",
    "MachineOut",
    "MeasurementOut",
    "NewMeasurement",
    "StoreCheckOut",
    "TrendPointOut",
    "router",
]

MEASUREMENT_ID_MAX = 2**63 - 1


class _Out(BaseModel):
    model_config = ConfigDict(from_attributes=True, frozen=True)


class ErrorOut(_Out):
    """An error: what went wrong, in one line."""

    detail: str


class MachineOut(_Out):
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


class MeasurementOut(_Out):
    """One stored measurement (its results: ``/api/v1/measurements/{id}/results``)."""

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


class MachineDetailOut(_Out):
    """One machine and all its measurements, oldest first."""

    machine: MachineOut
    measurements: list[MeasurementOut]


class TrendPointOut(_Out):
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


class FleetFigureOut(_Out):
    """One characteristic of one axis against the other machines of the type."""

    axis: str
    characteristic: str
    unit: str
    value: float
    fleet_median: float
    fleet_low: float
    fleet_high: float
    machines: int
    modified_z: float | None = Field(description="None when the fleet is too small.")
    outlier: bool


class ComparabilityOut(_Out):
    """What differs between the baseline and the latest measurement."""

    differences: list[str] = Field(description="Differences that weaken the comparison.")
    refused: str | None = Field(description="Why the two cannot be compared at all.")


class StoreCheckOut(_Out):
    """A machine's latest measurement against its delivery baseline and its fleet."""

    serial: str
    machine_type: str
    status: Status = Field(description="ok, warning or critical.")
    findings: list[str]
    latest: MeasurementOut
    baseline: MeasurementOut | None = Field(
        description="The first measurement labelled delivery, else the first; None if only one."
    )
    comparability: ComparabilityOut | None
    comparison: Comparison | None = Field(description="The comparison with the baseline.")
    fleet: list[FleetFigureOut]
    fleet_machines: int = Field(description="Other machines of the type with a measurement.")


class NewMeasurement(BaseModel):
    """A measurement to store: a results.json and what the store keeps beside it."""

    model_config = ConfigDict(extra="forbid")

    serial: str = Field(description="The machine's serial number.", examples=["M17"])
    label: str | None = Field(default=None, examples=["delivery"])
    site: str | None = None
    machine_type: str | None = Field(
        default=None, description="Default: the machine name in the results."
    )
    operator: str | None = None
    temperature_c: float | None = None
    operating_hours: float | None = None
    measured_utc: str | None = Field(
        default=None, description="ISO 8601; default: the recording's start."
    )
    recording_location: str | None = Field(
        default=None, description="Where the raw recording is kept."
    )
    results: Results = Field(description="The whole results.json of `ncmeasure analyze`.")


class AddedOut(_Out):
    """The outcome of adding a measurement."""

    measurement_id: int
    serial: str
    new: bool = Field(description="False when the same results were stored before.")


_bearer = HTTPBearer(
    auto_error=False,
    description="The server's token, when it was started with one.",
)
_NOT_FOUND: dict[int | str, dict[str, Any]] = {
    404: {"model": ErrorOut, "description": "No such machine, measurement or axis."}
}
router = APIRouter(
    prefix="/api/v1",
    tags=["fleet store"],
    dependencies=[Depends(_bearer)],
    responses={
        401: {"model": ErrorOut, "description": "The token is missing or wrong."},
        422: {"model": ErrorOut, "description": "Bad input."},
        503: {"model": ErrorOut, "description": "The database failed."},
    },
)
Ctx = Annotated[Context, Depends(context)]
Serial = Annotated[str, Path(description="The machine's serial number.")]
MeasurementId = Annotated[int, Path(ge=1, le=MEASUREMENT_ID_MAX)]


@router.get("/machines", summary="Every machine, by serial")
def list_machines(ctx: Ctx) -> list[MachineOut]:
    """Every machine in the store with its latest measurement's verdicts."""
    return [MachineOut.model_validate(m) for m in ctx.store.machines()]


@router.get("/machines/{serial}", summary="One machine and its measurements", responses=_NOT_FOUND)
def show_machine(ctx: Ctx, serial: Serial) -> MachineDetailOut:
    """The machine and its measurements, oldest first."""
    machine, measurements = ctx.store.machine(serial)
    return MachineDetailOut(
        machine=MachineOut.model_validate(machine),
        measurements=[MeasurementOut.model_validate(m) for m in measurements],
    )


@router.get(
    "/machines/{serial}/measurements",
    summary="A machine's measurements, oldest first",
    responses=_NOT_FOUND,
)
def list_measurements(ctx: Ctx, serial: Serial) -> list[MeasurementOut]:
    """The machine's measurements, oldest first."""
    _, measurements = ctx.store.machine(serial)
    return [MeasurementOut.model_validate(m) for m in measurements]


@router.get(
    "/measurements/{measurement_id}/results",
    summary="A measurement's results.json",
    responses=_NOT_FOUND,
)
def measurement_results(ctx: Ctx, measurement_id: MeasurementId) -> Results:
    """The stored results, exactly as they were added."""
    return ctx.store.results(measurement_id)


@router.get(
    "/machines/{serial}/check",
    summary="The latest measurement against the baseline and the fleet",
    responses=_NOT_FOUND,
)
def check(ctx: Ctx, serial: Serial) -> StoreCheckOut:
    """``ncmeasure store check`` as JSON."""
    return StoreCheckOut.model_validate(ctx.check(ctx.version(), serial))


@router.get(
    "/machines/{serial}/axes/{axis}/trend",
    summary="One axis' characteristics over the machine's life",
    responses=_NOT_FOUND,
)
def trend(ctx: Ctx, serial: Serial, axis: str) -> list[TrendPointOut]:
    """Coulomb, viscous friction, spread and more at every measurement, oldest first."""
    return [TrendPointOut.model_validate(p) for p in ctx.store.trend(serial, axis)]


@router.post(
    "/measurements",
    status_code=status.HTTP_201_CREATED,
    summary="Store a measurement",
    responses={
        200: {"model": AddedOut, "description": "These results were stored before."},
        201: {"description": "Stored."},
    },
)
def add_measurement(ctx: Ctx, body: NewMeasurement, response: Response) -> AddedOut:
    """Store a results.json for a machine (created on its first measurement).

    The same results are stored once: sending them again answers 200 with
    ``new: false``; sending them for another machine is refused (422).
    """
    results = body.results
    if results.format_version != RESULTS_FORMAT_VERSION:
        raise ConfigError(
            f"results format_version {results.format_version}, this server stores "
            f"{RESULTS_FORMAT_VERSION}; analyse the recording with this ncmeasure"
        )
    _check_finite(results)
    info = MeasurementInfo(**body.model_dump(exclude={"results"}))
    added = ctx.store.add(results, info)
    if not added.new:
        response.status_code = status.HTTP_200_OK
    return AddedOut.model_validate(added)


def _check_finite(results: Results) -> None:
    """Refuse NaN and infinities: results.json is strict JSON, the store keeps it so."""
    try:
        canonical_json(results)
    except ValueError as exc:
        raise ConfigError("results: NaN or infinite numbers are not valid in results.json") from exc
