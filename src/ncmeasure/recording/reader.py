"""Reading a recording back: ``samples.bin`` frame by frame, straight into a numpy array.

A frame that was cut short or damaged, and everything after it, is reported in
:attr:`Recording.problems` and never misread.
"""

from __future__ import annotations

import io
import logging
import os
import zlib
from collections.abc import Generator, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from ncmeasure.errors import RecordingError
from ncmeasure.formats.header import read_file
from ncmeasure.formats.recording import EventRecord, RecordingMeta
from ncmeasure.inputs import read_bytes
from ncmeasure.recording.format import (
    EVENTS_FILE,
    FRAME_HEADER,
    FRAME_MAGIC,
    META_FILE,
    ROW_DTYPE,
    SAMPLES_FILE,
    PathArg,
    is_being_written,
)
from ncmeasure.samples import Channel, LinkEvent

log = logging.getLogger(__name__)

MAX_META_BYTES = 16 * 1024 * 1024
"""Largest meta.json read (a few kB as ncmeasure writes it)."""
MAX_EVENTS_BYTES = 256 * 1024 * 1024
"""Largest events.jsonl read (a million events)."""


@dataclass
class ReadCount:
    """Rows of ``samples.bin`` files given out in this process, and the readings that gave them.

    :func:`iter_chunks` and :meth:`Recording.open` add to :data:`READ_COUNT`
    once per chunk and once per reading (never per row): a benchmark or a test
    takes the difference around an analysis to see how often it read the
    recording.
    """

    rows: int = 0
    readings: int = 0


READ_COUNT = ReadCount()
"""What every reading of a recording's samples in this process added up to."""


def _read_exactly(file: io.FileIO, target: memoryview) -> int:
    got = 0
    while got < len(target):
        count = file.readinto(target[got:])
        if not count:
            break
        got += count
    return got


@dataclass(frozen=True)
class _Frame:
    offset: int
    rows: int
    crc: int


def _walk_headers(file: io.FileIO, size: int, row_bytes: int, problems: list[str]) -> list[_Frame]:
    """The frames whose headers are whole and in sequence and whose payload fits the file.

    Only the 16-byte headers are read; the first one that is cut short, has no
    magic, the wrong sequence number or more rows than the rest of the file
    holds ends the walk with a problem.
    """
    frames: list[_Frame] = []
    header = bytearray(FRAME_HEADER.size)
    offset = 0
    while offset < size:
        rest = size - offset
        number = len(frames)
        where = f"after frame {number - 1}" if number else "at the start of samples.bin"
        file.seek(offset)
        if rest < FRAME_HEADER.size or _read_exactly(file, memoryview(header)) < len(header):
            problems.append(f"torn tail: {rest} bytes {where} ignored (incomplete frame)")
            break
        magic, count, crc, sequence = FRAME_HEADER.unpack(header)
        if magic != FRAME_MAGIC:
            # A crash can leave zeros where a frame was to be (file systems that extend
            # the file before its data is on disk), or a sparse hole of any size.
            found = "zero bytes" if not any(header) else "no frame header"
            problems.append(f"torn tail: {rest} bytes {where} ignored ({found} at byte {offset})")
            break
        if sequence != number:
            problems.append(
                f"frame {number} at byte {offset} carries sequence number {sequence}: "
                f"it and everything after it ignored ({rest} bytes)"
            )
            break
        payload_bytes = count * row_bytes
        if payload_bytes > rest - FRAME_HEADER.size:
            problems.append(f"torn tail: {rest} bytes {where} ignored (incomplete frame)")
            break
        frames.append(_Frame(offset, count, crc))
        offset += FRAME_HEADER.size + payload_bytes
    return frames


_READ_ROWS = 1 << 12
"""Rows read from ``samples.bin`` at a time and spread into their columns.

512 KiB for 16 columns: a piece stays in the processor's cache while it is
spread. Reading the benchmark's hour (3.5 M rows) took 0.26 s, against 0.40 s
with pieces of 32,768 rows and 0.34 s for the rows read whole (``time_s``
copied out of them)."""


def _read_frames(path: Path, columns: int) -> tuple[NDArray[np.float64], list[str]]:
    """Read every intact frame of ``samples.bin`` straight into one array, column by column.

    Two passes: the headers first, which give the number of rows, then every
    payload, :data:`_READ_ROWS` rows at a time, into its place in an array of
    exactly that size, with the frame's CRC checked over its pieces. The file
    holds rows; the array holds columns (Fortran order): every channel's
    samples are one contiguous run of memory, as the analysis reads them.
    Memory follows the rows the headers announce, never the file size: a file
    with a huge (sparse) damaged tail costs no more than its intact frames.

    Returns:
        The rows of the intact frames (n, columns), and the problems found.
    """
    problems: list[str] = []
    row_bytes = 8 * columns
    with path.open("rb", buffering=0) as file:
        size = os.fstat(file.fileno()).st_size  # a live writer may append more: ignored
        frames = _walk_headers(file, size, row_bytes, problems)
        total = sum(f.rows for f in frames)
        data = np.empty((total, columns), dtype=np.float64, order="F")
        piece = np.empty(min(total, _READ_ROWS) * row_bytes, dtype=np.uint8)
        rows = 0
        for number, frame in enumerate(frames):
            rest = size - frame.offset
            file.seek(frame.offset + FRAME_HEADER.size)
            crc = 0
            for first in range(0, frame.rows, _READ_ROWS):
                count = min(_READ_ROWS, frame.rows - first)
                target = piece[: count * row_bytes]
                if _read_exactly(file, target.data) < len(target):
                    where = f"after frame {number - 1}" if number else "at the start of samples.bin"
                    problems[:] = [f"torn tail: {rest} bytes {where} ignored (file shrank)"]
                    READ_COUNT.readings += 1
                    READ_COUNT.rows += rows
                    return data[:rows], problems
                crc = zlib.crc32(target.data, crc)
                at = rows + first
                data[at : at + count] = target.view(ROW_DTYPE).reshape(count, columns)
            if crc != frame.crc:
                problems[:] = [
                    f"frame {number} fails its checksum: it and everything after it "
                    f"ignored ({rest} bytes)"
                ]
                break
            rows += frame.rows
    READ_COUNT.readings += 1
    READ_COUNT.rows += rows
    return data[:rows], problems


@dataclass(frozen=True)
class RowChunk:
    """Consecutive rows of a recording: :func:`iter_chunks` yields them in order.

    Attributes:
        first: Index of the chunk's first row in the whole recording.
        time_s: Times of its rows (m,).
        values: The chosen channels of its rows (m, channels), in the order asked for.
    """

    first: int
    time_s: NDArray[np.float64]
    values: NDArray[np.float64]


def iter_chunks(
    directory: PathArg,
    rows: int = 1 << 16,
    channels: tuple[str, ...] | None = None,
    problems: list[str] | None = None,
    verified: set[int] | None = None,
    first_row: int = 0,
) -> Iterator[RowChunk]:
    """The rows of ``samples.bin`` chunk by chunk, never the whole file in memory.

    The same rows as :meth:`Recording.open`, with the same checks (frame walk,
    sequence numbers, CRC of every frame): a damaged frame ends the rows there,
    and its problem is appended to ``problems``; no row of a damaged frame is
    given. Memory is a chunk of ``rows`` rows (of the channels asked for),
    the rows of one frame waiting for its checksum and the frame index,
    whatever the length of the recording: a frame's rows fill chunks that are
    given once its checksum holds (a frame beyond :data:`_WAITING_BYTES` is
    checked in pieces first, then read again). Every row is read from the
    file once per reading, :data:`_READ_ROWS` at a time.

    Args:
        directory: The recording directory.
        rows: Rows per chunk (the last one may hold fewer).
        channels: Channel names to return, in this order (default: all).
        problems: Receives what was wrong with the file, one sentence each.
        verified: Byte offsets of the frames whose checksum was checked; a
            caller reading the same file several times passes the same set, so
            each frame is checked once in all.
        first_row: Begin with the frame that holds this row: the frames
            before it are neither read nor checked (a caller that read the
            file before and wants only its later rows). The chunks keep their
            place in the whole recording (:attr:`RowChunk.first`) and begin at
            that frame's first row.

    Raises:
        RecordingError: Not a recording, or a channel it does not have.
    """
    if rows < 1:
        raise ValueError("rows must be at least 1")
    path = Path(directory)
    columns, width = _chunk_columns(path, channels)
    row_bytes = 8 * width
    found = problems if problems is not None else []
    samples_path = path / SAMPLES_FILE
    try:
        file = samples_path.open("rb", buffering=0)
    except FileNotFoundError as exc:
        raise RecordingError(f"{path}: not a recording ({SAMPLES_FILE} is missing)") from exc
    READ_COUNT.readings += 1
    with file:
        size = os.fstat(file.fileno()).st_size
        frames = _walk_headers(file, size, row_bytes, found)
        chunks = _Chunker(rows, width, columns)
        longest = max((f.rows for f in frames), default=0)
        piece = np.empty(min(longest, _READ_ROWS) * row_bytes, dtype=np.uint8)
        # A frame whose rows (of the channels read) fit this waits, read once, for its
        # checksum; a longer one is checked in pieces first, then read again.
        waiting = _WAITING_BYTES // (8 * (1 + len(columns)))
        for number, frame in enumerate(frames):
            if chunks.first + frame.rows <= first_row and not chunks.held:
                chunks.first += frame.rows  # wholly before the rows wanted: not read
                continue
            checked = verified is not None and frame.offset in verified
            if not checked and frame.rows > waiting:
                crc = _frame_crc(file, frame, piece, row_bytes)
                if crc != frame.crc:
                    found[:] = [
                        _torn(number, frame, size) if crc is None else _bad(number, frame, size)
                    ]
                    break
                checked = True
            problem = yield from _frame_rows(file, frame, piece, chunks, checked)
            if problem == "torn":
                found[:] = [_torn(number, frame, size)]
                break
            if problem == "bad":
                found[:] = [_bad(number, frame, size)]
                break
            if verified is not None:
                verified.add(frame.offset)
        last = chunks.rest()
        if last is not None:
            yield last


_WAITING_BYTES = 64 << 20
"""Largest frame (its rows of the channels read) read once and held until its checksum holds.

No row of a damaged frame is given: a frame up to this size is read once,
its rows gathered into chunks that wait for the frame's checksum; a longer
one (a writer's frames hold at most :data:`~ncmeasure.recording.format.MAX_FRAME_ROWS`
rows) is checked in pieces first, then read again, never held whole. The
writer's frames of the benchmark's hour (137,500 rows of 13 columns) are about 14 MB."""


def _frame_rows(
    file: io.FileIO, frame: _Frame, piece: NDArray[np.uint8], chunks: _Chunker, checked: bool
) -> Generator[RowChunk, None, str | None]:
    """Read a frame's rows into ``chunks`` :data:`_READ_ROWS` at a time; the chunks now whole.

    Those of a frame ``checked`` before are given as they fill; the others wait
    until the frame's checksum holds and are dropped where it fails, the rows
    before the frame kept for :meth:`_Chunker.rest`.

    Returns:
        None, or what ended the rows at this frame: "torn" (the file is
        shorter than its frame) or "bad" (the checksum fails).
    """
    row_bytes = chunks.row_bytes
    file.seek(frame.offset + FRAME_HEADER.size)
    mark = chunks.mark()
    crc = 0
    for first in range(0, frame.rows, _READ_ROWS):
        count = min(_READ_ROWS, frame.rows - first)
        target = piece[: count * row_bytes]
        if _read_exactly(file, target.data) < len(target):
            if not checked:
                chunks.undo(mark)
            return "torn"
        if not checked:
            crc = zlib.crc32(target.data, crc)
        chunks.fill(target.view(ROW_DTYPE).reshape(count, chunks.width))
        if checked:
            yield from chunks.take()
    if not checked and crc != frame.crc:
        chunks.undo(mark)
        return "bad"
    yield from chunks.take()
    return None


def _chunk_columns(path: Path, channels: tuple[str, ...] | None) -> tuple[list[int], int]:
    """The row columns of ``channels`` (all when None) and the width of a row.

    Raises:
        RecordingError: Not a recording, or a channel it does not have.
    """
    meta = _read_meta(path)
    names = [c.name for c in meta.channels]
    wanted = tuple(names) if channels is None else channels
    missing = [name for name in wanted if name not in names]
    if missing:
        raise RecordingError(f"{path}: no channel {', '.join(map(repr, missing))}")
    return [1 + names.index(name) for name in wanted], 1 + len(names)


def _torn(number: int, frame: _Frame, size: int) -> str:
    """The problem of frame ``number`` whose payload the file no longer holds."""
    where = f"after frame {number - 1}" if number else "at the start of samples.bin"
    return f"torn tail: {size - frame.offset} bytes {where} ignored (file shrank)"


def _bad(number: int, frame: _Frame, size: int) -> str:
    """The problem of frame ``number`` whose checksum fails."""
    return (
        f"frame {number} fails its checksum: it and everything after it ignored "
        f"({size - frame.offset} bytes)"
    )


class _Chunker:
    """Rows in, chunks of exactly ``rows`` rows (of the chosen columns) out.

    Rows are spread into the arrays of the chunk they belong to as they come
    (a piece of :data:`_READ_ROWS` rows, still in the processor's cache): the
    chunk's values are held column by column (Fortran order), as
    :meth:`Recording.open` holds a recording, so a channel of a chunk is one
    contiguous run of memory that every pass reads without a copy. Chunks
    filled wait in :meth:`take` until their rows may be given.
    """

    def __init__(self, rows: int, width: int, columns: list[int]) -> None:
        self.rows = rows
        self.width = width
        self.row_bytes = 8 * width
        self.columns = columns
        self.time_s = np.empty(0, dtype=np.float64)  # the chunk being filled
        self.values = np.empty((0, len(columns)), dtype=np.float64, order="F")
        self.held = 0  # rows in the chunk being filled
        self.first = 0  # the row of the whole recording the chunk being filled begins with
        self.whole: list[RowChunk] = []  # filled, not yet given

    def fill(self, table: NDArray[np.float64]) -> None:
        """Take the rows of ``table`` (rows of every column)."""
        at, count = 0, len(table)
        while at < count:
            if not self.held:
                self.time_s = np.empty(self.rows, dtype=np.float64)
                self.values = np.empty((self.rows, len(self.columns)), np.float64, order="F")
            take = min(count - at, self.rows - self.held)
            rows = table[at : at + take]
            into = slice(self.held, self.held + take)
            self.time_s[into] = rows[:, 0]
            for k, column in enumerate(self.columns):
                self.values[into, k] = rows[:, column]
            self.held += take
            at += take
            if self.held == self.rows:
                self.whole.append(RowChunk(self.first, self.time_s, self.values))
                self.first += self.rows
                self.held = 0

    def take(self) -> list[RowChunk]:
        """The chunks filled since the last call, now given."""
        whole, self.whole = self.whole, []
        for chunk in whole:
            READ_COUNT.rows += len(chunk.time_s)
        return whole

    def mark(self) -> tuple[int, int, NDArray[np.float64], NDArray[np.float64]]:
        """Where the chunks stand (with nothing waiting in :meth:`take`), for :meth:`undo`."""
        return self.first, self.held, self.time_s, self.values

    def undo(self, mark: tuple[int, int, NDArray[np.float64], NDArray[np.float64]]) -> None:
        """Drop every row taken since ``mark``."""
        self.first, self.held, self.time_s, self.values = mark
        self.whole = []

    def rest(self) -> RowChunk | None:
        """The rows left over at the end, fewer than a chunk."""
        if not self.held:
            return None
        held, self.held = self.held, 0
        READ_COUNT.rows += held
        self.first += held
        return RowChunk(self.first - held, self.time_s[:held], self.values[:held])


def _frame_crc(
    file: io.FileIO, frame: _Frame, piece: NDArray[np.uint8], row_bytes: int
) -> int | None:
    """The CRC-32 of a frame's payload, read into ``piece`` piece by piece (None: the file is
    shorter)."""
    crc = 0
    file.seek(frame.offset + FRAME_HEADER.size)
    left = frame.rows * row_bytes
    while left:
        target = piece[: min(left, len(piece))]
        got = _read_exactly(file, target.data)
        crc = zlib.crc32(target[:got].data, crc)
        if got < len(target):
            return None
        left -= got
    return crc


def _read_events(path: Path, problems: list[str]) -> list[LinkEvent]:
    if not path.exists():
        problems.append(f"{EVENTS_FILE} is missing: no events")
        return []
    try:
        raw = read_bytes(path, "a recording's events.jsonl", MAX_EVENTS_BYTES, RecordingError)
    except RecordingError as exc:
        problems.append(f"{exc.message}: no events")
        return []
    lines = raw.split(b"\n")
    tail = lines.pop()  # the part after the last newline: empty unless torn
    events: list[LinkEvent] = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            events.append(EventRecord.model_validate_json(line).to_event())
        except ValidationError as exc:
            reason = exc.errors(include_url=False)[0]["msg"]
            problems.append(f"{EVENTS_FILE} line {number} is not a valid event ({reason}): ignored")
    if tail.strip():
        try:
            events.append(EventRecord.model_validate_json(tail).to_event())
        except ValidationError:
            problems.append(
                f"{EVENTS_FILE}: torn last line ({len(tail)} bytes, line {len(lines) + 1}) ignored"
            )
    return events


def _read_meta(directory: Path) -> RecordingMeta:
    if not directory.exists():
        raise RecordingError(f"{directory}: no such recording directory")
    if not directory.is_dir():
        raise RecordingError(f"{directory}: not a recording (a recording is a directory)")
    path = directory / META_FILE
    missing = f"{directory}: not a recording ({META_FILE} is missing)"
    return read_file(
        path,
        RecordingMeta,
        RecordingError,
        what="recording",
        max_bytes=MAX_META_BYTES,
        missing=missing,
    )


def _add_status_problems(
    meta: RecordingMeta, samples_path: Path, rows: int, problems: list[str]
) -> None:
    """What meta.json's status and sample count say about ``rows`` readable rows."""
    if meta.status == "recording":
        if is_being_written(samples_path):
            problems.insert(0, f"still being recorded (status 'recording'): {rows} samples so far")
        else:
            problems.insert(
                0,
                "not closed cleanly (status 'recording'): the recorder stopped "
                f"unexpectedly; {rows} samples recovered",
            )
    elif meta.samples is not None and meta.samples != rows:
        problems.append(
            f"{META_FILE} says {meta.samples} samples, {SAMPLES_FILE} holds {rows} readable samples"
        )


@dataclass
class RecordingHead:
    """A recording without its samples: meta.json, channels, events, problems.

    For an analysis that reads the samples chunk by chunk
    (:func:`iter_chunks`): :meth:`samples_read` adds what reading them found
    (a damaged frame, an unfinished recording) to :attr:`problems`, in the
    order :meth:`Recording.open` lists them.

    Attributes:
        directory: Where the recording lives.
        meta: The contents of ``meta.json``.
        channels: The sample columns, in order.
        events: The link events, in file order.
        problems: What was wrong with the files, one sentence each.
        rows: Readable rows, once :meth:`samples_read` was called (else None).
    """

    directory: Path
    meta: RecordingMeta
    channels: tuple[Channel, ...]
    events: list[LinkEvent]
    problems: list[str]
    rows: int | None = None

    @classmethod
    def open(cls, directory: PathArg) -> RecordingHead:
        """Read meta.json and events.jsonl of a recording directory.

        Raises:
            RecordingError: Not a recording, or its ``meta.json`` is missing or invalid.
        """
        path = Path(directory)
        meta = _read_meta(path)
        if not (path / SAMPLES_FILE).is_file():
            raise RecordingError(f"{path}: not a recording ({SAMPLES_FILE} is missing)")
        problems: list[str] = []
        events = _read_events(path / EVENTS_FILE, problems)
        channels = tuple(c.to_channel() for c in meta.channels)
        return cls(directory=path, meta=meta, channels=channels, events=events, problems=problems)

    def samples_read(self, rows: int, problems: list[str]) -> None:
        """Note the rows read and the problems of samples.bin (from :func:`iter_chunks`)."""
        found = [*problems, *self.problems]
        _add_status_problems(self.meta, self.directory / SAMPLES_FILE, rows, found)
        for problem in found:
            log.warning("recording %s: %s", self.directory, problem)
        self.problems = found
        self.rows = rows

    @property
    def axes(self) -> tuple[str, ...]:
        """The recorded axes, in channel order."""
        return tuple(dict.fromkeys(c.axis for c in self.channels))

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The column names (``X_current_a``, ...), in order."""
        return tuple(c.name for c in self.channels)


@dataclass(frozen=True, eq=False)
class Recording:
    """A recording read into memory.

    ``time_s`` and ``values`` are views into one array held column by column
    (``time_s`` its first column): every channel's samples are contiguous,
    and :meth:`column` returns views of them (no copies).

    Attributes:
        directory: Where the recording lives.
        meta: The contents of ``meta.json``.
        channels: The sample columns, in order.
        time_s: Time of every row (n,), seconds on the link's clock.
        values: The samples (n, channels).
        events: The link events, in file order.
        problems: What was wrong with the files (damaged tail, unfinished
            recording, ...), one sentence each; empty for a clean recording.
    """

    directory: Path
    meta: RecordingMeta
    channels: tuple[Channel, ...]
    time_s: NDArray[np.float64]
    values: NDArray[np.float64]
    events: list[LinkEvent]
    problems: list[str]

    @classmethod
    def open(cls, directory: PathArg) -> Recording:
        """Read a recording directory.

        A damaged or incomplete end of ``samples.bin`` or ``events.jsonl`` is
        not an error: the intact part is returned, and every problem is listed
        in :attr:`problems` and logged as a warning.

        Raises:
            RecordingError: The directory does not exist, is not a recording,
                or its ``meta.json`` is missing or invalid.
        """
        path = Path(directory)
        meta = _read_meta(path)
        channels = tuple(c.to_channel() for c in meta.channels)
        samples_path = path / SAMPLES_FILE
        try:
            data, problems = _read_frames(samples_path, 1 + len(channels))
        except FileNotFoundError as exc:
            raise RecordingError(f"{path}: not a recording ({SAMPLES_FILE} is missing)") from exc
        except OSError as exc:
            raise RecordingError(f"{samples_path}: cannot be read ({exc.strerror or exc})") from exc
        rows = len(data)
        events = _read_events(path / EVENTS_FILE, problems)
        _add_status_problems(meta, samples_path, rows, problems)
        for problem in problems:
            log.warning("recording %s: %s", path, problem)
        return cls(
            directory=path,
            meta=meta,
            channels=channels,
            time_s=data[:, 0],
            values=data[:, 1:],
            events=events,
            problems=problems,
        )

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def axes(self) -> tuple[str, ...]:
        """The recorded axes, in channel order."""
        return tuple(dict.fromkeys(c.axis for c in self.channels))

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The column names (``X_current_a``, ...), in order."""
        return tuple(c.name for c in self.channels)

    def column(self, name: str) -> NDArray[np.float64]:
        """The samples of one channel, by name (``time_s`` gives the times).

        Raises:
            RecordingError: The recording has no such channel.
        """
        if name == "time_s":
            return self.time_s
        for index, channel in enumerate(self.channels):
            if channel.name == name:
                column: NDArray[np.float64] = self.values[:, index]
                return column
        raise RecordingError(
            f"{self.directory}: no channel {name!r} (channels: {', '.join(self.channel_names)})"
        )

    def axis_signal(self, axis: str, signal: str) -> NDArray[np.float64]:
        """The samples of ``signal`` (e.g. ``current_a``) of ``axis``.

        Raises:
            RecordingError: The recording has no such channel.
        """
        return self.column(f"{axis}_{signal}")


def read_recording(directory: PathArg) -> Recording:
    """Read a recording directory; see :meth:`Recording.open`."""
    return Recording.open(directory)


def as_recording(recording: Recording | PathArg) -> Recording:
    return recording if isinstance(recording, Recording) else Recording.open(recording)


def rows_of(
    recording: Recording | RecordingHead | PathArg, rows: int = 1 << 16
) -> tuple[Recording | RecordingHead, Iterator[RowChunk]]:
    """A recording and its rows chunk by chunk, for a writer of the whole recording.

    A :class:`Recording` gives its rows from memory. A directory or a
    :class:`RecordingHead` is read chunk by chunk (:func:`iter_chunks`, memory
    bounded by one chunk whatever the length); once the chunks are exhausted,
    the head's :attr:`~RecordingHead.rows` and :attr:`~RecordingHead.problems`
    say what was read and what was wrong.

    Raises:
        RecordingError: Not a recording.
    """
    if isinstance(recording, Recording):
        rec = recording

        def from_memory() -> Iterator[RowChunk]:
            for start in range(0, len(rec), rows):
                stop = min(start + rows, len(rec))
                yield RowChunk(start, rec.time_s[start:stop], rec.values[start:stop])

        return rec, from_memory()
    head = recording if isinstance(recording, RecordingHead) else RecordingHead.open(recording)

    def from_file() -> Iterator[RowChunk]:
        problems: list[str] = []
        count = 0
        for chunk in iter_chunks(head.directory, rows, problems=problems):
            count += len(chunk.time_s)
            yield chunk
        head.samples_read(count, problems)

    return head, from_file()
