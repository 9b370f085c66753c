"""CAN logs of a CANopen bus (``.blf``, ``.asc``, ``.log``, ``.trc``, ...) become recordings.

A log written by any CAN tool (or by ``ncmeasure record --raw-log``) holds the
frames in the order they were on the bus; python-can's log readers
(``can.LogReader``) give them back. The machine file's ``[link]`` table (type
``canopen``) says how to read them, exactly as the CANopen link reads the live
bus (:meth:`~ncmeasure.links.canopen.link.CanOpenLink.decode_frames`): which
nodes, which TPDO layout (the controller's DCF or ``tpdo`` tables when the link
only listens, else the layout ncmeasure configures), the scale factors. Each
SYNC in the log starts a cycle; a PDO frame belongs to the SYNC before it; a
cycle that cannot be told apart is dropped and counted as a gap. A log that
ncmeasure wrote while recording gives the same samples as the recording made
live.
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Final

from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.traces.job import ImportJob

if TYPE_CHECKING:
    # python-can and canopen load when a CAN log is read, not for every import.
    import can

__all__ = ["CAN_LOG_SUFFIXES", "import_can_log", "is_can_log"]

log = logging.getLogger(__name__)

#: File endings of the CAN logs python-can reads (Vector BLF and ASC, candump, PCAN TRC).
CAN_LOG_SUFFIXES: Final = (".blf", ".asc", ".log", ".trc")
#: Time stamps from here on (2001-09-09) are seconds since 1970 (BLF, candump), the
#: measurement's date; smaller ones count from the log's start (ASC), and give no date.
ABSOLUTE_AFTER_S: Final = 1e9


def is_can_log(path: Path) -> bool:
    """True when ``path`` ends like a CAN log python-can reads."""
    return path.suffix.lower() in CAN_LOG_SUFFIXES


def _frames(job: ImportJob, counts: dict[str, int]) -> Iterator[can.Message]:
    """The log's frames, counted."""
    import can

    try:
        reader: Iterable[can.Message] = can.LogReader(str(job.path))
    except (ValueError, NotImplementedError) as exc:
        raise RecordingError(
            f"{job.path}: python-can reads no CAN log of this kind ({exc}); "
            f"supported endings: {', '.join(CAN_LOG_SUFFIXES)}"
        ) from exc
    try:
        for msg in reader:
            counts["frames"] += 1
            if counts["frames"] == 1 and msg.timestamp >= ABSOLUTE_AFTER_S:
                # read before the first row is written: the recording starts with it
                job.found_start(
                    dt.datetime.fromtimestamp(msg.timestamp, dt.UTC), "the first frame's time stamp"
                )
            yield msg
    except (ValueError, EOFError, IndexError, can.CanError) as exc:
        raise RecordingError(
            f"{job.path}: the CAN log is damaged after {counts['frames']} frames ({exc})"
        ) from exc
    finally:
        stop = getattr(reader, "stop", None)
        if callable(stop):
            stop()


def import_can_log(job: ImportJob) -> RecordingMeta:
    """Decode the CAN log of ``job`` with its machine file's CANopen link settings.

    Raises:
        ConfigError: no machine file, or its link is not CANopen, or its settings
            cannot decode a log (no rated current, no COB-ID).
        RecordingError: the log cannot be read, or holds no complete SYNC cycle.
    """
    machine = job.machine
    if machine is None or (machine.link or {}).get("type") != "canopen":
        raise ConfigError(
            f"{job.path}: a CAN log is read with the machine file's CANopen settings: "
            "--machine m.toml with [link] type = 'canopen' and a node_id per axis"
        )

    from ncmeasure.links import make_link  # the links' settings models: a CAN log only
    from ncmeasure.links.canopen.link import CanOpenLink

    link = make_link(machine)
    assert isinstance(link, CanOpenLink)
    job.link = {**link.describe(), "type": "import", "format": "can-log", "file": job.path.name}
    sink = job.open_sink(link.channels, nominal_period_s=link.nominal_period_s)
    counts = {"frames": 0}
    lost = gaps = 0
    for block, events in link.decode_frames(_frames(job, counts)):
        if len(block):
            sink.append(block.time_s, block.values)
        for event in events:
            if event.kind == "gap":
                gaps += 1
                lost += event.lost_samples
            sink.ensure_writer().add_event(event)
    stats = link.statistics()
    if sink.rows == 0:
        raise RecordingError(
            f"{job.path}: {counts['frames']} frames, but no complete SYNC cycle of the nodes "
            f"{', '.join(str(a['node_id']) for a in job.link['axes'].values())} "
            "(node ids, TPDO layout and SYNC in the machine file's [link] table?)"
        )
    job.note(
        f"{counts['frames']} frames: {stats['sync_cycles']} SYNC cycles, "
        f"{stats['pdo_frames']} PDO frames of the axes' drives, {sink.rows} rows"
    )
    if gaps:
        job.note(f"{lost} samples lost in {gaps} gap(s); the gap events say where and why")
    return job.finish()
