"""The physical friction model of one ball-screw feed axis (pure numpy, no I/O).

An :class:`AxisModel` says which friction torque, and which motor current, a
feed axis shows at a position and velocity. The drive train is split into the
components of the method's test rig: motor, fixed bearing, loose bearing,
ball-screw nut, guide carriages and covers. Each component has Coulomb,
viscous and Stribeck friction, expressed as torque on the screw (= motor)
shaft, and each splits its Coulomb and Stribeck part into a load-independent
share (seals, lubricant) and a share proportional to the normal force in its
rolling contacts (``F_R = μ F_N``, as torque ``T = (μ r) F_N``). The defaults
are the rig's identified values (method, "Reference numbers"), so the
components add up to the measured total.

Assembly variances (:class:`Variation`) change the normal forces:

* preload changes (bearings, nut, carriages) scale the nominal normal force:
  a constant offset along the travel;
* a radial shift of a bearing or of the nut bends the screw spindle. The
  nut, held by its carriage on the guides, is a moving support that clamps
  the screw (position and slope) to the guide line; it splits the screw into
  the span ``a`` to the fixed bearing and the span ``b = L − a`` to the loose
  bearing. A support misaligned by ``δ`` against the nut at the end of a span
  ``ℓ`` loads that span like a cantilever with a tip load (Euler–Bernoulli
  beam, Gere & Goodno, Mechanics of Materials, App. G, table G-1 case 4;
  Roark's Formulas for Stress and Strain, 8th ed., Table 8.1 case 1a with
  the load at the free end):

      δ = F ℓ³ / (3 E I)   →   k_beam(ℓ) = 3 E I / ℓ³,   I = π d_core⁴ / 64

  in series with the lateral contact and housing compliance ``1/k_s`` of the
  support chain (bearing housing on its joint, nut flange, carriage):

      F_fixed = (δ_F − δ_N) / (a³/(3EI) + 1/k_s)
      F_loose = (δ_L − δ_N) / (b³/(3EI) + 1/k_s)

  The bearings see ``|F_fixed|`` and ``|F_loose|``, the nut their sum. The
  closer the nut is to a misaligned support, the shorter and stiffer the
  path and the larger the force. This reproduces the test rig: a shifted
  loose bearing loads only span ``b``, which is long and soft next to the
  fixed bearing (no change there) and stiffens towards the loose bearing,
  where ``1/k_s`` caps it, so the rise is gradual, not a jump in the last
  interval; a shifted nut loads both spans, so friction rises next to both
  bearings and is lowest mid-travel, where both spans are long. Each
  component turns its constraining force into friction with its own
  per-newton coefficient (:attr:`Component.constraint_torque_per_newton_nm`),
  which differs from the preload coefficient where the force meets the
  rolling contacts at another angle (a radial load on a 60° support bearing).
  The default ``k_s`` (2.2 N/µm) is calibrated to the rig's shapes and
  sizes, not measured. Not modelled: the bending moment carried by the nut
  and by the fixed bearing pair (its spacing is unknown), and the clamping
  by the fixed bearing's tilt stiffness (``12EI/a³`` instead of ``3EI/a³``),
  which would make the fixed span stiffer mid-travel.
* a bowed guide rail (deviation ``δ · 4t(1 − t)``: 0 at both travel ends,
  ``rail_misalignment_um`` mid-travel) presses the carriages against their
  preload with the constraint stiffness of table and carriages: the guide
  friction follows the bow and peaks mid-travel;
* a sticking cover adds a step of ``cover_step`` × the axis' nominal
  friction beyond a position (default 40 % of the travel from its minimum:
  between two measuring positions for 3 or 5 evenly spaced ones, so no
  window straddles the step).

:data:`EXAMPLE_VARIATIONS` holds one variation per assembly cause, of a size
the analysis recognises on the rig axis.

A :class:`Condition` holds what a well-assembled axis has on top of its
components' nominal values: the level of each component's Coulomb and
viscous friction (temperature, lubrication) and a smooth relative profile of
its static friction along the travel (:class:`Profile`: uneven lubricant
film, preload tolerance of nut and carriages). Without one (the default) the
components are exactly their nominal selves; :mod:`ncmeasure.sim.realism`
draws conditions for a machine and a run.

The motor current is ``(friction + J α + gravity) / k_T`` plus cogging
ripple (3 and 18 periods per motor revolution), optional Gaussian noise and
rare outliers. Units are in the names: positions in mm, velocities in
mm/min, accelerations in m/s², torques in Nm, forces in N.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ncmeasure.config import AxisConfig, parse_assignments
from ncmeasure.errors import ConfigError
from ncmeasure.formats.axis import StatedMechanics
from ncmeasure.sim.rig import RIG_MECHANICS, rig_mechanics

__all__ = [
    "EXAMPLE_VARIATIONS",
    "AxisModel",
    "AxisParameters",
    "Component",
    "Components",
    "Condition",
    "Profile",
    "Variation",
    "default_components",
    "parse_variation",
]

FloatArray = NDArray[np.float64]

_G_M_S2 = 9.81
_STEEL_DENSITY_KG_M3 = 7850.0


def _omega_rad_s(velocity_mm_min: FloatArray, lead_mm: float) -> FloatArray:
    """Screw angular velocity for an axis velocity."""
    return np.asarray(2.0 * math.pi * velocity_mm_min / (60.0 * lead_mm), dtype=np.float64)


@dataclass(frozen=True)
class Component:
    """Friction of one drive-train component, as torque on the screw shaft.

    Attributes:
        coulomb_nm: Coulomb friction torque at nominal load.
        viscous_nms_rad: Viscous friction per screw angular velocity.
        stribeck_nm: Extra torque at standstill, decaying as ``exp(−|v|/v_S)``.
        stribeck_velocity_mm_min: Stribeck velocity (axis velocity).
        load_share: Share of Coulomb and Stribeck torque proportional to the
            normal force (the rest is load-independent: seals, lubricant).
        torque_per_newton_nm: Friction torque per newton of preload (``μ`` times
            the effective radius; for a linear guide ``μ h / 2π``). It fixes the
            nominal preload force that carries ``load_share``.
        constraint_torque_per_newton_nm: Friction torque per newton of
            constraining force from an assembly variation (the radial load a bent
            screw puts on a bearing or the nut, the lateral load a bowed rail puts
            on the carriages). ``None``: the same as ``torque_per_newton_nm``. It
            differs where the constraining force meets the rolling contacts at
            another angle than the preload does.
    """

    coulomb_nm: float
    viscous_nms_rad: float
    stribeck_nm: float = 0.0
    stribeck_velocity_mm_min: float = 300.0
    load_share: float = 0.0
    torque_per_newton_nm: float = 0.0
    constraint_torque_per_newton_nm: float | None = None

    def __post_init__(self) -> None:
        checks = {
            "coulomb_nm": self.coulomb_nm >= 0,
            "viscous_nms_rad": self.viscous_nms_rad >= 0,
            "stribeck_nm": self.stribeck_nm >= 0,
            "stribeck_velocity_mm_min": self.stribeck_velocity_mm_min > 0,
            "load_share": 0 <= self.load_share <= 1,
            "torque_per_newton_nm": self.torque_per_newton_nm >= 0,
            "constraint_torque_per_newton_nm": self.constraint_torque_per_newton_nm is None
            or self.constraint_torque_per_newton_nm >= 0,
        }
        bad = [
            f"{key}: {getattr(self, key)!r} is out of range" for key, ok in checks.items() if not ok
        ]
        if self.load_share > 0 and self.torque_per_newton_nm == 0:
            bad.append("torque_per_newton_nm: must be > 0 when load_share > 0")
        if bad:
            raise ConfigError("invalid friction component", bad)

    @property
    def nominal_normal_force_n(self) -> float:
        """The preload normal force that carries the load-dependent share."""
        if self.torque_per_newton_nm == 0:
            return 0.0
        return self.load_share * self.coulomb_nm / self.torque_per_newton_nm

    @property
    def constraint_coefficient_nm_per_n(self) -> float:
        """Friction torque per newton of constraining force (the fallback resolved)."""
        if self.constraint_torque_per_newton_nm is None:
            return self.torque_per_newton_nm
        return self.constraint_torque_per_newton_nm


def _component(
    coulomb: float,
    viscous: float,
    load_share: float,
    per_n: float,
    constraint_per_n: float | None = None,
) -> Component:
    return Component(
        coulomb_nm=coulomb,
        viscous_nms_rad=viscous,
        stribeck_nm=0.3 * coulomb,
        load_share=load_share,
        torque_per_newton_nm=per_n,
        constraint_torque_per_newton_nm=constraint_per_n,
    )


# Per-newton friction of the rolling contacts, as torque on the screw shaft.
#
# Bearings: angular-contact ball bearing, μ ≈ 0.002 at a 20 mm effective
# radius (SKF's simplified friction moment M = μ P d / 2 with μ = 0.002 for
# angular-contact ball bearings): 4·10⁻⁵ Nm/N of axial preload. A radial load
# meets the balls of a 60° screw-support bearing at the wrong angle: it raises
# the sum of the contact forces by F_r / (J cos α) with J ≈ 0.8 (a half load
# zone with the Hertz exponent 1.5: ∫cos^2.5 ψ / ∫cos^1.5 ψ), an axial load by
# F_a / sin α, so per newton a radial load counts tan 60° / 0.8 ≈ 2.2 times.
# The rig's loose bearing (type not given; it has the same friction) is taken
# alike.
_BEARING_PRELOAD_NM_PER_N = 4.0e-5
_BEARING_RADIAL_NM_PER_N = 2.2 * _BEARING_PRELOAD_NM_PER_N
# Nut: the preload drag torque of the ball-screw catalogues (JIS B 1192,
# e.g. THK's "preload torque"), T_p = 0.05 (tan β)^−0.5 · F_a0 · h / 2π, with
# tan β = h / (π d) = 20 / (π 40) for the rig's screw: 4.0·10⁻⁴ Nm/N. The
# rig's 0.25 Nm at load share 0.7 then means a preload of ≈ 440 N, a light
# preload for a 40 × 20 nut. A radial load on the 45° ball contacts raises
# the contact forces by about as much per newton (sin 45° = cos 45°), so the
# constraint coefficient is taken equal; not measured.
_NUT_NM_PER_N = 0.05 / math.sqrt(20.0 / (math.pi * 40.0)) * 20e-3 / (2 * math.pi)
# Guides: μ ≈ 0.003 for ball rail guides (catalogue range 0.002–0.005), as
# screw torque times h / 2π = 3.18 mm. A lateral load on a four-row 45°
# carriage is taken alike.
_GUIDE_NM_PER_N = 0.003 * 20e-3 / (2 * math.pi)


@dataclass(frozen=True)
class Components:
    """The friction components of one feed axis (defaults: the method's test rig).

    Coulomb and viscous values are the rig's identified ones (method, "Reference
    numbers"); load shares and per-newton coefficients are explained next to
    their constants above.
    """

    motor: Component = field(default_factory=lambda: _component(0.72, 0.05, 0.0, 0.0))
    fixed_bearing: Component = field(
        default_factory=lambda: _component(
            0.09, 0.00048, 0.6, _BEARING_PRELOAD_NM_PER_N, _BEARING_RADIAL_NM_PER_N
        )
    )
    loose_bearing: Component = field(
        default_factory=lambda: _component(
            0.09, 0.00048, 0.6, _BEARING_PRELOAD_NM_PER_N, _BEARING_RADIAL_NM_PER_N
        )
    )
    nut: Component = field(default_factory=lambda: _component(0.25, 0.00019, 0.7, _NUT_NM_PER_N))
    guides: Component = field(
        default_factory=lambda: _component(0.205, 0.000014, 0.8, _GUIDE_NM_PER_N)
    )
    covers: Component = field(default_factory=lambda: Component(0.0, 0.0))

    def items(self) -> tuple[tuple[str, Component], ...]:
        """``(name, component)`` pairs in drive-train order."""
        return tuple((f.name, getattr(self, f.name)) for f in fields(self))

    @property
    def coulomb_nm(self) -> float:
        """Sum of the components' Coulomb torques."""
        return sum(c.coulomb_nm for _, c in self.items())

    @property
    def viscous_nms_rad(self) -> float:
        """Sum of the components' viscous coefficients."""
        return sum(c.viscous_nms_rad for _, c in self.items())


def default_components() -> Components:
    """The component friction identified on the method's test rig."""
    return Components()


@dataclass(frozen=True)
class AxisParameters:
    """Geometry, drive and disturbance data of one axis.

    Attributes:
        mechanics: The axis' mechanical facts (default: the method's test rig,
            :data:`~ncmeasure.sim.rig.RIG_MECHANICS`). The model uses the
            travel (the nut centre sweeps it), the fixed-bearing end,
            ``vertical`` (gravity acts on the motor torque, positive direction
            up), the torque constant k_T and the lead (axis travel per screw
            revolution); k_T and the lead must be stated.
        screw_diameter_mm: Nominal screw diameter (for the screw inertia).
        screw_core_diameter_mm: Core diameter (for the bending stiffness).
        bearing_clearance_mm: Distance of each bearing from the nearest travel
            end of the nut centre; the span is travel + 2 × this.
        youngs_modulus_gpa: Young's modulus of the screw.
        support_stiffness_n_per_um: Lateral stiffness of the support chain in
            series with the screw's bending (bearing housing on its joint, nut
            flange, carriage). Default 2.2 N/µm: calibrated so that a 500 µm
            shim under the rig's loose bearing raises friction next to it by
            ≈ 30 % and a shifted nut gives a mid-travel change of ≈ 1/3 of
            the change next to the bearings; not measured. It is far below the
            catalogue stiffness of a support bearing (hundreds of N/µm): it
            stands for the bolted joints and brackets in the chain, and a stiffer
            value turns the rise towards a shifted bearing into a sharp jump in
            the last interval (cubic beam term).
        guide_stiffness_n_per_um: Lateral constraint stiffness of table and
            carriages against a bowed rail. Default 500 N/µm: preloaded size
            30–35 ball carriages are several hundred N/µm each; the two carriages
            on the bowed rail push the table against the two on the straight rail,
            in series with table and joints. Calibrated so that a 50 µm bow
            (beyond the parallelism that rail catalogues permit for preloaded
            carriages, ≈ 10–30 µm) raises friction mid-travel by ≈ 14 %; not
            measured.
        moved_mass_kg: Table and workpiece mass.
        rotor_inertia_kgm2: Motor rotor inertia (incl. coupling).
        cogging_3_nm: Cogging amplitude, 3 periods per revolution.
        cogging_18_nm: Cogging amplitude, 18 periods per revolution.
        noise_a: Standard deviation of the current noise (with an ``rng``).
        outlier_rate: Share of samples that are outliers (with an ``rng``).
        outlier_a: Size of an outlier.
        regularisation_mm_min: Velocity over which the friction sign turns
            smoothly (tanh), so the model has no jump at standstill.
    """

    mechanics: StatedMechanics = RIG_MECHANICS
    screw_diameter_mm: float = 40.0
    screw_core_diameter_mm: float = 34.0
    bearing_clearance_mm: float = 80.0
    youngs_modulus_gpa: float = 210.0
    support_stiffness_n_per_um: float = 2.2
    guide_stiffness_n_per_um: float = 500.0
    moved_mass_kg: float = 500.0
    rotor_inertia_kgm2: float = 0.0193
    cogging_3_nm: float = 0.06
    cogging_18_nm: float = 0.03
    noise_a: float = 0.02
    outlier_rate: float = 1e-3
    outlier_a: float = 2.0
    regularisation_mm_min: float = 1.0

    def __post_init__(self) -> None:
        low, high = self.mechanics.travel_mm
        stated = {
            "torque_constant_nm_per_a": self.mechanics.torque_constant_nm_per_a,
            "screw_lead_mm": self.mechanics.screw_lead_mm,
        }
        positive = (
            "screw_diameter_mm",
            "screw_core_diameter_mm",
            "youngs_modulus_gpa",
            "support_stiffness_n_per_um",
            "guide_stiffness_n_per_um",
            "regularisation_mm_min",
        )
        non_negative = (
            "bearing_clearance_mm",
            "moved_mass_kg",
            "rotor_inertia_kgm2",
            "cogging_3_nm",
            "cogging_18_nm",
            "noise_a",
            "outlier_a",
        )
        values = {**stated, **{key: getattr(self, key) for key in positive}}
        bad = [
            f"{key}: {value!r} must be > 0"
            for key, value in values.items()
            if value is None or not value > 0
        ]
        bad += [
            f"{key}: {getattr(self, key)!r} must be >= 0"
            for key in non_negative
            if not getattr(self, key) >= 0
        ]
        if not low < high:
            bad.append(f"travel_mm: min ({low:g}) must be below max ({high:g})")
        if not 0 <= self.outlier_rate <= 1:
            bad.append(f"outlier_rate: {self.outlier_rate!r} must be in [0, 1]")
        if bad:
            raise ConfigError("invalid axis parameters", bad)

    @classmethod
    def from_config(cls, axis: AxisConfig, **overrides: object) -> AxisParameters:
        """Parameters for a configured axis; mechanical facts it leaves unstated keep the
        rig's values, and ``overrides`` replace the rig's physics (``moved_mass_kg=300``)."""
        return replace(cls(mechanics=rig_mechanics(axis.mechanics())), **overrides)  # type: ignore[arg-type]

    @property
    def torque_constant_nm_per_a(self) -> float:
        """The mechanics' torque constant k_T."""
        value = self.mechanics.torque_constant_nm_per_a
        assert value is not None  # stated: __post_init__ refuses None
        return value

    @property
    def screw_lead_mm(self) -> float:
        """The mechanics' lead."""
        value = self.mechanics.screw_lead_mm
        assert value is not None  # stated: __post_init__ refuses None
        return value

    @property
    def span_mm(self) -> float:
        """Distance between fixed and loose bearing."""
        low, high = self.mechanics.travel_mm
        return high - low + 2 * self.bearing_clearance_mm

    @property
    def bending_stiffness_nm2(self) -> float:
        """E I of the screw core."""
        d_m = self.screw_core_diameter_mm / 1000.0
        return self.youngs_modulus_gpa * 1e9 * math.pi * d_m**4 / 64.0

    @property
    def inertia_kgm2(self) -> float:
        """Total inertia at the motor: rotor + screw + moved mass through the lead."""
        d_m = self.screw_diameter_mm / 1000.0
        screw = math.pi * _STEEL_DENSITY_KG_M3 * (self.span_mm / 1000.0) * d_m**4 / 32.0
        lever_m = self.screw_lead_mm / 1000.0 / (2 * math.pi)
        return self.rotor_inertia_kgm2 + screw + self.moved_mass_kg * lever_m**2

    @property
    def gravity_torque_nm(self) -> float:
        """Motor torque holding the moved mass on a vertical axis (0 if horizontal)."""
        if not self.mechanics.vertical:
            return 0.0
        return self.moved_mass_kg * _G_M_S2 * self.screw_lead_mm / 1000.0 / (2 * math.pi)


@dataclass(frozen=True)
class Profile:
    """A smooth relative change along the travel: ``Σ_k c_k cos(πkt) + s_k sin(πkt)``.

    ``t`` runs from 0 at the travel's minimum to 1 at its maximum, so mode ``k``
    has the wavelength ``2 L / k`` (L the travel): a few modes give a profile
    of low spatial frequencies only. Profiles add coefficient by coefficient.

    Attributes:
        cos: ``c_1, c_2, ...`` (relative, 0.01 = 1 %).
        sin: ``s_1, s_2, ...``, as many as ``cos``.
    """

    cos: tuple[float, ...] = ()
    sin: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if len(self.cos) != len(self.sin):
            raise ConfigError(
                "invalid profile",
                [f"cos, sin: {len(self.cos)} and {len(self.sin)} coefficients, must be as many"],
            )
        if not all(math.isfinite(c) for c in (*self.cos, *self.sin)):
            raise ConfigError("invalid profile", ["cos, sin: a coefficient is not finite"])

    def __add__(self, other: Profile) -> Profile:
        n = max(len(self.cos), len(other.cos))

        def padded(values: tuple[float, ...]) -> NDArray[np.float64]:
            return np.pad(np.asarray(values, dtype=np.float64), (0, n - len(values)))

        return Profile(
            cos=tuple(float(c) for c in padded(self.cos) + padded(other.cos)),
            sin=tuple(float(c) for c in padded(self.sin) + padded(other.sin)),
        )

    def at(self, t: ArrayLike) -> FloatArray:
        """The relative change at relative positions ``t`` (0..1 over the travel)."""
        t = np.asarray(t, dtype=np.float64)
        value = np.zeros_like(t)
        for k, (c, s) in enumerate(zip(self.cos, self.sin, strict=True), start=1):
            value = value + c * np.cos(math.pi * k * t) + s * np.sin(math.pi * k * t)
        return np.asarray(value, dtype=np.float64)


@dataclass(frozen=True)
class Condition:
    """How an axis' friction departs from its components' nominal values.

    Keys are component names (``motor``, ``fixed_bearing``, ``loose_bearing``,
    ``nut``, ``guides``, ``covers``); a component not named keeps its nominal
    value. The default condition changes nothing.

    Attributes:
        coulomb_factor: Factor on a component's Coulomb and Stribeck friction
            (its level: lubricant state, temperature).
        viscous_factor: Factor on a component's viscous coefficient (the oil's
            viscosity, the motor's iron losses).
        profile: Relative change of a component's Coulomb and Stribeck friction
            along the travel, ``× (1 + profile(t))``.
    """

    coulomb_factor: Mapping[str, float] = field(default_factory=dict)
    viscous_factor: Mapping[str, float] = field(default_factory=dict)
    profile: Mapping[str, Profile] = field(default_factory=dict)

    def __post_init__(self) -> None:
        known = {f.name for f in fields(Components)}
        bad = [
            f"{part}.{name}: not a component (known: {', '.join(sorted(known))})"
            for part in ("coulomb_factor", "viscous_factor", "profile")
            for name in getattr(self, part)
            if name not in known
        ]
        bad += [
            f"{part}.{name}: {value!r} must be > 0"
            for part in ("coulomb_factor", "viscous_factor")
            for name, value in getattr(self, part).items()
            if not (math.isfinite(value) and value > 0)
        ]
        if bad:
            raise ConfigError("invalid axis condition", bad)


COVER_STEP_DEFAULT = 0.4
"""Default place of a cover step, as a fraction of the travel from its minimum.

Not mid-travel: with 3 or 5 evenly spaced measuring positions a window sits
at mid-travel, and a step inside a window is half in, half out.
"""


@dataclass(frozen=True)
class Variation:
    """Assembly variances of one axis (all zero: a well-assembled axis).

    Attributes:
        fixed_bearing_shift_um: Radial shift of the fixed bearing.
        loose_bearing_shift_um: Radial shift of the loose bearing.
        nut_shift_um: Radial shift of the nut against its carriage.
        bearing_preload_change: Relative change of both bearings' preload (−0.6 = −60 %).
        nut_preload_change: Relative change of the nut preload.
        carriage_preload_change: Relative change of the carriages' preload.
        rail_misalignment_um: Bow of a guide rail: its lateral deviation is 0 at
            both travel ends and this value mid-travel, ``δ · 4t(1 − t)`` with
            ``t`` the relative position. It presses the carriages against their
            preload, so guide friction peaks mid-travel (a ramp would look like a
            shifted bearing to the analysis). The sign does not matter.
        cover_step: Friction step of a sticking cover, relative to the axis'
            nominal friction (0.2 = a 20 % step).
        cover_step_position_mm: Where the step occurs (default: :data:`COVER_STEP_DEFAULT`
            of the travel from its minimum).
    """

    fixed_bearing_shift_um: float = 0.0
    loose_bearing_shift_um: float = 0.0
    nut_shift_um: float = 0.0
    bearing_preload_change: float = 0.0
    nut_preload_change: float = 0.0
    carriage_preload_change: float = 0.0
    rail_misalignment_um: float = 0.0
    cover_step: float = 0.0
    cover_step_position_mm: float | None = None

    def __post_init__(self) -> None:
        bad: list[str] = []
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            if not math.isfinite(value):
                bad.append(f"{f.name}: {value!r} is not a finite number")
            elif f.name.endswith("_preload_change") and value <= -1:
                bad.append(f"{f.name}: {value!r} must be > -1 (a relative change)")
            elif f.name == "cover_step" and value < -1:
                bad.append(f"{f.name}: {value!r} must be >= -1 (a relative step)")
        if bad:
            raise ConfigError("invalid assembly variation", bad)

    def as_text(self) -> str:
        """The variation as ``key=value`` pairs, only the fields that are set (``""`` for none).

        A field is set when it differs from its default: non-zero, and for
        ``cover_step_position_mm`` any position. :func:`parse_variation` reads
        the text back to an equal variation, and ``ncmeasure simulate
        --variation`` takes it as it is.
        """
        pairs = []
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None or (f.default is not None and value == f.default):
                continue
            short = f"{value:g}"
            pairs.append(f"{f.name}={short if float(short) == value else repr(float(value))}")
        return ",".join(pairs)


_VARIATION_KEYS = tuple(f.name for f in fields(Variation))

EXAMPLE_VARIATIONS: Mapping[str, Variation] = MappingProxyType(
    {
        # Shims of the size the method's rig used (0.5–1 mm): ≈ +30 % next to the
        # shifted bearing, ≈ +1 % next to the other one.
        "loose_bearing": Variation(loose_bearing_shift_um=500.0),
        "fixed_bearing": Variation(fixed_bearing_shift_um=500.0),
        # ≈ +32 % next to both bearings, ≈ +10 % mid-travel.
        "screw_nut": Variation(nut_shift_um=500.0),
        # A 50 µm bow, beyond the permissible rail parallelism: ≈ +14 % mid-travel.
        "guide_rail": Variation(rail_misalignment_um=50.0),
        # The sticking telescopic cover of the method: a 20 % step mid-travel.
        "cover_or_seal": Variation(cover_step=0.2),
        # A nut one preload class too high (e.g. 2 % → 5 % of C_a, × 2.5): the same
        # +15 % everywhere, which only a comparison with a reference shows.
        "preload_or_carriage": Variation(nut_preload_change=1.5),
    }
)
"""One variation per assembly cause (keys: values of
:data:`~ncmeasure.formats.results.CauseName`), each of a size that the analysis
recognises on the rig axis; ``preload_or_carriage`` is a constant offset, which a
position profile shows as flat."""


def parse_variation(text: str) -> Variation:
    """Parse ``key=value`` pairs, separated by commas or spaces, into a :class:`Variation`.

    Example: ``parse_variation("loose_bearing_shift_um=20, nut_preload_change=-0.3")``.

    Raises:
        ConfigError: a pair without ``=``, an unknown or repeated key, a value that is
            not a number or out of range; the message names the key and value.
    """
    values: dict[str, float] = {}
    problems: list[str] = []
    pairs = parse_assignments(
        text.replace(",", " ").split(),
        "variation",
        form="key=value",
        example="loose_bearing_shift_um=20",
        problems=problems,
    )
    for key, raw in pairs:
        if key not in _VARIATION_KEYS:
            problems.append(f"{key}: unknown variation key (known: {', '.join(_VARIATION_KEYS)})")
            continue
        if key in values:
            problems.append(f"{key}: given twice")
            continue
        try:
            value = float(raw)
        except ValueError:
            problems.append(f"{key}: {raw!r} is not a number")
            continue
        if not math.isfinite(value):
            problems.append(f"{key}: {raw!r} is not a finite number")
            continue
        values[key] = value
    if problems:
        raise ConfigError(f"invalid variation {text!r}", problems)
    return Variation(**values)


class AxisModel:
    """Friction and motor current of one ball-screw feed axis.

    Args:
        axis: Axis parameters, or an :class:`~ncmeasure.config.AxisConfig`
            (its travel, bearing end, orientation, k_T and lead are used).
        components: Component friction (default: the method's test rig).
        variation: Assembly variances (default: none).
        condition: Levels and profiles of the components' friction (default:
            nominal; see :mod:`ncmeasure.sim.realism`).
    """

    def __init__(
        self,
        axis: AxisParameters | AxisConfig | None = None,
        components: Components | None = None,
        variation: Variation | None = None,
        condition: Condition | None = None,
    ) -> None:
        if axis is None:
            axis = AxisParameters()
        elif isinstance(axis, AxisConfig):
            axis = AxisParameters.from_config(axis)
        self.axis: AxisParameters = axis
        self.components: Components = components if components is not None else Components()
        self.variation: Variation = variation if variation is not None else Variation()
        self.condition: Condition | None = condition
        step_at = self.variation.cover_step_position_mm
        low, high = axis.mechanics.travel_mm
        if step_at is not None and not low <= step_at <= high:
            raise ConfigError(
                "invalid assembly variation",
                [
                    f"cover_step_position_mm: {step_at:g} mm is outside the travel "
                    f"[{low:g}, {high:g}] mm"
                ],
            )
        self._cover_step_mm = (
            step_at if step_at is not None else low + COVER_STEP_DEFAULT * (high - low)
        )

    # --- geometry -----------------------------------------------------------------

    def nut_distance_mm(self, position_mm: ArrayLike) -> FloatArray:
        """Distance of the nut centre from the fixed bearing, ``s``."""
        x = np.asarray(position_mm, dtype=np.float64)
        low, high = self.axis.mechanics.travel_mm
        from_end = x - low if self.axis.mechanics.fixed_bearing_end == "min" else high - x
        return np.asarray(self.axis.bearing_clearance_mm + from_end, dtype=np.float64)

    def rail_bow(self, position_mm: ArrayLike) -> FloatArray:
        """Shape of a bowed rail: ``4t(1 − t)`` over the travel (0 at both ends, 1 mid-travel)."""
        low, high = self.axis.mechanics.travel_mm
        t = np.clip((np.asarray(position_mm, dtype=np.float64) - low) / (high - low), 0.0, 1.0)
        return np.asarray(4.0 * t * (1.0 - t), dtype=np.float64)

    def normal_forces_n(self, position_mm: ArrayLike) -> dict[str, FloatArray]:
        """Constraining forces added to the preloads by the variation, per component.

        Keys: ``fixed_bearing``, ``loose_bearing``, ``nut``, ``guides`` (N, ≥ 0).
        """
        ax = self.axis
        var = self.variation
        x = np.asarray(position_mm, dtype=np.float64)
        span_m = ax.span_mm / 1000.0
        a_m = np.clip(self.nut_distance_mm(x) / 1000.0, 1e-6, span_m)  # nut to fixed bearing
        b_m = np.clip(span_m - a_m, 1e-6, span_m)  # nut to loose bearing
        three_ei = 3 * ax.bending_stiffness_nm2
        compliance = 1.0 / (ax.support_stiffness_n_per_um * 1e6)
        d_nut = var.nut_shift_um * 1e-6
        # Each span is a cantilever from the guided nut to a bearing, δ = F ℓ³ / (3 E I),
        # in series with the contact and housing compliance.
        fixed_force = (var.fixed_bearing_shift_um * 1e-6 - d_nut) / (a_m**3 / three_ei + compliance)
        loose_force = (var.loose_bearing_shift_um * 1e-6 - d_nut) / (b_m**3 / three_ei + compliance)
        rail_m = var.rail_misalignment_um * 1e-6 * self.rail_bow(x)
        return {
            "fixed_bearing": np.abs(fixed_force),
            "loose_bearing": np.abs(loose_force),
            "nut": np.abs(fixed_force + loose_force),
            "guides": np.abs(ax.guide_stiffness_n_per_um * 1e6 * rail_m),
        }

    # --- friction -----------------------------------------------------------------

    def _load_factors(self, x: FloatArray) -> dict[str, FloatArray]:
        """Per component: static friction at this position relative to nominal."""
        var = self.variation
        forces = self.normal_forces_n(x)
        preload = {
            "fixed_bearing": var.bearing_preload_change,
            "loose_bearing": var.bearing_preload_change,
            "nut": var.nut_preload_change,
            "guides": var.carriage_preload_change,
        }
        factors: dict[str, FloatArray] = {}
        for name, comp in self.components.items():
            factor = np.ones_like(x)
            if comp.coulomb_nm > 0 and (
                comp.torque_per_newton_nm > 0 or comp.constraint_coefficient_nm_per_n > 0
            ):
                extra_nm = comp.torque_per_newton_nm * comp.nominal_normal_force_n * preload.get(
                    name, 0.0
                ) + comp.constraint_coefficient_nm_per_n * forces.get(name, np.zeros_like(x))
                factor = factor + extra_nm / comp.coulomb_nm
            factors[name] = factor
        return factors

    def _static_factors(self, x: FloatArray) -> dict[str, FloatArray]:
        """Per component: static friction relative to nominal, with the condition."""
        factors = self._load_factors(x)
        condition = self.condition
        if condition is None:
            return factors
        low, high = self.axis.mechanics.travel_mm
        t = np.clip((x - low) / (high - low), 0.0, 1.0)
        for name in factors:
            factor = factors[name] * condition.coulomb_factor.get(name, 1.0)
            profile = condition.profile.get(name)
            if profile is not None:
                factor = factor * (1.0 + profile.at(t))
            factors[name] = factor
        return factors

    def coulomb_nm(self, position_mm: ArrayLike) -> FloatArray:
        """Coulomb friction torque along the travel (Nm): the static friction without
        Stribeck hump and viscous part, with variation and condition, broadcast."""
        x = np.asarray(position_mm, dtype=np.float64)
        factors = self._static_factors(x)
        total = sum(
            (comp.coulomb_nm * factors[name] for name, comp in self.components.items()),
            start=np.zeros_like(x),
        )
        if self.variation.cover_step != 0:
            total = total + np.where(
                x >= self._cover_step_mm,
                self.variation.cover_step * self.components.coulomb_nm,
                0.0,
            )
        return np.asarray(total, dtype=np.float64)

    def component_breakdown(
        self, position_mm: ArrayLike, velocity_mm_min: ArrayLike
    ) -> dict[str, FloatArray]:
        """Friction torque of each component (Nm, sign of the velocity), broadcast."""
        x, v = np.broadcast_arrays(
            np.asarray(position_mm, dtype=np.float64), np.asarray(velocity_mm_min, dtype=np.float64)
        )
        ax = self.axis
        omega = _omega_rad_s(v, ax.screw_lead_mm)
        sign = np.tanh(v / ax.regularisation_mm_min)
        factors = self._static_factors(x)
        viscous = {} if self.condition is None else self.condition.viscous_factor
        result: dict[str, FloatArray] = {}
        for name, comp in self.components.items():
            decay = np.exp(-np.abs(v) / comp.stribeck_velocity_mm_min)
            static = comp.coulomb_nm + comp.stribeck_nm * decay
            # The load-dependent share scales with the normal force; factor is
            # relative to the whole Coulomb torque, so apply it to static friction.
            torque = (
                static * factors[name] * sign
                + comp.viscous_nms_rad * viscous.get(name, 1.0) * omega
            )
            result[name] = np.asarray(torque, dtype=np.float64)
        if self.variation.cover_step != 0:
            # The nominal friction of the whole axis, without variation.
            nominal = sum(
                (c.coulomb_nm + c.stribeck_nm * np.exp(-np.abs(v) / c.stribeck_velocity_mm_min))
                * sign
                + c.viscous_nms_rad * omega
                for _, c in self.components.items()
            )
            beyond = x >= self._cover_step_mm
            result["covers"] = result["covers"] + np.where(
                beyond, self.variation.cover_step * nominal, 0.0
            )
        return result

    def friction_torque_nm(self, position_mm: ArrayLike, velocity_mm_min: ArrayLike) -> FloatArray:
        """Total friction torque at the motor (Nm), sign of the velocity, broadcast."""
        parts = self.component_breakdown(position_mm, velocity_mm_min)
        return np.asarray(sum(parts.values()), dtype=np.float64)

    def friction_map(self, positions_mm: ArrayLike, velocities_mm_min: ArrayLike) -> FloatArray:
        """Friction torque on a grid: shape ``(len(positions), len(velocities))``."""
        x = np.atleast_1d(np.asarray(positions_mm, dtype=np.float64))[:, None]
        v = np.atleast_1d(np.asarray(velocities_mm_min, dtype=np.float64))[None, :]
        return self.friction_torque_nm(x, v)

    # --- motor current ------------------------------------------------------------

    def cogging_current_a(self, position_mm: ArrayLike) -> FloatArray:
        """Position-periodic current ripple of the motor (3 and 18 periods per revolution)."""
        ax = self.axis
        x = np.asarray(position_mm, dtype=np.float64)
        angle = 2 * math.pi * (x - ax.mechanics.travel_mm[0]) / ax.screw_lead_mm
        torque = ax.cogging_3_nm * np.sin(3 * angle) + ax.cogging_18_nm * np.sin(18 * angle + 0.7)
        return np.asarray(torque / ax.torque_constant_nm_per_a, dtype=np.float64)

    def motor_current_a(
        self,
        position_mm: ArrayLike,
        velocity_mm_min: ArrayLike,
        acceleration_m_s2: ArrayLike = 0.0,
        *,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """Motor current (A): friction, inertia and gravity over k_T, cogging, noise.

        Args:
            position_mm: Axis position.
            velocity_mm_min: Axis velocity.
            acceleration_m_s2: Axis acceleration.
            rng: With a generator, Gaussian noise (``noise_a``) and rare outliers
                (``outlier_rate``, ``outlier_a`` with random sign) are added.
        """
        ax = self.axis
        x, v, a = np.broadcast_arrays(
            np.asarray(position_mm, dtype=np.float64),
            np.asarray(velocity_mm_min, dtype=np.float64),
            np.asarray(acceleration_m_s2, dtype=np.float64),
        )
        alpha = 2 * math.pi * a * 1000.0 / ax.screw_lead_mm
        torque = self.friction_torque_nm(x, v) + ax.inertia_kgm2 * alpha + ax.gravity_torque_nm
        current = torque / ax.torque_constant_nm_per_a + self.cogging_current_a(x)
        if rng is not None:
            current = current + rng.normal(0.0, ax.noise_a, size=current.shape)
            hit = rng.random(current.shape) < ax.outlier_rate
            signs = rng.choice(np.array([-1.0, 1.0]), size=current.shape)
            current = current + np.where(hit, signs * ax.outlier_a, 0.0)
        return np.asarray(current, dtype=np.float64)
