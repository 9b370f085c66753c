"""The report's figures: Stribeck curves, friction along the travel, raw data with windows.

Every ``plot_*`` function returns a :class:`matplotlib.figure.Figure` drawn on
its own Agg canvas: no pyplot, no global backend switch, nothing left in a
figure registry, so a program that uses pyplot interactively is unaffected.
The report's fonts and colours are matplotlib rc settings applied only while a
figure is drawn or saved (``rc_context``) and restored afterwards.
:func:`figure_png` and :func:`save_png` turn a figure into PNG bytes / a file
at the fixed :data:`DPI`, without a timestamp or software tag, so the same
results give the same bytes.

The report's own figures (Stribeck curves, friction along the travel, raw
data) are laid out once, by hand: margins in inches for the titles, axis
labels and legends, which have fixed font sizes, plus the measured width of
the widest tick label. matplotlib's constrained layout finds the same margins
by drawing the figure an extra time, which cost as much as the drawing itself.
No tick label is mathtext (no ``10^4``): the figures need no math fonts.
"""

from __future__ import annotations

import datetime as dt
import functools
import io
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, ParamSpec, cast

import numpy as np
from matplotlib import rc_context
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.axis import Axis
from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import LinearSegmentedColormap, LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle
from matplotlib.ticker import FuncFormatter, LogFormatter, LogLocator
from numpy.typing import NDArray
from PIL import Image

from ncmeasure.files import write_whole
from ncmeasure.formats.comparison import Comparison
from ncmeasure.formats.results import AxisResult, DirectionResult, NonlinearFit, VelocityProfile
from ncmeasure.recording import Recording
from ncmeasure.report.bearings import BearingLayout
from ncmeasure.report.curves import linear_curve, offset_is_significant, stribeck_curve
from ncmeasure.report.words import format_mm

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

__all__ = [
    "DPI",
    "PALETTE",
    "WIDTH_IN",
    "RawTrace",
    "figure_png",
    "plot_comparison",
    "plot_raw_data",
    "plot_stribeck",
    "plot_trace",
    "plot_travel",
    "plot_trend",
    "raw_trace",
    "save_png",
]

FloatArray = NDArray[np.float64]
_P = ParamSpec("_P")

#: Dots per inch of every PNG; with :data:`WIDTH_IN` a figure is 1056 px wide.
DPI: Final = 110
#: Width of every figure in inches.
WIDTH_IN: Final = 9.6
#: One colour per measuring position (and the raw-data signals); distinct on screen and paper.
PALETTE: Final = ("#1f5fa8", "#e07b00", "#2e8b3e", "#c0392b", "#7b4fa3", "#8c6d31", "#d45fa0")
INK: Final = "#222222"
GRID: Final = "#d9d9d9"
WINDOW_FILL: Final = "#9fd3a8"
_PROFILES = LinearSegmentedColormap.from_list("ncmeasure_profiles", ["#b9cfe8", "#0b2f5c"])

_RC: Final[dict[RcKeyType, Any]] = {
    "font.family": "DejaVu Sans",
    "font.size": 9.5,
    "axes.titlesize": 11,
    "axes.labelsize": 9.5,
    "axes.edgecolor": "#555555",
    "axes.labelcolor": INK,
    "xtick.color": "#444444",
    "ytick.color": "#444444",
    "legend.fontsize": 8.5,
    "legend.frameon": False,
}


def _styled(function: Callable[_P, Figure]) -> Callable[_P, Figure]:
    """Draw inside the report's rc settings, restored afterwards (no lasting global change)."""

    @functools.wraps(function)
    def draw(*args: _P.args, **kwargs: _P.kwargs) -> Figure:
        with rc_context(_RC):
            return function(*args, **kwargs)

    return draw


def _plain(text: str) -> str:
    """Text from user files as matplotlib draws it literally (no mathtext from ``$``)."""
    return text.replace("$", r"\$")


def _figure(height_in: float, *, constrained: bool = True) -> Figure:
    figure = Figure(
        figsize=(WIDTH_IN, height_in), dpi=DPI, layout="constrained" if constrained else None
    )
    _Canvas(figure)
    return figure


_SHARED = threading.local()


class _Canvas(FigureCanvasAgg):
    """An Agg canvas that, inside :func:`shared_renderers`, draws on a renderer it shares
    with the canvases of the same size in the same thread.

    matplotlib keeps what it measured of a text (its width, height and descent)
    per renderer; figures drawn one after the other on one renderer measure
    the texts they have in common (tick labels, axis labels, legend entries)
    once. Each draw clears the renderer first, as on a renderer of one's own.
    """

    def get_renderer(self) -> RendererAgg:
        shared: dict[tuple[int, int, float], RendererAgg] | None = getattr(
            _SHARED, "renderers", None
        )
        if shared is None:
            return super().get_renderer()  # type: ignore[no-untyped-call,no-any-return]
        width, height = self.get_width_height(physical=True)
        key = (width, height, self.figure.dpi)
        renderer = shared.get(key)
        if renderer is None:
            renderer = shared[key] = RendererAgg(  # type: ignore[no-untyped-call]
                width, height, self.figure.dpi
            )
        self.renderer = renderer
        self._lastKey = key
        return renderer


@contextmanager
def shared_renderers() -> Iterator[None]:
    """Let the report's figures drawn in this thread share their renderers (:class:`_Canvas`).

    A figure is drawn and its pixels taken before the next one is drawn
    (:func:`figure_png`), so that no figure's pixels are needed after another
    used its renderer. The renderers are dropped on leaving.
    """
    outer = getattr(_SHARED, "renderers", None)
    _SHARED.renderers = {} if outer is None else outer
    try:
        yield
    finally:
        _SHARED.renderers = outer


# --- fixed layout ------------------------------------------------------------------------
# Distances in points (1/72 in), from the rc settings in _RC and matplotlib's defaults:
# tick length 3.5 + pad 3.5, label pad 4, title pad 6; a line of text is 1.2 em high.
_EDGE_PT: Final = 4.0
_TICK_PT: Final = 3.5 + 3.5
_LABEL_PAD_PT: Final = 4.0
_TITLE_PAD_PT: Final = 6.0
_LINE_EM: Final = 1.2
#: Below an axes with tick labels and an axis label.
_X_BAND_PT: Final = _TICK_PT + _LINE_EM * 9.5 + _LABEL_PAD_PT + _LINE_EM * 9.5


def _points(value_pt: float) -> float:
    """Points as inches."""
    return value_pt / 72.0


def _renderer(figure: Figure) -> RendererAgg:
    """The renderer of the figure's Agg canvas (:func:`_figure`), to measure without drawing."""
    canvas = cast(FigureCanvasAgg, figure.canvas)
    return canvas.get_renderer()  # type: ignore[no-untyped-call,no-any-return]


def _text_width_in(figure: Figure, texts: Sequence[str], size_pt: float) -> float:
    """Width of the widest of the texts in the report's font, in inches (no drawing)."""
    if not texts:
        return 0.0
    renderer, font = _renderer(figure), FontProperties(size=size_pt)
    measure = renderer.get_text_width_height_descent
    widest = max(measure(t, font, ismath=False)[0] for t in texts)  # type: ignore[no-untyped-call]
    return float(widest) / figure.dpi


def _tick_label_width_in(figure: Figure, axis: Axis, size_pt: float) -> float:
    """Width of the widest major tick label the axis will draw at its current limits."""
    low, high = sorted(axis.get_view_interval())
    slack = 1e-9 * (high - low)
    shown = [x for x in axis.get_major_locator()() if low - slack <= x <= high + slack]
    labels = axis.get_major_formatter().format_ticks(shown)
    return _text_width_in(figure, [label for label in labels if label], size_pt)


def _y_band_in(figure: Figure, axis: Axis, size_pt: float = 9.5, label_pt: float = 9.5) -> float:
    """Room left of an axes for its tick labels and its axis label."""
    ticks = _tick_label_width_in(figure, axis, size_pt)
    return ticks + _points(_TICK_PT + _LABEL_PAD_PT + _LINE_EM * label_pt)


def _place(
    figure: Figure, ax: Axes, left_in: float, bottom_in: float, width_in: float, height_in: float
) -> None:
    """Put an axes at a rectangle given in inches from the figure's lower left corner."""
    figure_w, figure_h = figure.get_size_inches()
    ax.set_position(
        (left_in / figure_w, bottom_in / figure_h, width_in / figure_w, height_in / figure_h)
    )


def _bottom_legend(figure: Figure, handles: Sequence[Artist], ncols: int) -> float:
    """A legend centred at the bottom edge of the figure; returns the height it takes."""
    legend = figure.legend(
        handles=handles,
        loc="lower center",
        bbox_to_anchor=(0.5, _points(_EDGE_PT) / figure.get_size_inches()[1]),
        ncols=ncols,
        borderaxespad=0.0,
    )
    height_px = legend.get_window_extent(_renderer(figure)).height  # entries laid out, not drawn
    return float(height_px) / figure.dpi + _points(_EDGE_PT)


def _style(ax: Axes) -> None:
    ax.grid(True, color=GRID, linewidth=0.6)
    ax.set_axisbelow(True)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)


def figure_png(figure: Figure) -> bytes:
    """The figure as PNG bytes at :data:`DPI`; the figure is emptied (and left at that DPI).

    The PNG is RGB, without the alpha channel matplotlib writes (the background
    is white), at zlib level 3: smaller than matplotlib's PNG and written in
    half the time. A figure on its own Agg canvas (the ``plot_*`` functions')
    is drawn there and its pixels are taken from the canvas as they are, the
    alpha byte skipped: what ``savefig`` does, without copying the image twice.
    """
    with rc_context(_RC):
        if type(figure.canvas) in (FigureCanvasAgg, _Canvas):
            canvas = cast(FigureCanvasAgg, figure.canvas)
            figure.set_dpi(DPI)
            figure.patch.set_facecolor("white")
            canvas.draw()  # type: ignore[no-untyped-call]
            pixels: Any = canvas.buffer_rgba()  # type: ignore[no-untyped-call]
        else:
            raw = io.BytesIO()
            figure.savefig(raw, format="rgba", dpi=DPI, facecolor="white")
            figure.set_dpi(DPI)  # the size in pixels as matplotlib rounds it for the canvas
            pixels = raw.getbuffer()
    size = figure.canvas.get_width_height(physical=True)
    buffer = io.BytesIO()
    Image.frombytes("RGB", size, pixels, "raw", "RGBX").save(
        buffer, format="png", compress_level=3, dpi=(DPI, DPI)
    )
    _empty(figure)
    return buffer.getvalue()


def _empty(figure: Figure) -> None:
    """Remove everything from the figure.

    The axes are taken out before ``clear``, which would otherwise reset each
    of them first (new ticks, spines, ...) only to drop them.
    """
    for ax in list(figure.axes):
        figure.delaxes(ax)
    figure.clear()


def save_png(figure: Figure, path: str | Path) -> bytes:
    """Write the figure as a PNG file (see :func:`figure_png`) and return its bytes.

    Raises:
        OutputError: The file cannot be written.
    """
    data = figure_png(figure)
    write_whole(path, data)
    return data


def _unit_label(result: AxisResult) -> str:
    if result.quantity == "torque_nm":
        return "friction torque [Nm]"
    return "friction as motor current [A]"


def _drawn_model(direction: DirectionResult) -> NonlinearFit | None:
    """The nonlinear fit to draw: the extended model where identifiable, else Stribeck."""
    for fit in (direction.extended, direction.stribeck):
        if fit is not None and fit.identifiable:
            return fit
    return None


def _speed_text(value: float, sign: float) -> str:
    """A speed as a tick label: ``10 000``, ``0.5``, with ``−`` on the negative side."""
    if value <= 0:
        return ""
    text = f"{value:,.0f}".replace(",", " ") if value >= 1 else f"{value:g}"
    return f"−{text}" if sign < 0 else text


def _speed_tick(sign: float) -> FuncFormatter:
    return FuncFormatter(lambda value, _position: _speed_text(value, sign))


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
    a decade, some over less); the text is :func:`_speed_text`, not the
    mathtext ``2×10^2`` of matplotlib's default, which needs math fonts.
    """

    def __init__(self, sign: float) -> None:
        super().__init__(labelOnlyBase=False, minor_thresholds=(1, 0.4))
        self._sign = sign

    def __call__(self, x: float, pos: int | None = None) -> str:
        return _speed_text(x, self._sign) if super().__call__(x, pos) else ""


def _error_bars(ax: Axes, x: FloatArray, y: FloatArray, error: FloatArray, colour: str) -> None:
    """Points with ± ``error`` bars and caps: the artists ``ax.errorbar`` makes, fewer of them.

    ``errorbar(fmt="o", markersize=4.5, elinewidth=1.0, capsize=2.5, zorder=3)``
    draws the bars (one collection), then the lower and the upper caps (two
    lines of markers) at zorder 3 and the points above them at 3.1. Here both
    caps are one line of markers, lower ones first, so the same marks are
    drawn in the same order, without errorbar's per-call work.
    """
    low, high = y - error, y + error
    ax.add_line(
        Line2D(x, y, color=colour, marker="o", linestyle="none", markersize=4.5, zorder=3.1)
    )
    ax.vlines(x, low, high, colors=colour, linewidth=1.0, zorder=3)
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
        low, high = fit.velocity_range_mm_min
        low, high = max(low, slowest), max(high, low)
        inside = np.geomspace(low, high, 80)
        ax.plot(
            inside,
            linear_curve(fit, sign * inside, sign, points, offset),
            linestyle=(0, (5, 3)),
            color=colour,
            linewidth=1.3,
            zorder=2.5,
        )
        if low > slowest * 1.01:  # extrapolated below the fitted speeds: lighter
            below = np.geomspace(slowest, low, 40)
            ax.plot(
                below,
                linear_curve(fit, sign * below, sign, points, offset),
                linestyle=(0, (1, 2)),
                color=colour,
                linewidth=1.1,
                alpha=0.7,
                zorder=2,
            )
    model = _drawn_model(direction)
    if model is None or not points:
        return False
    grid = np.geomspace(abs(points[0].velocity_mm_min), abs(points[-1].velocity_mm_min), 160)
    curve = stribeck_curve(model, sign * grid, sign, points, offset)
    if curve is None:
        return False
    ax.plot(grid, curve, color=colour, linewidth=1.9, zorder=2)
    return True


@_styled
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
    figure = _figure(5.4, constrained=False)
    negative = figure.add_axes((0.1, 0.2, 0.4, 0.7))
    positive = figure.add_axes((0.55, 0.2, 0.4, 0.7), sharey=negative)
    offset = result.offset.value if result.offset is not None else None
    significant = offset_is_significant(result.offset)
    speeds = [
        abs(p.velocity_mm_min)
        for pos in result.positions
        for d in pos.directions.values()
        if d is not None
        for p in d.points
        if p.velocity_mm_min != 0
    ]
    slowest = min(speeds) if speeds else 10.0
    fastest = max(speeds) if speeds else 10000.0
    panels = {"negative": (negative, -1.0), "positive": (positive, 1.0)}
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
    for side, (ax, sign) in panels.items():
        _style(ax)
        ax.set_xscale("log")
        ax.set_xlim(slowest / 1.4, fastest * 1.4)
        if sign < 0:
            ax.invert_xaxis()
        _speed_ticks(ax.xaxis, sign, slowest / 1.4, fastest * 1.4)
        ax.axhline(0, color="#888888", linewidth=0.8, zorder=1)
        if offset is not None and significant:
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
    positive.tick_params(labelleft=False)
    positive.spines["left"].set_color("#aaaaaa")
    negative.set_ylabel(_unit_label(result))
    low, high = negative.get_ylim()
    negative.set_ylim(min(low, 0.0), max(high, 0.0))
    figure.suptitle(
        _plain(f"Axis {axis}: friction over velocity (Stribeck curves)"),
        x=0.01,
        y=1.0 - _points(_EDGE_PT) / figure.get_size_inches()[1],
        ha="left",
        va="top",
        fontsize=11,
    )
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
    if offset is not None and significant:
        style_handles.append(
            Line2D([], [], color="#666666", linestyle="-.", linewidth=1.0, label="offset")
        )
    handles = [*position_handles, *style_handles]
    legend_in = _bottom_legend(figure, handles, min(4, len(handles)))
    width_in, height_in = figure.get_size_inches()
    bottom_in = legend_in + _points(6.0 + _X_BAND_PT)
    top_in = _points(_EDGE_PT + _LINE_EM * 11 + 2.0 + _LINE_EM * 10 + _TITLE_PAD_PT)
    right_in, gap_in = 0.25, 0.15  # right: half a tick label ("10 000") may stick out

    def arrange(left_in: float) -> None:
        panel_in = (width_in - left_in - right_in - gap_in) / 2
        for number, ax in enumerate((negative, positive)):
            left = left_in + number * (panel_in + gap_in)
            _place(figure, ax, left, bottom_in, panel_in, height_in - bottom_in - top_in)

    arrange(0.8)  # the friction ticks depend on the panel's height only: measure them now
    arrange(_points(_EDGE_PT) + _y_band_in(figure, negative.yaxis))
    return figure


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


@_styled
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
    figure = _figure(4.6, constrained=False)
    ax = figure.add_axes((0.1, 0.1, 0.8, 0.8))
    _style(ax)
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
    ax.set_ylabel(_unit_label(result))
    ax.set_title(
        _plain(f"Axis {axis}: friction along the travel"),
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
    top_in = _points(_EDGE_PT + _LINE_EM * 11 + 18.0)  # the title's pad holds the bearing labels
    bottom_in = _points(_EDGE_PT + _X_BAND_PT)
    plot_h = height_in - top_in - bottom_in
    right_in, bar_w, bar_gap = 0.2, 0.19, 0.09
    if bar_ax is not None:
        _place(figure, bar_ax, width_in - 1.0, bottom_in, bar_w, plot_h)  # ticks follow height
        bar_ticks = _tick_label_width_in(figure, bar_ax.yaxis, 8.0)
        right_in = bar_w + bar_gap + bar_ticks + _points(_TICK_PT + _LABEL_PAD_PT)
        right_in += _points(_LINE_EM * 8.5 + _EDGE_PT)
        _place(figure, bar_ax, width_in - right_in + bar_gap, bottom_in, bar_w, plot_h)
    _place(figure, ax, 0.8, bottom_in, width_in - 0.8 - right_in, plot_h)
    left_in = _points(_EDGE_PT) + _y_band_in(figure, ax.yaxis)
    _place(figure, ax, left_in, bottom_in, width_in - left_in - right_in, plot_h)


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


@_styled
def plot_trace(trace: RawTrace) -> Figure:
    """:func:`plot_raw_data` from its data (:func:`raw_trace`, or read chunk by chunk)."""
    axis = trace.axis
    cuts = trace.windows
    figure = _figure(6.2, constrained=False)
    overview = figure.add_axes((0.1, 0.8, 0.8, 0.1))
    top = figure.add_axes((0.1, 0.45, 0.8, 0.3))
    bottom = figure.add_axes((0.1, 0.1, 0.8, 0.3), sharex=top)
    for ax in (overview, top, bottom):
        _style(ax)
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
        _plain(
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
    top.set_title(_plain(f"stretch {start:.1f} – {end:.1f} s"), loc="left", fontsize=9.5, y=1.0)

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
    _arrange_raw(figure, (overview, top, bottom), _bottom_legend(figure, handles, len(handles)))
    return figure


def _arrange_raw(figure: Figure, panels: tuple[Axes, Axes, Axes], legend_in: float) -> None:
    """The fixed layout of :func:`plot_raw_data`: three panels 1 : 2 : 2 high, room for the
    titles, the overview's time ticks, the bottom panel's axis labels and the legend."""
    overview, top, bottom = panels
    width_in, height_in = figure.get_size_inches()
    top_in = _points(_EDGE_PT + _LINE_EM * 11 + _TITLE_PAD_PT)
    # between overview and stretch: the overview's time ticks, then the stretch's title
    first_gap_in = _points(_TICK_PT + _LINE_EM * 9.5 + 4.0 + _LINE_EM * 9.5 + _TITLE_PAD_PT)
    second_gap_in = _points(9.0)
    bottom_in = (
        legend_in + _points(6.0 + _X_BAND_PT) if legend_in else _points(_EDGE_PT + _X_BAND_PT)
    )
    unit_in = (height_in - top_in - first_gap_in - second_gap_in - bottom_in) / 5
    right_in = 0.2

    def arrange(left_in: float) -> None:
        plot_w = width_in - left_in - right_in
        _place(figure, bottom, left_in, bottom_in, plot_w, 2 * unit_in)
        _place(figure, top, left_in, bottom_in + 2 * unit_in + second_gap_in, plot_w, 2 * unit_in)
        _place(figure, overview, left_in, height_in - top_in - unit_in, plot_w, unit_in)

    arrange(1.0)  # the value ticks depend on the panels' heights only: measure them now
    left_in = max(
        _y_band_in(figure, overview.yaxis, label_pt=8.5),
        _y_band_in(figure, top.yaxis),
        _y_band_in(figure, bottom.yaxis),
    )
    arrange(_points(_EDGE_PT) + left_in)


_STATUS_COLOURS: Final = {"ok": "#ffffff", "warning": "#e07b00", "critical": "#c0392b"}


@_styled
def plot_comparison(comparison: Comparison) -> Figure:
    """Change of friction per axis, position and direction against the base run.

    One row per (axis, position, direction), one marker per compared run: the
    median over the velocities of (run − base)/base in %. The bands mark the
    warning and critical limits.

    Args:
        comparison: The comparison.

    Returns:
        A new figure on an Agg canvas.
    """
    keys = sorted(
        {(g.axis, g.position_index, g.position_mm, g.direction) for g in comparison.groups},
        key=lambda k: (k[0], k[1], k[3] != "positive"),
    )
    labels = list(dict.fromkeys(g.label for g in comparison.groups))
    height = min(12.0, 1.6 + 0.28 * max(len(keys), 1))
    figure = _figure(height)
    ax = figure.add_subplot()
    _style(ax)
    warning = comparison.limits.warning_percent
    critical = comparison.limits.critical_percent
    values = [g.median_deviation_percent for g in comparison.groups]
    reach = max([critical * 1.25, *(abs(v) * 1.1 for v in values)])
    ax.axvspan(-warning, warning, color="#2e8b3e", alpha=0.08, linewidth=0)
    for sign in (-1, 1):
        ax.axvspan(sign * warning, sign * critical, color="#e07b00", alpha=0.12, linewidth=0)
        ax.axvspan(sign * critical, sign * reach, color="#c0392b", alpha=0.10, linewidth=0)
    ax.axvline(0, color="#555555", linewidth=0.9)
    rows = {key: index for index, key in enumerate(keys)}
    for number, label in enumerate(labels):
        groups = [g for g in comparison.groups if g.label == label]
        ax.scatter(
            [g.median_deviation_percent for g in groups],
            [rows[(g.axis, g.position_index, g.position_mm, g.direction)] for g in groups],
            color=PALETTE[number % len(PALETTE)],
            edgecolors=[_STATUS_COLOURS[g.status] for g in groups],
            linewidths=1.6,
            s=42,
            zorder=3,
            label=_plain(label),
        )
    ax.set_yticks(
        range(len(keys)),
        [_plain(f"{a} · {i + 1}: {format_mm(mm)} mm · {d}") for a, i, mm, d in keys],
    )
    ax.set_ylim(len(keys) - 0.5, -0.5)
    ax.set_xlim(-reach, reach)
    ax.set_xlabel("change of friction against the base [%]  (median over the velocities)")
    ax.set_title(
        _plain(
            f"Comparison with {comparison.base}: warning beyond ±{warning:g} %, "
            f"critical beyond ±{critical:g} %"
        ),
        loc="left",
    )
    if labels:
        figure.legend(loc="outside lower center", ncols=min(4, len(labels)))
    return figure


@_styled
def plot_trend(
    axis: str,
    times: Sequence[dt.datetime],
    series: Sequence[tuple[str, str, Sequence[float | None]]],
    *,
    baseline_index: int | None,
    warning_percent: float,
    critical_percent: float,
    labels: Sequence[str | None] = (),
) -> Figure:
    """An axis' characteristics over a machine's life, one panel each.

    Args:
        axis: The axis name (title).
        times: When each measurement was taken.
        series: Per panel ``(title, unit, values)``; a value may be None (not determined).
            A panel whose unit is ``%`` is drawn without limits (a spread).
        baseline_index: The baseline measurement: the limits are drawn as bands
            around its value (± warning, ± critical percent).
        warning_percent: Warning limit in percent of the baseline.
        critical_percent: Critical limit in percent of the baseline.
        labels: A label per measurement (``delivery``, ``service``), written at its point.

    Returns:
        A new figure on an Agg canvas.
    """
    figure = _figure(1.9 * max(1, len(series)) + 0.4)
    panels = figure.subplots(max(1, len(series)), 1, sharex=True, squeeze=False)[:, 0]
    figure.suptitle(f"Axis {_plain(axis)} over the machine's life", fontsize=11)
    for ax, (title, unit, values) in zip(panels, series, strict=False):
        _style(ax)
        known = [(t, v) for t, v in zip(times, values, strict=True) if v is not None]
        if known:
            ax.plot(
                [t for t, _ in known], [v for _, v in known], "o-", color=PALETTE[0], lw=1.4, ms=5
            )
        for index, label in enumerate(labels):
            value = values[index] if index < len(values) else None
            if label and value is not None:
                ax.annotate(
                    _plain(label),
                    (times[index], value),
                    textcoords="offset points",
                    xytext=(4, 6),
                    fontsize=7.5,
                    color="#555555",
                )
        base = values[baseline_index] if baseline_index is not None else None
        if base is not None and unit != "%" and base != 0:
            for limit, colour in ((critical_percent, "#c0392b"), (warning_percent, "#e07b00")):
                band = abs(base) * limit / 100.0
                ax.axhspan(base - band, base + band, color=colour, alpha=0.07, lw=0)
                for edge in (base - band, base + band):
                    ax.axhline(edge, color=colour, lw=0.8, ls="--")
            ax.axhline(base, color="#555555", lw=0.8, ls=":")
        ax.set_ylabel(_plain(f"{title}\n[{unit}]"))
    panels[-1].set_xlabel("measured (UTC)")
    figure.autofmt_xdate()
    return figure
