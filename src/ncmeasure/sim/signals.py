"""Signal sources: what a simulated drive reports for an axis at a given time.

A simulated drive (CANopen or Modbus) asks its source for the physical state
of its axis at each cycle and encodes it the way a real drive would
(increments, per-mille of rated current, registers). Sources are pure
functions of (axis, time), so a run is reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

__all__ = ["AxisState", "PatternSource", "SignalSource"]


@dataclass(frozen=True)
class AxisState:
    """The physical state of one axis."""

    position_mm: float
    velocity_mm_min: float
    current_a: float
    velocity_cmd_mm_min: float = 0.0
    marker: float = 0.0
    """The program's marker (0: not set), as wired to a drive input."""


class SignalSource(Protocol):
    """Anything that can say the state of axis ``axis`` (0-based) at ``time_s``."""

    def state(self, axis: int, time_s: float) -> AxisState:
        """The state of one axis at one instant."""
        ...


@dataclass(frozen=True)
class PatternSource:
    """A smooth, deterministic test pattern: each axis oscillates around its centre.

    Position ``centre + amplitude·sin(ωt)``, velocity its derivative, current
    a friction-like ``coulomb·sign(v) + viscous·v``; axes differ in phase.
    """

    centre_mm: float = 100.0
    amplitude_mm: float = 50.0
    period_s: float = 4.0
    coulomb_a: float = 2.0
    viscous_a_per_m_min: float = 0.1

    def state(self, axis: int, time_s: float) -> AxisState:
        omega = 2 * math.pi / self.period_s
        phase = omega * time_s + axis * math.pi / 3
        position = self.centre_mm + self.amplitude_mm * math.sin(phase)
        velocity = self.amplitude_mm * omega * math.cos(phase) * 60.0
        current = math.copysign(self.coulomb_a, velocity) + (
            self.viscous_a_per_m_min * velocity / 1000.0
        )
        return AxisState(position, velocity, current, velocity)
