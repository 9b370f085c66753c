"""The report as one HTML page: a Jinja template over a frozen view model.

:func:`render_page` turns the results (and a comparison) into a
:class:`~ncmeasure.report.view.PageView` of plain text, numbers formatted and
every decision (which verdict, which note, which cell says what) taken here in
Python (each axis' section in :mod:`~ncmeasure.report.axis_view`, the
comparison in :mod:`~ncmeasure.report.comparison_view`); the template
``templates/report.html.j2`` only lays it out. Jinja's autoescape
escapes every value, so names, evidence and warnings from files cannot
inject markup; the only markup is the template's and the figures' SVG, which
:mod:`ncmeasure.report.svg` writes with every text escaped. The CSS and the
figures are inline, there is no script: the file opens offline and prints as
is.

Reading order, for the person at the machine: the verdict per axis first
(with a comparison, combined with it), the recording, the comparison, the
numbers per axis, then each axis in detail. Notes (recording problems,
analysis warnings, settings) are folded away in ``<details>`` with their
count. Measuring positions are numbered as everywhere else: ``2: 375 mm``,
the position index + 1.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from typing import Final

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
from ncmeasure.analysis.reading import recording_gaps, skipped_cycles
from ncmeasure.formats.comparison import Comparison
from ncmeasure.formats.results import AxisResult, ModelName, Results
from ncmeasure.recording import Recording, RecordingHead
from ncmeasure.report.axis_view import axis_view
from ncmeasure.report.comparison_view import generic_comparison, known_comparison, value_text
from ncmeasure.report.curves import offset_is_significant
from ncmeasure.report.view import (
    LEVEL_TEXT,
    MODEL_NAMES,
    AxisSection,
    Cell,
    ComparisonView,
    Fact,
    Figure,
    Folded,
    PageView,
    Table,
    cell,
    make_table,
    plural,
    share_percent,
)
from ncmeasure.report.words import CAUSE_TITLES, SIGNATURE_SHORT, format_date, format_with_error

__all__ = ["page_view", "render_page"]

GAP_SHARE_HIGHLIGHT = 0.05
"""Lost samples beyond this share are highlighted in the header (a measurement worth
repeating, though the verdict judges only whether the kept windows cover it)."""


_SKIPPED_ACTION: Final = (
    "Check the axis' channels and its part of the program, then measure it again."
)


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
            cell(section.name, link=section.anchor),
            cell(LEVEL_TEXT[verdict.level], level=verdict.level),
            cell(verdict.reason, note=f"What to do: {verdict.action}"),
            cell(headline.coulomb_text, numeric=True),
        ]
        if compared:
            row.append(_against_cell(headline.against))
        rows.append(row)
    for name, reason in skipped.items():
        row = [
            cell(name, strong=True),
            cell(LEVEL_TEXT["skipped"], level="skipped"),
            cell(reason, note=f"What to do: {_SKIPPED_ACTION}"),
            cell("–", numeric=True),
        ]
        if compared:
            row.append(cell("not analysed", muted=True))
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
            " With a comparison the verdict judges the change against the reference: a "
            "change beyond the warning or critical limit, or a local change along the "
            "travel (its likely cause named), makes it check or fault; the axis' own verdict "
            "counts too, except one from its pattern along the travel that did not change "
            "since the reference: that is the machine's own fingerprint, and is lifted."
        )
    return make_table(headers, rows, css="verdicts"), note


def _against_cell(against: AxisComparison | None) -> Cell:
    if against is None:
        return cell("not compared", muted=True)
    return cell(against.status, status=against.status, note=against.change)


def _recording_facts(results: Results, recording: Recording | RecordingHead | None) -> list[Fact]:
    """Samples, duration, how the recording ended and what it lost: never hidden."""
    info = results.recording
    samples, duration_s, status = info.samples, info.duration_s, info.status
    gaps, lost, share, events = info.gaps, info.gap_samples, info.gap_share, info.gap_events
    skipped = info.skipped_cycles
    if samples is None and isinstance(recording, Recording):
        samples = len(recording)
        duration_s = float(recording.time_s[-1] - recording.time_s[0]) if samples else 0.0
        status = recording.meta.status
        gaps, lost, events = recording_gaps(recording)
        total = samples + lost
        share = lost / total if total else 0.0
        skipped = skipped_cycles(recording.events)
    facts = []
    if samples is not None:
        text = f"{samples}"
        if duration_s is not None:
            text += f" over {duration_s:.0f} s"
        facts.append(Fact("Samples", text))
    if samples is not None or status is not None:
        if gaps:
            loss = (
                f"{plural(gaps, 'gap')}: {plural(lost, 'sample')}, {share_percent(share)} lost"
                if lost
                else plural(gaps, "gap")
            )
        else:
            loss = "no sample lost"
        text = f"{status or 'status unknown'}, {loss}"
        if events and events != gaps:
            text += f" (the link reported {plural(events, 'gap event')})"
        if skipped and samples is not None:
            text += (
                f"; {plural(skipped, 'cycle')} of them skipped by the link (the host fell "
                f"behind), {share_percent(skipped / max(1, samples + lost))} of the recording"
            )
        facts.append(Fact("Status", text, css="lost-many" if share > GAP_SHARE_HIGHLIGHT else ""))
    return facts


def _facts(results: Results, recording: Recording | RecordingHead | None) -> tuple[Fact, ...]:
    info = results.recording
    meta = recording.meta if recording is not None else None
    machine = info.machine or (meta.machine if meta is not None else None)
    serial = info.serial or (meta.serial if meta is not None else None)
    facts = [Fact("Machine", machine or "not named")]
    if serial:
        facts.append(Fact("Serial number", serial))
    facts += [
        Fact("Recording", info.directory),
        Fact("Recorded", format_date(info.start_utc) if info.start_utc else "unknown (no date)"),
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
    if not dependency.identifiable:
        return short
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
            cell(section.name, link=section.anchor),
            cell(headlines[section.name].coulomb_text),
            cell(headlines[section.name].viscous_text),
            cell(_travel_short(section.result)),
            cell(_top_cause(section.result)),
            cell(_offset_text(section.result)),
            cell(_models_count(section.result)),
        ]
        for section in sections
    ]
    table = make_table(
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


# --- the page ------------------------------------------------------------------------------


def _settings(settings: Mapping[str, object]) -> Folded | None:
    if not settings:
        return None
    rows = [[cell(key), cell(value_text(value))] for key, value in sorted(settings.items())]
    return Folded(
        summary=f"Analysis settings ({len(rows)})",
        table=make_table(["Setting", "Value"], rows),
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
        compared = known_comparison(
            comparison, comparison_figure, [section.name for section in sections]
        )
    elif comparison is not None:
        compared = generic_comparison(comparison)
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
        axes=tuple(axis_view(section, headlines[section.name]) for section in sections),
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
