"""``store report``: the fleet at a glance as one HTML file.

A traffic-light grid of machines × axes (the change since each machine's
baseline and the outliers of its type, from
:func:`~ncmeasure.store.overview.fleet_overview`), the outliers, and the
trends of the axes that moved most, each with its limits. Like the
measurement report, the page is one file: inline CSS, images as data URIs,
no script, every text from the store escaped (Jinja autoescape).
"""

from __future__ import annotations

import base64
import datetime as dt
import functools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import jinja2
from matplotlib.figure import Figure

from ncmeasure._version import __version__
from ncmeasure.files import write_whole
from ncmeasure.formats.comparison import Limits
from ncmeasure.report.words import format_date, format_number
from ncmeasure.store.overview import AxisOverview, Change, FleetOverview, MachineOverview
from ncmeasure.store.records import TrendPoint
from ncmeasure.store.rows import CHARACTERISTICS
from ncmeasure.store.store import Store

__all__ = [
    "DEFAULT_GRID_ROWS",
    "DEFAULT_TRENDS",
    "MAX_OUTLIER_ROWS",
    "trend_figure",
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


def trend_figure(axis: str, points: Sequence[TrendPoint], limits: Limits) -> Figure:
    """An axis' Coulomb, viscous friction and spread over a machine's life, with the limits.

    The limits are drawn around the baseline (the first ``delivery`` measurement,
    else the first). Used by ``store trend --plot`` and ``store report``.
    """
    from ncmeasure.report.plots import plot_trend

    unit = points[-1].unit
    baseline = next((i for i, p in enumerate(points) if p.label == "delivery"), 0)
    return plot_trend(
        axis,
        [dt.datetime.fromisoformat(p.measured_utc) for p in points],
        [
            ("Coulomb", unit, [p.coulomb for p in points]),
            ("viscous", f"{unit} per m/min", [p.viscous_per_m_min for p in points]),
            ("spread along the travel", "%", [p.spread_percent for p in points]),
        ],
        baseline_index=baseline,
        warning_percent=limits.warning_percent,
        critical_percent=limits.critical_percent,
        labels=[p.label for p in points],
    )


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
    image: str


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


def _listed(overview: FleetOverview, count: int) -> list[MachineOverview]:
    """The machines of the grid: every one, by serial, when there are at most ``count``;
    else those not ok, the most severe first, at most ``count``."""
    if len(overview.machines) <= count:
        return overview.machines
    flagged = [m for m in overview.machines if m.status != "ok"]
    flagged.sort(key=lambda m: (-_SEVERITY[m.status], m.serial))
    return flagged[:count]


def _rows(overview: FleetOverview, machines: Sequence[MachineOverview]) -> list[_Row]:
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
                cells=[_cell(machine.axes.get(a), machine.baseline_label) for a in overview.axes],
            )
        )
    return rows


def _moved(overview: FleetOverview, count: int) -> list[tuple[MachineOverview, AxisOverview]]:
    """The axes to draw: not ok, the most severe and the largest change first."""
    flagged = [
        (machine, axis)
        for machine in overview.machines
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
    overview: FleetOverview,
    path: str | os.PathLike[str],
    *,
    trends: int = DEFAULT_TRENDS,
    grid: int = DEFAULT_GRID_ROWS,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Write the fleet report of ``overview`` to ``path`` (replaced whole, never half written).

    Args:
        store: The store the overview was read from (for the trends).
        overview: :func:`~ncmeasure.store.overview.fleet_overview`.
        path: The HTML file.
        trends: How many trend plots (the axes that moved most).
        grid: The most machines in the grid; a larger fleet lists those that need
            attention, the most severe first (:data:`DEFAULT_GRID_ROWS`).
        progress: Called with (done, total) after each trend plot.

    Raises:
        OutputError: The file cannot be written.
        StoreError: The database failed.
    """
    from ncmeasure.report.plots import figure_png

    moved = _moved(overview, trends)
    drawn: list[_Trend] = []
    for done, (machine, axis) in enumerate(moved, start=1):
        points = store.trend(machine.serial, axis.axis)
        png = figure_png(trend_figure(axis.axis, points, overview.limits))
        drawn.append(
            _Trend(
                serial=machine.serial,
                axis=axis.axis,
                status=axis.status,
                why=_why(axis),
                image="data:image/png;base64," + base64.b64encode(png).decode("ascii"),
            )
        )
        if progress is not None:
            progress(done, len(moved))
    outliers = overview.outliers[:MAX_OUTLIER_ROWS]
    listed = _listed(overview, grid)
    attention = sum(m.status != "ok" for m in overview.machines)
    text = _template().render(
        version=__version__,
        where=store.where,
        made=format_date(dt.datetime.now(dt.UTC).isoformat(timespec="seconds")),
        limits=overview.limits,
        types=overview.types,
        axes=overview.axes,
        rows=_rows(overview, listed),
        machines=len(overview.machines),
        unlisted_attention=attention - sum(m.status != "ok" for m in listed),
        unlisted_ok=sum(m.status == "ok" for m in overview.machines)
        - sum(m.status == "ok" for m in listed),
        counts={s: overview.count(s) for s in ("ok", "warning", "critical")},
        outliers=outliers,
        more_outliers=len(overview.outliers) - len(outliers),
        titles=_TITLES,
        trends=drawn,
        format_number=format_number,
    )
    return write_whole(path, text)
