"""The dashboard's figures as inline SVG: an axis' trend and its latest friction curves.

The trend shows Coulomb friction, viscous friction and the spread along the
travel at every measurement, over time, each point in the colour of its
verdict. The friction curves are the report's own figures
(:func:`~ncmeasure.report.plot_stribeck`, :func:`~ncmeasure.report.plot_travel`).

Figures are drawn on their own canvas (no pyplot) and written as SVG with
text as text. matplotlib's style settings are process-wide, so drawing is
serialised by one lock: pages are served from several threads.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import io
import re
import threading
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Final

from matplotlib import rc_context
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.dates import AutoDateLocator, ConciseDateFormatter
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ncmeasure.formats.results import AxisResult
from ncmeasure.report import bearing_layout, plot_stribeck, plot_travel
from ncmeasure.store import TrendPoint

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

__all__ = ["VERDICT_COLOURS", "curves_svg", "figure_svg", "travel_svg", "trend_svg"]

VERDICT_COLOURS = {"ok": "#2e8b3e", "check": "#d08a00", "fault": "#c0392b"}
"""The marker colour of each verdict (the page's traffic lights, a shade stronger)."""
_LINE = "#8a8f98"
_STYLE: Final[dict[RcKeyType, Any]] = {
    "font.family": "DejaVu Sans",
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.edgecolor": "#555555",
    "axes.labelcolor": "#222222",
    "xtick.color": "#444444",
    "ytick.color": "#444444",
    "legend.frameon": False,
    "legend.fontsize": 8.5,
}
_LOCK = threading.Lock()
_ID_OR_REFERENCE = re.compile(r'(\bid="|\bhref="#|url\(#)')


def _plain(text: str) -> str:
    """Text from the store as matplotlib draws it literally (no mathtext from ``$``)."""
    return text.replace("$", r"\$")


def figure_svg(figure: Figure, salt: str) -> str:
    """The figure as an ``<svg>`` element for a page (no XML prolog); the figure is cleared.

    Args:
        figure: The figure.
        salt: Distinct per figure on a page: the SVG's element ids are made unique with it.
    """
    buffer = io.BytesIO()
    with rc_context({"svg.hashsalt": salt, "svg.fonttype": "none"}):
        figure.savefig(buffer, format="svg", facecolor="white", metadata={"Date": None})
    figure.clear()
    text = buffer.getvalue().decode("utf-8")
    prefix = "f" + hashlib.sha256(salt.encode()).hexdigest()[:10] + "-"
    return _ID_OR_REFERENCE.sub(lambda m: m.group(1) + prefix, text[text.index("<svg") :])


def _drawn(draw: Callable[[], Figure], salt: str) -> str:
    """Draw and write one figure under the lock, in the dashboard's style (tick labels
    are made while writing, so the style holds for both)."""
    with _LOCK, rc_context(_STYLE):
        return figure_svg(draw(), salt)


def _trend_figure(axis: str, points: Sequence[TrendPoint]) -> Figure:
    unit = points[-1].unit
    shown = [p for p in points if p.unit == unit]
    figure = Figure(figsize=(9.6, 2.9), dpi=100, layout="constrained")
    FigureCanvasAgg(figure)
    panels = figure.subplots(1, 3, sharex=True)
    when = [dt.datetime.fromisoformat(p.measured_utc) for p in shown]
    for ax, name, label in zip(
        panels,
        ("coulomb", "viscous_per_m_min", "spread_percent"),
        (f"Coulomb friction [{unit}]", f"viscous friction [{unit} per m/min]", "spread [%]"),
        strict=True,
    ):
        pairs = [(w, p.value(name), p.verdict) for w, p in zip(when, shown, strict=True)]
        known = [(w, v, verdict) for w, v, verdict in pairs if v is not None]
        if known:
            ax.plot([w for w, _, _ in known], [v for _, v, _ in known], color=_LINE, lw=1.2)
            ax.scatter(
                [w for w, _, _ in known],
                [v for _, v, _ in known],
                c=[VERDICT_COLOURS.get(verdict, _LINE) for _, _, verdict in known],
                s=36,
                zorder=3,
                edgecolors="white",
                linewidths=0.6,
            )
        ax.set_title(_plain(label), loc="left")
        ax.grid(True, color="#d9d9d9", linewidth=0.6)
        ax.set_axisbelow(True)
        for side in ("top", "right"):
            ax.spines[side].set_visible(False)
        if len(set(when)) == 1:  # one day: a fortnight around it
            ax.set_xlim(when[0] - dt.timedelta(days=7), when[0] + dt.timedelta(days=7))
        locator = AutoDateLocator(maxticks=5)  # type: ignore[no-untyped-call]
        ax.xaxis.set_major_locator(locator)
        ax.xaxis.set_major_formatter(ConciseDateFormatter(locator))  # type: ignore[no-untyped-call]
        values = [v for _, v, _ in known]
        if name != "viscous_per_m_min" and values and min(values) >= 0 and max(values) > 0:
            ax.set_ylim(0.0, max(values) * 1.15)  # levels from zero: changes look their size
    levels = [level for level in VERDICT_COLOURS if any(p.verdict == level for p in shown)]
    handles = [
        Line2D([], [], marker="o", linestyle="", color=VERDICT_COLOURS[level], label=level)
        for level in levels
    ]
    figure.legend(handles=handles, loc="outside upper right", ncols=len(handles) or 1)
    hidden = len(points) - len(shown)
    note = f" ({hidden} measurement(s) in another unit not drawn)" if hidden else ""
    figure.suptitle(_plain(f"Axis {axis} over the machine's life{note}"), x=0.01, ha="left")
    return figure


def trend_svg(serial: str, axis: str, points: Sequence[TrendPoint]) -> str:
    """The axis' trend: Coulomb, viscous friction and spread over time, coloured by verdict.

    Points measured in another unit than the latest (A against Nm) are left out
    and counted in the title.

    Args:
        serial: The machine's serial (makes the SVG's ids unique on a page).
        axis: The axis name.
        points: The trend, oldest first (at least one point).
    """
    return _drawn(lambda: _trend_figure(axis, points), f"trend/{serial}/{axis}")


def curves_svg(salt: str, axis: str, result: AxisResult) -> str:
    """The report's friction-over-velocity figure of an axis (points per position and
    direction with their fits), as SVG."""
    return _drawn(lambda: plot_stribeck(axis, result), f"curves/{salt}/{axis}")


def travel_svg(salt: str, axis: str, result: AxisResult) -> str | None:
    """The report's friction-along-the-travel figure, as SVG; None without that analysis."""
    if result.position_dependency is None or not result.position_dependency.identifiable:
        return None
    layout = bearing_layout(axis, None, result)
    return _drawn(lambda: plot_travel(axis, result, layout), f"travel/{salt}/{axis}")
