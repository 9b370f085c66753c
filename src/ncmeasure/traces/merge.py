"""Row merging: the rows of the recording, built from a trace's records or timelines.

Two ways of building rows exist, matching the two ways controllers write traces:

* :class:`CarryForward` for record-oriented traces (Sinumerik) where a record
  holds only the signals sampled at that instant and the others keep their
  last value;
* :class:`SeriesMerge` for column-oriented traces (TwinCAT Scope, TNCscope)
  where every channel has its own timeline, merged on the union of the times
  as the samples arrive (:func:`merge_series` is the same merge over whole
  arrays, its definition).

Both hand their rows to a :class:`~ncmeasure.recording.ImportSink` a chunk
at a time, so an import holds a bounded part of the trace in memory.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import BinaryIO, Final

import numpy as np
from numpy.typing import NDArray

from ncmeasure.errors import RecordingError
from ncmeasure.recording import ImportSink
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.text import INVALID_ABOVE, is_invalid

__all__ = [
    "CHUNK_ROWS",
    "MERGE_ROWS",
    "SPILL_ROWS",
    "CarryForward",
    "Series",
    "SeriesMerge",
    "merge_series",
]

#: Rows handed to the recording at a time: bounds the memory of a streaming import.
CHUNK_ROWS: Final = 8192
#: Rows merged at a time from column-oriented traces (:class:`SeriesMerge`).
MERGE_ROWS: Final = 1 << 16
#: Samples of a channel that runs ahead of the others kept in memory; more wait on disk.
SPILL_ROWS: Final = 1 << 16


class CarryForward:
    """Rows from records that hold only some signals: the others keep their last value.

    A record before every channel has had a value is dropped (counted in
    :attr:`dropped_leading`). An invalid sample (:func:`is_invalid`) makes its
    channel NaN until the next valid value and is counted per channel.
    """

    def __init__(
        self,
        sink: ImportSink,
        names: Sequence[str],
        factors: Sequence[float],
        chunk_rows: int | None = None,
    ) -> None:
        self._sink = sink
        self.names = list(names)
        self._factors = list(factors)
        self._chunk_rows = chunk_rows or CHUNK_ROWS  # read now: tests make it small
        self._current = [math.nan] * len(names)
        self._seen = [False] * len(names)
        self._unseen = len(names)
        self._times: list[float] = []  # the records of commit() not handed over
        self._rows: list[list[float]] = []
        # the records of commit_block() not handed over (before those of commit())
        self._parts: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        self._part_rows = 0
        self._last_time = -math.inf
        self.records = 0
        self.dropped_leading = 0
        self.first_complete_s: float | None = None
        self.invalid = [0] * len(names)
        self.first_invalid: list[str | None] = [None] * len(names)

    def set(self, column: int, raw: float, where: Callable[[], str]) -> None:
        """Give ``column`` a new value (as the trace writes it) in the current record."""
        if not self._seen[column]:
            self._seen[column] = True
            self._unseen -= 1
        if is_invalid(raw):
            self.invalid[column] += 1
            if self.first_invalid[column] is None:
                self.first_invalid[column] = where()
            self._current[column] = math.nan
        else:
            self._current[column] = raw * self._factors[column]

    def commit(self, time_s: float, where: Callable[[], str]) -> None:
        """End the current record at ``time_s``.

        Raises:
            RecordingError: The time is not a finite number or not later than
                the record before.
        """
        if not math.isfinite(time_s):
            raise RecordingError(f"{where()}: time {time_s!r} is not a finite number")
        if not time_s > self._last_time:
            raise RecordingError(
                f"{where()}: time {time_s!r} s is not later than the record before "
                f"({self._last_time!r} s); times must increase"
            )
        self._last_time = time_s
        self.records += 1
        if self._unseen:
            self.dropped_leading += 1
            return
        if self.first_complete_s is None:
            self.first_complete_s = time_s
        self._times.append(time_s)
        self._rows.append(self._current.copy())
        if self._part_rows + len(self._times) >= self._chunk_rows:
            self.flush()

    def commit_block(
        self, time_s: NDArray[np.float64], raw: NDArray[np.float64], where: Callable[[int], str]
    ) -> None:
        """:meth:`set` and :meth:`commit` for many records at once, with the same outcome.

        Args:
            time_s: The records' times.
            raw: One row per record, one column per channel, as the trace writes
                them; NaN where the record holds no new sample of the channel (an
                invalid sample must be given as a number, e.g. the marker, or inf).
            where: ``where(index)`` names the place of record ``index``, for messages.

        Raises:
            RecordingError: A time is not a finite number or not later than the
                record before (raised as :meth:`commit` raises it, after the records
                before it were taken).
        """
        count = len(time_s)
        if count == 0:
            return
        steps = np.diff(time_s, prepend=self._last_time)
        bad = ~np.isfinite(time_s) | ~(steps > 0)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            self.commit_block(time_s[:first], raw[:first], where)
            for column in np.flatnonzero(~np.isnan(raw[first])).tolist():
                self.set(column, float(raw[first, column]), lambda: where(first))
            self.commit(float(time_s[first]), lambda: where(first))  # raises
        self._last_time = float(time_s[-1])
        self.records += count
        present = ~np.isnan(raw)
        with np.errstate(invalid="ignore"):
            invalid = present & ~(np.abs(raw) < INVALID_ABOVE)
            filled = raw * np.asarray(self._factors, dtype=np.float64)
        if invalid.any():
            filled[invalid] = np.nan
            for column in np.flatnonzero(invalid.any(axis=0)).tolist():
                hits = invalid[:, column]
                self.invalid[column] += int(np.count_nonzero(hits))
                if self.first_invalid[column] is None:
                    self.first_invalid[column] = where(int(np.argmax(hits)))
        # a record without a sample of a channel holds its last one, or the one from
        # before the block (a channel sampled in every record has nothing to fill)
        has = present.any(axis=0)
        first_sample = np.where(has, present.argmax(axis=0), count)
        rows = np.arange(count)
        for column in np.flatnonzero(~present.all(axis=0)).tolist():
            latest = np.maximum.accumulate(np.where(present[:, column], rows, -1))
            held = filled[np.maximum(latest, 0), column]
            held[: first_sample[column]] = self._current[column]
            filled[:, column] = held
        # a record is kept once every channel has had a value
        seen = np.asarray(self._seen)
        start = int(np.where(seen, 0, first_sample).max())  # count: none complete
        self._current = filled[-1].tolist()
        self._seen = (seen | has).tolist()
        self._unseen = len(self._seen) - sum(self._seen)
        kept = count - start
        self.dropped_leading += start
        if not kept:
            return
        if self.first_complete_s is None:
            self.first_complete_s = float(time_s[start])
        self._append_rows(time_s[start:], filled[start:])

    def _append_rows(self, time_s: NDArray[np.float64], rows: NDArray[np.float64]) -> None:
        """Collect rows and hand them over in chunks of the same size as :meth:`commit` does;
        what is left waits as arrays, not as Python floats."""
        self._python_rows_to_parts()
        at = 0
        while self._part_rows + len(time_s) - at >= self._chunk_rows:
            take = self._chunk_rows - self._part_rows
            self._parts.append((time_s[at : at + take], rows[at : at + take]))
            self._hand_over()
            at += take
        if at < len(time_s):
            self._parts.append((time_s[at:], rows[at:]))
            self._part_rows += len(time_s) - at

    def _python_rows_to_parts(self) -> None:
        if self._times:
            rows = np.array(self._rows, dtype=np.float64).reshape(len(self._times), len(self.names))
            self._parts.append((np.array(self._times, dtype=np.float64), rows))
            self._part_rows += len(self._times)
            self._times, self._rows = [], []

    def _hand_over(self) -> None:
        times = np.concatenate([t for t, _ in self._parts])
        values = np.concatenate([v for _, v in self._parts])
        self._parts, self._part_rows = [], 0
        self._sink.append(times, values)

    def flush(self) -> None:
        """Hand the collected rows to the recording."""
        self._python_rows_to_parts()
        if self._parts:
            self._hand_over()

    def missing(self) -> list[str]:
        """The channels that never had a value."""
        return [n for n, seen in zip(self.names, self._seen, strict=True) if not seen]

    def summarize(self, job: ImportJob, unit: str = "records") -> None:
        """Report dropped leading rows and invalid samples."""
        if self.dropped_leading and self.first_complete_s is not None:
            job.note(
                f"{self.dropped_leading} leading {unit} dropped: not every channel had a value "
                f"before t = {self.first_complete_s:g} s"
            )
        for name, count, first in zip(self.names, self.invalid, self.first_invalid, strict=True):
            if count:
                job.note(
                    f"{name}: {count} invalid sample(s) (controller's invalid-value marker) "
                    f"stored as NaN until the next valid value; first at {first}"
                )


@dataclass(frozen=True)
class Series:
    """One channel of a column-oriented trace: its own times and values."""

    name: str
    time_s: NDArray[np.float64]
    values: NDArray[np.float64]
    factor: float = 1.0


def merge_series(
    series: Sequence[Series], job: ImportJob
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rows on the union of the channels' times; each channel holds its last value.

    Rows before every channel has a value and after the first channel ends
    are dropped (a held value is not extrapolated past a channel's end);
    invalid samples become NaN. Both are reported.

    Raises:
        RecordingError: A channel has no valid time.
    """
    for s in series:
        if len(s.time_s) == 0:
            raise RecordingError(f"{job.path}: channel {s.name} holds no samples")
    start = max(float(s.time_s[0]) for s in series)
    end = min(float(s.time_s[-1]) for s in series)
    all_times = np.unique(np.concatenate([s.time_s for s in series]))
    keep = (all_times >= start) & (all_times <= end)
    before = int(np.count_nonzero(all_times < start))
    after = int(np.count_nonzero(all_times > end))
    times = all_times[keep]
    values = np.empty((len(times), len(series)), dtype=np.float64)
    for column, s in enumerate(series):
        index = np.searchsorted(s.time_s, times, side="right") - 1
        raw = np.asarray(s.values, dtype=np.float64)
        bad = ~np.isfinite(raw) | (np.abs(raw) >= INVALID_ABOVE)
        column_values = raw * s.factor
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            job.note(
                f"{s.name}: {int(bad.sum())} invalid sample(s) stored as NaN until the next "
                f"valid value; first at t = {float(s.time_s[first]):g} s"
            )
            column_values[bad] = np.nan
        values[:, column] = column_values[index]
    rates = {len(s.time_s) for s in series}
    if len(rates) > 1 or any(not np.array_equal(series[0].time_s, s.time_s) for s in series):
        job.note(
            f"channels have different timelines: merged on the union of their times "
            f"({len(times)} rows); each channel holds its last value between its samples"
        )
    if before:
        job.note(
            f"{before} leading row(s) dropped: not every channel had a value before t = {start:g} s"
        )
    if after:
        job.note(f"{after} trailing row(s) dropped: a channel ends at t = {end:g} s")
    return times, values


class _SampleQueue:
    """One channel's samples waiting to be merged, oldest first; beyond a bound, on disk.

    A channel of a column-oriented trace can run ahead of the others in the
    file (a 2 ms channel beside 1 ms channels gets twice the time per row), so
    its samples wait until the others catch up: up to ``spill_rows`` in
    memory, the older ones in an unnamed temporary file, read back in order.
    """

    def __init__(self, spill_rows: int) -> None:
        self._spill_rows = spill_rows
        self._front = np.empty((0, 2), dtype=np.float64)  # the oldest, ready to be read
        self._file: BinaryIO | None = None
        self._file_rows = 0  # rows in the file not read back yet
        self._read_at = 0
        self._back: list[NDArray[np.float64]] = []  # the newest, after the file's
        self._back_rows = 0

    def __len__(self) -> int:
        return len(self._front) + self._file_rows + self._back_rows

    def push(self, time_s: NDArray[np.float64], values: NDArray[np.float64]) -> None:
        """Add samples later than every sample queued before."""
        self._back.append(np.column_stack([time_s, values]))
        self._back_rows += len(time_s)
        if self._back_rows > self._spill_rows:
            if self._file is None:
                self._file = tempfile.TemporaryFile(prefix="ncmeasure-merge-")  # noqa: SIM115
            self._file.seek(0, 2)
            for block in self._back:
                self._file.write(np.ascontiguousarray(block).tobytes())
            self._file_rows += self._back_rows
            self._back, self._back_rows = [], 0

    def peek(self, limit: int) -> NDArray[np.float64]:
        """Up to ``limit`` of the oldest samples (rows of time, value), left in the queue."""
        parts = [self._front]
        have = len(self._front)
        if have < limit and self._file_rows:
            assert self._file is not None
            count = min(limit - have, self._file_rows)
            self._file.seek(self._read_at)
            data = self._file.read(count * 16)
            parts.append(np.frombuffer(data, dtype=np.float64).reshape(count, 2))
            self._read_at += count * 16
            self._file_rows -= count
            have += count
            if not self._file_rows:  # all read back: the file starts again from empty
                self._file.seek(0)
                self._file.truncate()
                self._read_at = 0
        if have < limit and not self._file_rows and self._back:
            parts.extend(self._back)
            self._back, self._back_rows = [], 0
        if len(parts) > 1:
            self._front = np.concatenate(parts)
        return self._front[:limit]

    def consume(self, count: int) -> None:
        """Drop the ``count`` oldest samples (after :meth:`peek`)."""
        self._front = self._front[count:]

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class SeriesMerge:
    """:func:`merge_series` as a stream: samples go in channel by channel, rows come out.

    Channels hand over their samples (times strictly increasing per channel)
    in any portions; a row at a time of the union is written once every
    channel has reached that time, so a channel ahead waits (on disk beyond
    ``spill_rows``) and memory stays bounded by the portions. The rows, the
    values and the report sentences are exactly those of :func:`merge_series`
    over all samples at once; :meth:`finish` adds the sentences.
    """

    def __init__(
        self,
        sink: ImportSink,
        names: Sequence[str],
        factors: Sequence[float],
        *,
        batch_rows: int,
        spill_rows: int,
    ) -> None:
        self._sink = sink
        self.names = list(names)
        self._factors = list(factors)
        self._batch_rows = batch_rows
        self._queues = [_SampleQueue(spill_rows) for _ in names]
        self._first = [math.nan] * len(names)
        self._latest = [-math.inf] * len(names)
        self._samples = [0] * len(names)
        self._carry = [math.nan] * len(names)
        self._invalid = [0] * len(names)
        self._first_invalid_s = [math.nan] * len(names)
        self._waiting = len(names)  # channels without a sample yet
        self._start = math.nan
        self.rows = 0
        self._union = 0
        self._before = 0

    def add(self, column: int, time_s: NDArray[np.float64], raw: NDArray[np.float64]) -> None:
        """Hand over samples of a channel, in the trace's unit (later than its samples before)."""
        if len(time_s) == 0:
            return
        raw = np.asarray(raw, dtype=np.float64)
        bad = ~np.isfinite(raw) | (np.abs(raw) >= INVALID_ABOVE)
        values = raw * self._factors[column]
        if bad.any():
            if not self._invalid[column]:
                self._first_invalid_s[column] = float(time_s[int(np.flatnonzero(bad)[0])])
            self._invalid[column] += int(bad.sum())
            values[bad] = np.nan
        if not self._samples[column]:
            self._first[column] = float(time_s[0])
            self._waiting -= 1
            if not self._waiting:
                self._start = max(self._first)
        self._samples[column] += len(time_s)
        self._latest[column] = float(time_s[-1])
        self._queues[column].push(np.asarray(time_s, dtype=np.float64), values)

    def flush(self) -> None:
        """Write the rows up to the time that every channel has reached."""
        if not self._waiting:
            self._drain(min(self._latest), write=True)

    def finish(self, job: ImportJob) -> None:
        """Write the last rows, drop those after the first channel's end, report.

        Raises:
            RecordingError: A channel has no sample.
        """
        try:
            for name, count in zip(self.names, self._samples, strict=True):
                if not count:
                    raise RecordingError(f"{job.path}: channel {name} holds no samples")
            end = min(self._latest)
            self._drain(end, write=True)
            after = self._union
            self._drain(math.inf, write=False)  # after the end: only counted
            after = self._union - after
        finally:
            self.close()
        for name, count, first in zip(
            self.names, self._invalid, self._first_invalid_s, strict=True
        ):
            if count:
                job.note(
                    f"{name}: {count} invalid sample(s) stored as NaN until the next "
                    f"valid value; first at t = {first:g} s"
                )
        if any(count != self._union for count in self._samples):
            job.note(
                f"channels have different timelines: merged on the union of their times "
                f"({self.rows} rows); each channel holds its last value between its samples"
            )
        if self._before:
            job.note(
                f"{self._before} leading row(s) dropped: not every channel had a value before "
                f"t = {self._start:g} s"
            )
        if after:
            job.note(f"{after} trailing row(s) dropped: a channel ends at t = {end:g} s")

    def close(self) -> None:
        """Remove the temporary files of channels that ran ahead."""
        for queue in self._queues:
            queue.close()

    def _drain(self, horizon: float, *, write: bool) -> None:
        """Merge the queued samples at times up to ``horizon``, a batch at a time."""
        while True:
            heads = [queue.peek(self._batch_rows) for queue in self._queues]
            upto = horizon
            for queue, head in zip(self._queues, heads, strict=True):
                if len(head) == self._batch_rows and len(queue) > len(head):
                    upto = min(upto, float(head[-1, 0]))  # more of this channel may follow
            counts = [int(np.searchsorted(h[:, 0], upto, side="right")) for h in heads]
            if not any(counts):
                return
            taken = [head[:n, 0] for head, n in zip(heads, counts, strict=True)]
            union = np.unique(np.concatenate(taken))
            self._union += len(union)
            keep = union >= self._start
            times = union[keep]
            rows = np.empty((len(times), len(heads)), dtype=np.float64)
            for column, (queue, head, count) in enumerate(
                zip(self._queues, heads, counts, strict=True)
            ):
                # value at t: the channel's last sample at or before t, from this batch or before
                held = np.concatenate([[self._carry[column]], head[:count, 1]])
                index = np.searchsorted(head[:count, 0], times, side="right")
                rows[:, column] = held[index]
                if count:
                    self._carry[column] = float(head[count - 1, 1])
                queue.consume(count)
            self._before += int(len(union) - len(times))
            if write and len(times):
                self.rows += len(times)
                self._sink.append(times, rows)
