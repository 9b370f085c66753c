"""The report page's view model: frozen dataclasses of plain text that the template lays out.

:mod:`ncmeasure.report.page` (with :mod:`~ncmeasure.report.axis_view` and
:mod:`~ncmeasure.report.comparison_view`) fills them from the results; every
decision is taken there, and the template ``templates/report.html.j2`` only
lays them out. Here also the words and the small cell builders the three share.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from markupsafe import Markup

from ncmeasure.analysis.judgement.summary import Headline
from ncmeasure.formats.results import AxisResult, ModelName, PositionResult
from ncmeasure.report.bearings import BearingLayout
from ncmeasure.report.svg import text
from ncmeasure.report.words import format_mm

__all__ = [
    "LEVEL_TEXT",
    "MODEL_NAMES",
    "AxisSection",
    "AxisView",
    "Cell",
    "ComparisonPart",
    "ComparisonView",
    "Diagnosis",
    "Fact",
    "Figure",
    "Folded",
    "Image",
    "Offset",
    "PageView",
    "Table",
]


@dataclass(frozen=True)
class Figure:
    """A plot for the page: its SVG, the file name beside the report, a caption."""

    svg: str
    filename: str
    alt: str
    caption: str


@dataclass
class AxisSection:
    """What the page shows for one axis."""

    name: str
    anchor: str
    result: AxisResult
    bearings: BearingLayout
    stribeck: Figure | None = None
    travel: Figure | None = None
    raw: Figure | None = None
    raw_note: str | None = None


# --- the view model ------------------------------------------------------------------------


@dataclass(frozen=True)
class Cell:
    """One table cell: text and how it is shown.

    Attributes:
        text: The text.
        note: A second, smaller line (muted).
        strong: Bold text.
        muted: Muted text.
        numeric: Right-aligned figures.
        level: A verdict badge (``ok``, ``check``, ``fault``, ``skipped``).
        status: A comparison status word (``ok``, ``warning``, ``critical``).
        link: An anchor inside the page.
        bar_percent: A likelihood bar before the text, 0–100.
        colspan: Columns the cell spans.
    """

    text: str = ""
    note: str = ""
    strong: bool = False
    muted: bool = False
    numeric: bool = False
    level: str | None = None
    status: str | None = None
    link: str | None = None
    bar_percent: int | None = None
    colspan: int = 1


@dataclass(frozen=True)
class Table:
    """A table: header cells and rows of cells."""

    headers: tuple[Cell, ...]
    rows: tuple[tuple[Cell, ...], ...]
    css: str = ""


@dataclass(frozen=True)
class Fact:
    """One line of a facts list."""

    label: str
    value: str
    code: bool = False
    css: str = ""


@dataclass(frozen=True)
class Folded:
    """A block closed by default (``<details>``): a summary line, then items and/or a table."""

    summary: str
    items: tuple[str, ...] = ()
    table: Table | None = None
    note: str = ""
    css: str = "notes"


@dataclass(frozen=True)
class Image:
    """An embedded plot: its SVG markup, ready for the page."""

    svg: Markup
    caption: str
    filename: str


@dataclass(frozen=True)
class Diagnosis:
    """The pattern along the travel and its likely causes."""

    pattern: str
    text: str
    causes: Table | None


@dataclass(frozen=True)
class Offset:
    """The direction-independent part of an axis."""

    value: str
    explanation: str


@dataclass(frozen=True)
class AxisView:
    """One axis' section."""

    name: str
    anchor: str
    level: str
    level_text: str
    reason: str
    action: str
    coulomb: str
    viscous: str
    travel: str
    facts: tuple[Fact, ...]
    notes: Folded | None
    stribeck: Image | None
    travel_figure: Image | None
    diagnosis: Diagnosis | None
    offset: Offset | None
    models: Table | None
    models_note: str
    nonlinear: Folded | None
    raw: Image | None
    raw_note: str


@dataclass(frozen=True)
class ComparisonPart:
    """One piece of the comparison section, shown in this order: heading, text, table, plot."""

    heading: str = ""
    headline: str = ""
    items: tuple[str, ...] = ()
    table: Table | None = None
    figure: Image | None = None
    note: str = ""
    folded: Folded | None = None


@dataclass(frozen=True)
class ComparisonView:
    """The comparison section."""

    intro: tuple[str, ...]
    facts: tuple[Fact, ...]
    parts: tuple[ComparisonPart, ...]


@dataclass(frozen=True)
class PageView:
    """Everything the template shows, as text."""

    title: str
    subtitle: str
    verdicts: Table
    verdict_note: str
    facts: tuple[Fact, ...]
    comparison: ComparisonView | None
    summary: Table
    summary_note: str
    notes: Folded | None
    axes: tuple[AxisView, ...]
    settings: Folded | None
    footer: str
    headlines: Mapping[str, Headline] = field(default_factory=dict)


# --- words ---------------------------------------------------------------------------------

LEVEL_TEXT: Final = {"ok": "ok", "check": "check", "fault": "fault", "skipped": "not analysed"}
"""The badge text of each verdict level."""

MODEL_NAMES: Final[dict[ModelName | None, str]] = {
    "linear": "Coulomb + viscous",
    "stribeck": "Stribeck",
    "extended": "extended Stribeck",
    None: "none",
}
"""The friction models by the name the report gives them."""


def cell(text: object = "", **kwargs: Any) -> Cell:
    """A cell of ``text`` (any value, as ``str``), shown as ``kwargs`` say."""
    return Cell(text=str(text), **kwargs)


def number_cell(text: object) -> Cell:
    """A right-aligned cell of figures."""
    return Cell(text=str(text), numeric=True)


def make_table(
    headers: Sequence[str | Cell], rows: Iterable[Sequence[Cell]], css: str = ""
) -> Table:
    """A table; a header given as text becomes a plain cell."""
    head = tuple(h if isinstance(h, Cell) else Cell(text=h) for h in headers)
    return Table(head, tuple(tuple(row) for row in rows), css)


def plural(count: int, noun: str) -> str:
    """``1 gap``, ``2 gaps``."""
    return f"{count} {noun if count == 1 else noun + 's'}"


def position_text(position: PositionResult) -> str:
    """``2: 375 mm``, kept on one line."""
    return numbered_position(position.position_index, position.position_mm)


def numbered_position(index: int, position_mm: float) -> str:
    """``2: 375 mm`` from the position index (numbered from 1), kept on one line."""
    return f"{index + 1}:\u00a0{format_mm(position_mm)}\u00a0mm"


_NAMESPACE: Final = ' xmlns="http://www.w3.org/2000/svg"'


def embed_image(figure: Figure) -> Image:
    """A figure to embed in the page: its SVG inline (the page names no address, not even
    SVG's namespace, which HTML implies), named for screen readers by ``alt``.

    The SVG is written by ncmeasure's own figures, every text in it escaped there; it
    is the one piece of markup the page takes as it is.
    """
    if not figure.svg.startswith("<svg "):
        raise ValueError("not an SVG figure of ncmeasure's")
    svg = figure.svg.replace(_NAMESPACE, "", 1)  # HTML puts an <svg> in SVG's namespace
    svg = f'<svg aria-label="{text(figure.alt)}" {svg.removeprefix("<svg ")}'
    return Image(
        svg=Markup(svg),  # written by report.*_svg, every text escaped there
        caption=figure.caption,
        filename=figure.filename,
    )


def share_percent(share: float) -> str:
    """A share as a percentage, one decimal (one significant digit below 0.1 %)."""
    percent = share * 100
    return f"{percent:.1f} %" if percent >= 0.1 or percent == 0 else f"{percent:.1g} %"
