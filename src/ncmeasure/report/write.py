"""write_report: results (+ recording, windows, comparison) -> one self-contained HTML file.

The HTML file holds every plot as SVG and its CSS inline, so it can be mailed,
archived and printed on its own. The same figures are also written beside it, as SVG
files in ``<stem>_plots/``, for use in other documents. The figures are written
directly (:mod:`ncmeasure.report.friction_svg`, :mod:`ncmeasure.report.raw_svg`,
:mod:`ncmeasure.report.comparison_figure`): no matplotlib.
"""

from __future__ import annotations

import gc
import logging
import os
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel

from ncmeasure.errors import NcMeasureError, OutputError, RecordingError
from ncmeasure.files import write_whole
from ncmeasure.formats.comparison import Comparison
from ncmeasure.formats.results import Results
from ncmeasure.recording import Recording, RecordingHead
from ncmeasure.report.bearings import bearing_layout
from ncmeasure.report.comparison_figure import comparison_svg
from ncmeasure.report.friction_svg import curves_svg, travel_svg
from ncmeasure.report.page import render_page
from ncmeasure.report.raw_svg import RawTrace, raw_trace, trace_svg
from ncmeasure.report.view import AxisSection, Figure
from ncmeasure.report.windows import find_window_times

__all__ = ["ReportProgress", "write_report"]

log = logging.getLogger(__name__)

Windows = Mapping[str, Sequence[tuple[float, float]]]


@dataclass(frozen=True)
class ReportProgress:
    """Handed to ``on_progress`` after every step of :func:`write_report`.

    Attributes:
        done: Steps finished.
        total: Steps in all (three plots per axis, then the page).
        step: What was just finished, e.g. ``axis X: Stribeck curves``.
    """

    done: int
    total: int
    step: str


def _safe_name(name: str) -> str:
    """An axis name as part of a file name (names from files may hold anything)."""
    cleaned = re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_")
    return cleaned[:40] or "axis"


def _default_title(results: Results, recording: Recording | RecordingHead | None) -> str:
    machine = results.recording.machine or (
        recording.meta.machine if recording is not None else None
    )
    return f"Friction report: {machine}" if machine else "Friction report"


def write_report(
    results: Results,
    path: str | os.PathLike[str],
    *,
    recording: Recording | RecordingHead | None = None,
    windows: Windows | None = None,
    comparison: BaseModel | None = None,
    title: str | None = None,
    on_progress: Callable[[ReportProgress], None] | None = None,
    traces: Mapping[str, RawTrace] | None = None,
) -> Path:
    """Write the friction report as one self-contained HTML file, its figures beside it.

    At the top the verdict per axis (ok / check / fault, why and what to do;
    with a comparison, combined with the axis' change against the reference)
    and the recording (samples, status, gaps), then the comparison when one
    is given, a summary of the numbers, and per axis: Stribeck curves per
    position and direction with the fits, friction along the travel with the
    bearings marked, the diagnosis in plain words, the offset, which model
    describes each curve and (with a recording) a stretch of raw data with the
    cut windows shaded. Notes and settings are folded away.

    Args:
        results: The analysis results.
        path: The HTML file to write (replaced if it exists). The plots go to
            ``<stem>_plots/`` in the same directory.
        recording: The recording the results came from; adds the raw data and
            the bearing layout from its axis metadata.
        windows: Per axis, the (t_start, t_end) windows in seconds that the
            analysis used (see :func:`~ncmeasure.report.windows.window_times`);
            shaded in the raw data. An axis missing here has its windows found
            again in the recording with the settings in ``results.settings``.
        comparison: A comparison with earlier results:
            :func:`~ncmeasure.analysis.judgement.compare.compare_results`' result, of
            which ``results`` is the last compared run; or any pydantic model
            (its ``summary`` and ``findings`` are shown first, the other
            fields in a table).
        title: The page title; default ``Friction report: <machine>``.
        on_progress: Called with a :class:`ReportProgress` after every step.
        traces: Per axis, the raw-data figure's data, gathered while the
            analysis read the recording with these ``windows``
            (:class:`~ncmeasure.report.traces.RawTraces`); the raw data of an
            axis missing here is read from ``recording``.

    Returns:
        The path of the HTML file.

    Raises:
        OutputError: The HTML file or a figure's file cannot be written.
    """
    with _heap_frozen():
        return _write_report(
            results, Path(path), recording, windows, comparison, title, on_progress, traces
        )


@contextmanager
def _heap_frozen() -> Iterator[None]:
    """Keep the objects alive before the report out of the garbage collector's full passes.

    Drawing makes many short-lived objects, and every so
    often the collector walks every object of the program: after an analysis,
    0.1 s and more each time, one to three times a report. Frozen
    (:func:`gc.freeze`), the objects that were there before are not walked;
    the figures' own garbage is collected as before. Where the program froze
    objects itself, nothing is changed.
    """
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _write_report(
    results: Results,
    target: Path,
    recording: Recording | RecordingHead | None,
    windows: Windows | None,
    comparison: BaseModel | None,
    title: str | None,
    on_progress: Callable[[ReportProgress], None] | None,
    traces: Mapping[str, RawTrace] | None,
) -> Path:
    plots_dir = target.with_name(f"{target.stem}_plots")
    try:
        plots_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{plots_dir}: cannot be created ({exc.strerror or exc})") from exc
    total = 3 * len(results.axes) + 1 + (comparison is not None)
    done = 0

    def advance(step: str) -> None:
        nonlocal done
        done += 1
        log.debug("report %d/%d: %s", done, total, step)
        if on_progress is not None:
            on_progress(ReportProgress(done, total, step))

    def keep(svg: str, filename: str, alt: str, caption: str) -> Figure:
        write_whole(plots_dir / filename, svg)
        return Figure(svg=svg, filename=f"{plots_dir.name}/{filename}", alt=alt, caption=caption)

    raw: dict[str, RawTrace | RecordingError] = dict(traces or {})
    missing = [name for name in results.axes if name not in raw]
    if isinstance(recording, RecordingHead) and missing:
        from ncmeasure.report.traces import read_raw_traces

        raw.update(read_raw_traces(recording, missing, windows or {}))
    sections: list[AxisSection] = []
    for index, (name, result) in enumerate(results.axes.items(), start=1):
        stem = f"{index:02d}_{_safe_name(name)}"
        section = AxisSection(
            name=name,
            anchor=f"axis-{index}",
            result=result,
            bearings=bearing_layout(name, recording, result),
        )
        section.stribeck = keep(
            curves_svg(name, result),
            f"{stem}_stribeck.svg",
            f"Friction over velocity of axis {name}",
            "Median friction per velocity step with ± one standard deviation, one colour "
            "per position; negative velocities on the left. Dashed: Coulomb + viscous fit "
            "over the speeds it was fitted to, dotted where extended below them; solid: "
            "Stribeck fit where identifiable. The velocity scale is logarithmic on "
            "both sides so that the slow steps, where friction drops with rising speed "
            "(Stribeck effect), are as visible as the fast ones.",
        )
        advance(f"axis {name}: Stribeck curves")
        travel = travel_svg(name, result, section.bearings)
        if travel is not None:
            section.travel = keep(
                travel,
                f"{stem}_travel.svg",
                f"Friction along the travel of axis {name}",
                "Friction magnitude at each measuring position: thin lines per velocity "
                "(darker is faster), the bold line the average over all velocities. "
                "A deviation in the assembly shows as a pattern along the travel, e.g. "
                "a rise towards the bearing that bends the screw.",
            )
        advance(f"axis {name}: friction along the travel")
        _raw_section(section, recording, windows, raw, results.settings, keep, stem)
        advance(f"axis {name}: raw data")
        sections.append(section)

    comparison_figure: Figure | None = None
    if isinstance(comparison, Comparison) and comparison.groups:
        comparison_figure = keep(
            comparison_svg(comparison),
            "comparison.svg",
            "Change of friction against the base run",
            "Median change of friction over the velocities, per axis, position and direction; "
            "one colour per compared run. Green band: within the warning limit; orange: "
            "warning; red: critical (an orange or red rim marks the point as well).",
        )
    if comparison is not None:
        advance("comparison")
    page = render_page(
        results,
        sections,
        title=title or _default_title(results, recording),
        recording=recording,
        comparison=comparison,
        comparison_figure=comparison_figure,
    )
    write_whole(target, page)
    advance("report page")
    log.info("report written to %s (plots in %s)", target, plots_dir)
    return target


def _raw_section(
    section: AxisSection,
    recording: Recording | RecordingHead | None,
    windows: Windows | None,
    traces: Mapping[str, RawTrace | RecordingError],
    settings: Mapping[str, object],
    keep: Callable[[str, str, str, str], Figure],
    stem: str,
) -> None:
    """Plot the raw data of an axis into its section, or say why there is none."""
    name = section.name
    if recording is None:
        section.raw_note = "No recording was given, so no raw data is shown."
        return
    if isinstance(recording, RecordingHead) or name in traces:
        # Gathered while the analysis read the recording, or read chunk by chunk: the
        # analysis' windows, or none (finding them again would read it once more).
        trace = traces[name]
        if windows is None or name not in windows:
            section.raw_note = "No windows are shaded: the analysis' windows were not given."
        if isinstance(trace, RecordingError):
            section.raw_note = f"The recording has no raw data of this axis ({trace.message})."
            return
        figure = trace_svg(trace)
    else:
        if windows is not None and name in windows:
            cuts = [(float(a), float(b)) for a, b in windows[name]]
        else:
            try:
                cuts = find_window_times(recording, name, settings)
                section.raw_note = (
                    "The shaded windows were found again in the recording with the analysis "
                    "settings (without the schedule)."
                )
            except NcMeasureError as exc:
                cuts = []
                section.raw_note = f"No windows are shaded: {exc.message}"
        try:
            figure = trace_svg(raw_trace(recording, name, cuts))
        except RecordingError as exc:
            section.raw_note = f"The recording has no raw data of this axis ({exc.message})."
            return
    section.raw = keep(
        figure,
        f"{stem}_raw.svg",
        f"Raw motor current and velocity of axis {name}",
        "Top: the axis' whole measurement (velocity); the box marks the stretch shown "
        "below. Middle: motor current; bottom: velocity. Only the shaded windows, where "
        "the axis moved at constant velocity, enter the friction values; acceleration, "
        "rapid moves and standstill are cut away.",
    )
