"""results.json: the versioned result of analysing one recording.

``ncmeasure schema results`` prints the JSON Schema. The shape, per axis::

    recording                            machine (type), serial, start_utc, source, gaps, ...
    skipped.<AXIS>                       why an axis could not be analysed, in words
    axes.<AXIS>.verdict                  level ok / check / fault, reason, action
    axes.<AXIS>.quantity                 "torque_nm" (with a torque constant) or "current_a"
    axes.<AXIS>.positions[]              one entry per measuring position
        .position_mm
        .directions.positive / .negative  (null where not measured)
            .points[]                    velocity_mm_min (signed), median, stderr, mean, std, n
            .model, .model_reason        which fit describes the curve, and why
            .fit                         Coulomb + viscous over its linear range
            .stribeck / .extended        nonlinear fits (parameters null when not identifiable)
    axes.<AXIS>.offset                   with both directions: bias (gravity, torque offset)
    axes.<AXIS>.pooled                   fits over all positions pooled, where no position
                                         holds enough speeds for a line of its own
    axes.<AXIS>.position_dependency      spread_percent, signature, causes[] best first,
                                         identifiable, compared_groups, noise_spread_percent

Friction values are in the axis' ``quantity``: Nm when the torque constant is
known (T = k_T · I), else A. The points are the measured values, offset
included; the fits describe friction, a positive magnitude in both
directions, with the axis' offset (``offset_removed``) taken out first. A fit
that the data do not determine publishes ``null`` parameters and its
``reason``, never a number that is not friction.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field

from ncmeasure.errors import ConfigError
from ncmeasure.files import write_whole
from ncmeasure.formats.axis import AxisMechanics
from ncmeasure.formats.header import FileHeader, read_file
from ncmeasure.formats.identity import Serial

__all__ = [
    "RESULTS_FORMAT",
    "RESULTS_FORMAT_VERSION",
    "AxisResult",
    "Cause",
    "CauseName",
    "DirectionResult",
    "LinearFit",
    "ModelName",
    "NonlinearFit",
    "OffsetResult",
    "Point",
    "PooledFit",
    "PositionDependency",
    "PositionResult",
    "RecordingInfo",
    "Results",
    "Signature",
    "VelocityProfile",
    "Verdict",
    "VerdictLevel",
    "load_results",
    "write_results",
]

log = logging.getLogger(__name__)

RESULTS_FORMAT = "ncmeasure-results"
RESULTS_FORMAT_VERSION = 2

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
    "not_identifiable",
]
"""How friction changes along the travel (``not_identifiable``: the layout of the
measurement cannot tell position effects from speed and direction effects)."""

ModelName = Literal["linear", "stribeck", "extended"]
"""The friction models: Coulomb + viscous, Stribeck, extended Stribeck."""

VerdictLevel = Literal["ok", "check", "fault"]
"""An axis at a glance: fine, worth a look (or a new measurement), or an assembly fault."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Point(_Model):
    """Friction at one velocity step: robust and plain statistics of the window samples."""

    velocity_mm_min: float = Field(description="Signed velocity of the step.")
    median: float = Field(
        description="Median friction, the robust figure (of grouped data for a quantised current)."
    )
    stderr: float | None = Field(
        default=None,
        description="Standard error of the median: the scatter of the medians of consecutive "
        "stretches of the windows (correlated samples), at least √(π/2)·std/√n.",
    )
    mean: float
    std: float
    n: int = Field(description="Samples in the windows of this step.")
    step: int | None = Field(default=None, description="Velocity step index, when known.")
    windows: int = Field(default=1, description="Windows pooled into this point.")


class LinearFit(_Model):
    """Coulomb + viscous friction, T(v) = T_C + t_v·|v| in the direction's sense.

    Linear least squares with regressor rows [v, 1]; standard errors from
    σ²(HᵀH)⁻¹ with σ the scatter of the points; reduced χ² accepted for k < 10
    (Σ ê² ≤ k (n − m) σ²). Fitted over the range of speeds where the line
    holds (above the Stribeck region): ``velocity_range_mm_min``.
    """

    coulomb: float | None = Field(
        description="Coulomb friction as a magnitude; null when the fit does not determine it "
        "(see reason)."
    )
    viscous_per_mm_min: float | None = Field(description="Viscous coefficient per mm/min.")
    coulomb_stderr: float | None
    viscous_stderr: float | None
    chi2_reduced: float
    accepted: bool
    n_points: int
    velocity_range_mm_min: tuple[float, float] = Field(
        description="Smallest and largest |v| of the points the fit used."
    )
    points_below_range: int = Field(
        default=0, description="Slower points left out: the line does not hold there."
    )
    reason: str | None = Field(
        default=None, description="Why the parameters are null, when they are."
    )


class NonlinearFit(_Model):
    """A Stribeck model fitted by nonlinear least squares (scipy).

    ``stribeck``: T = T_C + (T_S − T_C)·exp(−(|v|/v_S)^δ) + b·|v|;
    ``extended`` adds a rolling term + f_w·|v|^k.
    """

    model: Literal["stribeck", "extended"]
    parameters: dict[str, float] | None = Field(
        description="The parameters; null when the fit is not identifiable (see reason)."
    )
    ci95: dict[str, tuple[float, float]] | None = Field(
        description="95 % confidence interval per parameter (null with the parameters)."
    )
    identifiable: bool = Field(
        description="True when every interval excludes zero and is narrower than the value."
    )
    chi2_reduced: float
    stribeck_velocity_mm_min: float | None = None
    reason: str | None = Field(
        default=None, description="Why the fit is not identifiable, when it is not."
    )


class DirectionResult(_Model):
    """One position, one direction."""

    points: list[Point]
    fit: LinearFit | None
    stribeck: NonlinearFit | None = None
    extended: NonlinearFit | None = None
    offset_removed: float | None = Field(
        default=None,
        description="The axis' offset (gravity, bias) taken out of the points before fitting: "
        "the fits see direction × (median − offset).",
    )
    model: ModelName | None = Field(
        default=None, description="The model that describes this curve; null when none does."
    )
    model_reason: str = Field(default="", description="Why that model, in one sentence.")
    coulomb_measured: float | None = Field(
        default=None,
        description="This direction's Coulomb friction as measured, the offset left in: "
        "fit.coulomb + direction × offset_removed. Where friction differs between the "
        "directions (a robot joint, a cable chain pulling one way) this is each direction's "
        "own; the fits take the offset out as a bias (on a vertical axis: gravity, which "
        "this value then holds).",
    )


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
    position_numbers: list[int] = Field(
        default_factory=list,
        description="The number of each measuring position (1 = the lowest), as the report "
        "shows it.",
    )
    values: list[float]
    spread_percent: float = Field(description="(max − min) / mean × 100.")


class PooledFit(_Model):
    """Both directions' fits over the points of every position together.

    Made where each position holds too few speeds for a line of its own (e.g. a
    controller trace that runs each speed on its own part of the travel); it
    takes friction to be the same along the travel.
    """

    positions_mm: list[float] = Field(description="The positions whose points were pooled.")
    directions: dict[Literal["positive", "negative"], DirectionResult | None]
    note: str = Field(description="Why the positions were pooled, in one sentence.")


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
    identifiable: bool = Field(
        default=True,
        description="False when no two positions were measured at the same speed in the same "
        "direction: position effects cannot be told from speed and direction effects, and "
        "spread_percent is 0.",
    )
    compared_groups: int | None = Field(
        default=None,
        description="Groups of matched speed and direction holding 2 positions or more: the "
        "only comparisons position effects are judged from.",
    )
    noise_spread_percent: float | None = Field(
        default=None,
        description="The spread the same layout shows without any position effect: the 99th "
        "percentile over permutations of the values among the positions of each matched group "
        "(null where the layout gives no such null, e.g. a single group).",
    )


class Verdict(_Model):
    """An axis at a glance, for the person at the machine."""

    level: VerdictLevel
    reason: str = Field(description="Why, in one sentence.")
    action: str = Field(description="What to do.")


class AxisResult(AxisMechanics):
    """Everything found for one axis, and its mechanics as far as they were known.

    The mechanics come from the recording's meta.json, the machine file and the
    schedule, in that order; a fact none of them stated is null.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    verdict: Verdict
    quantity: Literal["torque_nm", "current_a"]
    unit: Literal["Nm", "A"]
    window_source: Literal["marker", "command", "plateau", "schedule"]
    windows: int
    samples_used: int
    sample_period_s: float | None = Field(default=None, description="Median time step.")
    velocity_quantum_mm_min: float = Field(
        default=0.0, description="One count of the velocity signal (0: continuous)."
    )
    current_quantum_a: float = Field(
        default=0.0, description="One count of the current signal in A (0: continuous)."
    )
    coarse: bool = Field(
        default=False,
        description="Windows hold few samples: points are uncertain, no Stribeck curve.",
    )
    implausible_values: dict[str, int] = Field(
        default_factory=dict,
        description="Values left out per channel as not physically possible ('no value' codes).",
    )
    positions: list[PositionResult]
    offset: OffsetResult | None = None
    pooled: PooledFit | None = Field(
        default=None,
        description="Friction lines over all positions pooled, per direction: only where no "
        "position holds enough speeds for a line of its own.",
    )
    position_dependency: PositionDependency | None = None
    warnings: list[str] = Field(default_factory=list)


class RecordingInfo(_Model):
    """Where the data came from."""

    directory: str
    machine: str | None = Field(description="The machine type (the machine file's name).")
    serial: Serial | None = Field(
        default=None, description="The serial number of the machine measured, where given."
    )
    start_utc: str | None = Field(description="When the measurement began; null: unknown.")
    config_hash: str | None
    source: str
    status: str | None = Field(default=None, description="How the recording ended.")
    samples: int | None = Field(default=None, description="Rows in the recording.")
    duration_s: float | None = None
    gaps: int = Field(default=0, description="Holes in the time axis (lost samples).")
    gap_samples: int = Field(default=0, description="Samples lost in them.")
    gap_share: float = Field(default=0.0, description="gap_samples / (samples + gap_samples).")
    gap_events: int = Field(default=0, description="Gap events the link reported.")
    skipped_cycles: int = Field(
        default=0,
        description="Of gap_samples, the cycles the link skipped because the host fell behind "
        "(SYNC cycles a CANopen producer could not send in time).",
    )


class Results(FileHeader):
    """The whole results.json."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    FORMAT: ClassVar[str] = RESULTS_FORMAT
    FORMAT_VERSION: ClassVar[int] = RESULTS_FORMAT_VERSION
    WRITTEN_BY: ClassVar[str] = "ncmeasure analyze"

    created_utc: str
    recording: RecordingInfo
    settings: dict[str, float | str | bool | None]
    axes: dict[str, AxisResult]
    skipped: dict[str, str] = Field(
        default_factory=dict, description="Axes that could not be analysed, with the reason."
    )


def write_results(results: Results, path: str | os.PathLike[str]) -> Path:
    """Write ``results.json`` atomically: a reader sees the old file or the new one, whole.

    Raises:
        OutputError: The file cannot be written.
    """
    target = write_whole(path, results.model_dump_json(indent=2) + "\n", fsync=True, parents=True)
    log.info("wrote %s", target)
    return target


MAX_RESULTS_BYTES = 256 * 1024 * 1024
"""Largest results.json read."""


def load_results(path: str | os.PathLike[str]) -> Results:
    """Read a ``results.json`` written by :func:`write_results`.

    Raises:
        ConfigError: The file is missing, not JSON, not an ncmeasure results
            file, of another format version, or not valid (one line per problem).
    """
    return read_file(
        Path(path),
        Results,
        ConfigError,
        what="results file",
        max_bytes=MAX_RESULTS_BYTES,
        missing=f"{path}: no such results file",
        older="analyse the recording again",
    )
