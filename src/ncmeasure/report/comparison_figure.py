"""The report's comparison figure, as SVG written directly, without matplotlib.

One row per axis, position and direction, one point per compared run: the median
over the velocities of (run − base)/base in %. Around zero the bands of the
limits: green within the warning limit, orange up to the critical one, red beyond;
a point beyond a limit has an orange or red rim as well, so the status reads
without colour on a grey print too (the rim, and the point's place in its band).
"""

from __future__ import annotations

import math
from typing import Final

from ncmeasure.formats.comparison import Comparison
from ncmeasure.report.colours import CRITICAL, GOOD, PALETTE, WARNING
from ncmeasure.report.svg import (
    FONT_PX,
    TEXT,
    WIDTH,
    Panel,
    frame,
    legend,
    svg_head,
    text,
    x_axis,
)
from ncmeasure.report.words import format_mm

__all__ = ["comparison_svg"]

_STATUS_RIMS: Final = {"ok": "#ffffff", "warning": WARNING, "critical": CRITICAL}
_ROW: Final = 20.0
"""The height of a row in px."""


def comparison_svg(comparison: Comparison) -> str:
    """Change of friction per axis, position and direction against the base run, as ``<svg>``."""
    keys = sorted(
        {(g.axis, g.position_index, g.position_mm, g.direction) for g in comparison.groups},
        key=lambda k: (k[0], k[1], k[3] != "positive"),
    )
    labels = list(dict.fromkeys(g.label for g in comparison.groups))
    warning = comparison.limits.warning_percent
    critical = comparison.limits.critical_percent
    values = [
        g.median_deviation_percent
        for g in comparison.groups
        if math.isfinite(g.median_deviation_percent)
    ]
    reach = max([critical * 1.25, *(abs(v) * 1.1 for v in values)])
    row_labels = {
        key: f"{key[0]} · {key[1] + 1}: {format_mm(key[2])} mm · {key[3]}" for key in keys
    }
    # room for the longest row label (about 0.55 em a character), within a third of the width
    widest = max((len(label) for label in row_labels.values()), default=10)
    left, right, top = min(WIDTH / 3, max(120.0, 16 + 0.55 * FONT_PX * widest)), 16.0, 40.0
    panel = Panel(
        left, top, WIDTH - left - right, _ROW * max(len(keys), 1), -reach, reach, 0.0, 1.0
    )
    legend_rows = math.ceil(len(labels) / 4)
    height = panel.bottom + 40 + 18 * legend_rows + 12
    out = svg_head(
        height,
        f"Comparison with {comparison.base}: warning beyond ±{warning:g} %, "
        f"critical beyond ±{critical:g} %",
    )
    bands = [(-warning, warning, GOOD, 0.08)]
    for sign in (-1.0, 1.0):
        bands.append((sign * warning, sign * critical, WARNING, 0.12))
        bands.append((sign * critical, sign * reach, CRITICAL, 0.10))
    for low, high, colour, opacity in bands:
        a, b = sorted((panel.x(low), panel.x(high)))
        out.append(
            f'<rect x="{a:.1f}" y="{panel.top:g}" width="{b - a:.1f}" height="{panel.height:g}" '
            f'fill="{colour}" fill-opacity="{opacity:g}"/>'
        )
    out += x_axis(panel, 9, grid=True)
    zero = panel.x(0.0)
    out.append(
        f'<line x1="{zero:.1f}" x2="{zero:.1f}" y1="{panel.top:g}" y2="{panel.bottom:g}" '
        f'stroke="#555555" stroke-width="0.9"/>'
    )
    row_y = {key: panel.top + (index + 0.5) * _ROW for index, key in enumerate(keys)}
    for key, y in row_y.items():
        out.append(
            f'<text x="{panel.left - 6:g}" y="{y + 4:.1f}" text-anchor="end" '
            f'fill="{TEXT}">{text(row_labels[key])}</text>'
        )
    out.append(frame(panel))
    for number, label in enumerate(labels):
        colour = PALETTE[number % len(PALETTE)]
        for g in comparison.groups:
            if g.label != label or not math.isfinite(g.median_deviation_percent):
                continue
            y = row_y[(g.axis, g.position_index, g.position_mm, g.direction)]
            out.append(
                f'<circle cx="{panel.x(g.median_deviation_percent):.1f}" cy="{y:.1f}" r="5" '
                f'fill="{colour}" stroke="{_STATUS_RIMS[g.status]}" stroke-width="1.6">'
                f"<title>{text(label)}: {g.median_deviation_percent:+.1f} % "
                f"({g.status})</title></circle>"
            )
    out.append(
        f'<text x="{panel.left + panel.width / 2:g}" y="{panel.bottom + 34:g}" '
        f'text-anchor="middle" fill="{TEXT}">change of friction against the base [%]  '
        f"(median over the velocities)</text>"
    )
    entries = [
        (f'<circle cx="9" cy="0" r="5" fill="{PALETTE[k % len(PALETTE)]}"/>', label)
        for k, label in enumerate(labels)
    ]
    out += legend(entries, panel.bottom + 56, panel.left, panel.width)
    out.append("</svg>")
    return "\n".join(out)
