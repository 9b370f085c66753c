"""A robot joint's constant-velocity friction test: one file per run, both directions.

The properties are those of a published kind of test on an industrial robot's
joint (harmonic drive, motor encoder, joint torque): each run drives the joint
at one commanded velocity over part of its range (at most a few seconds at
speed), stops, and the next run drives back; 20 speeds from about 0.01 rad/s
upwards, each in both directions, 40 runs. The files hold time, joint
position [rad], velocity [rad/s] derived from the encoder, commanded velocity
and joint torque [Nm].

What makes it hard, and is real:

- the velocity at the slow runs scatters by 10 to 40 % of the speed: white
  encoder-difference noise on top of the speed loop's correlated wobble
  (about 20 ms), which the position loop keeps bounded (the joint stays on its
  path, so the mean speed of a run is the commanded one);
- friction differs between the directions (Coulomb +8.0 / −7.2 Nm on one
  joint, +2.1 / −2.4 Nm on the other) and rises towards standstill
  (Stribeck);
- 1 kHz and 500 Hz sampling.

Made up: the exact figures, and the position-periodic torque ripple of the
gear (amplitude and period).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

FloatArray = NDArray[np.float64]

#: rad/s -> the unit the analysis counts in ("mm/min" of a linear axis: deg/min here)
DEG_MIN_PER_RAD_S: float = 180.0 / np.pi * 60.0
DEG_PER_RAD: float = 180.0 / np.pi


@dataclass(frozen=True)
class Joint:
    name: str
    speeds_rad_s: tuple[float, ...]
    coulomb_positive_nm: float
    coulomb_negative_nm: float
    viscous_nm_s_rad: float
    stribeck_rise_nm: float
    stribeck_velocity_rad_s: float
    dt_s: float

    def coulomb_nm(self, direction: int) -> float:
        return self.coulomb_positive_nm if direction > 0 else self.coulomb_negative_nm


SHOULDER = Joint(
    name="shoulder",
    speeds_rad_s=tuple(float(v) for v in np.round(np.geomspace(0.01, 1.0, 20), 4)),
    coulomb_positive_nm=8.0,
    coulomb_negative_nm=7.2,
    viscous_nm_s_rad=12.0,
    stribeck_rise_nm=1.5,
    stribeck_velocity_rad_s=0.02,
    dt_s=0.001,
)
WRIST = Joint(
    name="wrist",
    speeds_rad_s=tuple(float(v) for v in np.round(np.geomspace(0.005, 0.5, 20), 4)),
    coulomb_positive_nm=2.1,
    coulomb_negative_nm=2.4,
    viscous_nm_s_rad=6.0,
    stribeck_rise_nm=0.4,
    stribeck_velocity_rad_s=0.01,
    dt_s=0.002,
)

HOLD_S = 3.0
"""Longest time at speed in a run (a slow run covers only part of the range)."""
RANGE_RAD = 2.0
ACCELERATION_RAD_S2 = 2.0
VELOCITY_QUANTUM_RAD_S = 2e-4
WOBBLE_RELATIVE = 0.01
WOBBLE_ABSOLUTE_RAD_S = 0.002
WOBBLE_CORRELATION_S = 0.02
TORQUE_NOISE_NM = 0.15
RIPPLE_NM = 0.1
RIPPLE_PERIOD_RAD = 2 * np.pi / 200  # two per turn of a 100:1 gear's wave generator


def _ar1(rng: np.random.Generator, n: int, a: float) -> FloatArray:
    return np.asarray(lfilter([1.0], [1.0, -a], rng.normal(size=n)), dtype=np.float64)


def write_runs(joint: Joint, folder: Path, *, seed: int = 0) -> list[float]:
    """One CSV file per run into ``folder``; the runs' signed speeds [rad/s] in order."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    dt = joint.dt_s
    q = -RANGE_RAD / 2
    signed = [s * d for s in joint.speeds_rad_s for d in (1.0, -1.0)]
    for k, v in enumerate(signed):
        speed = abs(v)
        cruise = min(HOLD_S, RANGE_RAD / speed)
        ramp_n = max(2, int(np.ceil(speed / ACCELERATION_RAD_S2 / dt)))
        still = np.zeros(int(0.5 / dt))
        ramp = v * np.arange(1, ramp_n + 1) / ramp_n
        command = np.concatenate((still, ramp, np.full(int(cruise / dt), v), ramp[::-1][1:], still))
        n = len(command)
        # The speed loop's wobble: the rate of a bounded, correlated position error.
        wobble = np.gradient(_ar1(rng, n, float(np.exp(-dt / WOBBLE_CORRELATION_S))), dt)
        wobble /= wobble.std()
        amplitude = WOBBLE_RELATIVE * np.abs(command) + WOBBLE_ABSOLUTE_RAD_S * (command != 0)
        amplitude = np.convolve(amplitude, np.ones(25) / 25, mode="same")
        velocity = command + amplitude * wobble
        position = q + np.cumsum(velocity) * dt
        q = float(position[-1])
        readings = velocity + rng.normal(0.0, WOBBLE_ABSOLUTE_RAD_S / 3, n)
        readings = VELOCITY_QUANTUM_RAD_S * np.round(readings / VELOCITY_QUANTUM_RAD_S)
        direction = np.sign(velocity)
        coulomb = np.where(direction > 0, joint.coulomb_positive_nm, joint.coulomb_negative_nm)
        hump = joint.stribeck_rise_nm * np.exp(-((velocity / joint.stribeck_velocity_rad_s) ** 2))
        friction = direction * (coulomb + hump) + joint.viscous_nm_s_rad * velocity
        inertia = 0.4 * np.gradient(velocity, dt)
        ripple = RIPPLE_NM * np.sin(2 * np.pi * position / RIPPLE_PERIOD_RAD)
        torque = friction + inertia + ripple + rng.normal(0.0, TORQUE_NOISE_NM, n)
        time = np.arange(n) * dt
        table = np.column_stack((time, position, readings, command, torque))
        name = folder / f"run{k:02d}_{'pos' if v > 0 else 'neg'}_{speed:.4f}.csv"
        np.savetxt(
            name, table, delimiter=",", fmt="%.7g", header="time,q,dq,dq_cmd,tau", comments=""
        )
    return signed


def column_map(path: Path, *, command: bool, degrees: bool = True) -> Path:
    """The column map of the runs: radians as degrees (the analysis' unit of a rotary
    axis), or as they are (``degrees=False``: rad/s read where mm/min are expected)."""
    position = f", scale = {DEG_PER_RAD!r}" if degrees else ""
    velocity = f", scale = {DEG_MIN_PER_RAD_S!r}" if degrees else ""
    lines = [
        'time = { column = "time" }',
        "[channels]",
        f'J_position_mm = {{ column = "q"{position} }}',
        f'J_velocity_mm_min = {{ column = "dq"{velocity} }}',
        'J_current_a = { column = "tau" }',
    ]
    if command:
        lines.append(f'J_velocity_cmd_mm_min = {{ column = "dq_cmd"{velocity} }}')
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
