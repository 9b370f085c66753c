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
* the velocity signal's count (:func:`quantum`) and noise (:func:`noise_sigma`)
  widen every tolerance band and raise the standstill threshold to at least
  one count; where they exceed ``velocity_floor_mm_min`` and a position was
  recorded, windows are found and measured by the position;
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

Pure numpy/scipy; loops run over windows, never over samples.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Final, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.ndimage import maximum_filter1d, median_filter, minimum_filter1d
from scipy.stats import theilslopes

from ncmeasure.analysis.windows.streaming import chunks_of, quantum_task, run_task, whole
from ncmeasure.errors import RecordingError
from ncmeasure.formats.schedule import AxisSummary, Schedule
from ncmeasure.formats.schedule import Window as ScheduledWindow
from ncmeasure.recording import Recording

__all__ = [
    "COARSE_WINDOW_SAMPLES",
    "MIN_WINDOW_SAMPLES",
    "Cluster",
    "SegmentSettings",
    "Segmentation",
    "VelocityWindow",
    "WindowSource",
    "cluster_gaps",
    "find_windows",
    "noise_sigma",
    "quantum",
    "windows_of",
]

log = logging.getLogger(__name__)

WindowSource = Literal["marker", "command", "plateau", "schedule"]
Method = Literal["auto", "marker", "command", "plateau"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]

MIN_WINDOW_SAMPLES: Final = 3
"""No window keeps fewer samples, whatever ``min_window_s``: a median and a spread need 3."""

COARSE_WINDOW_SAMPLES: Final = 20
"""Windows holding fewer samples than this (median over the axis) make the data coarse:
their medians are uncertain and the Stribeck curve at low speed is not resolved."""

DISPLACEMENT_QUANTA: Final = 2.0
"""A window's displacement is known to this many position counts (one at each end)."""

_NOISE_BAND_FACTOR: Final = 3.0
"""The tolerance band is at least this many standard errors of the smoothed velocity."""


class SegmentSettings(BaseModel):
    """How windows are found and which samples they keep.

    The defaults suit ncmeasure's own programs (windows of 0.2 to 0.4 s,
    settle 0.1 s, 1 to 4 ms sampling, lowest step about 10 mm/min) and hold
    for foreign recordings down to 100 ms sampling: every duration is in
    seconds, and the sample counts follow from the sample period. They are
    written into ``results.json`` (``settings``), so a result says how it was
    made. :class:`~ncmeasure.analysis.analyze.AnalysisSettings` is this model.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    velocity_tolerance: float = Field(
        default=0.03,
        gt=0,
        lt=1,
        description="A window's velocity must agree with its commanded (or scheduled) one "
        "within this fraction, or velocity_floor_mm_min, or the velocity signal's resolution "
        "(one count, its noise), whichever is largest. Also the flatness a plateau must keep.",
    )
    velocity_floor_mm_min: float = Field(
        default=2.0,
        ge=0,
        description="Absolute floor of the velocity tolerance in mm/min: at low speed the "
        "relative tolerance would be smaller than the velocity signal's noise.",
    )
    settle_s: float = Field(
        default=0.1,
        ge=0,
        description="Samples until this long after the actual velocity entered the "
        "tolerance band are cut from each window (acceleration transient, overshoot).",
    )
    min_window_s: float = Field(
        default=0.1,
        gt=0,
        description="A window shorter than this after the cut is dropped; it keeps at least "
        f"{MIN_WINDOW_SAMPLES} samples whatever the sample period.",
    )
    plateau_min_s: float = Field(
        default=0.2,
        gt=0,
        description="Shortest plateau of constant actual velocity that counts as a window "
        "(only without marker and commanded velocity).",
    )
    plateau_filter_s: float = Field(
        default=0.02,
        ge=0,
        description="Width of the rolling median that smooths the actual velocity before "
        "plateaus and the end of transients are detected.",
    )
    standstill_mm_min: float = Field(
        default=1.0,
        ge=0,
        description="Velocities below this are standstill, never a window. A velocity of "
        "one count of the velocity signal or less is standstill too.",
    )
    step_tolerance: float = Field(
        default=0.01,
        gt=0,
        description="Without a schedule: windows whose velocities differ by less than this "
        "fraction (or step_floor_mm_min) belong to the same velocity step.",
    )
    step_floor_mm_min: float = Field(
        default=0.5,
        ge=0,
        description="Absolute floor of step_tolerance in mm/min.",
    )
    position_gap_mm: float = Field(
        default=20.0,
        gt=0,
        description="Without a schedule: window centres further apart than this (or "
        "position_gap_fraction of their span) belong to different measuring positions.",
    )
    position_gap_fraction: float = Field(
        default=0.05,
        ge=0,
        lt=1,
        description="Relative part of the position gap.",
    )
    max_velocity_mm_min: float | None = Field(
        default=None,
        gt=0,
        description="Windows faster than this are rapid traverse. Default: the schedule's "
        "top step; without a schedule, rapids are recognised by their count and duration.",
    )
    duration_outlier_factor: float = Field(
        default=4.0,
        gt=1,
        description="Without a schedule: windows lasting this many times longer than the "
        "trend of window duration over velocity are traverses or warm-up strokes.",
    )
    rapid_count_factor: float = Field(
        default=3.0,
        gt=1,
        description="Without a schedule: the fastest velocity level is rapid traverse when "
        "it holds this many times more windows than a typical level.",
    )
    window_method: Method = Field(
        default="auto",
        description="auto: marker, else commanded velocity, else plateaus. The others force "
        "one way.",
    )

    def tolerance_mm_min(self, velocity_mm_min: float | FloatArray) -> FloatArray:
        """The accepted |actual − target| at a target velocity: relative with a floor.

        The segmentation widens it further by the resolution of the velocity
        signal it finds in the data (:attr:`Segmentation.velocity_resolution_mm_min`).
        """
        return np.maximum(
            self.velocity_tolerance * np.abs(np.asarray(velocity_mm_min, dtype=np.float64)),
            self.velocity_floor_mm_min,
        )


@dataclass(frozen=True)
class VelocityWindow:
    """One window of constant velocity of one axis.

    Attributes:
        axis: The axis name.
        start: First sample index of the window.
        stop: One past the last sample index (``values[start:stop]``).
        velocity_mm_min: The signed velocity of the window's step: the
            schedule's, or the centre of its velocity cluster.
        level_mm_min: This window's own signed velocity: the commanded one
            where recorded, else the median actual velocity. Samples are kept
            where the actual velocity is within the tolerance of it.
        direction: +1 or −1.
        position_mm: Mean measured position over the window (integrated
            velocity where no position was recorded).
        position_index: Index of the measuring position, 0 = lowest.
        step: Velocity step index, 0 = slowest.
        source: How the window was found.
        window_id: The schedule's window id, when labelled by a schedule.
        repetition: The schedule's repetition, when labelled by a schedule.
    """

    axis: str
    start: int
    stop: int
    velocity_mm_min: float
    level_mm_min: float
    direction: Literal[1, -1]
    position_mm: float
    position_index: int
    step: int
    source: WindowSource
    window_id: int | None = None
    repetition: int | None = None

    @property
    def samples(self) -> int:
        """Number of samples in the window."""
        return self.stop - self.start


@dataclass(frozen=True)
class Cluster:
    """A velocity level or a measuring position found in the data (or given by the schedule).

    ``centre`` is the reported value (|v| in mm/min, or mm); ``low``/``high``
    the range of the windows in it.
    """

    index: int
    centre: float
    low: float
    high: float
    windows: int


@dataclass
class Segmentation:
    """What :func:`find_windows` found for one axis.

    Attributes:
        axis: The axis name.
        windows: The labelled windows, in time order.
        source: How the windows were found.
        labelled_by: ``"schedule"`` or ``"clusters"``.
        steps: Velocity levels (|v|), index = step, ascending.
        positions: Measuring positions, index = position_index, ascending.
        warnings: What the analysis should tell the user.
        tried: What was tried before ``source`` worked, one line each.
    """

    axis: str
    windows: list[VelocityWindow]
    source: WindowSource
    labelled_by: Literal["schedule", "clusters"]
    steps: list[Cluster]
    positions: list[Cluster]
    warnings: list[str] = field(default_factory=list)
    tried: list[str] = field(default_factory=list)
    sample_period_s: float = math.nan
    velocity_quantum_mm_min: float = 0.0
    velocity_resolution_mm_min: float = 0.0
    position_quantum_mm: float = 0.0
    coarse: bool = False

    @property
    def median_window_samples(self) -> float:
        """Median samples per window (NaN without windows)."""
        if not self.windows:
            return math.nan
        return float(np.median([w.samples for w in self.windows]))


@dataclass
class _Candidate:
    """A stretch of samples that may hold a window, before labelling."""

    start: int
    stop: int
    level_mm_min: float
    marker_value: float | None = None
    scheduled: ScheduledWindow | None = None


# --- small vectorised helpers ----------------------------------------------------------


def _runs(mask: BoolArray) -> tuple[IntArray, IntArray]:
    """Start and stop (exclusive) indices of the runs of True in ``mask``."""
    edges = np.diff(mask.astype(np.int8), prepend=np.int8(0), append=np.int8(0))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _value_runs(on: BoolArray, value: FloatArray) -> tuple[IntArray, IntArray]:
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


def _align(ok: BoolArray) -> list[int | None]:
    """Match rows (found windows) to columns (planned windows), both in program order.

    The most pairs ``ok[i, j]`` such that the order is kept on both sides (a
    longest common subsequence, by dynamic programming row by row). A greedy
    match would let one stray stretch (a warm-up stroke at a measured velocity)
    jump ahead in the schedule and lose every window before the one it took.
    Among equally long alignments, later rows take the later columns.
    """
    rows, cols = ok.shape
    table = np.zeros((rows + 1, cols + 1), dtype=np.int64)
    for i in range(1, rows + 1):
        best = np.maximum(table[i - 1, 1:], table[i - 1, :-1] + ok[i - 1])
        table[i, 1:] = np.maximum.accumulate(best)
    result: list[int | None] = [None] * rows
    i, j = rows, cols
    while i > 0 and j > 0:
        if ok[i - 1, j - 1] and table[i, j] == table[i - 1, j - 1] + 1:
            result[i - 1] = j - 1
            i, j = i - 1, j - 1
        elif table[i, j] == table[i - 1, j]:
            i -= 1
        else:
            j -= 1
    return result


def _odd(count: float) -> int:
    size = max(1, round(count))
    return size if size % 2 else size + 1


def quantum(values: FloatArray) -> float:
    """The resolution of a quantised signal (one count), or 0 for a continuous one.

    A signal is quantised when nearly all (:data:`LATTICE_SHARE`) of its
    non-zero sample-to-sample steps are whole multiples of the smallest one:
    a velocity read in counts of 8.5 mm/min, a current in per mille of the
    rated current. Steps below 10⁻⁹ of the signal's range are rounding noise
    of the unit conversion, not steps.
    """
    data = np.asarray(values, dtype=np.float64)
    data = data[np.isfinite(data)]
    # One computation for arrays and for recordings read chunk by chunk (the lattice
    # steps are summed exactly, so the count does not depend on the chunks).
    value: float = run_task(chunks_of(data, max(len(data), 1)), quantum_task(whole))
    return value


def _bridge(
    values: FloatArray, time_s: FloatArray, *, hold: bool = False
) -> tuple[FloatArray, int]:
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


def _unit_factor(ratios: Sequence[float]) -> float | None:
    """The common factor of position rate over velocity, when the ratios share one.

    A position in another unit moves every window by the same factor (25.4, 1000,
    0.001); frozen readings at standstill give ratios near 0, and an axis that
    did not follow its command gives scattered ones: no factor then.
    """
    values = np.array([r for r in ratios if math.isfinite(r) and r > 0], dtype=np.float64)
    if len(values) < max(2, 0.8 * len(ratios)):
        return None
    logs = np.log(values)
    centre = float(np.median(logs))
    if abs(centre) < math.log(1.2) or float(np.max(np.abs(logs - centre))) > math.log(1.1):
        return None
    return math.exp(centre)


def _agreement(derived: FloatArray, readings: FloatArray, above: float) -> float | None:
    """The median ratio derived/readings where the readings exceed ``above``, or None.

    Where the axis moves fast, one velocity count is small against the
    velocity, so the ratio says whether the position moves as the velocity
    readings say (1) or is in another unit.
    """
    fast = np.isfinite(derived) & np.isfinite(readings) & (np.abs(readings) > above)
    if np.count_nonzero(fast) < MIN_WINDOW_SAMPLES:
        return None
    return float(np.median(derived[fast] / readings[fast]))


def noise_sigma(values: FloatArray) -> float:
    """Robust standard deviation of a signal's sample-to-sample noise.

    From second differences (zero on a constant level and on a ramp), scaled
    by the median absolute deviation: v[i+1] − 2v[i] + v[i−1] of white noise
    of σ has the standard deviation √6·σ. Ramp corners and spikes are too few
    to move the median.
    """
    data = np.asarray(values, dtype=np.float64)
    data = data[np.isfinite(data)]
    if len(data) < 5:
        return 0.0
    second = np.diff(data, n=2)
    mad = float(np.median(np.abs(second - np.median(second))))
    return 1.4826 * mad / math.sqrt(6.0)


def cluster_gaps(values: Sequence[float] | FloatArray, gaps: FloatArray | float) -> IntArray:
    """Gap-based 1-D clustering: sorted values split where neighbours are further apart.

    Args:
        values: The values (any order).
        gaps: The largest distance inside a cluster: one number, or one per
            value, applying to the gap *below* that value in sorted order.

    Returns:
        The cluster index of every value, 0 for the lowest cluster, in the
        order of ``values``.
    """
    data = np.asarray(values, dtype=np.float64)
    labels = np.zeros(len(data), dtype=np.intp)
    if len(data) < 2:
        return labels
    order = np.argsort(data, kind="stable")
    ordered = data[order]
    limit = np.broadcast_to(np.asarray(gaps, dtype=np.float64), data.shape)[order]
    breaks = np.diff(ordered) > limit[1:]
    labels[order] = np.concatenate(([0], np.cumsum(breaks)))
    return labels


def _clusters(values: FloatArray, labels: IntArray) -> list[Cluster]:
    result = []
    for index in range(int(labels.max()) + 1 if len(labels) else 0):
        members = values[labels == index]
        result.append(
            Cluster(
                index=index,
                centre=float(np.median(members)),
                low=float(members.min()),
                high=float(members.max()),
                windows=len(members),
            )
        )
    return result


def position_velocity(
    time_s: FloatArray, position_mm: FloatArray, h: int, lo: int, hi: int, offset: int, n: int
) -> FloatArray:
    """Velocity from the position by central differences over ±h rows, in mm/min.

    For the rows ``lo`` .. ``hi`` of a recording of ``n`` rows, from arrays that
    hold its rows from ``offset`` on (at least ``lo − h`` .. ``hi + h``, clipped
    to the recording): the same values whether the arrays hold the whole
    recording or a stretch of it.
    """
    rows = np.arange(lo, hi)
    ahead = np.minimum(rows + h, n - 1) - offset
    behind = np.maximum(rows - h, 0) - offset
    span = time_s[ahead] - time_s[behind]
    with np.errstate(invalid="ignore", divide="ignore"):
        velocity = np.where(span > 0, (position_mm[ahead] - position_mm[behind]) / span * 60.0, 0.0)
    return np.asarray(velocity, dtype=np.float64)


def command_repeats(command: FloatArray) -> BoolArray:
    """Per row after the first: whether it repeats the row before (within rounding)."""
    jump = np.abs(np.diff(command))
    limit = 1e-4 * np.abs(command[1:]) + 1e-3
    repeats: BoolArray = jump <= limit
    return repeats


def command_stretches(command: FloatArray, n: int) -> tuple[IntArray, IntArray]:
    """Begin and end (exclusive) of the stretches of constant commanded velocity."""
    constant = np.zeros(n, dtype=np.bool_)
    constant[1:] = command_repeats(command)  # sample i repeats sample i - 1
    # A constant stretch starts one sample before its first repeat.
    begins = np.flatnonzero(~constant)
    ends = np.append(begins[1:], n)
    return begins, ends


def _keep_stretches(levels: FloatArray, lengths: IntArray, finder: _Finder) -> BoolArray:
    keep: BoolArray = (np.abs(levels) >= finder.settings.standstill_mm_min) & (
        lengths >= finder.min_n
    )
    return keep


def plateau_mask(
    smooth: FloatArray,
    band: Callable[[FloatArray], FloatArray],
    standstill: float,
    length: int,
    n: int,
    offset: int = 0,
) -> BoolArray:
    """The rows covered by a flat span of ``length`` rows of the smoothed velocity.

    ``smooth`` holds the rows ``offset`` .. ``offset + len(smooth)`` of a
    recording of ``n`` rows. A row's value needs the smoothed velocity
    ``length`` rows either side: it is exact where ``smooth`` reaches that far
    or to the recording's ends.
    """
    count = len(smooth)
    # ok[j]: the smoothed velocity stays within the tolerance over [j, j + length).
    low = minimum_filter1d(smooth, length, mode="nearest", origin=-(length // 2))
    high = maximum_filter1d(smooth, length, mode="nearest", origin=-(length // 2))
    slowest = minimum_filter1d(np.abs(smooth), length, mode="nearest", origin=-(length // 2))
    ok = (high - low) <= band(smooth)
    ok &= slowest >= standstill
    ok[max(0, n - length + 1 - offset) :] = False
    # Samples covered by any good span of `length` samples.
    covered = maximum_filter1d(ok.astype(np.int8), length, origin=(length - 1) // 2) > 0
    # Two levels that touch without a ramp between them are two plateaus.
    jump = np.zeros(count, dtype=np.bool_)
    jump[1:] = np.abs(np.diff(smooth)) > 0.5 * band(smooth[1:])
    mask: BoolArray = covered & ~jump
    return mask


# --- the finder ------------------------------------------------------------------------


class _Finder:
    """Finds and labels the windows of one axis (one call of :func:`find_windows`)."""

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
        velocity, bridged = _bridge(velocity, time_s)
        if bridged:
            self.warnings.append(
                f"{bridged} velocity samples without a value (NaN) bridged by their neighbours "
                "to find the windows"
            )
        if position is not None:
            position, _ = _bridge(position, time_s)
        if command is not None:
            command, _ = _bridge(command, time_s, hold=True)
        self.command = command
        self.positions_known = position is not None
        if position is None:
            # Relative positions are enough to tell measuring positions apart.
            filled = np.where(np.isfinite(velocity), velocity, 0.0)
            self.x = np.cumsum(filled) * (self.dt / 60.0)
            self.warnings.append(
                "no position channel: positions integrated from the velocity (relative)"
            )
        else:
            self.x = position
        self.setup_schedule(schedule)
        self.v = velocity
        self.t = time_s
        self.setup_counts()
        self.setup_resolution(
            quantum(velocity),
            quantum(position) if position is not None else 0.0,
            noise_sigma(velocity),
        )
        ratio: float | None = None
        if self.from_position:
            h = self.position_h(noise_sigma(self.x))
            by_position = self._position_velocity(h)
            ratio = _agreement(by_position, velocity, 5 * self.resolution)
            self.v_detect = velocity
            if ratio is not None and 0.9 <= ratio <= 1.1:
                self.v_detect = by_position
        else:
            self.v_detect = velocity
        self.setup_detection(ratio)

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

    def setup_counts(self) -> None:
        """Sample counts of the settings' durations at the sample period ``dt``."""
        settings = self.settings
        self.detect_resolution = 0.0
        self.settle_n = round(settings.settle_s / self.dt)
        self.filter_n = _odd(settings.plateau_filter_s / self.dt)
        self.min_n = max(MIN_WINDOW_SAMPLES, math.ceil(settings.min_window_s / self.dt - 1e-9))
        self.plateau_n = max(MIN_WINDOW_SAMPLES, round(settings.plateau_min_s / self.dt))

    def setup_resolution(self, v_quantum: float, x_quantum: float, sigma: float) -> None:
        """What the velocity signal resolves, and whether windows come from the position."""
        # What the velocity signal can resolve: one count, and the noise of the
        # rolling median over filter_n samples (√(π/2)·σ/√n).
        self.v_quantum = v_quantum
        self.x_quantum = x_quantum
        smoothed_noise = math.sqrt(math.pi / 2) * sigma / math.sqrt(self.filter_n)
        self.resolution = max(self.v_quantum, _NOISE_BAND_FACTOR * smoothed_noise)
        # A velocity signal coarser than the tolerance floor cannot tell the slow steps
        # apart: find and measure windows by the position instead, where recorded.
        self.from_position = (
            self.positions_known and self.resolution > self.settings.velocity_floor_mm_min
        )

    def setup_detection(self, ratio: float | None) -> None:
        """Keep the position's velocity when it agrees with the readings (``ratio``)."""
        settings = self.settings
        if self.from_position and (ratio is None or not 0.9 <= ratio <= 1.1):
            self.warnings.append(
                "the velocity signal is coarse, but the position does not move as the "
                "velocity says"
                + (f" (its rate is {ratio:.3g} × the velocity)" if ratio is not None else "")
                + ": windows are found by the velocity readings (another unit of the "
                "position?)"
            )
            self.from_position = False
            self.detect_resolution = 0.0
        if self.from_position:
            self.warnings.append(
                f"the velocity signal resolves {self.resolution:.3g} mm/min"
                + (f" (one count is {self.v_quantum:.3g} mm/min)" if self.v_quantum else "")
                + ": windows are found and measured by the position (displacement over time)"
            )
            self.standstill = max(settings.standstill_mm_min, self.detect_resolution)
        else:
            self.standstill = max(settings.standstill_mm_min, self.v_quantum * (1 + 1e-6))

    def position_h(self, sigma_x: float) -> int:
        """Half-width h of the position's central differences; sets their resolution.

        h is long enough that a position count, or the position's noise, moves
        the estimate by at most a quarter of the tolerance floor, and at most a
        quarter of a plateau. The resolution of the estimate (one position count
        over the span, three standard errors of its smoothed noise) widens the
        tolerance band like the velocity readings' resolution does.
        """
        floor = max(self.settings.velocity_floor_mm_min, 1e-9)
        step = max(self.x_quantum, 2.0 * sigma_x)
        wanted = math.ceil(60.0 * step / (0.25 * floor * 2 * self.dt))
        h = int(min(max(1, wanted), max(1, self.plateau_n // 4)))
        # The estimate's noise: two position samples of σ_x over 2h samples.
        noise = 60.0 * math.sqrt(2.0) * sigma_x / (2 * h * self.dt)
        self.detect_resolution = max(
            60.0 * self.x_quantum / (2 * h * self.dt), _NOISE_BAND_FACTOR * noise
        )
        return h

    def _position_velocity(self, h: int) -> FloatArray:
        """Velocity from the position by central differences over ±h samples, in mm/min."""
        return position_velocity(self.t, self.x, h, 0, len(self.x), 0, self.n)

    def band(self, level: float | FloatArray) -> FloatArray:
        """The accepted |velocity − level|: the settings' tolerance, at least the resolution."""
        resolution = self.detect_resolution if self.from_position else self.resolution
        return np.maximum(self.settings.tolerance_mm_min(level), resolution)

    # -- detection ---------------------------------------------------------------------

    def marker_candidates(self) -> list[_Candidate]:
        marker = self.marker
        if not self.marker_wanted():
            return []
        assert marker is not None
        on = np.isfinite(marker) & (marker > 0)
        starts, stops = _value_runs(on, marker)
        return self.marker_levels(starts.tolist(), stops.tolist(), marker[starts].tolist())

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
    ) -> list[_Candidate]:
        """Candidates of the marker runs that move (level: commanded, else actual velocity)."""
        if len(starts) == 0:
            self.tried.append("marker: recorded but never set")
            return []
        reference = self.command if self.command is not None else self.v_detect
        standstill = (
            self.settings.standstill_mm_min if self.command is not None else self.standstill
        )
        result = []
        for start, stop, value in zip(starts, stops, values, strict=True):
            level = float(np.nanmedian(reference[start:stop]))
            if not abs(level) >= standstill:
                continue
            result.append(_Candidate(start, stop, level, marker_value=float(value)))
        if not result:
            self.tried.append(f"marker: {len(starts)} marker windows, all at standstill")
        return result

    def command_candidates(self) -> list[_Candidate]:
        command = self.command
        if command is None:
            self.tried.append("commanded velocity: not recorded")
            return []
        if self.n < 2:
            return []
        begins, ends = command_stretches(command, self.n)
        keep = _keep_stretches(command[begins], ends - begins, self)
        return self.command_found(
            begins[keep].tolist(), ends[keep].tolist(), command[begins[keep]].tolist()
        )

    def command_found(
        self, begins: Sequence[int], ends: Sequence[int], levels: Sequence[float]
    ) -> list[_Candidate]:
        result = [
            _Candidate(int(b), int(e), float(c))
            for b, e, c in zip(begins, ends, levels, strict=True)
        ]
        if not result:
            self.tried.append(
                f"commanded velocity: no constant stretch of {self.min_n} samples "
                f"({self.settings.min_window_s:g} s) above "
                f"{self.settings.standstill_mm_min:g} mm/min"
            )
        return result

    def plateau_candidates(self) -> list[_Candidate]:
        length = self.plateau_n
        if self.plateau_too_short():
            return []
        finite = np.where(np.isfinite(self.v_detect), self.v_detect, 0.0)
        smooth = median_filter(finite, size=self.filter_n, mode="nearest")
        starts, stops = _runs(plateau_mask(smooth, self.band, self.standstill, length, self.n))
        return self.plateau_found(
            [
                (start, stop, float(np.median(smooth[start:stop])))
                for start, stop in zip(starts.tolist(), stops.tolist(), strict=True)
                if stop - start >= length
            ]
        )

    def plateau_too_short(self) -> bool:
        if self.n < self.plateau_n:
            self.tried.append(
                "plateaus: the recording is shorter than plateau_min_s "
                f"({self.settings.plateau_min_s:g} s)"
            )
            return True
        return False

    def plateau_found(self, runs: Sequence[tuple[int, int, float]]) -> list[_Candidate]:
        settings = self.settings
        result = [_Candidate(start, stop, level) for start, stop, level in runs]
        if not result:
            self.tried.append(
                f"plateaus: no stretch of {settings.plateau_min_s:g} s where the actual velocity "
                f"stays within {100 * settings.velocity_tolerance:g} % "
                f"(at least {float(self.band(0.0)):.3g} mm/min) above "
                f"{self.standstill:.3g} mm/min"
            )
        return result

    # -- trimming ----------------------------------------------------------------------

    def trim(
        self, start: int, stop: int, level: float, *, guard_end: bool = False
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
        smooth = median_filter(chunk, size=width, mode="nearest") if width > 1 else chunk
        inside = np.abs(smooth - level) <= self.band(level)
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

    # -- the schedule ------------------------------------------------------------------

    def match(
        self, candidates: Sequence[_Candidate], *, by_position: bool, whole_runs: bool
    ) -> list[ScheduledWindow | None]:
        """Match candidates to scheduled windows by program order, velocity and position."""
        assert self.summary is not None
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
        cand_x = np.array([float(np.nanmean(self.x[c.start : c.stop])) for c in candidates])
        cand_s = np.array([(c.stop - c.start) * self.dt for c in candidates])
        ok = np.sign(cand_v)[:, None] == np.sign(sched_v)[None, :]
        ok &= np.abs(cand_v[:, None] - sched_v[None, :]) <= 2 * self.band(sched_v)
        if by_position:
            ok &= (cand_x[:, None] >= run_lo - margin) & (cand_x[:, None] <= run_hi + margin)
        # A window never lasts longer than its run (plus a generous slack: controllers
        # ramp more gently than planned); warm-up strokes and long rapids do.
        slack = 2.0 if whole_runs else 1.5
        ok &= cand_s[:, None] <= slack * run_s[None, :] + 1.0
        return [None if j is None else planned[j] for j in _align(ok)]

    def match_by_id(self, candidates: Sequence[_Candidate]) -> list[ScheduledWindow | None]:
        assert self.summary is not None
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
            self.warnings.append(
                f"{mismatched} marker windows move against their scheduled direction: dropped"
            )
        return result

    def match_schedule(
        self, candidates: Sequence[_Candidate], *, by_id: bool, whole_runs: bool
    ) -> list[_Candidate]:
        """Attach the scheduled window to every candidate; drop the unmatched ones."""
        if by_id:
            matched = self.match_by_id(candidates)
        else:
            matched = self.match(
                candidates, by_position=self.positions_known, whole_runs=whole_runs
            )
            found = sum(m is not None for m in matched)
            if self.positions_known and found < 0.5 * min(len(candidates), self.planned_count):
                retry = self.match(candidates, by_position=False, whole_runs=whole_runs)
                if sum(m is not None for m in retry) > found:
                    self.warnings.append(
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
            self.warnings.append(
                f"{unmatched} constant-velocity stretches match no scheduled window "
                "(rapids, warm-up, other moves): dropped"
            )
        ids = [c.scheduled.id for c in kept if c.scheduled is not None]
        if len(set(ids)) < len(ids):
            self.warnings.append("some scheduled windows were found more than once: pooled")
        return kept

    @property
    def planned_count(self) -> int:
        return len(self.summary.windows) if self.summary is not None else 0

    def cut_runs(self, candidates: Sequence[_Candidate]) -> list[_Candidate]:
        """Marker brackets whole runs: cut the scheduled window out of each run."""
        cut_by_position: list[_Candidate | None] = []
        if self.positions_known:
            for candidate in candidates:
                window = candidate.scheduled
                assert window is not None
                lo = min(window.window_start_mm, window.window_end_mm)
                hi = max(window.window_start_mm, window.window_end_mm)
                x = self.x[candidate.start : candidate.stop]
                inside = np.flatnonzero((x >= lo) & (x <= hi))
                if len(inside) < self.min_n:
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
                    self.warnings.append(
                        f"{len(candidates) - len(good)} runs never crossed their scheduled "
                        "window positions: dropped"
                    )
                return good
            self.warnings.append(
                "the recorded positions do not cross the scheduled windows (another "
                "coordinate system?): windows cut by the schedule's times from the marker edge"
            )
        result = []
        for candidate in candidates:
            window = candidate.scheduled
            assert window is not None
            begin = candidate.start + round((window.t_window_start_s - window.t_start_s) / self.dt)
            end = candidate.start + round((window.t_window_end_s - window.t_start_s) / self.dt)
            end = min(end, candidate.stop)
            if end - begin >= self.min_n:
                result.append(replace(candidate, start=begin, stop=end))
        return result

    # -- rapids and outliers without a schedule ----------------------------------------

    def drop_too_fast(self, candidates: list[_Candidate]) -> list[_Candidate]:
        top = self.settings.max_velocity_mm_min
        if top is None and self.summary is not None and self.summary.velocities_mm_min:
            top = max(self.summary.velocities_mm_min)
        if top is None and self.rapid_mm_min is not None:
            # At the machine's rapid traverse velocity a move is a rapid, not a measurement.
            rapid = self.rapid_mm_min
            kept = [c for c in candidates if abs(c.level_mm_min) < rapid - float(self.band(rapid))]
            if len(kept) < len(candidates):
                self.warnings.append(
                    f"{len(candidates) - len(kept)} windows at the rapid traverse velocity "
                    f"({rapid:g} mm/min, machine file): dropped"
                )
            return kept
        if top is None:
            return candidates
        limit = top + float(self.band(top))
        kept = [c for c in candidates if abs(c.level_mm_min) <= limit]
        if len(kept) < len(candidates):
            self.warnings.append(
                f"{len(candidates) - len(kept)} windows faster than {top:g} mm/min "
                "(rapid traverse): dropped"
            )
        return kept

    def levels(self, candidates: Sequence[_Candidate]) -> IntArray:
        speeds = np.abs(np.array([c.level_mm_min for c in candidates]))
        gaps = np.maximum(self.settings.step_tolerance * speeds, self.settings.step_floor_mm_min)
        return cluster_gaps(speeds, gaps)

    def drop_rapids(self, candidates: list[_Candidate]) -> list[_Candidate]:
        """Without a schedule: drop the rapid-traverse level and over-long windows."""
        settings = self.settings
        if len(candidates) < 3:
            return candidates
        labels = self.levels(candidates)
        count = int(labels.max()) + 1
        per_level = np.bincount(labels, minlength=count)
        if count >= 3:
            fastest = count - 1
            typical = float(np.median(per_level[:-1]))
            if per_level[fastest] > settings.rapid_count_factor * max(typical, 1.0):
                speed = float(
                    np.median(
                        [
                            abs(c.level_mm_min)
                            for c, k in zip(candidates, labels, strict=True)
                            if k == fastest
                        ]
                    )
                )
                self.warnings.append(
                    f"the fastest level, {speed:g} mm/min, holds {per_level[fastest]} windows "
                    f"where the others hold about {typical:g}: taken as rapid traverse, dropped"
                )
                candidates = [c for c, k in zip(candidates, labels, strict=True) if k != fastest]
                labels = self.levels(candidates)
                count = int(labels.max()) + 1
        speeds = np.abs(np.array([c.level_mm_min for c in candidates]))
        durations = np.array([(c.stop - c.start) * self.dt for c in candidates])
        log_d = np.log(durations)
        level_v = np.array([np.median(np.log(speeds[labels == k])) for k in range(count)])
        level_d = np.array([np.median(log_d[labels == k]) for k in range(count)])
        if count >= 3:
            slope, intercept, _, _ = theilslopes(level_d, level_v)
            expected = intercept + slope * np.log(speeds)
        else:
            expected = level_d[labels]
        long = log_d - expected > math.log(settings.duration_outlier_factor)
        if long.any():
            self.warnings.append(
                f"{int(long.sum())} windows last over {settings.duration_outlier_factor:g} times "
                "longer than the others at their velocity (warm-up strokes, traverses): dropped"
            )
            candidates = [c for c, bad in zip(candidates, long, strict=True) if not bad]
        return candidates

    # -- labelling ---------------------------------------------------------------------

    def window(
        self, candidate: _Candidate, source: WindowSource, **labels: int | float
    ) -> VelocityWindow:
        direction: Literal[1, -1] = 1 if candidate.level_mm_min > 0 else -1
        x = self.x[candidate.start : candidate.stop]
        position = float(np.nanmean(x)) if np.isfinite(x).any() else float("nan")
        return VelocityWindow(
            axis=self.axis,
            start=candidate.start,
            stop=candidate.stop,
            velocity_mm_min=float(labels.get("velocity_mm_min", candidate.level_mm_min)),
            level_mm_min=candidate.level_mm_min,
            direction=direction,
            position_mm=position,
            position_index=int(labels.get("position_index", -1)),
            step=int(labels.get("step", -1)),
            source=source,
            window_id=int(labels["window_id"]) if "window_id" in labels else None,
            repetition=int(labels["repetition"]) if "repetition" in labels else None,
        )

    def label_by_schedule(
        self, candidates: Sequence[_Candidate], source: WindowSource
    ) -> tuple[list[VelocityWindow], list[Cluster], list[Cluster]]:
        assert self.summary is not None
        summary = self.summary
        windows = []
        off_schedule: list[int] = []
        for candidate in candidates:
            planned = candidate.scheduled
            assert planned is not None
            windows.append(
                self.window(
                    candidate,
                    source,
                    velocity_mm_min=planned.velocity_mm_min,
                    position_index=planned.position_index,
                    step=planned.step,
                    window_id=planned.id,
                    repetition=planned.repetition,
                )
            )
            tolerance = float(self.band(planned.velocity_mm_min))
            if abs(candidate.level_mm_min - planned.velocity_mm_min) > tolerance:
                off_schedule.append(planned.id)
        if off_schedule:
            shown = ", ".join(str(i) for i in off_schedule[:5])
            more = ", ..." if len(off_schedule) > 5 else ""
            self.warnings.append(
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

    def label_by_clusters(
        self, candidates: Sequence[_Candidate], source: WindowSource
    ) -> tuple[list[VelocityWindow], list[Cluster], list[Cluster]]:
        settings = self.settings
        speeds = np.abs(np.array([c.level_mm_min for c in candidates]))
        step_of = self.levels(candidates)
        steps = _clusters(speeds, step_of)
        centres = np.array([float(np.nanmean(self.x[c.start : c.stop])) for c in candidates])
        # Anchor the positions on the slower half of the steps: planners shift the
        # windows of fast steps inward where the run-up would not fit.
        slow = step_of <= (len(steps) - 1) // 2
        anchor = centres[slow & np.isfinite(centres)]
        if len(anchor) == 0:
            anchor = centres[np.isfinite(centres)]
        span = float(anchor.max() - anchor.min()) if len(anchor) else 0.0
        gap = max(settings.position_gap_mm, settings.position_gap_fraction * span)
        anchor_of = cluster_gaps(anchor, gap)
        anchors = _clusters(anchor, anchor_of)
        anchor_x = np.array([a.centre for a in anchors])
        position_of = np.argmin(np.abs(centres[:, None] - anchor_x[None, :]), axis=1)
        position_of[~np.isfinite(centres)] = 0
        # Renumber: a position that no window ended up nearest to is left out.
        used = np.unique(position_of)
        position_of = np.searchsorted(used, position_of)
        positions = [
            Cluster(
                index,
                anchors[int(anchor)].centre,
                float(centres[position_of == index].min()),
                float(centres[position_of == index].max()),
                int((position_of == index).sum()),
            )
            for index, anchor in enumerate(used)
        ]
        windows = []
        for candidate, step, position in zip(candidates, step_of, position_of, strict=True):
            sign = 1.0 if candidate.level_mm_min > 0 else -1.0
            windows.append(
                self.window(
                    candidate,
                    source,
                    velocity_mm_min=sign * steps[int(step)].centre,
                    position_index=int(position),
                    step=int(step),
                )
            )
        return windows, steps, positions

    # -- the whole job -----------------------------------------------------------------

    def attempt(self, method: Method) -> tuple[WindowSource, list[_Candidate], bool] | None:
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
        if method == "marker" and self.summary is not None:
            whole_runs = self.scope == "run"
            by_id = self.marker_values == "window_id"
            candidates = self.match_schedule(candidates, by_id=by_id, whole_runs=whole_runs)
            labelled = True
            if whole_runs:
                candidates = self.cut_runs(candidates)
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

    def measure(self, candidates: Sequence[_Candidate], *, commanded: bool) -> list[_Candidate]:
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
        another unit (:func:`_unit_factor`): nothing is dropped, the readings
        keep the say, and a warning names the factor. Displacements near zero
        or scattered share no factor: those windows are dropped, however many.
        """
        if not self.positions_known or not candidates:
            return list(candidates)
        failed: list[float] = []  # slope / reference of each window that disagrees
        still = 0
        kept: list[_Candidate] = []
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
                reference = float(np.nanmedian(readings))
            allowed = max(float(self.band(reference)), self.v_quantum, resolution)
            if abs(slope - reference) > allowed:
                failed.append(slope / reference if reference else math.nan)
                continue
            if not commanded:
                if abs(slope) < max(self.settings.standstill_mm_min, resolution):
                    still += 1
                    continue
                # The transient is cut again against the measured velocity.
                cut = self.trim(candidate.start, candidate.stop, slope)
                if cut is None:
                    continue
                candidate = replace(candidate, start=cut[0], stop=cut[1], level_mm_min=slope)
            kept.append(candidate)
        factor = _unit_factor(failed)
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

    def still(self) -> str | None:
        """Why the axis did not move at all, or None when it moved.

        Where a position was recorded it decides: the axis did not move when
        its position creeps by less than the standstill speed over the whole
        recording, whatever the velocity reads (a reading frozen at −3 mm/min
        moves nothing). Without a position, when its velocity never stays above
        the standstill threshold (at least one velocity count) for a window's
        length.
        """
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
        starts, stops = _runs(smooth >= threshold)
        if len(starts) and int((stops - starts).max()) >= self.min_n:
            return None
        return (
            f"the axis did not move: its velocity never stays above {threshold:.3g} mm/min"
            f"{count} over {duration_s:.3g} s (no position recorded)"
        )

    def run(self) -> Segmentation:
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
            if way == "command":
                why = "no marker windows" if self.marker is not None else "no marker"
                first = f"{why}: windows from the commanded velocity"
            elif self.marker is None and self.command is None:
                first = (
                    "no marker and no commanded velocity: windows from constant-velocity "
                    "plateaus of the actual velocity"
                )
            else:
                first = (
                    "neither marker nor commanded velocity gave windows: windows from "
                    "constant-velocity plateaus of the actual velocity"
                )
            reasons = [t for t in self.tried if not t.endswith("not recorded")]
            self.warnings[:0] = [first, *reasons]
        candidates = self.drop_too_fast(candidates)
        if self.summary is not None and not labelled:
            candidates = self.match_schedule(candidates, by_id=False, whole_runs=False)
            labelled = True
        if not labelled and source in ("command", "plateau"):
            candidates = self.drop_rapids(candidates)
        if not candidates:
            raise RecordingError(
                f"axis {self.axis}: every {source} window was dropped",
                [*self.tried, *self.warnings],
            )
        if labelled:
            windows, steps, positions = self.label_by_schedule(candidates, source)
        else:
            windows, steps, positions = self.label_by_clusters(candidates, source)
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
    """Find and label the constant-velocity windows of one axis.

    Args:
        axis: The axis name (to find its part of the schedule).
        time_s: Sample times (n,).
        velocity_mm_min: Actual velocity (n,).
        position_mm: Actual position (n,); integrated velocity when missing.
        command_mm_min: Commanded velocity (n,), where recorded.
        marker: The program's marker (n,), where recorded.
        schedule: The schedule.json of the program, to label the windows.
        settings: How windows are found.
        rapid_mm_min: The axis' rapid traverse velocity (machine file): without
            a schedule or ``max_velocity_mm_min``, windows at it are rapids.

    Returns:
        The windows with their labels, the steps and positions, and warnings.

    Raises:
        RecordingError: No window was found (the message says what was tried).
    """
    finder = _Finder(
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


def _optional(recording: Recording, axis: str, signal: str) -> FloatArray | None:
    name = f"{axis}_{signal}"
    return recording.column(name) if name in recording.channel_names else None


def windows_of(
    recording: Recording,
    axis: str,
    *,
    schedule: Schedule | None = None,
    settings: SegmentSettings | None = None,
) -> Segmentation:
    """:func:`find_windows` on the channels of one axis of a recording.

    Raises:
        RecordingError: The axis has no velocity channel, or no window was found.
    """
    velocity = _optional(recording, axis, "velocity_mm_min")
    if velocity is None:
        raise RecordingError(
            f"{recording.directory}: axis {axis} has no velocity channel ({axis}_velocity_mm_min)"
        )
    return find_windows(
        axis,
        recording.time_s,
        velocity,
        position_mm=_optional(recording, axis, "position_mm"),
        command_mm_min=_optional(recording, axis, "velocity_cmd_mm_min"),
        marker=_optional(recording, axis, "marker"),
        schedule=schedule,
        settings=settings,
    )
