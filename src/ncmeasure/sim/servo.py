"""The servo loop of a simulated axis: how the actual motion follows the command.

A second-order low pass ``H(s) = ω² / (s² + 2ζω s + ω²)`` (natural frequency
``ω = 2π f``, damping ``ζ``), discretised by the bilinear transform: the axis
lags during ramps, overshoots after them when ``ζ < 1``, and trails a
constant-velocity command by the following error ``v · 2ζ/ω``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.signal import cont2discrete, lfilter, lfilter_zi

__all__ = ["follow", "servo"]

FloatArray = NDArray[np.float64]


def servo(dt: float, frequency_hz: float, damping: float) -> tuple[FloatArray, FloatArray]:
    """Filter coefficients ``(b, a)`` of the loop for time step ``dt``."""
    omega = 2 * math.pi * frequency_hz
    num, den, _ = cont2discrete(
        ([omega**2], [1.0, 2 * damping * omega, omega**2]), dt, method="bilinear"
    )
    return np.asarray(num, dtype=np.float64).ravel(), np.asarray(den, dtype=np.float64)


def follow(b: FloatArray, a: FloatArray, command: FloatArray) -> FloatArray:
    """The loop's response to ``command``, starting at rest at its first value."""
    if len(command) == 0:
        return command
    zi = lfilter_zi(b, a) * command[0]
    out, _ = lfilter(b, a, command, zi=zi)
    return np.asarray(out, dtype=np.float64)
