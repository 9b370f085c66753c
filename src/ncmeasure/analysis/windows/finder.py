"""Windows of constant velocity: where in a recording an axis moved steadily.

The friction of a feed axis is the motor current at *constant* velocity, so
the first job of the analysis is to find those stretches of an axis' signals.
Three ways are tried, in this order; the first that yields windows wins:

``marker``
    The NC program sets a marker while a window is driven (``<AXIS>_marker``
    > 0). With a schedule whose ``marker_scope`` is ``"run"``, the marker
    brackets the whole run (ramps included) and the window is cut out of it
    at the schedule's ``window_start_mm`` .. ``window_end_mm``; the source is
    then called ``"schedule"``.
``command``
    Where the commanded velocity is constant and the actual velocity is
    within a tolerance of it (relative, with an absolute floor).
``plateau``
    From the actual velocity alone, for recordings of programs ncmeasure did
    not generate: a rolling median smooths the velocity, and every stretch
    where the smoothed velocity stays within the tolerance of its level for
    at least ``plateau_min_s`` (and above the standstill floor) is a plateau.

Real data sets the rules (``docs/analysis.md``, section 1):

* every rule is a duration; sample counts follow from the sample period
  (``min_window_s``, at least :data:`MIN_WINDOW_SAMPLES`), so 100 ms data of a
  data collector is analysed like 4 ms data, and called *coarse* when its
  windows hold fewer than :data:`COARSE_WINDOW_SAMPLES` samples;
* the velocity signal's count and noise (:mod:`~ncmeasure.analysis.windows.detection`)
  widen every tolerance band and raise the standstill threshold to at least
  one count; where they exceed ``velocity_floor_mm_min`` and a position was
  recorded, windows are found and measured by the position;
* no window spans a hole of the time axis (a step over
  :data:`~ncmeasure.analysis.windows.settings.HOLE_PERIODS` sample periods: a
  link outage, the step between two imported files): every stretch is cut at
  the holes, no plateaus are joined across one, and without a position
  channel the windows of several segments are one position;
* every window must agree with its displacement (v·Δt): a velocity reading
  frozen at standstill, or an axis that did not follow its command, is no
  window; where the velocity comes from the readings, the window's velocity
  is its displacement over its duration.

Every window loses its acceleration transient: the samples up to
``settle_s`` after the (smoothed) actual velocity entered the tolerance band
of the window's velocity. A window that the NC program already started
``settle_s`` after the run-up loses nothing. Windows shorter than
``min_window_s`` after that are dropped. When nothing is found, the error
says what was tried and whether the axis moved at all.

Labelling: with a schedule, each window gets the step, position index,
direction and repetition of the scheduled window it belongs to: by marker
value (``marker_values = "window_id"``), else by time order, velocity and
position (a window matches the next scheduled window in program order whose
velocity agrees within the tolerance and whose run contains the window's
centre). Windows that match nothing (rapids, warm-up strokes) are dropped.
Without a schedule, windows are clustered: velocities into steps (gaps in
|v| larger than ``step_tolerance`` relative, ``step_floor_mm_min`` absolute)
and window centres into positions (gaps larger than ``position_gap_mm`` or
``position_gap_fraction`` of the span, found among the slower half of the
steps, whose windows no planner shifts; every window then joins the nearest
position). Rapid traverse is dropped first: windows faster than
``max_velocity_mm_min`` (or the schedule's top step), the fastest level when
it holds ``rapid_count_factor`` times more windows than a typical level, and
windows lasting ``duration_outlier_factor`` times longer than their level's
trend of duration over velocity (warm-up strokes over the whole travel).

:class:`WindowFinder` does all of this on the stretches that each way found;
where they come from is its subclasses' part:
:class:`~ncmeasure.analysis.windows.chunked.ChunkedFinder` finds them in a
recording read chunk by chunk (the only way ncmeasure reads one: a recording in
memory is one chunk), keeping the samples of the stretches only. Labelling is
:mod:`~ncmeasure.analysis.windows.schedule` and
:mod:`~ncmeasure.analysis.windows.clusters`.

Pure numpy/scipy; loops run over windows, never over samples.
"""

from __future__ import annotations

import bisect
import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.clusters import (
    drop_rapids,
    drop_thin_steps,
    drop_too_fast,
    label_by_clusters,
)
from ncmeasure.analysis.windows.detection import Detection
from ncmeasure.analysis.windows.model import Candidate, Segmentation
from ncmeasure.analysis.windows.rolling import rolling_median
from ncmeasure.analysis.windows.schedule import ScheduleMatch
from ncmeasure.analysis.windows.settings import (
    COARSE_WINDOW_SAMPLES,
    CORRELATED_RHO,
    DISPLACEMENT_QUANTA,
    JOIN_GAP_SAMPLES,
    JOIN_SPREAD,
    STEADY_MEAN_SHARE,
    STEADY_SCATTER,
    STEADY_SHARE,
    Method,
    WindowSource,
)
from ncmeasure.analysis.windows.signals import correlated_noise, nan_median, unit_factor
from ncmeasure.errors import RecordingError
from ncmeasure.formats.schedule import AxisSummary, Schedule

__all__ = ["WindowFinder"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


class WindowFinder(Detection):
    """Finds and labels the windows of one axis from the stretches each way found.

    A subclass sets the signals (``t``, ``v``, ``x``, ``v_detect``, ``command``,
    ``marker``: arrays, or what answers their slices) and the counts
    (:class:`~ncmeasure.analysis.windows.detection.Detection`), and gives the
    stretches of each way (:meth:`marker_candidates`, :meth:`command_candidates`,
    :meth:`plateau_candidates`) and :meth:`still`; :meth:`run` does the rest.
    """

    n: int
    rapid_mm_min: float | None
    tried: list[str]
    t: FloatArray
    v: FloatArray
    x: FloatArray
    v_detect: FloatArray
    command: FloatArray | None
    marker: FloatArray | None
    holes: list[int]
    """The rows that follow a hole of the time axis (a step over
    :data:`~ncmeasure.analysis.windows.settings.HOLE_PERIODS` sample periods), in order."""

    def setup_schedule(self, schedule: Schedule | None) -> None:
        """The axis' part of the schedule, and how its program writes the marker."""
        self.summary: AxisSummary | None = None
        self.scope: Literal["window", "run", "none"] = "window"
        self.marker_values: Literal["window_id", "flag"] = "window_id"
        if schedule is not None:
            self.scope = schedule.marker_scope
            self.marker_values = schedule.marker_values
            for summary in schedule.axes:
                if summary.name == self.axis:
                    self.summary = summary
            if self.summary is None:
                self.warnings.append(
                    "the schedule has no windows for this axis: windows clustered instead"
                )
        self.schedule = ScheduleMatch(self.summary, self) if self.summary is not None else None

    # -- the ways of finding windows: the subclass' part -----------------------------

    def marker_candidates(self) -> list[Candidate]:
        """The marker's runs that move (:meth:`marker_wanted`, :meth:`marker_levels`)."""
        raise NotImplementedError

    def command_candidates(self) -> list[Candidate]:
        """The stretches of constant commanded velocity (:meth:`command_found`)."""
        raise NotImplementedError

    def plateau_candidates(self) -> list[Candidate]:
        """The plateaus of the smoothed velocity (:meth:`plateau_found`)."""
        raise NotImplementedError

    def still(self) -> str | None:
        """Why the axis did not move at all, or None when it moved.

        Where a position was recorded it decides: the axis did not move when
        its position creeps by less than the standstill speed over the whole
        recording, whatever the velocity reads (a reading frozen at −3 mm/min
        moves nothing). Without a position, when its velocity never stays above
        the standstill threshold (at least one velocity count) for a window's
        length.
        """
        raise NotImplementedError

    # -- what each way found ---------------------------------------------------------

    def split_at_holes(
        self, stretches: Sequence[tuple[int, int]], least: int = 1
    ) -> list[tuple[int, int]]:
        """The stretches cut at every hole of the time axis, the pieces of ``least`` rows kept.

        The axis may have moved any distance, at any speed, in a hole (a link
        outage, the step between two files): what lies either side of one is two
        stretches, never one window.
        """
        holes = np.asarray(self.holes, dtype=np.intp)
        result = []
        for start, stop in stretches:
            cuts = holes[(holes > start) & (holes < stop)].tolist()
            bounds = [start, *cuts, stop]
            result += [(a, b) for a, b in itertools.pairwise(bounds) if b - a >= least]
        return result

    def hole_between(self, start: int, stop: int) -> bool:
        """Whether a hole of the time axis lies inside the rows ``start`` .. ``stop``."""
        k = bisect.bisect_right(self.holes, start)
        return k < len(self.holes) and self.holes[k] < stop

    def segment_bounds(self, row: int) -> tuple[int, int]:
        """The first row of ``row``'s segment (after the hole before it) and the end."""
        k = bisect.bisect_right(self.holes, row)
        return (self.holes[k - 1] if k > 0 else 0), (
            self.holes[k] if k < len(self.holes) else self.n
        )

    def marker_wanted(self) -> bool:
        """Whether there is a marker to look at (else why not, in ``tried``)."""
        if self.marker is None:
            self.tried.append("marker: not recorded")
            return False
        if self.summary is not None and self.scope == "none":
            self.tried.append("marker: the schedule says the program writes none")
            return False
        return True

    def marker_levels(
        self, starts: Sequence[int], stops: Sequence[int], values: Sequence[float]
    ) -> list[Candidate]:
        """Candidates of the marker runs that move (level: commanded, else actual velocity)."""
        if len(starts) == 0:
            self.tried.append("marker: recorded but never set")
            return []
        reference = self.command if self.command is not None else self.v_detect
        standstill = (
            self.settings.standstill_mm_min if self.command is not None else self.standstill
        )
        result = []
        for run_start, run_stop, value in zip(starts, stops, values, strict=True):
            for start, stop in self.split_at_holes([(run_start, run_stop)]):
                level = nan_median(reference[start:stop])
                if not abs(level) >= standstill:
                    continue
                result.append(Candidate(start, stop, level, marker_value=float(value)))
        if not result:
            self.tried.append(f"marker: {len(starts)} marker windows, all at standstill")
        return result

    def command_found(
        self, begins: Sequence[int], ends: Sequence[int], levels: Sequence[float]
    ) -> list[Candidate]:
        result = [
            Candidate(start, stop, float(c))
            for b, e, c in zip(begins, ends, levels, strict=True)
            for start, stop in self.split_at_holes([(int(b), int(e))], self.min_n)
        ]
        if not result:
            self.tried.append(
                f"commanded velocity: no constant stretch of {self.min_n} samples "
                f"({self.settings.min_window_s:g} s) above "
                f"{self.settings.standstill_mm_min:g} mm/min"
            )
        return result

    def plateau_too_short(self) -> bool:
        if self.n < self.plateau_n:
            self.tried.append(
                "plateaus: the recording is shorter than plateau_min_s "
                f"({self.settings.plateau_min_s:g} s)"
            )
            return True
        return False

    def join_gap_n(self) -> int:
        """Samples between two plateaus that may still be one speed (:meth:`joined`)."""
        return max(JOIN_GAP_SAMPLES, 2 * self.plateau_n, 2 * self.filter_n, 2 * self.settle_n)

    def bridged(self, runs: Sequence[tuple[int, int]]) -> list[tuple[int, int]]:
        """What joining reads: the runs widened by :meth:`join_gap_n` either side, merged."""
        gap = self.join_gap_n()
        result: list[tuple[int, int]] = []
        for start, stop in runs:
            low, high = max(0, start - gap), min(self.n, stop + gap)
            if result and low <= result[-1][1]:
                result[-1] = (result[-1][0], high)
            else:
                result.append((low, high))
        return result

    def _widened(self, candidate: Candidate, low: int, high: int) -> Candidate:
        """A joined plateau grown over the readings next to it that its noise explains.

        By at most :meth:`join_gap_n` samples each way, not beyond ``low`` ..
        ``high`` (its neighbours): so a steady run is one window of all its
        samples, not of the stretches where the velocity happened to hold.
        """
        gap = self.join_gap_n()
        first, end = self.segment_bounds(candidate.start)
        low, high = max(low, first), min(high, end)
        level, sigma = candidate.level_mm_min, candidate.noise_mm_min
        spread = max(float(self.band(level)), JOIN_SPREAD * sigma)
        before_low = max(low, candidate.start - gap)
        before = self.v_detect[before_low : candidate.start]
        near = np.abs(before - level) <= spread
        start = candidate.start - (int(np.argmin(near[::-1])) if not near.all() else len(near))
        after_high = min(high, candidate.stop + gap)
        after = self.v_detect[candidate.stop : after_high]
        near = np.abs(after - level) <= spread
        stop = candidate.stop + (int(np.argmin(near)) if not near.all() else len(near))
        return replace(candidate, start=start, stop=stop)

    def joined(self, candidates: Sequence[Candidate]) -> list[Candidate]:
        """Neighbouring plateaus of one speed, broken apart by its correlated noise, joined.

        A drive's averaged velocity wanders around its level for many samples
        (lag-1 autocorrelation 0.7 to 0.9): the smoothed velocity leaves a band
        set by the tolerance now and then, and one steady run breaks into
        plateaus of the stretches where the velocity happened to hold. Two
        neighbouring plateaus (at most :meth:`join_gap_n` samples apart, same
        direction) are one when the noise of the velocity from the first one's
        start to the second one's end (:func:`~ncmeasure.analysis.windows.signals.correlated_noise`,
        σ) explains both: their levels differ by at most the band or
        ``JOIN_SPREAD``·σ, and every reading lies within as much of the joined
        stretch's median, above standstill; ``JOIN_SPREAD``·σ must stay within
        ``STEADY_SCATTER`` of the level (a move between is no noise).
        A step between two levels is no noise (the differences' mean square
        leaves it out): stairs stay apart. A joined plateau's level is the
        median of all its readings, and it carries σ, which widens its band
        when it is trimmed. A joined plateau, or one whose own noise is
        correlated (ρ ≥ ``CORRELATED_RHO``) and reaches beyond the band, is
        grown over the readings next to it that its noise explains
        (:meth:`_widened`).
        """
        result: list[Candidate] = []
        for candidate in candidates:
            if result and self._joins(result[-1], candidate):
                last = result[-1]
                span = self.v_detect[last.start : candidate.stop]
                sigma, _ = correlated_noise(span)
                level = nan_median(span)
                result[-1] = replace(
                    last, stop=candidate.stop, level_mm_min=level, noise_mm_min=sigma
                )
            else:
                result.append(candidate)
        for k, candidate in enumerate(result):
            if candidate.noise_mm_min == 0:
                # A plateau on its own may be a piece of a run whose correlated noise
                # broke it off all the same (white noise breaks no steady run).
                sigma, rho = correlated_noise(self.v_detect[candidate.start : candidate.stop])
                band = float(self.band(candidate.level_mm_min))
                steady = JOIN_SPREAD * sigma <= STEADY_SCATTER * abs(candidate.level_mm_min)
                if rho >= CORRELATED_RHO and steady and JOIN_SPREAD * sigma > band:
                    candidate = replace(candidate, noise_mm_min=sigma)
            if candidate.noise_mm_min > 0:
                low = result[k - 1].stop if k > 0 else 0
                high = result[k + 1].start if k + 1 < len(result) else self.n
                result[k] = self._widened(candidate, low, high)
        return result

    def _joins(self, first: Candidate, second: Candidate) -> bool:
        if second.start - first.stop > self.join_gap_n():
            return False
        if self.hole_between(first.start, second.stop):
            return False  # the axis may have done anything in the hole
        if first.level_mm_min * second.level_mm_min <= 0:
            return False
        span = self.v_detect[first.start : second.stop]
        span = span[np.isfinite(span)]
        sigma, _ = correlated_noise(span)
        if len(span) == 0 or sigma <= 0:
            return False
        level = float(np.median(span))
        band = float(self.band(level))
        if JOIN_SPREAD * sigma > STEADY_SCATTER * abs(level):
            return False  # noise as large as that is no steady run (a move, a ramp between)
        if abs(first.level_mm_min - second.level_mm_min) > max(band, JOIN_SPREAD * sigma):
            return False
        if np.min(np.abs(span)) < self.standstill or np.min(span * np.sign(level)) <= 0:
            return False
        return bool(np.max(np.abs(span - level)) <= max(band, JOIN_SPREAD * sigma))

    def plateau_found(
        self,
        runs: Sequence[tuple[int, int, float]],
        moving: Sequence[tuple[int, int]] = (),
    ) -> list[Candidate]:
        settings = self.settings
        result = self.joined([Candidate(start, stop, level) for start, stop, level in runs])
        if moving:
            result = self.steady_runs(result, moving)
        if not result:
            self.tried.append(
                f"plateaus: no stretch of {settings.plateau_min_s:g} s where the actual velocity "
                f"stays within {100 * settings.velocity_tolerance:g} % "
                f"(at least {float(self.band(0.0)):.3g} mm/min) above "
                f"{self.standstill:.3g} mm/min"
            )
        return result

    def steady_runs(
        self, plateaus: Sequence[Candidate], moving: Sequence[tuple[int, int]]
    ) -> list[Candidate]:
        """Every run of one speed as one window, however noisy its velocity.

        A run is a stretch where the smoothed velocity keeps its sign above
        standstill (``moving``, cut at holes). Where the velocity is noisy
        compared with the tolerance (a robot joint's encoder-derived velocity at
        a slow speed scatters by 10 to 50 %, with a correlated wobble of the
        speed loop on top), no stretch of it stays within the band and a run at
        one speed gives no plateau, or fragments. A run is steady when the two
        halves of its middle half agree (:meth:`_steady_core`): then its core
        (the run without its ramps) is one window where the run gave no
        plateau, or several, all at the core's level (fragments). A run of several
        speeds (stairs without a stop) is not steady, or its plateaus lie at
        other levels: they stay as they are.
        """
        result = list(plateaus)
        for start, stop in moving:
            core = self._steady_core(start, stop)
            if core is None:
                continue
            inside = [c for c in result if c.start < core.stop and c.stop > core.start]
            spread = max(float(self.band(core.level_mm_min)), JOIN_SPREAD * core.noise_mm_min)
            if any(abs(c.level_mm_min - core.level_mm_min) > spread for c in inside):
                continue
            if len(inside) == 1:
                continue  # a plateau of the run's own: joined and grown as before
            kept = [c for c in result if not any(c is d for d in inside)]
            result = sorted([*kept, core], key=lambda c: c.start)
        return result

    def _steady_core(self, start: int, stop: int) -> Candidate | None:
        """The core of a run at one speed (None when the run is not steady).

        The level is the median of the run's middle half and σ, ρ its noise
        (:func:`~ncmeasure.analysis.windows.signals.correlated_noise`); a
        sample of correlated noise counts as 1/m independent ones, m =
        (1 + ρ)/(1 − ρ). A rolling mean over w samples has the standard error
        σ √(m/w); w makes it a third of the band, within a quarter of the run,
        and three such errors must stay within ``STEADY_MEAN_SHARE`` of the
        level (ramps between speeds make σ as large as the speeds' difference).
        The run is steady when the rolling means over its middle half lie
        within the band (or 3 such errors) of the level, at least
        ``STEADY_SHARE`` of them (a ramp, a triangle of a short move, stairs do
        not). The core reaches from the middle to where the rolling mean is
        twice as far off (the ramps), and must hold a plateau (``plateau_min_s``).
        """
        values = self.v_detect[start:stop]
        length = len(values)
        if length < self.plateau_n or not np.isfinite(values).all():
            return None
        middle = values[length // 4 : length - length // 4]
        level = float(np.median(middle))
        if abs(level) < self.standstill:
            return None
        sigma, rho = correlated_noise(middle)
        band = float(self.band(level))
        m = (1.0 + rho) / (1.0 - rho)
        wanted = math.ceil(m * (3.0 * sigma / band) ** 2) if sigma > 0 else 1
        width = int(min(max(wanted, self.filter_n, 1), max(1, length // 4)))
        accept = max(band, 3.0 * sigma * math.sqrt(m / width))
        if accept > STEADY_MEAN_SHARE * abs(level):
            return None  # too short for its noise, or no noise: a move of several speeds
        sums = np.concatenate(([0.0], np.cumsum(values - level)))
        off = np.abs(sums[width:] - sums[:-width]) / width  # at row k + width // 2
        centre = width // 2
        inner = off[max(0, length // 4 - centre) : max(1, length - length // 4 - centre)]
        if np.count_nonzero(inner <= accept) < STEADY_SHARE * len(inner):
            return None
        far = off > 2.0 * accept
        mid = min(max(0, length // 2 - centre), len(off) - 1)
        before = np.flatnonzero(far[:mid])
        after = np.flatnonzero(far[mid:])
        first = start + (int(before[-1]) + 1 if len(before) else 0) + centre
        last = start + (mid + int(after[0]) if len(after) else len(off)) + centre
        if last - first < self.plateau_n:
            return None
        return Candidate(first, last, level, noise_mm_min=sigma)

    # -- trimming ----------------------------------------------------------------------

    def trim(
        self,
        start: int,
        stop: int,
        level: float,
        *,
        guard_end: bool = False,
        noise_mm_min: float = 0.0,
    ) -> tuple[int, int] | None:
        """Cut transients: begin ``settle_s`` after the velocity settled, end at its last good.

        Where the velocity itself says where the window ends (``guard_end``, or
        the velocity left the band before ``stop``), the end moves back by the
        smoothing width: the rolling median sees a deceleration that much late,
        and the current (the controller's torque) leads the velocity.
        """
        width = self.filter_n
        low = max(0, start - self.settle_n - width)
        high = min(self.n, stop + width)
        chunk = self.v_detect[low:high]
        chunk = np.where(np.isfinite(chunk), chunk, np.inf)
        smooth = rolling_median(chunk, width) if width > 1 else chunk
        band = np.maximum(self.band(level), JOIN_SPREAD * noise_mm_min)
        inside = np.abs(smooth - level) <= band
        a, b = start - low, stop - low
        good = inside[a:b]
        if not good.any():
            return None
        first = a + int(np.argmax(good))
        last = b - int(np.argmax(good[::-1]))
        if guard_end or last < b:
            last -= width
        begin = first
        c0, c1 = max(0, first - self.settle_n), min(last, first + self.settle_n)
        outside = ~inside[c0:c1]
        if outside.any():
            j = c0 + len(outside) - 1 - int(np.argmax(outside[::-1]))
            begin = max(first, j + 1 + self.settle_n)
        if last - begin < self.min_n:
            return None
        return low + begin, low + last

    # -- the whole job -----------------------------------------------------------------

    def attempt(self, method: Method) -> tuple[WindowSource, list[Candidate], bool] | None:
        """One way of finding windows, up to trimmed candidates; None when none is left.

        Returns:
            The source, the trimmed candidates, and whether they are already
            matched to the schedule (marker windows are matched before the cut).
        """
        settings = self.settings
        noted = len(self.warnings)
        source: WindowSource
        if method == "marker":
            candidates, source, name = self.marker_candidates(), "marker", "marker"
        elif method == "command":
            candidates, source, name = self.command_candidates(), "command", "commanded velocity"
        else:
            candidates, source, name = self.plateau_candidates(), "plateau", "plateaus"
        if not candidates:
            return None
        found = len(candidates)
        labelled = False
        if method == "marker" and self.schedule is not None:
            whole_runs = self.scope == "run"
            # A marker wired to a digital input (a drive's, a PLC's) only says on or off,
            # whatever the program writes: such windows are labelled by program order.
            on_off = self.marker_values == "window_id" and _on_off(candidates)
            by_id = self.marker_values == "window_id" and not on_off
            if on_off and whole_runs:
                # The program clears and sets the id at one standstill between two runs:
                # on a single input both runs are one.
                self.tried.append(
                    "marker: on or off only, where the program writes window ids around "
                    "whole runs; back-to-back runs cannot be told apart"
                )
                return None
            candidates = self.schedule.match_schedule(
                candidates, self.x, by_id=by_id, whole_runs=whole_runs
            )
            labelled = True
            if whole_runs:
                candidates = self.schedule.cut_runs(candidates, self.x)
                source = "schedule"
            if not candidates:
                self.tried.append(f"marker: {found} marker windows, none fits the schedule")
                del self.warnings[noted:]
                return None
        trimmed = []
        for candidate in candidates:
            cut = self.trim(
                candidate.start,
                candidate.stop,
                candidate.level_mm_min,
                guard_end=source == "plateau",
                noise_mm_min=candidate.noise_mm_min,
            )
            if cut is not None:
                trimmed.append(replace(candidate, start=cut[0], stop=cut[1]))
        if not trimmed:
            self.tried.append(
                f"{name}: {len(candidates)} stretches, in none does the actual velocity stay "
                f"within the tolerance for {self.min_n} samples ({settings.min_window_s:g} s) "
                f"after settle_s ({settings.settle_s:g} s)"
            )
            del self.warnings[noted:]
            return None
        if len(trimmed) < len(candidates):
            self.warnings.append(
                f"{len(candidates) - len(trimmed)} windows shorter than {self.min_n} samples "
                f"({settings.min_window_s:g} s) after the settling time: dropped"
            )
        commanded = method == "command" or (method == "marker" and self.command is not None)
        measured = self.measure(trimmed, commanded=commanded)
        if not measured:
            self.tried.append(
                f"{name}: {len(trimmed)} stretches, in none does the position move as the "
                "velocity says"
            )
            del self.warnings[noted:]
            return None
        return source, measured, labelled

    def measure(self, candidates: Sequence[Candidate], *, commanded: bool) -> list[Candidate]:
        """Check every window against the position; measure its velocity by displacement.

        At constant velocity the position moves by v·Δt. A window whose
        displacement disagrees with its velocity (beyond the tolerance band,
        one velocity count and two position counts over its duration) is not
        a window of steady motion: a frozen velocity reading at standstill, or
        an axis that did not follow its command. It is dropped. Where the
        velocity comes from the readings (plateaus, a marker without command),
        the window's velocity becomes its displacement over its duration: the
        readings' median sits on one of their counts, the displacement does not.

        When most windows disagree by one common factor, the position is in
        another unit (:func:`~ncmeasure.analysis.windows.signals.unit_factor`):
        nothing is dropped, the readings keep the say, and a warning names the
        factor. Displacements near zero
        or scattered share no factor: those windows are dropped, however many.
        """
        if not self.positions_known or not candidates:
            return list(candidates)
        failed: list[float] = []  # slope / reference of each window that disagrees
        still = 0
        kept: list[Candidate] = []
        for candidate in candidates:
            t = self.t[candidate.start : candidate.stop]
            x = self.x[candidate.start : candidate.stop]
            ok = np.isfinite(t) & np.isfinite(x)
            if np.count_nonzero(ok) < 2:
                kept.append(candidate)
                continue
            t, x = t[ok], x[ok]
            duration = float(t[-1] - t[0])
            centred = t - t.mean()
            slope = float(centred @ (x - x.mean()) / (centred @ centred)) * 60.0
            resolution = 60.0 * DISPLACEMENT_QUANTA * self.x_quantum / duration
            if commanded or self.from_position:
                reference = candidate.level_mm_min
            else:
                readings = self.v[candidate.start : candidate.stop]
                reference = nan_median(readings)
            allowed = max(float(self.band(reference)), self.v_quantum, resolution)
            if abs(slope - reference) > allowed:
                failed.append(slope / reference if reference else math.nan)
                continue
            if not commanded:
                if abs(slope) < max(self.settings.standstill_mm_min, resolution):
                    still += 1
                    continue
                # The transient is cut again against the measured velocity.
                cut = self.trim(
                    candidate.start, candidate.stop, slope, noise_mm_min=candidate.noise_mm_min
                )
                if cut is None:
                    continue
                candidate = replace(candidate, start=cut[0], stop=cut[1], level_mm_min=slope)
            kept.append(candidate)
        factor = unit_factor(failed)
        if len(failed) > 0.5 * len(candidates) and len(candidates) >= 4 and factor is not None:
            self.warnings.append(
                f"the recorded position moves {factor:.4g} times as far as the velocity says in "
                f"{len(failed)} of {len(candidates)} windows (another unit of the position?): "
                "windows are measured by the velocity readings alone"
            )
            return list(candidates)
        if failed:
            self.warnings.append(
                f"{len(failed)} windows dropped: the position did not move as the velocity says "
                + (
                    "(the axis did not follow its command)"
                    if commanded
                    else "(a velocity reading frozen at standstill?)"
                )
            )
        if still:
            self.warnings.append(
                f"{still} windows dropped: by their displacement the axis stood still"
            )
        return kept

    def run(self) -> Segmentation:
        """The windows of the first way that gives some, labelled; the steps and positions.

        Raises:
            RecordingError: No way gave a window (the problems say what was
                tried), or every window was dropped.
        """
        method = self.settings.window_method
        order: tuple[Method, ...] = (
            ("marker", "command", "plateau") if method == "auto" else (method,)
        )
        for way in order:
            found = self.attempt(way)
            if found is not None:
                break
        else:
            still = self.still()
            raise RecordingError(
                f"axis {self.axis}: no window of constant velocity found"
                + (f": {still}" if still else ""),
                [*self.tried, "settings: velocity_tolerance, velocity_floor_mm_min, "
                 "standstill_mm_min, plateau_min_s, min_window_s, settle_s"],
            )  # fmt: skip
        source, candidates, labelled = found
        if method == "auto" and way != "marker":
            first = _fallen_back(way, self.marker is not None, self.command is not None)
            reasons = [t for t in self.tried if not t.endswith("not recorded")]
            self.warnings[:0] = [first, *reasons]
        candidates = drop_too_fast(candidates, self, self.summary, self.rapid_mm_min)
        if self.schedule is not None and not labelled:
            candidates = self.schedule.match_schedule(
                candidates, self.x, by_id=False, whole_runs=False
            )
            labelled = True
        if not labelled and source in ("command", "plateau"):
            candidates = drop_rapids(candidates, self)
        if not labelled and source == "plateau":
            candidates = drop_thin_steps(candidates, self)
        if not candidates:
            raise RecordingError(
                f"axis {self.axis}: every {source} window was dropped",
                [*self.tried, *self.warnings],
            )
        if labelled:
            assert self.schedule is not None
            windows, steps, positions = self.schedule.label_by_schedule(candidates, self.x, source)
        else:
            windows, steps, positions = label_by_clusters(
                candidates, self.x, source, self, one_position=self._incomparable(candidates)
            )
        windows.sort(key=lambda w: w.start)
        typical = float(np.median([w.samples for w in windows]))
        coarse = typical < COARSE_WINDOW_SAMPLES
        if coarse:
            self.warnings.append(
                f"coarse data: at {self.dt * 1000:.3g} ms per sample a window holds a median "
                f"of {typical:.0f} samples (fewer than {COARSE_WINDOW_SAMPLES}): each point is "
                "uncertain and the Stribeck curve at low speed is not resolved; the friction is "
                "described by the linear model over its range"
            )
        log.debug(
            "axis %s: %d %s windows, %d steps, %d positions",
            self.axis,
            len(windows),
            source,
            len(steps),
            len(positions),
        )
        return Segmentation(
            axis=self.axis,
            windows=windows,
            source=source,
            labelled_by="schedule" if labelled else "clusters",
            steps=steps,
            positions=positions,
            warnings=list(dict.fromkeys(self.warnings)),
            tried=self.tried,
            sample_period_s=self.dt,
            velocity_quantum_mm_min=self.v_quantum,
            velocity_resolution_mm_min=self.resolution,
            position_quantum_mm=self.x_quantum,
            coarse=coarse,
        )

    def _incomparable(self, candidates: Sequence[Candidate]) -> bool:
        """Whether positions integrated from the velocity lie in segments between holes.

        Without a position channel a window's position is the velocity integrated
        from the start of its segment; across a hole of the time axis the axis may
        have moved any distance, so windows of two segments cannot be put at one
        position or at two. They are then all one position, and a warning says so.
        """
        if self.positions_known or not self.holes:
            return False
        segments = {bisect.bisect_right(self.holes, c.start) for c in candidates}
        if len(segments) < 2:
            return False
        self.warnings.append(
            f"no position channel, and the windows lie in {len(segments)} segments between "
            f"holes of the time axis ({len(self.holes)} holes: separate captures, link "
            "outages): where the axis stood in one relative to another is unknown, so all "
            "windows are taken as one position (positions integrated in each segment from "
            "its start); the position dependence is not judged"
        )
        return True


def _on_off(candidates: Sequence[Candidate]) -> bool:
    """Whether the marker windows all carry one value: a flag, not the window ids."""
    return len(candidates) > 1 and len({c.marker_value for c in candidates}) == 1


def _fallen_back(way: Method, has_marker: bool, has_command: bool) -> str:
    """The first warning where the windows come from a way after the marker."""
    if way == "command":
        why = "no marker windows" if has_marker else "no marker"
        return f"{why}: windows from the commanded velocity"
    if not has_marker and not has_command:
        return (
            "no marker and no commanded velocity: windows from constant-velocity "
            "plateaus of the actual velocity"
        )
    return (
        "neither marker nor commanded velocity gave windows: windows from "
        "constant-velocity plateaus of the actual velocity"
    )
