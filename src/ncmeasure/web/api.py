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

from fastapi import APIRouter, Depends, Path, Query, Request, Response, status
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
from ncmeasure.store.summaries import DEFAULT_PAGE, MAX_PAGE
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


Limit = Annotated[
    int,
    Query(
        ge=1,
        le=MAX_PAGE,
        description=f"Items per page (default {DEFAULT_PAGE}, at most {MAX_PAGE}).",
    ),
]
Cursor = Annotated[
    str | None,
    Query(
        max_length=200,
        description="Where the page starts: the X-Next-Cursor of the page before.",
    ),
]


def _paged(request: Request, response: Response, total: int, following: str | None) -> None:
    response.headers["X-Total-Count"] = str(total)
    if following is not None:
        response.headers["X-Next-Cursor"] = following
        url = request.url.include_query_params(cursor=following)
        response.headers["Link"] = f'<{url}>; rel="next"'


@router.get("/machines", summary="The machines, by serial, a page at a time")
def list_machines(
    ctx: Ctx,
    request: Request,
    response: Response,
    limit: Limit = DEFAULT_PAGE,
    cursor: Cursor = None,
    search: Annotated[
        str | None,
        Query(max_length=200, description="Only machines whose serial, type or site holds it."),
    ] = None,
) -> list[MachineSummary]:
    """The machines with their latest measurement's verdicts, sorted by serial, a page at a
    time: the headers X-Total-Count (how many match), X-Next-Cursor and Link rel="next"
    (absent on the last page) say what follows."""
    page = ctx.store.machine_page(limit=limit, after=cursor, search=search)
    _paged(request, response, page.total, page.next_cursor)
    return page.machines


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
def list_measurements(
    ctx: Ctx,
    serial: Serial,
    request: Request,
    response: Response,
    limit: Limit = DEFAULT_PAGE,
    cursor: Cursor = None,
) -> list[MeasurementSummary]:
    """The machine's measurements, oldest first, a page at a time: the headers
    X-Total-Count, X-Next-Cursor (the last measurement id of the page) and Link rel="next"
    (absent on the last page) say what follows."""
    _, measurements = ctx.store.machine(serial)
    start = 0
    if cursor is not None:
        ids = [str(m.id) for m in measurements]
        if cursor not in ids:
            raise ConfigError(f"cursor {cursor!r}: no measurement of {serial} with that id")
        start = ids.index(cursor) + 1
    page = measurements[start : start + limit]
    more = start + limit < len(measurements)
    _paged(request, response, len(measurements), str(page[-1].id) if more and page else None)
    return page


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
