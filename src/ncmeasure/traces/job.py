"""The import job: one import's arguments, report and progress, and the driver that runs it.

Every importer is a function ``read(job) -> RecordingMeta`` that streams rows
into the :class:`~ncmeasure.recording.ImportSink` that :meth:`ImportJob.open_sink`
creates; :func:`run_import` runs it and turns its result into a
:class:`TraceImport`. A failed import removes everything it wrote
(:meth:`~ncmeasure.recording.ImportSink.discard`).
"""

from __future__ import annotations

import csv
import datetime as dt
import functools
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.recording import ImportSink, Recording
from ncmeasure.samples import SIGNAL_UNITS, Channel
from ncmeasure.traces.derive import DerivingSink, derived_line, needs_velocity

if TYPE_CHECKING:  # the machine-file models: exporting a recording reads no machine file
    from ncmeasure.config import MachineConfig

__all__ = [
    "ImportJob",
    "ProgressFn",
    "TraceImport",
    "check_source",
    "check_target",
    "order_channels",
    "run_import",
]

log = logging.getLogger(__name__)

ProgressFn = Callable[[int, int], None]


def order_channels(channels: Sequence[Channel], machine: MachineConfig | None) -> list[Channel]:
    """The channels in the order every importer writes them: by axis (the machine file's
    order where it names them, else as found), then by signal."""
    axes = list(dict.fromkeys(c.axis for c in channels))
    if machine is not None:
        names = [a.name for a in machine.axes]
        axes.sort(key=lambda a: names.index(a) if a in names else len(names))
    signals = list(SIGNAL_UNITS)
    return sorted(channels, key=lambda c: (axes.index(c.axis), signals.index(c.signal)))


@dataclass(frozen=True)
class TraceImport:
    """The result of an import: the new recording and what happened on the way.

    Attributes:
        directory: The new recording's directory.
        meta: Its ``meta.json`` (channels, number of samples, period, report).
        report: One sentence per fact: which trace signal became which
            channel (with unit conversions), what was not imported and why,
            invalid samples, dropped rows.
    """

    directory: Path
    meta: RecordingMeta
    report: list[str]

    @functools.cached_property
    def recording(self) -> Recording:
        """The recording, read from disk on first use (an import itself never holds it whole)."""
        return Recording.open(self.directory)


class ImportJob:
    """One import: its arguments, the report it builds and the progress it reports."""

    def __init__(
        self,
        path: Path,
        directory: Path,
        format_name: str,
        *,
        machine: MachineConfig | None,
        axis_names: Mapping[str, str] | None,
        progress: ProgressFn | None,
        measured_at: dt.datetime | None = None,
    ) -> None:
        self.path = path
        self.measured_at = measured_at
        """When the user says the machine was measured (wins over the data's date)."""
        self.start_utc: dt.datetime | None = None
        """When the data say the measurement began (None: they hold no date)."""
        self.start_source = ""
        self.directory = directory
        self.format_name = format_name
        self.machine = machine
        self.axis_names = dict(axis_names) if axis_names is not None else None
        self._progress = progress
        self.total_bytes = path.stat().st_size
        self.report: list[str] = []
        self.link: dict[str, Any] = {"type": "import", "format": format_name, "file": path.name}
        self.sink: ImportSink | None = None

    def note(self, line: str) -> None:
        """Add a sentence to the report."""
        log.info("%s: %s", self.path.name, line)
        self.report.append(line)

    def tick(self, bytes_read: int) -> None:
        """Tell the progress callback how far the import got."""
        if self._progress is not None:
            self._progress(min(bytes_read, self.total_bytes), self.total_bytes)

    def open_sink(
        self,
        channels: Sequence[Channel],
        *,
        nominal_period_s: float | None,
        start_utc: dt.datetime | None = None,
        start_source: str = "the trace's header",
    ) -> ImportSink:
        """The recording the rows go to (created on disk when the first rows arrive).

        Args:
            channels: Its columns. An axis with a position and no velocity channel gets
                its velocity derived as the rows are written (:mod:`.derive`): give
                the rows of ``channels``, the recording holds the derived one as well.
            nominal_period_s: The sample period; None: inferred from the times.
            start_utc: When the data say the measurement began (None: they hold
                no date, or :meth:`found_start` says it before the first rows).
            start_source: Where that date comes from, for the report.
        """
        derived = needs_velocity(channels)
        self.sink = (DerivingSink if derived else ImportSink)(
            self.directory,
            channels,
            machine=self.machine,
            nominal_period_s=nominal_period_s,
            what="the trace",
            source=f"import:{self.format_name}",
            notes=f"imported from {self.path.name}",
            link=self.link,
        )
        self.found_start(start_utc, start_source)
        for axis in derived:
            self.note(derived_line(axis))
        return self.sink

    def found_start(self, start_utc: dt.datetime | None, source: str) -> None:
        """The data's date of the measurement's start, found before the first rows are
        written (e.g. the first row of a date-time column); ``--measured-at`` wins."""
        if start_utc is not None and start_utc.tzinfo is None:
            start_utc = start_utc.replace(tzinfo=dt.UTC)
            source += ", no time zone: taken as UTC"
        self.start_utc, self.start_source = start_utc, source
        if self.sink is not None:
            self.sink.start_at(self.measured_at or start_utc)

    def finish(self) -> RecordingMeta:
        """Close the recording with the complete report (it is not read back)."""
        if self.sink is None:
            raise RecordingError(f"{self.path}: no samples to import")
        if isinstance(self.sink, DerivingSink):
            self.sink.drain()  # the last rows, before their values are counted
        for line in self.sink.validity_lines():
            self.note(line)
        self.note(self._start_line())
        self.link["report"] = list(self.report)
        meta = self.sink.close("complete", link=dict(self.link))
        self.tick(self.total_bytes)  # the whole file is done, even if an end marker stopped reading
        return meta

    def _start_line(self) -> str:
        """The report's sentence on when the machine was measured, and how that is known."""
        found = self.start_utc
        if self.measured_at is not None:
            line = f"measured at {_utc_words(self.measured_at)} (--measured-at)"
            if found is not None and found != self.measured_at:
                line += f"; the data say {_utc_words(found)} ({self.start_source})"
            return line
        if found is not None:
            return f"measured at {_utc_words(found)} (from {self.start_source})"
        return (
            "the data hold no date: the measurement's time is unknown (give it with "
            "--measured-at; the fleet store needs it)"
        )

    def discard(self) -> None:
        """Remove what this import wrote."""
        if self.sink is not None:
            self.sink.discard()


def _utc_words(when: dt.datetime) -> str:
    return when.astimezone(dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def check_source(path: Path) -> None:
    """Fail with a clear message when ``path`` is not a file that can be imported."""
    if not path.is_file():
        if path.is_dir():
            raise RecordingError(f"{path}: is a directory, expected a trace file")
        raise RecordingError(f"{path}: no such file")


def run_import(job: ImportJob, read: Callable[[ImportJob], RecordingMeta]) -> TraceImport:
    """Run an importer on ``job``; on any failure remove what it wrote.

    Returns:
        The recording ``read`` finished and the job's report.

    Raises:
        RecordingError: What ``read`` raised, or a read error of the file
            (not text, cannot be read) turned into one.
    """
    try:
        meta = read(job)
    except BaseException as exc:
        job.discard()
        if isinstance(exc, UnicodeDecodeError):
            raise RecordingError(f"{job.path}: not a text file") from exc
        if isinstance(exc, csv.Error):
            raise RecordingError(f"{job.path}: cannot be split into cells ({exc})") from exc
        if isinstance(exc, OSError) and not isinstance(exc, RecordingError):
            raise RecordingError(f"{job.path}: cannot be read ({exc.strerror or exc})") from exc
        raise
    log.info(
        "imported %s (%s) into %s: %d samples",
        job.path,
        job.format_name,
        job.directory,
        meta.samples,
    )
    return TraceImport(job.directory, meta, job.report)


def check_target(directory: Path) -> None:
    """Fail before reading a large trace when the recording could not be written anyway."""
    if directory.exists():
        if not directory.is_dir():
            raise RecordingError(f"{directory}: exists and is not a directory")
        if any(directory.iterdir()):
            raise RecordingError(
                f"{directory}: directory is not empty; a recording needs a new or empty directory"
            )
