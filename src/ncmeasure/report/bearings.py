"""Where an axis' screw bearings sit: the travel ends and which of them is the fixed bearing.

``results.json`` describes friction, not the machine, so the layout comes from
the recording's ``meta.json`` (the machine file's ``travel_mm`` and
``fixed_bearing_end`` of each recorded axis). Without it the machine file's
default is assumed (fixed bearing at the min end) and the report says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

from ncmeasure.formats.results import AxisResult
from ncmeasure.recording import Recording, RecordingHead
from ncmeasure.report.words import format_mm

__all__ = ["BearingLayout", "bearing_layout"]

End = Literal["min", "max"]


@dataclass(frozen=True)
class BearingLayout:
    """The bearing layout of one axis.

    Attributes:
        travel_mm: Soft limits (min, max), or None when unknown.
        fixed_end: The travel end next to the fixed bearing.
        known: False when ``fixed_end`` is the assumed default.
    """

    travel_mm: tuple[float, float] | None
    fixed_end: End
    known: bool

    @property
    def loose_end(self) -> End:
        """The travel end next to the loose bearing."""
        return "max" if self.fixed_end == "min" else "min"

    def end_mm(self, end: End) -> float | None:
        """The position of a travel end, when the travel is known."""
        if self.travel_mm is None:
            return None
        return self.travel_mm[0] if end == "min" else self.travel_mm[1]

    def describe(self) -> str:
        """One line for the report, e.g. ``fixed bearing at 0 mm, loose bearing at 750 mm``."""
        fixed, loose = self.end_mm(self.fixed_end), self.end_mm(self.loose_end)
        if fixed is not None and loose is not None:
            text = f"fixed bearing at the {self.fixed_end} end ({format_mm(fixed)} mm), "
            text += f"loose bearing at the {self.loose_end} end ({format_mm(loose)} mm)"
        else:
            text = f"fixed bearing at the {self.fixed_end} end, "
            text += f"loose bearing at the {self.loose_end} end"
        if not self.known:
            text += " (assumed: the machine file was not available)"
        return text


def _travel(value: Any) -> tuple[float, float] | None:
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != 2:
        return None
    try:
        low, high = float(value[0]), float(value[1])
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        return None
    return low, high


def bearing_layout(
    axis: str,
    recording: Recording | RecordingHead | None = None,
    result: AxisResult | None = None,
) -> BearingLayout:
    """The bearing layout of ``axis``: from its results, else the recording's axis metadata.

    Args:
        axis: The axis name.
        recording: The recording the results came from, if at hand.
        result: The axis' results, which carry the layout the analysis used.

    Returns:
        The layout; ``known`` is False when the recording is missing or does
        not describe the axis.
    """
    if result is not None and result.fixed_bearing_end is not None:
        return BearingLayout(result.travel_mm, result.fixed_bearing_end, known=True)
    entries = recording.meta.axes if recording is not None else []
    for entry in entries:
        if entry.name != axis:
            continue
        travel = _travel(entry.travel_mm)
        if entry.fixed_bearing_end is not None:
            return BearingLayout(travel, entry.fixed_bearing_end, known=True)
        return BearingLayout(travel, "min", known=False)
    return BearingLayout(None, "min", known=False)
