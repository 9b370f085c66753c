"""The report's friction figures: Stribeck curves per axis, friction along the travel.

Both are drawn with the kit of :mod:`ncmeasure.report.plots` (own Agg canvas,
the report's rc settings, a fixed layout measured in inches).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.axis import Axis
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection
from matplotlib.colors import LinearSegmentedColormap, LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter, LogFormatter, LogLocator

from ncmeasure.formats.results import AxisResult, DirectionResult, VelocityProfile
from ncmeasure.report.bearings import BearingLayout
from ncmeasure.report.colours import INK, PALETTE
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
from ncmeasure.report.plots import (
    EDGE_PT,
    LABEL_PAD_PT,
    LINE_EM,
    TICK_PT,
    TITLE_PAD_PT,
    X_BAND_PT,
    FloatArray,
    bottom_legend,
    new_figure,
    place_axes,
    plain_text,
    points_in,
    style_axes,
    styled,
    tick_label_width_in,
    y_band_in,
)
from ncmeasure.report.words import format_mm

__all__ = ["plot_stribeck", "plot_travel"]

_PROFILES = LinearSegmentedColormap.from_list("ncmeasure_profiles", ["#b9cfe8", "#0b2f5c"])


def _speed_tick(sign: float) -> FuncFormatter:
    return FuncFormatter(lambda value, _position: speed_text(value, sign))


def _speed_ticks(axis: Axis, sign: float, low: float, high: float) -> None:
    """Tick labels of a logarithmic speed axis from ``low`` to ``high``: plain numbers.

    Over more than one and a half decades the minor ticks sit at 2 and 5 of
    each decade, unlabelled, instead of matplotlib's 2 to 9: every tick is a
    handful of artists, and on these axes the minor ticks were most of them.
    Over less the decades are too few to read the scale from, and every minor
    tick stays, labelled where matplotlib labels it.
    """
    axis.set_major_formatter(_speed_tick(sign))
    if high > low * 10**1.5:
        axis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
    axis.set_minor_formatter(_MinorSpeedTick(sign))


class _MinorSpeedTick(LogFormatter):
    """Labels of the minor ticks of a logarithmic speed axis, as plain numbers.

    Which minor ticks are labelled is matplotlib's choice (none over more than
    a decade, some over less); the text is :func:`~ncmeasure.report.curves.speed_text`, not the
    mathtext ``2×10^2`` of matplotlib's default, which needs math fonts.
    """

    def __init__(self, sign: float) -> None:
        super().__init__(labelOnlyBase=False, minor_thresholds=(1, 0.4))
        self._sign = sign

    def __call__(self, x: float, pos: int | None = None) -> str:
        return speed_text(x, self._sign) if super().__call__(x, pos) else ""


def _error_bars(ax: Axes, x: FloatArray, y: FloatArray, error: FloatArray, colour: str) -> None:
    """Points with ± ``error`` bars and caps: the artists ``ax.errorbar`` makes, fewer of them.

    ``errorbar(fmt="o", markersize=4.5, elinewidth=1.0, capsize=2.5, zorder=3)``
    draws the bars (one collection), then the lower and the upper caps (two
    lines of markers) at zorder 3 and the points above them at 3.1. Here both
    caps are one line of markers, lower ones first, so the same marks are
    drawn in the same order, without errorbar's per-call work; the bars are
    the collection ``vlines`` makes, from the array (``vlines`` goes through
    masked arrays), and take part in the data limits as there.
    """
    low, high = y - error, y + error
    ax.add_line(
        Line2D(x, y, color=colour, marker="o", linestyle="none", markersize=4.5, zorder=3.1)
    )
    bars = np.empty((len(x), 2, 2))
    bars[:, :, 0] = x[:, None]
    bars[:, 0, 1], bars[:, 1, 1] = low, high
    ax.add_collection(
        LineCollection(bars, colors=colour, linewidths=1.0, zorder=3),  # type: ignore[arg-type]
        autolim=True,
    )
    ax.add_line(
        Line2D(
            np.concatenate([x, x]),
            np.concatenate([low, high]),
            color=colour,
            marker="_",
            linestyle="none",
            markersize=5.0,
            markeredgecolor=colour,
            zorder=3,
        )
    )


def _draw_direction(
    ax: Axes,
    direction: DirectionResult,
    sign: float,
    colour: str,
    offset: float | None,
    slowest: float,
) -> bool:
    """Points, linear fit and Stribeck fit of one direction on a log |v| axis.

    Returns:
        True when a Stribeck curve was drawn.
    """
    points = sorted(direction.points, key=lambda p: abs(p.velocity_mm_min))
    points = [p for p in points if p.velocity_mm_min != 0]
    if points:
        _error_bars(
            ax,
            np.array([abs(p.velocity_mm_min) for p in points]),
            np.array([p.median for p in points]),
            np.array([p.std for p in points]),
            colour,
        )
    fit = direction.fit
    if fit is not None:
        inside, below = linear_spans(fit, slowest, 80)
        ax.plot(
            inside,
            linear_curve(fit, sign * inside, sign, points, offset),
            linestyle=(0, (5, 3)),
            color=colour,
            linewidth=1.3,
            zorder=2.5,
        )
        if below is not None:  # extrapolated below the fitted speeds: lighter
            ax.plot(
                below,
                linear_curve(fit, sign * below, sign, points, offset),
                linestyle=(0, (1, 2)),
                color=colour,
                linewidth=1.1,
                alpha=0.7,
                zorder=2,
            )
    model = drawn_model(direction)
    if model is None or not points:
        return False
    grid = np.geomspace(abs(points[0].velocity_mm_min), abs(points[-1].velocity_mm_min), 160)
    curve = stribeck_curve(model, sign * grid, sign, points, offset)
    if curve is None:
        return False
    ax.plot(grid, curve, color=colour, linewidth=1.9, zorder=2)
    return True


@styled
def plot_stribeck(axis: str, result: AxisResult) -> Figure:
    """Friction over velocity for every position and direction of an axis.

    Two panels share the friction scale: the negative direction on the left
    (velocity growing to the left), the positive on the right, both with a
    logarithmic speed scale so that the slow steps, where the Stribeck effect
    lives, get as much room as the fast ones. Median ± standard deviation per
    velocity step, one colour per position; the Coulomb + viscous fit dashed
    over the speeds it was fitted to (dotted where extrapolated below them);
    the Stribeck fit solid where it is identifiable.

    Args:
        axis: The axis name, for the title.
        result: The axis' results.

    Returns:
        A new figure on an Agg canvas.
    """
    figure = new_figure(5.4, constrained=False)
    negative = figure.add_axes((0.1, 0.2, 0.4, 0.7))
    positive = figure.add_axes((0.55, 0.2, 0.4, 0.7), sharey=negative)
    offset = result.offset.value if result.offset is not None else None
    significant = offset_is_significant(result.offset)
    slowest, fastest = speed_range(result)
    panels = {"negative": (negative, -1.0), "positive": (positive, 1.0)}
    position_handles, drawn, any_stribeck = _draw_positions(panels, result, offset, slowest)
    shown_offset = offset if significant else None
    _style_speed_panels(panels, drawn, slowest, fastest, shown_offset)
    positive.tick_params(labelleft=False)
    positive.spines["left"].set_color("#aaaaaa")
    negative.set_ylabel(unit_label(result))
    low, high = negative.get_ylim()
    negative.set_ylim(min(low, 0.0), max(high, 0.0))
    figure.suptitle(
        plain_text(f"Axis {axis}: friction over velocity (Stribeck curves)"),
        x=0.01,
        y=1.0 - points_in(EDGE_PT) / figure.get_size_inches()[1],
        ha="left",
        va="top",
        fontsize=11,
    )
    handles = [*position_handles, *_style_handles(any_stribeck, shown_offset is not None)]
    legend_in = bottom_legend(figure, handles, min(4, len(handles)))
    _arrange_stribeck(figure, negative, positive, legend_in)
    return figure


def _draw_positions(
    panels: Mapping[str, tuple[Axes, float]],
    result: AxisResult,
    offset: float | None,
    slowest: float,
) -> tuple[list[Line2D], dict[str, bool], bool]:
    """Every position's directions on their panels, one colour per position.

    Returns:
        A legend handle per position, which panels got points, and whether
        any Stribeck curve was drawn.
    """
    drawn = {"negative": False, "positive": False}
    position_handles: list[Line2D] = []
    any_stribeck = False
    for index, position in enumerate(result.positions):
        colour = PALETTE[index % len(PALETTE)]
        label = f"position {position.position_index + 1}: {format_mm(position.position_mm)} mm"
        position_handles.append(
            Line2D([], [], color=colour, marker="o", markersize=5, linewidth=1.9, label=label)
        )
        for name, direction in position.directions.items():
            if direction is None:
                continue
            ax, sign = panels[name]
            drawn[name] = drawn[name] or bool(direction.points)
            if _draw_direction(ax, direction, sign, colour, offset, slowest):
                any_stribeck = True
    return position_handles, drawn, any_stribeck


def _style_speed_panels(
    panels: Mapping[str, tuple[Axes, float]],
    drawn: Mapping[str, bool],
    slowest: float,
    fastest: float,
    offset: float | None,
) -> None:
    """The two speed panels' scales, zero line, offset line (when given), labels and titles."""
    for side, (ax, sign) in panels.items():
        style_axes(ax)
        ax.set_xscale("log")
        ax.set_xlim(slowest / 1.4, fastest * 1.4)
        if sign < 0:
            ax.invert_xaxis()
        _speed_ticks(ax.xaxis, sign, slowest / 1.4, fastest * 1.4)
        ax.axhline(0, color="#888888", linewidth=0.8, zorder=1)
        if offset is not None:
            ax.axhline(offset, color="#666666", linewidth=1.0, linestyle="-.", zorder=1)
        ax.set_xlabel("velocity [mm/min], logarithmic")
        ax.set_title(f"{side} direction", fontsize=10, color="#444444", y=1.0)
        if not drawn[side]:
            ax.text(
                0.5,
                0.5,
                "not measured",
                transform=ax.transAxes,
                ha="center",
                va="center",
                color="#888888",
                fontsize=12,
            )


def _style_handles(any_stribeck: bool, offset_shown: bool) -> list[Line2D]:
    """The legend entries that explain the marks: points, fits, the offset line."""
    style_handles = [
        Line2D(
            [], [], color=INK, marker="o", linestyle="none", markersize=4.5, label="median ± std"
        ),
        Line2D(
            [], [], color=INK, linestyle=(0, (5, 3)), linewidth=1.3, label="Coulomb + viscous fit"
        ),
    ]
    if any_stribeck:
        style_handles.append(Line2D([], [], color=INK, linewidth=1.9, label="Stribeck fit"))
    if offset_shown:
        style_handles.append(
            Line2D([], [], color="#666666", linestyle="-.", linewidth=1.0, label="offset")
        )
    return style_handles


def _arrange_stribeck(figure: Figure, negative: Axes, positive: Axes, legend_in: float) -> None:
    """The fixed layout of :func:`plot_stribeck`: two panels side by side between the title
    and the legend, as wide as the friction tick labels at the left leave room for."""
    width_in, height_in = figure.get_size_inches()
    bottom_in = legend_in + points_in(6.0 + X_BAND_PT)
    top_in = points_in(EDGE_PT + LINE_EM * 11 + 2.0 + LINE_EM * 10 + TITLE_PAD_PT)
    right_in, gap_in = 0.25, 0.15  # right: half a tick label ("10 000") may stick out

    def arrange(left_in: float) -> None:
        panel_in = (width_in - left_in - right_in - gap_in) / 2
        for number, ax in enumerate((negative, positive)):
            left = left_in + number * (panel_in + gap_in)
            place_axes(figure, ax, left, bottom_in, panel_in, height_in - bottom_in - top_in)

    arrange(0.8)  # the friction ticks depend on the panel's height only: measure them now
    arrange(points_in(EDGE_PT) + y_band_in(figure, negative.yaxis))


def _mark_bearings(ax: Axes, bearings: BearingLayout, positions: Sequence[float]) -> None:
    """Vertical lines at the travel ends, labelled fixed and loose bearing."""
    low_mm = min(positions, default=0.0)
    high_mm = max(positions, default=1.0)
    if bearings.travel_mm is not None:
        low_mm = min(low_mm, bearings.travel_mm[0])
        high_mm = max(high_mm, bearings.travel_mm[1])
    pad = 0.04 * max(high_mm - low_mm, 1.0)
    ax.set_xlim(low_mm - pad, high_mm + pad)
    suffix = "" if bearings.known else " (assumed)"
    for end, what in ((bearings.fixed_end, "fixed"), (bearings.loose_end, "loose")):
        where = bearings.end_mm(end)
        if where is not None:
            ax.axvline(where, color=INK, linewidth=2.2, alpha=0.55, zorder=1)
            x, coords = where, ax.get_xaxis_transform()
        else:
            x, coords = (0.0 if end == "min" else 1.0), ax.transAxes
        ax.text(
            x,
            1.01,
            f"{what} bearing{suffix}",
            transform=coords,
            ha="left" if end == "min" else "right",
            va="bottom",
            fontsize=9,
            fontweight="bold",
            color=INK,
        )


def _number_positions(ax: Axes, result: AxisResult, averages: Sequence[VelocityProfile]) -> None:
    """Ticks at the measuring positions, ``1: 5 mm``, and the numbers on the average's points.

    The numbers are the ones the tables and the diagnosis use (position index + 1).
    """
    numbered = {p.position_mm: p.position_index + 1 for p in result.positions}
    for profile in averages:
        numbers = profile.position_numbers or [numbered.get(x, 0) for x in profile.positions_mm]
        for number, x, y in zip(numbers, profile.positions_mm, profile.values, strict=False):
            ax.annotate(
                str(number),
                (x, abs(y)),
                xytext=(0, 9),
                textcoords="offset points",
                ha="center",
                va="bottom",
                fontsize=9,
                fontweight="bold",
                color=INK,
                bbox={"boxstyle": "round,pad=0.15", "facecolor": "white", "edgecolor": "none"},
                zorder=5,
            )
    if numbered:
        places = sorted(numbered)
        many = len(places) > 7
        ax.set_xticks(
            places,
            [f"{numbered[x]}" if many else f"{numbered[x]}: {format_mm(x)} mm" for x in places],
        )


@styled
def plot_travel(axis: str, result: AxisResult, bearings: BearingLayout) -> Figure:
    """Friction along the travel: one thin line per velocity, the average bold.

    The travel ends carry the fixed and loose bearing; the measuring positions
    are numbered as in the report's tables (``1: 5 mm``). Values are friction
    magnitudes (the sign of the direction removed).

    Args:
        axis: The axis name, for the title.
        result: The axis' results; needs ``position_dependency``.
        bearings: Where the fixed and loose bearing are.

    Raises:
        ValueError: The results have no position dependency.
    """
    dependency = result.position_dependency
    if dependency is None:
        raise ValueError(f"axis {axis}: the results have no friction along the travel")
    figure = new_figure(4.6, constrained=False)
    ax = figure.add_axes((0.1, 0.1, 0.8, 0.8))
    style_axes(ax)
    per_velocity = [p for p in dependency.profiles if p.velocity_mm_min is not None]
    averages = [p for p in dependency.profiles if p.velocity_mm_min is None]
    speeds = [abs(p.velocity_mm_min) for p in per_velocity if p.velocity_mm_min is not None]
    slowest, fastest = min(speeds, default=0.0), max(speeds, default=1.0)
    norm: Normalize = Normalize(vmin=slowest, vmax=fastest if fastest > slowest else slowest + 1)
    if slowest > 0 and fastest / slowest > 20:
        norm = LogNorm(vmin=slowest, vmax=fastest)
    # One collection for the thin lines and one for their points: as one line
    # each, fifty velocities are fifty artists, each set up and drawn on its own.
    lines = [np.column_stack([p.positions_mm, np.abs(p.values)]) for p in per_velocity]
    if lines:
        colours = _PROFILES(norm([abs(p.velocity_mm_min or 0.0) for p in per_velocity]))
        ax.add_collection(
            LineCollection(lines, colors=colours, linewidths=0.9, alpha=0.85, zorder=2)
        )
        ax.scatter(
            np.concatenate([line[:, 0] for line in lines]),
            np.concatenate([line[:, 1] for line in lines]),
            c=np.repeat(colours, [len(line) for line in lines], axis=0),
            s=2.5**2,  # a marker of 2.5 pt, as markersize=2.5
            linewidths=1.0,
            edgecolors="face",
            alpha=0.85,
            zorder=2,
        )
    for profile in averages:
        ax.plot(
            profile.positions_mm,
            np.abs(profile.values),
            color=PALETTE[1],
            linewidth=2.8,
            marker="o",
            markersize=7,
            zorder=4,
            label=f"average over velocities (spread {profile.spread_percent:.0f} %)",
        )
    positions = [x for p in dependency.profiles for x in p.positions_mm]
    _mark_bearings(ax, bearings, positions)
    _number_positions(ax, result, averages)
    low, high = ax.get_ylim()
    ax.set_ylim(min(0.0, low), high * 1.08)
    bar_ax: Axes | None = None
    if speeds:
        bar_ax = figure.add_axes((0.92, 0.1, 0.02, 0.8))
        bar = figure.colorbar(ScalarMappable(norm=norm, cmap=_PROFILES), cax=bar_ax)
        bar.set_label("velocity of the thin lines [mm/min]", fontsize=8.5)
        bar.ax.tick_params(labelsize=8)
        if isinstance(norm, LogNorm):
            _speed_ticks(bar.ax.yaxis, 1.0, slowest, fastest)
    ax.set_xlabel("measuring position (number: place along the travel)")
    ax.set_ylabel(unit_label(result))
    ax.set_title(
        plain_text(f"Axis {axis}: friction along the travel"),
        loc="left",
        pad=18,
        y=1.0,
    )
    if averages:
        ax.legend(loc="lower right")
    _arrange_travel(figure, ax, bar_ax)
    return figure


def _arrange_travel(figure: Figure, ax: Axes, bar_ax: Axes | None) -> None:
    """The fixed layout of :func:`plot_travel`: room for the title, the bearing labels above
    the plot and the colour bar with its tick labels and label at the right."""
    width_in, height_in = figure.get_size_inches()
    top_in = points_in(EDGE_PT + LINE_EM * 11 + 18.0)  # the title's pad holds the bearing labels
    bottom_in = points_in(EDGE_PT + X_BAND_PT)
    plot_h = height_in - top_in - bottom_in
    right_in, bar_w, bar_gap = 0.2, 0.19, 0.09
    if bar_ax is not None:
        place_axes(figure, bar_ax, width_in - 1.0, bottom_in, bar_w, plot_h)  # ticks follow height
        bar_ticks = tick_label_width_in(figure, bar_ax.yaxis, 8.0)
        right_in = bar_w + bar_gap + bar_ticks + points_in(TICK_PT + LABEL_PAD_PT)
        right_in += points_in(LINE_EM * 8.5 + EDGE_PT)
        place_axes(figure, bar_ax, width_in - right_in + bar_gap, bottom_in, bar_w, plot_h)
    place_axes(figure, ax, 0.8, bottom_in, width_in - 0.8 - right_in, plot_h)
    left_in = points_in(EDGE_PT) + y_band_in(figure, ax.yaxis)
    place_axes(figure, ax, left_in, bottom_in, width_in - left_in - right_in, plot_h)
