"""The raw-data figures' data read chunk by chunk: bounded, whatever the recording's length.

:func:`read_raw_traces` gives, for every axis, the :class:`~ncmeasure.report.plots.RawTrace`
that :func:`~ncmeasure.report.plots.raw_trace` gives for a recording in memory,
from :func:`~ncmeasure.recording.iter_chunks`, keeping only what the figure
shows: an overview of the velocity over the axis' measurement (the lowest
and highest reading of each of :data:`~ncmeasure.report.plots.OVERVIEW_BINS`
equal stretches of time, peaks kept) and the samples of the detailed
stretch (about ``stretch_s`` seconds). Up to three passes over the file, all
axes together: the times and the peak velocity; where an axis has no windows,
where it moved; then the overview and the stretch.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ncmeasure.errors import RecordingError
from ncmeasure.recording import RecordingHead, iter_chunks
from ncmeasure.report.plots import OVERVIEW_BINS, RawTrace, _stretch

__all__ = ["read_raw_traces"]

FloatArray = NDArray[np.float64]


@dataclass
class _Axis:
    """What the passes gather for one axis."""

    name: str
    windows: tuple[tuple[float, float], ...]
    command: bool
    peak: float = 0.0
    first_moving: float | None = None
    last_moving: float | None = None
    span: tuple[float, float] = (0.0, 0.0)
    stretch: tuple[float, float] = (0.0, 0.0)
    low: FloatArray = field(default_factory=lambda: np.full(OVERVIEW_BINS, math.inf))
    low_t: FloatArray = field(default_factory=lambda: np.zeros(OVERVIEW_BINS))
    high: FloatArray = field(default_factory=lambda: np.full(OVERVIEW_BINS, -math.inf))
    high_t: FloatArray = field(default_factory=lambda: np.zeros(OVERVIEW_BINS))
    parts: dict[str, list[FloatArray]] = field(default_factory=dict)


def read_raw_traces(
    head: RecordingHead,
    axes: Sequence[str],
    windows: Mapping[str, Sequence[tuple[float, float]]],
    *,
    stretch_s: float = 30.0,
    rows: int = 1 << 16,
) -> dict[str, RawTrace | RecordingError]:
    """The raw-data figure's data of every axis, read chunk by chunk.

    Args:
        head: The recording.
        axes: The axes.
        windows: Per axis, the windows the analysis used, (t_start, t_end) in s.
        stretch_s: Length of the detailed stretch in seconds.
        rows: Rows per chunk.

    Returns:
        Per axis its trace, or why it has none (no current or velocity channel).
    """
    names = set(head.channel_names)
    result: dict[str, RawTrace | RecordingError] = {}
    found: list[_Axis] = []
    for axis in axes:
        missing = [
            f"{axis}_{s}" for s in ("current_a", "velocity_mm_min") if f"{axis}_{s}" not in names
        ]
        if missing:
            result[axis] = RecordingError(
                f"{head.directory}: no channel {missing[0]!r} "
                f"(channels: {', '.join(head.channel_names)})"
            )
            continue
        cuts = tuple(sorted((float(a), float(b)) for a, b in windows.get(axis, ())))
        found.append(_Axis(axis, cuts, f"{axis}_velocity_cmd_mm_min" in names))
    channels: list[str] = []
    for entry in found:
        channels += [f"{entry.name}_current_a", f"{entry.name}_velocity_mm_min"]
        if entry.command:
            channels.append(f"{entry.name}_velocity_cmd_mm_min")
    column = {name: k for k, name in enumerate(channels)}

    verified: set[int] = set()

    def read() -> Iterator[tuple[FloatArray, FloatArray]]:
        for chunk in iter_chunks(head.directory, rows, tuple(channels), verified=verified):
            yield chunk.time_s, chunk.values

    def velocity(values: FloatArray, entry: _Axis) -> FloatArray:
        return values[:, column[f"{entry.name}_velocity_mm_min"]]

    total = 0
    first_t = last_t = math.nan
    for time_s, values in read():
        if len(time_s) == 0:
            continue
        if total == 0:
            first_t = float(time_s[0])
        last_t = float(time_s[-1])
        total += len(time_s)
        for entry in found:
            speeds = np.abs(velocity(values, entry))
            if np.isfinite(speeds).any():
                entry.peak = max(entry.peak, float(np.nanmax(speeds)))
    empty = np.empty(0, dtype=np.float64)
    if total == 0 or not found:
        for entry in found:
            nothing = (empty, empty, empty, empty, empty, None, total)
            result[entry.name] = RawTrace(
                entry.name, entry.windows, (0.0, 0.0), (0.0, 0.0), *nothing
            )
        return {axis: result[axis] for axis in axes if axis in result}
    moving = [e for e in found if not e.windows and e.peak > 0]
    if moving:
        for time_s, values in read():
            for entry in moving:
                above = np.flatnonzero(np.abs(velocity(values, entry)) > 0.01 * entry.peak)
                if len(above):
                    if entry.first_moving is None:
                        entry.first_moving = float(time_s[above[0]])
                    entry.last_moving = float(time_s[above[-1]])
    for entry in found:
        if entry.windows:
            start = min(w[0] for w in entry.windows)
            end = max(w[1] for w in entry.windows)
            pad = 0.02 * max(end - start, 1.0)
            entry.span = (max(first_t, start - pad), min(last_t, end + pad))
        elif entry.first_moving is not None and entry.last_moving is not None:
            entry.span = (entry.first_moving, entry.last_moving)
        else:
            entry.span = (first_t, last_t)
        entry.stretch = _stretch(entry.span, entry.windows, stretch_s)
        entry.parts = {"t": [], "i": [], "v": [], "cmd": []}
    for time_s, values in read():
        for entry in found:
            _overview(entry, time_s, velocity(values, entry))
            start, end = entry.stretch
            part = (time_s >= start) & (time_s <= end)
            if part.any():
                entry.parts["t"].append(time_s[part])
                entry.parts["i"].append(values[part, column[f"{entry.name}_current_a"]])
                entry.parts["v"].append(velocity(values, entry)[part])
                if entry.command:
                    cmd = values[part, column[f"{entry.name}_velocity_cmd_mm_min"]]
                    entry.parts["cmd"].append(cmd)
    for entry in found:
        kept = entry.high >= entry.low
        pairs = np.column_stack([entry.low_t, entry.high_t])[kept]
        levels = np.column_stack([entry.low, entry.high])[kept]
        order = np.argsort(pairs, axis=1, kind="stable")
        overview_t = np.take_along_axis(pairs, order, axis=1).ravel()
        overview_v = np.take_along_axis(levels, order, axis=1).ravel()

        def joined(key: str, entry: _Axis = entry) -> FloatArray:
            parts = entry.parts[key]
            return np.concatenate(parts) if parts else np.empty(0, dtype=np.float64)

        result[entry.name] = RawTrace(
            entry.name,
            entry.windows,
            entry.span,
            entry.stretch,
            overview_t,
            overview_v,
            joined("t"),
            joined("i"),
            joined("v"),
            joined("cmd") if entry.command else None,
            total,
        )
    return {axis: result[axis] for axis in axes}


def _overview(entry: _Axis, time_s: FloatArray, velocity: FloatArray) -> None:
    """The lowest and highest velocity (and their times) per bin of the axis' span."""
    low, high = entry.span
    inside = (time_s >= low) & (time_s <= high) & np.isfinite(velocity)
    if not inside.any():
        return
    times, values = time_s[inside], velocity[inside]
    width = (high - low) / OVERVIEW_BINS
    index = (
        np.minimum(((times - low) / width).astype(np.intp), OVERVIEW_BINS - 1)
        if width > 0
        else np.zeros(len(times), dtype=np.intp)
    )
    # Times rise, so each bin's rows are consecutive.
    starts = np.flatnonzero(np.diff(index, prepend=-1))
    for begin, stop in zip(starts.tolist(), [*starts[1:].tolist(), len(index)], strict=True):
        k = int(index[begin])
        chunk = values[begin:stop]
        i_low, i_high = int(np.argmin(chunk)), int(np.argmax(chunk))
        if chunk[i_low] < entry.low[k]:
            entry.low[k], entry.low_t[k] = chunk[i_low], times[begin + i_low]
        if chunk[i_high] > entry.high[k]:
            entry.high[k], entry.high_t[k] = chunk[i_high], times[begin + i_high]
