"""ASAM MDF4 exchange (the optional extra ``mdf``): a recording as one MDF4 file and back.

:func:`export_mdf4` embeds ``meta.json`` and ``events.jsonl`` as attachments, so
:func:`import_mdf4` restores them; a foreign MDF4 file whose channels are named
``<AXIS>_<signal>`` imports too.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import logging
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from ncmeasure.errors import DependencyError, RecordingError
from ncmeasure.files import replace_by_path
from ncmeasure.formats.recording import FORMAT_NAME, EventRecord, RecordingStatus
from ncmeasure.recording.format import (
    EVENTS_FILE,
    IMPORT_CHUNK_ROWS,
    META_FILE,
    PathArg,
    channel_from_name,
    event_line,
)
from ncmeasure.recording.reader import Recording, RecordingHead, rows_of
from ncmeasure.recording.sink import ImportSink, check_times
from ncmeasure.samples import SIGNAL_UNITS, Channel, LinkEvent

if TYPE_CHECKING:  # the machine-file models: exporting a recording reads no machine file
    from ncmeasure.config import MachineConfig

log = logging.getLogger(__name__)

_MDF_EXTRA = "pip install 'ncmeasure[mdf]'"


def _import_asammdf() -> ModuleType:
    try:
        import asammdf
    except ImportError as exc:
        raise DependencyError(f"MDF4 files need the asammdf package: {_MDF_EXTRA}") from exc
    return asammdf


def export_mdf4(recording: Recording | RecordingHead | PathArg, path: PathArg) -> Path:
    """Write a recording as an ASAM MDF4 file (one channel group, one time base).

    Channel names and units are kept; ``meta.json`` and ``events.jsonl`` are
    embedded as attachments, so :func:`import_mdf4` restores them. A recording
    given by its directory (or head) is read and appended chunk by chunk
    (asammdf keeps the samples in a temporary file until it saves).

    Args:
        recording: A recording, its head, or its directory. A head's ``rows``
            and ``problems`` are filled in by the export.
        path: The ``.mf4`` file to write (replaced if it exists).

    Returns:
        The path written.

    Raises:
        DependencyError: asammdf is not installed (extra ``mdf``).
        RecordingError: The recording cannot be read or the file cannot be written.
    """
    asammdf = _import_asammdf()
    rec, chunks = rows_of(recording, IMPORT_CHUNK_ROWS)
    target = Path(path)
    meta = json.dumps(rec.meta.model_dump(mode="json"), indent=2, default=str).encode("utf-8")
    count = 0
    try:
        mdf = asammdf.MDF(version="4.10")
        try:
            if rec.meta.start_utc is not None:  # unknown: the embedded meta.json says so
                mdf.header.start_time = dt.datetime.fromisoformat(rec.meta.start_utc)

            def first_group(time_s: np.ndarray, values: np.ndarray) -> None:
                mdf.append(
                    [
                        asammdf.Signal(
                            samples=np.ascontiguousarray(values[:, index]),
                            timestamps=time_s,
                            name=channel.name,
                            unit=channel.unit,
                            comment=f"axis {channel.axis}, {channel.signal}",
                        )
                        for index, channel in enumerate(rec.channels)
                    ],
                    acq_name=rec.meta.source or "ncmeasure",
                    comment=f"ncmeasure recording of {rec.meta.machine or 'a machine'}",
                    common_timebase=True,
                )

            for chunk in chunks:
                if count == 0:
                    first_group(chunk.time_s, chunk.values)
                else:
                    columns = chunk.values.T
                    mdf.extend(
                        0,
                        [(chunk.time_s, None), *((np.ascontiguousarray(c), None) for c in columns)],
                    )
                count += len(chunk.time_s)
            if count == 0:
                first_group(np.empty(0), np.empty((0, len(rec.channels))))
            events = b"".join(event_line(event) for event in rec.events)
            mdf.attach(meta, file_name=META_FILE, comment="ncmeasure recording metadata",
                       mime="application/json")  # fmt: skip
            mdf.attach(events, file_name=EVENTS_FILE, comment="ncmeasure link events",
                       mime="application/x-ndjson")  # fmt: skip
            # asammdf opens the path itself and writes .mf4 files: a temporary one,
            # renamed to the name asked for once it is whole
            with replace_by_path(target, suffix=".mf4") as temporary:
                mdf.save(temporary, overwrite=True)
        finally:
            mdf.close()
    except RecordingError:
        raise
    except OSError as exc:
        raise RecordingError(f"{target}: cannot be written ({exc.strerror or exc})") from exc
    except Exception as exc:  # asammdf's own errors
        raise RecordingError(f"{target}: cannot be written as MDF4 ({exc})") from exc
    log.info("exported %d samples of %s to %s", count, rec.directory, target)
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
                    events.append(EventRecord.model_validate_json(line).to_event())
                except ValidationError:
                    log.warning("%s: an embedded event cannot be read: %r", path, line[:80])
    return meta, events


def import_mdf4(
    path: PathArg,
    directory: PathArg,
    *,
    machine: MachineConfig | None = None,
    nominal_period_s: float | None = None,
    measured_at: dt.datetime | None = None,
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
        measured_at: When the machine was measured; default: the embedded
            metadata's start, else the file header's.

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
        found = _mdf_channels(mdf, source)
        time_s, values = _mdf_samples(mdf, source, found)
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
        meta.update(_embedded_meta(embedded))
        if nominal_period_s is None and embedded.get("nominal_period_s"):
            nominal_period_s = float(embedded["nominal_period_s"])
        if embedded.get("status") in ("incomplete", "interrupted", "link_lost", "failed"):
            status = embedded["status"]
    start = measured_at or _start_time(embedded, start_time)
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
        for begin in range(0, len(time_s), IMPORT_CHUNK_ROWS):
            end = begin + IMPORT_CHUNK_ROWS
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


def _mdf_channels(mdf: Any, source: Path) -> list[tuple[Channel, int, int]]:
    """The data channels of the file with their group and index (time masters left out).

    Raises:
        RecordingError: A channel's name or unit does not fit, a channel
            appears twice, or there is none.
    """
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
    return found


def _mdf_samples(
    mdf: Any, source: Path, found: list[tuple[Channel, int, int]]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The channels' common time base and their values, one column each.

    Raises:
        RecordingError: The channels do not share one time base.
    """
    signals = [mdf.get(c.name, group=g, index=i, raw=False) for c, g, i in found]
    time_s = np.asarray(signals[0].timestamps, dtype=np.float64)
    for (channel, _, _), signal in zip(found, signals, strict=True):
        if not np.array_equal(np.asarray(signal.timestamps, dtype=np.float64), time_s):
            raise RecordingError(
                f"{source}: channel {channel.name} has a time base other than "
                f"{found[0][0].name}'s; ncmeasure needs one time base (resample first)"
            )
    values = np.column_stack([np.asarray(s.samples, dtype=np.float64) for s in signals])
    return time_s, values


def _start_time(embedded: dict[str, Any] | None, header_time: Any) -> dt.datetime | None:
    """When the measurement began: the embedded metadata's start (None there: it was
    unknown), else the file header's measurement start; never the time of the import."""
    when: Any = header_time
    if embedded is not None and "start_utc" in embedded:
        when = None
        with contextlib.suppress(TypeError, ValueError):
            when = dt.datetime.fromisoformat(embedded["start_utc"])
    if not isinstance(when, dt.datetime):
        return None
    return when if when.tzinfo is not None else when.replace(tzinfo=dt.UTC)


def _embedded_meta(embedded: dict[str, Any]) -> dict[str, Any]:
    """The fields of embedded metadata that the new recording keeps."""
    original = {k: embedded.get(k) for k in ("link", "config_hash", "notes", "serial")}
    meta: dict[str, Any] = {k: v for k, v in original.items() if v is not None}
    meta["faster_than_real_time"] = bool(embedded.get("faster_than_real_time", False))
    with contextlib.suppress(TypeError, ValueError):
        scale = float(embedded.get("time_scale", 1.0))
        if np.isfinite(scale) and scale >= 0:
            meta["time_scale"] = scale
    return meta
