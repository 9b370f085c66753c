"""``ncmeasure measure``: the whole path at the machine, from cycle start to the verdict.

The technician's path at a real machine is ``generate`` → the setup sheet →
``measure``. :func:`load_programs` checks that the programs folder is the one
the machine file generates (``schedule.json``'s config hash is the file's);
:func:`record_program` opens the link (:func:`~ncmeasure.acquire.record`) and
records one run of the program with a :class:`ProgramWatch`:

- **Start.** Where the link records a marker channel (``<AXIS>_marker``) and
  the schedule has a marker, the marker's first edge; else the first motion of
  an axis of the schedule (its velocity above half the smallest velocity it is
  measured at, or its position leaving where it stood). Before the start only
  :data:`PRE_ROLL_S` of rows are kept.
- **Windows passed.** Each axis' windows in turn: by the marker's falling
  edges where it is recorded (a span counts for the axis that moved during it:
  one marker output is often wired to every drive's input), else when the axis
  crosses the window's end in its direction. The program time each one is passed at, against the
  schedule's, gives the slowing (the override below 100 %, feed holds).
- **End.** Every axis back at its park and still for :data:`STILL_S` after
  the last window (with or without the marker: the run-out and the return to
  park follow the marker's last fall); then :data:`POST_ROLL_S` more.
  Bounded by the schedule's duration times the measured slowing plus
  :data:`~ncmeasure.formats.schedule.SCHEDULE_MARGIN_S`.

:func:`evaluate` then does what ``analyze --store --serial --report`` does, and
compares: the analysis, ``results.json``, the measurement in the fleet store
(measured at the program's start), the machine's check against its baseline
(:func:`~ncmeasure.store.check.check_machine`) and the report with that
comparison. The verdict is the worst of the check's status and the axes'
verdicts (check: warning, fault: critical).
"""

from __future__ import annotations

import datetime as dt
import logging
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ncmeasure.acquire import AcquisitionResult, EndedBy, Progress, record
from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError
from ncmeasure.formats.comparison import Limits, Status
from ncmeasure.formats.results import Results, write_results
from ncmeasure.formats.schedule import SCHEDULE_MARGIN_S, Schedule, Window
from ncmeasure.links import DriveLink
from ncmeasure.samples import LinkClock, SampleBlock

__all__ = [
    "POST_ROLL_S",
    "PRE_ROLL_S",
    "SERIES_LOG",
    "SERIES_RETRY_S",
    "STILL_S",
    "Evaluation",
    "ProgramWatch",
    "SeriesLog",
    "WatchState",
    "evaluate",
    "load_programs",
    "read_series_log",
    "record_program",
]

log = logging.getLogger(__name__)

PRE_ROLL_S = 2.0
"""Rows kept from before the start (link time)."""
POST_ROLL_S = 1.0
"""Rows kept after the program's end was seen."""
STILL_S = 1.0
"""How long every axis must stand still at its park for the program to have ended."""
MARKER_GRACE_S = 10.0
"""Time allowed, beyond the schedule's, between the first motion and the marker's first edge:
after it a marker that never rose is taken for a wiring fault and the motion is the start."""
PARK_TOLERANCE_MM = 0.05
"""An axis this close to its park is at it; one that moved farther has left where it stood."""

Phase = Literal["waiting", "running", "ending", "ended"]


def load_programs(programs: Path, machine_file: Path) -> tuple[Schedule, MachineConfig]:
    """The programs' schedule and their machine file, checked to belong together
    (:func:`~ncmeasure.program.check.programs_of`)."""
    from ncmeasure.program.check import programs_of

    return programs_of(programs, machine_file)


@dataclass(frozen=True)
class WatchState:
    """What the watch waits for and how far the program is (for a progress display)."""

    phase: Phase
    text: str
    """In words: what it waits for, or where the program is."""
    windows_passed: int
    windows_total: int
    program_time_s: float | None
    """The program's time since its start (link time), None before the start."""
    schedule_time_s: float | None
    """The schedule's time of the last window passed."""
    slowing: float
    """Measured program time over the schedule's (1: as planned; 1.25: override 80 %)."""


@dataclass
class _Axis:
    name: str
    velocity: int
    position: int
    marker: int | None
    park_mm: float
    threshold_mm_min: float
    t_start_s: float
    windows: list[Window]
    passed: int = 0
    marker_on: bool = False
    stood_mm: float | None = None
    moved_mm: float = 0.0
    """How far the axis must move while the marker is on for the span to be its own: half
    its shortest window (one marker is often wired to every drive's input)."""
    rise_mm: float | None = None
    """Where the axis stood when the marker last rose."""
    armed: bool = False
    """Without a marker: the axis has stood on the start's side of its next window."""


class ProgramWatch:
    """Keeps one run of the program from its start to its end (an acquisition's watch).

    Args:
        channel_names: The link's columns.
        schedule: The program's schedule.
        real_time: The link runs on the wall clock (the start's UTC time is then
            taken back from the link's lag; in lockstep it is the time it was seen).
        margin_s: Time allowed after the schedule's end, slowed as measured.
        start_timeout_s: End without a start after this long (link time); None: wait.

    Raises:
        ConfigError: the link records no velocity or position of a schedule's axis.
    """

    def __init__(
        self,
        channel_names: Sequence[str],
        schedule: Schedule,
        *,
        real_time: bool = True,
        margin_s: float = SCHEDULE_MARGIN_S,
        start_timeout_s: float | None = None,
        pre_roll_s: float = PRE_ROLL_S,
    ) -> None:
        index = {name: i for i, name in enumerate(channel_names)}
        missing = [
            f"{axis.name}_{signal}"
            for axis in schedule.axes
            for signal in ("velocity_mm_min", "position_mm")
            if f"{axis.name}_{signal}" not in index
        ]
        if missing:
            raise ConfigError(
                f"the link records no {', '.join(missing)}: the program's start and end "
                "cannot be seen"
            )
        use_marker = schedule.marker_scope != "none"
        self._axes = [
            _Axis(
                name=axis.name,
                velocity=index[f"{axis.name}_velocity_mm_min"],
                position=index[f"{axis.name}_position_mm"],
                marker=index.get(f"{axis.name}_marker") if use_marker else None,
                park_mm=axis.park_mm,
                threshold_mm_min=0.5 * min((abs(v) for v in axis.velocities_mm_min), default=2.0),
                t_start_s=axis.t_start_s,
                windows=sorted(axis.windows, key=lambda w: w.t_window_end_s),
                moved_mm=0.5
                * min(
                    (abs(w.window_end_mm - w.window_start_mm) for w in axis.windows),
                    default=0.0,
                ),
            )
            for axis in schedule.axes
        ]
        self.by_marker = any(axis.marker is not None for axis in self._axes)
        self.marker_missing = False
        """The marker is recorded but never rose while the axes moved: started by motion."""
        self._motion_s: float | None = None
        self._motion_axis: _Axis | None = None
        first_marked = min(
            (
                (w.t_window_start_s if schedule.marker_scope == "window" else w.t_start_s)
                - axis.t_start_s
                for axis in schedule.axes
                for w in axis.windows[:1]
            ),
            default=0.0,
        )
        self._marker_grace_s = 2.0 * max(0.0, first_marked) + MARKER_GRACE_S
        self._schedule = schedule
        self._real_time = real_time
        self._margin_s = margin_s
        self._start_timeout_s = start_timeout_s
        self._pre_roll_s = pre_roll_s
        self._held: deque[SampleBlock] = deque()
        self._first_s: float | None = None
        self.phase: Phase = "waiting"
        self.start_s: float | None = None
        """The start on the link's clock."""
        self.start_utc: dt.datetime | None = None
        """The start's wall-clock time (UTC)."""
        self.offset_s = 0.0
        """The schedule's time at the start (the marker's first window, an axis' start)."""
        self.slowing = 1.0
        self._last_s: float | None = None
        self._still_since: float | None = None
        self._end_s: float | None = None
        self._last_passed: Window | None = None
        self._last_passed_s: float | None = None
        self.windows_total = sum(len(axis.windows) for axis in self._axes)
        self._last_window_s = max(
            (w.t_window_end_s for axis in self._axes for w in axis.windows), default=0.0
        )

    # --- what it is doing ----------------------------------------------------------------

    @property
    def bound_s(self) -> float | None:
        """The latest end on the link's clock: the schedule, slowed as measured, plus margin."""
        if self.start_s is None:
            return None
        rest = max(0.0, self._schedule.duration_s - self.offset_s)
        return self.start_s + rest * max(1.0, self.slowing) + self._margin_s

    @property
    def bound_text(self) -> str:
        """How the bound is made, in words."""
        rest = max(0.0, self._schedule.duration_s - self.offset_s)
        slowed = (
            f" × {self.slowing:.2f} (the program runs slower than planned: override "
            f"≈ {100 / self.slowing:.0f} %)"
            if self.slowing > 1.0
            else ""
        )
        return f"the schedule's {rest:.0f} s{slowed} + {self._margin_s:g} s"

    @property
    def windows_passed(self) -> int:
        """Windows passed so far."""
        return sum(axis.passed for axis in self._axes)

    def state(self) -> WatchState:
        """What it waits for and how far the program is."""
        names = ", ".join(axis.name for axis in self._axes)
        passed = self.windows_passed
        program_s = (
            None if self.start_s is None or self._last_s is None else self._last_s - self.start_s
        )
        if self.phase == "waiting":
            text = (
                f"waiting for the start: the marker's first edge ({names})"
                if self.by_marker
                else f"waiting for the start: the first motion of {names}"
            )
            if self.by_marker and self._motion_s is not None:
                text += (
                    "; the axes move but the marker has not risen (if it never does, the "
                    "first motion is taken for the start)"
                )
        elif self.phase == "running":
            where = (
                f"; axis {self._last_passed.axis} window {self._last_passed.id} passed at "
                f"{self._last_passed.t_window_end_s:.0f} s of the schedule"
                if self._last_passed is not None
                else ""
            )
            waits = "every axis at its park and still after the last window"
            text = (
                f"program running: {passed} of {self.windows_total} windows{where}; "
                f"waiting for its end ({waits})"
            )
        else:
            text = f"program ended: {passed} of {self.windows_total} windows passed"
        return WatchState(
            phase=self.phase,
            text=text,
            windows_passed=passed,
            windows_total=self.windows_total,
            program_time_s=program_s,
            schedule_time_s=(
                self._last_passed.t_window_end_s if self._last_passed is not None else None
            ),
            slowing=self.slowing,
        )

    # --- the rows ------------------------------------------------------------------------

    def pass_rows(
        self, block: SampleBlock, link_now_s: float | None
    ) -> tuple[SampleBlock, EndedBy | None]:
        """The rows of ``block`` to keep, and what ended the recording (None: go on)."""
        if not len(block):
            return block, None
        if self._first_s is None:
            self._first_s = float(block.time_s[0])
        self._last_s = float(block.time_s[-1])
        kept = block
        if self.phase == "waiting":
            start = self._find_start(block, by_marker=self.by_marker)
            if start is None and self.by_marker and self._marker_never_rose(block):
                start_s = self._motion_s
                assert start_s is not None
                self._begin_at(start_s, link_now_s)
                kept = self._pre_rolled(block)
                self._follow(kept, int(np.searchsorted(kept.time_s, start_s, "left")))
            elif start is None:
                self._hold(block)
                timeout = self._start_timeout_s
                if timeout is not None and self._last_s - self._first_s >= timeout:
                    return _empty_like(block), "no_start"
                return _empty_like(block), None
            else:
                self._begin(block, start, link_now_s)
                kept = self._pre_rolled(block)
                self._follow(block, start)
        else:
            self._follow(block, 0)
        if self._end_s is not None:
            cut = int(np.searchsorted(kept.time_s, self._end_s + POST_ROLL_S, "right"))
            if cut < len(kept):
                self.phase = "ended"
                return _head(kept, cut), "program"
        bound = self.bound_s
        if bound is not None and self._last_s >= bound:
            cut = int(np.searchsorted(kept.time_s, bound, "right"))
            self.phase = "ended"
            return _head(kept, cut), "schedule"
        return kept, None

    def _hold(self, block: SampleBlock) -> None:
        """Keep the last :attr:`pre_roll_s` of rows before the start."""
        self._held.append(block)
        newest = float(block.time_s[-1])
        if self._motion_s is not None:  # from the first motion on: it may become the start
            newest = min(newest, self._motion_s)
        while len(self._held) > 1 and float(self._held[1].time_s[0]) <= newest - self._pre_roll_s:
            self._held.popleft()

    def _pre_rolled(self, block: SampleBlock) -> SampleBlock:
        """The held rows within the pre-roll of the start, then ``block``."""
        assert self.start_s is not None
        parts = [*self._held, block]
        self._held.clear()
        time_s = np.concatenate([p.time_s for p in parts])
        values = np.concatenate([p.values for p in parts])
        first = int(np.searchsorted(time_s, self.start_s - self._pre_roll_s, "left"))
        return SampleBlock(time_s[first:], values[first:])

    def _marker_never_rose(self, block: SampleBlock) -> bool:
        """The axes moved and the marker has not risen for longer than the schedule allows
        (a marker input not wired, or not set by the program): from now on the first motion
        is the start and the windows are passed by position. Notes the first motion."""
        if self._motion_s is None:
            first = self._first_motion(block)
            if first is None:
                return False
            self._motion_s = float(block.time_s[first[0]])
            self._motion_axis = first[1]
        assert self._last_s is not None
        if self._last_s - self._motion_s < self._marker_grace_s:
            return False
        log.warning(
            "the axes moved for %.0f s and the marker never rose: the start is the first "
            "motion (check the marker's wiring, SETUP.md)",
            self._last_s - self._motion_s,
        )
        self.by_marker = False
        self.marker_missing = True
        for axis in self._axes:
            axis.marker = None
        if self._motion_axis is not None:
            self._start_offset(self._motion_axis, by_marker=False)
        return True

    def _first_motion(self, block: SampleBlock) -> tuple[int, _Axis] | None:
        """The first row in ``block`` where an axis moves (and the axis), not yet the start."""
        found = [
            (int(hits[0]), axis)
            for axis in self._axes
            if (hits := self._motion_rows(axis, block)).size
        ]
        return min(found, key=lambda pair: pair[0], default=None)

    def _motion_rows(self, axis: _Axis, block: SampleBlock) -> Any:
        if axis.stood_mm is None:
            axis.stood_mm = float(block.values[0, axis.position])
        velocity = block.values[:, axis.velocity]
        position = block.values[:, axis.position]
        return np.flatnonzero(
            (np.abs(velocity) > axis.threshold_mm_min)
            | (np.abs(position - axis.stood_mm) > PARK_TOLERANCE_MM)
        )

    def _find_start(self, block: SampleBlock, *, by_marker: bool) -> int | None:
        """The row of the start in ``block``, if it is there."""
        found: list[tuple[int, _Axis]] = []
        for axis in self._axes:
            if by_marker:
                if axis.marker is None:
                    continue
                marker = block.values[:, axis.marker]
                hits = np.flatnonzero(np.isfinite(marker) & (marker > 0))
            else:
                hits = self._motion_rows(axis, block)
            if hits.size:
                found.append((int(hits[0]), axis))
        if not found:
            return None
        row, axis = min(found, key=lambda pair: pair[0])
        self._start_offset(axis, by_marker)
        return row

    def _start_offset(self, axis: _Axis, by_marker: bool) -> None:
        """The schedule's time at the start, from the axis that started."""
        if by_marker and axis.windows:
            first = axis.windows[0]
            self.offset_s = (
                first.t_window_start_s
                if self._schedule.marker_scope == "window"
                else first.t_start_s
            )
        elif axis.stood_mm is not None and abs(axis.stood_mm - axis.park_mm) <= PARK_TOLERANCE_MM:
            self.offset_s = axis.t_start_s  # parked: its own measurement is its first motion

    def _begin(self, block: SampleBlock, row: int, link_now_s: float | None) -> None:
        self._begin_at(float(block.time_s[row]), link_now_s)

    def _begin_at(self, start_s: float, link_now_s: float | None) -> None:
        self.phase = "running"
        self.start_s = start_s
        now = dt.datetime.now(dt.UTC)
        lag_s = (link_now_s - self.start_s) if self._real_time and link_now_s is not None else 0.0
        self.start_utc = now - dt.timedelta(seconds=max(0.0, lag_s))
        log.info("program start at %.3f s (link time)", self.start_s)

    def _follow(self, block: SampleBlock, row: int) -> None:
        """Windows passed and the end, from ``row`` of ``block`` on."""
        time_s = block.time_s[row:]
        values = block.values[row:]
        for axis in self._axes:
            self._pass_windows(axis, time_s, values)
        if self._end_s is not None or not len(time_s):
            return
        # with a marker too: the program ends when every axis is back at its park and
        # still for STILL_S after the last window (the run-out and the return follow the
        # last fall). The first row at which that holds, not the block's last: a block
        # may hold the end and, after it, the next run's first motion.
        still = np.ones(len(time_s), dtype=bool)
        for axis in self._axes:
            still &= np.abs(values[:, axis.velocity]) <= axis.threshold_mm_min
            still &= np.abs(values[:, axis.position] - axis.park_mm) <= PARK_TOLERANCE_MM
        rows = np.arange(len(time_s))
        carried = np.nan if self._still_since is None else self._still_since
        begins = still & ~np.concatenate(([self._still_since is not None], still[:-1]))
        # per row, the row its still stretch began at (−1: carried in from before)
        began = np.maximum.accumulate(np.where(begins, rows, -1))
        since = np.where(began >= 0, time_s[np.maximum(began, 0)], carried)
        ended = still & (time_s - since >= STILL_S) & (time_s >= self._after_last_s())
        hits = np.flatnonzero(ended)
        if hits.size:
            self._still_since = float(since[hits[0]])
            self._end_s = self._still_since + STILL_S
            self.phase = "ending"
        else:
            self._still_since = float(since[-1]) if still[-1] else None

    def _after_last_s(self) -> float:
        """From when the end may come: the last window passed, or its time in the schedule
        (slowed as measured) reached; infinity while neither is known."""
        if self.windows_passed >= self.windows_total:
            return -np.inf if self._last_passed_s is None else self._last_passed_s
        if self.start_s is None:
            return np.inf
        return self.start_s + (self._last_window_s - self.offset_s) * self.slowing

    def _pass_windows(self, axis: _Axis, time_s: Any, values: Any) -> None:
        """Advance ``axis`` past the windows these rows complete."""
        start = 0
        if axis.marker is not None:
            marker = values[:, axis.marker]
            on = np.isfinite(marker) & (marker > 0)
            before = np.concatenate(([axis.marker_on], on[:-1]))
            edges = np.flatnonzero(on != before)
            if len(on):
                axis.marker_on = bool(on[-1])
            for edge in edges:
                here = float(values[edge, axis.position])
                if on[edge]:  # a rise: where the axis stands
                    axis.rise_mm = here
                    continue
                # a fall: the span was this axis' window only if it moved meanwhile (the
                # same marker may reach every drive's input while another axis runs)
                moved = axis.rise_mm is not None and abs(here - axis.rise_mm) >= axis.moved_mm
                axis.rise_mm = None
                if moved and axis.passed < len(axis.windows):
                    self._passed(axis, float(time_s[edge]))
            return
        # Without a marker a window is passed when the axis, having stood on its start's
        # side, crosses its end moving its way: state kept across blocks, so the result
        # does not depend on how the rows arrive.
        while axis.passed < len(axis.windows) and start < len(time_s):
            window = axis.windows[axis.passed]
            if not axis.armed:
                before = np.flatnonzero(
                    window.direction * (values[start:, axis.position] - window.window_start_mm) <= 0
                )
                if not before.size:
                    return
                start += int(before[0])
                axis.armed = True
            beyond = window.direction * (values[start:, axis.position] - window.window_end_mm)
            moving = window.direction * values[start:, axis.velocity] > axis.threshold_mm_min
            hits = np.flatnonzero((beyond >= 0) & moving)
            if not hits.size:
                return
            start += int(hits[0])
            axis.armed = False
            self._passed(axis, float(time_s[start]))

    def _passed(self, axis: _Axis, time_s: float) -> None:
        window = axis.windows[axis.passed]
        axis.passed += 1
        self._last_passed = window
        self._last_passed_s = time_s
        if self.start_s is not None:
            planned_s = window.t_window_end_s - self.offset_s
            if planned_s > 1.0:
                self.slowing = max(1.0, (time_s - self.start_s) / planned_s)


def _empty_like(block: SampleBlock) -> SampleBlock:
    return SampleBlock(block.time_s[:0], block.values[:0])


def _head(block: SampleBlock, rows: int) -> SampleBlock:
    return SampleBlock(block.time_s[:rows], block.values[:rows])


@dataclass
class Recorded:
    """One run of the program as :func:`record_program` recorded it."""

    acquisition: AcquisitionResult
    watch: ProgramWatch | None
    """None when the link failed before it opened."""

    @property
    def started(self) -> bool:
        """The program's start was seen."""
        return self.watch is not None and self.watch.start_s is not None


def record_program(
    config: MachineConfig,
    schedule: Schedule,
    out: Path,
    *,
    link: str | None = None,
    link_settings: dict[str, Any] | None = None,
    axis_settings: dict[str, dict[str, Any]] | None = None,
    notes: str = "",
    stop: threading.Event | None = None,
    on_progress: Callable[[Progress, WatchState], None] | None = None,
    clock: LinkClock | None = None,
    start_timeout_s: float | None = None,
    margin_s: float = SCHEDULE_MARGIN_S,
    serial: str | None = None,
) -> Recorded:
    """Open the link, wait for the program's start, record it until its end.

    Args:
        config: The machine (its ``[link]`` unless ``link``/``link_settings`` say otherwise).
        schedule: The program's schedule.
        out: New recording directory.
        link, link_settings, axis_settings: As :func:`~ncmeasure.acquire.record` takes them.
        notes: Free text stored with the recording.
        stop: Set it to stop (Ctrl-C): what was recorded is kept.
        on_progress: ``on_progress(progress, state)`` about twice a second.
        clock: The link's clock (a SimulatedClock in lockstep with simulated drives).
        start_timeout_s: Give up without a start after this long (link time).
        margin_s: Time allowed after the schedule's end (slowed as measured).
        serial: The machine's serial number, written into the recording's meta.json.

    Raises:
        ConfigError: bad link settings, or a link that records no velocity or position.
        LinkError: the link cannot be opened.
        RecordingError: the recording cannot be written.
    """
    watches: list[ProgramWatch] = []

    def watch(drive_link: DriveLink) -> ProgramWatch:
        made = ProgramWatch(
            [c.name for c in drive_link.channels],
            schedule,
            real_time=drive_link.clock.real_time,
            margin_s=margin_s,
            start_timeout_s=start_timeout_s,
        )
        watches.append(made)
        if drive_link.signals_ready:
            # the program waits for it before its first move; closing the link sets it off
            drive_link.set_ready(True)
            log.info("ready output set: the program may start")
        return made

    def progress(p: Progress) -> None:
        if on_progress is not None and watches:
            on_progress(p, watches[0].state())

    result = record(
        config,
        out=out,
        link=link,
        link_settings=link_settings,
        axis_settings=axis_settings,
        schedule=schedule,
        notes=notes,
        stop=stop,
        on_progress=progress,
        clock=clock,
        watch=watch,
        serial=serial,
    )
    return Recorded(result, watches[0] if watches else None)


@dataclass
class Evaluation:
    """What :func:`evaluate` wrote and found."""

    results: Results
    results_file: Path
    report: Path
    added: Any
    """The store's ``Added``: the measurement's id, new or already stored."""
    check: Any
    """The store's ``StoreCheck``: the machine against its baseline and its fleet."""
    status: Status
    """The verdict: the store check's status (the one rule, which holds the axes' verdicts)."""


def evaluate(
    recording: Path,
    schedule: Schedule,
    config: MachineConfig,
    out: Path,
    *,
    store: str | None,
    info: Any,
    limits: Limits | None = None,
    progress: Callable[[str, float | None], None] | None = None,
) -> Evaluation:
    """Analyse a recording, store it, check the machine against its baseline, report.

    Args:
        recording: The recording directory.
        schedule: The program's schedule.
        config: The machine.
        out: Folder for results.json and report.html.
        store: The fleet store's URL (None: the default store).
        info: The store's ``MeasurementInfo`` (serial, label, measured time, ...).
        limits: Warning and critical limits of the change against the baseline.
        progress: ``progress(stage, fraction)``.

    Raises:
        NcMeasureError: the analysis, the store or the report failed.
    """
    from ncmeasure.analysis.analyze import analyze
    from ncmeasure.recording import RecordingHead
    from ncmeasure.report import write_report
    from ncmeasure.report.traces import RawTraces
    from ncmeasure.store import open_store, store_url
    from ncmeasure.store.check import check_machine

    def report(stage: str, fraction: float | None) -> None:
        if progress is not None:
            progress(stage, fraction)

    head = RecordingHead.open(recording)
    traces = RawTraces(head)
    windows: dict[str, list[tuple[float, float]]] = {}
    report("analysing", None)
    results = analyze(
        head,
        schedule=schedule,
        machine=config,
        progress=lambda _stage, fraction: report("analysing", fraction),
        window_times=windows,
        on_windows=traces.watch,
    )
    results_file = write_results(results, out / "results.json")
    report("storing and comparing", None)
    with open_store(store_url(store), write=True) as fleet:
        added = fleet.add(results, info)
        check = check_machine(fleet, info.serial, limits)
    report("writing the report", None)
    page = write_report(
        results,
        out / "report.html",
        recording=head,
        windows=windows,
        traces=traces.found,
        comparison=check.comparison,
    )
    return Evaluation(
        results=results,
        results_file=results_file,
        report=page,
        added=added,
        check=check,
        status=check.status,
    )


def default_output(programs: Path, serial: str, when: dt.datetime | None = None) -> Path:
    """``PROGRAMS/measurements/SERIAL-YYYYmmddTHHMMSSZ``: a new folder per measurement."""
    moment = (when or dt.datetime.now(dt.UTC)).astimezone(dt.UTC)
    return programs / "measurements" / f"{serial}-{moment:%Y%m%dT%H%M%SZ}"


def utc_text(moment: dt.datetime) -> str:
    """ISO 8601 in UTC, to the millisecond (the store's measured time)."""
    return moment.astimezone(dt.UTC).isoformat(timespec="milliseconds")


SERIES_LOG = "series.log"
"""The file of a series folder with a line per run and per link outage."""
SERIES_COLUMNS = (
    "time_utc",
    "run",
    "outcome",
    "verdict",
    "measurement",
    "windows",
    "folder",
    "note",
)
"""The series log's columns (tab-separated, a header line first)."""
SERIES_RETRY_S = (2.0, 4.0, 8.0, 15.0, 30.0)
"""Waits (wall clock) before each new try to reach the drives in a series; the last repeats."""


class SeriesLog:
    """The series log: a tab-separated line per run (and per link outage), on disk at once.

    Each line is appended, flushed and synced before the next run starts, so a crash or a
    power cut loses no finished line. A technician reads it in any editor or spreadsheet.

    Raises:
        OutputError: the log cannot be written.
    """

    def __init__(self, path: Path) -> None:
        from ncmeasure.errors import OutputError

        self.path = path
        try:
            if not path.exists() or path.stat().st_size == 0:
                self._append("\t".join(SERIES_COLUMNS))
        except OSError as exc:
            raise OutputError(f"{path}: cannot write the series log ({exc.strerror})") from exc

    def line(
        self,
        *,
        run: int | str,
        outcome: str,
        verdict: str = "",
        measurement: int | str = "",
        windows: str = "",
        folder: str = "",
        note: str = "",
        moment: dt.datetime | None = None,
    ) -> None:
        """Append one line (tabs and line breaks in the texts become spaces)."""
        from ncmeasure.errors import OutputError

        cells = [
            utc_text(moment or dt.datetime.now(dt.UTC)),
            str(run),
            outcome,
            verdict,
            str(measurement),
            windows,
            folder,
            note,
        ]
        text = "\t".join(" ".join(str(c).split()) for c in cells)
        try:
            self._append(text)
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot write the series log ({exc.strerror})") from exc

    def _append(self, text: str) -> None:
        import os

        with self.path.open("a", encoding="utf-8") as file:
            file.write(text + "\n")
            file.flush()
            os.fsync(file.fileno())


def read_series_log(path: Path) -> list[dict[str, str]]:
    """The series log's lines as dictionaries by column (for scripts and tests)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    if not lines:
        return []
    header = lines[0].split("\t")
    return [dict(zip(header, line.split("\t"), strict=False)) for line in lines[1:] if line]
