"""Labelling by the schedule: found stretches matched to the scheduled windows of the axis.

By marker value (``marker_values = "window_id"``), else by time order,
velocity and position: a stretch matches the next scheduled window in
program order whose velocity agrees within the tolerance and whose run
contains the stretch's centre (:func:`~ncmeasure.analysis.windows.signals.align`).
Where the marker brackets whole runs (``marker_scope = "run"``) the window is
cut out of each run at the schedule's positions (or its times).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.detection import Detection
from ncmeasure.analysis.windows.model import (
    Candidate,
    Cluster,
    VelocityWindow,
    labelled_window,
    nan_mean,
)
from ncmeasure.analysis.windows.settings import WindowSource
from ncmeasure.analysis.windows.signals import align
from ncmeasure.formats.schedule import AxisSummary
from ncmeasure.formats.schedule import Window as ScheduledWindow

__all__ = ["ScheduleMatch"]

FloatArray = NDArray[np.float64]


class ScheduleMatch:
    """The axis' part of the schedule, and how found stretches match its windows.

    Args:
        summary: The axis' part of the schedule.
        detection: The finder's counts and bands; its warnings receive what
            matching drops.
    """

    def __init__(self, summary: AxisSummary, detection: Detection) -> None:
        self.summary = summary
        self.detection = detection

    def match(
        self, candidates: Sequence[Candidate], x: FloatArray, *, by_position: bool, whole_runs: bool
    ) -> list[ScheduledWindow | None]:
        """Match candidates to scheduled windows by program order, velocity and position."""
        planned = self.summary.windows
        if not planned or not candidates:
            return [None] * len(candidates)
        sched_v = np.array([w.velocity_mm_min for w in planned])
        run_lo = np.array([min(w.start_mm, w.stop_mm) for w in planned])
        run_hi = np.array([max(w.start_mm, w.stop_mm) for w in planned])
        run_s = np.array([w.t_stop_s - w.t_start_s for w in planned])
        span = self.summary.travel_mm[1] - self.summary.travel_mm[0]
        margin = max(5.0, 0.02 * abs(span))
        cand_v = np.array([c.level_mm_min for c in candidates])
        cand_x = np.array([nan_mean(x[c.start : c.stop]) for c in candidates])
        cand_s = np.array([(c.stop - c.start) * self.detection.dt for c in candidates])
        ok = np.sign(cand_v)[:, None] == np.sign(sched_v)[None, :]
        ok &= np.abs(cand_v[:, None] - sched_v[None, :]) <= 2 * self.detection.band(sched_v)
        if by_position:
            ok &= (cand_x[:, None] >= run_lo - margin) & (cand_x[:, None] <= run_hi + margin)
        # A window never lasts longer than its run (plus a generous slack: controllers
        # ramp more gently than planned); warm-up strokes and long rapids do.
        slack = 2.0 if whole_runs else 1.5
        ok &= cand_s[:, None] <= slack * run_s[None, :] + 1.0
        return [None if j is None else planned[j] for j in align(ok)]

    def match_by_id(self, candidates: Sequence[Candidate]) -> list[ScheduledWindow | None]:
        """Match marker windows to scheduled windows by the marker's value, the window id."""
        by_id = {w.id: w for w in self.summary.windows}
        result: list[ScheduledWindow | None] = []
        mismatched = 0
        for candidate in candidates:
            value = candidate.marker_value
            window = by_id.get(round(value)) if value is not None else None
            if window is not None and np.sign(window.velocity_mm_min) != np.sign(
                candidate.level_mm_min
            ):
                mismatched += 1
                window = None
            result.append(window)
        if mismatched:
            self.detection.warnings.append(
                f"{mismatched} marker windows move against their scheduled direction: dropped"
            )
        return result

    def match_schedule(
        self, candidates: Sequence[Candidate], x: FloatArray, *, by_id: bool, whole_runs: bool
    ) -> list[Candidate]:
        """Attach the scheduled window to every candidate; drop the unmatched ones."""
        if by_id:
            matched = self.match_by_id(candidates)
        else:
            known = self.detection.positions_known
            matched = self.match(candidates, x, by_position=known, whole_runs=whole_runs)
            found = sum(m is not None for m in matched)
            if known and found < 0.5 * min(len(candidates), self.planned_count):
                retry = self.match(candidates, x, by_position=False, whole_runs=whole_runs)
                if sum(m is not None for m in retry) > found:
                    self.detection.warnings.append(
                        "the recorded positions do not fit the schedule's (another coordinate "
                        "system?): windows matched by velocity and order only"
                    )
                    matched = retry
        kept = []
        for candidate, window in zip(candidates, matched, strict=True):
            if window is not None:
                candidate.scheduled = window
                kept.append(candidate)
        unmatched = len(candidates) - len(kept)
        if unmatched:
            self.detection.warnings.append(
                f"{unmatched} constant-velocity stretches match no scheduled window "
                "(rapids, warm-up, other moves): dropped"
            )
        ids = [c.scheduled.id for c in kept if c.scheduled is not None]
        if len(set(ids)) < len(ids):
            self.detection.warnings.append(
                "some scheduled windows were found more than once: pooled"
            )
        return kept

    @property
    def planned_count(self) -> int:
        """The scheduled windows of the axis."""
        return len(self.summary.windows)

    def cut_runs(self, candidates: Sequence[Candidate], x: FloatArray) -> list[Candidate]:
        """Marker brackets whole runs: cut the scheduled window out of each run."""
        cut_by_position: list[Candidate | None] = []
        if self.detection.positions_known:
            for candidate in candidates:
                window = candidate.scheduled
                assert window is not None
                lo = min(window.window_start_mm, window.window_end_mm)
                hi = max(window.window_start_mm, window.window_end_mm)
                run_x = x[candidate.start : candidate.stop]
                inside = np.flatnonzero((run_x >= lo) & (run_x <= hi))
                if len(inside) < self.detection.min_n:
                    cut_by_position.append(None)
                    continue
                cut_by_position.append(
                    replace(
                        candidate,
                        start=candidate.start + int(inside[0]),
                        stop=candidate.start + int(inside[-1]) + 1,
                    )
                )
            good = [c for c in cut_by_position if c is not None]
            if len(good) >= 0.5 * len(candidates):
                if len(good) < len(candidates):
                    self.detection.warnings.append(
                        f"{len(candidates) - len(good)} runs never crossed their scheduled "
                        "window positions: dropped"
                    )
                return good
            self.detection.warnings.append(
                "the recorded positions do not cross the scheduled windows (another "
                "coordinate system?): windows cut by the schedule's times from the marker edge"
            )
        result = []
        for candidate in candidates:
            window = candidate.scheduled
            assert window is not None
            dt = self.detection.dt
            begin = candidate.start + round((window.t_window_start_s - window.t_start_s) / dt)
            end = candidate.start + round((window.t_window_end_s - window.t_start_s) / dt)
            end = min(end, candidate.stop)
            if end - begin >= self.detection.min_n:
                result.append(replace(candidate, start=begin, stop=end))
        return result

    def label_by_schedule(
        self, candidates: Sequence[Candidate], x: FloatArray, source: WindowSource
    ) -> tuple[list[VelocityWindow], list[Cluster], list[Cluster]]:
        """The windows with their scheduled labels, and the schedule's steps and positions."""
        summary = self.summary
        windows = []
        off_schedule: list[int] = []
        for candidate in candidates:
            planned = candidate.scheduled
            assert planned is not None
            windows.append(
                labelled_window(
                    self.detection.axis,
                    candidate,
                    x,
                    source,
                    velocity_mm_min=planned.velocity_mm_min,
                    position_index=planned.position_index,
                    step=planned.step,
                    window_id=planned.id,
                    repetition=planned.repetition,
                )
            )
            tolerance = float(self.detection.band(planned.velocity_mm_min))
            if abs(candidate.level_mm_min - planned.velocity_mm_min) > tolerance:
                off_schedule.append(planned.id)
        if off_schedule:
            shown = ", ".join(str(i) for i in off_schedule[:5])
            more = ", ..." if len(off_schedule) > 5 else ""
            self.detection.warnings.append(
                f"{len(off_schedule)} windows moved at another velocity than scheduled "
                f"(feed override?): windows {shown}{more}"
            )
        steps = []
        for index, speed in enumerate(summary.velocities_mm_min):
            levels = [abs(w.level_mm_min) for w in windows if w.step == index]
            steps.append(
                Cluster(
                    index,
                    speed,
                    min(levels, default=speed),
                    max(levels, default=speed),
                    len(levels),
                )
            )
        positions = []
        for index, nominal in enumerate(summary.nominal_positions_mm):
            centres = [w.position_mm for w in windows if w.position_index == index]
            positions.append(
                Cluster(
                    index,
                    nominal,
                    min(centres, default=nominal),
                    max(centres, default=nominal),
                    len(centres),
                )
            )
        return windows, steps, positions
