"""Windows of a recording too long to hold: found chunk by chunk, kept as slices.

The second pass of a bounded-memory analysis. :mod:`~ncmeasure.analysis.windows.scan`
gave every whole-signal statistic; :class:`SlicedFinder` finds the same
windows as :func:`~ncmeasure.analysis.windows.finder.find_windows` on the whole
arrays, with memory bounded by the windows, not by the recording:

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
  labelling read only these slices (:class:`Sparse`).

Every row is cleaned and bridged as on the whole arrays (implausible values
left out, gaps bridged from the neighbours :mod:`~ncmeasure.analysis.windows.scan`
noted), so the windows are the same, bit for bit.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import median_filter

from ncmeasure.analysis.windows.finder import (
    MIN_WINDOW_SAMPLES,
    SegmentSettings,
    _Candidate,
    _Finder,
    _runs,
    command_repeats,
    plateau_mask,
    position_velocity,
)
from ncmeasure.analysis.windows.scan import AxisStatistics, bridge_chunk
from ncmeasure.analysis.windows.streaming import median_task, run_task
from ncmeasure.errors import RecordingError
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import RowChunk
from ncmeasure.validity import implausible

__all__ = ["SlicedFinder", "Sparse"]

FloatArray = NDArray[np.float64]
Columns = dict[str, FloatArray]
Block = tuple[int, int, Columns]
"""Rows ``lo`` .. ``hi`` of a recording: their columns, in rows lo..hi."""
Feed = Callable[[RowChunk], None]


class Sparse:
    """Stretches of one signal of a recording, read like the whole array by slices.

    ``values[a:b]`` gives the samples a..b when one stretch holds them all; a
    slice reaching outside the stretches is an error of the analysis, never
    a silent gap.
    """

    def __init__(self, rows: int, starts: Sequence[int], parts: Sequence[FloatArray]) -> None:
        self.rows = rows
        self.starts = list(starts)
        self.parts = list(parts)

    def __len__(self) -> int:
        return self.rows

    def __getitem__(self, index: slice) -> FloatArray:
        start = 0 if index.start is None else int(index.start)
        stop = self.rows if index.stop is None else int(index.stop)
        k = bisect.bisect_right(self.starts, start) - 1
        if k < 0 or stop - self.starts[k] > len(self.parts[k]) or index.step is not None:
            raise IndexError(f"rows {start}..{stop} are outside the slices kept")
        offset = self.starts[k]
        return self.parts[k][start - offset : stop - offset]

    @property
    def samples(self) -> int:
        """Samples held."""
        return sum(len(p) for p in self.parts)


def _as_array(values: Sparse) -> FloatArray:
    """A :class:`Sparse` where the finder keeps its arrays.

    The finder reads them by slices of its candidates (with their margins)
    only, which a Sparse answers; what reads a whole signal is overridden in
    :class:`SlicedFinder`.
    """
    return cast("FloatArray", values)


class _Ahead:
    """Columns of consecutive rows, kept ``left`` rows behind and ``right`` ahead.

    :meth:`push` appends a chunk's rows and says which rows are now complete:
    those with ``right`` rows after them, or every row once the last one
    (row ``n − 1``) is in. The buffer keeps ``left`` rows before them.
    """

    def __init__(self, left: int, right: int, n: int) -> None:
        self.left = left
        self.right = right
        self.n = n
        self.offset = 0
        self.done = 0
        self.columns: Columns = {}

    def push(self, columns: Columns) -> tuple[int, int] | None:
        if not self.columns:
            self.columns = dict(columns)
        else:
            self.columns = {k: np.concatenate((self.columns[k], columns[k])) for k in self.columns}
        held = len(next(iter(self.columns.values())))
        available = self.offset + held
        end = available if available >= self.n else available - self.right
        if end <= self.done:
            return None
        begin, self.done = self.done, end
        return begin, end

    def forget(self) -> None:
        """Drop the rows no later row needs."""
        keep = max(self.offset, self.done - self.left)
        cut = keep - self.offset
        if cut > 0:
            self.columns = {k: v[cut:] for k, v in self.columns.items()}
            self.offset = keep


@dataclass
class _Runs:
    """Runs of a mask given block by block, in order."""

    open_start: int | None = None
    starts: list[int] = field(default_factory=list)
    stops: list[int] = field(default_factory=list)

    def add(self, mask: NDArray[np.bool_], lo: int, last: bool) -> None:
        starts, stops = _runs(mask)
        starts = (starts + lo).tolist()
        stops = (stops + lo).tolist()
        hi = lo + len(mask)
        if self.open_start is not None:
            if starts and starts[0] == lo:
                starts[0] = self.open_start
            else:
                starts.insert(0, self.open_start)
                stops.insert(0, lo)
            self.open_start = None
        if stops and stops[-1] == hi and not last:
            self.open_start = starts.pop()
            stops.pop()
        self.starts.extend(starts)
        self.stops.extend(stops)


def _merged(stretches: Iterable[tuple[int, int]]) -> list[tuple[int, int]]:
    """Stretches sorted, overlapping or touching ones joined."""
    merged: list[list[int]] = []
    for a, b in sorted(stretches):
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return [(a, b) for a, b in merged]


class _Keeper:
    """The samples of one signal inside given stretches, from blocks of rows in order."""

    def __init__(self, stretches: Sequence[tuple[int, int]]) -> None:
        self.stretches = stretches
        self.starts = [a for a, _ in stretches]
        self.pieces: list[list[FloatArray]] = [[] for _ in stretches]

    def add(self, lo: int, hi: int, values: FloatArray) -> None:
        k = max(0, bisect.bisect_right(self.starts, lo) - 1)
        while k < len(self.stretches) and self.stretches[k][0] < hi:
            a, b = self.stretches[k]
            if b > lo:
                self.pieces[k].append(values[max(a, lo) - lo : min(b, hi) - lo].copy())
            k += 1

    def sparse(self, rows: int) -> Sparse:
        parts = [
            np.concatenate(p) if len(p) > 1 else (p[0] if p else np.empty(0, dtype=np.float64))
            for p in self.pieces
        ]
        self.pieces = []
        return Sparse(rows, self.starts, parts)


@dataclass
class _Found:
    """What the pass over the rows found for one axis."""

    marker_starts: list[int] = field(default_factory=list)
    marker_stops: list[int] = field(default_factory=list)
    marker_values: list[float] = field(default_factory=list)
    command: list[tuple[int, int, float]] = field(default_factory=list)
    plateaus: list[tuple[int, int]] = field(default_factory=list)
    longest_moving: int = 0
    plateaus_swept: bool = False


@dataclass
class _Sweep:
    """What the pass over the rows carries from one block of rows to the next."""

    plateaus: _Ahead
    want_plateaus: bool
    want_still: bool
    plateau_runs: _Runs = field(default_factory=_Runs)
    marker_on: bool = False
    marker_value: float = math.nan
    command_last: float | None = None
    command_begin: int | None = None
    command_level: float = math.nan
    moving_open: int = 0
    moving_best: int = 0


class SlicedFinder(_Finder):
    """:func:`~ncmeasure.analysis.windows.finder.find_windows` on a recording read chunk by chunk.

    Made from the axis' first-pass statistics; :meth:`agreement_task` (only
    where :attr:`needs_agreement`) and :meth:`sweep_task` are tasks of
    :func:`~ncmeasure.analysis.windows.streaming.run_tasks` over the chunks of
    ``read`` (several axes share each reading); :meth:`run` then reads the
    slices of the stretches it tries and labels the windows.
    """

    def __init__(
        self,
        axis: str,
        statistics: AxisStatistics,
        channels: Iterable[str],
        bounds: Mapping[str, float | None],
        read: Callable[[], Iterator[RowChunk]],
        column: Mapping[str, int],
        schedule: Schedule | None,
        settings: SegmentSettings,
        rapid_mm_min: float | None = None,
    ) -> None:
        self.axis = axis
        self.rapid_mm_min = rapid_mm_min
        self.settings = settings
        self.statistics = statistics
        self.read = read
        self.column = dict(column)
        self.bounds = dict(bounds)
        present = set(channels)
        self.has = {
            s: f"{axis}_{s}" in present
            for s in ("position_mm", "velocity_cmd_mm_min", "marker", "current_a")
        }
        self.n = statistics.rows
        self.dt = statistics.sample_period_s if self.n > 1 else 1.0
        if not self.dt > 0:
            raise RecordingError(f"axis {axis}: the sample times do not increase")
        empty = _as_array(Sparse(self.n, [], []))
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
        self.found = _Found()

    # -- the rows, cleaned and bridged -------------------------------------------------

    def _rows(self, derived: bool) -> Callable[[RowChunk], list[Block]]:
        """For one pass: a chunk's rows -> the blocks of rows now complete.

        The columns t, v, x, and where recorded cmd, marker, i, and with
        ``derived`` vd (the velocity the windows are found by): the position's
        central differences need ``h`` rows ahead, so blocks lag by ``h`` rows.
        """
        axis = self.axis
        column = self.column
        stats = self.statistics
        scale = self.dt / 60.0
        carry = {"x": 0.0}
        h = self.h if derived and self.from_position else 0
        ahead = _Ahead(h, h, self.n)

        def cleaned(chunk: RowChunk, signal: str) -> FloatArray:
            name = f"{axis}_{signal}"
            values = chunk.values[:, column[name]]
            bad = implausible(values, self.bounds.get(name))
            if bad.any():
                values = values.copy()
                values[bad] = np.nan
            return np.ascontiguousarray(values, dtype=np.float64)

        def bridged(chunk: RowChunk, signal: str, index: int) -> FloatArray:
            before, after = stats.neighbours[signal]
            return bridge_chunk(cleaned(chunk, signal), chunk.time_s, before[index], after[index])

        def held(chunk: RowChunk, index: int) -> FloatArray:
            values = cleaned(chunk, "velocity_cmd_mm_min")
            bad = ~np.isfinite(values)
            if not bad.any() or stats.finite.get("velocity_cmd_mm_min", 0) == 0:
                return values
            before, after = stats.neighbours["velocity_cmd_mm_min"]
            good = np.flatnonzero(~bad)
            previous = before[index]
            if previous is not None:
                fallback = previous[1]
            elif len(good):
                fallback = float(values[good[0]])
            else:
                following = after[index]
                assert following is not None
                fallback = following[1]
            last = np.maximum.accumulate(np.where(bad, -1, np.arange(len(values))))
            return np.where(last >= 0, values[np.maximum(last, 0)], fallback)

        def rows(chunk: RowChunk) -> list[Block]:
            index = chunk.first // stats.chunk_rows
            columns: Columns = {"t": chunk.time_s}
            columns["v"] = bridged(chunk, "velocity_mm_min", index)
            if self.positions_known:
                columns["x"] = bridged(chunk, "position_mm", index)
            else:
                filled = np.where(np.isfinite(columns["v"]), columns["v"], 0.0)
                summed = np.cumsum(np.concatenate(([carry["x"]], filled)))[1:]
                if len(summed):
                    carry["x"] = float(summed[-1])
                columns["x"] = summed * scale
            if self.has["velocity_cmd_mm_min"]:
                columns["cmd"] = held(chunk, index)
            if self.has["marker"]:
                columns["marker"] = cleaned(chunk, "marker")
            if self.has["current_a"]:
                columns["i"] = cleaned(chunk, "current_a")
            span = ahead.push(columns)
            if span is None:
                return []
            lo, hi = span
            offset = ahead.offset
            part = {k: v[lo - offset : hi - offset] for k, v in ahead.columns.items()}
            if derived:
                if h:
                    part["vd"] = position_velocity(
                        ahead.columns["t"], ahead.columns["x"], h, lo, hi, offset, self.n
                    )
                else:
                    part["vd"] = part["v"]
            ahead.forget()
            return [(lo, hi, part)]

        return rows

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
        """Pass: marker runs and command stretches (see the module docstring)."""
        assert not self.needs_agreement
        self.found = _Found()
        rows = self._rows(derived=True)
        state = _Sweep(plateaus=_Ahead(0, 0, self.n), want_plateaus=False, want_still=False)

        def feed(chunk: RowChunk) -> None:
            for lo, hi, part in rows(chunk):
                if "marker" in part:
                    self._marker_runs(state, part["marker"], lo, hi)
                if "cmd" in part:
                    self._command_stretches(state, part["cmd"], lo, hi)

        yield feed

    def _plateau_task(self) -> Generator[Feed, None, None]:
        """Pass: plateaus, and without a position the longest stretch above standstill.

        Only where the marker and the command gave no window, as on the whole
        arrays (the rolling median over every row is the costly part).
        """
        rows = self._rows(derived=True)
        reach = self.plateau_n + self.filter_n + 2
        state = _Sweep(
            plateaus=_Ahead(reach, reach, self.n),
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
        self.found.longest_moving = state.moving_best
        self.found.plateaus_swept = True

    def _sweep_plateaus(self) -> None:
        if not self.found.plateaus_swept:
            run_task(self.read, self._plateau_task())

    def _marker_runs(self, state: _Sweep, marker: FloatArray, lo: int, hi: int) -> None:
        """Runs of a set marker that break where its value changes (as _value_runs)."""
        found = self.found
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

    def _command_stretches(self, state: _Sweep, command: FloatArray, lo: int, hi: int) -> None:
        """Stretches of constant commanded velocity (as command_stretches), kept as there."""
        if state.command_last is None:
            repeats = np.concatenate(([False], command_repeats(command)))
        else:
            repeats = command_repeats(np.concatenate(([state.command_last], command)))
        for begin in (np.flatnonzero(~repeats) + lo).tolist():
            if state.command_begin is not None:
                self._close_command(state.command_begin, begin, state.command_level)
            state.command_begin = begin
            state.command_level = float(command[begin - lo])
        state.command_last = float(command[-1])
        if hi == self.n and state.command_begin is not None and self.n >= 2:
            self._close_command(state.command_begin, self.n, state.command_level)

    def _close_command(self, begin: int, end: int, level: float) -> None:
        if abs(level) >= self.settings.standstill_mm_min and end - begin >= self.min_n:
            self.found.command.append((begin, end, level))

    def _plateaus(self, state: _Sweep, detect_part: FloatArray) -> None:
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
            smooth = median_filter(finite, size=self.filter_n, mode="nearest")
            mask = plateau_mask(smooth, self.band, self.standstill, self.plateau_n, self.n, offset)
            state.plateau_runs.add(mask[lo - offset : hi - offset], lo, hi == self.n)
        if state.want_still:
            moving = np.abs(finite)
            if self.filter_n > 1:
                moving = median_filter(moving, size=self.filter_n, mode="nearest")
            above = moving[lo - offset : hi - offset] >= self.standstill
            starts, stops = _runs(above)
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
        lie inside its stretch).
        """
        margin_before = self.settle_n + self.filter_n
        margin_after = self.filter_n
        outer = _merged(
            (max(0, a - margin_before), min(self.n, b + margin_after)) for a, b in stretches
        )
        inner = _merged(stretches)
        # The marker's values were noted by the sweep; the slices need not hold it.
        same_detect = not self.from_position  # vd is v: one copy serves both
        wide = ("vd",) if not same_detect else ("v",)
        narrow = tuple(k for k in ("t", "v", "x", "cmd", "i") if k not in wide)
        kept = {k: _Keeper(outer) for k in wide} | {k: _Keeper(inner) for k in narrow}
        rows = self._rows(derived=True)
        for chunk in self.read():
            for lo, hi, part in rows(chunk):
                for key, keeper in kept.items():
                    if key in part:
                        keeper.add(lo, hi, part[key])

        def sparse(key: str) -> FloatArray:
            return _as_array(kept[key].sparse(self.n))

        self.t, self.v, self.x = sparse("t"), sparse("v"), sparse("x")
        self.v_detect = self.v if same_detect else sparse("vd")
        if self.command is not None:
            self.command = sparse("cmd")
        self.current = sparse("i") if self.has["current_a"] else _as_array(Sparse(self.n, [], []))

    # -- the ways of finding windows, on slices ----------------------------------------

    def marker_candidates(self) -> list[_Candidate]:
        if not self.marker_wanted():
            return []
        found = self.found
        if found.marker_starts:
            self._gather(list(zip(found.marker_starts, found.marker_stops, strict=True)))
        return self.marker_levels(found.marker_starts, found.marker_stops, found.marker_values)

    def command_candidates(self) -> list[_Candidate]:
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

    def plateau_candidates(self) -> list[_Candidate]:
        if self.plateau_too_short():
            return []
        self._sweep_plateaus()
        runs = self.found.plateaus
        levels = []
        if runs:
            self._gather(runs)
            for start, stop in runs:
                low = max(0, start - self.settle_n - self.filter_n)
                high = min(self.n, stop + self.filter_n)
                detect = self.v_detect[low:high]
                finite = np.where(np.isfinite(detect), detect, 0.0)
                smooth = median_filter(finite, size=self.filter_n, mode="nearest")
                levels.append((start, stop, float(np.median(smooth[start - low : stop - low]))))
        return self.plateau_found(levels)

    def still(self) -> str | None:
        """:meth:`_Finder.still` from the first pass's ranges and the sweep's longest run."""
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
        empty = _as_array(Sparse(self.n, [], []))
        self.t = self.v = self.x = self.v_detect = self.current = empty
        if self.command is not None:
            self.command = empty

    def window_current(self, start: int, stop: int) -> FloatArray:
        """The current of a window's samples: a copy, the slices may be released."""
        return self.current[start:stop].copy()
