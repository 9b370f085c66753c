"""The reference the analysis is checked against: the windows found on the whole arrays.

ncmeasure reads a recording one way only: in passes of chunks
(:mod:`ncmeasure.analysis.reading`; a recording in memory is one chunk), with
statistics computed exactly chunk by chunk (:mod:`ncmeasure.analysis.windows.streaming`)
and stretches carried across chunk edges. This module is the plain version of
the same method, on whole numpy arrays: the median time step by ``np.median``,
the count of a quantised signal and the noise of its second differences on the
whole signal, gaps bridged by ``np.interp`` over the whole channel, the marker's
runs, the command's stretches and the plateaus of the smoothed velocity found in
the whole arrays, and every window's samples sliced from them. It shares with the
production code what is not about reading: the settings, the trimming, the
position check, the schedule matching and the labelling
(:class:`~ncmeasure.analysis.windows.finder.WindowFinder`), and what turns an
axis' windows into its result (:func:`~ncmeasure.analysis.axis.finish_axis`).

:func:`find_windows` is the oracle of
:func:`ncmeasure.analysis.windows.find.find_windows`, :func:`analyze` of
:func:`ncmeasure.analysis.analyze.analyze`: the same windows, the same
``results.json``, bit for bit.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import median_filter

from ncmeasure.analysis.analyze import AnalysisSettings, chosen_axes, results_of
from ncmeasure.analysis.axis import (
    AxisFacts,
    AxisFound,
    Progress,
    axis_facts,
    axis_summary,
    check_channels,
    check_velocity,
    dead_channel,
    finish_axis,
    implausible_checker,
    implausible_lines,
)
from ncmeasure.analysis.reading import recording_gaps
from ncmeasure.analysis.windows.finder import WindowFinder
from ncmeasure.analysis.windows.model import Candidate, Segmentation
from ncmeasure.analysis.windows.settings import MIN_WINDOW_SAMPLES, SegmentSettings
from ncmeasure.analysis.windows.signals import (
    command_repeats,
    hole_rows,
    plateau_mask,
    position_velocity,
    runs,
)
from ncmeasure.analysis.windows.watch import Watchers
from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.formats.results import AxisResult, Results
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RowChunk

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]


# --- whole-signal statistics -------------------------------------------------------------


def quantum(values: FloatArray) -> float:
    """The resolution of a quantised signal (one count), or 0 for a continuous one.

    A signal is quantised when 95 % of its non-zero sample-to-sample steps are
    whole multiples of the smallest one; steps below 10⁻⁹ of the signal's range
    are rounding noise. The count is the sum of the lattice steps (exactly
    rounded, ``math.fsum``) over the sum of their multiples.
    """
    data = np.asarray(values, dtype=np.float64)
    data = data[np.isfinite(data)]
    if len(data) < 3:
        return 0.0
    steps = np.abs(np.diff(data))
    steps = steps[steps > 1e-9 * float(np.max(np.abs(data)))]
    if len(steps) < 10:
        return 0.0
    ratio = steps / float(steps.min())
    on = np.abs(ratio - np.round(ratio)) <= 0.02
    if np.count_nonzero(on) < 0.95 * len(steps):
        return 0.0
    return math.fsum(steps[on].tolist()) / float(np.sum(np.round(ratio[on])))


def noise_sigma(values: FloatArray) -> float:
    """Robust standard deviation of a signal's sample-to-sample noise.

    From second differences, scaled by the median absolute deviation:
    v[i+1] − 2v[i] + v[i−1] of white noise of σ has the standard deviation √6·σ.
    """
    data = np.asarray(values, dtype=np.float64)
    data = data[np.isfinite(data)]
    if len(data) < 5:
        return 0.0
    second = np.diff(data, n=2)
    mad = float(np.median(np.abs(second - np.median(second))))
    return 1.4826 * mad / math.sqrt(6.0)


def bridge(values: FloatArray, time_s: FloatArray, *, hold: bool = False) -> tuple[FloatArray, int]:
    """``values`` with NaN samples filled from their neighbours, and how many were filled.

    Linear interpolation over time (``hold``: the last value, for a step signal
    such as the commanded velocity); NaN at the ends takes the nearest value.
    A channel without any finite value is returned as it is.
    """
    bad = ~np.isfinite(values)
    count = int(np.count_nonzero(bad))
    if count == 0 or count == len(values):
        return values, 0
    good = np.flatnonzero(~bad)
    filled = np.array(values, dtype=np.float64, copy=True)
    if hold:
        last = np.maximum.accumulate(np.where(bad, 0, np.arange(len(values))))
        filled = filled[last]
        filled[: good[0]] = values[good[0]]
    else:
        filled[bad] = np.interp(time_s[bad], time_s[good], values[good])
    return filled, count


def _span(values: FloatArray) -> float:
    """max − min of the finite values (0 without any)."""
    finite = values[np.isfinite(values)]
    return float(np.ptp(finite)) if len(finite) else 0.0


def _agreement(derived: FloatArray, readings: FloatArray, above: float) -> float | None:
    """The median ratio derived/readings where the readings exceed ``above``, or None."""
    fast = np.isfinite(derived) & np.isfinite(readings) & (np.abs(readings) > above)
    if np.count_nonzero(fast) < MIN_WINDOW_SAMPLES:
        return None
    return float(np.median(derived[fast] / readings[fast]))


# --- the stretches of each way, in the whole arrays --------------------------------------


def value_runs(on: BoolArray, value: FloatArray) -> tuple[IntArray, IntArray]:
    """Runs of ``on`` that also break wherever ``value`` changes."""
    n = len(on)
    if n == 0:
        return np.empty(0, np.intp), np.empty(0, np.intp)
    changed = np.empty(n, dtype=np.bool_)
    changed[0] = True
    changed[1:] = (value[1:] != value[:-1]) | ~on[:-1]
    ends = np.empty(n, dtype=np.bool_)
    ends[-1] = True
    ends[:-1] = (value[:-1] != value[1:]) | ~on[1:]
    return np.flatnonzero(on & changed), np.flatnonzero(on & ends) + 1


def command_stretches(command: FloatArray, n: int) -> tuple[IntArray, IntArray]:
    """Begin and end (exclusive) of the stretches of constant commanded velocity."""
    constant = np.zeros(n, dtype=np.bool_)
    constant[1:] = command_repeats(command)  # sample i repeats sample i - 1
    # A constant stretch starts one sample before its first repeat.
    begins = np.flatnonzero(~constant)
    ends = np.append(begins[1:], n)
    return begins, ends


class WholeFinder(WindowFinder):
    """Finds the windows of one axis in its whole arrays (one call of :func:`find_windows`)."""

    def __init__(
        self,
        axis: str,
        time_s: FloatArray,
        velocity: FloatArray,
        position: FloatArray | None,
        command: FloatArray | None,
        marker: FloatArray | None,
        schedule: Schedule | None,
        settings: SegmentSettings,
        rapid_mm_min: float | None = None,
    ) -> None:
        self.axis = axis
        self.rapid_mm_min = rapid_mm_min
        self.settings = settings
        self.v = velocity
        self.n = len(velocity)
        steps = np.diff(time_s)
        self.dt = float(np.median(steps)) if len(steps) else 1.0
        if not self.dt > 0:
            raise RecordingError(f"axis {axis}: the sample times do not increase")
        self.marker = marker
        self.warnings: list[str] = []
        self.tried: list[str] = []
        if position is not None and np.count_nonzero(np.isfinite(position)) < 0.5 * len(position):
            self.warnings.append(
                "the position channel holds a value in fewer than half of the rows: not used"
            )
            position = None
        velocity, bridged = bridge(velocity, time_s)
        if bridged:
            self.warnings.append(
                f"{bridged} velocity samples without a value (NaN) bridged by their neighbours "
                "to find the windows"
            )
        if position is not None:
            position, _ = bridge(position, time_s)
        if command is not None:
            command, _ = bridge(command, time_s, hold=True)
        self.command = command
        self.positions_known = position is not None
        self.holes = hole_rows(time_s, self.dt).tolist()
        if position is None:
            # Relative positions are enough to tell measuring positions apart; none is
            # carried across a hole of the time axis: each segment from its own start.
            filled = np.where(np.isfinite(velocity), velocity, 0.0)
            bounds = [0, *self.holes, len(filled)]
            self.x = np.concatenate(
                [np.cumsum(filled[a:b]) for a, b in itertools.pairwise(bounds)]
            ) * (self.dt / 60.0)
            self.warnings.append(
                "no position channel: positions integrated from the velocity (relative)"
            )
        else:
            self.x = position
        self.setup_schedule(schedule)
        self.v = velocity
        self.t = time_s
        finite = np.abs(velocity[np.isfinite(velocity)])
        self.scale_floors(
            float(finite.max()) if len(finite) else math.nan,
            max(noise_sigma(velocity), quantum(velocity)),
        )
        self.setup_counts()
        self.setup_resolution(
            quantum(velocity),
            quantum(position) if position is not None else 0.0,
            noise_sigma(velocity),
        )
        ratio: float | None = None
        if self.from_position:
            h = self.position_h(noise_sigma(self.x))
            by_position = position_velocity(self.t, self.x, h, 0, len(self.x), 0, self.n)
            ratio = _agreement(by_position, velocity, 5 * self.resolution)
            self.v_detect = velocity
            if ratio is not None and 0.9 <= ratio <= 1.1:
                self.v_detect = by_position
        else:
            self.v_detect = velocity
        self.setup_detection(ratio)

    def marker_candidates(self) -> list[Candidate]:
        marker = self.marker
        if not self.marker_wanted():
            return []
        assert marker is not None
        on = np.isfinite(marker) & (marker > 0)
        starts, stops = value_runs(on, marker)
        return self.marker_levels(starts.tolist(), stops.tolist(), marker[starts].tolist())

    def command_candidates(self) -> list[Candidate]:
        command = self.command
        if command is None:
            self.tried.append("commanded velocity: not recorded")
            return []
        if self.n < 2:
            return []
        begins, ends = command_stretches(command, self.n)
        levels = command[begins]
        keep = (np.abs(levels) >= self.settings.standstill_mm_min) & (ends - begins >= self.min_n)
        return self.command_found(
            begins[keep].tolist(), ends[keep].tolist(), command[begins[keep]].tolist()
        )

    def plateau_candidates(self) -> list[Candidate]:
        length = self.plateau_n
        if self.plateau_too_short():
            return []
        finite = np.where(np.isfinite(self.v_detect), self.v_detect, 0.0)
        smooth = median_filter(finite, size=self.filter_n, mode="nearest")
        starts, stops = runs(plateau_mask(smooth, self.band, self.standstill, length, self.n))
        found = [
            (start, stop)
            for start, stop in zip(starts.tolist(), stops.tolist(), strict=True)
            if stop - start >= length
        ]
        moving = []
        for mask in (smooth >= self.standstill, smooth <= -self.standstill):
            starts, stops = runs(mask)
            moving += [
                (start, stop)
                for start, stop in zip(starts.tolist(), stops.tolist(), strict=True)
                if stop - start >= length
            ]
        return self.plateau_found(
            [
                (start, stop, float(np.median(smooth[start:stop])))
                for start, stop in self.split_at_holes(found, length)
            ],
            self.split_at_holes(sorted(moving), length),
        )

    def still(self) -> str | None:
        if self.n < 2:
            return "the recording holds fewer than 2 samples"
        duration_s = float(self.t[-1] - self.t[0])
        threshold = self.standstill
        count = (
            f" (one count of the velocity signal is {self.v_quantum:.3g} mm/min)"
            if self.v_quantum and self.v_quantum * (1 + 1e-6) >= threshold
            else ""
        )
        if self.positions_known:
            span_mm = _span(self.x)
            if duration_s > 0 and span_mm / duration_s * 60.0 > self.settings.standstill_mm_min:
                return None
            return (
                f"the axis did not move: its position stays within {span_mm * 1000:.3g} µm "
                f"over {duration_s:.3g} s (whatever its velocity signal reads)"
            )
        smooth = np.abs(np.where(np.isfinite(self.v_detect), self.v_detect, 0.0))
        if self.filter_n > 1:
            smooth = median_filter(smooth, size=self.filter_n, mode="nearest")
        starts, stops = runs(smooth >= threshold)
        if len(starts) and int((stops - starts).max()) >= self.min_n:
            return None
        return (
            f"the axis did not move: its velocity never stays above {threshold:.3g} mm/min"
            f"{count} over {duration_s:.3g} s (no position recorded)"
        )


def find_windows(
    axis: str,
    time_s: FloatArray,
    velocity_mm_min: FloatArray,
    *,
    position_mm: FloatArray | None = None,
    command_mm_min: FloatArray | None = None,
    marker: FloatArray | None = None,
    schedule: Schedule | None = None,
    settings: SegmentSettings | None = None,
    rapid_mm_min: float | None = None,
) -> Segmentation:
    """The windows of one axis found in its whole arrays (as ``find_windows`` is documented)."""
    finder = WholeFinder(
        axis,
        np.asarray(time_s, dtype=np.float64),
        np.asarray(velocity_mm_min, dtype=np.float64),
        None if position_mm is None else np.asarray(position_mm, dtype=np.float64),
        None if command_mm_min is None else np.asarray(command_mm_min, dtype=np.float64),
        None if marker is None else np.asarray(marker, dtype=np.float64),
        schedule,
        settings or SegmentSettings(),
        rapid_mm_min,
    )
    return finder.run()


# --- the analysis of a recording on its whole arrays -------------------------------------


def _creep_mm_min(time_s: FloatArray, position_mm: FloatArray) -> float:
    """How fast the position's whole span would be covered over the recording, in mm/min."""
    finite = np.isfinite(position_mm)
    duration = float(time_s[-1] - time_s[0]) if len(time_s) > 1 else 0.0
    if duration <= 0 or not finite.any():
        return 0.0
    return float(np.ptp(position_mm[finite])) / duration * 60.0


def _signals(
    recording: Recording, axis: str, facts: AxisFacts
) -> tuple[dict[str, FloatArray], dict[str, int], list[str]]:
    """The axis' channels with the values no drive can report (no-value codes) as NaN."""
    checker = implausible_checker(recording.channel_names, axis, facts)
    cleaned = {
        name.removeprefix(f"{axis}_"): checker.clean(name, recording.time_s, recording.column(name))
        for name in checker.limits
    }
    counts, lines = implausible_lines(checker, recording.meta)
    return cleaned, counts, lines


class WholeRecording:
    """A recording in memory analysed axis by axis on its whole arrays.

    What :func:`~ncmeasure.analysis.analyze.results_of` needs of a reading of a
    recording (:class:`~ncmeasure.analysis.analyze.AxisSource`).
    """

    def __init__(
        self,
        recording: Recording,
        schedule: Schedule | None,
        machine: MachineConfig | None,
        settings: SegmentSettings,
    ) -> None:
        self.recording = recording
        self.schedule = schedule
        self.machine = machine
        self.settings = settings
        self.gaps = recording_gaps(recording)
        self.rows = len(recording)
        self.start_s = float(recording.time_s[0]) if self.rows else math.nan
        self.end_s = float(recording.time_s[-1]) if self.rows else math.nan
        self.watchers = Watchers({})

    def found(self, axis: str, progress: Progress) -> tuple[AxisFacts, AxisFound]:
        """What :meth:`~ncmeasure.analysis.reading.RecordingPasses.found` gives, found whole."""
        recording, settings = self.recording, self.settings
        check_channels(axis, recording.channel_names)
        summary = axis_summary(self.schedule, axis)
        facts = axis_facts(axis, recording, self.machine, summary)
        signals, counts, lines = _signals(recording, axis, facts)
        current = signals["current_a"]
        velocity = signals["velocity_mm_min"]
        position = signals.get("position_mm")
        finite = velocity[np.isfinite(velocity)]
        check_velocity(
            axis,
            dead_channel(axis, "velocity_mm_min", velocity, "mm/min"),
            position is not None
            and _creep_mm_min(recording.time_s, position) > settings.standstill_mm_min,
            float(finite[0]) if len(finite) else None,
        )
        progress(f"axis {axis}: windows", 0.0)
        segmentation = find_windows(
            axis,
            recording.time_s,
            velocity,
            position_mm=position,
            command_mm_min=signals.get("velocity_cmd_mm_min"),
            marker=signals.get("marker"),
            schedule=self.schedule,
            settings=settings,
            rapid_mm_min=facts.rapid_velocity_mm_min,
        )
        time_s = recording.time_s
        return facts, AxisFound(
            segmentation=segmentation,
            window_current=[current[w.start : w.stop] for w in segmentation.windows],
            window_times=[
                (float(time_s[w.start]), float(time_s[w.stop - 1])) for w in segmentation.windows
            ],
            current_dead=dead_channel(axis, "current_a", current, "A"),
            current_quantum_a=quantum(current),
            implausible_counts=counts,
            implausible_lines=lines,
        )

    def axis(
        self, axis: str, progress: Progress, gap_share: float
    ) -> tuple[AxisResult, list[tuple[float, float]]]:
        facts, found = self.found(axis, progress)
        summary = axis_summary(self.schedule, axis)
        result = finish_axis(axis, facts, summary, found, report=progress, gap_share=gap_share)
        return result, found.window_times

    def read_channels(
        self, wanted: tuple[str, ...], between_s: tuple[float, float] | None
    ) -> Iterable[RowChunk]:
        whole = self.recording
        index = [whole.channel_names.index(name) for name in wanted]
        return [RowChunk(0, whole.time_s, whole.values[:, index])]


def _quiet(stage: str, fraction: float) -> None:
    """Reports nothing."""


def analyze(
    recording: Recording,
    *,
    schedule: Schedule | None = None,
    machine: MachineConfig | None = None,
    settings: AnalysisSettings | None = None,
    axes: Sequence[str] | None = None,
    window_times: dict[str, list[tuple[float, float]]] | None = None,
) -> Results:
    """The results of :func:`ncmeasure.analysis.analyze.analyze`, every axis on its whole arrays."""
    settings = settings or AnalysisSettings()
    chosen = chosen_axes(recording, axes)
    return results_of(
        recording,
        chosen,
        WholeRecording(recording, schedule, machine, settings),
        schedule=schedule,
        settings=settings,
        progress=_quiet,
        window_times=window_times,
    )
