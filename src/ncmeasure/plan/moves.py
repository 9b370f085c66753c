"""What a subprogram does, move by move, and the clock that times the moves as they are planned."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

from ncmeasure.config import (
    AxisConfig,
)
from ncmeasure.profile import move_time_s


def to_mm(value_um: int) -> float:
    return value_um / 1000.0


def floor_feed(value_mm_min: float) -> float:
    """Largest feed on the 0.001 mm/min grid not above ``value_mm_min`` as a control reads it.

    The result is compared as written with three decimals (``f"{feed:.3f}"`` read
    back), so no float noise can put a written feed above the value.
    """
    count = math.floor(value_mm_min * 1000.0 + 1e-6)  # exact values stay (1.9 is 1.9)
    while count > 0 and float(f"{count / 1000.0:.3f}") > value_mm_min:
        count -= 1
    return count / 1000.0


@dataclass(frozen=True)
class Rapid:
    """Rapid traverse (G0) of one axis to ``target_mm``."""

    axis: str
    target_mm: float
    kind: Literal["rapid"] = "rapid"


@dataclass(frozen=True)
class Feed:
    """Linear feed (G1) of one axis to ``target_mm`` at ``feed_mm_min`` (warm-up)."""

    axis: str
    target_mm: float
    feed_mm_min: float
    kind: Literal["feed"] = "feed"


@dataclass(frozen=True)
class Run:
    """One measuring run, from rest at the current position to rest at ``stop_mm``.

    Three collinear feed blocks at the same feed: run-up to ``window_start_mm``,
    the window to ``window_end_mm`` (marker = ``window_id``), run-out to
    ``stop_mm`` (marker back to 0). How the marker is written is the dialect's
    business.
    """

    axis: str
    start_mm: float
    window_start_mm: float
    window_end_mm: float
    stop_mm: float
    feed_mm_min: float
    window_id: int
    kind: Literal["run"] = "run"


@dataclass(frozen=True)
class Dwell:
    """Standstill for ``seconds``."""

    seconds: float
    kind: Literal["dwell"] = "dwell"


@dataclass(frozen=True)
class Comment:
    """A comment line in the program (dialects without comments drop it)."""

    text: str
    kind: Literal["comment"] = "comment"


Move = Rapid | Feed | Run | Dwell | Comment


class Clock:
    """Accumulates the expected program time while moves are appended."""

    def __init__(
        self,
        axis: AxisConfig,
        start_s: float,
        position_mm: float,
        rapid_s: Callable[[int], float],
    ) -> None:
        self.axis = axis
        self.t_s = start_s
        self.position_mm = position_mm
        self.moves: list[Move] = []
        self._rapid_s = rapid_s

    def rapid(self, target_um: int) -> None:
        target = to_mm(target_um)
        if target == self.position_mm:
            return
        # every position lies on the micrometre grid
        self.t_s += self._rapid_s(round(abs(target - self.position_mm) * 1000.0))
        self.position_mm = target
        self.moves.append(Rapid(self.axis.name, target))

    def feed(self, target_um: int, feed_mm_min: float) -> None:
        target = to_mm(target_um)
        self.t_s += move_time_s(
            target - self.position_mm,
            feed_mm_min,
            self.axis.max_acceleration_m_s2,
            self.axis.max_jerk_m_s3,
        )
        self.position_mm = target
        self.moves.append(Feed(self.axis.name, target, feed_mm_min))

    def dwell(self, seconds: float) -> None:
        seconds = round(seconds, 3)  # what the program writes: whole milliseconds
        if seconds > 0:
            self.t_s += seconds
            self.moves.append(Dwell(seconds))


def move_blocks(moves: Sequence[Move]) -> int:
    """Blocks the moves take in a program: one per rapid, feed and dwell, three per run."""
    return sum(3 if move.kind == "run" else 0 if move.kind == "comment" else 1 for move in moves)
