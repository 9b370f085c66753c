"""An axis' trend over a machine's life as SVG written directly, without matplotlib.

The fleet report draws a handful of trends; matplotlib's import and its per-artist
work cost more than the rest of the report. The figure is the one of
:func:`~ncmeasure.report.plots.plot_trend`: one panel per characteristic, the values
as a line with points, each measurement's label at its point, and around the
baseline the warning and critical bands (dashed edges) and the baseline itself
(dotted), except in a panel whose unit is ``%``. Text is text (the browser's font).
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Sequence

from ncmeasure.report.colours import CRITICAL, LINE, WARNING
from ncmeasure.report.svg import nice_ticks, number_text, text

__all__ = ["date_label", "date_ticks", "time_span", "trend_svg"]

_WIDTH = 760.0
_PANEL = 150.0
_GAP = 26.0
_LEFT = 78.0
_RIGHT = 16.0
_TOP = 34.0
_BOTTOM = 46.0
_DAY = 86400.0


def date_label(when: float) -> str:
    """A date tick's label: the day (UTC) of a time in seconds."""
    return dt.datetime.fromtimestamp(when, dt.UTC).strftime("%Y-%m-%d")


def date_ticks(start: float, end: float, most: int = 6) -> list[float]:
    """Midnights (UTC) between two times (seconds), one every so many days: the shortest
    step that gives at most ``most`` of them."""

    def every(step: int) -> list[float]:
        day = math.ceil(start / _DAY / step) * step
        ticks = []
        while day * _DAY <= end:
            ticks.append(day * _DAY)
            day += step
        return ticks

    for step in (1, 2, 3, 7, 14, 30, 61, 91, 182, 365):
        if (end - start) / _DAY / step <= most + 1 and len(found := every(step)) <= most:
            return found
    years = 1
    while len(found := every(365 * years)) > most:
        years += 1
    return found


def time_span(seconds: Sequence[float]) -> tuple[float, float]:
    """The time a trend shows (seconds): its measurements with 5 % to spare, or a
    fortnight around them when they fall within a day."""
    start, end = min(seconds), max(seconds)
    if end - start < _DAY:  # one day: a fortnight around it
        return start - 7 * _DAY, end + 7 * _DAY
    pad = (end - start) * 0.05
    return start - pad, end + pad


def trend_svg(
    axis: str,
    times: Sequence[dt.datetime],
    series: Sequence[tuple[str, str, Sequence[float | None]]],
    *,
    baseline_index: int | None,
    warning_percent: float,
    critical_percent: float,
    labels: Sequence[str | None] = (),
) -> str:
    """An axis' characteristics over a machine's life, one panel each, as an ``<svg>``.

    The arguments are those of :func:`~ncmeasure.report.plots.plot_trend`.

    Args:
        axis: The axis name (title).
        times: When each measurement was taken (at least one).
        series: Per panel ``(title, unit, values)``; a value may be None (not determined).
            A panel whose unit is ``%`` is drawn without limits (a spread).
        baseline_index: The baseline measurement: the limits are drawn as bands
            around its value (± warning, ± critical percent).
        warning_percent: Warning limit in percent of the baseline.
        critical_percent: Critical limit in percent of the baseline.
        labels: A label per measurement (``delivery``, ``service``), written at its point.
    """
    seconds = [(t if t.tzinfo else t.replace(tzinfo=dt.UTC)).timestamp() for t in times]
    start, end = time_span(seconds)
    plot_width = _WIDTH - _LEFT - _RIGHT
    panels = max(1, len(series))
    height = _TOP + panels * _PANEL + (panels - 1) * _GAP + _BOTTOM

    def x_of(when: float) -> float:
        return _LEFT + (when - start) / (end - start) * plot_width

    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {_WIDTH:g} {height:g}" '
        f'width="{_WIDTH:g}" height="{height:g}" role="img" font-family="sans-serif" '
        f'font-size="11" style="max-width:100%;height:auto;background:#fff">',
        f"<title>Axis {text(axis)} over the machine's life</title>",
        f'<text x="{_WIDTH / 2:g}" y="20" text-anchor="middle" font-size="14">'
        f"Axis {text(axis)} over the machine&#x27;s life</text>",
    ]
    x_ticks = date_ticks(start, end)
    for index, (title, unit, values) in enumerate(series):
        top = _TOP + index * (_PANEL + _GAP)
        bottom = top + _PANEL
        base = values[baseline_index] if baseline_index is not None else None
        banded = base is not None and unit != "%" and base != 0
        known = [(s, v) for s, v in zip(seconds, values, strict=True) if v is not None]
        span = [v for _, v in known]
        if banded and base is not None:
            reach = abs(base) * max(warning_percent, critical_percent) / 100.0
            span += [base - reach, base + reach]
        low, high = (min(span), max(span)) if span else (0.0, 1.0)
        if high - low <= 1e-12 * max(1.0, abs(high)):
            low, high = low - max(1.0, abs(low)) * 0.05, high + max(1.0, abs(high)) * 0.05
        pad = (high - low) * 0.06
        low, high = low - pad, high + pad

        def y_of(
            value: float, low: float = low, high: float = high, bottom: float = bottom
        ) -> float:
            return bottom - (value - low) / (high - low) * _PANEL

        out.append(
            f'<g><rect x="{_LEFT:g}" y="{top:g}" width="{plot_width:g}" '
            f'height="{_PANEL:g}" fill="none" stroke="#888"/>'
        )
        for tick in nice_ticks(low, high):
            y = y_of(tick)
            out.append(
                f'<line x1="{_LEFT - 4:g}" x2="{_LEFT:g}" y1="{y:.1f}" y2="{y:.1f}" stroke="#444"/>'
                f'<text x="{_LEFT - 6:g}" y="{y + 4:.1f}" text-anchor="end" fill="#444">'
                f"{number_text(tick)}</text>"
            )
        for tick in x_ticks:
            x = x_of(tick)
            out.append(
                f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{bottom:g}" y2="{bottom + 4:g}" '
                f'stroke="#444"/>'
            )
        if banded and base is not None:
            for limit, colour in (
                (critical_percent, CRITICAL),
                (warning_percent, WARNING),
            ):
                band = abs(base) * limit / 100.0
                y_high, y_low = y_of(base + band), y_of(base - band)
                out.append(
                    f'<rect x="{_LEFT:g}" y="{y_high:.1f}" width="{plot_width:g}" '
                    f'height="{y_low - y_high:.1f}" fill="{colour}" fill-opacity="0.07"/>'
                )
                for y in (y_high, y_low):
                    out.append(
                        f'<line x1="{_LEFT:g}" x2="{_LEFT + plot_width:g}" y1="{y:.1f}" '
                        f'y2="{y:.1f}" stroke="{colour}" stroke-width="0.8" '
                        f'stroke-dasharray="4 3"/>'
                    )
            y = y_of(base)
            out.append(
                f'<line x1="{_LEFT:g}" x2="{_LEFT + plot_width:g}" y1="{y:.1f}" y2="{y:.1f}" '
                f'stroke="#555" stroke-width="0.8" stroke-dasharray="1 2"/>'
            )
        if known:
            points = " ".join(f"{x_of(s):.1f},{y_of(v):.1f}" for s, v in known)
            out.append(
                f'<polyline points="{points}" fill="none" stroke="{LINE}" stroke-width="1.4"/>'
            )
            out.extend(
                f'<circle cx="{x_of(s):.1f}" cy="{y_of(v):.1f}" r="3.5" fill="{LINE}"/>'
                for s, v in known
            )
        for at, label in enumerate(labels):
            value = values[at] if at < len(values) else None
            if label and value is not None:
                out.append(
                    f'<text x="{x_of(seconds[at]) + 5:.1f}" y="{y_of(value) - 7:.1f}" '
                    f'font-size="9" fill="#555">{text(label)}</text>'
                )
        middle = top + _PANEL / 2
        out.append(
            f'<text transform="translate(14 {middle:g}) rotate(-90)" text-anchor="middle">'
            f"<tspan>{text(title)}</tspan>"
            f'<tspan x="0" dy="13">[{text(unit)}]</tspan></text></g>'
        )
    bottom = _TOP + panels * _PANEL + (panels - 1) * _GAP
    for tick in x_ticks:
        out.append(
            f'<text x="{x_of(tick):.1f}" y="{bottom + 16:g}" text-anchor="middle" '
            f'fill="#444">{date_label(tick)}</text>'
        )
    out.append(
        f'<text x="{_LEFT + plot_width / 2:g}" y="{bottom + 36:g}" text-anchor="middle">'
        "measured (UTC)</text></svg>"
    )
    return "\n".join(out)
