"""The report as one HTML page: a Jinja template over a frozen view model.

:func:`render_page` turns the results (and a comparison) into a
:class:`PageView` of plain text, numbers formatted and every decision
(which verdict, which note, which cell says what) taken here in Python; the
template ``templates/report.html.j2`` only lays it out. Jinja's autoescape
escapes every value, so names, evidence and warnings from files cannot
inject markup; the only markup is the template's. The CSS is inline, the
images are data URIs, there is no script: the file opens offline and prints
as is.

Reading order, for the person at the machine: the verdict per axis first
(with a comparison, combined with it), the recording, the comparison, the
numbers per axis, then each axis in detail. Notes (recording problems,
analysis warnings, settings) are folded away in ``<details>`` with their
count. Measuring positions are numbered as everywhere else: ``2: 375 mm``,
the position index + 1.
"""

from __future__ import annotations

import base64
import functools
import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import jinja2
from jinja2.sandbox import SandboxedEnvironment
from pydantic import BaseModel

from ncmeasure._version import __version__
from ncmeasure.analysis.judgement.summary import (
    AxisComparison,
    Headline,
    axis_comparison,
    axis_headline,
)
from ncmeasure.analysis.judgement.verdict import percent_text
from ncmeasure.analysis.reading import recording_gaps
from ncmeasure.formats.comparison import Comparison, GroupDeviation
from ncmeasure.formats.results import (
    AxisResult,
    DirectionResult,
    LinearFit,
    ModelName,
    NonlinearFit,
    PositionResult,
    Results,
)
from ncmeasure.recording import Recording, RecordingHead
from ncmeasure.report.bearings import BearingLayout
from ncmeasure.report.curves import offset_is_significant
from ncmeasure.report.words import (
    CAUSE_CHECKS,
    CAUSE_TITLES,
    SIGNATURE_SHORT,
    SIGNATURE_TEXT,
    format_date,
    format_mm,
    format_number,
    format_with_error,
)

__all__ = ["AxisSection", "Figure", "PageView", "page_view", "render_page"]

GAP_SHARE_HIGHLIGHT = 0.05
"""Lost samples beyond this share are highlighted in the header (a measurement worth
repeating, though the verdict judges only whether the kept windows cover it)."""


@dataclass(frozen=True)
class Figure:
    """A plot for the page: PNG bytes, the file name beside the report, a caption."""

    png: bytes
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
    """An embedded plot."""

    src: str
    alt: str
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

_SKIPPED_ACTION: Final = (
    "Check the axis' channels and its part of the program, then measure it again."
)


def _c(text: object = "", **kwargs: Any) -> Cell:
    return Cell(text=str(text), **kwargs)


def _n(text: object) -> Cell:
    return Cell(text=str(text), numeric=True)


def _table(headers: Sequence[str | Cell], rows: Iterable[Sequence[Cell]], css: str = "") -> Table:
    head = tuple(h if isinstance(h, Cell) else Cell(text=h) for h in headers)
    return Table(head, tuple(tuple(row) for row in rows), css)


def _plural(count: int, noun: str) -> str:
    return f"{count} {noun if count == 1 else noun + 's'}"


def _where(position: PositionResult) -> str:
    """``2: 375 mm``, kept on one line."""
    return _numbered(position.position_index, position.position_mm)


def _numbered(index: int, position_mm: float) -> str:
    return f"{index + 1}:\u00a0{format_mm(position_mm)}\u00a0mm"


def _image(figure: Figure) -> Image:
    data = base64.b64encode(figure.png).decode("ascii")
    return Image(
        src=f"data:image/png;base64,{data}",
        alt=figure.alt,
        caption=figure.caption,
        filename=figure.filename,
    )


def _percent(share: float) -> str:
    percent = share * 100
    return f"{percent:.1f} %" if percent >= 0.1 or percent == 0 else f"{percent:.1g} %"


# --- the top: verdict and recording --------------------------------------------------------


def _verdict_rows(
    sections: Sequence[AxisSection],
    headlines: Mapping[str, Headline],
    skipped: Mapping[str, str],
    comparison: BaseModel | None,
) -> tuple[Table, str]:
    base = comparison.base if isinstance(comparison, Comparison) else None
    compared = base is not None
    rows = []
    for section in sections:
        headline = headlines[section.name]
        verdict = headline.verdict
        row = [
            _c(section.name, link=section.anchor),
            _c(LEVEL_TEXT[verdict.level], level=verdict.level),
            _c(verdict.reason, note=f"What to do: {verdict.action}"),
            _c(headline.coulomb_text, numeric=True),
        ]
        if compared:
            row.append(_against_cell(headline.against))
        rows.append(row)
    for name, reason in skipped.items():
        row = [
            _c(name, strong=True),
            _c(LEVEL_TEXT["skipped"], level="skipped"),
            _c(reason, note=f"What to do: {_SKIPPED_ACTION}"),
            _c("–", numeric=True),
        ]
        if compared:
            row.append(_c("not analysed", muted=True))
        rows.append(row)
    headers = ["Axis", "Verdict", "Why, and what to do", "Coulomb friction"]
    if compared:
        headers.append(f"Against {base}")
    note = (
        "ok: no assembly fault shows. check: worth a look, or the measurement cannot show "
        "the assembly fully. fault: an assembly fault; find it before the machine is shipped "
        "or used. Coulomb friction: the mean over the measuring positions and both "
        "directions, the lowest and highest position in brackets."
    )
    if compared:
        note += (
            " With a comparison the verdict is the worse of the axis' own and its change "
            "against the reference."
        )
    return _table(headers, rows, css="verdicts"), note


def _against_cell(against: AxisComparison | None) -> Cell:
    if against is None:
        return _c("not compared", muted=True)
    return _c(against.status, status=against.status, note=against.change)


def _recording_facts(results: Results, recording: Recording | RecordingHead | None) -> list[Fact]:
    """Samples, duration, how the recording ended and what it lost: never hidden."""
    info = results.recording
    samples, duration_s, status = info.samples, info.duration_s, info.status
    gaps, lost, share, events = info.gaps, info.gap_samples, info.gap_share, info.gap_events
    if samples is None and isinstance(recording, Recording):
        samples = len(recording)
        duration_s = float(recording.time_s[-1] - recording.time_s[0]) if samples else 0.0
        status = recording.meta.status
        gaps, lost, events = recording_gaps(recording)
        total = samples + lost
        share = lost / total if total else 0.0
    facts = []
    if samples is not None:
        text = f"{samples}"
        if duration_s is not None:
            text += f" over {duration_s:.0f} s"
        facts.append(Fact("Samples", text))
    if samples is not None or status is not None:
        if gaps:
            loss = (
                f"{_plural(gaps, 'gap')}: {_plural(lost, 'sample')}, {_percent(share)} lost"
                if lost
                else _plural(gaps, "gap")
            )
        else:
            loss = "no sample lost"
        text = f"{status or 'status unknown'}, {loss}"
        if events and events != gaps:
            text += f" (the link reported {_plural(events, 'gap event')})"
        facts.append(Fact("Status", text, css="lost-many" if share > GAP_SHARE_HIGHLIGHT else ""))
    return facts


def _facts(results: Results, recording: Recording | RecordingHead | None) -> tuple[Fact, ...]:
    info = results.recording
    machine = info.machine or (recording.meta.machine if recording is not None else None)
    facts = [
        Fact("Machine", machine or "not named"),
        Fact("Recording", info.directory),
        Fact("Recorded", format_date(info.start_utc)),
        Fact("Analysed", format_date(results.created_utc)),
        Fact("Source", info.source or "–"),
        *_recording_facts(results, recording),
    ]
    if info.config_hash:
        facts.append(Fact("Program (config hash)", info.config_hash, code=True))
    facts.append(
        Fact("ncmeasure", f"{results.ncmeasure_version} (results format {results.format_version})")
    )
    return tuple(facts)


# --- summary -------------------------------------------------------------------------------


def _models_count(result: AxisResult) -> str:
    counts: dict[ModelName | None, int] = {}
    for position in result.positions:
        for found in position.directions.values():
            if found is not None:
                counts[found.model] = counts.get(found.model, 0) + 1
    order: tuple[ModelName | None, ...] = ("linear", "stribeck", "extended", None)
    return ", ".join(f"{MODEL_NAMES[m]} {counts[m]}" for m in order if counts.get(m)) or "–"


def _top_cause(result: AxisResult) -> str:
    dependency = result.position_dependency
    if dependency is None or not dependency.causes:
        return "–"
    cause = dependency.causes[0]
    return f"{CAUSE_TITLES.get(cause.cause, cause.cause)} ({cause.score * 100:.0f} %)"


def _travel_short(result: AxisResult) -> str:
    dependency = result.position_dependency
    if dependency is None:
        return "–"
    short = SIGNATURE_SHORT.get(dependency.signature, dependency.signature)
    return f"{dependency.spread_percent:.0f} % spread, {short}"


def _offset_text(result: AxisResult) -> str:
    if result.offset is None:
        return "–"
    if not offset_is_significant(result.offset):
        return "none"
    return f"{format_with_error(result.offset.value, result.offset.stderr)} {result.unit}"


def _summary(
    sections: Sequence[AxisSection], headlines: Mapping[str, Headline]
) -> tuple[Table, str]:
    rows = [
        [
            _c(section.name, link=section.anchor),
            _c(headlines[section.name].coulomb_text),
            _c(headlines[section.name].viscous_text),
            _c(_travel_short(section.result)),
            _c(_top_cause(section.result)),
            _c(_offset_text(section.result)),
            _c(_models_count(section.result)),
        ]
        for section in sections
    ]
    table = _table(
        [
            "Axis",
            "Coulomb friction (mean, range over positions)",
            "Viscous friction",
            "Along the travel",
            "Most likely cause",
            "Offset",
            "Curves described by",
        ],
        rows,
    )
    note = (
        "Coulomb friction is the velocity-independent part, viscous friction the rise per "
        "m/min of feed, both from the straight line fitted above the Stribeck region with the "
        "offset taken out. Spread along the travel is (max − min) / mean of the friction "
        "averaged over all velocities. The last column counts the curves (position × "
        "direction) each friction model describes."
    )
    return table, note


def _notes(
    sections: Sequence[AxisSection], recording: Recording | RecordingHead | None
) -> Folded | None:
    """Recording problems, then the warnings of the analysis: each shared one once."""
    warnings: list[str] = [f"Recording: {p}" for p in recording.problems] if recording else []
    shared = set.intersection(*(set(s.result.warnings) for s in sections)) if sections else set()
    if len(sections) > 1:
        ordered = [w for w in sections[0].result.warnings if w in shared]
        warnings.extend(f"All axes: {w}" for w in ordered)
    else:
        shared = set()
    for section in sections:
        warnings.extend(
            f"Axis {section.name}: {w}" for w in section.result.warnings if w not in shared
        )
    if not warnings:
        return None
    return Folded(
        summary=f"Notes of the recording and the analysis ({len(warnings)})",
        items=tuple(warnings),
    )


# --- one axis ------------------------------------------------------------------------------


def _axis_notes(section: AxisSection) -> Folded | None:
    result = section.result
    # The warnings already say when the data is coarse and which values were left out.
    items = list(result.warnings)
    if result.velocity_quantum_mm_min > 0:
        items.append(
            f"the velocity is reported in steps of {format_number(result.velocity_quantum_mm_min)}"
            " mm/min"
        )
    if result.current_quantum_a > 0:
        items.append(
            f"the current is reported in steps of {format_number(result.current_quantum_a)} A"
        )
    if not items:
        return None
    return Folded(summary=f"Notes on axis {section.name} ({len(items)})", items=tuple(items))


def _diagnosis(section: AxisSection) -> Diagnosis | None:
    dependency = section.result.position_dependency
    if dependency is None:
        return None
    trend = dependency.trend_per_100mm
    text = (
        f"Friction varies by {percent_text(dependency.spread_percent)} along the travel "
        f"(max − min relative to the mean); the trend is {trend:+.1f} % per 100 mm "
        "(positive: rising towards the max end). "
        f"Bearings: {section.bearings.describe()}."
    )
    causes = None
    if dependency.causes:
        causes = _table(
            ["#", "Cause and what to check", _c("Likelihood", numeric=True), "Evidence"],
            [
                [
                    _c(rank),
                    _c(
                        CAUSE_TITLES.get(cause.cause, cause.cause),
                        strong=True,
                        note=CAUSE_CHECKS.get(cause.cause, ""),
                    ),
                    _c(
                        f"{cause.score * 100:.0f} %",
                        numeric=True,
                        bar_percent=round(max(0.0, min(1.0, cause.score)) * 100),
                    ),
                    _c(cause.evidence),
                ]
                for rank, cause in enumerate(dependency.causes, start=1)
            ],
        )
    return Diagnosis(
        pattern=SIGNATURE_TEXT.get(dependency.signature, dependency.signature),
        text=text,
        causes=causes,
    )


def _linear_cells(fit: LinearFit | None, points: int) -> list[Cell]:
    """Coulomb, viscous, |v| range and χ²ᵣ of the line; a null parameter shows its reason."""
    if fit is None:
        return [_c("no straight-line fit", muted=True, colspan=4, note=_plural(points, "point"))]
    reason = fit.reason or "not determined by the points"
    cells: list[Cell] = []
    if fit.coulomb is None and fit.viscous_per_mm_min is None:
        cells.append(_c(reason, muted=True, colspan=2))
    else:
        cells.append(
            _c(reason, muted=True)
            if fit.coulomb is None
            else _n(format_with_error(fit.coulomb, fit.coulomb_stderr))
        )
        cells.append(
            _c(reason, muted=True)
            if fit.viscous_per_mm_min is None
            else _n(
                format_with_error(
                    fit.viscous_per_mm_min * 1000,
                    fit.viscous_stderr * 1000 if fit.viscous_stderr is not None else None,
                )
            )
        )
    low, high = fit.velocity_range_mm_min
    note = _plural(fit.n_points, "point")
    if fit.points_below_range:
        note += f"; {fit.points_below_range} slower left out"
    cells.append(_c(f"{format_number(low)} – {format_number(high)}", numeric=True, note=note))
    cells.append(_n(format_number(fit.chi2_reduced)))
    return cells


def _models(result: AxisResult) -> Table | None:
    unit = result.unit
    rows = []
    for position in result.positions:
        for direction, found in sorted(position.directions.items()):
            if found is None:
                continue
            model = _c(
                MODEL_NAMES[found.model],
                strong=found.model is not None,
                muted=found.model is None,
                note=found.model_reason,
            )
            rows.append(
                [
                    _c(_where(position)),
                    _c(direction),
                    model,
                    *_linear_cells(found.fit, len(found.points)),
                ]
            )
    if not rows:
        return None
    return _table(
        [
            "Position",
            "Direction",
            "Model, and why",
            _c(f"Coulomb [{unit}]", numeric=True),
            _c(f"Viscous [{unit} per m/min]", numeric=True),
            _c("over |v| [mm/min]", numeric=True),
            _c("χ²ᵣ", numeric=True),
        ],
        rows,
    )


_MODELS_NOTE: Final = (
    "The model that describes the curve's points within their scatter: Coulomb + viscous "
    "friction (a straight line over speed), the Stribeck model (friction rising towards "
    "standstill) or the extended Stribeck model; 'none' when no model does. A Stribeck hump "
    "is friction, not a fault. Coulomb and viscous friction are those of the straight line, "
    "fitted by least squares over the speeds given (above the Stribeck region), ± one "
    "standard error, with the axis' offset taken out; χ²ᵣ is its reduced χ² (the line "
    "describes the points for χ²ᵣ below 10)."
)


def _parameter(fit: NonlinearFit, name: str, scale: float = 1.0) -> Cell:
    """A parameter as value ± half its 95 % interval, or a dash when the model lacks it."""
    if fit.parameters is None or name not in fit.parameters:
        return _n("–")
    value = fit.parameters[name] * scale
    interval = fit.ci95.get(name) if fit.ci95 is not None else None
    if interval is None:
        return _n(format_number(value))
    return _n(format_with_error(value, (interval[1] - interval[0]) / 2 * scale))


_NONLINEAR_PARAMETERS: Final = (
    ("T_C", 1.0),
    ("T_S", 1.0),
    ("v_S", 1.0),
    ("delta", 1.0),
    ("b", 1000.0),
    ("f_w", 1.0),
    ("k", 1.0),
)


def _nonlinear_fits(found: DirectionResult) -> list[NonlinearFit]:
    return [fit for fit in (found.stribeck, found.extended) if fit is not None]


def _nonlinear(result: AxisResult) -> Folded | None:
    unit = result.unit
    rows = []
    for position in result.positions:
        for direction, found in sorted(position.directions.items()):
            if found is None:
                continue
            for fit in _nonlinear_fits(found):
                name = MODEL_NAMES[fit.model]
                if fit.parameters is None:
                    values = [
                        _c(
                            fit.reason or "not identifiable",
                            muted=True,
                            colspan=len(_NONLINEAR_PARAMETERS),
                        )
                    ]
                    model = _c(name)
                else:
                    values = [_parameter(fit, p, scale) for p, scale in _NONLINEAR_PARAMETERS]
                    model = _c(
                        name,
                        note="" if fit.identifiable else f"not drawn: {fit.reason or 'uncertain'}",
                    )
                rows.append(
                    [
                        _c(_where(position)),
                        _c(direction),
                        model,
                        *values,
                        _n(format_number(fit.chi2_reduced)),
                    ]
                )
    if not rows:
        return None
    table = _table(
        [
            "Position",
            "Direction",
            "Model",
            _c(f"T_C [{unit}]", numeric=True),
            _c(f"T_S [{unit}]", numeric=True),
            _c("v_S [mm/min]", numeric=True),
            _c("δ", numeric=True),
            _c(f"b [{unit} per m/min]", numeric=True),
            _c(f"f_w [{unit}]", numeric=True),
            _c("k", numeric=True),
            _c("χ²ᵣ", numeric=True),
        ],
        rows,
        css="compact",
    )
    return Folded(
        summary=f"Stribeck model fits ({_plural(len(rows), 'fit')})",
        table=table,
        note="Stribeck model T = T_C + (T_S − T_C)·exp(−(|v|/v_S)^δ) + b·|v| with T_C the "
        "Coulomb friction, T_S the static (breakaway) friction and v_S the Stribeck velocity; "
        "the extended model adds a rolling term f_w·(|v| / 1 m/min)^k. ± half the 95 % "
        "confidence interval. A fit the points do not determine shows why instead of "
        "parameters; only identifiable fits are drawn in the plot.",
        css="fits",
    )


def _axis(section: AxisSection, headline: Headline) -> AxisView:
    result = section.result
    verdict = headline.verdict
    positions = ", ".join(_where(p) for p in result.positions) or "–"
    facts = (
        Fact("Quantity", "friction torque in Nm" if result.unit == "Nm" else "motor current in A"),
        Fact(
            "Torque constant",
            f"{result.torque_constant_nm_per_a:g} Nm/A"
            if result.torque_constant_nm_per_a is not None
            else "not known (values are motor current)",
        ),
        Fact("Positions", positions),
        Fact(
            "Windows", f"{result.windows} ({result.window_source}), {result.samples_used} samples"
        ),
        Fact("Bearings", section.bearings.describe()),
    )
    offset = None
    if result.offset is not None:
        offset = Offset(
            value=f"{format_with_error(result.offset.value, result.offset.stderr)} {result.unit}"
            + ("" if offset_is_significant(result.offset) else " (not significant)"),
            explanation=result.offset.explanation,
        )
    return AxisView(
        name=section.name,
        anchor=section.anchor,
        level=verdict.level,
        level_text=LEVEL_TEXT[verdict.level],
        reason=verdict.reason,
        action=verdict.action,
        coulomb=headline.coulomb_text,
        viscous=headline.viscous_text,
        travel=headline.travel_text,
        facts=facts,
        notes=_axis_notes(section),
        stribeck=_image(section.stribeck) if section.stribeck else None,
        travel_figure=_image(section.travel) if section.travel else None,
        diagnosis=_diagnosis(section),
        offset=offset,
        models=_models(result),
        models_note=_MODELS_NOTE,
        nonlinear=_nonlinear(result),
        raw=_image(section.raw) if section.raw else None,
        raw_note=section.raw_note or "",
    )


# --- comparison ----------------------------------------------------------------------------


def _value_text(value: Any) -> str:
    if isinstance(value, float):
        return format_number(value)
    if isinstance(value, BaseModel):
        value = value.model_dump(mode="json")
    if isinstance(value, dict | list | tuple):
        text = json.dumps(value, ensure_ascii=False, default=str)
        return text if len(text) <= 400 else text[:400] + " …"
    return "–" if value is None else str(value)


def _model_table(model: BaseModel, skip: Sequence[str] = ()) -> Table | None:
    rows = [
        [_c(name.replace("_", " ")), _c(_value_text(getattr(model, name)))]
        for name in type(model).model_fields
        if name not in skip
    ]
    return _table(["Item", "Value"], rows) if rows else None


def _generic_comparison(comparison: BaseModel) -> ComparisonView:
    """Any other comparison model: its summary and findings first, the rest as a table."""
    parts: list[ComparisonPart] = []
    summary = getattr(comparison, "summary", None)
    if isinstance(summary, str):
        parts.append(ComparisonPart(headline=summary))
    elif isinstance(summary, BaseModel):
        parts.append(ComparisonPart(table=_model_table(summary)))
    elif isinstance(summary, Sequence) and summary:
        parts.append(ComparisonPart(items=tuple(_value_text(s) for s in summary)))
    findings = getattr(comparison, "findings", None)
    if isinstance(findings, Sequence) and not isinstance(findings, str) and findings:
        models = [f for f in findings if isinstance(f, BaseModel)]
        if models and len(models) == len(findings):
            columns: list[str] = []
            for found in models:
                columns.extend(n for n in type(found).model_fields if n not in columns)
            table = _table(
                [c.replace("_", " ") for c in columns],
                [[_c(_value_text(getattr(m, c, None))) for c in columns] for m in models],
            )
            parts.append(ComparisonPart(heading="Findings", table=table))
        else:
            parts.append(
                ComparisonPart(heading="Findings", items=tuple(_value_text(f) for f in findings))
            )
    parts.append(
        ComparisonPart(heading="Details", table=_model_table(comparison, ("summary", "findings")))
    )
    return ComparisonView(intro=(), facts=(), parts=tuple(parts))


def _group_where(group: GroupDeviation) -> str:
    where = _numbered(group.position_index, group.position_mm)
    return f"axis {group.axis}, {where}, {group.direction}"


_MAX_PROBLEMS = 15


def _known_comparison(
    comparison: Comparison, figure: Figure | None, axes: Sequence[str]
) -> ComparisonView:
    limits = comparison.limits
    if comparison.mode == "lifetime":
        intro = (
            f"This machine against its earlier measurement {comparison.base!r}: how much "
            "friction changed at each position and direction."
        )
    else:
        intro = (
            f"Machines of one type against {comparison.base!r}: the change per position "
            "and direction, and the spread of the fleet."
        )
    facts = (
        Fact("Base", comparison.base),
        Fact("Compared", ", ".join(comparison.others)),
        Fact(
            "Limits",
            f"warning beyond ±{limits.warning_percent:g} %, critical beyond "
            f"±{limits.critical_percent:g} % (median change over the velocities)",
        ),
        Fact("Compared on", format_date(comparison.created_utc)),
    )
    parts: list[ComparisonPart] = []
    rows = []
    names = list(dict.fromkeys([*axes, *(g.axis for g in comparison.groups)]))
    for label in comparison.others:
        for axis in names:
            found = axis_comparison(comparison, axis, label)
            if found is None:
                continue
            change = next(
                (c for c in comparison.changes if c.label == label and c.axis == axis), None
            )
            cause = change.causes[0] if change is not None and change.causes else None
            rows.append(
                [
                    _c(label),
                    _c(axis),
                    _c(found.status, status=found.status),
                    _c(found.change),
                    _c(
                        CAUSE_TITLES.get(cause.cause, cause.cause) if cause else "–",
                        strong=cause is not None,
                        note=f"{cause.evidence} (score {cause.score:.2f})" if cause else "",
                    ),
                ]
            )
    if rows:
        parts.append(
            ComparisonPart(
                heading="Change per axis and likely cause",
                table=_table(
                    ["Run", "Axis", "Status", "Change", "Likely cause of the change"], rows
                ),
                note="The status is the worst of the axis' positions and directions. The "
                "cause comes from the ratio against the base per velocity and position, so the "
                "machine's own position dependency cancels; a change alike at every position "
                "beyond the warning limit is a global offset (preload, guide carriage, "
                "lubricant).",
            )
        )
    if comparison.runs:
        run_rows = []
        for run in comparison.runs:
            groups = [g for g in comparison.groups if g.label == run.label]
            worst = max(groups, key=lambda g: abs(g.median_deviation_percent), default=None)
            where = (
                f"{_group_where(worst)}: {worst.median_deviation_percent:+.1f} %"
                if worst is not None
                else "–"
            )
            run_rows.append(
                [
                    _c(run.label),
                    _c(run.machine or "–"),
                    _n(run.points),
                    _n(f"{run.max_abs_deviation_percent:.1f} %"),
                    _c(where),
                    _c(run.status, status=run.status),
                ]
            )
        parts.append(
            ComparisonPart(
                heading="Runs",
                table=_table(
                    [
                        "Run",
                        "Machine",
                        _c("Points", numeric=True),
                        _c("Largest change", numeric=True),
                        "Where",
                        "Status",
                    ],
                    run_rows,
                ),
            )
        )
    if figure is not None:
        parts.append(ComparisonPart(figure=_image(figure)))
    if comparison.groups:
        group_rows = [
            [
                _c(group.label),
                _c(group.axis),
                _c(_numbered(group.position_index, group.position_mm)),
                _c(group.direction),
                _n(group.points),
                _n(f"{group.median_deviation_percent:+.1f} %"),
                _n(f"{group.max_abs_point_deviation_percent:.1f} %"),
                _c(group.status, status=group.status),
            ]
            for group in comparison.groups
        ]
        parts.append(
            ComparisonPart(
                heading="Change per position and direction",
                table=_table(
                    [
                        "Run",
                        "Axis",
                        "Position",
                        "Direction",
                        _c("Velocities", numeric=True),
                        _c("Median change", numeric=True),
                        _c("Largest single change", numeric=True),
                        "Status",
                    ],
                    group_rows,
                ),
            )
        )
    for fleet in comparison.fleet:
        fleet_rows = [
            [
                _c(run),
                _n(f"{format_number(mean)} {fleet.unit}"),
                _n(f"{z:+.1f}"),
                _c("outlier" if run in fleet.outliers else ""),
            ]
            for run, mean, z in zip(fleet.runs, fleet.mean_friction, fleet.modified_z, strict=False)
        ]
        parts.append(
            ComparisonPart(
                heading=f"Fleet, axis {fleet.axis}",
                table=_table(
                    [
                        "Run",
                        _c("Mean friction", numeric=True),
                        _c("Modified z-score", numeric=True),
                        "",
                    ],
                    fleet_rows,
                ),
                note=f"Mean {format_number(fleet.mean)} {fleet.unit}, spread "
                f"{fleet.spread_percent:.1f} % (max − min over the mean), standard deviation "
                f"{format_number(fleet.std)} {fleet.unit}, over {fleet.common_points} points "
                "measured in every run.",
            )
        )
    if comparison.problems:
        shown = list(comparison.problems[:_MAX_PROBLEMS])
        if len(comparison.problems) > len(shown):
            shown.append(f"… and {len(comparison.problems) - len(shown)} more")
        parts.append(
            ComparisonPart(
                folded=Folded(
                    summary=f"Not compared ({len(comparison.problems)})", items=tuple(shown)
                )
            )
        )
    return ComparisonView(intro=(intro,), facts=facts, parts=tuple(parts))


# --- the page ------------------------------------------------------------------------------


def _settings(settings: Mapping[str, object]) -> Folded | None:
    if not settings:
        return None
    rows = [[_c(key), _c(_value_text(value))] for key, value in sorted(settings.items())]
    return Folded(
        summary=f"Analysis settings ({len(rows)})",
        table=_table(["Setting", "Value"], rows),
        css="settings",
    )


def page_view(
    results: Results,
    sections: Sequence[AxisSection],
    *,
    title: str,
    recording: Recording | RecordingHead | None = None,
    comparison: BaseModel | None = None,
    comparison_figure: Figure | None = None,
) -> PageView:
    """What the page shows, as text: the view model :func:`render_page` renders.

    With a :class:`~ncmeasure.analysis.judgement.compare.Comparison`, each axis' verdict
    is combined with its change against the base (the last compared run's:
    the run the report shows).
    """
    headlines: dict[str, Headline] = {}
    for section in sections:
        against = (
            axis_comparison(comparison, section.name)
            if isinstance(comparison, Comparison)
            else None
        )
        headlines[section.name] = axis_headline(section.result, against)
    verdicts, verdict_note = _verdict_rows(sections, headlines, results.skipped, comparison)
    summary, summary_note = _summary(sections, headlines)
    compared: ComparisonView | None = None
    if isinstance(comparison, Comparison):
        compared = _known_comparison(
            comparison, comparison_figure, [section.name for section in sections]
        )
    elif comparison is not None:
        compared = _generic_comparison(comparison)
    return PageView(
        title=title,
        subtitle="Friction of the feed axes, measured with the machine's own drives at constant "
        "velocities in short windows at a few positions per axis.",
        verdicts=verdicts,
        verdict_note=verdict_note,
        facts=_facts(results, recording),
        comparison=compared,
        summary=summary,
        summary_note=summary_note,
        notes=_notes(sections, recording),
        axes=tuple(_axis(section, headlines[section.name]) for section in sections),
        settings=_settings(results.settings),
        footer=f"Written by ncmeasure {__version__} from results of ncmeasure "
        f"{results.ncmeasure_version}, analysed {format_date(results.created_utc)}.",
        headlines=headlines,
    )


@functools.cache
def _template() -> jinja2.Template:
    environment = SandboxedEnvironment(
        loader=jinja2.PackageLoader("ncmeasure.report", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    return environment.get_template("report.html.j2")


def render_page(
    results: Results,
    sections: Sequence[AxisSection],
    *,
    title: str,
    recording: Recording | RecordingHead | None = None,
    comparison: BaseModel | None = None,
    comparison_figure: Figure | None = None,
) -> str:
    """The whole report as one HTML document (see the module for what it shows)."""
    view = page_view(
        results,
        sections,
        title=title,
        recording=recording,
        comparison=comparison,
        comparison_figure=comparison_figure,
    )
    return _template().render(page=view)
