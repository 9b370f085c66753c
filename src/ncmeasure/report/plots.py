"""The trend figure of ``ncmeasure store trend --plot``, drawn with matplotlib as a PNG.

The report's and the dashboard's figures are SVG written directly
(:mod:`ncmeasure.report.friction_svg`, :mod:`~ncmeasure.report.raw_svg`,
:mod:`~ncmeasure.report.comparison_figure`, :mod:`~ncmeasure.report.trend_svg`);
this module is the one that draws with matplotlib, for a PNG to put in a document.

:func:`plot_trend` returns a :class:`matplotlib.figure.Figure` drawn on its own Agg
canvas: no pyplot, no global backend switch, nothing left in a figure registry, so a
program that uses pyplot interactively is unaffected. Fonts and colours are
matplotlib rc settings applied only while the figure is drawn or saved
(``rc_context``) and restored afterwards. :func:`figure_png` and :func:`save_png`
turn a figure into PNG bytes / a file at the fixed :data:`DPI`, without a timestamp
or software tag, so the same results give the same bytes.
"""

from __future__ import annotations

import datetime as dt
import functools
import io
import struct
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, ParamSpec

import numpy as np
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

from ncmeasure.files import write_whole
from ncmeasure.report.colours import CRITICAL, GRID, INK, PALETTE, WARNING

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

__all__ = ["DPI", "PALETTE", "WIDTH_IN", "figure_png", "plot_trend", "save_png"]

_P = ParamSpec("_P")

#: Dots per inch of every PNG; with :data:`WIDTH_IN` a figure is 1056 px wide.
DPI: Final = 110
#: Width of every figure in inches.
WIDTH_IN: Final = 9.6

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


def new_figure(height_in: float) -> Figure:
    """A figure :data:`WIDTH_IN` wide and ``height_in`` high on its own Agg canvas."""
    figure = Figure(figsize=(WIDTH_IN, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


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
    of the time. A figure on its own Agg canvas (:func:`plot_trend`'s) is
    drawn there and its pixels are taken from the canvas as they are: what
    ``savefig`` does, without copying the image twice.
    """
    with rc_context(_RC):
        canvas = figure.canvas
        if type(canvas) is FigureCanvasAgg:
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
