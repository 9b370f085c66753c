"""What a real feed axis has beyond its nominal model: fingerprint, drift, the drives' noise.

Off by default: a :class:`~ncmeasure.sim.machine.VirtualMachine` without a
:class:`Realism` is perfectly flat along the travel, and two runs differ only
by white noise. With one, each axis gets

* a **healthy fingerprint**, drawn once per machine (``machine_seed``) and
  fixed across its runs: assembly deviations within tolerance (radial offsets
  of bearings and nut, a rail bow, the nut's preload tolerance; the
  :class:`~ncmeasure.sim.axis.Variation` physics) and a smooth profile of the
  nut's and the carriages' friction along the travel (uneven lubricant film,
  ball-groove and rail tolerances), so a healthy axis varies by a few percent
  along the travel;
* a **run-to-run drift**, drawn per run (``seed``): the level of Coulomb and
  viscous friction (temperature, lubrication state), a small change of the
  profile along the travel, and the gain error of the drive's torque
  (current sensing, k_T with the magnet temperature);
* the **drives' noise**: the current quantised by the drive's ADC with its
  noise, the speed loop's answer to the encoder's quantised velocity, and the
  reported velocity as the encoder's position difference.

:meth:`Realism.fingerprint` and :meth:`Realism.drift` draw them; the
virtual machine puts them into each axis' :class:`~ncmeasure.sim.axis.AxisModel`
(:meth:`AxisModel.friction_map` is then the run's true friction) and keeps
what it drew in ``VirtualMachine.realised``. The numbers and their sources
are in docs/virtual-machine.md ("Realism").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np
from numpy.typing import NDArray

from ncmeasure.errors import ConfigError
from ncmeasure.sim.axis import AxisModel, Components, Condition, Profile, Variation
from ncmeasure.sim.rig import RIG_MECHANICS

__all__ = ["AxisRealism", "Drift", "Fingerprint", "Realism", "random_profile", "with_tolerance"]

FloatArray = NDArray[np.float64]

_PROFILE_MODES = 4
"""Modes of a random profile: wavelengths 2L, L, 2L/3, L/2 (L the travel)."""

_LUBRICATED = ("fixed_bearing", "loose_bearing", "nut", "guides")
"""Components whose viscous friction is the shear of oil or grease."""


def random_profile(rms: float, rng: np.random.Generator, modes: int = _PROFILE_MODES) -> Profile:
    """A smooth random :class:`~ncmeasure.sim.axis.Profile` whose expected RMS along the
    travel is ``rms``; mode ``k`` has an amplitude ∝ 1/k (low spatial frequencies dominate).

    Args:
        rms: Expected root mean square of the profile (relative).
        rng: The generator to draw from.
        modes: Number of modes.
    """
    weights = 1.0 / np.arange(1, modes + 1)
    # E[(c cos + s sin)²] over t and draws = (σ_c² + σ_s²)/2 = σ² per mode
    scale = rms / math.sqrt(float(np.sum(weights**2)))
    cos = rng.normal(0.0, 1.0, modes) * weights * scale
    sin = rng.normal(0.0, 1.0, modes) * weights * scale
    return Profile(cos=tuple(float(c) for c in cos), sin=tuple(float(s) for s in sin))


@dataclass(frozen=True)
class Fingerprint:
    """One axis' healthy fingerprint: fixed for a machine, the same in every run.

    Attributes:
        variation: Assembly deviations within tolerance (added to a fault's).
        profile: Relative profile of each component's static friction along the travel.
    """

    variation: Variation
    profile: dict[str, Profile]


@dataclass(frozen=True)
class Drift:
    """One axis' state in one run.

    Attributes:
        coulomb_factor: Level of every component's Coulomb and Stribeck friction.
        viscous_factor: Per component: level of its viscous friction.
        profile: Relative change of the static friction along the travel (every component).
        gain: Factor on the current the drive reports (1.01: reads 1 % high).
    """

    coulomb_factor: float
    viscous_factor: dict[str, float]
    profile: Profile
    gain: float


@dataclass(frozen=True)
class AxisRealism:
    """What realism gave one axis in one run: its fingerprint, its drift, and the noise."""

    fingerprint: Fingerprint
    drift: Drift
    current_lsb_a: float
    """The drive's current step (ADC resolution)."""
    current_noise_a: float
    """Standard deviation of the ADC's noise, before quantisation."""
    speed_loop_gain_nms_rad: float
    """Proportional gain of the speed loop (motor torque per screw rad/s)."""
    position_increment_mm: float
    """The encoder's increment as axis travel."""
    velocity_average_samples: int
    """Grid steps over which the reported velocity is the encoder's position difference."""

    def condition(self) -> Condition:
        """Fingerprint and drift as an :class:`~ncmeasure.sim.axis.Condition`."""
        names = [f.name for f in fields(Components)]
        profile = {
            name: self.fingerprint.profile.get(name, Profile()) + self.drift.profile
            for name in names
        }
        return Condition(
            coulomb_factor=dict.fromkeys(names, self.drift.coulomb_factor),
            viscous_factor=dict(self.drift.viscous_factor),
            profile=profile,
        )


@dataclass(frozen=True)
class Realism:
    """The sizes of fingerprint, drift and noise (the defaults: docs/virtual-machine.md).

    Fingerprint (per machine):

    Attributes:
        shift_tolerance_um: Standard deviation of each bearing's and the nut's radial
            offset from the guide line, within the assembly tolerance.
        rail_bow_tolerance_um: Standard deviation of a rail bow (its size is ``|N(0, σ)|``).
        nut_preload_tolerance: Standard deviation of the nut's preload, relative.
        nut_profile: RMS of the nut's friction profile along the travel, relative.
        guide_profile: RMS of the carriages' friction profile along the travel, relative.

    Drift (per run):

    Attributes:
        coulomb_drift: Standard deviation of the level of Coulomb and Stribeck friction.
        lubricant_viscous_drift: Standard deviation of the viscous friction of oil and
            grease (bearings, nut, guides).
        motor_viscous_drift: Standard deviation of the motor's viscous friction (iron
            losses, shaft seal).
        profile_drift: RMS of a run's change of the profile along the travel.
        gain_error: Standard deviation of the drive's torque (current) gain error.

    Noise:

    Attributes:
        current_adc_bits: Resolution of the drive's current measurement.
        current_range_factor: Its range is ± this × the axis' rated current.
        current_noise_lsb: Standard deviation of its noise, in ADC steps.
        speed_loop_hz: Bandwidth of the speed loop (its gain is ``J · 2π f``).
        encoder_increments_per_rev: Encoder increments per motor revolution.
        velocity_average_s: The reported velocity is the encoder's position difference
            over this time (at least one simulation step).
    """

    shift_tolerance_um: float = 10.0
    rail_bow_tolerance_um: float = 5.0
    nut_preload_tolerance: float = 0.15
    nut_profile: float = 0.12
    guide_profile: float = 0.08
    coulomb_drift: float = 0.02
    lubricant_viscous_drift: float = 0.10
    motor_viscous_drift: float = 0.02
    profile_drift: float = 0.0025
    gain_error: float = 0.0075
    current_adc_bits: int = 12
    current_range_factor: float = 3.0
    current_noise_lsb: float = 1.0
    speed_loop_hz: float = 100.0
    encoder_increments_per_rev: int = 2**20
    velocity_average_s: float = 0.001

    def __post_init__(self) -> None:
        bad: list[str] = []
        for f in fields(self):
            value = getattr(self, f.name)
            if not math.isfinite(value) or value < 0:
                bad.append(f"{f.name}: {value!r} must be a finite number >= 0")
        for name in ("current_range_factor", "speed_loop_hz", "velocity_average_s"):
            if getattr(self, name) <= 0:
                bad.append(f"{name}: {getattr(self, name)!r} must be > 0")
        for name in ("current_adc_bits", "encoder_increments_per_rev"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                bad.append(f"{name}: {value!r} must be a whole number >= 1")
        if self.nut_preload_tolerance >= 0.5:
            bad.append(
                f"nut_preload_tolerance: {self.nut_preload_tolerance!r} must be < 0.5 "
                "(a preload that may vanish is no tolerance)"
            )
        if bad:
            raise ConfigError("invalid realism", bad)

    def fingerprint(self, rng: np.random.Generator) -> Fingerprint:
        """Draw one axis' healthy fingerprint."""
        shifts = rng.normal(0.0, self.shift_tolerance_um, 3)
        variation = Variation(
            fixed_bearing_shift_um=float(shifts[0]),
            loose_bearing_shift_um=float(shifts[1]),
            nut_shift_um=float(shifts[2]),
            rail_misalignment_um=float(abs(rng.normal(0.0, self.rail_bow_tolerance_um))),
            nut_preload_change=float(
                np.clip(rng.normal(0.0, self.nut_preload_tolerance), -0.5, 0.5)
            ),
        )
        profile = {
            "nut": random_profile(self.nut_profile, rng),
            "guides": random_profile(self.guide_profile, rng),
        }
        return Fingerprint(variation=variation, profile=profile)

    def drift(self, rng: np.random.Generator) -> Drift:
        """Draw one axis' drift for one run."""
        coulomb = 1.0 + rng.normal(0.0, self.coulomb_drift)
        lubricant = 1.0 + rng.normal(0.0, self.lubricant_viscous_drift)
        motor = 1.0 + rng.normal(0.0, self.motor_viscous_drift)
        viscous = {"motor": _positive(motor), **dict.fromkeys(_LUBRICATED, _positive(lubricant))}
        profile = random_profile(self.profile_drift, rng)
        gain = 1.0 + rng.normal(0.0, self.gain_error)
        return Drift(
            coulomb_factor=_positive(coulomb), viscous_factor=viscous, profile=profile, gain=gain
        )

    def for_axis(
        self, model: AxisModel, fingerprint: Fingerprint, drift: Drift, dt_s: float
    ) -> AxisRealism:
        """Fingerprint, drift and the noise figures of one axis (its drive and encoder)."""
        ax = model.axis
        rated = ax.mechanics.rated_current_a or RIG_MECHANICS.rated_current_a or 1.0
        lsb = 2.0 * self.current_range_factor * rated / 2**self.current_adc_bits
        return AxisRealism(
            fingerprint=fingerprint,
            drift=drift,
            current_lsb_a=lsb,
            current_noise_a=self.current_noise_lsb * lsb,
            speed_loop_gain_nms_rad=ax.inertia_kgm2 * 2.0 * math.pi * self.speed_loop_hz,
            position_increment_mm=ax.screw_lead_mm / self.encoder_increments_per_rev,
            velocity_average_samples=max(1, round(self.velocity_average_s / dt_s)),
        )


def _positive(factor: float) -> float:
    """A drawn level factor, kept positive (a draw beyond 5 σ of 20 % would not be)."""
    return float(max(factor, 0.05))


def with_tolerance(fault: Variation, tolerance: Variation) -> Variation:
    """A fault on top of the assembly's own deviations: shifts, bow and preload changes add."""
    values = {
        f.name: getattr(fault, f.name) + getattr(tolerance, f.name)
        for f in fields(Variation)
        if f.name not in ("cover_step", "cover_step_position_mm")
    }
    return replace(fault, **values)
