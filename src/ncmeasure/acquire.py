"""The acquisition service: a drive link -> a crash-safe recording, with progress.

:func:`acquire` moves blocks from an open link into a recording writer until
a duration, the end of the schedule, the end of the source, a stop request
(Ctrl-C / SIGTERM in the CLI), or a link failure. Every one of these paths
closes the recording with a status that says how it ended, so nothing
received is ever lost. :func:`record` is the one-call Python API::

    import ncmeasure
    result = ncmeasure.record("machine.toml", duration_s=60, out="run1")

Durations and time stamps are on the link's clock: real time for real
drives, simulated time for ncmeasure's own simulated drives
(``clock=SimulatedClock()``: link and simulator in lockstep, as fast as the
computer allows; the recording's metadata says so, ``link.clock`` and
``time_scale`` 0). The duration is checked against the link's own time
(:meth:`~ncmeasure.links.base.DriveLink.now_s`) whether rows arrive or not,
so a recording of drives that fall silent still ends on time.

A recording is ``complete`` only without gaps: one that lost samples ends
``incomplete``, with the gaps in its events and their number in ``meta.json``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from ncmeasure.config import MachineConfig, load_machine
from ncmeasure.errors import ConfigError, LinkError, RecordingError
from ncmeasure.formats.identity import check_serial
from ncmeasure.formats.schedule import SCHEDULE_MARGIN_S, Schedule
from ncmeasure.links import DriveLink, make_link
from ncmeasure.recording import RecordingWriter
from ncmeasure.samples import LinkClock, LinkEvent, SampleBlock

__all__ = [
    "AcquisitionResult",
    "Progress",
    "Watch",
    "acquire",
    "check_duration",
    "link_time_scale",
    "record",
]

log = logging.getLogger(__name__)

Status = Literal["complete", "incomplete", "interrupted", "link_lost"]

#: After the duration, rows already on their way are waited for this long (link time).
IN_FLIGHT_S = 1.0

#: In lockstep, the pause after each block read: the rows gather into blocks of many
#: (written at once) instead of one by one, and the simulator's threads keep the CPU
#: (wall-clock seconds; the link holds its rows meanwhile, nothing is lost).
LOCKSTEP_READ_PAUSE_S = 0.02


@dataclass
class Progress:
    """What the live display shows; handed to ``on_progress`` about twice a second."""

    elapsed_s: float
    """Wall-clock time since the link was opened."""
    link_time_s: float
    """Time of the newest row on the link's clock."""
    rows: int
    rows_per_s: float
    latest: dict[str, float]
    """The newest value of every channel, by channel name."""
    gaps: int
    lost_samples: int
    faults: int
    last_event: str | None = None
    skipped_cycles: int = 0
    """Of ``lost_samples``, the cycles the link skipped because the host fell behind."""


EndedBy = Literal["duration", "schedule", "source", "stop", "link", "program", "no_start"]


class Watch(Protocol):
    """Decides which rows a recording keeps and when it ends (``ncmeasure measure``).

    :func:`acquire` hands it every block as it comes; it returns the rows to
    write (none while it waits for a start, a pre-roll with the start) and, once
    the recording is to end, what ended it: ``program`` (the program's end was
    seen), ``schedule`` (its bound) or ``no_start`` (no start came in time).
    """

    def pass_rows(
        self, block: SampleBlock, link_now_s: float | None
    ) -> tuple[SampleBlock, EndedBy | None]:
        """The rows of ``block`` to keep, and what ended the recording (None: go on)."""
        ...


@dataclass
class AcquisitionResult:
    """How a recording ended."""

    directory: Path
    status: Status
    rows: int
    link_time_s: float
    wall_time_s: float
    events: list[LinkEvent] = field(default_factory=list)
    error: str | None = None
    moved_aside: Path | None = None
    """Where an unfinished earlier attempt in the directory was moved (see
    :meth:`RecordingWriter.create`)."""
    ended_by: EndedBy = "stop"
    """What ended the recording: the user's ``duration`` (a limit), the ``schedule``'s
    end with its margin (a guide, when no duration was given), the ``source``'s end
    (a replay), a ``stop`` (Ctrl-C, SIGTERM) or the ``link`` failing."""
    duration_s: float | None = None
    """The user's duration, if one was given."""
    schedule_end_s: float | None = None
    """The schedule's estimated end plus its margin, if a schedule was given."""
    nominal_period_s: float | None = None
    """The link's sample period (the SYNC period of a CANopen link)."""

    @property
    def gaps(self) -> int:
        """Number of gap events."""
        return sum(1 for e in self.events if e.kind == "gap")

    @property
    def lost_samples(self) -> int:
        """Samples the gap events say were lost."""
        return sum(e.lost_samples for e in self.events if e.kind == "gap")

    @property
    def lost_share(self) -> float:
        """Lost samples as a share of the samples there should have been (0 … 1)."""
        total = self.rows + self.lost_samples
        return self.lost_samples / total if total else 0.0

    @property
    def skipped_cycles(self) -> int:
        """Of the lost samples, the cycles the link skipped because the host fell behind
        (SYNC cycles its producer could not send in time; the gap events'
        ``skipped_cycles``)."""
        return sum(int(e.details.get("skipped_cycles", 0)) for e in self.events if e.kind == "gap")

    @property
    def skipped_share(self) -> float:
        """Skipped cycles as a share of the samples there should have been (0 … 1)."""
        total = self.rows + self.lost_samples
        return self.skipped_cycles / total if total else 0.0

    @property
    def achieved_rate_hz(self) -> float | None:
        """The rate the link sampled at, skipped cycles left out (None: no period known)."""
        if not self.nominal_period_s:
            return None
        return (1.0 - self.skipped_share) / self.nominal_period_s


def check_duration(duration_s: float | None, what: str = "duration") -> None:
    """Refuse a duration that is not a positive, finite number of seconds.

    Raises:
        ConfigError: 0, negative, NaN or infinite.
    """
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise ConfigError(
            f"{what} {duration_s!r} s: a recording lasts a positive, finite number of seconds"
        )


def link_time_scale(link: DriveLink) -> float:
    """Seconds of link time per wall-clock second, for a recording's ``time_scale``.

    0 for a link in lockstep with a simulator (as fast as the computer allows)
    and for a replay as fast as possible; the replay's ``speed``; else 1.
    """
    if link.clock.lockstep:
        return 0.0
    speed = getattr(link.settings, "speed", 1.0)
    return float(speed) if isinstance(speed, (int, float)) else 1.0


def acquire(
    link: DriveLink,
    writer: RecordingWriter,
    *,
    duration_s: float | None = None,
    stop: threading.Event | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    progress_interval_s: float = 0.5,
    read_timeout_s: float = 0.2,
    watch: Watch | None = None,
) -> AcquisitionResult:
    """Record from an open ``link`` into ``writer`` until done, then close the writer.

    Args:
        link: An open drive link.
        writer: The recording to append to; closed on return with the status.
        duration_s: Stop once the link's clock has run this long from the first
            row (from the link's start while no row has come); None: no limit.
        stop: Set it (from a signal handler or another thread) to stop early.
        on_progress: Called with a :class:`Progress` every ``progress_interval_s``.
        progress_interval_s: Seconds between progress calls.
        read_timeout_s: Longest wait for data in one read; bounds the reaction
            time to ``stop``.
        watch: Keeps only the rows it passes and may end the recording (see
            :class:`Watch`); None: every row is kept.

    Returns:
        The result; ``status`` is ``complete`` (duration or end of source, no
        gap), ``incomplete`` (the same, but samples were lost), ``interrupted``
        (stop was set) or ``link_lost`` (the link failed; the rows received
        until then are in the recording).

    Raises:
        ConfigError: ``duration_s`` is not a positive, finite number.
        RecordingError: The recording cannot be written (a full disk): it is
            closed with what is on disk, and the message says how much that is.
    """
    check_duration(duration_s)
    stop = stop or threading.Event()
    started = time.monotonic()
    meter = _ProgressMeter(on_progress, progress_interval_s, started)
    rows = 0
    first_time_s: float | None = None
    link_time_s = 0.0
    latest: dict[str, float] = {}
    events: list[LinkEvent] = []
    names = [c.name for c in link.channels]
    status: Status = "interrupted"
    error: str | None = None

    def take_events() -> None:
        for event in link.events():
            events.append(event)
            writer.add_event(event)

    reached_end = False
    ended_by: EndedBy = "stop"
    lockstep = link.clock.lockstep
    try:
        while not stop.is_set() and not reached_end:
            block = link.read(timeout_s=read_timeout_s)
            take_events()
            if block is None:
                reached_end, ended_by = True, "source"  # the source has no more data
                break
            if duration_s is not None:
                if len(block) and first_time_s is None:
                    first_time_s = float(block.time_s[0])
                block, reached_end = _until_end(link, block, (first_time_s or 0.0) + duration_s)
                ended_by = "duration" if reached_end else ended_by
            if watch is not None and not reached_end:
                block, watch_end = watch.pass_rows(block, link.now_s())
                if watch_end is not None:
                    reached_end, ended_by = True, watch_end
            if len(block):
                writer.append(block)
                rows += len(block)
                link_time_s = float(block.time_s[-1])
                latest = dict(zip(names, block.values[-1].tolist(), strict=True))
            meter.tick(rows, link_time_s, latest, events)
            if lockstep and len(block):
                stop.wait(LOCKSTEP_READ_PAUSE_S)
        status = "complete" if reached_end else "interrupted"
    except RecordingError:
        # The disk refused the rows. close() raises in its turn while it still does,
        # saying what is kept on disk; that message replaces this one.
        writer.close(status="failed")
        raise
    except LinkError as exc:
        status, error, ended_by = "link_lost", str(exc), "link"
        log.error("link lost: %s", exc)
        try:
            take_events()  # the failing link's last words, if it still has them
        except Exception:
            log.exception("could not collect the link's last events")
    finally:
        writer.close(status=status)  # a no-op after a failure: closed above
    if status == "complete" and any(e.kind == "gap" for e in events):
        status = "incomplete"
    return AcquisitionResult(
        directory=writer.directory,
        status=status,
        rows=rows,
        link_time_s=link_time_s,
        wall_time_s=time.monotonic() - started,
        events=events,
        error=error,
        moved_aside=writer.moved_aside,
        ended_by=ended_by,
        duration_s=duration_s,
        nominal_period_s=link.nominal_period_s,
    )


def _until_end(link: DriveLink, block: SampleBlock, end_s: float) -> tuple[SampleBlock, bool]:
    """The rows of ``block`` before ``end_s`` on the link's clock, and whether the end came.

    The end has come when a row reaches it, or when the link has no row
    waiting and its own time is :data:`IN_FLIGHT_S` past it.
    """
    reached_end = False
    cut = int(np.searchsorted(block.time_s, end_s, "left"))
    if cut < len(block):
        block = SampleBlock(block.time_s[:cut], block.values[:cut])
        reached_end = True
    now_s = link.now_s() if not len(block) else None
    if now_s is not None and now_s >= end_s + IN_FLIGHT_S:
        # nothing is waiting in the link and its time is past the end: the
        # drives fell silent (a link ahead of its reader still has rows)
        reached_end = True
    return block, reached_end


class _ProgressMeter:
    """Hands a :class:`Progress` to ``on_progress`` every ``interval_s`` of wall-clock time."""

    def __init__(
        self, on_progress: Callable[[Progress], None] | None, interval_s: float, started: float
    ) -> None:
        self._on_progress = on_progress
        self._interval_s = interval_s
        self._started = started
        self._next = started + interval_s
        # the rate is taken over the last few progress calls
        self._rate_window: list[tuple[float, int]] = [(started, 0)]

    def tick(
        self, rows: int, link_time_s: float, latest: dict[str, float], events: list[LinkEvent]
    ) -> None:
        """Report progress if it is time to."""
        now = time.monotonic()
        if self._on_progress is None or now < self._next:
            return
        self._rate_window = [*self._rate_window, (now, rows)][-6:]
        (t0, r0), (t1, r1) = self._rate_window[0], self._rate_window[-1]
        self._on_progress(
            Progress(
                elapsed_s=now - self._started,
                link_time_s=link_time_s,
                rows=rows,
                rows_per_s=(r1 - r0) / (t1 - t0) if t1 > t0 else 0.0,
                latest=latest,
                gaps=sum(1 for e in events if e.kind == "gap"),
                lost_samples=sum(e.lost_samples for e in events),
                faults=sum(1 for e in events if e.kind in ("fault", "emcy")),
                last_event=f"{events[-1].kind}: {events[-1].message}" if events else None,
                skipped_cycles=sum(
                    int(e.details.get("skipped_cycles", 0)) for e in events if e.kind == "gap"
                ),
            )
        )
        self._next = now + self._interval_s


def record(
    machine: MachineConfig | str | Path,
    *,
    out: str | Path,
    link: str | None = None,
    link_settings: Mapping[str, Any] | None = None,
    axis_settings: Mapping[str, Mapping[str, Any]] | None = None,
    duration_s: float | None = None,
    schedule: Schedule | None = None,
    schedule_margin_s: float = SCHEDULE_MARGIN_S,
    notes: str = "",
    stop: threading.Event | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    clock: LinkClock | None = None,
    watch: Callable[[DriveLink], Watch] | None = None,
    serial: str | None = None,
) -> AcquisitionResult:
    """Record a machine's drives into the recording directory ``out``.

    Args:
        machine: The machine (file or loaded config); its ``[link]`` table
            says which link and how, unless ``link``/``link_settings`` say otherwise.
        out: New recording directory.
        link: Link type (``canopen``, ``modbus``, ``replay``, or a registered one).
        link_settings: Link settings overriding the machine file's.
        axis_settings: Per-axis link settings by axis name (e.g. node ids).
        duration_s: How long to record, on the link's clock.
        schedule: The measurement's schedule: the recording carries its config
            hash, and without ``duration_s`` it stops after the schedule's
            estimated duration plus ``schedule_margin_s`` (a guide: a program slowed
            by the override or a feed hold runs longer). ``duration_s`` is a limit
            and wins; the result says which ended the recording.
        schedule_margin_s: Extra time after the schedule's end.
        notes: Free text stored with the recording.
        stop: Set it to stop early.
        on_progress: Progress callback (see :class:`Progress`).
        clock: The link's clock: a :class:`~ncmeasure.samples.SimulatedClock`
            for ncmeasure's own simulated drives (lockstep); ``None``: real time.
            ``duration_s`` and the time stamps are on this clock.
        watch: Builds a :class:`Watch` for the opened link (its channels and clock):
            it keeps the rows from a start on and ends the recording; the schedule's
            end is then its business (``duration_s`` stays a limit).
        serial: The serial number of the machine measured (its machine file names
            the type): it goes into ``meta.json`` and from there into the results.

    Raises:
        ConfigError: bad machine file, link settings or serial number.
        LinkError: the link cannot be opened (nothing is recorded then).
        RecordingError: the recording cannot be created or written (see
            :func:`acquire`).
    """
    check_duration(duration_s)
    if serial is not None:
        check_serial(serial)
    config = machine if isinstance(machine, MachineConfig) else load_machine(machine)
    drive_link = make_link(config, link, link_settings, axis_settings)
    if clock is not None:
        drive_link.use_clock(clock)
    if schedule is not None:
        names = {a.name for a in schedule.axes}
        unknown = names - {a.name for a in config.axes}
        if unknown:
            raise ConfigError(
                f"the schedule moves axes {', '.join(sorted(unknown))} that the machine lacks"
            )
        schedule_end_s = schedule.duration_s + schedule_margin_s
    else:
        schedule_end_s = None
    limit_s = duration_s if duration_s is not None or watch else schedule_end_s
    # The link opens first: a drive that cannot be reached leaves no empty recording behind.
    time_scale = link_time_scale(drive_link)
    drive_link.open()
    try:
        writer = RecordingWriter.create(
            out,
            drive_link.channels,
            nominal_period_s=drive_link.nominal_period_s,
            machine=config,
            serial=serial,
            link=drive_link.describe(),
            config_hash=schedule.config_hash if schedule else None,
            notes=notes,
            source=drive_link.name,
            faster_than_real_time=time_scale != 1.0 or drive_link.clock.lockstep,
            time_scale=time_scale,
        )
        result = acquire(
            drive_link,
            writer,
            duration_s=limit_s,
            stop=stop,
            on_progress=on_progress,
            watch=watch(drive_link) if watch is not None else None,
        )
    finally:
        drive_link.close()
    result.duration_s = duration_s
    result.schedule_end_s = schedule_end_s
    if result.ended_by == "duration" and duration_s is None and watch is None:
        result.ended_by = "schedule"
    return result
