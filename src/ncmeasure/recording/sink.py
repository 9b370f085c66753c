"""Where imports write: a recording created when the first rows arrive, checked on the way in.

Every importer (CSV, MDF4, controller traces, column maps, CAN logs) streams its
rows into an :class:`ImportSink`; :func:`check_times` is the shared rule that
times are finite and strictly increasing.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta, RecordingStatus
from ncmeasure.recording.format import (
    EVENTS_FILE,
    MAX_FLUSH_INTERVAL_S,
    META_FILE,
    SAMPLES_FILE,
    machine_axis,
)
from ncmeasure.recording.reader import Recording
from ncmeasure.recording.writer import RecordingWriter
from ncmeasure.samples import Channel, SampleBlock
from ncmeasure.validity import Implausible

if TYPE_CHECKING:  # the machine-file models: reading a recording needs none
    from ncmeasure.config import MachineConfig

log = logging.getLogger(__name__)

#: Distinct time steps counted in memory; more go to a temporary file.
_DISTINCT_STEPS: Final = 4096
#: Time steps read back at a time when their median is selected.
_STEP_READ: Final = 1 << 20
#: Bits of the step's sort key per counting pass (4 passes cover 64 bits; a table of
#: 65,536 counts, not megabytes).
_DIGIT_BITS: Final = (16, 16, 16, 16)


class StepMedian:
    """The exact median of the time steps of all rows, in memory that does not grow with them.

    While the steps take few distinct values (a trace sampled at a fixed period:
    one, or a few that rounding makes), each value's count is kept, and the
    median is read from the counts. Beyond :data:`_DISTINCT_STEPS` values the
    steps go to an unnamed temporary file as float64; :meth:`median` selects
    the middle one (the mean of the two middle ones for an even count, as
    ``numpy.median``) by counting the bits of their sort keys, 16 bits a pass,
    so it reads the file a few times and holds one block and one table of
    counts. The result is bit for bit ``numpy.median(numpy.diff(all times))``.
    """

    def __init__(self) -> None:
        self._file: IO[bytes] | None = None
        self._counts: dict[float, int] | None = {}  # None: the steps are in the file
        self._last: float | None = None
        self.count = 0

    def add(self, time_s: NDArray[np.float64]) -> None:
        """Add the next rows' times (later than the ones before)."""
        if len(time_s) == 0:
            return
        times = np.asarray(time_s, dtype=np.float64)
        steps = np.diff(times) if self._last is None else np.diff(times, prepend=self._last)
        self._last = float(times[-1])
        if len(steps) == 0:
            return
        self.count += len(steps)
        if self._counts is not None:
            values, counts = np.unique(steps, return_counts=True)
            if len(self._counts) + len(values) <= _DISTINCT_STEPS:
                for value, count in zip(values.tolist(), counts.tolist(), strict=True):
                    self._counts[value] = self._counts.get(value, 0) + count
                return
            # too many values: every step so far to the file
            held = np.array(list(self._counts), dtype=np.float64)
            steps = np.concatenate([np.repeat(held, list(self._counts.values())), steps])
            self._counts = None
        if self._file is None:
            # closed in close(), which finish and discard call
            self._file = tempfile.TemporaryFile(prefix="ncmeasure-steps-")  # noqa: SIM115
        self._file.write(np.ascontiguousarray(steps, dtype="<f8").tobytes())

    def close(self) -> None:
        """Remove the temporary file."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def median(self) -> float | None:
        """The median step; None before two rows."""
        if not self.count:
            return None
        middle = self.count // 2
        upper = self._select(middle)
        if self.count % 2:
            return upper
        lower = self._select(middle - 1)
        return float(np.mean(np.array([lower, upper], dtype=np.float64)))

    def _blocks(self) -> Any:
        assert self._file is not None
        self._file.seek(0)
        while data := self._file.read(_STEP_READ * 8):
            steps = np.frombuffer(data, dtype="<f8")
            # an order-keeping key: sign bit flipped for positive numbers, all bits for negative
            bits = steps.view(np.uint64)
            yield np.where(bits >> np.uint64(63), ~bits, bits | np.uint64(1 << 63))

    def _select(self, rank: int) -> float:
        """The step of rank ``rank`` (0 = smallest)."""
        if self._counts is not None:
            for value in sorted(self._counts):
                rank -= self._counts[value]
                if rank < 0:
                    return value
            raise AssertionError("a rank beyond the steps counted")
        prefix = np.uint64(0)
        known_bits = 0
        for width in _DIGIT_BITS:
            shift = np.uint64(64 - known_bits - width)
            counts = np.zeros(1 << width, dtype=np.int64)
            for keys in self._blocks():
                if known_bits:
                    keys = keys[(keys >> np.uint64(64 - known_bits)) == prefix]
                digits = (keys >> shift) & np.uint64((1 << width) - 1)
                counts += np.bincount(digits.astype(np.int64), minlength=1 << width)
            cumulative = np.cumsum(counts)
            digit = int(np.searchsorted(cumulative, rank, side="right"))
            rank -= int(cumulative[digit - 1]) if digit else 0
            prefix = (prefix << np.uint64(width)) | np.uint64(digit)
            known_bits += width
        key = np.array([prefix], dtype=np.uint64)
        bits = np.where(key >> np.uint64(63), key & ~np.uint64(1 << 63), ~key)
        return float(bits.view(np.float64)[0])


def check_times(
    time_s: NDArray[np.float64], previous_s: float, where: Callable[[int], str]
) -> None:
    """Raise unless ``time_s`` is finite and increases strictly from ``previous_s`` on.

    Args:
        time_s: The times of a block of rows, in seconds.
        previous_s: The last time before the block (``-inf`` for the first block).
        where: ``where(index)`` names the place of row ``index`` in the source
            (``file:line``), for the message.

    Raises:
        RecordingError: ``<where>: problem`` for the first time that is not
            finite or not later than the one before.
    """
    bad = ~np.isfinite(time_s)
    steps = np.diff(time_s, prepend=previous_s)
    backwards = ~(steps > 0) & ~bad
    if not (bad.any() or backwards.any()):
        return
    index = int(np.flatnonzero(bad | backwards)[0])
    value = float(time_s[index])  # a Python float: numpy 2 shows np.float64(...) in repr
    if bad[index]:
        raise RecordingError(f"{where(index)}: time_s {value!r} is not a finite number")
    before = float(time_s[index - 1]) if index else previous_s
    raise RecordingError(
        f"{where(index)}: time_s {value!r} is not later than the row before "
        f"({before!r}); times must increase strictly"
    )


class ImportSink:
    """The recording an import writes, created on disk when the first rows arrive.

    Until then the sample period may still be unknown: the recording is
    created once two rows show a time step, with the median step of the rows
    so far, and closed with the median step of all rows. Rows go to disk
    chunk by chunk, so an import keeps at most one chunk in memory; the time
    steps, for the period, wait in a temporary file (:class:`StepMedian`).
    An import that fails calls :meth:`discard`, which
    removes what it wrote (never anything that was there before), so it can be
    retried into the same directory.

    Every value is checked on the way in (:mod:`ncmeasure.validity`): a "no
    value" code such as −999999, or a value beyond what the axis can do (its
    rated current and maximum velocity from the machine file, else fixed
    bounds), is stored as NaN and counted; :meth:`validity_lines` says so, and
    :meth:`finish` adds it to the report in ``meta.json`` (``link.report``).

    Args:
        directory: The new recording.
        channels: Its columns.
        machine: The machine file, for the axis metadata.
        nominal_period_s: The sample period; None: inferred from the times.
        what: How error messages name the input (``the file``, ``the trace``).
        meta: Further arguments of :meth:`RecordingWriter.create` (source,
            notes, link, serial, ...); ``start_utc`` is the time the data say
            the first sample was taken, None (the default) when they do not: an
            import never takes its own time for the measurement's.
    """

    def __init__(
        self,
        directory: Path,
        channels: Sequence[Channel],
        *,
        machine: MachineConfig | None,
        nominal_period_s: float | None,
        what: str = "the file",
        **meta: Any,
    ) -> None:
        self.directory = directory
        self.channels = tuple(channels)
        self.machine = machine
        self.nominal_period_s = nominal_period_s
        self.what = what
        self.meta = {"start_utc": None, **meta}
        self.existed = directory.exists()
        self.rows = 0
        self.writer: RecordingWriter | None = None
        facts: dict[str, dict[str, Any]] = {}
        for channel in self.channels:
            axis = machine_axis(machine, channel.axis)
            if axis is not None:
                facts[channel.name] = {
                    "rated_current_a": axis.rated_current_a,
                    "max_velocity_mm_min": axis.max_velocity_mm_min,
                }
        self.validity = Implausible.for_channels({c.name: c.signal for c in self.channels}, facts)
        self._steps = StepMedian()
        self._pending: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []

    def append(self, time_s: NDArray[np.float64], values: NDArray[np.float64]) -> None:
        """Write rows (times strictly increasing, also across calls; checked by the writer)."""
        if len(time_s) == 0:
            return
        values = np.asarray(values, dtype=np.float64)
        copied = False
        for column, channel in enumerate(self.channels):
            original = values[:, column]
            cleaned = self.validity.clean(channel.name, time_s, original)
            if cleaned is not original:
                if not copied:
                    values, copied = values.copy(), True
                values[:, column] = cleaned
        self.rows += len(time_s)
        self._steps.add(time_s)
        if self.writer is None:
            self._pending.append((time_s, values))
            if self.rows < 2 and self.nominal_period_s is None:
                return
            writer = self.ensure_writer()
            pending, self._pending = self._pending, []
            for t, v in pending:
                writer.append(SampleBlock(t, v))
            writer.flush()
            return
        self.writer.append(SampleBlock(time_s, values))  # it writes a frame per FLUSH_ROWS

    def start_at(self, start_utc: dt.datetime | None) -> None:
        """When the first sample was taken (None: unknown); before the first rows only.

        Raises:
            RecordingError: The recording is written already.
        """
        if self.writer is not None:
            raise RecordingError(f"{self.directory}: the start is set before the first rows")
        self.meta["start_utc"] = start_utc

    def ensure_writer(self) -> RecordingWriter:
        """The writer, created on first use (with the period known by then).

        Raises:
            RecordingError: no period given and fewer than two rows so far.
        """
        if self.writer is not None:
            return self.writer
        period_s = self.nominal_period_s
        if period_s is None:
            period_s = self._median_step_s()
        self.writer = RecordingWriter.create(
            self.directory,
            self.channels,
            nominal_period_s=period_s,
            machine=self.machine,
            flush_interval_s=MAX_FLUSH_INTERVAL_S,
            **self.meta,
        )
        return self.writer

    def finish(self, status: RecordingStatus = "complete", **updates: Any) -> Recording:
        """Close the recording with ``status`` (and metadata ``updates``) and read it back.

        Raises:
            RecordingError: no rows, or a single row and no sample period.
        """
        self.close(status, **updates)
        return Recording.open(self.directory)

    def close(self, status: RecordingStatus = "complete", **updates: Any) -> RecordingMeta:
        """Close the recording with ``status`` (and metadata ``updates``), without reading it back.

        Returns:
            Its ``meta.json`` as written.

        Raises:
            RecordingError: no rows, or a single row and no sample period; or the
                recording could not be finished (a full disk): the caller discards it.
        """
        if self.writer is None and not self._pending:
            raise RecordingError(f"{self.directory}: {self.what} holds no complete sample")
        writer = self.ensure_writer()
        if self.nominal_period_s is None:
            updates["nominal_period_s"] = self._median_step_s()
        lines = self.validity_lines()
        if lines:
            link = dict(updates.get("link", self.meta.get("link") or {}))
            report = list(link.get("report", []))
            link["report"] = report + [line for line in lines if line not in report]
            link["implausible"] = dict(self.validity.counts)
            updates["link"] = link
        self._steps.close()
        try:
            writer.close(status, **updates)
        except RecordingError as exc:
            # The writer's message tells a recorder what stays on disk; a failed import
            # keeps nothing (its caller discards it), so say that instead.
            cause = exc.__cause__ if isinstance(exc.__cause__, RecordingError) else exc
            raise RecordingError(f"{cause.message}; the import is not kept") from exc
        log.info("imported into %s: %d samples", self.directory, writer.rows_written)
        return writer.meta

    def validity_lines(self) -> list[str]:
        """One sentence per channel whose values were left out as not physically possible."""
        return self.validity.lines()

    def discard(self) -> None:
        """Remove the files this import wrote and, if the import made it, the directory."""
        self._steps.close()
        if self.writer is None:
            return
        with contextlib.suppress(RecordingError):
            self.writer.close("failed")
        for name in (META_FILE, SAMPLES_FILE, EVENTS_FILE):
            with contextlib.suppress(OSError):
                (self.directory / name).unlink()
        if not self.existed:
            with contextlib.suppress(OSError):
                self.directory.rmdir()

    def _median_step_s(self) -> float:
        median = self._steps.median()
        if median is None:
            raise RecordingError(
                f"{self.directory}: {self.what} holds a single sample and no sample period; "
                "a recording needs at least two (or pass nominal_period_s)"
            )
        return median
