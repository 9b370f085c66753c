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

:func:`s_curve` gives the whole rest-to-rest move as functions of time (the
virtual machine drives its axes with it). The ramp to the peak velocity
``v_p`` has three phases, with ``a_p = min(a, sqrt(v_p·j))``,
``T_1 = a_p/j`` and ``t_r = v_p/a_p + a_p/j``:

* ``0 ≤ τ < T_1``: jerk ``j``; ``a = jτ``, ``v = jτ²/2``, ``s = jτ³/6``;
* ``T_1 ≤ τ < t_r − T_1``: constant acceleration ``a_p``;
* ``t_r − T_1 ≤ τ ≤ t_r``: jerk ``−j``; with ``r = t_r − τ``:
  ``a = jr``, ``v = v_p − jr²/2``, ``s = v_p t_r/2 − (v_p r − jr³/6)``.

Then the cruise at ``v_p`` and the mirrored stop; a move too short to reach
the velocity limit peaks at the highest velocity whose two ramps fit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Ramp", "SCurve", "move_time_s", "ramp", "s_curve", "times_at"]

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
    return (
        2.0
        * ramp(
            _peak_velocity(distance_mm, velocity_mm_min, acceleration_m_s2, jerk_m_s3),
            acceleration_m_s2,
            jerk_m_s3,
        ).time_s
    )


def _peak_velocity(distance_mm: float, velocity_mm_min: float, a: float, j: float) -> float:
    """The highest velocity ≤ ``velocity_mm_min`` whose two ramps fit in ``distance_mm``."""
    if 2.0 * ramp(velocity_mm_min, a, j).distance_mm <= distance_mm:
        return velocity_mm_min
    low, high = 0.0, velocity_mm_min
    for _ in range(60):
        middle = 0.5 * (low + high)
        if 2.0 * ramp(middle, a, j).distance_mm < distance_mm:
            low = middle
        else:
            high = middle
    return high


@dataclass(frozen=True)
class SCurve:
    """A jerk-limited rest-to-rest move over ``distance_mm`` (see the module docstring)."""

    distance_mm: float
    peak_velocity_mm_min: float
    acceleration_m_s2: float
    """The acceleration actually reached (``a_p``)."""
    jerk_m_s3: float
    ramp_time_s: float
    cruise_time_s: float

    @property
    def duration_s(self) -> float:
        """Time from start to standstill at the target."""
        return 2.0 * self.ramp_time_s + self.cruise_time_s

    def at(
        self, time_s: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Distance travelled (mm), velocity (mm/min) and acceleration (m/s²) at ``time_s``.

        Times before the start give the start at rest, after the end the target at rest.
        """
        return _travel(
            np.asarray(time_s, dtype=np.float64),
            self.distance_mm,
            self.peak_velocity_mm_min,
            self.acceleration_m_s2,
            self.jerk_m_s3,
            self.ramp_time_s,
            self.duration_s,
        )


_Values = NDArray[np.float64] | float


def _ramp(
    tau: NDArray[np.float64], v_p_mm_min: _Values, a_p: _Values, j: _Values, t_r: _Values
) -> tuple[NDArray[np.float64], ...]:
    """Distance (m), velocity (m/s), acceleration (m/s²) at ``tau`` into the ramp.

    Every argument an array of one shape, or a number: many moves at once.
    """
    v_p = v_p_mm_min / _MM_MIN_PER_M_S
    t_1: _Values
    if np.ndim(a_p) == 0 and np.ndim(j) == 0:
        t_1 = a_p / j if j > 0 else 0.0  # one move: in Python floats, as it always was
    else:
        t_1 = np.divide(a_p, j, out=np.zeros(np.shape(j)), where=np.greater(j, 0.0))
    tau = np.clip(tau, 0.0, t_r)
    r = t_r - tau
    v_1, s_1 = j * t_1**2 / 2.0, j * t_1**3 / 6.0
    first, last = tau < t_1, r < t_1
    u = tau - t_1
    acc = np.where(first, j * tau, np.where(last, j * r, a_p))
    vel = np.where(first, j * tau**2 / 2.0, np.where(last, v_p - j * r**2 / 2.0, v_1 + a_p * u))
    dist = np.where(
        first,
        j * tau**3 / 6.0,
        np.where(
            last,
            v_p * t_r / 2.0 - (v_p * r - j * r**3 / 6.0),
            s_1 + v_1 * u + a_p * u**2 / 2.0,
        ),
    )
    return dist, vel, acc


def _travel(
    time_s: NDArray[np.float64],
    distance_mm: _Values,
    v_p_mm_min: _Values,
    a_p: _Values,
    j: _Values,
    t_r: _Values,
    total: _Values,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:meth:`SCurve.at` of one move, or of many (each argument an array of one shape)."""
    t = np.clip(time_s, 0.0, total)
    up = _ramp(t, v_p_mm_min, a_p, j, t_r)
    down = _ramp(total - t, v_p_mm_min, a_p, j, t_r)
    v_p = v_p_mm_min / _MM_MIN_PER_M_S
    length = distance_mm / 1000.0
    accelerating, braking = t < t_r, t > total - t_r
    dist = np.where(
        accelerating,
        up[0],
        np.where(braking, length - down[0], v_p * t_r / 2.0 + v_p * (t - t_r)),
    )
    vel = np.where(accelerating, up[1], np.where(braking, down[1], v_p))
    acc = np.where(accelerating, up[2], np.where(braking, -down[2], 0.0))
    return dist * 1000.0, vel * _MM_MIN_PER_M_S, acc


def times_at(curves: Sequence[SCurve], distances_mm: ArrayLike) -> NDArray[np.float64]:
    """When each move of ``curves`` has covered its distance of ``distances_mm``.

    Bisection (the distance only grows) of every move at once, 50 halvings of
    its duration.
    """

    def field(name: str) -> NDArray[np.float64]:
        return np.array([getattr(c, name) for c in curves], dtype=np.float64)

    wanted = np.asarray(distances_mm, dtype=np.float64)
    params = (
        field("distance_mm"),
        field("peak_velocity_mm_min"),
        field("acceleration_m_s2"),
        field("jerk_m_s3"),
        field("ramp_time_s"),
    )
    total = np.array([c.duration_s for c in curves], dtype=np.float64)
    low, high = np.zeros(total.shape), total.copy()
    for _ in range(50):
        middle = 0.5 * (low + high)
        short = _travel(middle, *params, total)[0] < wanted
        low = np.where(short, middle, low)
        high = np.where(short, high, middle)
    return high


def s_curve(
    distance_mm: float, velocity_mm_min: float, acceleration_m_s2: float, jerk_m_s3: float
) -> SCurve:
    """The jerk-limited move over ``distance_mm`` (≥ 0) at most at ``velocity_mm_min``."""
    distance_mm = abs(distance_mm)
    if distance_mm == 0.0 or velocity_mm_min <= 0.0:
        return SCurve(distance_mm, 0.0, 0.0, jerk_m_s3, 0.0, 0.0)
    peak = _peak_velocity(distance_mm, velocity_mm_min, acceleration_m_s2, jerk_m_s3)
    up = ramp(peak, acceleration_m_s2, jerk_m_s3)
    v = peak / _MM_MIN_PER_M_S
    a_p = min(acceleration_m_s2, math.sqrt(v * jerk_m_s3))
    cruise = max(0.0, (distance_mm - 2.0 * up.distance_mm) / (peak / 60.0))
    return SCurve(distance_mm, peak, a_p, jerk_m_s3, up.time_s, cruise)
