"""A recording read in passes shared by all its axes: statistics, sweep, then each axis' windows.

:class:`RecordingPasses` reads a recording the one way the analysis reads
one: chunk by chunk, keeping only the samples around the windows. A
recording given by its directory (a :class:`~ncmeasure.recording.RecordingHead`)
is read from ``samples.bin`` (:func:`~ncmeasure.recording.iter_chunks`, with
the progress of every pass); a :class:`~ncmeasure.recording.Recording` already
in memory is one chunk of its own arrays. The passes:

1. the whole-signal statistics of every axis
   (:mod:`~ncmeasure.analysis.windows.scan`);
2. where the velocity is coarse, the agreement of the position's velocity
   with the readings;
3. the sweep for the marker runs and the stretches of constant command
   (:mod:`~ncmeasure.analysis.windows.chunked`), with the holes of the time
   axis (:func:`recording_gaps`): both ride the readings of the statistics
   once the sample period is known (:func:`~ncmeasure.analysis.windows.chunked.early_sweep_task`),
   a reading of their own only where the statistics end first;
4. per axis, the samples of its stretches (:meth:`RecordingPasses.axis`).

Work that needs an axis' windows (``on_windows``) rides along the passes that
follow them (:mod:`~ncmeasure.analysis.windows.watch`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.axis import (
    AxisFacts,
    AxisFound,
    Progress,
    axis_facts,
    axis_summary,
    check_channels,
    check_velocity,
    dead_range,
    finish_axis,
    implausible_checker,
    implausible_lines,
)
from ncmeasure.analysis.windows.chunked import ChunkedFinder, early_sweep_task
from ncmeasure.analysis.windows.find import recording_chunks
from ncmeasure.analysis.windows.scan import AxisStatistics, Rows, axes_statistics_along
from ncmeasure.analysis.windows.settings import SegmentSettings
from ncmeasure.analysis.windows.signals import HoleCounter
from ncmeasure.analysis.windows.streaming import run_tasks
from ncmeasure.analysis.windows.watch import Watchers
from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.formats.results import AxisResult
from ncmeasure.formats.schedule import AxisSummary, Schedule
from ncmeasure.recording import SAMPLES_FILE, Recording, RecordingHead, RowChunk, iter_chunks
from ncmeasure.samples import LinkEvent
from ncmeasure.validity import Implausible

__all__ = ["RecordingPasses", "recording_gaps", "skipped_cycles"]


def recording_gaps(recording: Recording) -> tuple[int, int, int]:
    """Gaps of a recording: holes in its time axis, samples lost in them, gap events.

    A hole is a time step longer than 1.5 times the regular period around it, the
    median of the steps on either side
    (:class:`~ncmeasure.analysis.windows.signals.HoleCounter`): the files of an import
    may differ in sample period, and a file sampled more slowly is no run of holes,
    while an outage broken by a sample is two holes. It lost round(step / regular
    period) − 1 samples. The step into a segment (the start of another file of an
    import of several, an ``info`` event with ``details["segment"]``) is no hole. Where
    the link reported more lost samples in its gap events than the time axis shows (a
    gap at the very end), the larger count is taken.
    """
    counter = HoleCounter(recording.meta.nominal_period_s, segment_starts(recording.events))
    counter.feed(recording.time_s)
    holes, lost = counter.finish()
    return _with_events(holes, lost, recording.events)


def skipped_cycles(events: Sequence[LinkEvent]) -> int:
    """Of the samples the gap events lost, the cycles the link skipped because the host
    fell behind (their ``skipped_cycles``: SYNC cycles a CANopen producer could not send)."""
    return sum(int(e.details.get("skipped_cycles", 0)) for e in events if e.kind == "gap")


def segment_starts(events: Sequence[LinkEvent]) -> NDArray[np.float64]:
    """The times where a segment begins (a file of an import of several)."""
    return np.array(
        [e.time_s for e in events if e.kind == "info" and "segment" in e.details], dtype=np.float64
    )


def _with_events(holes: int, lost: int, events: Sequence[LinkEvent]) -> tuple[int, int, int]:
    gap_events = [e for e in events if e.kind == "gap"]
    reported = sum(e.lost_samples for e in gap_events)
    return max(holes, len(gap_events)), max(lost, reported), len(gap_events)


def _holes_task(
    period: float, starts: NDArray[np.float64]
) -> Generator[Callable[[RowChunk], None], None, tuple[int, int]]:
    """Holes of the time axis and the samples lost in them, chunk by chunk (as recording_gaps;
    the step into a segment at ``starts`` is none)."""
    counter = HoleCounter(period, starts)
    yield lambda chunk: counter.feed(chunk.time_s)
    return counter.finish()


def _row_span(read: Callable[[], Iterator[RowChunk]]) -> tuple[int, float, float]:
    """Rows, first and last time of a recording (one pass)."""
    rows, start, end = 0, math.nan, math.nan
    for chunk in read():
        if len(chunk.time_s):
            if rows == 0:
                start = float(chunk.time_s[0])
            end = float(chunk.time_s[-1])
        rows += len(chunk.time_s)
    return rows, start, end


GATHER_AHEAD_BYTES = 256 << 20
"""Most the slices of every axis' windows may take together to be gathered on one reading.

A recording read per pass (longer than :data:`HOLD_BYTES`) reads each axis'
slices once more; where the slices of all its axes take at most this, they are
gathered on a single reading shared by the axes instead (4 h of three axes:
about 60 MB an axis). Longer ones keep one axis' slices at a time."""

HOLD_BYTES = 512 << 20
"""Largest recording (the channels the passes read, as float64) whose chunks are held.

An analysis reads its rows in several passes (statistics, sweep, each axis'
slices). A recording whose chunks fit this is read from ``samples.bin`` once:
the first reading keeps its chunks and the later ones go over them (an hour
of three axes at 1 kHz, 16 columns, is 454 MB). A longer one is read again
for every pass, so that memory stays bounded whatever the length."""


class _FileReader:
    """The rows of a recording's file, chunk by chunk, with the progress of every pass.

    A recording of at most :data:`HOLD_BYTES` is read once: the chunks of the
    first whole reading are kept and given again to every later pass.
    """

    def __init__(
        self, head: RecordingHead, channels: tuple[str, ...], rows: int, progress: Progress
    ) -> None:
        self.head = head
        self.channels = channels
        self.column = {name: k for k, name in enumerate(channels)}
        self.chunk_rows = rows
        self.progress = progress
        self.problems: list[str] = []
        self.verified: set[int] = set()  # frames checked once for all passes
        # Progress while reading: the pass and the share of its rows read so far.
        samples_bytes = (head.directory / SAMPLES_FILE).stat().st_size
        self.expected = max(1, samples_bytes // (8 * (1 + len(head.channels))))
        self.passes = 0
        self.chunk_times: dict[int, float] = {}  # first row -> its time, of every chunk read
        self.holding = self.expected * 8 * (1 + len(channels)) <= HOLD_BYTES
        self.held: list[RowChunk] | None = None  # the chunks of a whole reading, kept

    def chunks(self) -> Iterator[RowChunk]:
        """One reading of every row of the channels the passes need."""
        if self.held is not None:
            return iter(self.held)
        self.problems = []
        chunks = iter_chunks(
            self.head.directory,
            self.chunk_rows,
            self.channels,
            problems=self.problems,
            verified=self.verified,
        )
        return self._kept(chunks) if self.holding else chunks

    def _kept(self, chunks: Iterator[RowChunk]) -> Iterator[RowChunk]:
        """The chunks, kept for the passes that follow once the reading went through."""
        kept: list[RowChunk] = []
        for chunk in chunks:
            kept.append(chunk)
            yield chunk
        self.held = kept

    def release(self) -> None:
        """Let go of the chunks held: the passes are done."""
        self.held = None
        self.holding = False

    def seen(self, chunk: RowChunk) -> None:
        """Note a chunk read: the progress of the pass, the time of its first row."""
        if chunk.first == 0:
            self.passes += 1
        if len(chunk.time_s):
            self.chunk_times[chunk.first] = float(chunk.time_s[0])
        done = (chunk.first + len(chunk.time_s)) / self.expected
        self.progress(f"reading the recording, pass {self.passes}", min(1.0, done))

    def read_channels(
        self, wanted: tuple[str, ...], between_s: tuple[float, float] | None
    ) -> Iterator[RowChunk]:
        """The rows of some channels, all, or from the chunk before ``between_s`` to its end."""
        # With a stretch of time: from the last chunk that began before it (its
        # first row as the passes noted it; the frames before are not read) up
        # to the one that holds its end. Times increase strictly.
        first_row = 0
        if between_s is not None:
            begun = [row for row, t in self.chunk_times.items() if t < between_s[0]]
            first_row = max(begun, default=0)
        chunks: Iterable[RowChunk]
        if self.held is not None:
            # The chunks are still held: those from first_row on, not the file again.
            index = [self.column[name] for name in wanted]
            chunks = (
                RowChunk(c.first, c.time_s, c.values[:, index])
                for c in self.held
                if c.first >= first_row
            )
        else:
            chunks = iter_chunks(
                self.head.directory,
                self.chunk_rows,
                wanted,
                verified=self.verified,
                first_row=first_row,
            )
        for chunk in chunks:
            if between_s is not None and len(chunk.time_s) and chunk.time_s[0] > between_s[1]:
                return
            done = (chunk.first + len(chunk.time_s)) / self.expected
            self.progress("reading the recording once more", min(1.0, done))
            yield chunk

    def done(self, rows: int) -> None:
        """Tell the recording's head the rows read and what was wrong with its samples."""
        self.head.samples_read(rows, self.problems)


class _MemoryReader:
    """The rows of a recording in memory: one chunk of its own arrays, read at once."""

    def __init__(self, recording: Recording) -> None:
        self.recording = recording
        self.column = {name: k for k, name in enumerate(recording.channel_names)}
        self.chunk_rows = max(len(recording), 1)
        # One reading: the one chunk, the same every time (none for an empty recording).
        self.chunks = recording_chunks(recording)

    def seen(self, chunk: RowChunk) -> None:
        """Nothing to report: the rows are in memory."""

    def read_channels(
        self, wanted: tuple[str, ...], between_s: tuple[float, float] | None
    ) -> Iterable[RowChunk]:
        """The channels wanted, of every row, as one chunk."""
        whole = self.recording
        index = [whole.channel_names.index(name) for name in wanted]
        return [RowChunk(0, whole.time_s, whole.values[:, index])]

    def done(self, rows: int) -> None:
        """The recording's problems were noted when it was read."""


class RecordingPasses:
    """The axes of a recording found in passes over its rows, memory bounded by their windows.

    The constructor reads the recording in a few passes shared by all axes;
    :meth:`axis` then reads the slices of each axis' windows and gives its
    result. What stops an axis early is kept and raised by :meth:`axis`, in
    the order the analysis of that axis meets it.

    Attributes:
        rows: Rows of the recording.
        start_s: Time of its first row (NaN without rows).
        end_s: Time of its last row.
        gaps: Holes in the time axis, samples lost in them, gap events.
        watchers: The tasks of ``on_windows``, fed on the passes that follow.
    """

    def __init__(
        self,
        head: Recording | RecordingHead,
        axes: Sequence[str],
        schedule: Schedule | None,
        machine: MachineConfig | None,
        settings: SegmentSettings,
        rows: int,
        progress: Progress,
    ) -> None:
        self.head = head
        self.settings = settings
        self.errors: dict[str, Exception] = {}
        self.facts: dict[str, AxisFacts] = {}
        self.summary: dict[str, AxisSummary | None] = {}
        self.checker: dict[str, Implausible] = {}
        self.finders: dict[str, ChunkedFinder] = {}
        ready = self._ready(axes, schedule, machine)
        bounds = {n: b for c in self.checker.values() for n, b in c.limits.items()}
        reader: _FileReader | _MemoryReader = (
            _MemoryReader(head)
            if isinstance(head, Recording)
            else _FileReader(head, tuple(bounds), rows, progress)
        )
        self.read_channels = reader.read_channels
        # Tasks of on_windows ride along the readings after their axis' windows are found.
        self.watchers = Watchers(reader.column)

        def read() -> Iterator[RowChunk]:
            for chunk in self.watchers.reading(reader.chunks()):
                reader.seen(chunk)
                yield chunk

        kept = isinstance(reader, _FileReader) and reader.holding
        source = Rows(read, reader.column, reader.chunk_rows, bounds, kept=kept)
        holes_task = _holes_task(head.meta.nominal_period_s, segment_starts(head.events))

        def along(
            first: Mapping[str, AxisStatistics], period: Callable[[], float | None]
        ) -> dict[str, Generator[Callable[[RowChunk], None], None, Any]]:
            # The sweep of every axis and the holes ride the statistics' readings.
            riders: dict[str, Generator[Callable[[RowChunk], None], None, Any]] = {"": holes_task}
            for axis in ready:
                riders[axis] = early_sweep_task(axis, first[axis], source, settings, period)
            return riders

        swept: dict[str, Any] = {}
        if ready:
            self.statistics, swept = axes_statistics_along(source, ready, along)
        else:
            self.statistics = {}
        for axis in ready:
            try:
                self.finders[axis] = self._finder(axis, source, schedule)
            except (RecordingError, ValueError, IndexError, ArithmeticError) as exc:
                self.errors[axis] = exc
        agreeing = {a: f.agreement_task() for a, f in self.finders.items() if f.needs_agreement}
        if agreeing:
            run_tasks(read, agreeing)
        tasks: dict[str, Generator[Callable[[RowChunk], None], None, Any]] = {}
        for axis, finder in self.finders.items():
            if swept.get(axis) is not None:
                finder.take_sweep(swept[axis])
            else:
                tasks[axis] = finder.sweep_task()
        if "" not in swept:
            tasks[""] = holes_task
        found = run_tasks(read, tasks) if tasks else {}
        holes, lost = swept[""] if "" in swept else found[""]
        first = next(iter(self.statistics.values()), None)
        if first is not None:
            self.rows, self.start_s, self.end_s = first.rows, first.start_s, first.end_s
        else:
            self.rows, self.start_s, self.end_s = _row_span(read)
        self.gaps = _with_events(holes, lost, head.events)
        reader.done(self.rows)
        # The chunks held for the passes go once every axis' slices are read.
        self._unread = set(self.finders)
        # True: the chunks held stay until the passes are dropped, for the tasks of
        # on_windows that need one more reading (read_channels); else they go once
        # every axis' slices are read.
        self.keep_held = False
        # A file read per pass: the slices of every axis gathered on one reading where
        # they fit GATHER_AHEAD_BYTES (not with tasks of on_windows: they ride the
        # readings that follow each axis' windows).
        self.gather_ahead = isinstance(reader, _FileReader) and not reader.holding
        self._read = read
        self._release: Callable[[], None] | None = None
        if isinstance(reader, _FileReader):
            file_reader = reader

            def release() -> None:
                file_reader.release()
                source.forget()

            self._release = release

    def _ready(
        self, axes: Sequence[str], schedule: Schedule | None, machine: MachineConfig | None
    ) -> list[str]:
        """The axes that have the channels they need; their facts, schedule and checks."""
        names = self.head.channel_names
        ready: list[str] = []
        for axis in axes:
            try:
                check_channels(axis, names)
            except RecordingError as exc:
                self.errors[axis] = exc
                continue
            self.summary[axis] = axis_summary(schedule, axis)
            self.facts[axis] = axis_facts(axis, self.head, machine, self.summary[axis])
            self.checker[axis] = implausible_checker(names, axis, self.facts[axis])
            ready.append(axis)
        return ready

    def _finder(self, axis: str, source: Rows, schedule: Schedule | None) -> ChunkedFinder:
        stats = self.statistics[axis]
        finite = stats.finite.get("velocity_mm_min", 0)
        low, high = stats.low["velocity_mm_min"], stats.high["velocity_mm_min"]
        moving = False
        if "position_mm" in stats.finite:
            duration = stats.end_s - stats.start_s if stats.rows > 1 else 0.0
            if duration > 0 and stats.finite["position_mm"]:
                span = stats.high["position_mm"] - stats.low["position_mm"]
                moving = span / duration * 60.0 > self.settings.standstill_mm_min
        check_velocity(
            axis,
            dead_range(axis, "velocity_mm_min", stats.rows, finite, low, high, "mm/min"),
            moving,
            low if finite else None,
        )
        return ChunkedFinder(
            axis,
            stats,
            source,
            schedule,
            self.settings,
            self.facts[axis].rapid_velocity_mm_min,
        )

    def _gather_ahead(self) -> None:
        """The slices of the first way of every axis, on one reading, where they fit."""
        wanted = {a: f.first_stretches() for a, f in self.finders.items() if a not in self.errors}
        ahead = {a: s for a, s in wanted.items() if s}
        size = sum(self.finders[a].slice_bytes(s) for a, s in ahead.items())
        if len(ahead) < 2 or size > GATHER_AHEAD_BYTES:
            return
        feeds = [self.finders[a].gather_ahead(s) for a, s in ahead.items()]
        for chunk in self._read():
            for feed in feeds:
                feed(chunk)

    def found(self, axis: str, progress: Progress) -> AxisFound:
        """The axis' windows, the current of each, and what its whole signals said."""
        if axis in self.errors:
            raise self.errors[axis]
        if self.gather_ahead:
            self.gather_ahead = False
            self._gather_ahead()
        stats = self.statistics[axis]
        finder = self.finders[axis]
        progress(f"axis {axis}: windows", 0.0)
        try:
            segmentation = finder.run()
        except RecordingError:
            finder.release()
            raise
        finally:
            self._unread.discard(axis)
            if not self._unread and self._release is not None and not self.keep_held:
                self._release()
        checker = self.checker[axis]
        scanned = stats.implausible
        if scanned is not None:
            # In the channel order of the check, whatever order the chunks met them.
            checker.counts = {n: scanned.counts[n] for n in checker.limits if n in scanned.counts}
            checker.first = {n: scanned.first[n] for n in checker.limits if n in scanned.first}
        counts, lines = implausible_lines(checker, self.head.meta)
        window_current = [finder.window_current(w.start, w.stop) for w in segmentation.windows]
        times = [finder.window_times(w.start, w.stop) for w in segmentation.windows]
        finder.release()
        return AxisFound(
            segmentation=segmentation,
            window_current=window_current,
            window_times=times,
            current_dead=dead_range(
                axis,
                "current_a",
                stats.rows,
                stats.finite.get("current_a", 0),
                stats.low.get("current_a", math.nan),
                stats.high.get("current_a", math.nan),
                "A",
            ),
            current_quantum_a=stats.current_quantum_a,
            implausible_counts=counts,
            implausible_lines=lines,
        )

    def axis(
        self, axis: str, progress: Progress, gap_share: float
    ) -> tuple[AxisResult, list[tuple[float, float]]]:
        """The axis' result and the (first, last) sample time of every window used.

        Raises:
            RecordingError: The axis cannot be analysed (the message says why).
        """
        found = self.found(axis, progress)
        result = finish_axis(
            axis,
            self.facts[axis],
            self.summary[axis],
            found,
            report=progress,
            gap_share=gap_share,
        )
        return result, found.window_times
