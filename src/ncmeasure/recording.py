"""The on-disk recording format: a crash-safe writer, a fast reader, CSV and MDF4 exchange.

A recording is a directory of three files::

    meta.json      what was recorded: machine, axes, link, channels, status (RecordingMeta)
    samples.bin    append-only frames of float64 rows: time_s, then one column per channel
    events.jsonl   one LinkEvent per line: gaps, faults, reboots, reconnects

:class:`RecordingWriter` takes the :class:`~ncmeasure.samples.SampleBlock` objects
of a drive link. A background thread writes the buffered rows as one checksummed
frame and fsyncs it at least every ``flush_interval_s`` (at most 0.5 s), so a
recorder killed with ``kill -9`` or by a power cut loses at most its last half
second. :class:`Recording` reads a recording back in one pass over the file,
straight into a numpy array; a frame that was cut short or damaged, and
everything after it, is reported in :attr:`Recording.problems` and never misread.

:func:`export_csv` / :func:`import_csv` exchange recordings as one bit-exact CSV
file, :func:`export_mdf4` / :func:`import_mdf4` as ASAM MDF4 (the optional extra
``mdf``). The format is described byte by byte in ``docs/recording-format.md``.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import itertools
import json
import logging
import os
import re
import struct
import threading
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType, TracebackType
from typing import IO, Any, Final, Literal, Self, get_args

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from ncmeasure._version import __version__
from ncmeasure.config import AXIS_NAME_PATTERN, AxisConfig, MachineConfig, format_validation_error
from ncmeasure.errors import DependencyError, LinkError, RecordingError
from ncmeasure.samples import SIGNAL_UNITS, Channel, EventKind, LinkEvent, SampleBlock
from ncmeasure.validity import Implausible

__all__ = [
    "EVENTS_FILE",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "FRAME_HEADER",
    "FRAME_MAGIC",
    "MAX_FLUSH_INTERVAL_S",
    "META_FILE",
    "SAMPLES_FILE",
    "ChannelMeta",
    "ImportSink",
    "Recording",
    "RecordingMeta",
    "RecordingStatus",
    "RecordingWriter",
    "axis_metadata",
    "channel_from_name",
    "check_times",
    "export_csv",
    "export_mdf4",
    "import_csv",
    "import_mdf4",
    "read_recording",
]

log = logging.getLogger(__name__)

PathArg = str | os.PathLike[str]

FORMAT_NAME: Final = "ncmeasure-recording"
FORMAT_VERSION: Final = 1
META_FILE = "meta.json"
SAMPLES_FILE = "samples.bin"
EVENTS_FILE = "events.jsonl"

#: Frame header: magic, row count, CRC32 of the payload, frame sequence number.
FRAME_HEADER = struct.Struct("<4sIII")
FRAME_MAGIC = b"NCMF"
#: The longest a writer may keep rows in memory before they are on disk.
MAX_FLUSH_INTERVAL_S = 0.5
#: Rows per frame at most; a larger flush is split (the row count is a uint32).
MAX_FRAME_ROWS = 1 << 20
_ROW_DTYPE = np.dtype("<f8")
_CSV_CHUNK_ROWS = 20_000
_IMPORT_CHUNK_ROWS = 100_000
_MDF_EXTRA = "pip install 'ncmeasure[mdf]'"

RecordingStatus = Literal["recording", "complete", "interrupted", "link_lost", "failed"]
_STATUSES: tuple[str, ...] = get_args(RecordingStatus)
# Fields that describe the data itself; close() must not change them.
_FIXED_FIELDS = frozenset(
    {"format", "format_version", "channels", "status", "samples", "ncmeasure_version"}
)

try:  # advisory locks tell a reader that a writer is still at work (POSIX only)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]


# --- metadata --------------------------------------------------------------------------


class ChannelMeta(BaseModel):
    """One sample column in ``meta.json``: its name, axis, signal and unit."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    axis: str = Field(min_length=1)
    signal: str = Field(min_length=1)
    unit: str

    @model_validator(mode="after")
    def _check_name(self) -> Self:
        if self.name != f"{self.axis}_{self.signal}":
            raise ValueError(
                f"name {self.name!r} must be <axis>_<signal> ({self.axis}_{self.signal})"
            )
        return self

    @classmethod
    def from_channel(cls, channel: Channel) -> ChannelMeta:
        """The metadata entry of a link channel."""
        return cls(name=channel.name, axis=channel.axis, signal=channel.signal, unit=channel.unit)

    def to_channel(self) -> Channel:
        """The link channel this entry describes."""
        return Channel(self.axis, self.signal, self.unit)


class RecordingMeta(BaseModel):
    """The contents of ``meta.json``: what was recorded, how, and how it ended."""

    model_config = ConfigDict(extra="forbid")

    format: Literal["ncmeasure-recording"] = FORMAT_NAME
    format_version: Literal[1] = FORMAT_VERSION
    ncmeasure_version: str = __version__
    machine: str | None = None
    axes: list[dict[str, Any]] = Field(default_factory=list)
    link: dict[str, Any] = Field(default_factory=dict)
    channels: list[ChannelMeta] = Field(min_length=1)
    nominal_period_s: float = Field(gt=0, allow_inf_nan=False)
    start_utc: str
    config_hash: str | None = None
    notes: str = ""
    source: str = ""
    faster_than_real_time: bool = False
    time_scale: float = Field(default=1.0, ge=0, allow_inf_nan=False)
    """Seconds of ``time_s`` per wall-clock second while recording: the link clock's
    speed or the replay speed (0: a replay as fast as possible); 1 is real time."""
    status: RecordingStatus = "recording"
    end_utc: str | None = None
    samples: int | None = Field(default=None, ge=0)

    @model_validator(mode="after")
    def _check_unique_channels(self) -> Self:
        names = [c.name for c in self.channels]
        doubled = sorted({n for n in names if names.count(n) > 1})
        if doubled:
            raise ValueError(f"channels appear twice: {', '.join(doubled)}")
        return self


def axis_metadata(axis: AxisConfig) -> dict[str, Any]:
    """The facts about an axis that the analysis of a recording needs.

    Args:
        axis: An axis of the machine file.

    Returns:
        A JSON-ready dict: name, travel_mm, vertical, fixed_bearing_end,
        torque_constant_nm_per_a, rated_current_a, screw_lead_mm,
        max_velocity_mm_min, rapid_velocity_mm_min (the last two tell rapids and
        impossible values apart).
    """
    return {
        "name": axis.name,
        "travel_mm": list(axis.travel_mm),
        "max_velocity_mm_min": axis.max_velocity_mm_min,
        "rapid_velocity_mm_min": axis.rapid_mm_min,
        "vertical": axis.vertical,
        "fixed_bearing_end": axis.fixed_bearing_end,
        "torque_constant_nm_per_a": axis.torque_constant_nm_per_a,
        "rated_current_a": axis.rated_current_a,
        "screw_lead_mm": axis.screw_lead_mm,
    }


def machine_axis(machine: MachineConfig | None, name: str) -> AxisConfig | None:
    """The axis ``name`` of the machine file, or None (no machine file, no such axis)."""
    if machine is None:
        return None
    return next((axis for axis in machine.axes if axis.name == name), None)


def channel_from_name(name: str) -> Channel | None:
    """The channel a column name such as ``X_velocity_cmd_mm_min`` stands for.

    The signal is the longest known suffix (see ``SIGNAL_UNITS``), the axis
    the part before it, which must be a valid axis name.

    Returns:
        The channel with the unit of its signal, or ``None`` when the name does
        not follow ``<AXIS>_<signal>``.
    """
    for signal in sorted(SIGNAL_UNITS, key=len, reverse=True):
        suffix = f"_{signal}"
        if name.endswith(suffix):
            axis = name[: -len(suffix)]
            if re.fullmatch(AXIS_NAME_PATTERN, axis):
                return Channel(axis, signal, SIGNAL_UNITS[signal])
            return None
    return None


def _now_utc() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")


def _fsync_directory(directory: Path) -> None:
    """Make a new or renamed entry of ``directory`` survive a power cut (POSIX)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # Windows cannot open a directory; NTFS journals the entry
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _write_meta(directory: Path, meta: RecordingMeta) -> None:
    """Replace ``meta.json`` atomically: a reader sees the old or the new file, whole."""
    path = directory / META_FILE
    tmp = directory / (META_FILE + ".tmp")
    text = json.dumps(meta.model_dump(mode="json"), indent=2, ensure_ascii=False, default=str)
    try:
        with tmp.open("w", encoding="utf-8") as file:
            file.write(text + "\n")
            file.flush()
            os.fsync(file.fileno())
        tmp.replace(path)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot be written ({exc.strerror or exc})") from exc
    _fsync_directory(directory)


def _event_line(event: LinkEvent) -> bytes:
    record = {
        "time_s": float(event.time_s),
        "kind": event.kind,
        "message": event.message,
        "axis": event.axis,
        "lost_samples": int(event.lost_samples),
        "details": dict(event.details),
    }
    return (json.dumps(record, ensure_ascii=False, default=str) + "\n").encode("utf-8")


class _EventRecord(BaseModel):
    """One line of ``events.jsonl`` (unknown keys from newer writers are ignored)."""

    model_config = ConfigDict(extra="ignore")

    time_s: float
    kind: EventKind
    message: str
    axis: str | None = None
    lost_samples: int = 0
    details: dict[str, Any] = Field(default_factory=dict)

    def to_event(self) -> LinkEvent:
        return LinkEvent(
            time_s=self.time_s,
            kind=self.kind,
            message=self.message,
            axis=self.axis,
            lost_samples=self.lost_samples,
            details=self.details,
        )


# --- writer ----------------------------------------------------------------------------


def _write_all(file: IO[bytes], data: bytes | memoryview) -> None:
    view = memoryview(data).cast("B")
    while view:
        written = file.write(view)
        if not written:
            raise OSError("the file accepted no more bytes")
        view = view[written:]


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
        self._samples = samples_file
        self._events = events_file
        self._flush_interval_s = flush_interval_s
        self._lock = threading.Lock()
        self._pending_rows: list[NDArray[np.float64]] = []
        self._pending_count = 0
        self._pending_events: list[bytes] = []
        self._last_time_s = -np.inf
        self._rows_appended = 0
        self._rows_written = 0
        self._frames = 0
        self._samples_size = 0
        self._events_size = 0
        self._closed = False
        self._error: RecordingError | None = None
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
        link: Mapping[str, Any] | None = None,
        config_hash: str | None = None,
        notes: str = "",
        source: str = "",
        faster_than_real_time: bool = False,
        time_scale: float = 1.0,
        flush_interval_s: float = 0.25,
        start_utc: dt.datetime | None = None,
    ) -> RecordingWriter:
        """Start a new recording in ``directory`` (created with its parents).

        Args:
            directory: A directory that does not exist yet or is empty.
            channels: The sample columns, in the order of the blocks' values.
            nominal_period_s: The intended time between two rows.
            machine: The machine file; its name and the recorded axes' data go
                into ``meta.json``. Every channel's axis must be one of its axes.
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
            start_utc: When the recording began; now when not given.

        Raises:
            RecordingError: The directory exists and is not empty, cannot be
                created, or a channel's axis is not in ``machine``.
            ValueError: An argument is out of range.
        """
        if not channels:
            raise ValueError("a recording needs at least one channel")
        if not 0 < flush_interval_s <= MAX_FLUSH_INTERVAL_S:
            raise ValueError(
                f"flush_interval_s must be in (0, {MAX_FLUSH_INTERVAL_S}] s, "
                f"not {flush_interval_s!r}"
            )
        if not (np.isfinite(nominal_period_s) and nominal_period_s > 0):
            raise ValueError(f"nominal_period_s must be positive, not {nominal_period_s!r}")
        if not (np.isfinite(time_scale) and time_scale >= 0):
            raise ValueError(f"time_scale must be 0 or positive, not {time_scale!r}")
        path = Path(directory)
        axes: list[dict[str, Any]] = []
        if machine is not None:
            known = {a.name: a for a in machine.axes}
            for name in dict.fromkeys(c.axis for c in channels):
                if name not in known:
                    raise RecordingError(
                        f"{path}: channel axis {name} is not an axis of machine "
                        f"{machine.machine.name!r} ({', '.join(known)})"
                    )
                axes.append(axis_metadata(known[name]))
        start = (start_utc or dt.datetime.now(dt.UTC)).astimezone(dt.UTC)
        try:
            meta = RecordingMeta(
                machine=machine.machine.name if machine is not None else None,
                axes=axes,
                link=dict(link or {}),
                channels=[ChannelMeta.from_channel(c) for c in channels],
                nominal_period_s=nominal_period_s,
                start_utc=start.isoformat(timespec="milliseconds"),
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

        if path.exists():
            if not path.is_dir():
                raise RecordingError(f"{path}: exists and is not a directory")
            if any(path.iterdir()):
                raise RecordingError(
                    f"{path}: directory is not empty; a recording needs a new or empty directory"
                )
        try:
            path.mkdir(parents=True, exist_ok=True)
            _write_meta(path, meta)
            samples = (path / SAMPLES_FILE).open("ab", buffering=0)
        except OSError as exc:
            raise RecordingError(f"{path}: cannot create a recording here ({exc})") from exc
        try:
            events = (path / EVENTS_FILE).open("ab", buffering=0)
        except OSError as exc:
            samples.close()
            raise RecordingError(f"{path}: cannot create a recording here ({exc})") from exc
        if fcntl is not None:
            with contextlib.suppress(OSError):  # only a hint for readers
                fcntl.flock(samples.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        _fsync_directory(path)
        log.info(
            "recording to %s: %d channels, nominal period %g s",
            path,
            len(channels),
            nominal_period_s,
        )
        return cls(path, meta, samples, events, flush_interval_s)

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
        return self._rows_written

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

    def add_event(self, event: LinkEvent) -> None:
        """Buffer a link event; the next flush appends it to ``events.jsonl``.

        Raises:
            RecordingError: The writer is closed or the last background flush failed.
        """
        line = _event_line(event)
        with self._lock:
            self._check_usable()
            self._pending_events.append(line)

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

        Args:
            status: How the recording ended: ``complete``, ``interrupted``,
                ``link_lost`` or ``failed``.
            **meta_updates: Other ``meta.json`` fields to change, e.g. ``notes``
                or ``nominal_period_s`` (not the format, channels, status or samples).

        Raises:
            RecordingError: An update is not a valid metadata field or value
                (nothing is closed then), or the final flush failed (the
                recording is closed with status ``failed``).
        """
        if self._closed:
            return
        if status not in _STATUSES or status == "recording":
            raise RecordingError(
                f"{self.directory}: cannot close with status {status!r} "
                "(complete, interrupted, link_lost or failed)"
            )
        fixed = sorted(_FIXED_FIELDS.intersection(meta_updates))
        if fixed:
            raise RecordingError(
                f"{self.directory}: close() cannot change {', '.join(fixed)} in meta.json"
            )
        try:
            RecordingMeta.model_validate({**self._meta.model_dump(), **meta_updates})
        except ValidationError as exc:
            raise RecordingError(
                f"{self.directory}: invalid metadata update", format_validation_error(exc)
            ) from exc

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
            for file in (self._samples, self._events):
                try:
                    file.close()  # also releases the writer's lock
                except OSError:
                    log.exception("closing %s", getattr(file, "name", file))
            self._meta = RecordingMeta.model_validate(
                {
                    **self._meta.model_dump(),
                    **meta_updates,
                    "status": status,
                    "end_utc": _now_utc(),
                    "samples": self._rows_written,
                }
            )
            _write_meta(self.directory, self._meta)
        log.info("recording %s closed: %s, %d samples", self.directory, status, self._rows_written)
        if error is not None:
            raise error

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
            raise RecordingError(
                f"{self.directory}: the recording cannot be written: {self._error.message}"
            ) from self._error

    def _flush_locked(self) -> None:
        if not self._pending_rows and not self._pending_events:
            return
        frames = self._frames
        try:
            if self._pending_rows:
                rows = (
                    self._pending_rows[0]
                    if len(self._pending_rows) == 1
                    else np.concatenate(self._pending_rows)
                )
                for start in range(0, len(rows), MAX_FRAME_ROWS):
                    payload = np.ascontiguousarray(rows[start : start + MAX_FRAME_ROWS], _ROW_DTYPE)
                    header = FRAME_HEADER.pack(
                        FRAME_MAGIC, len(payload), zlib.crc32(payload.data), frames
                    )
                    _write_all(self._samples, header)
                    _write_all(self._samples, payload.data)
                    frames += 1
                os.fsync(self._samples.fileno())
            if self._pending_events:
                _write_all(self._events, b"".join(self._pending_events))
                os.fsync(self._events.fileno())
        except OSError as exc:
            # Cut partial writes away, so the next frame follows a whole one.
            for file, size in (
                (self._samples, self._samples_size),
                (self._events, self._events_size),
            ):
                with contextlib.suppress(OSError):
                    file.truncate(size)
            raise RecordingError(
                f"{self.directory}: cannot write samples ({exc.strerror or exc})"
            ) from exc
        self._frames = frames
        self._rows_written += self._pending_count
        self._samples_size = self._samples.tell()
        self._events_size = self._events.tell()
        self._pending_rows.clear()
        self._pending_count = 0
        self._pending_events.clear()
        self._error = None

    def _flush_loop(self) -> None:
        while not self._stop.wait(self._flush_interval_s):
            with self._lock:
                if self._closed:
                    return
                try:
                    self._flush_locked()
                except RecordingError as exc:
                    if self._error is None:
                        log.error("%s (retrying every %g s)", exc, self._flush_interval_s)
                    self._error = exc


# --- reader ----------------------------------------------------------------------------


def _read_exactly(file: io.FileIO, target: memoryview) -> int:
    got = 0
    while got < len(target):
        count = file.readinto(target[got:])
        if not count:
            break
        got += count
    return got


def _read_frames(path: Path, columns: int) -> tuple[NDArray[np.float64], list[str]]:
    """Read every intact frame of ``samples.bin`` straight into one array.

    Returns:
        The rows of the intact frames (n, columns), and the problems found.
    """
    problems: list[str] = []
    row_bytes = 8 * columns
    with path.open("rb", buffering=0) as file:
        size = os.fstat(file.fileno()).st_size  # a live writer may append more: ignored
        raw = np.empty(size // row_bytes * row_bytes, dtype=np.uint8)  # pages are touched lazily
        buffer = raw.data
        header = bytearray(FRAME_HEADER.size)
        offset = rows = frame = 0
        while offset < size:
            rest = size - offset
            where = f"after frame {frame - 1}" if frame else "at the start of samples.bin"
            if rest < FRAME_HEADER.size or _read_exactly(file, memoryview(header)) < len(header):
                problems.append(f"torn tail: {rest} bytes {where} ignored (incomplete frame)")
                break
            magic, count, crc, sequence = FRAME_HEADER.unpack(header)
            if magic != FRAME_MAGIC:
                problems.append(
                    f"torn tail: {rest} bytes {where} ignored (no frame header at byte {offset})"
                )
                break
            if sequence != frame:
                problems.append(
                    f"frame {frame} at byte {offset} carries sequence number {sequence}: "
                    f"it and everything after it ignored ({rest} bytes)"
                )
                break
            payload_bytes = count * row_bytes
            if payload_bytes > rest - FRAME_HEADER.size:
                problems.append(f"torn tail: {rest} bytes {where} ignored (incomplete frame)")
                break
            target = buffer[rows * row_bytes : rows * row_bytes + payload_bytes]
            if _read_exactly(file, target) < payload_bytes:
                problems.append(f"torn tail: {rest} bytes {where} ignored (file shrank)")
                break
            if zlib.crc32(target) != crc:
                problems.append(
                    f"frame {frame} fails its checksum: it and everything after it "
                    f"ignored ({rest} bytes)"
                )
                break
            offset += FRAME_HEADER.size + payload_bytes
            rows += count
            frame += 1
    data: NDArray[np.float64] = raw[: rows * row_bytes].view(_ROW_DTYPE).reshape(rows, columns)
    return data, problems


def _read_events(path: Path, problems: list[str]) -> list[LinkEvent]:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        problems.append(f"{EVENTS_FILE} is missing: no events")
        return []
    except OSError as exc:
        problems.append(f"{EVENTS_FILE} cannot be read ({exc.strerror or exc}): no events")
        return []
    lines = raw.split(b"\n")
    tail = lines.pop()  # the part after the last newline: empty unless torn
    events: list[LinkEvent] = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            events.append(_EventRecord.model_validate_json(line).to_event())
        except ValidationError as exc:
            reason = exc.errors(include_url=False)[0]["msg"]
            problems.append(f"{EVENTS_FILE} line {number} is not a valid event ({reason}): ignored")
    if tail.strip():
        try:
            events.append(_EventRecord.model_validate_json(tail).to_event())
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
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise RecordingError(f"{directory}: not a recording ({META_FILE} is missing)") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path}: cannot be read ({exc})") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecordingError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict) or data.get("format") != FORMAT_NAME:
        found = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise RecordingError(
            f"{path}: not an ncmeasure recording (format is {found!r}, expected {FORMAT_NAME!r})"
        )
    version = data.get("format_version")
    if isinstance(version, int) and version > FORMAT_VERSION:
        raise RecordingError(
            f"{path}: format_version {version} is newer than this ncmeasure reads "
            f"({FORMAT_VERSION}); update ncmeasure"
        )
    try:
        return RecordingMeta.model_validate(data)
    except ValidationError as exc:
        raise RecordingError(f"{path}: invalid metadata", format_validation_error(exc)) from exc


def _is_being_written(path: Path) -> bool | None:
    """True while a writer holds ``samples.bin``; None where that cannot be told."""
    if fcntl is None:  # pragma: no cover - Windows
        return None
    try:
        with path.open("rb") as file:
            try:
                fcntl.flock(file.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            except OSError:
                return None
            fcntl.flock(file.fileno(), fcntl.LOCK_UN)
            return False
    except OSError:
        return None


@dataclass(frozen=True, eq=False)
class Recording:
    """A recording read into memory.

    ``values`` is a view into one array that also holds ``time_s`` as its
    first column; :meth:`column` returns views as well (no copies).

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
        if meta.status == "recording":
            if _is_being_written(samples_path):
                problems.insert(
                    0, f"still being recorded (status 'recording'): {rows} samples so far"
                )
            else:
                problems.insert(
                    0,
                    "not closed cleanly (status 'recording'): the recorder stopped "
                    f"unexpectedly; {rows} samples recovered",
                )
        elif meta.samples is not None and meta.samples != rows:
            problems.append(
                f"{META_FILE} says {meta.samples} samples, {SAMPLES_FILE} holds {rows} "
                "readable samples"
            )
        for problem in problems:
            log.warning("recording %s: %s", path, problem)
        return cls(
            directory=path,
            meta=meta,
            channels=channels,
            time_s=np.ascontiguousarray(data[:, 0]),
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


def _as_recording(recording: Recording | PathArg) -> Recording:
    return recording if isinstance(recording, Recording) else Recording.open(recording)


def _frame_rows(recording: Recording, start: int, stop: int) -> NDArray[np.float64]:
    rows = np.empty((stop - start, 1 + len(recording.channels)), dtype=np.float64)
    rows[:, 0] = recording.time_s[start:stop]
    rows[:, 1:] = recording.values[start:stop]
    return rows


# --- CSV -------------------------------------------------------------------------------


def export_csv(recording: Recording | PathArg, path: PathArg) -> Path:
    """Write a recording as one CSV file: ``time_s`` and the channels, bit-exact.

    The header row names the columns (``time_s,X_current_a,...``); every value
    is written as Python's shortest repr that reads back to the same float64
    (``0.1``, ``1e-300``, ``-0.0``, ``nan``), so :func:`import_csv` restores the
    samples bit for bit. The file is written in chunks and renamed into place
    when complete.

    Args:
        recording: A recording, or the directory of one.
        path: The CSV file to write (replaced if it exists).

    Returns:
        The path written.

    Raises:
        RecordingError: The recording cannot be read or the file cannot be written.
    """
    rec = _as_recording(recording)
    target = Path(path)
    tmp = target.with_name(target.name + ".tmp")
    try:
        with tmp.open("w", encoding="utf-8", newline="\n") as file:
            file.write(",".join(["time_s", *rec.channel_names]) + "\n")
            for start in range(0, len(rec), _CSV_CHUNK_ROWS):
                rows = _frame_rows(rec, start, min(start + _CSV_CHUNK_ROWS, len(rec)))
                # float.__repr__ is the shortest text that round-trips exactly.
                file.write("".join([",".join(map(repr, row)) + "\n" for row in rows.tolist()]))
        tmp.replace(target)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise RecordingError(f"{target}: cannot be written ({exc.strerror or exc})") from exc
    log.info("exported %d samples of %s to %s", len(rec), rec.directory, target)
    return target


def _parse_csv_header(path: Path, line: str) -> list[Channel]:
    if not line:
        raise RecordingError(f"{path}:1: the file is empty; expected a header row")
    cells = [cell.strip() for cell in line.lstrip("\ufeff").rstrip("\r\n").split(",")]
    if cells[0] != "time_s":
        raise RecordingError(f"{path}:1: the first column must be time_s, not {cells[0]!r}")
    if len(cells) < 2:
        raise RecordingError(f"{path}:1: no channel columns after time_s")
    channels: list[Channel] = []
    for number, name in enumerate(cells[1:], start=2):
        channel = channel_from_name(name)
        if channel is None:
            raise RecordingError(
                f"{path}:1: column {number} {name!r} is not <AXIS>_<signal> with a known "
                f"signal ({', '.join(SIGNAL_UNITS)})"
            )
        if channel in channels:
            raise RecordingError(f"{path}:1: column {number} {name!r} appears twice")
        channels.append(channel)
    return channels


def _csv_line_error(path: Path, lines: Sequence[str], first_line: int, names: Sequence[str]) -> str:
    """Find the first bad line of a chunk the fast parser refused, as ``file:line: problem``."""
    for offset, line in enumerate(lines):
        text = line.rstrip("\r\n")
        if not text.strip():
            continue
        cells = text.split(",")
        where = f"{path}:{first_line + offset}"
        if len(cells) != len(names):
            return f"{where}: {len(cells)} cells, expected {len(names)} ({', '.join(names)})"
        for name, cell in zip(names, cells, strict=True):
            try:
                float(cell)
            except ValueError:
                return f"{where}: column {name}: {cell.strip()!r} is not a number"
    return f"{path}:{first_line}-{first_line + len(lines) - 1}: cannot be read as numbers"


def _line_numbers(lines: Sequence[str], first_line: int) -> list[int]:
    """File line number of every data row of a chunk (blank lines hold no row)."""
    return [first_line + i for i, line in enumerate(lines) if line.strip()]


def _csv_where(path: Path, lines: Sequence[str], first_line: int) -> Callable[[int], str]:
    """``file:line`` of the data row at an index of a chunk (blank lines hold no row)."""

    def where(index: int) -> str:
        return f"{path}:{_line_numbers(lines, first_line)[index]}"

    return where


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
    chunk by chunk, so an import keeps at most one chunk in memory (and the
    times, for the period). An import that fails calls :meth:`discard`, which
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
            notes, link, start_utc, ...).
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
        self.meta = meta
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
        self._times: list[NDArray[np.float64]] = []
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
        self._times.append(np.array(time_s, dtype=np.float64))
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
        self.writer.append(SampleBlock(time_s, values))
        self.writer.flush()

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
        writer.close(status, **updates)
        log.info("imported into %s: %d samples", self.directory, writer.rows_written)
        return Recording.open(self.directory)

    def validity_lines(self) -> list[str]:
        """One sentence per channel whose values were left out as not physically possible."""
        return self.validity.lines()

    def discard(self) -> None:
        """Remove the files this import wrote and, if the import made it, the directory."""
        if self.writer is None:
            return
        with contextlib.suppress(RecordingError):
            self.writer.close("failed")
        for name in (META_FILE, SAMPLES_FILE, EVENTS_FILE, META_FILE + ".tmp"):
            with contextlib.suppress(OSError):
                (self.directory / name).unlink()
        if not self.existed:
            with contextlib.suppress(OSError):
                self.directory.rmdir()

    def _median_step_s(self) -> float:
        times = np.concatenate(self._times) if self._times else np.empty(0)
        if len(times) < 2:
            raise RecordingError(
                f"{self.directory}: {self.what} holds a single sample and no sample period; "
                "a recording needs at least two (or pass nominal_period_s)"
            )
        return float(np.median(np.diff(times)))


def import_csv(
    path: PathArg,
    directory: PathArg,
    *,
    machine: MachineConfig | None = None,
    nominal_period_s: float | None = None,
) -> Recording:
    """Make a recording from a CSV file in the layout of :func:`export_csv`.

    The header names ``time_s`` and the channels (``<AXIS>_<signal>``, e.g.
    ``X_current_a``; units follow from the signal). The file is read in chunks
    with numpy's parser, which reads the shortest float reprs back bit-exact.

    Args:
        path: The CSV file.
        directory: The new recording (must not exist or be empty).
        machine: The machine file, for the axis data in ``meta.json``.
        nominal_period_s: The sample period; the median time step when not given.

    Returns:
        The new recording, read back.

    Raises:
        RecordingError: ``file:line: problem`` for a bad header, a row with the
            wrong number of cells, a cell that is not a number, or times that do
            not increase; or the recording cannot be written. What the import
            wrote is removed again then.
    """
    source = Path(path)
    target: ImportSink | None = None
    try:
        with source.open("r", encoding="utf-8") as file:
            channels = _parse_csv_header(source, file.readline())
            names = ["time_s", *(c.name for c in channels)]
            target = ImportSink(
                Path(directory),
                channels,
                machine=machine,
                nominal_period_s=nominal_period_s,
                source="import:csv",
                notes=f"imported from {source.name}",
            )
            line_number = 1
            previous_s = -np.inf
            while lines := list(itertools.islice(file, _IMPORT_CHUNK_ROWS)):
                first_line = line_number + 1
                line_number += len(lines)
                try:
                    data = np.loadtxt(
                        lines, delimiter=",", comments=None, dtype=np.float64, ndmin=2
                    )
                except ValueError as exc:
                    raise RecordingError(_csv_line_error(source, lines, first_line, names)) from exc
                if data.shape[0] == 0:
                    continue
                if data.shape[1] != len(names):
                    raise RecordingError(_csv_line_error(source, lines, first_line, names))
                check_times(data[:, 0], previous_s, _csv_where(source, lines, first_line))
                previous_s = float(data[-1, 0])
                target.append(data[:, 0], data[:, 1:])
        return target.finish()
    except BaseException as exc:
        if target is not None:
            target.discard()
        if isinstance(exc, FileNotFoundError) and target is None:
            raise RecordingError(f"{source}: no such file") from exc
        if isinstance(exc, UnicodeDecodeError):
            raise RecordingError(f"{source}: not a text file (UTF-8 expected)") from exc
        if isinstance(exc, OSError) and not isinstance(exc, RecordingError):
            raise RecordingError(f"{source}: cannot be read ({exc.strerror or exc})") from exc
        raise


# --- MDF4 ------------------------------------------------------------------------------


def _import_asammdf() -> ModuleType:
    try:
        import asammdf
    except ImportError as exc:
        raise DependencyError(f"MDF4 files need the asammdf package: {_MDF_EXTRA}") from exc
    return asammdf


def export_mdf4(recording: Recording | PathArg, path: PathArg) -> Path:
    """Write a recording as an ASAM MDF4 file (one channel group, one time base).

    Channel names and units are kept; ``meta.json`` and ``events.jsonl`` are
    embedded as attachments, so :func:`import_mdf4` restores them.

    Args:
        recording: A recording, or the directory of one.
        path: The ``.mf4`` file to write (replaced if it exists).

    Returns:
        The path written.

    Raises:
        DependencyError: asammdf is not installed (extra ``mdf``).
        RecordingError: The recording cannot be read or the file cannot be written.
    """
    asammdf = _import_asammdf()
    rec = _as_recording(recording)
    target = Path(path)
    events = b"".join(_event_line(event) for event in rec.events)
    meta = json.dumps(rec.meta.model_dump(mode="json"), indent=2, default=str).encode("utf-8")
    try:
        mdf = asammdf.MDF(version="4.10")
        try:
            mdf.header.start_time = dt.datetime.fromisoformat(rec.meta.start_utc)
            signals = [
                asammdf.Signal(
                    samples=np.ascontiguousarray(rec.values[:, index]),
                    timestamps=rec.time_s,
                    name=channel.name,
                    unit=channel.unit,
                    comment=f"axis {channel.axis}, {channel.signal}",
                )
                for index, channel in enumerate(rec.channels)
            ]
            mdf.append(
                signals,
                acq_name=rec.meta.source or "ncmeasure",
                comment=f"ncmeasure recording of {rec.meta.machine or 'a machine'}",
                common_timebase=True,
            )
            mdf.attach(meta, file_name=META_FILE, comment="ncmeasure recording metadata",
                       mime="application/json")  # fmt: skip
            mdf.attach(events, file_name=EVENTS_FILE, comment="ncmeasure link events",
                       mime="application/x-ndjson")  # fmt: skip
            mdf.save(target, overwrite=True)
        finally:
            mdf.close()
    except OSError as exc:
        raise RecordingError(f"{target}: cannot be written ({exc.strerror or exc})") from exc
    except Exception as exc:  # asammdf's own errors
        raise RecordingError(f"{target}: cannot be written as MDF4 ({exc})") from exc
    log.info("exported %d samples of %s to %s", len(rec), rec.directory, target)
    return target


def _mdf_attachments(mdf: Any, path: Path) -> tuple[dict[str, Any] | None, list[LinkEvent]]:
    """The ``meta.json`` and events that :func:`export_mdf4` embedded, where present."""
    meta: dict[str, Any] | None = None
    events: list[LinkEvent] = []
    for index in range(len(mdf.attachments)):
        try:
            data, name, _ = mdf.extract_attachment(index)
        except Exception as exc:  # a foreign or broken attachment is not ours to read
            log.debug("%s: attachment %d skipped: %s", path, index, exc)
            continue
        if Path(name).name == META_FILE:
            with contextlib.suppress(ValueError):
                loaded = json.loads(bytes(data))
                if isinstance(loaded, dict) and loaded.get("format") == FORMAT_NAME:
                    meta = loaded
        elif Path(name).name == EVENTS_FILE:
            for line in bytes(data).splitlines():
                try:
                    events.append(_EventRecord.model_validate_json(line).to_event())
                except ValidationError:
                    log.warning("%s: an embedded event cannot be read: %r", path, line[:80])
    return meta, events


def import_mdf4(
    path: PathArg,
    directory: PathArg,
    *,
    machine: MachineConfig | None = None,
    nominal_period_s: float | None = None,
) -> Recording:
    """Make a recording from an MDF4 file written by :func:`export_mdf4` or a similar tool.

    Every channel other than the time masters must be named
    ``<AXIS>_<signal>``, have the unit of its signal (or none) and share one
    time base. Metadata and events embedded by :func:`export_mdf4` are kept.

    Args:
        path: The MDF file.
        directory: The new recording (must not exist or be empty).
        machine: The machine file, for the axis data in ``meta.json``
            (default: the embedded metadata's axes, if any).
        nominal_period_s: The sample period; the embedded value or else the
            median time step when not given.

    Returns:
        The new recording, read back.

    Raises:
        DependencyError: asammdf is not installed (extra ``mdf``).
        RecordingError: The file cannot be read, a channel name or unit does
            not fit, the channels have different time bases, or the recording
            cannot be written.
    """
    asammdf = _import_asammdf()
    source = Path(path)
    target = Path(directory)
    if not source.is_file():
        raise RecordingError(f"{source}: no such file")
    try:
        mdf = asammdf.MDF(source)
    except Exception as exc:  # asammdf raises many kinds for a foreign or broken file
        raise RecordingError(f"{source}: not a readable MDF file ({exc})") from exc
    try:
        embedded, events = _mdf_attachments(mdf, source)
        found: list[tuple[Channel, int, int]] = []
        for group_index, group in enumerate(mdf.groups):
            master = mdf.masters_db.get(group_index)
            for channel_index, mdf_channel in enumerate(group.channels):
                if channel_index == master:
                    continue
                channel = channel_from_name(mdf_channel.name)
                if channel is None:
                    raise RecordingError(
                        f"{source}: channel {mdf_channel.name!r} (group {group_index}) is not "
                        f"<AXIS>_<signal> with a known signal ({', '.join(SIGNAL_UNITS)})"
                    )
                unit = mdf_channel.unit
                if unit and unit != channel.unit:
                    raise RecordingError(
                        f"{source}: channel {channel.name} is in {unit!r}; ncmeasure "
                        f"records {channel.signal} in {channel.unit!r}"
                    )
                if channel in (f[0] for f in found):
                    raise RecordingError(f"{source}: channel {channel.name} appears twice")
                found.append((channel, group_index, channel_index))
        if not found:
            raise RecordingError(f"{source}: no data channels")
        signals = [mdf.get(c.name, group=g, index=i, raw=False) for c, g, i in found]
        time_s = np.asarray(signals[0].timestamps, dtype=np.float64)
        for (channel, _, _), signal in zip(found, signals, strict=True):
            if not np.array_equal(np.asarray(signal.timestamps, dtype=np.float64), time_s):
                raise RecordingError(
                    f"{source}: channel {channel.name} has a time base other than "
                    f"{found[0][0].name}'s; ncmeasure needs one time base (resample first)"
                )
        values = np.column_stack([np.asarray(s.samples, dtype=np.float64) for s in signals])
        start_time = mdf.header.start_time
    except RecordingError:
        raise
    except Exception as exc:
        raise RecordingError(f"{source}: cannot be read ({exc})") from exc
    finally:
        mdf.close()

    meta: dict[str, Any] = {"source": "import:mdf4", "notes": f"imported from {source.name}"}
    status: RecordingStatus = "complete"
    if embedded is not None:
        original = {k: embedded.get(k) for k in ("link", "config_hash", "notes")}
        meta.update({k: v for k, v in original.items() if v is not None})
        meta["faster_than_real_time"] = bool(embedded.get("faster_than_real_time", False))
        with contextlib.suppress(TypeError, ValueError):
            scale = float(embedded.get("time_scale", 1.0))
            if np.isfinite(scale) and scale >= 0:
                meta["time_scale"] = scale
        if nominal_period_s is None and embedded.get("nominal_period_s"):
            nominal_period_s = float(embedded["nominal_period_s"])
        if embedded.get("status") in ("interrupted", "link_lost", "failed"):
            status = embedded["status"]
    try:
        start = dt.datetime.fromisoformat(str((embedded or {}).get("start_utc")))
    except ValueError:
        start = start_time if isinstance(start_time, dt.datetime) else dt.datetime.now(dt.UTC)
    if start.tzinfo is None:
        start = start.replace(tzinfo=dt.UTC)
    job = ImportSink(
        target,
        [c for c, _, _ in found],
        machine=machine,
        nominal_period_s=nominal_period_s,
        start_utc=start,
        **meta,
    )
    try:
        check_times(time_s, -np.inf, lambda i: f"{source}: sample {i}")
        for begin in range(0, len(time_s), _IMPORT_CHUNK_ROWS):
            end = begin + _IMPORT_CHUNK_ROWS
            job.append(time_s[begin:end], values[begin:end])
        updates: dict[str, Any] = {}
        if machine is None and embedded is not None:
            updates = {"machine": embedded.get("machine"), "axes": embedded.get("axes") or []}
        if events:
            writer = job.ensure_writer()
            for event in events:
                writer.add_event(event)
        return job.finish(status, **updates)
    except BaseException:
        job.discard()
        raise
