"""The dashboard's trend of an axis as SVG written directly, without matplotlib.

Three panels side by side: Coulomb friction, viscous friction and the spread along
the travel at every measurement, over time; a grey line through the points, each
point in the colour of its verdict (:data:`~ncmeasure.report.colours.VERDICT_COLOURS`),
a legend of the verdicts shown. Levels that cannot be negative start at zero, so a
change looks its size. Points measured in another unit than the latest are left out
and counted in the title.

A machine's page fetches one of these per axis; drawn with matplotlib, the first in a
server process cost 0.25–0.7 s of CPU (its import and its artists), more than the
page itself. Text is text (the browser's font); the SVG has no element ids, so any
number of them can share a page.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence

from ncmeasure.report.colours import VERDICT_COLOURS
from ncmeasure.report.svg import Panel, frame, polyline, text, y_grid
from ncmeasure.report.trend_svg import date_label, date_ticks, time_span
from ncmeasure.store.records import TrendPoint

__all__ = ["trend_svg"]

_WIDTH = 960.0
_HEIGHT = 290.0
_TOP = 56.0
_BOTTOM = 30.0
_LEFT = 58.0
_RIGHT = 12.0
_GAP = 66.0
_LINE = "#8a8f98"
_PANELS = (
    ("coulomb", "Coulomb friction [{unit}]"),
    ("viscous_per_m_min", "viscous friction [{unit} per m/min]"),
    ("spread_percent", "spread [%]"),
)
_FROM_ZERO = frozenset({"coulomb", "spread_percent"})
"""Levels that start at zero when every value is ≥ 0 (the viscous slope may be either)."""


def _seconds(text: str) -> float:
    when = dt.datetime.fromisoformat(text)
    return (when if when.tzinfo else when.replace(tzinfo=dt.UTC)).timestamp()


def _span(values: Sequence[float], from_zero: bool) -> tuple[float, float]:
    """The value range a panel shows."""
    if not values:
        return 0.0, 1.0
    low, high = min(values), max(values)
    if from_zero and low >= 0 and high > 0:
        return 0.0, high * 1.15
    if high - low <= 1e-12 * max(1.0, abs(high)):
        return low - max(1.0, abs(low)) * 0.05, high + max(1.0, abs(high)) * 0.05
    pad = (high - low) * 0.06
    return low - pad, high + pad


def trend_svg(serial: str, axis: str, points: Sequence[TrendPoint]) -> str:
    """The axis' trend: Coulomb, viscous friction and spread over time, coloured by verdict.

    Args:
        serial: The machine's serial (the figure's description).
        axis: The axis name.
        points: The trend, oldest first (at least one point).
    """
    unit = points[-1].unit
    shown = [p for p in points if p.unit == unit]
    seconds = [_seconds(p.measured_utc) for p in shown]
    start, end = time_span(seconds)
    width = (_WIDTH - _LEFT - _RIGHT - (len(_PANELS) - 1) * _GAP) / len(_PANELS)
    bottom = _HEIGHT - _BOTTOM
    hidden = len(points) - len(shown)
    note = f" ({hidden} measurement(s) in another unit not drawn)" if hidden else ""
    title = f"Axis {axis} over the machine's life{note}"
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {_WIDTH:g} {_HEIGHT:g}" '
        f'width="{_WIDTH:g}" height="{_HEIGHT:g}" role="img" font-family="sans-serif" '
        f'font-size="11" style="max-width:100%;height:auto;background:#fff">',
        f"<title>{text(title)}: machine {text(serial)}</title>",
        f'<text x="8" y="18" font-size="13" fill="#222">{text(title)}</text>',
    ]
    levels = [level for level in VERDICT_COLOURS if any(p.verdict == level for p in shown)]
    x = _WIDTH - _RIGHT - sum(30 + 7.0 * len(level) for level in levels)  # right-aligned
    for level in levels:  # the legend
        out.append(
            f'<circle cx="{x + 14:.1f}" cy="14" r="4.5" fill="{VERDICT_COLOURS[level]}"/>'
            f'<text x="{x + 22:.1f}" y="18" fill="#222">{level}</text>'
        )
        x += 30 + 7.0 * len(level)
    ticks = date_ticks(start, end, most=3)
    for index, (name, label) in enumerate(_PANELS):
        left = _LEFT + index * (width + _GAP)
        known = [
            (s, value, p.verdict)
            for s, p in zip(seconds, shown, strict=True)
            if (value := p.value(name)) is not None
        ]
        low, high = _span([v for _, v, _ in known], name in _FROM_ZERO)
        panel = Panel(left, _TOP, width, bottom - _TOP, start, end, low, high)
        out.append(
            f'<g><text x="{left:g}" y="{_TOP - 10:g}" fill="#222">'
            f"{text(label.format(unit=unit))}</text>"
        )
        out += y_grid(panel)
        for tick in ticks:
            at = panel.x(tick)
            out.append(
                f'<line x1="{at:.1f}" x2="{at:.1f}" y1="{bottom:g}" y2="{bottom + 4:g}" '
                f'stroke="#444"/><text x="{at:.1f}" y="{bottom + 17:g}" text-anchor="middle" '
                f'fill="#444">{date_label(tick)}</text>'
            )
        out.append(frame(panel))
        if known:
            out.append(
                polyline(
                    panel,
                    [s for s, _, _ in known],
                    [v for _, v, _ in known],
                    f'stroke="{_LINE}" stroke-width="1.2"',
                )
            )
            out.extend(
                f'<circle cx="{panel.x(s):.1f}" cy="{panel.y(v):.1f}" r="4.5" '
                f'fill="{VERDICT_COLOURS.get(verdict, _LINE)}" stroke="#fff" '
                f'stroke-width="0.6"/>'
                for s, v, verdict in known
            )
        out.append("</g>")
    out.append("</svg>")
    return "\n".join(out)
