"""The dashboard: the fleet grid, a machine's page and an axis' page, as plain HTML.

::

    /                                  machines × axes: each axis' status (the store
                                       check's rule) with its latest verdict, and the
                                       machine's status
    /machines/{serial}                 the check, the measurements, a trend plot per axis
    /machines/{serial}/axes/{axis}     the trend, its numbers, the latest friction curves
    /machines/{serial}/axes/{axis}/trend.svg   the axis' trend plot alone

The pages need no JavaScript and load nothing from elsewhere; the plots are
inline SVG, except on a machine's page: there each axis' trend is an image of this
server (``trend.svg``), which the browser fetches after the page, so the page costs
its table and check, not a plot per axis. The view models here hold text; the templates
(``templates/*.html.j2``, Jinja with autoescape) only lay them out, so text
from the store (a site, an operator, a serial) is always escaped.
"""

from __future__ import annotations

import bisect
import functools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal
from urllib.parse import quote, urlencode

import jinja2
from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import HTMLResponse, Response
from markupsafe import Markup

from ncmeasure._version import __version__
from ncmeasure.analysis.judgement.summary import axis_comparison, axis_headline
from ncmeasure.report.bearings import bearing_layout
from ncmeasure.report.friction_svg import curves_svg, travel_svg
from ncmeasure.report.words import format_date, format_number
from ncmeasure.store import MeasurementSummary, TrendPoint
from ncmeasure.store.check import StoreCheck
from ncmeasure.store.overview import MachineOverview
from ncmeasure.store.rows import CHARACTERISTICS
from ncmeasure.store.statuses import judged_page
from ncmeasure.store.summaries import DEFAULT_PAGE, MAX_PAGE
from ncmeasure.web.context import Context, Version, context

__all__ = ["html_page", "router"]

LEVELS = ("ok", "check", "fault")
STATUSES = ("ok", "warning", "critical")
SECURITY_HEADERS = {
    "content-security-policy": (
        "default-src 'none'; style-src 'unsafe-inline'; img-src 'self' data:; "
        "form-action 'self'; frame-ancestors 'none'; base-uri 'none'"
    ),
    "x-content-type-options": "nosniff",
    "referrer-policy": "no-referrer",
    "cache-control": "no-store",
}
"""Sent with every page: no script runs, nothing loads from elsewhere, no token leaks."""
_TITLES = {c.name: c.title for c in CHARACTERISTICS}

router = APIRouter(include_in_schema=False)
Ctx = Annotated[Context, Depends(context)]


@functools.cache
def _environment() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.PackageLoader("ncmeasure.web", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def html_page(
    request: Request, template: str, status_code: int = 200, **values: Any
) -> HTMLResponse:
    """A page rendered from ``templates/<template>`` with the security headers."""
    where = getattr(request.app.state, "where", "")
    text = (
        _environment()
        .get_template(template)
        .render(root=_root(request), version=__version__, where=where, **values)
    )
    return HTMLResponse(text, status_code=status_code, headers=SECURITY_HEADERS)


def _root(request: Request) -> str:
    root: str = request.scope.get("root_path", "")
    return root.rstrip("/")


def _level(value: str | None) -> str:
    return value if value in LEVELS else "none"


def _machine_href(root: str, serial: str) -> str:
    return f"{root}/machines/{quote(serial, safe='')}"


def _axis_href(root: str, serial: str, axis: str) -> str:
    return f"{_machine_href(root, serial)}/axes/{quote(axis, safe='')}"


# ----------------------------------------------------------------------------- fleet


@dataclass(frozen=True)
class Cell:
    """One traffic light of the grid: an axis' status (``none``: no such axis), showing its
    latest verdict (marked where its pattern is the machine's unchanged fingerprint)."""

    status: str
    text: str
    title: str
    href: str | None


@dataclass(frozen=True)
class GridRow:
    """One machine of the fleet grid."""

    serial: str
    href: str
    machine_type: str
    site: str
    measurements: int
    latest: str
    cells: list[Cell]
    status: str
    findings: str


def _findings(machine: MachineOverview) -> str:
    """What makes a machine's status: every axis' reasons, then the lifted verdicts."""
    found = [r for axis in machine.axes.values() for r in axis.reasons]
    found += [n for axis in machine.axes.values() for n in axis.notes]
    return " · ".join(found)


def _cell(root: str, machine: MachineOverview, name: str) -> Cell:
    axis = machine.axes.get(name)
    if axis is None:
        return Cell("none", "–", "not measured", None)
    title = "\n".join([f"status: {axis.status}", *axis.explained()])
    return Cell(
        axis.status,
        axis.verdict_shown(machine.baseline_label),
        title,
        _axis_href(root, machine.serial, name),
    )


@dataclass(frozen=True)
class Pager:
    """Where the grid's page stands among the machines that match."""

    shown: int
    total: int
    first_href: str | None
    """The first page, when this is not it."""
    next_href: str | None
    """The next page, when there is one."""


@router.get("/", response_class=HTMLResponse)
def fleet_page(
    request: Request,
    ctx: Ctx,
    q: Annotated[str | None, Query(max_length=200)] = None,
    status: Annotated[Literal["ok", "warning", "critical"] | None, Query()] = None,
    after: Annotated[str | None, Query(max_length=200)] = None,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = DEFAULT_PAGE,
) -> HTMLResponse:
    """The fleet grid: the machines (rows, by serial, a page at a time, those that match
    the search) × every axis (columns)."""
    version = ctx.version()
    root = _root(request)
    fleet = ctx.statuses(version)
    axes = fleet.axis_names
    search = (q or "").strip() or None
    matching = fleet.matching(search, status)
    serials = [fleet.serials[i] for i in matching]
    start = bisect.bisect_right(serials, after) if after else 0
    chosen = [int(fleet.machine_ids[i]) for i in matching[start : start + limit]]
    shown = judged_page(ctx.store, fleet, chosen)
    rows = []
    for m in shown:
        latest = format_date(m.latest_utc) + (f" · {m.latest_label}" if m.latest_label else "")
        rows.append(
            GridRow(
                serial=m.serial,
                href=_machine_href(root, m.serial),
                machine_type=m.machine_type,
                site=m.site or "–",
                measurements=m.measurements,
                latest=latest,
                cells=[_cell(root, m, a) for a in axes],
                status=m.status,
                findings=_findings(m),
            )
        )
    counts = fleet.axis_counts(matching)
    kept: dict[str, object] = {
        "q": search,
        "status": status,
        "limit": None if limit == DEFAULT_PAGE else limit,
    }
    more = start + limit < len(matching)
    pager = Pager(
        shown=len(rows),
        total=len(matching),
        first_href=_query_href(root, kept) if after else None,
        next_href=_query_href(root, {**kept, "after": shown[-1].serial}) if more else None,
    )
    return html_page(
        request,
        "fleet.html.j2",
        title="Fleet",
        axes=axes,
        rows=rows,
        counts=counts,
        pager=pager,
        search=search or "",
        status=status or "",
        statuses=STATUSES,
        machines=len(fleet.serials),
        home=f"{root}/",
    )


def _query_href(root: str, params: dict[str, object]) -> str:
    chosen = {k: str(v) for k, v in params.items() if v is not None}
    return f"{root}/?{urlencode(chosen)}" if chosen else f"{root}/"


# --------------------------------------------------------------------------- machine


@dataclass(frozen=True)
class MeasurementRow:
    """One measurement in a machine's table."""

    id: int
    when: str
    label: str
    operator: str
    temperature: str
    operating_hours: str
    link: str
    verdicts: list[str]
    results_href: str


@dataclass(frozen=True)
class FleetRow:
    """One characteristic of the check against the fleet."""

    axis: str
    characteristic: str
    value: str
    median: str
    range: str
    machines: int
    z: str
    outlier: bool


@dataclass(frozen=True)
class AxisPlot:
    """One axis on the machine's page: its trend and the link to its page."""

    axis: str
    href: str
    src: str
    """The trend plot's address (an SVG image)."""


def _or_dash(value: object) -> str:
    return "–" if value is None else str(value)


def _measurement_rows(
    root: str, measurements: Sequence[MeasurementSummary], axes: Sequence[str]
) -> list[MeasurementRow]:
    return [
        MeasurementRow(
            id=m.id,
            when=format_date(m.measured_utc),
            label=_or_dash(m.label),
            operator=_or_dash(m.operator),
            temperature="–" if m.temperature_c is None else f"{m.temperature_c:g} °C",
            operating_hours="–" if m.operating_hours is None else f"{m.operating_hours:g} h",
            link=_or_dash(m.link),
            verdicts=[_level(m.verdicts.get(a)) for a in axes],
            results_href=f"{root}/api/v1/measurements/{m.id}/results",
        )
        for m in measurements
    ]


def _fleet_rows(check: StoreCheck) -> list[FleetRow]:
    return [
        FleetRow(
            axis=f.axis,
            characteristic=_TITLES.get(f.characteristic, f.characteristic),
            value=f"{format_number(f.value)} {f.unit}",
            median=format_number(f.fleet_median),
            range=f"{format_number(f.fleet_low)} – {format_number(f.fleet_high)}",
            machines=f.machines,
            z="–" if f.modified_z is None else f"{f.modified_z:+.1f}",
            outlier=f.outlier,
        )
        for f in check.fleet
    ]


def _trend_svg(
    ctx: Context,
    version: Version,
    serial: str,
    axis: str,
    points: Sequence[TrendPoint] | None = None,
) -> Markup:
    """The axis' trend plot (cached); ``points``: the trend if already read."""

    def draw() -> str:
        from ncmeasure.web.trend import trend_svg

        found = points if points is not None else ctx.store.trend(serial, axis)
        return trend_svg(serial, axis, found)

    return Markup(ctx.cached(version, ("trend", serial, axis), draw))  # SVG text is escaped


def _axes_of(measurements: Iterable[MeasurementSummary]) -> list[str]:
    return sorted({a for m in measurements for a in m.verdicts})


@router.get("/machines/{serial}", response_class=HTMLResponse)
def machine_page(request: Request, ctx: Ctx, serial: str) -> HTMLResponse:
    """A machine: the store check, its measurements, a trend plot per axis."""
    version = ctx.version()
    root = _root(request)
    machine, measurements = ctx.store.machine(serial)
    axes = _axes_of(measurements)
    check = ctx.check(version, serial)
    plots = [
        AxisPlot(
            axis=a,
            href=_axis_href(root, serial, a),
            src=_axis_href(root, serial, a) + "/trend.svg",
        )
        for a in axes
    ]
    baseline = check.baseline
    return html_page(
        request,
        "machine.html.j2",
        title=f"Machine {machine.serial}",
        machine=machine,
        latest=format_date(machine.latest_utc),
        check=check,
        baseline="–"
        if baseline is None
        else f"{format_date(baseline.measured_utc)} · {baseline.label or f'#{baseline.id}'}",
        fleet=_fleet_rows(check),
        axes=axes,
        measurements=_measurement_rows(root, measurements, axes),
        plots=plots,
    )


# ------------------------------------------------------------------------------ axis


@dataclass(frozen=True)
class TrendRow:
    """One measurement of an axis' trend."""

    when: str
    label: str
    operating_hours: str
    verdict: str
    coulomb: str
    viscous: str
    spread: str
    signature: str


def _trend_rows(points: Sequence[TrendPoint]) -> list[TrendRow]:
    return [
        TrendRow(
            when=format_date(p.measured_utc),
            label=_or_dash(p.label),
            operating_hours="–" if p.operating_hours is None else f"{p.operating_hours:g}",
            verdict=_level(p.verdict),
            coulomb=format_number(p.coulomb),
            viscous=format_number(p.viscous_per_m_min),
            spread=format_number(p.spread_percent),
            signature=(p.signature or "–").replace("_", " "),
        )
        for p in points
    ]


@router.get("/machines/{serial}/axes/{axis}/trend.svg")
def trend_image(ctx: Ctx, serial: str, axis: str) -> Response:
    """The axis' trend plot as an SVG image (the machine's page shows it)."""
    svg = _trend_svg(ctx, ctx.version(), serial, axis)
    return Response(str(svg), media_type="image/svg+xml", headers=SECURITY_HEADERS)


@router.get("/machines/{serial}/axes/{axis}", response_class=HTMLResponse)
def axis_page(request: Request, ctx: Ctx, serial: str, axis: str) -> HTMLResponse:
    """One axis of a machine: its trend and the friction curves of its latest measurement."""
    version = ctx.version()
    root = _root(request)
    points = ctx.store.trend(serial, axis)
    latest = points[-1]
    results = ctx.store.results(latest.measurement_id)
    result = results.axes[axis]
    # the verdict as every surface judges it: against the baseline where the store check
    # compared them (the change is judged, not the machine's fingerprint), with its status
    check = ctx.check(version, serial)
    against = (
        axis_comparison(check.comparison, axis)
        if check.comparison is not None and latest.measurement_id == check.latest.id
        else None
    )
    verdict = axis_headline(result, against).verdict if against is not None else result.verdict
    status = check.axis_status.get(axis, "ok")
    kept = latest.measurement_id
    curves = ctx.of_measurement(kept, ("curves", axis), lambda: curves_svg(axis, result))
    travel = ctx.of_measurement(
        kept, ("travel", axis), lambda: travel_svg(axis, result, bearing_layout(axis, None, result))
    )
    return html_page(
        request,
        "axis.html.j2",
        title=f"Machine {serial} · axis {axis}",
        serial=serial,
        machine_href=_machine_href(root, serial),
        axis=axis,
        unit=latest.unit,
        verdict=verdict,
        level=_level(verdict.level),
        status=status,
        latest=f"{format_date(latest.measured_utc)}"
        + (f" · {latest.label}" if latest.label else ""),
        results_href=f"{root}/api/v1/measurements/{latest.measurement_id}/results",
        trend=_trend_svg(ctx, version, serial, axis, points),
        rows=_trend_rows(points),
        curves=Markup(curves),  # the SVG's text is escaped
        travel=None if travel is None else Markup(travel),
    )
