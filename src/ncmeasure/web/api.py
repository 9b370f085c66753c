"""The JSON REST API under ``/api/v1``: machines, measurements, results, checks, trends.

Every response is one of the store's own records (:mod:`ncmeasure.store.records`,
:class:`~ncmeasure.store.check.StoreCheck`), returned as it is, so ``/openapi.json``
(and the docs at ``/docs``) describe the API completely and cannot drift from the
store. Errors are ``{"detail": "one line"}``: 404 for a machine, measurement or axis
the store does not have, 422 for bad input, 401 without the token, 503 when the
database fails.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Response, status
from fastapi.security import HTTPBearer
from pydantic import BaseModel, Field

from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import RESULTS_FORMAT_VERSION, Results
from ncmeasure.store.check import StoreCheck
from ncmeasure.store.records import (
    Added,
    MachineDetail,
    MachineSummary,
    MeasurementInfo,
    MeasurementSummary,
    TrendPoint,
)
from ncmeasure.store.rows import canonical_json
from ncmeasure.web.context import Context, context

__all__ = ["ErrorOut", "NewMeasurement", "router"]

MEASUREMENT_ID_MAX = 2**63 - 1


class ErrorOut(BaseModel):
    """An error: what went wrong, in one line."""

    detail: str


class NewMeasurement(MeasurementInfo):
    """A measurement to store: a results.json and what the store keeps beside it."""

    results: Results = Field(description="The whole results.json of `ncmeasure analyze`.")


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
def list_machines(ctx: Ctx) -> list[MachineSummary]:
    """Every machine in the store with its latest measurement's verdicts."""
    return ctx.store.machines()


@router.get("/machines/{serial}", summary="One machine and its measurements", responses=_NOT_FOUND)
def show_machine(ctx: Ctx, serial: Serial) -> MachineDetail:
    """The machine and its measurements, oldest first."""
    machine, measurements = ctx.store.machine(serial)
    return MachineDetail(machine=machine, measurements=measurements)


@router.get(
    "/machines/{serial}/measurements",
    summary="A machine's measurements, oldest first",
    responses=_NOT_FOUND,
)
def list_measurements(ctx: Ctx, serial: Serial) -> list[MeasurementSummary]:
    """The machine's measurements, oldest first."""
    _, measurements = ctx.store.machine(serial)
    return measurements


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
def check(ctx: Ctx, serial: Serial) -> StoreCheck:
    """``ncmeasure store check`` as JSON."""
    return ctx.check(ctx.version(), serial)


@router.get(
    "/machines/{serial}/axes/{axis}/trend",
    summary="One axis' characteristics over the machine's life",
    responses=_NOT_FOUND,
)
def trend(ctx: Ctx, serial: Serial, axis: str) -> list[TrendPoint]:
    """Coulomb, viscous friction, spread and more at every measurement, oldest first."""
    return ctx.store.trend(serial, axis)


@router.post(
    "/measurements",
    status_code=status.HTTP_201_CREATED,
    summary="Store a measurement",
    responses={
        200: {"model": Added, "description": "These results were stored before."},
        201: {"description": "Stored."},
    },
)
def add_measurement(ctx: Ctx, body: NewMeasurement, response: Response) -> Added:
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
    added = ctx.store.add(results, MeasurementInfo(**body.model_dump(exclude={"results"})))
    if not added.new:
        response.status_code = status.HTTP_200_OK
    return added


def _check_finite(results: Results) -> None:
    """Refuse NaN and infinities: results.json is strict JSON, the store keeps it so."""
    try:
        canonical_json(results)
    except ValueError as exc:
        raise ConfigError("results: NaN or infinite numbers are not valid in results.json") from exc
