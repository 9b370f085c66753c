"""``store report``: the fleet at a glance as one HTML file.

A traffic-light grid of machines × axes (the change since each machine's
baseline and the outliers of its type), the outliers, and the trends of the
axes that moved most, each with its limits. Like the measurement report, the
page is one file: inline CSS, the trends as inline SVG, no script, every text from
the store escaped (Jinja autoescape).

What it shows is bounded, not the fleet (:func:`fleet_report`): the counts per
status and type cover every machine, from the statuses the lists read
(:func:`~ncmeasure.store.statuses.fleet_statuses`); the grid lists at most
``grid`` machines (all of a small fleet, else those that need attention, the
most severe first), and only those are judged in full
(:func:`~ncmeasure.store.statuses.judged_page`); the outliers come from the
fleet's arrays, at most :data:`MAX_OUTLIER_ROWS` listed; the trends are drawn
for the listed machines' axes that moved most. Other limits than the default
ones judge every machine again (:func:`~ncmeasure.store.overview.fleet_overview`):
the kept statuses are those of the default limits.
"""

from __future__ import annotations

import datetime as dt
import functools
import os
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jinja2

from ncmeasure._version import __version__
from ncmeasure.files import write_whole
from ncmeasure.formats.comparison import Limits, Status, worst_status
from ncmeasure.report.words import format_date, format_number
from ncmeasure.store.overview import (
    AxisOverview,
    Change,
    FleetOverview,
    MachineOverview,
    Outlier,
)
from ncmeasure.store.records import TrendPoint
from ncmeasure.store.rows import CHARACTERISTICS
from ncmeasure.store.store import Store

if TYPE_CHECKING:
    from matplotlib.figure import Figure  # imported by the plots, when a trend is drawn

__all__ = [
    "DEFAULT_GRID_ROWS",
    "DEFAULT_TRENDS",
    "MAX_OUTLIER_ROWS",
    "FleetReport",
    "fleet_report",
    "report_of",
    "trend_figure",
    "trend_svg",
    "write_fleet_report",
]

DEFAULT_TRENDS = 12
"""Trend plots in a report: the axes that moved most."""
MAX_OUTLIER_ROWS = 500
"""Outliers listed in the report (the largest first; the count says how many more)."""
DEFAULT_GRID_ROWS = 500
"""Machines in the report's grid: a fleet of more lists those that need attention, the
most severe first (the counts cover every machine; ``store list --status`` pages the rest)."""

_TITLES = {c.name: c.title for c in CHARACTERISTICS}
_RELATIVE = {c.name: c.relative for c in CHARACTERISTICS}
_SEVERITY = {"critical": 2, "warning": 1, "ok": 0}
_STATUSES: tuple[Status, ...] = ("ok", "warning", "critical")


def _trend_arguments(
    points: Sequence[TrendPoint], limits: Limits
) -> tuple[list[dt.datetime], list[tuple[str, str, list[float | None]]], dict[str, Any]]:
    """What a trend figure draws: the times, the panels and the limits around the baseline
    (the first ``delivery`` measurement, else the first)."""
    unit = points[-1].unit
    baseline = next((i for i, p in enumerate(points) if p.label == "delivery"), 0)
    series: list[tuple[str, str, list[float | None]]] = [
        ("Coulomb", unit, [p.coulomb for p in points]),
        ("viscous", f"{unit} per m/min", [p.viscous_per_m_min for p in points]),
        ("spread along the travel", "%", [p.spread_percent for p in points]),
    ]
    return (
        [dt.datetime.fromisoformat(p.measured_utc) for p in points],
        series,
        {
            "baseline_index": baseline,
            "warning_percent": limits.warning_percent,
            "critical_percent": limits.critical_percent,
            "labels": [p.label for p in points],
        },
    )


def trend_figure(axis: str, points: Sequence[TrendPoint], limits: Limits) -> Figure:
    """An axis' Coulomb, viscous friction and spread over a machine's life, with the limits.

    The limits are drawn around the baseline (the first ``delivery`` measurement,
    else the first). Used by ``store trend --plot``.
    """
    from ncmeasure.report.plots import plot_trend

    times, series, options = _trend_arguments(points, limits)
    return plot_trend(axis, times, series, **options)


def trend_svg(axis: str, points: Sequence[TrendPoint], limits: Limits) -> str:
    """The figure of :func:`trend_figure` as an ``<svg>`` element, written directly (no
    matplotlib): the trends of ``store report``."""
    from ncmeasure.report.trend_svg import trend_svg as draw

    times, series, options = _trend_arguments(points, limits)
    return draw(axis, times, series, **options)


@dataclass(frozen=True)
class _Cell:
    status: str
    text: str
    title: str


@dataclass(frozen=True)
class _Row:
    serial: str
    machine_type: str
    site: str
    measured: str
    status: str
    cells: list[_Cell]


@dataclass(frozen=True)
class _Trend:
    serial: str
    axis: str
    status: str
    why: str
    svg: str


def _change_text(change: Change) -> str:
    """``+23 %`` for a friction level, ``+4.2 pt`` for the spread along the travel."""
    if _RELATIVE[change.characteristic]:
        return f"{change.change:+.0f} %"
    return f"{change.change:+.1f} pt"


def _cell(axis: AxisOverview | None, baseline_label: str | None) -> _Cell:
    if axis is None:
        return _Cell("none", "–", "not measured")
    lines = [f"status: {axis.status}", *axis.explained()]
    lines.append(f"latest verdict: {axis.verdict_shown(baseline_label)}")
    for change in axis.changes:
        lines.append(
            f"{_TITLES[change.characteristic]}: {format_number(change.baseline)} → "
            f"{format_number(change.latest)} ({_change_text(change)})"
        )
    for outlier in axis.outliers:
        lines.append(
            f"outlier: {_TITLES[outlier.characteristic]} {format_number(outlier.value)} "
            f"{outlier.unit}, fleet median {format_number(outlier.fleet_median)} "
            f"(z {outlier.modified_z:+.1f})"
        )
    coulomb = next((c for c in axis.changes if c.characteristic == "coulomb"), None)
    text = axis.verdict_shown(baseline_label)
    if coulomb is not None:
        text += f" {_change_text(coulomb)}"
    if axis.outliers:
        text += " ◆"
    return _Cell(axis.status, text, "\n".join(lines))


@dataclass(frozen=True)
class FleetReport:
    """What the report shows of the fleet: counts of every machine, a bounded grid, the
    outliers (:func:`fleet_report`)."""

    machines: int
    """Every machine with a measurement."""
    types: dict[str, int]
    """Machines per machine type."""
    counts: dict[Status, int]
    """Machines per status."""
    axes: list[str]
    """Every axis name in the fleet, sorted."""
    listed: list[MachineOverview]
    """The grid's machines, judged in full, in the grid's order."""
    unlisted_attention: int
    unlisted_ok: int
    outliers: list[Outlier]
    """The largest |modified z| first, at most :data:`MAX_OUTLIER_ROWS`."""
    outlier_count: int
    """Every outlier of the fleet."""
    judged: list[MachineOverview]
    """The machines whose axes the trends are chosen from."""
    limits: Limits

    @property
    def status(self) -> Status:
        """The worst machine's status (ok for an empty fleet)."""
        return worst_status(s for s, n in self.counts.items() if n)


def _listed(machines: Sequence[MachineOverview], count: int) -> list[MachineOverview]:
    """The machines of the grid: every one, by serial, when there are at most ``count``;
    else those not ok, the most severe first, at most ``count``."""
    if len(machines) <= count:
        return list(machines)
    flagged = [m for m in machines if m.status != "ok"]
    flagged.sort(key=lambda m: (-_SEVERITY[m.status], m.serial))
    return flagged[:count]


def report_of(overview: FleetOverview, grid: int = DEFAULT_GRID_ROWS) -> FleetReport:
    """The report of a fleet judged machine by machine
    (:func:`~ncmeasure.store.overview.fleet_overview`)."""
    listed = _listed(overview.machines, grid)
    counts: dict[Status, int] = {s: overview.count(s) for s in _STATUSES}
    listed_attention = sum(m.status != "ok" for m in listed)
    return FleetReport(
        machines=len(overview.machines),
        types=overview.types,
        counts=counts,
        axes=overview.axes,
        listed=listed,
        unlisted_attention=counts["warning"] + counts["critical"] - listed_attention,
        unlisted_ok=counts["ok"] - (len(listed) - listed_attention),
        outliers=overview.outliers[:MAX_OUTLIER_ROWS],
        outlier_count=len(overview.outliers),
        judged=overview.machines,
        limits=overview.limits,
    )


def fleet_report(
    store: Store, limits: Limits | None = None, *, grid: int = DEFAULT_GRID_ROWS
) -> FleetReport:
    """The fleet as the report shows it, read at the cost of what it shows: the statuses
    as the lists read them, only the grid's machines judged in full (the module docstring).

    Args:
        store: The store.
        limits: The warning and critical limits (None: the default ones); other limits
            than the default judge every machine.
        grid: The most machines in the grid (:data:`DEFAULT_GRID_ROWS`).

    Raises:
        StoreError: The database failed.
    """
    from ncmeasure.store.overview import fleet_overview
    from ncmeasure.store.statuses import fleet_statuses, judged_page

    limits = limits or Limits()
    if limits != Limits():
        return report_of(fleet_overview(store, limits), grid)
    fleet = fleet_statuses(store)
    count = len(fleet.serials)
    everyone = range(count)  # by serial
    if count <= grid:
        chosen = list(everyone)
    else:
        flagged = [i for i in everyone if fleet.levels[i] > 0]
        flagged.sort(key=lambda i: -int(fleet.levels[i]))  # stable: by serial within
        chosen = flagged[:grid]
    judged = {
        m.serial: m for m in judged_page(store, fleet, [int(fleet.machine_ids[i]) for i in chosen])
    }
    listed = [judged[fleet.serials[i]] for i in chosen]
    outliers = fleet.outliers(limits)
    order = {c.name: k for k, c in enumerate(CHARACTERISTICS)}
    for outlier in outliers:  # the grid's diamonds and tooltips
        machine = judged.get(outlier.serial)
        if machine is not None and outlier.axis in machine.axes:
            machine.axes[outlier.axis].outliers.append(outlier)
    for machine in listed:
        for axis in machine.axes.values():
            axis.outliers.sort(key=lambda o: order[o.characteristic])
    levels = [int(fleet.levels[i]) for i in everyone]
    counts: dict[Status, int] = {s: levels.count(level) for level, s in enumerate(_STATUSES)}
    listed_attention = sum(int(fleet.levels[i]) > 0 for i in chosen)
    return FleetReport(
        machines=count,
        types=dict(sorted(Counter(fleet.types).items())),
        counts=counts,
        axes=fleet.axis_names,
        listed=listed,
        unlisted_attention=counts["warning"] + counts["critical"] - listed_attention,
        unlisted_ok=counts["ok"] - (len(chosen) - listed_attention),
        outliers=outliers[:MAX_OUTLIER_ROWS],
        outlier_count=len(outliers),
        judged=listed,
        limits=limits,
    )


def _rows(axes: Sequence[str], machines: Sequence[MachineOverview]) -> list[_Row]:
    rows = []
    for machine in machines:
        label = f" · {machine.latest_label}" if machine.latest_label else ""
        rows.append(
            _Row(
                serial=machine.serial,
                machine_type=machine.machine_type,
                site=machine.site or "–",
                measured=f"{format_date(machine.latest_utc)}{label} ({machine.measurements})",
                status=machine.status,
                cells=[_cell(machine.axes.get(a), machine.baseline_label) for a in axes],
            )
        )
    return rows


def _moved(
    machines: Sequence[MachineOverview], count: int
) -> list[tuple[MachineOverview, AxisOverview]]:
    """The axes to draw: not ok, the most severe and the largest change first."""
    flagged = [
        (machine, axis)
        for machine in machines
        for axis in machine.axes.values()
        if axis.status != "ok"
    ]

    def key(pair: tuple[MachineOverview, AxisOverview]) -> tuple[int, float, str, str]:
        machine, axis = pair
        largest = max((abs(c.change) for c in axis.changes), default=0.0)
        return (-_SEVERITY[axis.status], -largest, machine.serial, axis.axis)

    return sorted(flagged, key=key)[:count]


def _why(axis: AxisOverview) -> str:
    """Why the axis' status is what it is: the judgement's reasons and notes."""
    return "; ".join(axis.explained())


@functools.cache
def _template() -> jinja2.Template:
    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("ncmeasure.store", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    return environment.get_template("fleet_report.html.j2")


def write_fleet_report(
    store: Store,
    overview: FleetReport | FleetOverview,
    path: str | os.PathLike[str],
    *,
    trends: int = DEFAULT_TRENDS,
    grid: int = DEFAULT_GRID_ROWS,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Write the fleet report to ``path`` (replaced whole, never half written).

    Args:
        store: The store the fleet was read from (for the trends).
        overview: :func:`fleet_report`, or a fleet judged machine by machine
            (:func:`~ncmeasure.store.overview.fleet_overview`).
        path: The HTML file.
        trends: How many trend plots (the axes that moved most).
        grid: The most machines in the grid of a ``FleetOverview``; a larger fleet lists
            those that need attention, the most severe first (:data:`DEFAULT_GRID_ROWS`).
        progress: Called with (done, total) after each trend plot.

    Raises:
        OutputError: The file cannot be written.
        StoreError: The database failed.
    """
    shown = report_of(overview, grid) if isinstance(overview, FleetOverview) else overview
    moved = _moved(shown.judged, trends)
    drawn: list[_Trend] = []
    for done, (machine, axis) in enumerate(moved, start=1):
        points = store.trend(machine.serial, axis.axis)
        drawn.append(
            _Trend(
                serial=machine.serial,
                axis=axis.axis,
                status=axis.status,
                why=_why(axis),
                svg=trend_svg(axis.axis, points, shown.limits),
            )
        )
        if progress is not None:
            progress(done, len(moved))
    text = _template().render(
        version=__version__,
        where=store.where,
        made=format_date(dt.datetime.now(dt.UTC).isoformat(timespec="seconds")),
        limits=shown.limits,
        types=shown.types,
        axes=shown.axes,
        rows=_rows(shown.axes, shown.listed),
        machines=shown.machines,
        unlisted_attention=shown.unlisted_attention,
        unlisted_ok=shown.unlisted_ok,
        counts=shown.counts,
        outliers=shown.outliers,
        more_outliers=shown.outlier_count - len(shown.outliers),
        titles=_TITLES,
        trends=drawn,
        format_number=format_number,
    )
    return write_whole(path, text)
