"""Fixtures with the properties of real machines' data, built from synthetic recordings.

Real recordings differ from ncmeasure's own in ways the analysis must hold
against: a data collector samples every 100 ms and has no marker; a drive
reports velocity in counts of several mm/min; a channel is dead; a velocity
reading freezes at standstill; a link loses rows; a logger writes −999999
where it has no value. Each function here takes a simulated measurement
(:func:`ncmeasure.sim.synthetic.simulate`) and gives it one such property;
:func:`write` stores the result as an ordinary recording.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ncmeasure.recording import Recording, RecordingWriter
from ncmeasure.samples import LinkEvent, SampleBlock
from ncmeasure.sim.synthetic import SyntheticAxis, SyntheticData, machine_config, simulate

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Data(SyntheticData):
    """Rows of a recording in memory (times, channels, values, the program's schedule)."""

    @classmethod
    def of(cls, data: SyntheticData) -> Data:
        return cls(data.time_s, data.channels, data.values, data.schedule)

    def index(self, name: str) -> int:
        return [c.name for c in self.channels].index(name)

    def column(self, name: str) -> FloatArray:
        return self.values[:, self.index(name)]

    def rows(self, keep: NDArray[np.bool_]) -> Data:
        """Only the rows where ``keep`` is True: the others are lost (gaps)."""
        return replace(self, time_s=self.time_s[keep], values=self.values[keep])

    def without(self, *names: str) -> Data:
        """The channels named left out (a logger that does not record them)."""
        keep = [i for i, c in enumerate(self.channels) if c.name not in names]
        return replace(
            self, channels=tuple(self.channels[i] for i in keep), values=self.values[:, keep]
        )

    def set(self, name: str, values: FloatArray) -> Data:
        copy = self.values.copy()
        copy[:, self.index(name)] = values
        return replace(self, values=copy)


def measure(axes: Sequence[SyntheticAxis], *, seed: int = 0, **options: object) -> Data:
    """Simulate a measurement at 4 ms (marker and command recorded unless told otherwise)."""
    return Data.of(simulate(axes, seed=seed, **options))  # type: ignore[arg-type]


def decimate(data: Data, factor: int) -> Data:
    """Every ``factor``-th row: a data collector sampling ``factor`` times slower."""
    return replace(data, time_s=data.time_s[::factor], values=data.values[::factor])


def write(
    directory: Path,
    data: Data,
    axes: Sequence[SyntheticAxis] | None = None,
    *,
    period_s: float | None = None,
    events: Sequence[LinkEvent] = (),
) -> Recording:
    """Store ``data`` as a recording (with the axes' machine data when given, and
    ``events``)."""
    period = period_s if period_s is not None else float(np.median(np.diff(data.time_s)))
    with RecordingWriter.create(
        directory,
        data.channels,
        nominal_period_s=period,
        machine=machine_config(axes) if axes else None,
        config_hash=data.schedule.config_hash,
        source="test",
        faster_than_real_time=True,
    ) as writer:
        for begin in range(0, len(data.time_s), 100_000):
            end = begin + 100_000
            writer.append(SampleBlock(data.time_s[begin:end], data.values[begin:end]))
        for event in events:
            writer.add_event(event)
    return Recording.open(directory)


def window_rows(data: Data, axis: str, window_id: int) -> NDArray[np.bool_]:
    """The rows during which the program's marker holds a window id."""
    return np.asarray(data.column(f"{axis}_marker") == window_id, dtype=np.bool_)
