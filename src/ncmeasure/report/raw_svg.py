"""The raw-data figure of an axis: motor current and velocity over time, the windows shaded.

:func:`raw_trace` takes what the figure shows from a recording in memory (a
recording read chunk by chunk gathers it in :mod:`ncmeasure.report.traces`);
:func:`trace_svg` draws it as SVG, written directly (the kit of
:mod:`ncmeasure.report.svg`): on top the axis' whole measurement (velocity, peaks
kept, a box around the stretch below), then a stretch of about 30 s from its first
windows on: current, then commanded and actual velocity. Only the shaded windows
enter the friction values.

Each line keeps the lowest and highest value of every bin about a pixel wide
(:func:`_envelope`), so a peak of one sample still shows; windows closer than half a
pixel are shaded as one band. So the figure stays a few hundred kB, whatever the
recording's length and its number of windows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from ncmeasure.recording import Recording
from ncmeasure.report.colours import INK, PALETTE
from ncmeasure.report.svg import (
    TEXT,
    WIDTH,
    Panel,
    frame,
    legend,
    polyline,
    svg_head,
    text,
    x_axis,
    y_grid,
)

__all__ = ["OVERVIEW_BINS", "WINDOW_FILL", "RawTrace", "raw_data_svg", "raw_trace", "trace_svg"]

FloatArray = NDArray[np.float64]

WINDOW_FILL: Final = "#9fd3a8"
"""The shade of the windows used for friction."""
_STRETCH_BINS: Final = 1000
"""The stretch's lines keep the lowest and highest value of this many bins (about one
per pixel of the panel)."""


def _envelope(time_s: FloatArray, values: FloatArray, bins: int) -> tuple[FloatArray, FloatArray]:
    """At most ``2·bins`` points that keep every peak: min and max of each bin, in order.

    A sample that is not a number (lost) does not hide a bin's peaks; a bin of nothing
    else stays not a number, a gap in the line.
    """
    if len(time_s) <= 2 * bins:
        return time_s, values
    size = -(-len(time_s) // bins)  # ceil: the last bin is padded with the last sample
    pad = size * bins - len(time_s)
    blocks = np.pad(values, (0, pad), mode="edge").reshape(bins, size)
    times = np.pad(time_s, (0, pad), mode="edge").reshape(bins, size)
    missing = np.isnan(blocks)
    low_index = np.argmin(np.where(missing, np.inf, blocks), axis=1)
    high_index = np.argmax(np.where(missing, -np.inf, blocks), axis=1)
    first = np.minimum(low_index, high_index)
    second = np.maximum(low_index, high_index)
    rows = np.arange(bins)
    out_t = np.column_stack([times[rows, first], times[rows, second]]).ravel()
    out_v = np.column_stack([blocks[rows, first], blocks[rows, second]]).ravel()
    return out_t, out_v


def _axis_span(
    time_s: FloatArray, velocity: FloatArray, windows: Sequence[tuple[float, float]]
) -> tuple[float, float]:
    """The time the axis was being measured: its windows, or where it moved."""
    if windows:
        start = min(w[0] for w in windows)
        end = max(w[1] for w in windows)
        pad = 0.02 * max(end - start, 1.0)
        return max(float(time_s[0]), start - pad), min(float(time_s[-1]), end + pad)
    peak = float(np.nanmax(np.abs(velocity))) if len(velocity) else 0.0
    moving = np.flatnonzero(np.abs(velocity) > 0.01 * peak) if peak > 0 else np.array([], int)
    if len(moving) == 0:
        return float(time_s[0]), float(time_s[-1])
    return float(time_s[moving[0]]), float(time_s[moving[-1]])


def _stretch(
    span: tuple[float, float], windows: Sequence[tuple[float, float]], stretch_s: float
) -> tuple[float, float]:
    """A stretch of about ``stretch_s`` seconds from the first windows on."""
    if not windows:
        return span[0], min(span[1], span[0] + stretch_s)
    lead = 0.5
    start = max(span[0], windows[0][0] - lead)
    end = windows[0][1] + lead
    for window in windows[1:]:
        if window[1] + lead - start > stretch_s:
            break
        end = window[1] + lead
    return start, min(span[1], end)


@dataclass(frozen=True)
class RawTrace:
    """What the raw-data figure of an axis shows: bounded, whatever the recording's length.

    Attributes:
        axis: The axis.
        windows: The windows shaded, (t_start, t_end) in s, in time order.
        span: The time the axis was measured (the overview's range).
        stretch: The stretch shown in detail.
        overview_time_s: Times of the overview's velocity (at most 4000 points, peaks kept).
        overview_velocity: The overview's velocity.
        time_s: Times of the stretch's samples.
        current: Current over the stretch.
        velocity: Actual velocity over the stretch.
        command: Commanded velocity over the stretch, where recorded.
        rows: Samples of the recording (0: an empty recording).
    """

    axis: str
    windows: tuple[tuple[float, float], ...]
    span: tuple[float, float]
    stretch: tuple[float, float]
    overview_time_s: FloatArray
    overview_velocity: FloatArray
    time_s: FloatArray
    current: FloatArray
    velocity: FloatArray
    command: FloatArray | None
    rows: int


OVERVIEW_BINS: Final = 2000
"""The overview keeps the lowest and highest velocity of this many bins."""


def raw_trace(
    recording: Recording,
    axis: str,
    windows: Sequence[tuple[float, float]] = (),
    *,
    stretch_s: float = 30.0,
) -> RawTrace:
    """The raw-data figure's data of one axis of a recording in memory.

    Raises:
        RecordingError: The recording lacks the current or velocity of the axis.
    """
    time_s = recording.time_s
    current = recording.axis_signal(axis, "current_a")
    velocity = recording.axis_signal(axis, "velocity_mm_min")
    command: FloatArray | None = None
    if f"{axis}_velocity_cmd_mm_min" in recording.channel_names:
        command = recording.axis_signal(axis, "velocity_cmd_mm_min")
    cuts = tuple(sorted((float(a), float(b)) for a, b in windows))
    empty = np.empty(0, dtype=np.float64)
    if len(time_s) == 0:
        return RawTrace(axis, cuts, (0.0, 0.0), (0.0, 0.0), empty, empty, empty, empty, empty,
                        None, 0)  # fmt: skip
    span = _axis_span(time_s, velocity, cuts)
    start, end = _stretch(span, cuts, stretch_s)
    inside = (time_s >= span[0]) & (time_s <= span[1])
    t_all, v_all = _envelope(time_s[inside], velocity[inside], OVERVIEW_BINS)
    part = (time_s >= start) & (time_s <= end)
    return RawTrace(
        axis,
        cuts,
        span,
        (start, end),
        t_all,
        v_all,
        time_s[part],
        current[part],
        velocity[part],
        None if command is None else command[part],
        len(time_s),
    )


def raw_data_svg(
    recording: Recording,
    axis: str,
    windows: Sequence[tuple[float, float]] = (),
    *,
    stretch_s: float = 30.0,
) -> str:
    """Motor current and velocity of one axis over time, the cut windows shaded, as ``<svg>``.

    Args:
        recording: The recording.
        axis: The axis; needs ``<axis>_current_a`` and ``<axis>_velocity_mm_min``.
        windows: The constant-velocity windows the analysis used, (t_start, t_end) in s.
        stretch_s: Length of the detailed stretch in seconds.

    Raises:
        RecordingError: The recording lacks the current or velocity of the axis.
    """
    return trace_svg(raw_trace(recording, axis, windows, stretch_s=stretch_s))


def _range(*series: FloatArray | None) -> tuple[float, float]:
    """The value range of a panel: the finite values of its lines, 6 % to spare."""
    finite = [s[np.isfinite(s)] for s in series if s is not None and len(s)]
    values = np.concatenate(finite) if finite else np.empty(0)
    if not len(values):
        return -1.0, 1.0
    low, high = float(values.min()), float(values.max())
    pad = (high - low) * 0.06 or max(abs(high) * 0.1, 1.0)
    return low - pad, high + pad


def _shade(panel: Panel, windows: Sequence[tuple[float, float]]) -> str:
    """The windows inside the panel's time range as full-height bands, one path; windows
    less than half a pixel apart are one band."""
    if not windows:
        return ""
    edges = np.asarray(windows, dtype=np.float64).reshape(-1, 2)
    edges = edges[(edges[:, 1] >= panel.x_low) & (edges[:, 0] <= panel.x_high)]
    if not len(edges):
        return ""
    edges = np.clip(edges[np.argsort(edges[:, 0], kind="stable")], panel.x_low, panel.x_high)
    x = panel.xs(edges)
    bands: list[list[float]] = []
    for start, end in x:
        if bands and start - bands[-1][1] < 0.5:
            bands[-1][1] = max(bands[-1][1], end)
        else:
            bands.append([start, end])
    path = "".join(
        f"M{a:.1f} {panel.top:g}h{max(b - a, 0.3):.1f}v{panel.height:g}h{-max(b - a, 0.3):.1f}z"
        for a, b in bands
    )
    return f'<path d="{path}" fill="{WINDOW_FILL}" fill-opacity="0.55"/>'


def _y_title(panel: Panel, title: str) -> str:
    return (
        f'<text transform="translate(16 {panel.top + panel.height / 2:g}) rotate(-90)" '
        f'text-anchor="middle" fill="{TEXT}">{text(title)}</text>'
    )


def trace_svg(trace: RawTrace) -> str:
    """:func:`raw_data_svg` from its data (:func:`raw_trace`, or read chunk by chunk)."""
    axis = trace.axis
    left, right = 78.0, 16.0
    width = WIDTH - left - right
    if trace.rows == 0:
        out = svg_head(120.0, f"Axis {axis}: raw data")
        out.append(
            f'<text x="{WIDTH / 2:g}" y="70" text-anchor="middle" font-size="14" '
            f'fill="#888888">the recording holds no samples</text></svg>'
        )
        return "\n".join(out)
    span = trace.span
    start, end = trace.stretch
    if not span[1] > span[0]:
        span = (span[0] - 0.5, span[0] + 0.5)
    if not end > start:
        start, end = start - 0.5, start + 0.5
    overview = Panel(left, 34.0, width, 70.0, *span, *_range(trace.overview_velocity))
    t_i, current = _envelope(trace.time_s, trace.current, _STRETCH_BINS)
    t_v, velocity = _envelope(trace.time_s, trace.velocity, _STRETCH_BINS)
    command = None
    if trace.command is not None:
        command = _envelope(trace.time_s, trace.command, _STRETCH_BINS)
    top = Panel(left, 152.0, width, 150.0, start, end, *_range(current))
    bottom = Panel(
        left,
        312.0,
        width,
        150.0,
        start,
        end,
        *_range(velocity, None if command is None else command[1]),
    )
    height = bottom.bottom + 42 + 18 + 10
    out = svg_head(
        height,
        f"Axis {axis}: raw data — whole measurement ({span[1] - span[0]:.0f} s, box: "
        "the stretch below)",
    )
    out.append(_shade(overview, trace.windows))
    out += y_grid(overview)
    out.append(
        polyline(
            overview,
            trace.overview_time_s,
            trace.overview_velocity,
            f'stroke="{PALETTE[1]}" stroke-width="0.8"',
        )
    )
    box_left, box_right = overview.x(max(start, span[0])), overview.x(min(end, span[1]))
    out.append(
        f'<rect x="{box_left:.1f}" y="{overview.top:g}" width="{box_right - box_left:.1f}" '
        f'height="{overview.height:g}" fill="none" stroke="{INK}" stroke-width="1.3"/>'
    )
    out.append(frame(overview))
    out += x_axis(overview, 8)
    out.append(
        f'<text transform="translate(16 {overview.top + overview.height / 2:g}) rotate(-90)" '
        f'text-anchor="middle" font-size="10" fill="{TEXT}">mm/min</text>'
    )
    stretch = f"stretch {start:.1f} – {end:.1f} s".replace("-", "\u2212")
    out.append(f'<text x="{left:g}" y="{top.top - 10:g}" fill="{INK}">{stretch}</text>')
    out.append(_shade(top, trace.windows))
    out += y_grid(top)
    out.append(polyline(top, t_i, current, f'stroke="{PALETTE[0]}" stroke-width="0.9"'))
    out.append(frame(top))
    out += x_axis(top, 8, labels=False)
    out.append(_y_title(top, "current [A]"))
    out.append(_shade(bottom, trace.windows))
    out += y_grid(bottom)
    if command is not None:
        out.append(
            polyline(
                bottom,
                *command,
                'stroke="#777777" stroke-width="1.1" stroke-dasharray="4 2"',
            )
        )
    out.append(polyline(bottom, t_v, velocity, f'stroke="{PALETTE[1]}" stroke-width="1.1"'))
    out.append(frame(bottom))
    out += x_axis(bottom, 8)
    out.append(_y_title(bottom, "velocity [mm/min]"))
    out.append(
        f'<text x="{left + width / 2:g}" y="{bottom.bottom + 32:g}" text-anchor="middle" '
        f'fill="{TEXT}">time [s]</text>'
    )
    entries = [
        (
            f'<line x1="0" x2="18" y1="0" y2="0" stroke="{PALETTE[0]}" stroke-width="1.3"/>',
            "motor current",
        )
    ]
    if command is not None:
        entries.append(
            (
                '<line x1="0" x2="18" y1="0" y2="0" stroke="#777777" stroke-width="1.3" '
                'stroke-dasharray="4 2"/>',
                "commanded velocity",
            )
        )
    entries += [
        (
            f'<line x1="0" x2="18" y1="0" y2="0" stroke="{PALETTE[1]}" stroke-width="1.3"/>',
            "actual velocity",
        ),
        (
            f'<rect x="0" y="-6" width="18" height="12" fill="{WINDOW_FILL}" fill-opacity="0.55"/>',
            "windows used for friction",
        ),
    ]
    out += legend(entries, bottom.bottom + 54, left, width)
    out.append("</svg>")
    return "\n".join(out)
