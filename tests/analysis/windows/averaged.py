"""Captures of a drive's averaged velocity: correlated noise, in counts, at 6.4 to 256 ms.

A maxon EPOS2 reports "velocity actual value averaged" in 1-rpm counts of the
motor; through a ball screw one count is the screw lead in mm/min. At steady
speed the readings scatter by 1 to 2 % of the speed with a lag-1
autocorrelation of 0.72 to 0.87 (the drive's moving average), and the current
moves with that ripple (the speed controller answers it). Each capture is one
speed in one direction: standstill, a ramp, 500 samples at speed, a ramp down.
Captures follow one another in one recording, as an import of one file per
capture gives them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

LEAD_MM: float = 2.0
"""Screw lead: one 1-rpm count of the motor is this many mm/min."""
SPEEDS_MM_MIN: tuple[float, ...] = (100.0, 200.0, 500.0, 1000.0, 2000.0)
COULOMB_A: float = 0.40
VISCOUS_A_PER_MM_MIN: float = 0.0002
SCATTER: float = 0.015
"""Steady-speed scatter of the readings, a fraction of the speed."""
RHO: float = 0.8
"""Lag-1 autocorrelation of the scatter."""
CAPTURE_SAMPLES: int = 500
RIPPLE_GAIN: float = 2.0
"""Relative current change per relative velocity ripple (the controller's answer)."""


@dataclass(frozen=True)
class Captures:
    time_s: FloatArray
    velocity_mm_min: FloatArray
    current_a: FloatArray
    command_mm_min: FloatArray
    speeds_mm_min: tuple[float, ...]
    """Every capture's signed commanded speed, in recording order."""

    def truth_a(self, speed_mm_min: float) -> float:
        """The friction current at a signed speed."""
        return float(np.sign(speed_mm_min) * (COULOMB_A + VISCOUS_A_PER_MM_MIN * abs(speed_mm_min)))


def captures(
    dt_s: float,
    *,
    seed: int = 0,
    speeds_mm_min: tuple[float, ...] = SPEEDS_MM_MIN,
    scatter: float = SCATTER,
    rho: float = RHO,
) -> Captures:
    """Every speed in both directions, one 500-sample capture each, back to back."""
    rng = np.random.default_rng(seed)
    signed = [s * d for s in speeds_mm_min for d in (1.0, -1.0)]
    velocity: list[FloatArray] = []
    current: list[FloatArray] = []
    command: list[FloatArray] = []
    acceleration = 6000.0  # mm/min per s
    for speed in signed:
        still = np.zeros(10)
        ramp_n = max(2, int(np.ceil(abs(speed) / acceleration / dt_s)))
        ramp = speed * np.arange(1, ramp_n + 1) / ramp_n
        noise = np.empty(CAPTURE_SAMPLES)
        noise[0] = rng.normal()
        innovations = rng.normal(size=CAPTURE_SAMPLES) * np.sqrt(1 - rho**2)
        for k in range(1, CAPTURE_SAMPLES):
            noise[k] = rho * noise[k - 1] + innovations[k]
        ripple = scatter * abs(speed) * noise
        steady = speed + ripple
        true_v = np.concatenate((still, ramp, steady, ramp[::-1][1:], still))
        cmd = np.concatenate((still, ramp, np.full(CAPTURE_SAMPLES, speed), ramp[::-1][1:], still))
        level = np.sign(speed) * (COULOMB_A + VISCOUS_A_PER_MM_MIN * abs(speed))
        i_steady = level * (1.0 + RIPPLE_GAIN * ripple / speed)
        amps = np.concatenate(
            (
                np.zeros(len(still)),
                np.full(len(ramp), 1.5 * level),
                i_steady,
                np.full(len(ramp) - 1, 0.5 * level),
                np.zeros(len(still)),
            )
        )
        amps = amps + rng.normal(scale=0.005, size=len(amps))
        velocity.append(LEAD_MM * np.round(true_v / LEAD_MM))
        current.append(amps)
        command.append(cmd)
    v = np.concatenate(velocity)
    t = dt_s * np.arange(len(v))
    return Captures(t, v, np.concatenate(current), np.concatenate(command), tuple(signed))
