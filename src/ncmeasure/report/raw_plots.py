"""The report's raw-data figure: motor current and velocity over time, the windows shaded.

:func:`raw_trace` takes what the figure shows from a recording in memory (a
recording read chunk by chunk gathers it in :mod:`ncmeasure.report.traces`);
:func:`plot_trace` draws it with the kit of :mod:`ncmeasure.report.plots`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from ncmeasure.recording import Recording
from ncmeasure.report.colours import INK, PALETTE
from ncmeasure.report.plots import (
    EDGE_PT,
    LINE_EM,
    TICK_PT,
    TITLE_PAD_PT,
    WINDOW_FILL,
    X_BAND_PT,
    FloatArray,
    bottom_legend,
    new_figure,
    place_axes,
    plain_text,
    points_in,
    style_axes,
    styled,
    y_band_in,
)

__all__ = ["OVERVIEW_BINS", "RawTrace", "plot_raw_data", "plot_trace", "raw_trace"]


def _envelope(time_s: FloatArray, values: FloatArray, bins: int) -> tuple[FloatArray, FloatArray]:
    """At most ``2·bins`` points that keep every peak: min and max of each bin, in order."""
    if len(time_s) <= 2 * bins:
        return time_s, values
    size = -(-len(time_s) // bins)  # ceil: the last bin is padded with the last sample
    pad = size * bins - len(time_s)
    blocks = np.pad(values, (0, pad), mode="edge").reshape(bins, size)
    times = np.pad(time_s, (0, pad), mode="edge").reshape(bins, size)
    low_index = np.argmin(blocks, axis=1)
    high_index = np.argmax(blocks, axis=1)
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


def _shade(ax: Axes, windows: Sequence[tuple[float, float]], start: float, end: float) -> None:
    """The windows between ``start`` and ``end`` as full-height bands, in one collection.

    One artist instead of one ``axvspan`` per window (a measurement has
    thousands): the same bands, drawn and laid out in a fraction of the time.
    They do not change the data limits, as ``axvspan`` does not where the
    caller sets them. The bands go to the collection as one array, which it
    turns into paths without checking each band on its own.
    """
    if not windows:
        return
    edges = np.asarray(windows, dtype=np.float64).reshape(-1, 2)
    shown = edges[(edges[:, 1] >= start) & (edges[:, 0] <= end)]
    if not len(shown):
        return
    bands = np.empty((len(shown), 4, 2))
    bands[:, :2, 0] = shown[:, :1]  # (t0, 0), (t0, 1), (t1, 1), (t1, 0)
    bands[:, 2:, 0] = shown[:, 1:]
    bands[:, :, 1] = (0.0, 1.0, 1.0, 0.0)
    ax.add_collection(
        PolyCollection(
            bands,  # type: ignore[arg-type]  # an array, which the stubs do not list
            transform=ax.get_xaxis_transform(),
            facecolors=WINDOW_FILL,
            alpha=0.55,
            linewidths=0,
            zorder=0,
        ),
        autolim=False,
    )


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


def plot_raw_data(
    recording: Recording,
    axis: str,
    windows: Sequence[tuple[float, float]] = (),
    *,
    stretch_s: float = 30.0,
) -> Figure:
    """Motor current and velocity of one axis over time, the cut windows shaded.

    The top strip shows the axis' whole measurement (velocity, peaks kept),
    the two panels below a stretch of about ``stretch_s`` seconds from its
    first windows on: current, then commanded and actual velocity. Only the
    shaded windows enter the friction values.

    Args:
        recording: The recording.
        axis: The axis; needs ``<axis>_current_a`` and ``<axis>_velocity_mm_min``.
        windows: The constant-velocity windows the analysis used, (t_start, t_end) in s.
        stretch_s: Length of the detailed stretch in seconds.

    Raises:
        RecordingError: The recording lacks the current or velocity of the axis.
    """
    return plot_trace(raw_trace(recording, axis, windows, stretch_s=stretch_s))


@styled
def plot_trace(trace: RawTrace) -> Figure:
    """:func:`plot_raw_data` from its data (:func:`raw_trace`, or read chunk by chunk)."""
    axis = trace.axis
    cuts = trace.windows
    figure = new_figure(6.2, constrained=False)
    overview = figure.add_axes((0.1, 0.8, 0.8, 0.1))
    top = figure.add_axes((0.1, 0.45, 0.8, 0.3))
    bottom = figure.add_axes((0.1, 0.1, 0.8, 0.3), sharex=top)
    for ax in (overview, top, bottom):
        style_axes(ax)
    if trace.rows == 0:
        top.text(
            0.5,
            0.5,
            "the recording holds no samples",
            transform=top.transAxes,
            ha="center",
            va="center",
            color="#888888",
        )
        _arrange_raw(figure, (overview, top, bottom), 0.0)
        return figure
    span = trace.span
    start, end = trace.stretch
    _shade(overview, cuts, *span)
    overview.plot(trace.overview_time_s, trace.overview_velocity, color=PALETTE[1], linewidth=0.7)
    overview.add_patch(
        Rectangle(
            (start, 0.0),
            end - start,
            1.0,
            transform=overview.get_xaxis_transform(),
            fill=False,
            edgecolor=INK,
            linewidth=1.2,
            zorder=5,
        )
    )
    overview.set_xlim(*span)
    overview.set_ylabel("mm/min", fontsize=8.5)
    overview.set_title(
        plain_text(
            f"Axis {axis}: raw data — whole measurement ({span[1] - span[0]:.0f} s, box: "
            "the stretch below)"
        ),
        loc="left",
        y=1.0,
    )

    time_s, current, velocity, command = trace.time_s, trace.current, trace.velocity, trace.command

    t_part, i_part = _envelope(time_s, current, 4000)
    _shade(top, cuts, start, end)
    top.plot(t_part, i_part, color=PALETTE[0], linewidth=0.8)
    top.set_ylabel("current [A]")
    top.tick_params(labelbottom=False)
    top.set_title(plain_text(f"stretch {start:.1f} – {end:.1f} s"), loc="left", fontsize=9.5, y=1.0)

    _shade(bottom, cuts, start, end)
    if command is not None:
        t_cmd, c_part = _envelope(time_s, command, 4000)
        bottom.plot(
            t_cmd,
            c_part,
            color="#777777",
            linewidth=1.0,
            linestyle=(0, (4, 2)),
            label="commanded velocity",
        )
    t_vel, v_part = _envelope(time_s, velocity, 4000)
    bottom.plot(t_vel, v_part, color=PALETTE[1], linewidth=1.0, label="actual velocity")
    bottom.set_ylabel("velocity [mm/min]")
    bottom.set_xlabel("time [s]")
    bottom.set_xlim(start, end)
    handles = [
        Line2D([], [], color=PALETTE[0], linewidth=1.2, label="motor current"),
        *bottom.get_legend_handles_labels()[0],
        Patch(facecolor=WINDOW_FILL, alpha=0.55, label="windows used for friction"),
    ]
    _arrange_raw(figure, (overview, top, bottom), bottom_legend(figure, handles, len(handles)))
    return figure


def _arrange_raw(figure: Figure, panels: tuple[Axes, Axes, Axes], legend_in: float) -> None:
    """The fixed layout of :func:`plot_raw_data`: three panels 1 : 2 : 2 high, room for the
    titles, the overview's time ticks, the bottom panel's axis labels and the legend."""
    overview, top, bottom = panels
    width_in, height_in = figure.get_size_inches()
    top_in = points_in(EDGE_PT + LINE_EM * 11 + TITLE_PAD_PT)
    # between overview and stretch: the overview's time ticks, then the stretch's title
    first_gap_in = points_in(TICK_PT + LINE_EM * 9.5 + 4.0 + LINE_EM * 9.5 + TITLE_PAD_PT)
    second_gap_in = points_in(9.0)
    bottom_in = (
        legend_in + points_in(6.0 + X_BAND_PT) if legend_in else points_in(EDGE_PT + X_BAND_PT)
    )
    unit_in = (height_in - top_in - first_gap_in - second_gap_in - bottom_in) / 5
    right_in = 0.2

    def arrange(left_in: float) -> None:
        plot_w = width_in - left_in - right_in
        place_axes(figure, bottom, left_in, bottom_in, plot_w, 2 * unit_in)
        place_axes(
            figure, top, left_in, bottom_in + 2 * unit_in + second_gap_in, plot_w, 2 * unit_in
        )
        place_axes(figure, overview, left_in, height_in - top_in - unit_in, plot_w, unit_in)

    arrange(1.0)  # the value ticks depend on the panels' heights only: measure them now
    left_in = max(
        y_band_in(figure, overview.yaxis, label_pt=8.5),
        y_band_in(figure, top.yaxis),
        y_band_in(figure, bottom.yaxis),
    )
    arrange(points_in(EDGE_PT) + left_in)
