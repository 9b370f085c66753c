"""The recording format on disk: file names, frame layout, metadata and event lines.

A recording is a directory of three files::

    meta.json      what was recorded: machine, axes, link, channels, status (RecordingMeta)
    samples.bin    append-only frames of float64 rows: time_s, then one column per channel
    events.jsonl   one LinkEvent per line: gaps, faults, reboots, reconnects

The format is described byte by byte in ``docs/recording-format.md``; the
writer (:mod:`.writer`) and the reader (:mod:`.reader`) share what is here.
"""

from __future__ import annotations

import datetime as dt
import errno
import json
import logging
import os
import re
import struct
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ncmeasure.errors import RecordingError
from ncmeasure.files import replace_text
from ncmeasure.formats.axis import AXIS_NAME_PATTERN
from ncmeasure.formats.recording import RecordedAxis, RecordingMeta
from ncmeasure.samples import SIGNAL_UNITS, Channel, LinkEvent

if TYPE_CHECKING:  # the machine-file models: reading or exporting a recording needs none
    from ncmeasure.config import AxisConfig, MachineConfig

try:  # advisory locks tell a reader that a writer is still at work (POSIX only)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger(__name__)

PathArg = str | os.PathLike[str]

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
ROW_DTYPE = np.dtype("<f8")
IMPORT_CHUNK_ROWS = 100_000

# --- metadata --------------------------------------------------------------------------


def axis_metadata(axis: AxisConfig) -> RecordedAxis:
    """The facts about an axis that the analysis of a recording needs.

    Args:
        axis: An axis of the machine file.

    Returns:
        Its mechanics, with the maximum and rapid velocity (they tell rapids and
        impossible values apart).
    """
    return RecordedAxis(
        name=axis.name,
        **axis.mechanics().model_dump(),
        max_velocity_mm_min=axis.max_velocity_mm_min,
        rapid_velocity_mm_min=axis.rapid_mm_min,
    )


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


def now_utc() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")


def fsync_directory(directory: Path) -> None:
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


_DISK_FULL = frozenset(
    code for code in (errno.ENOSPC, getattr(errno, "EDQUOT", None)) if code is not None
)


def write_failure(directory: Path, what: str, exc: OSError) -> str:
    """Why ``what`` of the recording ``directory`` could not be written, for a message.

    A full disk or an exhausted quota (ENOSPC, EDQUOT) reads ``disk full``, a file
    size limit (EFBIG) ``file size limit reached``; the recording is named first.
    """
    reason = exc.strerror or str(exc)
    if exc.errno in _DISK_FULL:
        return f"{directory}: disk full ({reason}) while writing {what}"
    if exc.errno == errno.EFBIG:
        return f"{directory}: file size limit reached ({reason}) while writing {what}"
    return f"{directory}: {what} cannot be written ({reason})"


def write_meta(directory: Path, meta: RecordingMeta) -> None:
    """Replace ``meta.json`` atomically: a reader sees the old or the new file, whole.

    Raises:
        RecordingError: The file cannot be written (the old one stays, no
            temporary file is left behind).
    """
    path = directory / META_FILE
    text = json.dumps(meta.model_dump(mode="json"), indent=2, ensure_ascii=False, default=str)
    try:
        with replace_text(path, fsync=True) as file:
            file.write(text + "\n")
    except OSError as exc:
        raise RecordingError(write_failure(directory, META_FILE, exc)) from exc
    fsync_directory(directory)


def is_being_written(path: Path) -> bool | None:
    """True while a writer holds ``samples.bin`` (``path``); None where that cannot be told."""
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


def event_line(event: LinkEvent) -> bytes:
    record = {
        "time_s": float(event.time_s),
        "kind": event.kind,
        "message": event.message,
        "axis": event.axis,
        "lost_samples": int(event.lost_samples),
        "details": dict(event.details),
    }
    return (json.dumps(record, ensure_ascii=False, default=str) + "\n").encode("utf-8")
