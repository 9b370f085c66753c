"""The windows of signals in memory: given arrays, or an axis of a recording in memory.

:func:`find_windows` (arrays) and :func:`windows_of` (a recording's axis) read
their rows as the analysis reads a recording's file: the passes of
:class:`~ncmeasure.analysis.windows.chunked.ChunkedFinder` over chunks of rows,
a recording as one chunk (its own columns, no copy), arrays in chunks of
:data:`ARRAY_CHUNK_ROWS` rows. The values are taken as they are: nothing is
left out as implausible (the analysis does that, :mod:`ncmeasure.validity`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Final

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.chunked import ChunkedFinder
from ncmeasure.analysis.windows.model import Segmentation
from ncmeasure.analysis.windows.scan import Rows, axes_statistics
from ncmeasure.analysis.windows.settings import SegmentSettings
from ncmeasure.analysis.windows.streaming import run_task
from ncmeasure.errors import RecordingError
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RowChunk

__all__ = [
    "ARRAY_CHUNK_ROWS",
    "WINDOW_SIGNALS",
    "array_rows",
    "axis_windows",
    "find_windows",
    "recording_chunks",
    "windows_of",
]

FloatArray = NDArray[np.float64]

ARRAY_CHUNK_ROWS: Final = 1 << 16
"""Rows per chunk of given arrays (each chunk's columns are stacked: a copy of that many rows)."""

WINDOW_SIGNALS: Final = ("velocity_mm_min", "position_mm", "velocity_cmd_mm_min", "marker")
"""The signals of an axis the windows are found by."""


def recording_chunks(recording: Recording) -> Callable[[], Iterator[RowChunk]]:
    """A reader of a recording in memory: one chunk of all its rows and channels.

    The same chunk on every reading (views of the recording's arrays, no copy;
    none for an empty recording).
    """
    chunks = [RowChunk(0, recording.time_s, recording.values)] if len(recording) else []
    return lambda: iter(chunks)


def array_rows(
    time_s: FloatArray, columns: Mapping[str, FloatArray], rows: int = ARRAY_CHUNK_ROWS
) -> Rows:
    """Arrays of equal length as rows read in chunks, every value taken as it is."""
    names = tuple(columns)
    count = len(time_s)

    def read() -> Iterator[RowChunk]:
        for lo in range(0, count, rows):
            hi = min(lo + rows, count)
            values = np.column_stack([columns[name][lo:hi] for name in names])
            yield RowChunk(lo, time_s[lo:hi], values)

    return Rows(read, {name: k for k, name in enumerate(names)}, rows, checked=False)


def axis_windows(
    axis: str,
    source: Rows,
    schedule: Schedule | None,
    settings: SegmentSettings,
    rapid_mm_min: float | None = None,
) -> Segmentation:
    """The windows of one axis of ``source``: its statistics, the passes, the finder's run.

    Raises:
        RecordingError: No window was found (the message says what was tried).
    """
    statistics = axes_statistics(source, (axis,))[axis]
    finder = ChunkedFinder(axis, statistics, source, schedule, settings, rapid_mm_min)
    if finder.needs_agreement:
        run_task(source.read, finder.agreement_task())
    run_task(source.read, finder.sweep_task())
    return finder.run()


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
    given = {
        "velocity_mm_min": velocity_mm_min,
        "position_mm": position_mm,
        "velocity_cmd_mm_min": command_mm_min,
        "marker": marker,
    }
    columns = {
        f"{axis}_{signal}": np.asarray(values, dtype=np.float64)
        for signal, values in given.items()
        if values is not None
    }
    source = array_rows(np.asarray(time_s, dtype=np.float64), columns)
    return axis_windows(axis, source, schedule, settings or SegmentSettings(), rapid_mm_min)


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
    names = recording.channel_names
    if f"{axis}_velocity_mm_min" not in names:
        raise RecordingError(
            f"{recording.directory}: axis {axis} has no velocity channel ({axis}_velocity_mm_min)"
        )
    column = {
        f"{axis}_{signal}": names.index(f"{axis}_{signal}")
        for signal in WINDOW_SIGNALS
        if f"{axis}_{signal}" in names
    }
    source = Rows(recording_chunks(recording), column, max(len(recording), 1), checked=False)
    return axis_windows(axis, source, schedule, settings or SegmentSettings())
