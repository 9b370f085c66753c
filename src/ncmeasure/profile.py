"""Jerk-limited motion: run-up distances and move durations of a feed axis.

The controller drives an axis with an S-shaped velocity profile limited by
the axis' maximum acceleration ``a`` and jerk ``j``. Accelerating from rest
to velocity ``v`` takes

* ``t = v/a + a/j`` and covers ``s = v·t/2`` when ``v ≥ a²/j`` (the
  acceleration limit is reached and held), or
* ``t = 2·sqrt(v/j)`` and ``s = v·t/2`` when ``v < a²/j`` (the ramp is pure
  jerk: acceleration never reaches ``a``).

The profile is symmetric in time, which is why ``s = v·t/2`` holds in both
cases, and stopping from ``v`` takes the same time and distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Ramp", "move_time_s", "ramp"]

_MM_MIN_PER_M_S = 60_000.0


@dataclass(frozen=True)
class Ramp:
    """Acceleration from rest to a velocity (or deceleration to rest)."""

    time_s: float
    distance_mm: float


def ramp(velocity_mm_min: float, acceleration_m_s2: float, jerk_m_s3: float) -> Ramp:
    """Time and distance to accelerate from rest to ``velocity_mm_min``."""
    v = abs(velocity_mm_min) / _MM_MIN_PER_M_S
    a, j = acceleration_m_s2, jerk_m_s3
    time_s = v / a + a / j if v * j >= a * a else 2.0 * math.sqrt(v / j)
    return Ramp(time_s=time_s, distance_mm=v * time_s / 2.0 * 1000.0)


def move_time_s(
    distance_mm: float, velocity_mm_min: float, acceleration_m_s2: float, jerk_m_s3: float
) -> float:
    """Duration of a rest-to-rest move over ``distance_mm`` at most at ``velocity_mm_min``.

    When the distance is too short to reach the velocity, the peak velocity is
    found by bisection (the ramp distance grows monotonically with velocity).
    """
    distance_mm = abs(distance_mm)
    if distance_mm == 0.0:
        return 0.0
    full = ramp(velocity_mm_min, acceleration_m_s2, jerk_m_s3)
    if 2.0 * full.distance_mm <= distance_mm:
        return 2.0 * full.time_s + (distance_mm - 2.0 * full.distance_mm) / (velocity_mm_min / 60.0)
    low, high = 0.0, velocity_mm_min
    for _ in range(60):
        middle = 0.5 * (low + high)
        if 2.0 * ramp(middle, acceleration_m_s2, jerk_m_s3).distance_mm < distance_mm:
            low = middle
        else:
            high = middle
    return 2.0 * ramp(high, acceleration_m_s2, jerk_m_s3).time_s
