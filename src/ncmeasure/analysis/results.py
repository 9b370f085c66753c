"""results.json: the versioned result of analysing one recording.

``ncmeasure schema results`` prints the JSON Schema. The shape, per axis::

    axes.<AXIS>.quantity                 "torque_nm" (with a torque constant) or "current_a"
    axes.<AXIS>.positions[]              one entry per measuring position
        .position_mm
        .directions.positive / .negative  (null where not measured)
            .points[]                    velocity_mm_min (signed), median, mean, std, n
            .fit                         Coulomb + viscous, linear least squares
            .stribeck / .extended        nonlinear fits, or null
    axes.<AXIS>.offset                   with both directions: bias (gravity, torque offset)
    axes.<AXIS>.position_dependency      spread_percent, signature, causes[] best first

Friction values are in the axis' ``quantity``: Nm when the torque constant is
known (T = k_T · I), else A. ``coulomb`` is a magnitude in both directions.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from ncmeasure import __version__

__all__ = [
    "RESULTS_FORMAT",
    "RESULTS_FORMAT_VERSION",
    "AxisResult",
    "Cause",
    "CauseName",
    "DirectionResult",
    "LinearFit",
    "NonlinearFit",
    "OffsetResult",
    "Point",
    "PositionDependency",
    "PositionResult",
    "RecordingInfo",
    "Results",
    "Signature",
    "VelocityProfile",
]

RESULTS_FORMAT = "ncmeasure-results"
RESULTS_FORMAT_VERSION = 1

CauseName = Literal[
    "none",
    "preload_or_carriage",
    "loose_bearing",
    "fixed_bearing",
    "screw_nut",
    "guide_rail",
    "cover_or_seal",
]
"""The fixed vocabulary of assembly causes (method.md, "What the patterns mean")."""

Signature = Literal[
    "flat",
    "rising_to_loose_bearing",
    "rising_to_fixed_bearing",
    "high_at_both_ends",
    "step",
    "irregular",
    "insufficient_data",
]
"""How friction changes along the travel."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Point(_Model):
    """Friction at one velocity step: robust and plain statistics of the window samples."""

    velocity_mm_min: float = Field(description="Signed velocity of the step.")
    median: float = Field(description="Median friction, the robust figure.")
    mean: float
    std: float
    n: int = Field(description="Samples in the windows of this step.")
    step: int | None = Field(default=None, description="Velocity step index, when known.")
    windows: int = Field(default=1, description="Windows pooled into this point.")


class LinearFit(_Model):
    """Coulomb + viscous friction, T(v) = T_C + t_v·|v| in the direction's sense.

    Linear least squares with regressor rows [v, 1]; standard errors from
    σ²(HᵀH)⁻¹ with σ the scatter of the points; reduced χ² accepted for k < 10
    (Σ ê² ≤ k (n − m) σ²).
    """

    coulomb: float = Field(description="Coulomb friction as a magnitude.")
    viscous_per_mm_min: float = Field(description="Viscous coefficient per mm/min.")
    coulomb_stderr: float
    viscous_stderr: float
    chi2_reduced: float
    accepted: bool
    n_points: int
    velocity_range_mm_min: tuple[float, float] = Field(
        description="Smallest and largest |v| of the points the fit used."
    )


class NonlinearFit(_Model):
    """A Stribeck model fitted by nonlinear least squares (scipy).

    ``stribeck``: T = T_C + (T_S − T_C)·exp(−(|v|/v_S)^δ) + b·|v|;
    ``extended`` adds a rolling term + f_w·|v|^k.
    """

    model: Literal["stribeck", "extended"]
    parameters: dict[str, float]
    ci95: dict[str, tuple[float, float]] = Field(
        description="95 % confidence interval per parameter."
    )
    identifiable: bool = Field(
        description="True when every interval excludes zero and is narrower than the value."
    )
    chi2_reduced: float
    stribeck_velocity_mm_min: float | None = None


class DirectionResult(_Model):
    """One position, one direction."""

    points: list[Point]
    fit: LinearFit | None
    stribeck: NonlinearFit | None = None
    extended: NonlinearFit | None = None


class PositionResult(_Model):
    """One measuring position."""

    position_mm: float
    position_index: int
    directions: dict[Literal["positive", "negative"], DirectionResult | None]


class OffsetResult(_Model):
    """Direction-independent part of the measured value: gravity or a torque/current bias.

    With both directions, T₊(v) = F + o and T₋(v) = −F + o, so the offset o is
    half the sum and the friction F half the difference.
    """

    value: float
    stderr: float | None = None
    explanation: str


class VelocityProfile(_Model):
    """Friction along the travel at one velocity (or averaged over all)."""

    velocity_mm_min: float | None = Field(description="None for the average over velocities.")
    positions_mm: list[float]
    values: list[float]
    spread_percent: float = Field(description="(max − min) / mean × 100.")


class Cause(_Model):
    """A likely assembly cause, with how strongly the data point at it."""

    cause: CauseName
    score: float = Field(ge=0, le=1)
    evidence: str


class PositionDependency(_Model):
    """How friction depends on the position along the travel."""

    spread_percent: float
    trend_per_100mm: float = Field(
        description="Slope of the averaged friction along the travel, relative to its mean, "
        "in % per 100 mm (positive: rising towards the max end)."
    )
    signature: Signature
    profiles: list[VelocityProfile]
    causes: list[Cause] = Field(description="Likely causes, best first.")


class AxisResult(_Model):
    """Everything found for one axis."""

    quantity: Literal["torque_nm", "current_a"]
    unit: Literal["Nm", "A"]
    torque_constant_nm_per_a: float | None
    travel_mm: tuple[float, float] | None = Field(
        default=None, description="Soft limits, when known (recording or machine file)."
    )
    fixed_bearing_end: Literal["min", "max"] | None = None
    vertical: bool | None = None
    screw_lead_mm: float | None = None
    window_source: Literal["marker", "command", "plateau", "schedule"]
    windows: int
    samples_used: int
    positions: list[PositionResult]
    offset: OffsetResult | None = None
    position_dependency: PositionDependency | None = None
    warnings: list[str] = Field(default_factory=list)


class RecordingInfo(_Model):
    """Where the data came from."""

    directory: str
    machine: str | None
    start_utc: str | None
    config_hash: str | None
    source: str


class Results(_Model):
    """The whole results.json."""

    format: Literal["ncmeasure-results"] = "ncmeasure-results"
    format_version: int = RESULTS_FORMAT_VERSION
    ncmeasure_version: str = __version__
    created_utc: str
    recording: RecordingInfo
    settings: dict[str, float | str | bool | None]
    axes: dict[str, AxisResult]
