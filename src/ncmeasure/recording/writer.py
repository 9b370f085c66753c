"""The crash-safe recording writer.

:class:`RecordingWriter` takes the :class:`~ncmeasure.samples.SampleBlock` objects
of a drive link. A background thread writes the buffered rows as one checksummed
frame and fsyncs it at least every ``flush_interval_s`` (at most 0.5 s), so a
recorder killed with ``kill -9`` or by a power cut loses at most its last half
second. A writer fed faster than real time (a replay, an import) flushes as
soon as :data:`FLUSH_ROWS` rows wait, so they, and the frames, stay bounded
whatever the pace.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import os
import threading
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any, Literal, Self, get_args

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from ncmeasure.errors import LinkError, RecordingError
from ncmeasure.formats.identity import iso_utc
from ncmeasure.formats.recording import ChannelMeta, RecordedAxis, RecordingMeta, RecordingStatus
from ncmeasure.inputs import format_validation_error, parse_json, read_text
from ncmeasure.recording.format import (
    EVENTS_FILE,
    FRAME_HEADER,
    FRAME_MAGIC,
    MAX_FLUSH_INTERVAL_S,
    MAX_FRAME_ROWS,
    META_FILE,
    ROW_DTYPE,
    SAMPLES_FILE,
    PathArg,
    axis_metadata,
    event_line,
    fsync_directory,
    is_being_written,
    now_utc,
    write_failure,
    write_meta,
)
from ncmeasure.samples import Channel, LinkEvent, SampleBlock

if TYPE_CHECKING:  # the machine-file models: reading a recording needs none
    from ncmeasure.config import MachineConfig

try:  # advisory locks tell a reader that a writer is still at work (POSIX only)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger(__name__)

_STATUSES: tuple[str, ...] = get_args(RecordingStatus)
# Fields that describe the data itself; close() must not change them.
_FIXED_FIELDS = frozenset(
    {
        "format",
        "format_version",
        "channels",
        "status",
        "samples",
        "gaps",
        "lost_samples",
        "skipped_cycles",
        "skipped_share",
        "ncmeasure_version",
    }
)


def _share(part: int, whole: int) -> float:
    """``part`` of ``whole`` (0 … 1), 0 when there is nothing."""
    return part / whole if whole else 0.0


def _write_all(file: IO[bytes], data: bytes | memoryview) -> None:
    view = memoryview(data).cast("B")
    while view:
        written = file.write(view)
        if not written:
            raise OSError("the file accepted no more bytes")
        view = view[written:]


_UNFINISHED: frozenset[str] = frozenset({"recording", "failed"})
"""Statuses of an attempt that a new recording into its directory moves aside."""


def _attempt_status(path: Path) -> str | None:
    """The status in ``path``'s meta.json; None when it holds no readable recording."""
    try:
        text = read_text(path / META_FILE, "a recording's meta.json", 1024 * 1024, RecordingError)
        data = parse_json(text, str(path / META_FILE), RecordingError)
    except RecordingError:
        return None
    status = data.get("status") if isinstance(data, dict) else None
    return status if isinstance(status, str) and status in _STATUSES else None


def _move_failed_attempt_aside(path: Path) -> Path:
    """Make room in the non-empty directory ``path`` for a new recording, or refuse.

    A recording that did not finish (status ``failed``, or ``recording`` with no
    writer at work: a full disk, a crash) is renamed to ``<name>.failed-<n>``
    beside it, whole and readable; nothing else is ever moved or replaced.

    Returns:
        Where the earlier attempt now is.

    Raises:
        RecordingError: The directory holds a finished recording, one still
            being written, or anything that is not a recording.
    """
    status = _attempt_status(path)
    if status is None:
        raise RecordingError(
            f"{path}: directory is not empty; a recording needs a new or empty directory"
        )
    if status not in _UNFINISHED:
        raise RecordingError(
            f"{path}: directory is not empty: it holds a finished recording (status {status}), "
            "which is never overwritten; record into a new directory"
        )
    if status == "recording":
        live = is_being_written(path / SAMPLES_FILE)
        if live or live is None:
            reason = "still being recorded" if live else "perhaps still being recorded"
            raise RecordingError(
                f"{path}: directory is not empty: it holds a recording {reason}; "
                "record into a new directory"
            )
    number = 1
    while (aside := path.with_name(f"{path.name}.failed-{number}")).exists():
        number += 1
    try:
        path.rename(aside)
    except OSError as exc:
        raise RecordingError(
            f"{path}: holds an unfinished recording (status {status}) that cannot be moved "
            f"aside to {aside.name} ({exc.strerror or exc}); move or remove it, or record "
            "into a new directory"
        ) from exc
    log.info("%s: the unfinished recording there (status %s) moved to %s", path, status, aside)
    return aside


def _check_arguments(
    channels: Sequence[Channel],
    nominal_period_s: float,
    time_scale: float,
    flush_interval_s: float,
) -> None:
    """Raise ValueError for the arguments of :meth:`RecordingWriter.create` out of range."""
    if not channels:
        raise ValueError("a recording needs at least one channel")
    if not 0 < flush_interval_s <= MAX_FLUSH_INTERVAL_S:
        raise ValueError(
            f"flush_interval_s must be in (0, {MAX_FLUSH_INTERVAL_S}] s, not {flush_interval_s!r}"
        )
    if not (np.isfinite(nominal_period_s) and nominal_period_s > 0):
        raise ValueError(f"nominal_period_s must be positive, not {nominal_period_s!r}")
    if not (np.isfinite(time_scale) and time_scale >= 0):
        raise ValueError(f"time_scale must be 0 or positive, not {time_scale!r}")


def _recorded_axes(
    path: Path, channels: Sequence[Channel], machine: MachineConfig | None
) -> list[RecordedAxis]:
    """The machine data of the channels' axes for ``meta.json`` (none without a machine).

    Raises:
        RecordingError: A channel's axis is not an axis of ``machine``.
    """
    axes: list[RecordedAxis] = []
    if machine is not None:
        known = {a.name: a for a in machine.axes}
        for name in dict.fromkeys(c.axis for c in channels):
            if name not in known:
                raise RecordingError(
                    f"{path}: channel axis {name} is not an axis of machine "
                    f"{machine.machine.name!r} ({', '.join(known)})"
                )
            axes.append(axis_metadata(known[name]))
    return axes


def _make_room(path: Path) -> Path | None:
    """Check that ``path`` can take a new recording; move an unfinished attempt aside.

    Returns:
        Where an unfinished attempt was moved (see :func:`_move_failed_attempt_aside`).

    Raises:
        RecordingError: ``path`` is not a directory, or holds what may not be moved.
    """
    if path.exists():
        if not path.is_dir():
            raise RecordingError(f"{path}: exists and is not a directory")
        if any(path.iterdir()):
            return _move_failed_attempt_aside(path)
    return None


def _open_files(path: Path, meta: RecordingMeta) -> tuple[IO[bytes], IO[bytes]]:
    """Create the directory, write ``meta`` and open the samples and events files.

    Returns:
        ``samples.bin`` (locked while written, where the platform can) and
        ``events.jsonl``, both unbuffered, for appending.

    Raises:
        RecordingError: Something cannot be created or written; nothing half
            made stays behind.
    """
    made = not path.exists()
    created: list[IO[bytes]] = []
    try:
        path.mkdir(parents=True, exist_ok=True)
        write_meta(path, meta)
        samples = (path / SAMPLES_FILE).open("ab", buffering=0)
        created.append(samples)
        events = (path / EVENTS_FILE).open("ab", buffering=0)
        created.append(events)
    except (OSError, RecordingError) as exc:
        # Nothing half made stays behind: the directory was new or empty.
        for file in created:
            file.close()
        for name in (META_FILE, SAMPLES_FILE, EVENTS_FILE):
            with contextlib.suppress(OSError):
                (path / name).unlink()
        if made:
            with contextlib.suppress(OSError):
                path.rmdir()
        if isinstance(exc, RecordingError):
            raise
        raise RecordingError(
            f"{path}: cannot create a recording here ({exc.strerror or exc})"
        ) from exc
    if fcntl is not None:
        with contextlib.suppress(OSError):  # only a hint for readers
            fcntl.flock(samples.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    fsync_directory(path)
    return samples, events


def _check_close(
    directory: Path, meta: RecordingMeta, status: RecordingStatus, meta_updates: Mapping[str, Any]
) -> None:
    """Refuse a closing status or ``meta.json`` update that :meth:`RecordingWriter.close`
    must not write, before anything is closed.

    Raises:
        RecordingError: The status is not a final one, an update changes a
            field that describes the data, or makes the metadata invalid.
    """
    if status not in _STATUSES or status == "recording":
        raise RecordingError(
            f"{directory}: cannot close with status {status!r} "
            "(complete, incomplete, interrupted, link_lost or failed)"
        )
    fixed = sorted(_FIXED_FIELDS.intersection(meta_updates))
    if fixed:
        raise RecordingError(f"{directory}: close() cannot change {', '.join(fixed)} in meta.json")
    try:
        RecordingMeta.model_validate({**meta.model_dump(), **meta_updates})
    except ValidationError as exc:
        raise RecordingError(
            f"{directory}: invalid metadata update", format_validation_error(exc)
        ) from exc


def _unfinished_message(
    directory: Path,
    cause: RecordingError,
    rows_written: int,
    *,
    flush_failed: bool,
    meta_failed: bool,
) -> str:
    """What a close that failed (``cause``) left on disk, and what the next recording does."""
    message = f"{cause.message}. " + ("The recording stopped there; its" if flush_failed else "Its")
    message += f" {rows_written} samples on disk are whole and readable"
    if meta_failed:
        message += f" ({META_FILE} could not be updated and still says 'recording')"
    message += (
        f"; a new recording into {directory} moves this attempt aside to "
        f"{directory.name}.failed-<n>"
    )
    return message


class _FrameFiles:
    """A recording's ``samples.bin`` and ``events.jsonl`` and how much of them is whole.

    Each :meth:`write` appends rows as checksummed frames and events as lines,
    fsyncs both, and only then counts them; a write that fails cuts both files
    back to where the last whole write ended. Not thread-safe: the
    :class:`RecordingWriter` calls it under its lock.
    """

    def __init__(self, directory: Path, samples: IO[bytes], events: IO[bytes]) -> None:
        self.directory = directory
        self._samples = samples
        self._events = events
        self.frames = 0
        self.rows_written = 0
        self._samples_size = 0
        self._events_size = 0

    def write(
        self, pending_rows: Sequence[NDArray[np.float64]], rows: int, events: Sequence[bytes]
    ) -> None:
        """Append ``rows`` rows (in blocks) as frames and the event lines; fsync.

        Raises:
            RecordingError: The disk refused the data (the files are cut back
                to their last good state).
        """
        frames = self.frames
        what = SAMPLES_FILE
        try:
            if pending_rows:
                block = pending_rows[0] if len(pending_rows) == 1 else np.concatenate(pending_rows)
                for start in range(0, len(block), MAX_FRAME_ROWS):
                    payload = np.ascontiguousarray(block[start : start + MAX_FRAME_ROWS], ROW_DTYPE)
                    header = FRAME_HEADER.pack(
                        FRAME_MAGIC, len(payload), zlib.crc32(payload.data), frames
                    )
                    _write_all(self._samples, header)
                    _write_all(self._samples, payload.data)
                    frames += 1
                os.fsync(self._samples.fileno())
            if events:
                what = EVENTS_FILE
                _write_all(self._events, b"".join(events))
                os.fsync(self._events.fileno())
        except BaseException as exc:
            # Cut partial writes away, so the next frame follows a whole one: after a
            # full disk, and after an interrupt (Ctrl-C) while append flushes on the
            # caller's thread. The rows stay buffered.
            for file, size in (
                (self._samples, self._samples_size),
                (self._events, self._events_size),
            ):
                with contextlib.suppress(OSError):
                    file.truncate(size)
            if isinstance(exc, OSError):
                raise RecordingError(write_failure(self.directory, what, exc)) from exc
            raise
        self.frames = frames
        self.rows_written += rows
        self._samples_size = self._samples.tell()
        self._events_size = self._events.tell()

    def close(self) -> None:
        """Close both files (which also releases the writer's lock); failures are logged."""
        for file in (self._samples, self._events):
            try:
                file.close()  # also releases the writer's lock
            except OSError:
                log.exception("closing %s", getattr(file, "name", file))


FLUSH_ROWS = 1 << 17
"""An append that leaves this many rows waiting writes them as a frame and fsyncs it
at once: few enough to bound the memory of a fast writer (16 columns: 17 MB), many
enough that fsync does not set the pace of an import. At 1 kHz the flush thread
writes about 250 rows a frame, long before."""


class RecordingWriter:
    """Appends sample blocks and link events to a new recording, crash-safe.

    Make one with :meth:`create` and use it as a context manager; leaving the
    ``with`` block closes it with status ``complete``, or ``interrupted``
    (Ctrl-C, ``sys.exit``), ``link_lost`` (a :class:`~ncmeasure.errors.LinkError`) or
    ``failed`` (any other exception)::

        with RecordingWriter.create("rec/", link.channels,
                                    nominal_period_s=link.nominal_period_s,
                                    machine=config, link=link.describe()) as writer:
            while (block := link.read(timeout_s=1.0)) is not None:
                writer.append(block)
                for event in link.events():
                    writer.add_event(event)

    Rows wait in memory until a flush writes them as one frame and fsyncs the
    file; a daemon thread flushes every ``flush_interval_s``. All methods are
    thread-safe.
    """

    def __init__(
        self,
        directory: Path,
        meta: RecordingMeta,
        samples_file: IO[bytes],
        events_file: IO[bytes],
        flush_interval_s: float,
    ) -> None:
        """Use :meth:`create`; this takes over files that it opened."""
        self.directory = directory
        self._meta = meta
        self._channels = tuple(c.to_channel() for c in meta.channels)
        self._files = _FrameFiles(directory, samples_file, events_file)
        self._flush_interval_s = flush_interval_s
        self._lock = threading.Lock()
        self._pending_rows: list[NDArray[np.float64]] = []
        self._pending_count = 0
        self._pending_events: list[bytes] = []
        self._last_time_s = -np.inf
        self._rows_appended = 0
        self._gaps = 0
        self._lost_samples = 0
        self._skipped_cycles = 0
        self._closed = False
        self._error: RecordingError | None = None
        self.moved_aside: Path | None = None
        """Where :meth:`create` moved an unfinished earlier attempt in the directory."""
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._flush_loop, name=f"recording-flush:{directory.name}", daemon=True
        )
        self._thread.start()

    @classmethod
    def create(
        cls,
        directory: PathArg,
        channels: Sequence[Channel],
        *,
        nominal_period_s: float,
        machine: MachineConfig | None = None,
        serial: str | None = None,
        link: Mapping[str, Any] | None = None,
        config_hash: str | None = None,
        notes: str = "",
        source: str = "",
        faster_than_real_time: bool = False,
        time_scale: float = 1.0,
        flush_interval_s: float = 0.25,
        start_utc: dt.datetime | Literal["now"] | None = "now",
    ) -> RecordingWriter:
        """Start a new recording in ``directory`` (created with its parents).

        A directory that holds an unfinished earlier attempt (status ``failed``,
        or ``recording`` with no writer at work: the disk was full, the recorder
        crashed) is first moved aside whole to ``<directory>.failed-<n>``
        (:attr:`moved_aside` says where), so a retry can use the same name; a
        finished recording is never overwritten or moved.

        Args:
            directory: A directory that does not exist yet, is empty, or holds
                an unfinished attempt.
            channels: The sample columns, in the order of the blocks' values.
            nominal_period_s: The intended time between two rows.
            machine: The machine file; its name and the recorded axes' data go
                into ``meta.json``. Every channel's axis must be one of its axes.
            serial: The serial number of the machine measured (the machine
                file names its type), for ``meta.json``.
            link: What :meth:`DriveLink.describe` returns.
            config_hash: The schedule's config hash, to match the recording
                with the program that was run.
            notes: Free text.
            source: Where the samples come from: ``canopen``, ``replay``, ``import:csv``...
            faster_than_real_time: True when a replay or simulation ran faster
                than the machine would.
            time_scale: Seconds of ``time_s`` per wall-clock second: the link
                clock's speed (a virtual machine), the replay speed (0: as fast
                as possible), 1 for real time.
            flush_interval_s: Longest time rows stay in memory, at most 0.5 s.
            start_utc: When the first sample was taken: ``"now"`` (a recording
                made here), a time (an import whose data say it), or None: unknown
                (an import without a date; never the time of the import).

        Raises:
            RecordingError: The directory holds anything but an unfinished
                attempt, cannot be created or written (a full disk leaves
                nothing behind), or a channel's axis is not in ``machine``.
            ValueError: An argument is out of range.
        """
        _check_arguments(channels, nominal_period_s, time_scale, flush_interval_s)
        path = Path(directory)
        axes = _recorded_axes(path, channels, machine)
        start = dt.datetime.now(dt.UTC) if isinstance(start_utc, str) else start_utc
        try:
            meta = RecordingMeta(
                machine=machine.machine.name if machine is not None else None,
                serial=serial,
                axes=axes,
                link=dict(link or {}),
                channels=[ChannelMeta.from_channel(c) for c in channels],
                nominal_period_s=nominal_period_s,
                start_utc=iso_utc(start) if start is not None else None,
                config_hash=config_hash,
                notes=notes,
                source=source,
                faster_than_real_time=faster_than_real_time,
                time_scale=time_scale,
            )
        except ValidationError as exc:
            raise RecordingError(
                f"{path}: invalid recording metadata", format_validation_error(exc)
            ) from exc

        moved_aside = _make_room(path)
        samples, events = _open_files(path, meta)
        log.info(
            "recording to %s: %d channels, nominal period %g s",
            path,
            len(channels),
            nominal_period_s,
        )
        writer = cls(path, meta, samples, events, flush_interval_s)
        writer.moved_aside = moved_aside
        return writer

    # --- properties -------------------------------------------------------------------

    @property
    def meta(self) -> RecordingMeta:
        """The metadata as last written to ``meta.json``."""
        return self._meta

    @property
    def channels(self) -> tuple[Channel, ...]:
        """The sample columns, in order."""
        return self._channels

    @property
    def rows_written(self) -> int:
        """Rows on disk (fsynced)."""
        return self._files.rows_written

    @property
    def rows_appended(self) -> int:
        """Rows handed to :meth:`append`, on disk or still in memory."""
        return self._rows_appended

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has finished."""
        return self._closed

    # --- writing ----------------------------------------------------------------------

    def append(self, block: SampleBlock) -> None:
        """Buffer the rows of ``block``; the next flush writes them.

        Raises:
            RecordingError: The block's column count differs from the channels,
                a time is not finite or not later than the row before it, the
                writer is closed, or the last background flush failed.
        """
        values = np.asarray(block.values, dtype=np.float64)
        time_s = np.asarray(block.time_s, dtype=np.float64)
        if values.ndim != 2 or values.shape[1] != len(self._channels):
            columns = values.shape[1] if values.ndim == 2 else values.ndim
            raise RecordingError(
                f"{self.directory}: a block with {columns} value columns does not fit a "
                f"recording of {len(self._channels)} channels "
                f"({', '.join(c.name for c in self._channels)})"
            )
        count = len(time_s)
        if count and not np.isfinite(time_s).all():
            index = int(np.flatnonzero(~np.isfinite(time_s))[0])
            raise RecordingError(
                f"{self.directory}: row {index} of the block has time_s {time_s[index]!r}"
            )
        if count > 1:
            steps = np.diff(time_s)
            if not (steps > 0).all():
                index = int(np.flatnonzero(~(steps > 0))[0]) + 1
                raise RecordingError(
                    f"{self.directory}: time_s does not increase inside the block: row {index} "
                    f"is at {time_s[index]!r} s after {time_s[index - 1]!r} s"
                )
        rows = np.empty((count, 1 + len(self._channels)), dtype=np.float64)
        rows[:, 0] = time_s
        rows[:, 1:] = values
        with self._lock:
            self._check_usable()
            if count == 0:
                return
            if not time_s[0] > self._last_time_s:
                raise RecordingError(
                    f"{self.directory}: time_s goes backwards: the block starts at "
                    f"{time_s[0]!r} s, the row before it is at {self._last_time_s!r} s"
                )
            self._pending_rows.append(rows)
            self._pending_count += count
            self._rows_appended += count
            self._last_time_s = float(time_s[-1])
            if self._pending_count >= FLUSH_ROWS:
                self._flush_or_keep_error()

    def add_event(self, event: LinkEvent) -> None:
        """Buffer a link event; the next flush appends it to ``events.jsonl``.

        Raises:
            RecordingError: The writer is closed or the last background flush failed.
        """
        line = event_line(event)
        with self._lock:
            self._check_usable()
            self._pending_events.append(line)
            if event.kind == "gap":
                self._gaps += 1
                self._lost_samples += int(event.lost_samples)
                self._skipped_cycles += int(event.details.get("skipped_cycles", 0))

    def flush(self) -> None:
        """Write the buffered rows as one frame and the buffered events, then fsync.

        Raises:
            RecordingError: The writer is closed, or the disk refused the data
                (the files are cut back to their last good state and the rows
                stay buffered for the next attempt).
        """
        with self._lock:
            if self._closed:
                raise RecordingError(f"{self.directory}: the recording is closed")
            self._flush_locked()

    def close(self, status: RecordingStatus = "complete", **meta_updates: Any) -> None:
        """Flush, stop the flush thread and finish ``meta.json``. Safe to call twice.

        A recording is ``complete`` only without gaps: ``complete`` becomes
        ``incomplete`` when gap events were added; ``meta.json`` gets their number
        and the samples they lost in any case.

        Args:
            status: How the recording ended: ``complete``, ``incomplete``,
                ``interrupted``, ``link_lost`` or ``failed``.
            **meta_updates: Other ``meta.json`` fields to change, e.g. ``notes``
                or ``nominal_period_s`` (not the format, channels, status or samples).

        Raises:
            RecordingError: An update is not a valid metadata field or value
                (nothing is closed then), or the final flush or ``meta.json``
                failed (a full disk: the recording is closed with status
                ``failed``, or keeps ``recording`` when not even ``meta.json``
                could be written; the message says so, and how many samples
                are on disk and readable).
        """
        if self._closed:
            return
        _check_close(self.directory, self._meta, status, meta_updates)

        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join()
        error: RecordingError | None = None
        with self._lock:
            if self._closed:  # closed by another thread meanwhile
                return
            try:
                self._flush_locked()
            except RecordingError as exc:
                error = exc
                status = "failed"
            self._closed = True
            if status == "complete" and self._gaps:
                status = "incomplete"
            self._files.close()
            final = RecordingMeta.model_validate(
                {
                    **self._meta.model_dump(),
                    **meta_updates,
                    "status": status,
                    "end_utc": now_utc(),
                    "samples": self._files.rows_written,
                    "gaps": self._gaps,
                    "lost_samples": self._lost_samples,
                    "skipped_cycles": self._skipped_cycles,
                    "skipped_share": _share(
                        self._skipped_cycles, self._files.rows_written + self._lost_samples
                    ),
                }
            )
            meta_error: RecordingError | None = None
            try:
                write_meta(self.directory, final)
                self._meta = final
            except RecordingError as exc:
                meta_error = exc
        rows_written = self._files.rows_written
        log.info("recording %s closed: %s, %d samples", self.directory, status, rows_written)
        if error is None and meta_error is None:
            return
        cause = error or meta_error
        assert cause is not None
        raise RecordingError(
            _unfinished_message(
                self.directory,
                cause,
                rows_written,
                flush_failed=error is not None,
                meta_failed=meta_error is not None,
            )
        ) from cause

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc is None:
            self.close("complete")
            return
        status: RecordingStatus = "failed"
        if isinstance(exc, KeyboardInterrupt | SystemExit):
            status = "interrupted"
        elif isinstance(exc, LinkError):
            status = "link_lost"
        try:
            self.close(status)
        except RecordingError:  # the exception in flight matters more
            log.exception("closing recording %s after an error", self.directory)

    # --- internals --------------------------------------------------------------------

    def _check_usable(self) -> None:
        if self._closed:
            raise RecordingError(f"{self.directory}: the recording is closed")
        if self._error is not None:
            raise RecordingError(self._error.message) from self._error

    def _flush_locked(self) -> None:
        if not self._pending_rows and not self._pending_events:
            return
        # on failure the rows and events stay buffered for the next attempt
        self._files.write(self._pending_rows, self._pending_count, self._pending_events)
        self._pending_rows.clear()
        self._pending_count = 0
        self._pending_events.clear()
        self._error = None

    def _flush_or_keep_error(self) -> None:
        """Flush (the lock held); a failure is kept: the next append or add_event raises
        it, and flush and close try again. The rows stay buffered for the next attempt."""
        try:
            self._flush_locked()
        except RecordingError as exc:
            if self._error is None:
                log.info("%s (retrying every %g s)", exc, self._flush_interval_s)
            self._error = exc

    def _flush_loop(self) -> None:
        while not self._stop.wait(self._flush_interval_s):
            with self._lock:
                if self._closed:
                    return
                self._flush_or_keep_error()
