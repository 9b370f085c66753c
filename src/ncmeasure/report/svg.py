"""What the SVG figures share: the head, a panel's scales, its frame and grid, a line, a legend.

The report's figures (:mod:`ncmeasure.report.friction_svg`,
:mod:`ncmeasure.report.raw_svg`, :mod:`ncmeasure.report.comparison_figure`) and the
dashboard's (the same friction figures, :mod:`ncmeasure.web.trend`) are written with
these; the fleet report's trends (:mod:`ncmeasure.report.trend_svg`) take their ticks,
numbers and text from here. Text is text (the viewer's sans-serif font), every text
from a file through :func:`text`; no element has an id, so any number of figures can
share a page.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from html import escape

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ncmeasure.report.colours import GRID, INK

__all__ = [
    "TEXT",
    "WIDTH",
    "Panel",
    "frame",
    "legend",
    "nice_ticks",
    "number_text",
    "polyline",
    "svg_head",
    "text",
    "tick_texts",
    "x_axis",
    "y_grid",
]

WIDTH = 960.0
"""The width of a figure in px (it shrinks to the page, keeping its proportions)."""
FONT_PX = 12.0
"""The figures' text size in px (at the page's 1056 px, about 13 px on screen)."""

TEXT = "#444444"
"""Tick labels and axis titles."""

_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")
"""Characters XML 1.0 does not allow in a document (HTML tolerates them, an SVG file not)."""


def text(value: str) -> str:
    """Text from a file (a name, a label) for an SVG element or attribute: escaped, and a
    character XML does not allow shown as U+FFFD, so that every figure's file is XML."""
    return escape(_NOT_XML.sub("\ufffd", value))


def nice_ticks(low: float, high: float, count: int = 5) -> list[float]:
    """Round values (1, 2, 2.5 or 5 × a power of ten apart) covering ``low`` to ``high``,
    about ``count`` of them."""
    if not (math.isfinite(low) and math.isfinite(high)) or high <= low:
        return [low]
    raw = (high - low) / max(1, count - 1)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * power >= raw)
    first = math.ceil(low / step - 1e-9)
    last = math.floor(high / step + 1e-9)
    return [round(k * step, 12) for k in range(first, last + 1)]


def number_text(value: float) -> str:
    """A value as written at an axis: six significant digits, a minus sign (U+2212)."""
    return f"{value:.6g}".replace("-", "\u2212")


def tick_texts(ticks: Sequence[float]) -> list[str]:
    """The labels of evenly spaced ticks (:func:`nice_ticks`): as many decimals as their
    step needs and no exponent, so that neighbours differ (``1700000012.5``, not
    ``1.7e+09``), with a minus sign (U+2212)."""
    if len(ticks) < 2:
        return [number_text(t) for t in ticks]
    step = abs(ticks[1] - ticks[0])
    if not math.isfinite(step) or step <= 0:
        return [number_text(t) for t in ticks]
    power = math.floor(math.log10(step) + 1e-9)
    mantissa = step / 10.0**power
    decimals = max(0, -power + (1 if abs(mantissa - 2.5) < 1e-6 else 0))
    return [f"{t:.{decimals}f}".replace("-", "\u2212") for t in ticks]


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

    def xs(self, values: ArrayLike) -> NDArray[np.float64]:
        """:meth:`x` of many values at once (not a number where a logarithmic scale
        has no place for a value)."""
        v = np.asarray(values, dtype=np.float64)
        low, high = self.x_low, self.x_high
        if self.x_log:
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.where(v > 0, np.log10(v), np.nan)
            low, high = math.log10(low), math.log10(high)
        share = (v - low) / (high - low)
        return self.left + (1.0 - share if self.x_reversed else share) * self.width

    def ys(self, values: ArrayLike) -> NDArray[np.float64]:
        """:meth:`y` of many values at once."""
        share = (np.asarray(values, dtype=np.float64) - self.y_low) / (self.y_high - self.y_low)
        return self.top + (1.0 - share) * self.height

    @property
    def bottom(self) -> float:
        return self.top + self.height


def polyline(panel: Panel, xs: ArrayLike, ys: ArrayLike, style: str) -> str:
    """A line through the finite points (a gap where a value is not finite, or where a
    logarithmic scale has no place for it)."""
    x, y = panel.xs(xs), panel.ys(ys)
    if x.shape != y.shape:
        raise ValueError(f"{x.size} x values for {y.size} y values")
    good = np.isfinite(x) & np.isfinite(y)
    out: list[str] = []
    for run in np.split(np.arange(x.size), np.flatnonzero(~good)):
        run = run[good[run]]
        if len(run) > 1:
            points = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(x[run], y[run], strict=True))
            out.append(f'<polyline points="{points}" fill="none" {style}/>')
    return "".join(out)


def y_grid(panel: Panel, labels: bool = True, count: int = 7) -> list[str]:
    """Grid lines across the panel at round values (about ``count``), the values at the
    left."""
    out: list[str] = []
    ticks = nice_ticks(panel.y_low, panel.y_high, count)
    for tick, label in zip(ticks, tick_texts(ticks), strict=True):
        y = panel.y(tick)
        out.append(
            f'<line x1="{panel.left:g}" x2="{panel.left + panel.width:g}" y1="{y:.1f}" '
            f'y2="{y:.1f}" stroke="{GRID}" stroke-width="0.6"/>'
        )
        if labels:
            out.append(
                f'<text x="{panel.left - 5:g}" y="{y + 4:.1f}" text-anchor="end" '
                f'fill="{TEXT}">{label}</text>'
            )
    return out


def x_axis(panel: Panel, count: int, *, labels: bool = True, grid: bool = False) -> list[str]:
    """Round values (about ``count``) along a linear x scale: a tick below the panel (or a
    grid line across it) and the value under it."""
    out: list[str] = []
    ticks = [
        t for t in nice_ticks(panel.x_low, panel.x_high, count) if panel.x_low <= t <= panel.x_high
    ]
    for tick, label in zip(ticks, tick_texts(ticks), strict=True):
        x = panel.x(tick)
        if grid:
            out.append(
                f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{panel.top:g}" y2="{panel.bottom:g}" '
                f'stroke="{GRID}" stroke-width="0.6"/>'
            )
        else:
            out.append(
                f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{panel.bottom:g}" '
                f'y2="{panel.bottom + 4:g}" stroke="#444"/>'
            )
        if labels:
            out.append(
                f'<text x="{x:.1f}" y="{panel.bottom + 16:g}" text-anchor="middle" '
                f'fill="{TEXT}">{label}</text>'
            )
    return out


def frame(panel: Panel) -> str:
    """The panel's left and bottom edges."""
    return (
        f'<path d="M{panel.left:g} {panel.top:g}V{panel.bottom:g}H{panel.left + panel.width:g}" '
        f'fill="none" stroke="#555"/>'
    )


def svg_head(height: float, title: str) -> list[str]:
    """A figure's opening tag, its title for screen readers, a white background (for
    programs that ignore the style) and its title at the top left."""
    return [
        f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {WIDTH:g} {height:g}" '
        f'width="{WIDTH:g}" height="{height:g}" role="img" font-family="sans-serif" '
        f'font-size="{FONT_PX:g}" style="max-width:100%;height:auto;background:#fff">',
        f"<title>{text(title)}</title>",
        f'<rect width="{WIDTH:g}" height="{height:g}" fill="#ffffff"/>',
        f'<text x="8" y="20" font-size="15" fill="{INK}">{text(title)}</text>',
    ]


def legend(
    entries: Sequence[tuple[str, str]], top: float, left: float, width: float, columns: int = 4
) -> list[str]:
    """``columns`` entries to a row: a mark (SVG, 18 px wide, centred on y = 0) and its text."""
    out: list[str] = []
    column = width / columns
    for k, (mark, label) in enumerate(entries):
        x = left + (k % columns) * column
        y = top + (k // columns) * 18
        out.append(
            f'<g transform="translate({x:.1f} {y:.1f})">{mark}'
            f'<text x="24" y="4" fill="{INK}">{text(label)}</text></g>'
        )
    return out
