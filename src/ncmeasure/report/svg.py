"""What the SVG figures share: the head, a panel's scales, its frame and grid, a line, a legend.

The report's figures (:mod:`ncmeasure.report.friction_svg`,
:mod:`ncmeasure.report.raw_svg`, :mod:`ncmeasure.report.comparison_figure`) and the
dashboard's (the same friction figures, :mod:`ncmeasure.web.trend`) are written with
these; the ticks and the numbers at them are those of :mod:`ncmeasure.report.trend_svg`.
Text is text (the viewer's sans-serif font); no element has an id, so any number of
figures can share a page.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from html import escape

from ncmeasure.report.colours import INK
from ncmeasure.report.trend_svg import nice_ticks, number_text

__all__ = ["TEXT", "WIDTH", "Panel", "frame", "legend", "polyline", "svg_head", "y_grid"]

WIDTH = 960.0
"""The width of a figure in px (it shrinks to the page, keeping its proportions)."""

TEXT = "#444444"
"""Tick labels and axis titles."""


@dataclass(frozen=True)
class Panel:
    """A plot area in pixels and the data range it shows (x logarithmic or linear)."""

    left: float
    top: float
    width: float
    height: float
    x_low: float
    x_high: float
    y_low: float
    y_high: float
    x_log: bool = False
    x_reversed: bool = False

    def x(self, value: float) -> float:
        low, high, v = self.x_low, self.x_high, value
        if self.x_log:
            low, high, v = math.log10(low), math.log10(high), math.log10(max(value, 1e-300))
        share = (v - low) / (high - low)
        return self.left + (1.0 - share if self.x_reversed else share) * self.width

    def y(self, value: float) -> float:
        share = (value - self.y_low) / (self.y_high - self.y_low)
        return self.top + (1.0 - share) * self.height

    @property
    def bottom(self) -> float:
        return self.top + self.height


def polyline(panel: Panel, xs: Iterable[float], ys: Iterable[float], style: str) -> str:
    """A line through the finite points (a gap where a value is not finite)."""
    runs: list[list[str]] = [[]]
    for x, y in zip(xs, ys, strict=True):
        if math.isfinite(x) and math.isfinite(y) and (x > 0 or not panel.x_log):
            runs[-1].append(f"{panel.x(x):.1f},{panel.y(y):.1f}")
        elif runs[-1]:
            runs.append([])
    return "".join(
        f'<polyline points="{" ".join(run)}" fill="none" {style}/>' for run in runs if len(run) > 1
    )


def y_grid(panel: Panel, labels: bool = True) -> list[str]:
    """Grid lines across the panel at round values, with the values at the left."""
    out: list[str] = []
    for tick in nice_ticks(panel.y_low, panel.y_high):
        y = panel.y(tick)
        out.append(
            f'<line x1="{panel.left:g}" x2="{panel.left + panel.width:g}" y1="{y:.1f}" '
            f'y2="{y:.1f}" stroke="#d9d9d9" stroke-width="0.6"/>'
        )
        if labels:
            out.append(
                f'<text x="{panel.left - 5:g}" y="{y + 4:.1f}" text-anchor="end" '
                f'fill="{TEXT}">{number_text(tick)}</text>'
            )
    return out


def frame(panel: Panel) -> str:
    """The panel's left and bottom edges."""
    return (
        f'<path d="M{panel.left:g} {panel.top:g}V{panel.bottom:g}H{panel.left + panel.width:g}" '
        f'fill="none" stroke="#555"/>'
    )


def svg_head(height: float, title: str) -> list[str]:
    """A figure's opening tag, its title for screen readers and its title at the top left."""
    return [
        f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {WIDTH:g} {height:g}" '
        f'width="{WIDTH:g}" height="{height:g}" role="img" font-family="sans-serif" '
        f'font-size="11" style="max-width:100%;height:auto;background:#fff">',
        f"<title>{escape(title)}</title>",
        f'<text x="8" y="20" font-size="14" fill="{INK}">{escape(title)}</text>',
    ]


def legend(
    entries: Sequence[tuple[str, str]], top: float, left: float, width: float, columns: int = 4
) -> list[str]:
    """``columns`` entries to a row: a mark (SVG, 18 px wide, centred on y = 0) and its text."""
    out: list[str] = []
    column = width / columns
    for k, (mark, text) in enumerate(entries):
        x = left + (k % columns) * column
        y = top + (k // columns) * 18
        out.append(
            f'<g transform="translate({x:.1f} {y:.1f})">{mark}'
            f'<text x="24" y="4" fill="{INK}">{escape(text)}</text></g>'
        )
    return out
