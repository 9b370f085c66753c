"""The dashboard's matplotlib figures as inline SVG: an axis' latest friction curves.

They are the report's own figures (:func:`~ncmeasure.report.plot_stribeck`,
:func:`~ncmeasure.report.plot_travel`). The trend is written directly
(:mod:`ncmeasure.web.trend`).

Figures are drawn on their own canvas (no pyplot) and written as SVG with
text as text. matplotlib's style settings are process-wide, so drawing is
serialised by one lock: pages are served from several threads.
"""

from __future__ import annotations

import hashlib
import io
import re
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Final

from matplotlib import rc_context
from matplotlib.figure import Figure

from ncmeasure.formats.results import AxisResult
from ncmeasure.report import bearing_layout, plot_stribeck, plot_travel

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

__all__ = ["curves_svg", "figure_svg", "travel_svg"]

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
