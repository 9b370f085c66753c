"""An axis' friction figures, as SVG written directly, without matplotlib.

The report and the dashboard show the same two figures of an axis, from here:

- **friction over velocity**: the negative direction on the left (velocity growing
  to the left), the positive on the right, a logarithmic speed scale, a shared
  friction scale; median ± standard deviation per velocity step, one colour per
  position; the Coulomb + viscous fit dashed over the speeds it was fitted to (dotted
  where extrapolated below them), the Stribeck (or extended) fit solid where it is
  identifiable; the zero line, and the offset line where the offset is significant;
- **friction along the travel**: one thin line per velocity (light: slow, dark: fast,
  the scale at the right), the average over the velocities bold with the positions'
  numbers, the fixed and loose bearing at the travel's ends.

The curves are those of :mod:`ncmeasure.report.curves`. Drawn with matplotlib, an axis'
page cost 0.25–0.3 s of CPU per measurement, and 0.5 s more for matplotlib's import on
the first page of a server process.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ncmeasure.formats.results import AxisResult, DirectionResult
from ncmeasure.report.bearings import BearingLayout
from ncmeasure.report.colours import GRID, INK, PALETTE
from ncmeasure.report.curves import (
    drawn_model,
    linear_curve,
    linear_spans,
    offset_is_significant,
    speed_range,
    speed_text,
    stribeck_curve,
    unit_label,
)
from ncmeasure.report.svg import (
    TEXT,
    WIDTH,
    Panel,
    frame,
    legend,
    nice_ticks,
    polyline,
    svg_head,
    text,
    y_grid,
)
from ncmeasure.report.words import format_mm

__all__ = ["curves_svg", "travel_svg"]

_AXIS_GREY = "#888888"
_DASHED = "4 3"
_DOTTED = "1 2"
_SLOW, _FAST = (0xB9, 0xCF, 0xE8), (0x0B, 0x2F, 0x5C)
"""The thin lines' colours at the slowest and the fastest velocity."""


def _speed_ticks(low: float, high: float) -> tuple[list[float], list[float]]:
    """Labelled and unlabelled ticks of a logarithmic speed scale: the decades, and 2
    and 5 of each (labelled too over a decade and a half or less)."""
    labelled: list[float] = []
    minor: list[float] = []
    for power in range(math.floor(math.log10(low)), math.ceil(math.log10(high)) + 1):
        for m in (1.0, 2.0, 5.0):
            value = m * 10.0**power
            if low <= value <= high:
                (labelled if m == 1.0 else minor).append(value)
    if high <= low * 10**1.5 or len(labelled) < 2:
        return sorted(labelled + minor), []
    return labelled, minor


def _direction_marks(
    panel: Panel,
    direction: DirectionResult,
    sign: float,
    colour: str,
    offset: float | None,
    slowest: float,
) -> tuple[list[str], bool]:
    """Points with ± std bars, the linear fit and the nonlinear one of one direction."""
    out: list[str] = []
    points = sorted(
        (
            p
            for p in direction.points
            if p.velocity_mm_min != 0 and math.isfinite(p.velocity_mm_min + p.median)
        ),
        key=lambda p: abs(p.velocity_mm_min),
    )
    model = drawn_model(direction)
    stribeck = False
    if model is not None and points:
        grid = np.geomspace(abs(points[0].velocity_mm_min), abs(points[-1].velocity_mm_min), 80)
        curve = stribeck_curve(model, sign * grid, sign, points, offset)
        if curve is not None:
            out.append(polyline(panel, grid, curve, f'stroke="{colour}" stroke-width="1.9"'))
            stribeck = True
    fit = direction.fit
    if fit is not None:
        inside, below = linear_spans(fit, slowest, 40)
        out.append(
            polyline(
                panel,
                inside,
                linear_curve(fit, sign * inside, sign, points, offset),
                f'stroke="{colour}" stroke-width="1.3" stroke-dasharray="{_DASHED}"',
            )
        )
        if below is not None:  # extrapolated below the fitted speeds: lighter
            out.append(
                polyline(
                    panel,
                    below,
                    linear_curve(fit, sign * below, sign, points, offset),
                    f'stroke="{colour}" stroke-width="1.1" stroke-dasharray="{_DOTTED}" '
                    f'stroke-opacity="0.7"',
                )
            )
    for p in points:
        x, y = panel.x(abs(p.velocity_mm_min)), panel.y(p.median)
        if math.isfinite(p.std):
            y_low, y_high = panel.y(p.median - p.std), panel.y(p.median + p.std)
            out.append(
                f'<path d="M{x:.1f} {y_low:.1f}V{y_high:.1f}M{x - 2.5:.1f} {y_low:.1f}h5'
                f'M{x - 2.5:.1f} {y_high:.1f}h5" stroke="{colour}" stroke-width="1"/>'
            )
        out.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="3" fill="{colour}"/>')
    return out, stribeck


def _curve_range(
    result: AxisResult, offset: float | None, significant: bool
) -> tuple[float, float]:
    """The friction range of the velocity figure: every point's ± std and zero."""
    values = [0.0]
    for position in result.positions:
        for direction in position.directions.values():
            for p in direction.points if direction is not None else ():
                spread = p.std if math.isfinite(p.std) else 0.0
                values += [p.median - spread, p.median + spread]
    if offset is not None and significant:
        values.append(offset)
    finite = [v for v in values if math.isfinite(v)]
    low, high = min(finite), max(finite)
    pad = (high - low) * 0.06 or 1.0
    return low - pad, high + pad


def curves_svg(axis: str, result: AxisResult) -> str:
    """Friction over velocity for every position and direction of an axis, as ``<svg>``."""
    offset = result.offset.value if result.offset is not None else None
    significant = offset_is_significant(result.offset)
    slowest, fastest = speed_range(result)
    y_low, y_high = _curve_range(result, offset, significant)
    legend_rows = math.ceil((len(result.positions) + 4) / 4)
    top, left, gap, plot_h = 58.0, 70.0, 14.0, 290.0
    height = top + plot_h + 42 + 18 * legend_rows + 10
    width = (WIDTH - left - 16 - gap) / 2
    panels = {
        side: Panel(
            left + k * (width + gap),
            top,
            width,
            plot_h,
            slowest / 1.4,
            fastest * 1.4,
            y_low,
            y_high,
            x_log=True,
            x_reversed=side == "negative",
        )
        for k, side in enumerate(("negative", "positive"))
    }
    out = svg_head(height, f"Axis {axis}: friction over velocity (Stribeck curves)")
    labelled, minor = _speed_ticks(slowest / 1.4, fastest * 1.4)
    shown_offset = offset if significant else None
    drawn = {"negative": False, "positive": False}
    any_stribeck = False
    marks: dict[str, list[str]] = {"negative": [], "positive": []}
    for index, position in enumerate(result.positions):
        colour = PALETTE[index % len(PALETTE)]
        for named, direction in position.directions.items():
            if direction is None or named not in panels:
                continue
            sign = -1.0 if named == "negative" else 1.0
            drawn[named] = drawn[named] or bool(direction.points)
            found, stribeck = _direction_marks(
                panels[named], direction, sign, colour, offset, slowest
            )
            marks[named] += found
            any_stribeck = any_stribeck or stribeck
    for side, panel in panels.items():
        sign = -1.0 if side == "negative" else 1.0
        out.append(
            f'<g><text x="{panel.left + panel.width / 2:g}" y="{top - 8:g}" '
            f'text-anchor="middle" fill="{TEXT}">{side} direction</text>'
        )
        out += y_grid(panel, labels=side == "negative")
        for tick in labelled + minor:
            x = panel.x(tick)
            if tick in labelled:
                out.append(
                    f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{panel.top:g}" y2="{panel.bottom:g}" '
                    f'stroke="{GRID}" stroke-width="0.6"/>'
                )
            size = 4 if tick in labelled else 2.5
            out.append(
                f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{panel.bottom:g}" '
                f'y2="{panel.bottom + size:g}" stroke="#444"/>'
            )
            if tick in labelled:
                out.append(
                    f'<text x="{x:.1f}" y="{panel.bottom + 16:g}" text-anchor="middle" '
                    f'fill="{TEXT}">{speed_text(tick, sign)}</text>'
                )
        zero = panel.y(0.0)
        out.append(
            f'<line x1="{panel.left:g}" x2="{panel.left + panel.width:g}" y1="{zero:.1f}" '
            f'y2="{zero:.1f}" stroke="{_AXIS_GREY}" stroke-width="0.8"/>'
        )
        if shown_offset is not None:
            y = panel.y(shown_offset)
            out.append(
                f'<line x1="{panel.left:g}" x2="{panel.left + panel.width:g}" y1="{y:.1f}" '
                f'y2="{y:.1f}" stroke="#666" stroke-dasharray="6 2 1 2"/>'
            )
        out.append(frame(panel))
        out += marks[side]
        if not drawn[side]:
            out.append(
                f'<text x="{panel.left + panel.width / 2:g}" y="{top + plot_h / 2:g}" '
                f'text-anchor="middle" font-size="14" fill="{_AXIS_GREY}">not measured</text>'
            )
        out.append(
            f'<text x="{panel.left + panel.width / 2:g}" y="{panel.bottom + 32:g}" '
            f'text-anchor="middle" fill="{TEXT}">velocity [mm/min], logarithmic</text></g>'
        )
    out.append(
        f'<text transform="translate(16 {top + plot_h / 2:g}) rotate(-90)" '
        f'text-anchor="middle" fill="{TEXT}">{text(unit_label(result))}</text>'
    )
    entries = [
        (
            f'<line x1="0" x2="18" y1="0" y2="0" stroke="{PALETTE[i % len(PALETTE)]}" '
            f'stroke-width="1.9"/><circle cx="9" cy="0" r="3" fill="{PALETTE[i % len(PALETTE)]}"/>',
            f"position {p.position_index + 1}: {format_mm(p.position_mm)} mm",
        )
        for i, p in enumerate(result.positions)
    ]
    entries.append((f'<circle cx="9" cy="0" r="3" fill="{INK}"/>', "median ± std"))
    entries.append(
        (
            f'<line x1="0" x2="18" y1="0" y2="0" stroke="{INK}" stroke-width="1.3" '
            f'stroke-dasharray="{_DASHED}"/>',
            "Coulomb + viscous fit",
        )
    )
    if any_stribeck:
        entries.append(
            (
                f'<line x1="0" x2="18" y1="0" y2="0" stroke="{INK}" stroke-width="1.9"/>',
                "Stribeck fit",
            )
        )
    if shown_offset is not None:
        entries.append(
            (
                '<line x1="0" x2="18" y1="0" y2="0" stroke="#666" stroke-dasharray="6 2 1 2"/>',
                "offset",
            )
        )
    out += legend(entries, top + plot_h + 52, left, WIDTH - left - 16)
    out.append("</svg>")
    return "\n".join(out)


def _shade(share: float) -> str:
    """The colour of a thin line: light for the slowest velocity, dark for the fastest."""
    share = min(1.0, max(0.0, share))
    red, green, blue = (round(a + (b - a) * share) for a, b in zip(_SLOW, _FAST, strict=True))
    return f"#{red:02x}{green:02x}{blue:02x}"


def travel_svg(axis: str, result: AxisResult, bearings: BearingLayout) -> str | None:
    """Friction along the travel: one thin line per velocity, the average bold, the
    bearings at the travel's ends, as ``<svg>``; None without that analysis."""
    dependency = result.position_dependency
    if dependency is None or not dependency.identifiable:
        return None
    per_velocity = [p for p in dependency.profiles if p.velocity_mm_min is not None]
    averages = [p for p in dependency.profiles if p.velocity_mm_min is None]
    speeds = [abs(p.velocity_mm_min or 0.0) for p in per_velocity]
    slowest, fastest = min(speeds, default=0.0), max(speeds, default=1.0)
    logarithmic = slowest > 0 and fastest / slowest > 20

    def share(speed: float) -> float:
        if fastest <= slowest:
            return 0.0
        if logarithmic:
            return math.log(speed / slowest) / math.log(fastest / slowest)
        return (speed - slowest) / (fastest - slowest)

    positions = [x for p in dependency.profiles for x in p.positions_mm if math.isfinite(x)]
    low_mm, high_mm = min(positions, default=0.0), max(positions, default=1.0)
    if bearings.travel_mm is not None:
        low_mm, high_mm = min(low_mm, bearings.travel_mm[0]), max(high_mm, bearings.travel_mm[1])
    pad = 0.04 * max(high_mm - low_mm, 1.0)
    values = [abs(v) for p in dependency.profiles for v in p.values if math.isfinite(v)]
    y_high = (max(values, default=1.0) or 1.0) * 1.08
    top, left, plot_h = 62.0, 70.0, 250.0
    right = 150.0 if per_velocity else 16.0
    height = top + plot_h + 50
    panel = Panel(left, top, WIDTH - left - right, plot_h, low_mm - pad, high_mm + pad, 0.0, y_high)
    out = svg_head(height, f"Axis {axis}: friction along the travel")
    out.append("<g>")
    out += y_grid(panel)
    out.append(frame(panel))
    suffix = "" if bearings.known else " (assumed)"
    for end, what in ((bearings.fixed_end, "fixed"), (bearings.loose_end, "loose")):
        where = bearings.end_mm(end)
        if where is not None:
            x = panel.x(where)
            out.append(
                f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{top:g}" y2="{panel.bottom:g}" '
                f'stroke="{INK}" stroke-width="2.2" stroke-opacity="0.55"/>'
            )
        else:  # the end of the plot
            x = panel.left if end == "min" else panel.left + panel.width
        anchor = "start" if end == "min" else "end"
        out.append(
            f'<text x="{x:.1f}" y="{top - 6:g}" text-anchor="{anchor}" font-weight="bold" '
            f'fill="{INK}">{what} bearing{suffix}</text>'
        )
    for profile, speed in zip(per_velocity, speeds, strict=True):
        colour = _shade(share(speed))
        magnitudes = [abs(v) for v in profile.values]
        out.append(
            polyline(
                panel,
                profile.positions_mm,
                magnitudes,
                f'stroke="{colour}" stroke-width="0.9" stroke-opacity="0.85"',
            )
        )
        out.extend(
            f'<circle cx="{panel.x(x):.1f}" cy="{panel.y(y):.1f}" r="1.6" fill="{colour}"/>'
            for x, y in zip(profile.positions_mm, magnitudes, strict=True)
            if math.isfinite(x + y)
        )
    numbered = {
        p.position_mm: p.position_index + 1
        for p in result.positions
        if math.isfinite(p.position_mm)
    }
    for profile in averages:
        magnitudes = [abs(v) for v in profile.values]
        out.append(
            polyline(
                panel, profile.positions_mm, magnitudes, f'stroke="{PALETTE[1]}" stroke-width="2.8"'
            )
        )
        numbers = profile.position_numbers or [numbered.get(x, 0) for x in profile.positions_mm]
        for number, x, y in zip(numbers, profile.positions_mm, magnitudes, strict=False):
            if not math.isfinite(x + y):
                continue
            out.append(
                f'<circle cx="{panel.x(x):.1f}" cy="{panel.y(y):.1f}" r="5" fill="{PALETTE[1]}"/>'
                # a white halo below the number: a second text, not paint-order, which not
                # every SVG program draws
                f'<text x="{panel.x(x):.1f}" y="{panel.y(y) - 10:.1f}" text-anchor="middle" '
                f'font-weight="bold" fill="#fff" stroke="#fff" stroke-width="3">{number}</text>'
                f'<text x="{panel.x(x):.1f}" y="{panel.y(y) - 10:.1f}" text-anchor="middle" '
                f'font-weight="bold" fill="{INK}">{number}</text>'
            )
    many = len(numbered) > 7
    for x in sorted(numbered):
        label = f"{numbered[x]}" if many else f"{numbered[x]}: {format_mm(x)} mm"
        out.append(
            f'<line x1="{panel.x(x):.1f}" x2="{panel.x(x):.1f}" y1="{panel.bottom:g}" '
            f'y2="{panel.bottom + 4:g}" stroke="#444"/>'
            f'<text x="{panel.x(x):.1f}" y="{panel.bottom + 16:g}" text-anchor="middle" '
            f'fill="{TEXT}">{text(label)}</text>'
        )
    out.append(
        f'<text x="{panel.left + panel.width / 2:g}" y="{panel.bottom + 36:g}" '
        f'text-anchor="middle" fill="{TEXT}">measuring position (number: place along the '
        f"travel)</text>"
        f'<text transform="translate(16 {top + plot_h / 2:g}) rotate(-90)" '
        f'text-anchor="middle" fill="{TEXT}">{text(unit_label(result))}</text>'
    )
    if averages:
        spread = averages[0].spread_percent
        out.append(
            f'<g transform="translate({panel.left + panel.width - 290:.1f} '
            f'{panel.bottom - 14:.1f})"><line x1="0" x2="18" y1="0" y2="0" '
            f'stroke="{PALETTE[1]}" stroke-width="2.8"/><circle cx="9" cy="0" r="5" '
            f'fill="{PALETTE[1]}"/><text x="24" y="4" fill="{INK}">average over velocities '
            f"(spread {spread:.0f} %)</text></g>"
        )
    out.append("</g>")
    if per_velocity:
        out += _velocity_scale(panel, slowest, fastest, logarithmic, share)
    out.append("</svg>")
    return "\n".join(out)


def _velocity_scale(
    panel: Panel,
    slowest: float,
    fastest: float,
    logarithmic: bool,
    share: Callable[[float], float],
) -> list[str]:
    """The thin lines' colour scale at the right: 24 bands, slow at the bottom."""
    left = panel.left + panel.width + 20
    bands = 24
    step = panel.height / bands
    out = [
        f'<rect x="{left:g}" y="{panel.top + (bands - 1 - k) * step:.1f}" width="14" '
        f'height="{step + 0.5:.1f}" fill="{_shade((k + 0.5) / bands)}"/>'
        for k in range(bands)
    ]
    if logarithmic:
        ticks = [t for t in _speed_ticks(slowest, fastest)[0] if slowest <= t <= fastest]
    else:
        ticks = [t for t in nice_ticks(slowest, fastest) if slowest <= t <= fastest]
    for tick in ticks or [slowest, fastest]:
        y = panel.bottom - share(tick) * panel.height
        out.append(
            f'<line x1="{left + 14:g}" x2="{left + 18:g}" y1="{y:.1f}" y2="{y:.1f}" '
            f'stroke="#444"/><text x="{left + 21:g}" y="{y + 4:.1f}" font-size="10" '
            f'fill="{TEXT}">{speed_text(tick, 1.0)}</text>'
        )
    middle = panel.top + panel.height / 2
    out.append(
        f'<text transform="translate({left + 76:g} {middle:g}) rotate(-90)" '
        f'text-anchor="middle" font-size="10" fill="{TEXT}">velocity of the thin lines '
        f"[mm/min]</text>"
    )
    return out
