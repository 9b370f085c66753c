"""The window finder on a recording read chunk by chunk: stretches found in passes, kept as slices.

The second pass of the analysis, whose memory is bounded by the windows, not by
the recording. :mod:`~ncmeasure.analysis.windows.scan` gave every whole-signal
statistic; :class:`ChunkedFinder` then finds the stretches that
:class:`~ncmeasure.analysis.windows.finder.WindowFinder` trims, checks and labels:

* a pass over the rows finds the runs of the marker and the stretches of
  constant commanded velocity, carrying state across chunk edges; only where
  they give no window, one more finds the plateaus of the smoothed actual
  velocity (the rolling median and the flatness filters see
  ``plateau_min_s`` plus the filter width beyond each chunk); the velocity
  derived from the position looks ±h rows beyond each chunk;
* where the velocity signal is coarse, a pass before it takes the median
  ratio of derived to read velocity (:mod:`~ncmeasure.analysis.windows.streaming`);
* a way that found stretches reads, in one more pass, the samples of its
  stretches only (time, velocity, position, derived velocity, command,
  marker, current), with margins of ``settle_s`` plus the filter width;
  trimming, the position check, the schedule, cutting whole runs and
  labelling read only these slices (:class:`~ncmeasure.analysis.windows.sweep.Sparse`).

Every row is cleaned and bridged as the whole signal would be (implausible
values left out, gaps bridged from the neighbours
:mod:`~ncmeasure.analysis.windows.scan` noted,
:func:`~ncmeasure.analysis.windows.sweep.cleaned_rows`), so the windows do not
depend on the chunks, bit for bit: a recording in memory, read as one chunk,
gives the windows of its file read in chunks of any size. The tests check both
against a finder on the whole arrays (``tests/analysis/oracle.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Sequence

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.detection import min_window_rows
from ncmeasure.analysis.windows.finder import WindowFinder
from ncmeasure.analysis.windows.model import Candidate
from ncmeasure.analysis.windows.rolling import rolling_median
from ncmeasure.analysis.windows.scan import AxisStatistics, Rows
from ncmeasure.analysis.windows.settings import MIN_WINDOW_SAMPLES, SegmentSettings
from ncmeasure.analysis.windows.signals import command_repeats, plateau_mask, runs
from ncmeasure.analysis.windows.streaming import median_task, run_task
from ncmeasure.analysis.windows.sweep import (
    Ahead,
    Block,
    Found,
    Keeper,
    Sparse,
    SweepState,
    as_array,
    cleaned_rows,
    merged,
    moving_runs,
)
from ncmeasure.errors import RecordingError
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import RowChunk

__all__ = ["ChunkedFinder", "Swept", "early_sweep_task"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
Feed = Callable[[RowChunk], None]


class ChunkedFinder(WindowFinder):
    """Finds the windows of one axis of a recording read chunk by chunk.

    Made from the axis' first-pass statistics; :meth:`agreement_task` (only
    where :attr:`needs_agreement`) and :meth:`sweep_task` are tasks of
    :func:`~ncmeasure.analysis.windows.streaming.run_tasks` over the chunks of
    ``source`` (several axes share each reading); :meth:`run` then reads the
    slices of the stretches it tries and labels the windows.
    """

    def __init__(
        self,
        axis: str,
        statistics: AxisStatistics,
        source: Rows,
        schedule: Schedule | None,
        settings: SegmentSettings,
        rapid_mm_min: float | None = None,
    ) -> None:
        self.axis = axis
        self.rapid_mm_min = rapid_mm_min
        self.settings = settings
        self.statistics = statistics
        self.source = source
        self.read = source.read
        present = set(source.column)
        self.has = {
            s: f"{axis}_{s}" in present
            for s in ("position_mm", "velocity_cmd_mm_min", "marker", "current_a")
        }
        self.n = statistics.rows
        self.dt = statistics.sample_period_s if self.n > 1 else 1.0
        if not self.dt > 0:
            raise RecordingError(f"axis {axis}: the sample times do not increase")
        empty = as_array(Sparse(self.n, [], []))
        self.marker = empty if self.has["marker"] else None
        self.warnings: list[str] = []
        self.tried: list[str] = []
        if self.has["position_mm"] and not statistics.position_usable:
            self.warnings.append(
                "the position channel holds a value in fewer than half of the rows: not used"
            )
        if statistics.velocity_bridged:
            self.warnings.append(
                f"{statistics.velocity_bridged} velocity samples without a value (NaN) bridged "
                "by their neighbours to find the windows"
            )
        self.command = empty if self.has["velocity_cmd_mm_min"] else None
        self.positions_known = statistics.position_usable
        if not self.positions_known:
            self.warnings.append(
                "no position channel: positions integrated from the velocity (relative)"
            )
        self.setup_schedule(schedule)
        self.t = self.v = self.x = self.v_detect = self.current = empty
        low = statistics.low.get("velocity_mm_min", math.nan)
        high = statistics.high.get("velocity_mm_min", math.nan)
        self.scale_floors(
            max(abs(low), abs(high)),
            max(statistics.velocity_sigma_mm_min, statistics.velocity_quantum_mm_min),
        )
        self.setup_counts()
        self.setup_resolution(
            statistics.velocity_quantum_mm_min,
            statistics.position_quantum_mm,
            statistics.velocity_sigma_mm_min,
        )
        self.h = self.position_h(statistics.position_sigma_mm) if self.from_position else 0
        self.needs_agreement = self.from_position
        if not self.needs_agreement:
            self.setup_detection(None)
        self.found = Found()
        self.holes = []
        # Slices gathered on a reading shared with other axes: their stretches, the finish.
        self.ahead: tuple[list[tuple[int, int]], Callable[[], None]] | None = None

    # -- the rows, cleaned and bridged -------------------------------------------------

    def _rows(
        self, derived: bool, holes: list[int] | None = None
    ) -> Callable[[RowChunk], list[Block]]:
        """For one pass: a chunk's rows -> the blocks of rows complete (:func:`cleaned_rows`)."""
        return cleaned_rows(
            self.axis,
            self.statistics,
            self.source,
            self.has,
            positions_known=self.positions_known,
            dt=self.dt,
            h=self.h if derived and self.from_position else 0,
            derived=derived,
            holes=holes,
        )

    def agreement_task(self) -> Generator[Feed, None, None]:
        """Pass: the median ratio of the position's velocity to the readings; then detection.

        As on the whole arrays: over the rows where the readings exceed five
        times their resolution, None under :data:`MIN_WINDOW_SAMPLES` of them.
        """
        above = 5 * self.resolution
        count = [0]

        def view() -> Callable[[RowChunk], FloatArray]:
            rows = self._rows(derived=True)
            count[0] = 0

            def ratios(chunk: RowChunk) -> FloatArray:
                found = []
                for _, _, part in rows(chunk):
                    derived, readings = part["vd"], part["v"]
                    fast = np.isfinite(derived) & np.isfinite(readings) & (np.abs(readings) > above)
                    found.append(derived[fast] / readings[fast])
                values = np.concatenate(found) if found else np.empty(0, dtype=np.float64)
                count[0] += len(values)
                return values

            return ratios

        ratio = yield from median_task(view)
        self.setup_detection(ratio if count[0] >= MIN_WINDOW_SAMPLES else None)
        self.needs_agreement = False

    # -- the pass over the rows --------------------------------------------------------

    def sweep_task(self) -> Generator[Feed, None, None]:
        """Pass: marker runs, command stretches and the holes of the time axis."""
        assert not self.needs_agreement
        sweep = _Sweep(self.n, self.min_n, self.settings.standstill_mm_min)
        self.found = sweep.found
        self.holes = []
        rows = self._rows(derived=True, holes=self.holes)

        def feed(chunk: RowChunk) -> None:
            for lo, hi, part in rows(chunk):
                sweep.add(lo, hi, part)

        yield feed

    def take_sweep(self, swept: Swept) -> None:
        """What an :func:`early_sweep_task` found, in place of :meth:`sweep_task`'s pass.

        Its command stretches are those of any level; the ones below this finder's
        standstill (known once every statistic is: the floors may be scaled) are left
        out here, in order, as :meth:`sweep_task` leaves them out.
        """
        found, holes, dt = swept
        assert dt == self.dt
        standstill = self.settings.standstill_mm_min
        found.command = [c for c in found.command if abs(c[2]) >= standstill]
        self.found = found
        self.holes = holes

    def _plateau_task(self) -> Generator[Feed, None, None]:
        """Pass: plateaus, and without a position the longest stretch above standstill.

        Only where the marker and the command gave no window, as on the whole
        arrays (the rolling median over every row is the costly part).
        """
        rows = self._rows(derived=True)
        reach = self.plateau_n + self.filter_n + 2
        state = SweepState(
            plateaus=Ahead(reach, reach, self.n),
            want_plateaus=self.n >= self.plateau_n,
            want_still=not self.positions_known,
        )

        def feed(chunk: RowChunk) -> None:
            for _, _, part in rows(chunk):
                self._plateaus(state, part["vd"])

        yield feed
        self.found.plateaus = [
            (a, b)
            for a, b in zip(state.plateau_runs.starts, state.plateau_runs.stops, strict=True)
            if b - a >= self.plateau_n
        ]
        self.found.moving = moving_runs(state.forward, state.backward, self.plateau_n)
        self.found.longest_moving = state.moving_best
        self.found.plateaus_swept = True

    def _sweep_plateaus(self) -> None:
        if not self.found.plateaus_swept:
            run_task(self.read, self._plateau_task())

    def _plateaus(self, state: SweepState, detect_part: FloatArray) -> None:
        """Plateau runs and the longest stretch above standstill, with the filters' reach."""
        ahead = state.plateaus
        span = ahead.push({"vd": detect_part})
        if span is None:
            return
        lo, hi = span
        offset = ahead.offset
        detect = ahead.columns["vd"]
        finite = np.where(np.isfinite(detect), detect, 0.0)
        if state.want_plateaus:
            smooth = rolling_median(finite, self.filter_n)
            mask = plateau_mask(smooth, self.band, self.standstill, self.plateau_n, self.n, offset)
            state.plateau_runs.add(mask[lo - offset : hi - offset], lo, hi == self.n)
            part = smooth[lo - offset : hi - offset]
            state.forward.add(part >= self.standstill, lo, hi == self.n)
            state.backward.add(part <= -self.standstill, lo, hi == self.n)
        if state.want_still:
            moving = np.abs(finite)
            if self.filter_n > 1:
                moving = rolling_median(moving, self.filter_n)
            above = moving[lo - offset : hi - offset] >= self.standstill
            starts, stops = runs(above)
            if len(starts):
                lengths = (stops - starts).tolist()
                if starts[0] == 0:
                    lengths[0] += state.moving_open
                state.moving_best = max(state.moving_best, *lengths)
                state.moving_open = lengths[-1] if stops[-1] == len(above) else 0
            else:
                state.moving_open = 0
        ahead.forget()

    # -- slices ------------------------------------------------------------------------

    def _gather(self, stretches: Sequence[tuple[int, int]]) -> None:
        """Read the samples of ``stretches`` and keep them as slices.

        Trimming reads the velocity the windows are found by ``settle_s`` plus
        the filter width before a stretch and the filter width after it; every
        other signal is read inside the stretches only (matching, cutting runs,
        the position check and labelling look at a window's own samples, which
        lie inside its stretch). Slices gathered beforehand on a shared reading
        (:meth:`gathering`) of the same stretches are taken as they are.
        """
        ahead, self.ahead = self.ahead, None
        if ahead is not None and ahead[0] == list(stretches):
            ahead[1]()
            return
        feed, finish = self.gathering(stretches)
        for chunk in self.read():
            feed(chunk)
        finish()

    def gathering(self, stretches: Sequence[tuple[int, int]]) -> tuple[Feed, Callable[[], None]]:
        """The gathering of :meth:`_gather` as a feed of a reading's chunks and its finish."""
        margin_before = self.settle_n + self.filter_n
        margin_after = self.filter_n
        outer = merged(
            (max(0, a - margin_before), min(self.n, b + margin_after)) for a, b in stretches
        )
        inner = merged(stretches)
        # The marker's values were noted by the sweep; the slices need not hold it.
        same_detect = not self.from_position  # vd is v: one copy serves both
        wide = ("vd",) if not same_detect else ("v",)
        narrow = tuple(k for k in ("t", "v", "x", "cmd", "i") if k not in wide)
        kept = {k: Keeper(outer) for k in wide} | {k: Keeper(inner) for k in narrow}
        rows = self._rows(derived=True)

        def feed(chunk: RowChunk) -> None:
            for lo, hi, part in rows(chunk):
                for key, keeper in kept.items():
                    if key in part:
                        keeper.add(lo, hi, part[key])

        def finish() -> None:
            def sparse(key: str) -> FloatArray:
                return as_array(kept[key].sparse(self.n))

            self.t, self.v, self.x = sparse("t"), sparse("v"), sparse("x")
            self.v_detect = self.v if same_detect else sparse("vd")
            if self.command is not None:
                self.command = sparse("cmd")
            self.current = (
                sparse("i") if self.has["current_a"] else as_array(Sparse(self.n, [], []))
            )

        return feed, finish

    def first_stretches(self) -> list[tuple[int, int]] | None:
        """The stretches the first way of finding windows will read, as the sweep found them.

        The marker's runs where a marker is wanted and was set, else the stretches of
        constant command (where the method allows it); None where no way reads any.
        """
        method = self.settings.window_method
        found = self.found
        wanted = self.summary is None or self.scope != "none"
        marker_set = self.marker is not None and bool(found.marker_starts) and wanted
        if marker_set and method in ("auto", "marker"):
            return list(zip(found.marker_starts, found.marker_stops, strict=True))
        commanded = self.command is not None and self.n >= 2 and bool(found.command)
        if commanded and method in ("auto", "command"):
            return [(a, b) for a, b, _ in found.command]
        return None

    def gather_ahead(self, stretches: list[tuple[int, int]]) -> Feed:
        """Gather the slices of ``stretches`` on a reading shared with other axes.

        Returns the feed of that reading's chunks; :meth:`_gather` of the same
        stretches then takes the slices without a reading of its own.
        """
        feed, finish = self.gathering(stretches)
        self.ahead = (stretches, finish)
        return feed

    def slice_bytes(self, stretches: Sequence[tuple[int, int]]) -> int:
        """About the memory the slices of ``stretches`` take (float64, the signals
        :meth:`gathering` keeps: the velocity the windows are found by with its
        margins, time, position, and the velocity, command and current where kept)."""
        margin = self.settle_n + 2 * self.filter_n
        inner = sum(b - a for a, b in merged(stretches))
        narrow = 2 + int(self.from_position) + int(self.command is not None)
        narrow += int(self.has["current_a"])
        return 8 * ((1 + narrow) * inner + margin * len(stretches))

    # -- the ways of finding windows, on slices ----------------------------------------

    def marker_candidates(self) -> list[Candidate]:
        if not self.marker_wanted():
            return []
        found = self.found
        if found.marker_starts:
            self._gather(list(zip(found.marker_starts, found.marker_stops, strict=True)))
        return self.marker_levels(found.marker_starts, found.marker_stops, found.marker_values)

    def command_candidates(self) -> list[Candidate]:
        if self.command is None:
            self.tried.append("commanded velocity: not recorded")
            return []
        if self.n < 2:
            return []
        stretches = self.found.command
        if stretches:
            self._gather([(a, b) for a, b, _ in stretches])
        return self.command_found(
            [a for a, _, _ in stretches], [b for _, b, _ in stretches], [c for *_, c in stretches]
        )

    def plateau_candidates(self) -> list[Candidate]:
        if self.plateau_too_short():
            return []
        self._sweep_plateaus()
        runs = self.split_at_holes(self.found.plateaus, self.plateau_n)
        moving = self.split_at_holes(self.found.moving, self.plateau_n)
        levels = []
        if runs or moving:
            # Joining neighbouring plateaus reads the readings between them too, and a
            # steady run all of its readings.
            self._gather([*self.bridged(runs), *moving])
            for start, stop in runs:
                low = max(0, start - self.settle_n - self.filter_n)
                high = min(self.n, stop + self.filter_n)
                detect = self.v_detect[low:high]
                finite = np.where(np.isfinite(detect), detect, 0.0)
                smooth = rolling_median(finite, self.filter_n)
                levels.append((start, stop, float(np.median(smooth[start - low : stop - low]))))
        return self.plateau_found(levels, moving)

    def still(self) -> str | None:
        """:meth:`WindowFinder.still` from the first pass's ranges and the sweep's longest run."""
        if self.n < 2:
            return "the recording holds fewer than 2 samples"
        stats = self.statistics
        duration_s = float(stats.end_s - stats.start_s)
        threshold = self.standstill
        count = (
            f" (one count of the velocity signal is {self.v_quantum:.3g} mm/min)"
            if self.v_quantum and self.v_quantum * (1 + 1e-6) >= threshold
            else ""
        )
        if self.positions_known:
            low, high = stats.low.get("position_mm", 0.0), stats.high.get("position_mm", 0.0)
            span_mm = float(high - low) if math.isfinite(low) and math.isfinite(high) else 0.0
            if duration_s > 0 and span_mm / duration_s * 60.0 > self.settings.standstill_mm_min:
                return None
            return (
                f"the axis did not move: its position stays within {span_mm * 1000:.3g} µm "
                f"over {duration_s:.3g} s (whatever its velocity signal reads)"
            )
        self._sweep_plateaus()
        if self.found.longest_moving >= self.min_n:
            return None
        return (
            f"the axis did not move: its velocity never stays above {threshold:.3g} mm/min"
            f"{count} over {duration_s:.3g} s (no position recorded)"
        )

    def window_times(self, start: int, stop: int) -> tuple[float, float]:
        """Time of a window's first and last sample (from the slices)."""
        times = self.t[start:stop]
        return float(times[0]), float(times[-1])

    def release(self) -> None:
        """Forget the slices (the windows' current and times were taken)."""
        empty = as_array(Sparse(self.n, [], []))
        self.t = self.v = self.x = self.v_detect = self.current = empty
        if self.command is not None:
            self.command = empty
        self.ahead = None

    def window_current(self, start: int, stop: int) -> FloatArray:
        """The current of a window's samples: a copy, the slices may be released."""
        return self.current[start:stop].copy()


Swept = tuple[Found, list[int], float]
"""What a sweep found: the marker runs and command stretches, the rows after a hole of
the time axis, and the sample period it took."""


class _Sweep:
    """The sweep's marker runs and command stretches of one axis, block by block of rows.

    ``standstill``: the least level of a command stretch kept (None: every level).
    """

    def __init__(self, n: int, min_n: int, standstill: float | None) -> None:
        self.n = n
        self.min_n = min_n
        self.standstill = standstill
        self.found = Found()
        self.state = SweepState(plateaus=Ahead(0, 0, n), want_plateaus=False, want_still=False)

    def add(self, lo: int, hi: int, part: dict[str, FloatArray]) -> None:
        """The rows lo..hi of a block (its columns, :func:`cleaned_rows`)."""
        if "marker" in part:
            self.marker_runs(part["marker"], lo, hi)
        if "cmd" in part:
            self.command_stretches(part["cmd"], lo, hi)

    def marker_runs(self, marker: FloatArray, lo: int, hi: int) -> None:
        """Runs of a set marker that break where its value changes as well."""
        found, state = self.found, self.state
        on = np.isfinite(marker) & (marker > 0)
        ext_on = np.concatenate(([state.marker_on], on))
        ext_value = np.concatenate(([state.marker_value], marker))
        changed = ext_value[1:] != ext_value[:-1]
        starts = np.flatnonzero(ext_on[1:] & (changed | ~ext_on[:-1]))
        stops = np.flatnonzero(ext_on[:-1] & (changed | ~ext_on[1:]))
        found.marker_starts.extend((starts + lo).tolist())
        found.marker_values.extend(marker[starts].tolist())
        found.marker_stops.extend((stops + lo).tolist())
        if hi == self.n and on[-1]:
            found.marker_stops.append(self.n)
        state.marker_on = bool(on[-1])
        state.marker_value = float(marker[-1])

    def command_stretches(self, command: FloatArray, lo: int, hi: int) -> None:
        """Stretches of constant commanded velocity (a change of the command begins one)."""
        state = self.state
        if state.command_last is None:
            repeats = np.concatenate(([False], command_repeats(command)))
        else:
            repeats = command_repeats(np.concatenate(([state.command_last], command)))
        begins = np.flatnonzero(~repeats)
        if len(begins):
            # The stretch left open by the block before ends where this block's first begins.
            if state.command_begin is not None:
                self.close_commands(
                    np.array([state.command_begin]),
                    begins[:1] + lo,
                    np.array([state.command_level]),
                )
            # Every stretch that begins here and ends at the next begin here.
            self.close_commands(begins[:-1] + lo, begins[1:] + lo, command[begins[:-1]])
            state.command_begin = int(begins[-1]) + lo
            state.command_level = float(command[begins[-1]])
        state.command_last = float(command[-1])
        if hi == self.n and state.command_begin is not None and self.n >= 2:
            self.close_commands(
                np.array([state.command_begin]), np.array([self.n]), np.array([state.command_level])
            )

    def close_commands(self, begin: IntArray, end: IntArray, level: FloatArray) -> None:
        """Keep the stretches above standstill (any level: None) that last ``min_window_s``."""
        keep = end - begin >= self.min_n
        if self.standstill is not None:
            keep &= np.abs(level) >= self.standstill
        self.found.command.extend(
            zip(begin[keep].tolist(), end[keep].tolist(), level[keep].tolist(), strict=True)
        )


def _nothing(chunk: RowChunk) -> None:
    """A pass's feed that looks at nothing."""


def early_sweep_task(
    axis: str,
    statistics: AxisStatistics,
    source: Rows,
    settings: SegmentSettings,
    period: Callable[[], float | None],
) -> Generator[Feed, None, Swept | None]:
    """:meth:`ChunkedFinder.sweep_task` on the readings of the statistics (a rider of
    :func:`~ncmeasure.analysis.windows.scan.axes_statistics_along`).

    The sweep needs of the statistics only the first pass's (the neighbours that bridge
    the gaps, the rows) and the sample period (the holes of the time axis, the shortest
    window): it waits for the period, then sweeps on the next reading. It keeps the
    command stretches of every level (the standstill a finder leaves out below is known
    only at the end: :meth:`ChunkedFinder.take_sweep`). None where the period is none
    a finder takes (it says why).
    """
    while (median := period()) is None:
        yield _nothing
    n = statistics.rows
    dt = median if n > 1 else 1.0
    if not dt > 0:
        return None
    present = set(source.column)
    has = {
        s: f"{axis}_{s}" in present
        for s in ("position_mm", "velocity_cmd_mm_min", "marker", "current_a")
    }
    sweep = _Sweep(n, min_window_rows(settings, dt), None)
    holes: list[int] = []
    rows = cleaned_rows(
        axis,
        statistics,
        source,
        has,
        positions_known=statistics.position_usable,
        dt=dt,
        h=0,
        derived=False,
        holes=holes,
    )

    def feed(chunk: RowChunk) -> None:
        for lo, hi, part in rows(chunk):
            sweep.add(lo, hi, part)

    yield feed
    return sweep.found, holes, dt
