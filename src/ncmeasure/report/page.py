"""The report as one HTML page: inline CSS, images as data URIs, every name escaped.

The page is built from small functions that return HTML text. Anything that
comes from a file (machine and axis names, evidence, warnings, settings) goes
through :func:`esc`; only the :class:`Html` strings built here pass unescaped.
No script, no external resource: the file opens offline and prints as is.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

from pydantic import BaseModel

from ncmeasure import __version__
from ncmeasure.analysis.compare import Comparison
from ncmeasure.analysis.results import (
    AxisResult,
    DirectionResult,
    LinearFit,
    NonlinearFit,
    PositionDependency,
    PositionResult,
    Results,
)
from ncmeasure.recording import Recording
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

__all__ = ["AxisSection", "Figure", "Html", "esc", "render_page"]


class Html(str):
    """Text that is already HTML and must not be escaped again."""

    __slots__ = ()


def esc(value: object) -> Html:
    """Any value as HTML text: ``Html`` as is, everything else escaped (quotes too)."""
    if isinstance(value, Html):
        return value
    return Html(html.escape(str(value), quote=True))


def join(parts: Iterable[object], separator: str = "\n") -> Html:
    """Escape and join parts."""
    return Html(separator.join(esc(p) for p in parts))


def tag(name: str, content: object = "", **attributes: object) -> Html:
    """``<name attr="...">content</name>``; attribute values escaped, ``class_`` for class."""
    attrs = "".join(
        f' {key.rstrip("_").replace("_", "-")}="{esc(value)}"'
        for key, value in attributes.items()
        if value is not None
    )
    return Html(f"<{name}{attrs}>{esc(content)}</{name}>")


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


CSS: Final = """
:root { --ink: #1d1d1f; --muted: #5b5b60; --rule: #d0d0d4; --soft: #f4f5f7;
        --accent: #3b5875; --ok: #13602a; --bad: #b3261e; --warn: #8a5a00; }
* { box-sizing: border-box; }
html { background: #ffffff; }
body { margin: 0 auto; max-width: 1100px; padding: 28px 22px 40px;
       font: 15px/1.45 "DejaVu Sans", "Segoe UI", Arial, Helvetica, sans-serif;
       color: var(--ink); }
h1 { font-size: 26px; margin: 0 0 4px; letter-spacing: 0.2px; }
h1 .machine { color: var(--accent); }
h2 { font-size: 21px; margin: 36px 0 10px; padding-bottom: 6px;
     border-bottom: 2px solid var(--ink); }
h3 { font-size: 16.5px; margin: 26px 0 8px; }
p { margin: 6px 0 10px; }
.subtitle { color: var(--muted); margin: 0 0 18px; }
dl.facts { display: grid; grid-template-columns: max-content 1fr; gap: 3px 18px;
           margin: 10px 0 18px; padding: 12px 16px; background: var(--soft);
           border: 1px solid var(--rule); border-radius: 4px; }
dl.facts dt { color: var(--muted); }
dl.facts dd { margin: 0; overflow-wrap: anywhere; }
table { border-collapse: collapse; width: 100%; margin: 8px 0 14px; font-size: 14px; }
th, td { border: 1px solid var(--rule); padding: 5px 8px; text-align: left;
         vertical-align: top; }
th { background: var(--soft); font-weight: 600; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
td.num { white-space: nowrap; }
table.compact { font-size: 12.5px; }
table.compact th, table.compact td { padding: 4px 5px; }
tbody tr:nth-child(even) td { background: #fafafb; }
.yes, .status-ok { color: var(--ok); font-weight: 600; }
.status-warning { color: var(--warn); font-weight: 700; }
.status-critical { color: var(--bad); font-weight: 700; }
.no { color: var(--bad); font-weight: 600; }
.note { color: var(--muted); font-size: 13.5px; }
.box { border: 1px solid var(--rule); border-left: 5px solid var(--accent);
       padding: 10px 14px; margin: 10px 0 14px; background: #fbfcfe; }
.box.warn { border-left-color: var(--warn); background: #fffaf0; }
.box p:first-child { margin-top: 0; } .box p:last-child { margin-bottom: 0; }
.headline { font-size: 16px; font-weight: 600; }
.bar { display: inline-block; width: 90px; height: 10px; background: #e6e8ec;
       border: 1px solid #c4c8d0; vertical-align: middle; margin-right: 6px; }
.bar span { display: block; height: 100%; background: var(--accent); }
figure { margin: 10px 0 18px; break-inside: avoid; page-break-inside: avoid; }
figure img { display: block; width: 100%; height: auto; border: 1px solid var(--rule); }
figcaption { color: var(--muted); font-size: 13.5px; margin-top: 5px; }
figcaption .file { font-family: "DejaVu Sans Mono", Consolas, monospace; font-size: 12px; }
nav.contents { margin: 6px 0 0; font-size: 14px; }
nav.contents a { color: var(--accent); margin-right: 14px; }
footer { margin-top: 40px; padding-top: 8px; border-top: 1px solid var(--rule);
         color: var(--muted); font-size: 12.5px; }
code { font-family: "DejaVu Sans Mono", Consolas, monospace; font-size: 13px; }
@page { size: A4; margin: 14mm 12mm; }
@media print {
  body { max-width: none; padding: 0; font-size: 11pt; }
  section.axis, section.comparison { break-before: page; page-break-before: always; }
  h2, h3 { break-after: avoid; page-break-after: avoid; }
  table, .box { break-inside: avoid; page-break-inside: avoid; }
  nav.contents { display: none; }
  a { color: inherit; text-decoration: none; }
}
"""


def _img(figure: Figure) -> Html:
    data = base64.b64encode(figure.png).decode("ascii")
    image = Html(f'<img src="data:image/png;base64,{data}" alt="{esc(figure.alt)}">')
    caption = tag(
        "figcaption",
        Html(esc(figure.caption) + " " + tag("span", f"({figure.filename})", class_="file")),
    )
    return tag("figure", Html(image + caption))


def _table(
    headers: Sequence[object],
    rows: Iterable[Sequence[object]],
    numeric: Sequence[int] = (),
    css_class: str | None = None,
) -> Html:
    """A table; columns listed in ``numeric`` align right."""

    def cells(name: str, row: Sequence[object]) -> Html:
        return join(
            (tag(name, c, class_="num" if i in numeric else None) for i, c in enumerate(row)), ""
        )

    body = join(tag("tr", cells("td", row)) for row in rows)
    head = cells("th", headers)
    opening = Html("<table>") if css_class is None else Html(f'<table class="{esc(css_class)}">')
    return Html(f"{opening}<thead><tr>{head}</tr></thead><tbody>\n{body}\n</tbody></table>")


def _facts(items: Iterable[tuple[str, object]]) -> Html:
    parts = join((Html(tag("dt", k) + tag("dd", v)) for k, v in items), "")
    return tag("dl", parts, class_="facts")


def _yes_no(value: bool) -> Html:
    return tag("span", "yes" if value else "no", class_="yes" if value else "no")


def _bar(score: float) -> Html:
    width = max(0.0, min(1.0, score)) * 100
    return Html(f'<span class="bar"><span style="width:{width:.0f}%"></span></span>')


# --- numbers of an axis ----------------------------------------------------------------


def _fits(result: AxisResult) -> list[tuple[float, str, LinearFit]]:
    return [
        (position.position_mm, direction, found.fit)
        for position in result.positions
        for direction, found in sorted(position.directions.items())
        if found is not None and found.fit is not None
    ]


def _mean(values: Sequence[float]) -> float | None:
    finite = [v for v in values if math.isfinite(v)]
    return sum(finite) / len(finite) if finite else None


def _coulomb_per_position(result: AxisResult) -> list[float]:
    """Coulomb friction per position, the mean of its directions (offset taken out)."""
    values = []
    for position in result.positions:
        found = [
            d.fit.coulomb
            for d in position.directions.values()
            if d and d.fit and d.fit.coulomb is not None
        ]
        if found:
            values.append(sum(found) / len(found))
    return values


def coulomb_headline(result: AxisResult) -> str:
    """Mean Coulomb friction over positions (both directions), with its range over positions."""
    values = _coulomb_per_position(result)
    mean = _mean(values)
    if mean is None:
        return "–"
    text = f"{format_number(mean)} {result.unit}"
    if len(values) > 1:
        text += f" ({format_number(min(values))}–{format_number(max(values))})"
    return text


def viscous_headline(result: AxisResult) -> str:
    """Mean viscous friction per m/min."""
    mean = _mean(
        [
            fit.viscous_per_mm_min * 1000
            for _, _, fit in _fits(result)
            if fit.viscous_per_mm_min is not None
        ]
    )
    if mean is None:
        return "–"
    return f"{format_number(mean)} {result.unit} per m/min"


def _top_cause(dependency: PositionDependency | None) -> str:
    if dependency is None or not dependency.causes:
        return "–"
    cause = dependency.causes[0]
    return f"{CAUSE_TITLES.get(cause.cause, cause.cause)} ({cause.score * 100:.0f} %)"


def _travel_headline(dependency: PositionDependency | None) -> str:
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


# --- sections --------------------------------------------------------------------------


def _header(results: Results, recording: Recording | None, title: str) -> Html:
    info = results.recording
    machine = info.machine or (recording.meta.machine if recording is not None else None)
    items: list[tuple[str, object]] = [
        ("Machine", machine or "not named"),
        ("Recording", info.directory),
        ("Recorded", format_date(info.start_utc)),
        ("Analysed", format_date(results.created_utc)),
        ("Source", info.source or "–"),
    ]
    if recording is not None:
        duration = float(recording.time_s[-1] - recording.time_s[0]) if len(recording) else 0.0
        items.append(
            ("Samples", f"{len(recording)} over {duration:.0f} s ({recording.meta.status})")
        )
    if info.config_hash:
        items.append(("Program (config hash)", Html(tag("code", info.config_hash))))
    items.append(
        ("ncmeasure", f"{results.ncmeasure_version} (results format {results.format_version})")
    )
    heading = tag("h1", title)
    subtitle = tag(
        "p",
        "Friction of the feed axes, measured with the machine's own drives at constant "
        "velocities in short windows at a few positions per axis.",
        class_="subtitle",
    )
    return Html(heading + subtitle + _facts(items))


def _summary(sections: Sequence[AxisSection], recording: Recording | None) -> Html:
    rows = []
    for section in sections:
        result = section.result
        dependency = result.position_dependency
        fits = _fits(result)
        accepted = sum(1 for _, _, fit in fits if fit.accepted)
        rows.append(
            [
                Html(f'<a href="#{esc(section.anchor)}">{esc(section.name)}</a>'),
                coulomb_headline(result),
                viscous_headline(result),
                _travel_headline(dependency),
                _top_cause(dependency),
                _offset_text(result),
                f"{accepted} of {len(fits)}" if fits else "–",
            ]
        )
    table = _table(
        [
            "Axis",
            "Coulomb friction (mean, range over positions)",
            "Viscous friction",
            "Along the travel",
            "Most likely cause",
            "Offset",
            "Fits accepted",
        ],
        rows,
    )
    parts = [tag("h2", "Summary"), table]
    parts.append(
        tag(
            "p",
            "Coulomb friction is the velocity-independent part, viscous friction the rise "
            "per m/min of feed. Spread along the travel is (max − min) / mean of the friction "
            "averaged over all velocities.",
            class_="note",
        )
    )
    warnings = [
        f"Axis {section.name}: {text}" for section in sections for text in section.result.warnings
    ]
    if recording is not None:
        warnings = [f"Recording: {p}" for p in recording.problems] + warnings
    if warnings:
        items = join(tag("li", w) for w in warnings)
        parts.append(
            tag("div", Html(tag("p", tag("strong", "Notes")) + tag("ul", items)), class_="box warn")
        )
    nav = join((Html(f'<a href="#{esc(s.anchor)}">Axis {esc(s.name)}</a>') for s in sections), " ")
    parts.insert(1, tag("nav", nav, class_="contents"))
    return tag("section", join(parts), class_="summary")


def _diagnosis(section: AxisSection) -> Html:
    result = section.result
    dependency = result.position_dependency
    parts: list[Html] = [tag("h3", "Diagnosis")]
    if dependency is None:
        parts.append(
            tag(
                "p",
                "No position dependency in the results (one position measured, or too few "
                "points): the assembly cannot be judged from this measurement.",
            )
        )
        return join(parts)
    signature = SIGNATURE_TEXT.get(dependency.signature, dependency.signature)
    trend = dependency.trend_per_100mm
    lines = [
        tag("p", signature, class_="headline"),
        tag(
            "p",
            f"Friction varies by {dependency.spread_percent:.0f} % along the travel "
            f"(max − min relative to the mean); the trend is {trend:+.1f} % per 100 mm "
            "(positive: rising towards the max end). "
            f"Bearings: {section.bearings.describe()}.",
        ),
    ]
    parts.append(tag("div", join(lines), class_="box"))
    if dependency.causes:
        rows = [
            [
                str(rank),
                Html(
                    tag("strong", CAUSE_TITLES.get(cause.cause, cause.cause))
                    + Html("<br>")
                    + tag("span", CAUSE_CHECKS.get(cause.cause, ""), class_="note")
                ),
                Html(_bar(cause.score) + esc(f"{cause.score * 100:.0f} %")),
                cause.evidence,
            ]
            for rank, cause in enumerate(dependency.causes, start=1)
        ]
        parts.append(tag("p", "Likely causes, best first:"))
        parts.append(
            _table(["#", "Cause and what to check", "Likelihood", "Evidence"], rows, numeric=(2,))
        )
    return join(parts)


def _linear_rows(result: AxisResult) -> list[list[object]]:
    rows: list[list[object]] = []
    for position in result.positions:
        for direction, found in sorted(position.directions.items()):
            if found is None:
                continue
            fit = found.fit
            where = _where(position)
            if fit is None:
                rows.append([where, direction, "no fit", "", "", "", str(len(found.points)), ""])
                continue
            if fit.coulomb is None or fit.viscous_per_mm_min is None:
                rows.append([where, direction, fit.reason or "not determined", "", "", "",
                             str(fit.n_points), ""])  # fmt: skip
                continue
            low, high = fit.velocity_range_mm_min
            rows.append(
                [
                    where,
                    direction,
                    format_with_error(fit.coulomb, fit.coulomb_stderr),
                    format_with_error(
                        fit.viscous_per_mm_min * 1000, (fit.viscous_stderr or 0.0) * 1000
                    ),
                    format_number(fit.chi2_reduced),
                    _yes_no(fit.accepted),
                    str(fit.n_points),
                    f"{low:g} – {high:g}",
                ]
            )
    return rows


def _parameter(fit: NonlinearFit, name: str, scale: float = 1.0) -> str:
    """A parameter as value ± half its 95 % interval, or a dash when the model lacks it."""
    if fit.parameters is None or name not in fit.parameters:
        return "–"
    value = fit.parameters[name] * scale
    interval = fit.ci95.get(name) if fit.ci95 is not None else None
    if interval is None:
        return format_number(value)
    return format_with_error(value, (interval[1] - interval[0]) / 2 * scale)


def _nonlinear_rows(result: AxisResult) -> list[list[object]]:
    rows: list[list[object]] = []
    for position in result.positions:
        for direction, found in sorted(position.directions.items()):
            if found is None:
                continue
            for fit in _nonlinear(found):
                rows.append(
                    [
                        _where(position),
                        direction,
                        fit.model,
                        _parameter(fit, "T_C"),
                        _parameter(fit, "T_S"),
                        _parameter(fit, "v_S"),
                        _parameter(fit, "delta"),
                        _parameter(fit, "b", 1000.0),
                        _parameter(fit, "f_w"),
                        _parameter(fit, "k"),
                        format_number(fit.chi2_reduced),
                        _yes_no(fit.identifiable),
                    ]
                )
    return rows


def _where(position: PositionResult) -> str:
    """``2: 375 mm``, kept on one line."""
    return f"{position.position_index + 1}: {format_mm(position.position_mm)}\u00a0mm"


def _nonlinear(found: DirectionResult) -> list[NonlinearFit]:
    return [fit for fit in (found.stribeck, found.extended) if fit is not None]


def _fit_tables(result: AxisResult) -> Html:
    unit = result.unit
    parts: list[Html] = [tag("h3", "Fits")]
    linear = _linear_rows(result)
    if linear:
        parts.append(
            _table(
                [
                    "Position",
                    "Direction",
                    f"Coulomb [{unit}]",
                    f"Viscous [{unit} per m/min]",
                    "χ² reduced",
                    "Accepted",
                    "Points",
                    "|v| range [mm/min]",
                ],
                linear,
                numeric=(2, 3, 4, 6, 7),
            )
        )
        parts.append(
            tag(
                "p",
                "Coulomb + viscous friction by linear least squares, ± one standard error. "
                "A fit is accepted when its reduced χ² stays below 10 (the straight line "
                "describes the points within their scatter); a rejected fit at low speed "
                "usually means a pronounced Stribeck effect.",
                class_="note",
            )
        )
    else:
        parts.append(tag("p", "No fits in the results.", class_="note"))
    nonlinear = _nonlinear_rows(result)
    if nonlinear:
        parts.append(
            _table(
                [
                    "Position",
                    "Direction",
                    "Model",
                    f"T_C [{unit}]",
                    f"T_S [{unit}]",
                    "v_S [mm/min]",
                    "δ",
                    f"b [{unit} per m/min]",
                    f"f_w [{unit}]",
                    "k",
                    "χ² reduced",
                    "Identifiable",
                ],
                nonlinear,
                numeric=tuple(range(3, 11)),
                css_class="compact",
            )
        )
        parts.append(
            tag(
                "p",
                "Stribeck model T = T_C + (T_S − T_C)·exp(−(|v|/v_S)^δ) + b·|v| with T_C the "
                "Coulomb friction, T_S the static (breakaway) friction and v_S the Stribeck "
                "velocity; the extended model adds a rolling term f_w·(|v| / 1 m/min)^k. "
                "± half the 95 % confidence interval. Only identifiable fits (every interval "
                "narrower than its value, no parameter at a bound) are drawn in the plot.",
                class_="note",
            )
        )
    return join(parts)


def _axis(section: AxisSection) -> Html:
    result = section.result
    facts: list[tuple[str, object]] = [
        ("Quantity", "friction torque in Nm" if result.unit == "Nm" else "motor current in A"),
        (
            "Torque constant",
            f"{result.torque_constant_nm_per_a:g} Nm/A"
            if result.torque_constant_nm_per_a is not None
            else "not known (values are motor current)",
        ),
        ("Positions", ", ".join(f"{format_mm(p.position_mm)} mm" for p in result.positions) or "–"),
        ("Windows", f"{result.windows} ({result.window_source}), {result.samples_used} samples"),
        ("Bearings", section.bearings.describe()),
    ]
    parts: list[Html] = [
        tag("h2", f"Axis {section.name}"),
        _facts(facts),
        tag(
            "p",
            Html(
                tag("span", "Coulomb friction ", class_="headline")
                + tag("span", coulomb_headline(result), class_="headline")
                + esc(" · viscous " + viscous_headline(result))
                + esc(" · along the travel: " + _travel_headline(result.position_dependency))
            ),
        ),
    ]
    if result.warnings:
        items = join(tag("li", w) for w in result.warnings)
        parts.append(tag("div", tag("ul", items), class_="box warn"))
    parts.append(tag("h3", "Friction over velocity"))
    if section.stribeck is not None:
        parts.append(_img(section.stribeck))
    parts.append(tag("h3", "Friction along the travel"))
    if section.travel is not None:
        parts.append(_img(section.travel))
    else:
        parts.append(tag("p", "Only one position measured: no profile along the travel."))
    parts.append(_diagnosis(section))
    if result.offset is not None:
        parts.append(tag("h3", "Offset (gravity or bias)"))
        offset = result.offset
        parts.append(
            tag(
                "div",
                Html(
                    tag(
                        "p",
                        f"{format_with_error(offset.value, offset.stderr)} {result.unit}"
                        + ("" if offset_is_significant(offset) else " (not significant)"),
                        class_="headline",
                    )
                    + tag("p", offset.explanation)
                ),
                class_="box",
            )
        )
    parts.append(_fit_tables(result))
    parts.append(tag("h3", "Raw data"))
    if section.raw is not None:
        parts.append(_img(section.raw))
    if section.raw_note:
        parts.append(tag("p", section.raw_note, class_="note"))
    return tag("section", join(parts), class_="axis", id=section.anchor)


def _value_text(value: Any) -> str:
    if isinstance(value, float):
        return format_number(value)
    if isinstance(value, BaseModel):
        value = value.model_dump(mode="json")
    if isinstance(value, dict | list | tuple):
        text = json.dumps(value, ensure_ascii=False, default=str)
        return text if len(text) <= 400 else text[:400] + " …"
    return "–" if value is None else str(value)


def _model_table(model: BaseModel, skip: Sequence[str] = ()) -> Html:
    rows = [
        [name.replace("_", " "), _value_text(getattr(model, name))]
        for name in type(model).model_fields
        if name not in skip
    ]
    return _table(["Item", "Value"], rows) if rows else Html("")


def _findings(findings: Sequence[Any]) -> Html:
    models = [f for f in findings if isinstance(f, BaseModel)]
    if models and len(models) == len(findings):
        columns: list[str] = []
        for model in models:
            for name in type(model).model_fields:
                if name not in columns:
                    columns.append(name)
        rows = [[_value_text(getattr(m, c, None)) for c in columns] for m in models]
        return _table([c.replace("_", " ") for c in columns], rows)
    return tag("ul", join(tag("li", _value_text(f)) for f in findings))


def _generic_comparison(comparison: BaseModel) -> Html:
    """Any other comparison model: its summary and findings first, the rest as a table."""
    parts: list[Html] = []
    summary = getattr(comparison, "summary", None)
    if isinstance(summary, str):
        parts.append(tag("div", tag("p", summary, class_="headline"), class_="box"))
    elif isinstance(summary, BaseModel):
        parts.append(_model_table(summary))
    elif isinstance(summary, Sequence) and summary:
        items = join(tag("li", _value_text(s)) for s in summary)
        parts.append(tag("div", tag("ul", items), class_="box"))
    findings = getattr(comparison, "findings", None)
    if isinstance(findings, Sequence) and not isinstance(findings, str) and findings:
        parts.append(tag("h3", "Findings"))
        parts.append(_findings(findings))
    parts.append(tag("h3", "Details"))
    parts.append(_model_table(comparison, skip=("summary", "findings")))
    return join(parts)


def _status(status: str) -> Html:
    return tag("span", status, class_=f"status-{status}")


_MAX_PROBLEMS = 15


def _known_comparison(comparison: Comparison, figure: Figure | None) -> Html:
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
    parts: list[Html] = [
        tag("p", intro),
        _facts(
            [
                ("Base", comparison.base),
                ("Compared", ", ".join(comparison.others)),
                (
                    "Limits",
                    f"warning beyond ±{limits.warning_percent:g} %, critical beyond "
                    f"±{limits.critical_percent:g} % (median change over the velocities)",
                ),
                ("Compared on", format_date(comparison.created_utc)),
            ]
        ),
    ]
    if comparison.findings:
        items = join(tag("li", f) for f in comparison.findings)
        parts.append(tag("div", tag("ul", items), class_="box"))
    if comparison.runs:
        rows = [
            [
                run.label,
                run.machine or "–",
                str(run.points),
                f"{run.max_abs_deviation_percent:.1f} %",
                run.worst or "–",
                _status(run.status),
            ]
            for run in comparison.runs
        ]
        parts.append(
            _table(
                ["Run", "Machine", "Points", "Largest change", "Where", "Status"],
                rows,
                numeric=(2, 3),
            )
        )
    if figure is not None:
        parts.append(_img(figure))
    if comparison.changes:
        rows = [
            [
                change.label,
                change.axis,
                f"{change.mean_change_percent:+.1f} %",
                SIGNATURE_SHORT[change.signature],
                CAUSE_TITLES[change.causes[0].cause],
                f"{change.causes[0].score:.2f}",
            ]
            for change in comparison.changes
            if change.causes
        ]
        parts.append(tag("h3", "Likely cause of the change"))
        parts.append(
            _table(
                ["Run", "Axis", "Mean change", "Change along the travel", "Likely cause", "Score"],
                rows,
                numeric=(2, 5),
            )
        )
        parts.append(
            tag(
                "p",
                "From the ratio against the base per velocity and position, so the "
                "machine's own position dependency cancels; a change alike at every position "
                "beyond the warning limit is a global offset (preload, guide carriage, "
                "lubricant).",
                class_="note",
            )
        )
    if comparison.groups:
        rows = [
            [
                group.label,
                group.axis,
                f"{group.position_index + 1}: {format_mm(group.position_mm)}\u00a0mm",
                group.direction,
                str(group.points),
                f"{group.median_deviation_percent:+.1f} %",
                f"{group.max_abs_point_deviation_percent:.1f} %",
                _status(group.status),
            ]
            for group in comparison.groups
        ]
        parts.append(tag("h3", "Change per position and direction"))
        parts.append(
            _table(
                [
                    "Run",
                    "Axis",
                    "Position",
                    "Direction",
                    "Velocities",
                    "Median change",
                    "Largest single change",
                    "Status",
                ],
                rows,
                numeric=(4, 5, 6),
            )
        )
    for fleet in comparison.fleet:
        parts.append(tag("h3", f"Fleet, axis {fleet.axis}"))
        rows = [
            [
                run,
                f"{format_number(mean)} {fleet.unit}",
                f"{z:+.1f}",
                "outlier" if run in fleet.outliers else "",
            ]
            for run, mean, z in zip(fleet.runs, fleet.mean_friction, fleet.modified_z, strict=False)
        ]
        parts.append(_table(["Run", "Mean friction", "Modified z-score", ""], rows, numeric=(1, 2)))
        parts.append(
            tag(
                "p",
                f"Mean {format_number(fleet.mean)} {fleet.unit}, spread "
                f"{fleet.spread_percent:.1f} % (max − min over the mean), standard deviation "
                f"{format_number(fleet.std)} {fleet.unit}, over {fleet.common_points} points "
                "measured in every run.",
                class_="note",
            )
        )
    if comparison.problems:
        shown = comparison.problems[:_MAX_PROBLEMS]
        notes = [tag("li", problem) for problem in shown]
        if len(comparison.problems) > len(shown):
            notes.append(tag("li", f"… and {len(comparison.problems) - len(shown)} more"))
        parts.append(
            tag(
                "div",
                Html(tag("p", tag("strong", "Not compared")) + tag("ul", join(notes))),
                class_="box warn",
            )
        )
    return join(parts)


def _comparison(comparison: BaseModel, figure: Figure | None) -> Html:
    body = (
        _known_comparison(comparison, figure)
        if isinstance(comparison, Comparison)
        else _generic_comparison(comparison)
    )
    return tag("section", Html(tag("h2", "Comparison") + body), class_="comparison")


def _settings(settings: Mapping[str, object]) -> Html:
    if not settings:
        return Html("")
    rows = [[key, _value_text(value)] for key, value in sorted(settings.items())]
    return join([tag("h3", "Analysis settings"), _table(["Setting", "Value"], rows)])


def render_page(
    results: Results,
    sections: Sequence[AxisSection],
    *,
    title: str,
    recording: Recording | None = None,
    comparison: BaseModel | None = None,
    comparison_figure: Figure | None = None,
) -> str:
    """The whole report as one HTML document."""
    body = [
        _header(results, recording, title),
        _summary(sections, recording),
        *(_axis(section) for section in sections),
    ]
    if comparison is not None:
        body.append(_comparison(comparison, comparison_figure))
    body.append(tag("section", _settings(results.settings), class_="settings"))
    body.append(
        tag(
            "footer",
            f"Written by ncmeasure {__version__} from results of ncmeasure "
            f"{results.ncmeasure_version}, analysed {format_date(results.created_utc)}.",
        )
    )
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{esc(title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n"
        f"{join(body)}\n</body>\n</html>\n"
    )
