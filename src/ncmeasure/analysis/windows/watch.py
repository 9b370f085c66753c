"""Work on the raw rows that needs an axis' windows, done on the analysis' own readings.

An analysis that reads a recording chunk by chunk reads the file several
times: the statistics and the sweep of all axes, then the samples of each
axis' windows, axis after axis. A caller that needs the raw rows once more
when it knows an axis' windows (the report's raw-data figure: the stretch it
shows and the span of its overview follow the windows) gives
:func:`~ncmeasure.analysis.analyze.analyze` an ``on_windows`` function
(:data:`OnWindows`). Called with the :class:`AxisWindows` of every analysed
axis, it returns a :class:`Watch`: the channels it needs and a task of
:mod:`~ncmeasure.analysis.windows.streaming` (a generator yielding a feed for each
whole pass over the rows, returning when done; its value is not used). The
analysis feeds every task the chunks of its next readings of the file, and
only where none is left (the last axis') reads once more: only the channels
those tasks need, and where they say which stretch of time they look at,
only the frames of the file that hold it. A reading left off midway (an
axis whose analysis failed while reading) feeds nothing: its tasks start
afresh.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.streaming import Task
from ncmeasure.errors import RecordingError
from ncmeasure.recording import RowChunk

__all__ = ["AxisWindows", "NamedChunk", "OnWindows", "Reader", "Watch", "Watchers"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class AxisWindows:
    """An axis' windows as the analysis found them, and the recording's extent.

    Attributes:
        axis: The axis.
        windows: (time of the first sample, time of the last sample) of every
            window the friction values come from, as ``analyze``'s ``window_times``.
        rows: Rows of the recording.
        start_s: Time of its first row.
        end_s: Time of its last row.
    """

    axis: str
    windows: tuple[tuple[float, float], ...]
    rows: int
    start_s: float
    end_s: float


@dataclass(frozen=True)
class NamedChunk:
    """Consecutive rows of a recording, their channels by name: what a task is fed.

    Attributes:
        first: Index of the chunk's first row in the whole recording.
        time_s: Times of its rows (m,).
        values: Its channels (m, channels); ``column`` says which is where.
        column: Column of ``values`` of every channel it holds, by name.
    """

    first: int
    time_s: FloatArray
    values: FloatArray
    column: Mapping[str, int]

    def channel(self, name: str) -> FloatArray:
        """The values of one channel (a view)."""
        return self.values[:, self.column[name]]


@dataclass(frozen=True)
class Watch:
    """What ``on_windows`` returns for an axis.

    Attributes:
        channels: The channels the task needs (each recorded).
        task: The task.
        between_s: Where every pass of the task looks only at the rows of this
            stretch of time (first, last), a reading for it alone may skip the
            rest; None: every row matters.
    """

    channels: tuple[str, ...]
    task: Task[NamedChunk, Any]
    between_s: tuple[float, float] | None = None


OnWindows = Callable[[AxisWindows], Watch | None]
"""Called once an axis' windows are found; None: nothing to do for this axis."""

Reader = Callable[[tuple[str, ...], tuple[float, float] | None], Iterable[RowChunk]]
"""Reads the rows of some channels, all of them or at least those of a stretch of time."""


class _Watched:
    """One task: made anew where a reading it was fed was left off."""

    def __init__(self, make: Callable[[], Watch | None]) -> None:
        self.make = make
        self.watch: Watch | None = None
        self.feed: Callable[[NamedChunk], None] | None = None

    @property
    def channels(self) -> tuple[str, ...]:
        return self.watch.channels if self.watch is not None else ()

    def start(self) -> bool:
        """Make the task; False when there is nothing to do."""
        self.watch = self.make()
        return self.watch is not None and self.advance()

    def advance(self) -> bool:
        """The feed of the task's next pass; False when it is done."""
        assert self.watch is not None
        try:
            self.feed = next(self.watch.task)
        except StopIteration:
            self.feed = None
            return False
        return True


class Watchers:
    """The tasks of ``on_windows``, fed from an analysis' readings of a recording.

    Args:
        column: The column of every channel in the chunks the analysis reads.
    """

    def __init__(self, column: Mapping[str, int]) -> None:
        self.column = dict(column)
        self.waiting: list[_Watched] = []

    def add(self, make: Callable[[], Watch | None]) -> None:
        """Start a task (``make`` makes it, again where a reading is left off)."""
        watched = _Watched(make)
        if watched.start():
            self.waiting.append(watched)

    def reading(self, chunks: Iterable[RowChunk]) -> Iterator[RowChunk]:
        """The chunks of a whole reading, each also fed to the tasks waiting for a pass.

        Only tasks whose channels the chunks hold are fed.
        """
        fed = [w for w in self.waiting if all(c in self.column for c in w.channels)]
        if not fed:
            yield from chunks
            return
        self.waiting = [w for w in self.waiting if w not in fed]
        whole = False
        try:
            for chunk in chunks:
                named = NamedChunk(chunk.first, chunk.time_s, chunk.values, self.column)
                for watched in fed:
                    assert watched.feed is not None
                    watched.feed(named)
                yield chunk
            whole = True
        finally:
            for watched in fed:
                if watched.advance() if whole else watched.start():
                    self.waiting.append(watched)

    def finish(self, read: Reader) -> None:
        """Read as often as the tasks not done yet need, only what they need.

        ``read(channels, between_s)`` gives the rows of these channels, in this
        order: every row, or with ``between_s`` at least those of that stretch
        of time. A recording that cannot be read any more (it was read a moment
        ago) ends the tasks not done, with a warning.
        """
        while self.waiting:
            channels = tuple(dict.fromkeys(c for w in self.waiting for c in w.channels))
            column = {name: k for k, name in enumerate(channels)}
            fed, self.waiting = self.waiting, []
            stretches = [w.watch.between_s if w.watch is not None else None for w in fed]
            between: tuple[float, float] | None = None
            if all(s is not None for s in stretches):
                between = (min(s[0] for s in stretches if s), max(s[1] for s in stretches if s))
            try:
                for chunk in read(channels, between):
                    named = NamedChunk(chunk.first, chunk.time_s, chunk.values, column)
                    for watched in fed:
                        assert watched.feed is not None
                        watched.feed(named)
            except (RecordingError, OSError) as exc:
                log.warning("the recording could not be read once more: %s", exc)
                return
            self.waiting = [w for w in fed if w.advance()]
