"""The analysis of one recording: windows -> friction table -> fits -> diagnosis -> Results.

:func:`analyze` runs the whole method (method.md, "The analysis") on every
recorded axis::

    recording = read_recording("run1")
    results = analyze(recording, schedule=load_schedule("programs/schedule.json"),
                      machine=load_machine("machine.toml"))
    write_results(results, "run1.results.json")

The recording is read in passes of chunks (:mod:`~ncmeasure.analysis.reading`;
one chunk when it is in memory); per axis: the constant-velocity windows
(:mod:`~ncmeasure.analysis.windows`), then its result
(:func:`~ncmeasure.analysis.axis.finish_axis`): the friction table, the fits
per position and direction, the offset, the position dependency and the verdict.
:func:`~ncmeasure.formats.results.write_results` and
:func:`~ncmeasure.formats.results.load_results` write and read ``results.json``.
"""

from __future__ import annotations

import datetime as dt
import functools
import logging
import os
from collections.abc import Iterable, Sequence
from typing import Protocol

from ncmeasure.analysis.axis import Progress
from ncmeasure.analysis.reading import RecordingPasses, skipped_cycles
from ncmeasure.analysis.windows.settings import SegmentSettings
from ncmeasure.analysis.windows.watch import AxisWindows, OnWindows, Watchers
from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.formats.identity import check_serial
from ncmeasure.formats.results import AxisResult, RecordingInfo, Results
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RecordingHead, RowChunk

__all__ = [
    "CHUNK_ROWS",
    "AnalysisSettings",
    "AxisSource",
    "analyze",
    "analyze_axis",
    "results_of",
]

log = logging.getLogger(__name__)

CHUNK_ROWS = 1 << 16
"""Rows per chunk where a recording is read from its file (about 0.5 MiB per channel)."""


class AnalysisSettings(SegmentSettings):
    """How the analysis finds windows: every setting of :class:`SegmentSettings`.

    The defaults suit ncmeasure's own programs and foreign recordings from 1 to
    100 ms per sample. They are written into ``results.json`` (``settings``),
    so a result says how it was made. ``ncmeasure analyze --set key=value``
    sets any of them by the same names.
    """


def _quiet(stage: str, fraction: float) -> None:
    """The progress callback that reports nothing."""


class AxisSource(Protocol):
    """What :func:`results_of` needs of a recording read for its axes
    (:class:`~ncmeasure.analysis.reading.RecordingPasses`).

    Attributes:
        rows: Rows of the recording.
        start_s: Time of its first row.
        end_s: Time of its last row.
        gaps: Holes in the time axis, samples lost in them, gap events.
        watchers: The tasks of ``on_windows``, fed on the readings that follow.
    """

    rows: int
    start_s: float
    end_s: float
    gaps: tuple[int, int, int]
    watchers: Watchers

    def axis(
        self, axis: str, progress: Progress, gap_share: float
    ) -> tuple[AxisResult, list[tuple[float, float]]]:
        """The axis' result and the (first, last) sample time of every window used."""
        ...

    def read_channels(
        self, wanted: tuple[str, ...], between_s: tuple[float, float] | None
    ) -> Iterable[RowChunk]:
        """The rows of some channels: all, or at least those of a stretch of time."""
        ...


def chosen_axes(head: Recording | RecordingHead, axes: Sequence[str] | None) -> tuple[str, ...]:
    """The axes to analyse: ``axes``, each recorded, else every recorded axis.

    Raises:
        RecordingError: The recording has no channels, or ``axes`` names an
            axis that was not recorded.
    """
    recorded = head.axes
    if not recorded:
        raise RecordingError(f"{head.directory}: the recording has no channels")
    if axes is not None:
        unknown = [a for a in axes if a not in recorded]
        if unknown:
            raise RecordingError(
                f"{head.directory}: axis {', '.join(unknown)} not recorded "
                f"(recorded: {', '.join(recorded)})"
            )
    return tuple(dict.fromkeys(axes)) if axes is not None else recorded


def analyze(
    recording: Recording | RecordingHead | str | os.PathLike[str],
    *,
    schedule: Schedule | None = None,
    machine: MachineConfig | None = None,
    settings: AnalysisSettings | None = None,
    axes: Sequence[str] | None = None,
    progress: Progress | None = None,
    rows: int = CHUNK_ROWS,
    window_times: dict[str, list[tuple[float, float]]] | None = None,
    on_windows: OnWindows | None = None,
    serial: str | None = None,
) -> Results:
    """Analyse every axis of a recording: friction per position, direction and velocity.

    An axis that cannot be analysed (a missing or dead channel, an axis that
    did not move, no window) does not stop the others: it is listed in
    ``skipped`` with the reason.

    The recording is never held whole by the analysis: it is read in passes
    of chunks, and memory grows with the windows, not with the length. A
    recording given by its directory (or a :class:`RecordingHead`) is read
    from its file (``rows`` rows per chunk; ``ncmeasure analyze`` reads it
    so); a :class:`Recording` already in memory is read as one chunk of its
    own arrays. Both give the same results.

    Args:
        recording: The recording (recorded, imported or synthetic), or its directory.
        schedule: The schedule.json of the program that ran: labels every
            window with its step, position and direction, and tells rapids
            from windows. Without it, steps and positions are clustered.
        machine: The machine file: torque constant, screw lead, travel,
            fixed-bearing end and vertical axes where the recording lacks them.
        settings: How windows are found; :class:`AnalysisSettings` defaults.
        axes: Analyse only these axes (default: every recorded axis).
        progress: Called with (stage, fraction done in 0..1); while a recording
            is read from its file, with ``reading the recording, pass N`` and
            the share of that pass read.
        rows: Rows per chunk when the recording is read from its file.
        window_times: Receives, per analysed axis, the (first, last) sample time
            of every window the friction values come from (for the report's
            raw data, :func:`~ncmeasure.report.write_report`'s ``windows``).
        on_windows: Called with every analysed axis' windows; the task it
            returns is fed the recording's rows on the readings that follow
            (:mod:`~ncmeasure.analysis.windows.watch`; the report's
            :class:`~ncmeasure.report.traces.RawTraces`). Where no reading
            follows, the recording is read once more, only the channels the
            tasks need; a recording in memory is handed over whole.
        serial: The serial number of the machine measured, for the results
            (``recording.serial``) where the recording does not carry it.

    Returns:
        The results, ready for :func:`~ncmeasure.formats.results.write_results`.
        ``recording.machine`` is the recording's machine (type) name, else the
        machine file's; ``recording.serial`` the recording's serial, else ``serial``.

    Raises:
        RecordingError: No axis could be analysed (the message lists why, axis
            by axis), or ``axes`` names an axis that was not recorded.
        ConfigError: ``serial`` is not a serial number, or the recording was made
            on a machine of another serial.
    """
    settings = settings or AnalysisSettings()
    head = (
        recording
        if isinstance(recording, Recording | RecordingHead)
        else RecordingHead.open(recording)
    )
    machine_name, serial_number = _identity(head, machine, serial)
    chosen = chosen_axes(head, axes)
    report: Progress = progress or _quiet
    passes = RecordingPasses(head, chosen, schedule, machine, settings, rows, report)
    passes.keep_held = on_windows is not None  # their last reading from the chunks held
    passes.gather_ahead &= on_windows is None  # its tasks ride each axis' own reading
    results = results_of(
        head,
        chosen,
        passes,
        schedule=schedule,
        settings=settings,
        progress=report,
        window_times=window_times,
        on_windows=on_windows,
    )
    info = results.recording.model_copy(update={"machine": machine_name, "serial": serial_number})
    return results.model_copy(update={"recording": info})


def _identity(
    head: Recording | RecordingHead, machine: MachineConfig | None, serial: str | None
) -> tuple[str | None, str | None]:
    """The machine (type) name and the serial number of the results.

    Raises:
        ConfigError: ``serial`` is not a serial number, or not the recording's.
    """
    meta = head.meta
    if serial is not None:
        check_serial(serial)
        if meta.serial is not None and meta.serial != serial:
            raise ConfigError(
                f"{head.directory}: the recording was made on machine {meta.serial!r} "
                f"(serial in its meta.json), not on {serial!r}"
            )
    name = meta.machine if meta.machine is not None else (machine.machine.name if machine else None)
    return name, meta.serial if meta.serial is not None else serial


def _common_warnings(
    head: Recording | RecordingHead, chosen: Sequence[str], schedule: Schedule | None
) -> list[str]:
    """What every axis' warnings begin with: a schedule of another program, axes not in it."""
    common: list[str] = []
    if (
        schedule is not None
        and head.meta.config_hash is not None
        and schedule.config_hash != head.meta.config_hash
    ):
        common.append(
            f"the schedule belongs to another program (config hash {schedule.config_hash}, "
            f"the recording's {head.meta.config_hash})"
        )
    if schedule is not None:
        planned = {a.name for a in schedule.axes}
        for name in chosen:
            if name not in planned:
                common.append(f"axis {name} is not in the schedule")
    return common


def results_of(
    head: Recording | RecordingHead,
    chosen: Sequence[str],
    source: AxisSource,
    *,
    schedule: Schedule | None,
    settings: AnalysisSettings,
    progress: Progress,
    window_times: dict[str, list[tuple[float, float]]] | None = None,
    on_windows: OnWindows | None = None,
) -> Results:
    """The results of the axes ``chosen`` of a recording read by ``source`` (see :func:`analyze`).

    Raises:
        RecordingError: No axis could be analysed.
    """
    common = _common_warnings(head, chosen, schedule)
    gaps, gap_samples, _ = source.gaps
    samples = source.rows
    total = samples + gap_samples
    gap_share = gap_samples / total if total else 0.0
    if gaps:
        common.append(
            f"{gap_samples} samples lost in {gaps} gap(s) ({gap_share * 100:.2g} % of the "
            "recording): windows in them are shorter or missing"
        )
    not_served = skipped_cycles(head.events)
    if not_served:
        common.append(
            f"{not_served} of them cycles the link skipped because the host fell behind "
            f"({not_served / total * 100:.2g} % of the recording): it sampled at "
            f"{(1 - not_served / total) / head.meta.nominal_period_s:.0f} Hz instead of "
            f"{1 / head.meta.nominal_period_s:.0f} Hz"
        )
    results: dict[str, AxisResult] = {}
    skipped: dict[str, str] = {}
    details: list[str] = []
    for number, name in enumerate(chosen):
        log.info("analysing axis %s of %s", name, head.directory)

        def axis_progress(stage: str, fraction: float, number: int = number) -> None:
            progress(stage, (number + fraction) / len(chosen))

        try:
            result, times = source.axis(name, axis_progress, gap_share)
        except RecordingError as exc:
            reason = exc.message.removeprefix(f"axis {name}: ")
            skipped[name] = reason
            details.append(f"axis {name}: {reason}")
            details.extend(f"  {line}" for line in exc.problems)
            log.info("axis %s not analysed: %s", name, reason)
            continue
        except (ValueError, IndexError, ArithmeticError) as exc:
            # Data this analysis did not foresee must not take the other axes with it.
            log.debug("axis %s failed", name, exc_info=True)
            reason = (
                f"the analysis failed on this axis' data ({type(exc).__name__}: {exc}); "
                "please report it with the recording (--debug shows where)"
            )
            skipped[name] = reason
            details.append(f"axis {name}: {reason}")
            continue
        if common:
            result = result.model_copy(update={"warnings": [*common, *result.warnings]})
        results[name] = result
        if window_times is not None:
            window_times[name] = times
        if on_windows is not None:
            found = AxisWindows(name, tuple(times), samples, source.start_s, source.end_s)
            source.watchers.add(functools.partial(on_windows, found))
    if not results:
        raise RecordingError(f"{head.directory}: no axis could be analysed", details)
    source.watchers.finish(source.read_channels)
    progress("done", 1.0)
    return _results(head, source, settings, results, skipped)


def _results(
    head: Recording | RecordingHead,
    source: AxisSource,
    settings: AnalysisSettings,
    axes: dict[str, AxisResult],
    skipped: dict[str, str],
) -> Results:
    meta = head.meta
    samples = source.rows
    duration = source.end_s - source.start_s if samples else 0.0
    gaps, gap_samples, gap_events = source.gaps
    total = samples + gap_samples
    return Results(
        created_utc=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        recording=RecordingInfo(
            directory=str(head.directory),
            machine=meta.machine,
            serial=meta.serial,
            start_utc=meta.start_utc,
            config_hash=meta.config_hash,
            source=meta.source,
            status=meta.status,
            samples=samples,
            duration_s=duration,
            gaps=gaps,
            gap_samples=gap_samples,
            gap_share=gap_samples / total if total else 0.0,
            gap_events=gap_events,
            skipped_cycles=skipped_cycles(head.events),
        ),
        settings=settings.model_dump(),
        axes=axes,
        skipped=skipped,
    )


def analyze_axis(
    recording: Recording,
    axis: str,
    *,
    schedule: Schedule | None = None,
    machine: MachineConfig | None = None,
    settings: AnalysisSettings | None = None,
    progress: Progress | None = None,
    gap_share: float = 0.0,
) -> AxisResult:
    """Analyse one axis of a recording in memory; see :func:`analyze`.

    ``progress`` is called with (stage, fraction of this axis done).

    Raises:
        RecordingError: The axis cannot be analysed: it lacks current or
            velocity, a channel is dead (one value in every row), it did not
            move, or no window was found. The message says why in words.
    """
    settings = settings or AnalysisSettings()
    report: Progress = progress or _quiet
    passes = RecordingPasses(recording, (axis,), schedule, machine, settings, CHUNK_ROWS, report)
    return passes.axis(axis, report, gap_share)[0]
