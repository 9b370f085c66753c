"""A velocity derived from the position, for an axis whose trace has no velocity channel.

The analysis finds its windows in the velocity. A data collector or a trace
that recorded only an axis' position would leave that axis unanalysable;
:class:`DerivingSink` adds ``<AXIS>_velocity_mm_min`` to such a recording as
it is written, from central differences of the position on the sample times
(:func:`derive_velocity`), chunk by chunk: a chunk waits for the first row
of the next one, its right neighbour.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.recording import ImportSink, Recording, channel_from_name
from ncmeasure.samples import Channel

if TYPE_CHECKING:  # the machine-file models: exporting a recording reads no machine file
    from ncmeasure.config import MachineConfig

__all__ = ["DerivingSink", "derive_velocity", "derived_line", "needs_velocity"]


def needs_velocity(channels: Sequence[Channel]) -> list[str]:
    """The axes with a position channel and no velocity channel."""
    names = {c.name for c in channels}
    axes = dict.fromkeys(c.axis for c in channels if c.signal == "position_mm")
    return [a for a in axes if f"{a}_velocity_mm_min" not in names]


def derive_velocity(
    time_s: NDArray[np.float64], position_mm: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Velocity [mm/min] from positions [mm] at their sample times [s].

    Central differences ``(x[i+1] - x[i-1]) / (t[i+1] - t[i-1])``, one-sided at
    the ends; on uneven times too (the second-order formula of
    :func:`numpy.gradient` would weight a neighbour more than the sample itself
    at a jump of the step). NaN where a neighbour is NaN; one sample: NaN.
    """
    n = len(time_s)
    if n < 2:
        return np.full(n, np.nan)
    index = np.arange(n)
    lo, hi = np.maximum(index - 1, 0), np.minimum(index + 1, n - 1)
    return (position_mm[hi] - position_mm[lo]) / (time_s[hi] - time_s[lo]) * 60.0


def derived_line(axis: str) -> str:
    """The report's sentence on a derived velocity."""
    return (
        f"{axis}_velocity_mm_min [mm/min]: derived from {axis}_position_mm (central "
        "differences on the sample times); the file has no velocity channel"
    )


def _with_derived(channels: Sequence[Channel], axes: Sequence[str]) -> list[Channel]:
    """The channels in their order, each derived velocity just before its position."""
    out: list[Channel] = []
    for channel in channels:
        if channel.signal == "position_mm" and channel.axis in axes:
            derived = channel_from_name(f"{channel.axis}_velocity_mm_min")
            assert derived is not None
            out.append(derived)
        out.append(channel)
    return out


class DerivingSink(ImportSink):
    """An :class:`~ncmeasure.recording.ImportSink` that adds a derived velocity for every
    axis with a position and no velocity channel.

    :meth:`append` takes rows of the importer's channels (``source_channels``);
    the recording holds those and the derived velocities. A chunk is written
    once the next chunk's first row (or the end) is known.
    """

    def __init__(
        self,
        directory: Path,
        channels: Sequence[Channel],
        *,
        machine: MachineConfig | None,
        nominal_period_s: float | None,
        **meta: Any,
    ) -> None:
        self._held: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._written = 0
        self.source_channels = tuple(channels)
        self.derived = needs_velocity(channels)
        out = _with_derived(channels, self.derived)
        super().__init__(directory, out, machine=machine, nominal_period_s=nominal_period_s, **meta)
        names = [c.name for c in out]
        self._columns = [names.index(c.name) for c in self.source_channels]
        self._targets = [names.index(f"{a}_velocity_mm_min") for a in self.derived]
        self._positions = [
            next(i for i, c in enumerate(self.source_channels) if c.name == f"{a}_position_mm")
            for a in self.derived
        ]
        self._before: tuple[float, NDArray[np.float64]] | None = None

    @property
    def rows(self) -> int:
        """Rows taken so far, the held chunk's included."""
        return self._written + (len(self._held[0]) if self._held is not None else 0)

    @rows.setter
    def rows(self, value: int) -> None:
        self._written = value

    def append(self, time_s: NDArray[np.float64], values: NDArray[np.float64]) -> None:
        """Take rows of the source channels; write the chunk held before."""
        if len(time_s) == 0:
            return
        time_s = np.asarray(time_s, dtype=np.float64)
        values = np.asarray(values, dtype=np.float64)
        if self._held is not None:
            self._write_held((float(time_s[0]), values[0]))
        self._held = (time_s, values)

    def _write_held(self, after: tuple[float, NDArray[np.float64]] | None) -> None:
        assert self._held is not None
        time_s, values = self._held
        t, v, left = time_s, values, 0
        if self._before is not None:
            t = np.concatenate(([self._before[0]], t))
            v = np.vstack((self._before[1][None, :], v))
            left = 1
        if after is not None:
            t = np.concatenate((t, [after[0]]))
            v = np.vstack((v, after[1][None, :]))
        out = np.full((len(time_s), len(self.channels)), np.nan)
        out[:, self._columns] = values
        for target, position in zip(self._targets, self._positions, strict=True):
            out[:, target] = derive_velocity(t, v[:, position])[left : left + len(time_s)]
        self._before = (float(time_s[-1]), values[-1])
        self._held = None
        super().append(time_s, out)

    def drain(self) -> None:
        """Write the chunk held back: no rows follow (before asking for the counts)."""
        if self._held is not None:
            self._write_held(None)

    def close(self, status: Any = "complete", **updates: Any) -> RecordingMeta:
        """Write the last chunk, then close as :meth:`ImportSink.close`."""
        self.drain()
        return super().close(status, **updates)

    def finish(self, status: Any = "complete", **updates: Any) -> Recording:
        """Write the last chunk, then close and read back as :meth:`ImportSink.finish`."""
        self.drain()
        return super().finish(status, **updates)
