"""How the report's figures are drawn, and its comparison and trend figures.

The figures themselves: Stribeck curves and friction along the travel in
:mod:`ncmeasure.report.friction_plots`, raw data with windows in
:mod:`ncmeasure.report.raw_plots`, the comparison and an axis' trend over a
machine's life here.

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
import struct
import threading
import zlib
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, ParamSpec, cast

import numpy as np
from matplotlib import rc_context
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.axis import Axis
from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.ticker import Locator
from numpy.typing import NDArray

from ncmeasure.files import write_whole
from ncmeasure.formats.comparison import Comparison
from ncmeasure.report.colours import CRITICAL, GOOD, GRID, INK, PALETTE, WARNING
from ncmeasure.report.words import format_mm

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

__all__ = [
    "DPI",
    "PALETTE",
    "WIDTH_IN",
    "figure_png",
    "plot_comparison",
    "plot_trend",
    "save_png",
    "shared_renderers",
]

FloatArray = NDArray[np.float64]
_P = ParamSpec("_P")

#: Dots per inch of every PNG; with :data:`WIDTH_IN` a figure is 1056 px wide.
DPI: Final = 110
#: Width of every figure in inches.
WIDTH_IN: Final = 9.6
#: One colour per measuring position (and the raw-data signals); distinct on screen and paper.
WINDOW_FILL: Final = "#9fd3a8"

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


def styled(function: Callable[_P, Figure]) -> Callable[_P, Figure]:
    """Draw inside the report's rc settings, restored afterwards (no lasting global change)."""

    @functools.wraps(function)
    def draw(*args: _P.args, **kwargs: _P.kwargs) -> Figure:
        with rc_context(_RC):
            return function(*args, **kwargs)

    return draw


def plain_text(text: str) -> str:
    """Text from user files as matplotlib draws it literally (no mathtext from ``$``)."""
    return text.replace("$", r"\$")


def new_figure(height_in: float, *, constrained: bool = True) -> Figure:
    """A report-wide figure ``height_in`` high on its own (shareable) Agg canvas."""
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
EDGE_PT: Final = 4.0
TICK_PT: Final = 3.5 + 3.5
LABEL_PAD_PT: Final = 4.0
TITLE_PAD_PT: Final = 6.0
LINE_EM: Final = 1.2
#: Below an axes with tick labels and an axis label.
X_BAND_PT: Final = TICK_PT + LINE_EM * 9.5 + LABEL_PAD_PT + LINE_EM * 9.5


def points_in(value_pt: float) -> float:
    """Points as inches."""
    return value_pt / 72.0


def _renderer(figure: Figure) -> RendererAgg:
    """The renderer of the figure's Agg canvas (:func:`new_figure`), to measure without drawing."""
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


def tick_label_width_in(figure: Figure, axis: Axis, size_pt: float) -> float:
    """Width of the widest major tick label the axis will draw at its current limits."""
    low, high = sorted(axis.get_view_interval())
    slack = 1e-9 * (high - low)
    shown = [x for x in axis.get_major_locator()() if low - slack <= x <= high + slack]
    labels = axis.get_major_formatter().format_ticks(shown)
    return _text_width_in(figure, [label for label in labels if label], size_pt)


def y_band_in(figure: Figure, axis: Axis, size_pt: float = 9.5, label_pt: float = 9.5) -> float:
    """Room left of an axes for its tick labels and its axis label."""
    ticks = tick_label_width_in(figure, axis, size_pt)
    return ticks + points_in(TICK_PT + LABEL_PAD_PT + LINE_EM * label_pt)


def place_axes(
    figure: Figure, ax: Axes, left_in: float, bottom_in: float, width_in: float, height_in: float
) -> None:
    """Put an axes at a rectangle given in inches from the figure's lower left corner."""
    figure_w, figure_h = figure.get_size_inches()
    ax.set_position(
        (left_in / figure_w, bottom_in / figure_h, width_in / figure_w, height_in / figure_h)
    )


def bottom_legend(figure: Figure, handles: Sequence[Artist], ncols: int) -> float:
    """A legend centred at the bottom edge of the figure; returns the height it takes."""
    legend = figure.legend(
        handles=handles,
        loc="lower center",
        bbox_to_anchor=(0.5, points_in(EDGE_PT) / figure.get_size_inches()[1]),
        ncols=ncols,
        borderaxespad=0.0,
    )
    height_px = legend.get_window_extent(_renderer(figure)).height  # entries laid out, not drawn
    return float(height_px) / figure.dpi + points_in(EDGE_PT)


def style_axes(ax: Axes) -> None:
    """The report's look of an axes: a light grid below the data, no top and right spine."""
    ax.grid(True, color=GRID, linewidth=0.6)
    ax.set_axisbelow(True)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)


def figure_png(figure: Figure) -> bytes:
    """The figure as PNG bytes at :data:`DPI`; the figure is emptied (and left at that DPI).

    The PNG is RGB, without the alpha channel matplotlib writes (the background
    is white), its rows unfiltered and deflated at zlib level 3
    (:func:`_png`): the same pixels as matplotlib's PNG, written in a fraction
    of the time. A figure on its own Agg canvas (the ``plot_*`` functions') is
    drawn there and its pixels are taken from the canvas as they are: what
    ``savefig`` does, without copying the image twice. Every axis is drawn
    with only the ticks inside its view (:class:`_InView`).
    """
    with rc_context(_RC):
        _ticks_in_view(figure)
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
    width, height = figure.canvas.get_width_height(physical=True)
    rgba = np.frombuffer(pixels, dtype=np.uint8).reshape(height, width, 4)
    data = _png(rgba)
    _empty(figure)
    return data


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png(rgba: NDArray[np.uint8]) -> bytes:
    """An RGB PNG of the RGBA pixels (the alpha byte left out), at :data:`DPI`.

    Every row unfiltered (filter byte 0), deflated at zlib level 3: choosing a
    filter per row, as PIL does, took most of the time for a few per cent of
    size on these mostly white images.
    """
    height, width = rgba.shape[:2]
    rows = np.zeros((height, 1 + 3 * width), dtype=np.uint8)
    rows[:, 1:].reshape(height, width, 3)[...] = rgba[:, :, :3]
    per_metre = int(DPI / 0.0254 + 0.5)
    return b"".join(
        (
            b"\x89PNG\r\n\x1a\n",
            _png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)),
            _png_chunk(b"pHYs", struct.pack(">IIB", per_metre, per_metre, 1)),
            _png_chunk(b"IDAT", zlib.compress(rows.data, 3)),
            _png_chunk(b"IEND", b""),
        )
    )


class _InView(Locator):
    """A locator's ticks, only those inside the axis' view.

    matplotlib makes a tick (five artists) and a label for every location a
    locator returns, and a linear or logarithmic locator returns one or more
    beyond each end of the view, which are then not drawn. Left out here
    (with a margin: every tick matplotlib draws is kept), they are not made.
    The labels stay the same: a formatter's offset and exponent come from the
    locations inside the view, and its number of decimals from their spread,
    which two neighbouring ticks show as all of them do; with fewer than two
    inside, the formatter sees every location, as before. Everything else
    (the limits of an autoscaled view) is the inner locator's.
    """

    def __init__(self, inner: Locator) -> None:
        self.inner = inner
        self.axis = inner.axis

    def set_axis(self, axis: Any) -> None:
        super().set_axis(axis)
        self.inner.set_axis(axis)

    def __call__(self) -> Any:
        ticks = np.asarray(self.inner(), dtype=np.float64)
        if not isinstance(self.axis, Axis) or len(ticks) == 0:
            return ticks
        scale = self.axis.get_transform()
        low, high = sorted(scale.transform(self.axis.get_view_interval()))
        with np.errstate(invalid="ignore", divide="ignore"):
            where = scale.transform(ticks)
        slack = 1e-6 * (high - low)
        keep = ~((where < low - slack) | (where > high + slack))  # NaN: as matplotlib decides
        return ticks[keep] if np.count_nonzero(keep) >= 2 else ticks

    def tick_values(self, vmin: float, vmax: float) -> Any:
        return self.inner.tick_values(vmin, vmax)

    def nonsingular(self, v0: float, v1: float) -> tuple[float, float]:
        return self.inner.nonsingular(v0, v1)

    def view_limits(self, vmin: float, vmax: float) -> tuple[float, float]:
        return self.inner.view_limits(vmin, vmax)


def _ticks_in_view(figure: Figure) -> None:
    """Wrap every axis' locators in :class:`_InView` (shared axes share them: once)."""
    for ax in figure.axes:
        for axis in (ax.xaxis, ax.yaxis):
            for ticker in (axis.major, axis.minor):
                if ticker.locator is not None and not isinstance(ticker.locator, _InView):
                    ticker.locator = _InView(ticker.locator)


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


_STATUS_COLOURS: Final = {"ok": "#ffffff", "warning": WARNING, "critical": CRITICAL}


@styled
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
    figure = new_figure(height)
    ax = figure.add_subplot()
    style_axes(ax)
    warning = comparison.limits.warning_percent
    critical = comparison.limits.critical_percent
    values = [g.median_deviation_percent for g in comparison.groups]
    reach = max([critical * 1.25, *(abs(v) * 1.1 for v in values)])
    ax.axvspan(-warning, warning, color=GOOD, alpha=0.08, linewidth=0)
    for sign in (-1, 1):
        ax.axvspan(sign * warning, sign * critical, color=WARNING, alpha=0.12, linewidth=0)
        ax.axvspan(sign * critical, sign * reach, color=CRITICAL, alpha=0.10, linewidth=0)
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
            label=plain_text(label),
        )
    ax.set_yticks(
        range(len(keys)),
        [plain_text(f"{a} · {i + 1}: {format_mm(mm)} mm · {d}") for a, i, mm, d in keys],
    )
    ax.set_ylim(len(keys) - 0.5, -0.5)
    ax.set_xlim(-reach, reach)
    ax.set_xlabel("change of friction against the base [%]  (median over the velocities)")
    ax.set_title(
        plain_text(
            f"Comparison with {comparison.base}: warning beyond ±{warning:g} %, "
            f"critical beyond ±{critical:g} %"
        ),
        loc="left",
    )
    if labels:
        figure.legend(loc="outside lower center", ncols=min(4, len(labels)))
    return figure


@styled
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
    figure = new_figure(1.9 * max(1, len(series)) + 0.4)
    panels = figure.subplots(max(1, len(series)), 1, sharex=True, squeeze=False)[:, 0]
    figure.suptitle(f"Axis {plain_text(axis)} over the machine's life", fontsize=11)
    for ax, (title, unit, values) in zip(panels, series, strict=False):
        style_axes(ax)
        known = [(t, v) for t, v in zip(times, values, strict=True) if v is not None]
        if known:
            ax.plot(
                [t for t, _ in known], [v for _, v in known], "o-", color=PALETTE[0], lw=1.4, ms=5
            )
        for index, label in enumerate(labels):
            value = values[index] if index < len(values) else None
            if label and value is not None:
                ax.annotate(
                    plain_text(label),
                    (times[index], value),
                    textcoords="offset points",
                    xytext=(4, 6),
                    fontsize=7.5,
                    color="#555555",
                )
        base = values[baseline_index] if baseline_index is not None else None
        if base is not None and unit != "%" and base != 0:
            for limit, colour in ((critical_percent, CRITICAL), (warning_percent, WARNING)):
                band = abs(base) * limit / 100.0
                ax.axhspan(base - band, base + band, color=colour, alpha=0.07, lw=0)
                for edge in (base - band, base + band):
                    ax.axhline(edge, color=colour, lw=0.8, ls="--")
            ax.axhline(base, color="#555555", lw=0.8, ls=":")
        ax.set_ylabel(plain_text(f"{title}\n[{unit}]"))
    panels[-1].set_xlabel("measured (UTC)")
    figure.autofmt_xdate()
    return figure
