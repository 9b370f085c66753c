"""The machine file: pydantic models of a machine, its axes and the measurement.

A machine file is TOML with three parts: ``[machine]`` (name, controller
dialect, program name), one ``[[axes]]`` table per feed axis (limits, park
position, drive data), and ``[measurement]`` (positions, velocity steps,
windows). An axis may override parts of the measurement in its own
``[axes.measurement]`` table. Every model forbids unknown keys, so a typo is
an error, not a silently ignored setting.

:func:`load_machine` reads and validates a file; every problem comes back as
one ``location: message`` line inside a :class:`~ncmeasure.errors.ConfigError`.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, Optional

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    create_model,
    field_validator,
)
from pydantic_core import PydanticCustomError

from ncmeasure.errors import ConfigError
from ncmeasure.formats.axis import AXIS_NAME_PATTERN, BearingEnd, StatedMechanics
from ncmeasure.inputs import MAX_TOML_BYTES, format_validation_error, parse_toml, read_text

__all__ = [
    "AxisConfig",
    "Limits",
    "MachineConfig",
    "MachineSection",
    "Measurement",
    "MeasurementOverride",
    "ceil_um",
    "config_hash",
    "floor_um",
    "format_validation_error",
    "load_machine",
    "parse_assignments",
    "parse_machine",
    "read_toml",
    "to_um",
    "usable_um",
]

# Characters that would break out of a comment or a program name in one of
# the dialects, or reach into the file system.
_FORBIDDEN_TEXT = re.compile(r"[\x00-\x1f\x7f;()%$/\\*\"'{}\[\]]|\.\.")
PROGRAM_NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_]{0,23}$"

# Physical ranges of the machine file's numbers. Positions: what controls accept
# (HEIDENHAIN TNC 640 ISO manual §19.3 p.631: ±99 999.9999 mm). Feeds: programs write
# them with 0.001 mm/min resolution, so the lowest must stay well above that; the highest
# is far beyond any feed axis.
MAX_POSITION_MM = 100_000.0
MIN_FEED = 0.01
MAX_FEED = 1_000_000.0
MAX_WINDOW_S = 600.0
MAX_POSITIONS = 50
MAX_WINDOWS = 50_000
"""Most windows any plan may have: what generate, check and the analysis handle in
seconds and a few hundred MB."""
Position = Annotated[float, Field(ge=-MAX_POSITION_MM, le=MAX_POSITION_MM)]
SAFE_PARK_FRACTION = 0.25
"""A vertical or retract_first axis parks within this fraction of its travel from its safe end."""


def to_um(value_mm: float) -> int:
    """The nearest whole micrometre."""
    return round(value_mm * 1000.0)


def ceil_um(value_mm: float) -> int:
    """Smallest micrometre count not below ``value_mm`` (float noise never crosses it)."""
    # The tolerance keeps exact values (e.g. 2.5 mm) from rounding up by float noise;
    # the correction step makes sure the result is never below the value.
    count = math.ceil(value_mm * 1000.0 - 1e-6)
    return count + 1 if count / 1000.0 < value_mm else count


def floor_um(value_mm: float) -> int:
    """Largest micrometre count not above ``value_mm``."""
    count = math.floor(value_mm * 1000.0 + 1e-6)
    return count - 1 if count / 1000.0 > value_mm else count


def _tuple(value: object) -> object:
    """TOML has arrays, not tuples: a list becomes the tuple it stands for."""
    return tuple(value) if isinstance(value, list) else value


def _safe_text(value: str) -> str:
    match = _FORBIDDEN_TEXT.search(value)
    if match:
        shown = repr(match.group(0))
        raise PydanticCustomError(
            "unsafe_text",
            "must not contain {char}: it would break the NC program or a file path",
            {"char": shown},
        )
    return value


def _check_pattern(value: str, pattern: str, rule: str) -> str:
    if not re.fullmatch(pattern, value):
        raise PydanticCustomError(
            "name", "{value} is not {rule}", {"value": repr(value), "rule": rule}
        )
    return value


class _Model(BaseModel):
    model_config = ConfigDict(
        extra="forbid", frozen=True, validate_default=True, strict=True, allow_inf_nan=False
    )


READY_TIMEOUT_S = 60.0
"""Default of ``machine.ready_timeout_s``: how long a program waits for the recorder."""
READY_OUTPUT_KEYS = {"canopen": "ready_output_bit", "modbus": "ready"}
"""The per-axis link key naming where the recorder's ready output leaves the bus."""


class MachineSection(_Model):
    """The ``[machine]`` table: which machine, which controller, which program."""

    name: Annotated[str, Field(min_length=1, max_length=64)] = Field(
        description="Machine type, written into every program header: one file and one "
        "program serve every machine of the type; the serial number is given at "
        "measurement (`ncmeasure measure --serial`, `record --serial`, `analyze --serial`).",
        examples=["HMX-400"],
    )
    controller: str = Field(
        description="Controller dialect, one of `ncmeasure controllers` "
        "(e.g. sinumerik-840d, fanuc, heidenhain-iso, twincat, linuxcnc).",
    )
    program: str = Field(
        default="FRICTION",
        description="Name of the main program; subprograms are named <program>_<axis>. "
        "Letters, digits and underscores, starting with a letter; the dialect may restrict "
        "it further.",
    )
    program_number: Annotated[int, Field(ge=1, le=99_999_999)] = Field(
        default=1000,
        description="Program number for dialects with numbered programs (Fanuc O-number); "
        "subprograms take the following numbers.",
    )
    park_order: list[str] | None = Field(
        default=None,
        description="Order in which the main program parks the axes, one axis at a time. "
        "Vertical and retract_first axes must come first. Default: those first, then the "
        "others in file order.",
    )
    measure_order: list[str] | None = Field(
        default=None,
        description="Order in which the axes are measured. Vertical and retract_first axes "
        "must come last (they leave their park after every other axis is done). Default: "
        "file order, those axes last.",
    )

    confirm_start: bool = Field(
        default=True,
        description="The main program stops before its first move with an operator message "
        "(work area clear, no tool, override) and waits for cycle start. Set false for "
        "unattended series started by the PLC.",
    )

    ready_input: Annotated[int, Field(ge=0, le=99_999)] | None = Field(
        default=None,
        description="The controller's digital input wired to the recorder's ready signal "
        "(the output the link names: a drive's 0x60FE bit, a Modbus coil). The main program "
        "waits for it before its first move and stops with RECORDER NOT READY after "
        "ready_timeout_s. Default: no wait.",
    )
    ready_timeout_s: Annotated[float, Field(gt=0, le=3600)] = Field(
        default=READY_TIMEOUT_S,
        description="How long the main program waits for the recorder's ready signal "
        "(with ready_input).",
    )

    controller_options: dict[str, Annotated[int, Field(ge=0, le=99_999)] | bool] = Field(
        default_factory=dict,
        description="Machine-specific settings of the controller dialect, e.g. which "
        "parameter or M function carries the marker (see `ncmeasure controllers --details`).",
    )

    _check_name = field_validator("name")(classmethod(lambda cls, v: _safe_text(v)))

    @field_validator("program")
    @classmethod
    def _check_program(cls, value: str) -> str:
        return _check_pattern(
            value,
            PROGRAM_NAME_PATTERN,
            "a program name: use letters, digits and underscores, starting with a letter, "
            "at most 24 characters",
        )


class Measurement(_Model):
    """The ``[measurement]`` table: what to measure on every axis."""

    positions: int | Annotated[list[Position], Field(max_length=MAX_POSITIONS)] = Field(
        default=3,
        description="Measuring positions: a count, spread evenly over the usable travel "
        "(3: next to the fixed bearing, middle, next to the loose bearing), or a list in mm.",
    )
    velocity_steps: Annotated[int, Field(ge=1, le=500)] = Field(
        default=50, description="Number of constant-velocity steps per direction."
    )
    min_velocity_mm_min: Annotated[float, Field(ge=MIN_FEED, le=MAX_FEED)] = Field(
        default=10.0, description="Lowest measured velocity in mm/min."
    )
    max_velocity_mm_min: Annotated[float, Field(ge=MIN_FEED, le=MAX_FEED)] | None = Field(
        default=None,
        description="Highest measured velocity in mm/min. "
        "Default: max_velocity_fraction × the axis' maximum velocity.",
    )
    max_velocity_fraction: Annotated[float, Field(ge=0.001, le=1)] = Field(
        default=0.5,
        description="Fraction of the axis maximum velocity used when max_velocity_mm_min "
        "is not given.",
    )
    spacing: Literal["geometric", "linear"] = Field(
        default="geometric",
        description="Velocity step spacing: geometric puts more steps at low speed, where "
        "friction is nonlinear (Stribeck region); linear spaces them evenly.",
    )
    window_s: Annotated[float, Field(ge=0.001, le=MAX_WINDOW_S)] | None = Field(
        default=None,
        description="Minimum duration of constant velocity per window in s. "
        "Default: window_samples × sample_period_ms.",
    )
    window_samples: Annotated[int, Field(ge=1, le=1_000_000)] = Field(
        default=100, description="Samples per window when window_s is not given."
    )
    sample_period_ms: Annotated[float, Field(ge=0.01, le=1000)] = Field(
        default=4.0,
        description="Sample period of the recording in ms (e.g. the interpolation cycle).",
    )
    settle_s: Annotated[float, Field(ge=0, le=10)] = Field(
        default=0.1,
        description="Time at constant velocity before the marker goes on, for the servo "
        "loop to settle after the run-up.",
    )
    dynamics_safety: Annotated[float, Field(ge=1, le=10)] = Field(
        default=1.2,
        description="Factor on the jerk-limited run-up and stopping distances, covering "
        "controllers that ramp more gently than the axis limits allow.",
    )
    margin_mm: Annotated[float, Field(ge=0, le=MAX_POSITION_MM)] = Field(
        default=5.0,
        description="Distance kept from both soft limits by every move of the measurement.",
    )
    warmup_strokes: Annotated[int, Field(ge=0, le=100)] = Field(
        default=2,
        description="Back-and-forth strokes over the usable travel before measuring, so "
        "the lubrication film forms and the first window is not an outlier.",
    )
    warmup_velocity_mm_min: Annotated[float, Field(ge=MIN_FEED, le=MAX_FEED)] | None = Field(
        default=None,
        description="Feed of the warm-up strokes in mm/min. Default: the highest "
        "measured velocity.",
    )
    repetitions: Annotated[int, Field(ge=1, le=100)] = Field(
        default=1, description="How often the whole measurement of an axis is repeated."
    )
    both_directions: bool = Field(
        default=True,
        description="Measure in positive and negative direction (Stribeck curve for v > 0 "
        "and v < 0).",
    )
    order: Literal["velocity", "position"] = Field(
        default="velocity",
        description="Order of the runs: 'velocity' measures one velocity step at every "
        "position before the next step (a step's windows close together in time, more "
        "rapids); 'position' measures every step in both directions at one position before "
        "the next position (few rapids; each position at another time since the warm-up).",
    )
    dwell_s: Annotated[float, Field(ge=0, le=60)] = Field(
        default=0.0, description="Dwell at standstill before each window, in s."
    )
    unfit_steps: Literal["error", "drop"] = Field(
        default="error",
        description="A velocity step whose run-up, window and stop do not fit in the usable "
        "travel: 'error' stops with the numbers, 'drop' leaves the step out with a warning.",
    )

    @field_validator("dwell_s")
    @classmethod
    def _check_dwell(cls, value: float) -> float:
        if 0 < value < 0.001:
            raise PydanticCustomError(
                "dwell", "a dwell is 0 or at least 0.001 s (programs write whole milliseconds)"
            )
        return value

    @field_validator("positions")
    @classmethod
    def _check_positions(cls, value: int | list[float]) -> int | list[float]:
        if isinstance(value, int):
            if not 1 <= value <= MAX_POSITIONS:
                raise PydanticCustomError(
                    "positions", "a count must be between 1 and {most}", {"most": MAX_POSITIONS}
                )
            return value
        if not value:
            raise PydanticCustomError("positions", "the list of positions is empty")
        if len(set(value)) != len(value):
            raise PydanticCustomError("positions", "the list repeats a position")
        return sorted(value)

    @property
    def window_duration_s(self) -> float:
        """Minimum duration of each constant-velocity window in seconds."""
        if self.window_s is not None:
            return self.window_s
        return self.window_samples * self.sample_period_ms / 1000.0


def _all_optional(model: type[_Model], name: str, doc: str) -> type[_Model]:
    """``model`` with every field optional and unset by default: a table of replacements.

    The fields keep their types and descriptions; their ranges and rules are
    checked when the replacements are merged into a whole ``model``.
    """
    fields: dict[str, Any] = {
        key: (Optional[info.annotation], Field(default=None, description=info.description))  # noqa: UP045 (a runtime type)
        for key, info in model.model_fields.items()
    }
    return create_model(name, __base__=_Model, __doc__=doc, __module__=__name__, **fields)


if TYPE_CHECKING:

    class MeasurementOverride(Measurement):
        """Per-axis ``[axes.measurement]`` table, as the type checker sees it."""

else:
    MeasurementOverride = _all_optional(
        Measurement,
        "MeasurementOverride",
        """Per-axis ``[axes.measurement]`` table: any measurement field, replacing the global one.

        Derived from :class:`Measurement` (one model, not two); the merged result is
        validated as a whole :class:`Measurement`.
        """,
    )


class AxisConfig(StatedMechanics):
    """One ``[[axes]]`` table: a feed axis, its limits and its drive.

    The mechanical facts (travel, vertical, fixed-bearing end, torque constant,
    rated current, screw lead) are :class:`~ncmeasure.formats.axis.StatedMechanics`.
    """

    model_config = _Model.model_config

    name: str = Field(
        description="Axis address as the controller writes it (X, Y, Z, Z1, ...). "
        "The dialect decides which names it allows.",
    )
    # The machine file's positions are bounded (MAX_POSITION_MM) and TOML gives lists.
    travel_mm: Annotated[tuple[Position, Position], BeforeValidator(_tuple)] = Field(
        description="Soft limits [min, max] in mm. No program position ever leaves them."
    )
    park_mm: Position = Field(
        description="Where the axis waits while the other axes are measured, in mm."
    )
    max_velocity_mm_min: Annotated[float, Field(ge=MIN_FEED, le=MAX_FEED)] = Field(
        description="Maximum axis velocity in mm/min. No feed exceeds it."
    )
    rapid_velocity_mm_min: Annotated[float, Field(ge=MIN_FEED, le=MAX_FEED)] | None = Field(
        default=None,
        description="Rapid traverse velocity in mm/min, for the duration estimate. "
        "Default: max_velocity_mm_min.",
    )
    max_acceleration_m_s2: Annotated[float, Field(ge=0.001, le=200)] = Field(
        description="Maximum axis acceleration in m/s²."
    )
    max_jerk_m_s3: Annotated[float, Field(ge=0.001, le=100_000)] = Field(
        description="Maximum axis jerk in m/s³."
    )
    control_axis: Annotated[int, Field(ge=1, le=32)] | None = Field(
        default=None,
        description="The axis' number in the control, where a dialect addresses axes by "
        "number (FANUC: parameter 1020 order; its offset check reads #5020+n and #5040+n). "
        "Default: its place in the machine file, 1 for the first.",
    )
    retract_first: bool = Field(
        default=False,
        description="Treat the axis like a vertical one: it goes to its park before any "
        "other axis moves, is measured after all others, and its park must lie at its "
        "safe end (a quill, a ram, a tool-side axis over the table). Vertical axes always do.",
    )
    safe_end: BearingEnd | None = Field(
        default=None,
        description="The end of the travel away from the table and workpiece, where a "
        "vertical or retract_first axis parks. Default: max (ISO 841: the positive "
        "direction of Z moves the tool away from the workpiece).",
    )
    measurement: MeasurementOverride | None = Field(
        default=None, description="Per-axis replacement of [measurement] fields."
    )
    link: dict[str, Any] = Field(
        default_factory=dict,
        description="Per-axis settings of the drive link, e.g. { node_id = 1 } for CANopen "
        "or { unit_id = 1 } for Modbus; checked by the link (see the README).",
    )

    @field_validator("name")
    @classmethod
    def _check_axis_name(cls, value: str) -> str:
        return _check_pattern(
            value,
            AXIS_NAME_PATTERN,
            "an axis name: an upper-case letter, then up to 7 upper-case letters or digits "
            "(X, Y, Z, Z1, ...)",
        )

    def control_number(self, place: int) -> int:
        """The axis' number in the control: ``control_axis``, else ``place`` (1-based)."""
        return self.control_axis or place

    @property
    def retracts(self) -> bool:
        """True for an axis that parks first and is measured last (vertical or retract_first)."""
        return self.vertical or self.retract_first

    @property
    def safe_side(self) -> BearingEnd:
        """The end of the travel where the axis is safe (away from the table)."""
        return self.safe_end or "max"

    def safe_park_mm(self) -> tuple[float, float]:
        """The part of the travel where a retracting axis may park: the quarter at its safe end."""
        low, high = self.travel_mm
        zone = SAFE_PARK_FRACTION * (high - low)
        return (high - zone, high) if self.safe_side == "max" else (low, low + zone)

    @property
    def rapid_mm_min(self) -> float:
        """Rapid traverse velocity used for duration estimates."""
        return self.rapid_velocity_mm_min or self.max_velocity_mm_min


class Limits(_Model):
    """The ``[limits]`` table: how large a measurement program may become."""

    max_duration_h: Annotated[float, Field(ge=0.01, le=720)] = Field(
        default=8.0,
        description="Longest planned measurement accepted, in hours (default: one shift). "
        "A longer plan is refused before anything is rendered.",
    )
    max_program_kb: Annotated[int, Field(ge=1, le=1_000_000)] | None = Field(
        default=None,
        description="Largest set of program files accepted, in kB (1 kB = 1024 bytes). "
        "Default: the program memory the controller definition assumes "
        "(`ncmeasure controllers --details`).",
    )
    max_windows: Annotated[int, Field(ge=1, le=MAX_WINDOWS)] = Field(
        default=20_000,
        description="Most measuring windows accepted, all axes together (each is a run of "
        f"three blocks and an entry of schedule.json); at most {MAX_WINDOWS}. "
        "A plan with more is refused before anything is rendered.",
    )


def usable_um(axis: AxisConfig, meas: Measurement) -> tuple[int, int]:
    """The usable travel of ``axis`` in whole micrometres: soft limits minus the margin.

    Each number is rounded to micrometres on its own (limits inward, the margin up)
    before they are added, so that the result is exactly what the file says in
    decimals (750.3 − 5.1 is 745.2, not the float 745.1999…) and never more.
    """
    margin = ceil_um(meas.margin_mm)
    return ceil_um(axis.travel_mm[0]) + margin, floor_um(axis.travel_mm[1]) - margin


class MachineConfig(_Model):
    """A whole machine file."""

    machine: MachineSection
    axes: Annotated[list[AxisConfig], Field(min_length=1, max_length=32)]
    measurement: Measurement = Field(default_factory=Measurement)
    limits: Limits = Field(default_factory=Limits)
    link: dict[str, Any] | None = Field(
        default=None,
        description="The drive link: type = 'canopen' | 'modbus' | 'replay' and its settings; "
        "checked by the link when recording (see the README).",
    )

    def axis(self, name: str) -> AxisConfig:
        """Return the axis called ``name``."""
        for axis in self.axes:
            if axis.name == name:
                return axis
        raise KeyError(name)

    def park_sequence(self) -> list[AxisConfig]:
        """Axes in the order the main program parks them (vertical axes first)."""
        if self.machine.park_order is not None:
            return [self.axis(name) for name in self.machine.park_order]
        return sorted(self.axes, key=lambda axis: not axis.retracts)

    def measure_sequence(self) -> list[AxisConfig]:
        """Axes in the order they are measured (vertical and retract_first axes last)."""
        if self.machine.measure_order is not None:
            return [self.axis(name) for name in self.machine.measure_order]
        return sorted(self.axes, key=lambda axis: axis.retracts)

    def measurement_for(self, axis: AxisConfig) -> Measurement:
        """The measurement of ``axis``: the global table with the axis' overrides applied."""
        if axis.measurement is None:
            return self.measurement
        merged = self.measurement.model_dump(exclude_unset=True)
        override = axis.measurement.model_dump(exclude_none=True)
        # A window given one way on the axis replaces a window given the other way globally.
        if "window_s" in override:
            merged.pop("window_samples", None)
        if "window_samples" in override:
            merged.pop("window_s", None)
        merged.update(override)
        return Measurement.model_validate(merged)


def _retracting(axis: AxisConfig) -> str:
    return "vertical" if axis.vertical else "retract_first"


def _retract_order(config: MachineConfig, key: str, order: list[str]) -> Iterator[str]:
    """A park order must park retracting axes first; a measure order must measure them last."""
    retracts = [config.axis(name).retracts for name in order]
    if key == "park_order":
        wrong = [name for i, name in enumerate(order) if not retracts[i] and any(retracts[i + 1 :])]
        if wrong:
            late = ", ".join(n for i, n in enumerate(order) if retracts[i] and i > 0)
            yield (
                f"machine.park_order: {', '.join(wrong)} would move before {late}, which must "
                "retract first (vertical or retract_first); list them first"
            )
    else:
        early = [name for i, name in enumerate(order) if retracts[i] and not all(retracts[i:])]
        if early:
            yield (
                f"machine.measure_order: {', '.join(early)} would leave its park before other "
                "axes are measured; a vertical or retract_first axis is measured last"
            )


def _safe_park(index: int, axis: AxisConfig) -> Iterator[str]:
    """A vertical or retract_first axis parks in the quarter of its travel at its safe end."""
    low, high = axis.safe_park_mm()
    if not low <= axis.park_mm <= high:
        side = "upper" if axis.safe_side == "max" else "lower"
        yield (
            f"axes[{index}].park_mm: {axis.park_mm:.15g} mm is not at the safe end of "
            f"{_retracting(axis)} axis {axis.name}: it parks first and every other axis "
            f"traverses with it there, so it must lie in the {side} quarter of its travel "
            f"[{low:.15g}, {high:.15g}] mm (safe_end = {axis.safe_side!r})"
        )


def _ready_checks(config: MachineConfig) -> Iterator[str]:
    """The recorder-ready handshake is configured whole or not at all.

    The controller's side is ``machine.ready_input`` (and its time-out); the bus side
    is one axis' link key (:data:`READY_OUTPUT_KEYS`) where the machine file has a
    CANopen or Modbus ``[link]``. Without a ``[link]`` table the link comes from the
    command line and checks itself when it opens.
    """
    machine = config.machine
    if machine.ready_input is None and "ready_timeout_s" in machine.model_fields_set:
        yield (
            "machine.ready_timeout_s: a time-out for the recorder's ready signal, but no "
            "machine.ready_input the program waits on; set both, or neither"
        )
    link_type = (config.link or {}).get("type")
    key = READY_OUTPUT_KEYS.get(link_type) if isinstance(link_type, str) else None
    if key is None:
        return
    naming = [i for i, axis in enumerate(config.axes) if key in axis.link]
    if machine.ready_input is not None and not naming:
        yield (
            f"machine.ready_input: the program waits for the recorder's ready signal, but no "
            f"axis' link names where it leaves the bus: set axes[i].link.{key} on the axis "
            "whose drive has the output wired to the controller, or remove ready_input"
        )
    if machine.ready_input is None:
        for index in naming:
            yield (
                f"axes[{index}].link.{key}: the recorder signals ready, but no program waits "
                "for it: set machine.ready_input (the controller's input it is wired to), or "
                f"remove {key}"
            )
    for index in naming[1:]:
        yield (
            f"axes[{index}].link.{key}: the ready output is already named on "
            f"axes[{naming[0]}]; name it on one axis only"
        )


def _cross_checks(config: MachineConfig) -> Iterator[str]:
    """Checks across fields, each as a ``location: message`` line."""
    names = [axis.name for axis in config.axes]
    for index, name in enumerate(names):
        if name in names[:index]:
            yield f"axes[{index}].name: axis {name} appears twice"
    numbers = [axis.control_number(index + 1) for index, axis in enumerate(config.axes)]
    for index, number in enumerate(numbers):
        if number in numbers[:index]:
            other = numbers.index(number)
            yield (
                f"axes[{index}].control_axis: axis {config.axes[index].name} would be control "
                f"axis {number}, like axis {config.axes[other].name} (axes[{other}]); give "
                "every axis its own number (control_axis, default: its place in the file)"
            )
    yield from _ready_checks(config)
    for key in ("park_order", "measure_order"):
        order = getattr(config.machine, key)
        if order is not None and sorted(order) != sorted(names):
            yield f"machine.{key}: must list every axis exactly once ({', '.join(names)})"
        elif order is not None:
            yield from _retract_order(config, key, order)
    for index, axis in enumerate(config.axes):
        low, high = axis.travel_mm
        if not low < high:
            yield f"axes[{index}].travel_mm: min ({low:.15g}) must be below max ({high:.15g})"
        elif not low <= axis.park_mm <= high:
            yield (
                f"axes[{index}].park_mm: {axis.park_mm:.15g} mm is outside the travel "
                f"[{low:.15g}, {high:.15g}] mm"
            )
        elif axis.retracts:
            yield from _safe_park(index, axis)
        elif axis.safe_end is not None:
            yield (
                f"axes[{index}].safe_end: only a vertical or retract_first axis has a safe end "
                "it parks at; set vertical = true or retract_first = true, or remove safe_end"
            )
    for index, axis in enumerate(config.axes):
        if not axis.travel_mm[0] < axis.travel_mm[1]:
            continue
        where = f"axes[{index}].measurement" if axis.measurement else "measurement"
        try:
            meas = config.measurement_for(axis)
        except ValidationError as exc:
            yield from format_validation_error(exc, f"axes[{index}].measurement")
            continue
        if "window_s" in meas.model_fields_set and "window_samples" in meas.model_fields_set:
            yield (
                f"{where}.window_s: set either window_s or window_samples × sample_period_ms, "
                "not both"
            )
        top = meas.max_velocity_mm_min
        if top is not None and top > axis.max_velocity_mm_min:
            yield (
                f"{where}.max_velocity_mm_min: {top:.15g} mm/min exceeds the maximum velocity "
                f"of axis {axis.name} ({axis.max_velocity_mm_min:.15g} mm/min)"
            )
        top = top if top is not None else meas.max_velocity_fraction * axis.max_velocity_mm_min
        if meas.min_velocity_mm_min >= top:
            yield (
                f"{where}.min_velocity_mm_min: {meas.min_velocity_mm_min:.15g} mm/min must be "
                f"below the highest measured velocity ({top:.15g} mm/min) on axis {axis.name}"
            )
        warm = meas.warmup_velocity_mm_min
        if warm is not None and warm > axis.max_velocity_mm_min:
            yield (
                f"{where}.warmup_velocity_mm_min: {warm:.15g} mm/min exceeds the maximum "
                f"velocity of axis {axis.name} ({axis.max_velocity_mm_min:.15g} mm/min)"
            )
        low, high = axis.travel_mm
        low_um, high_um = usable_um(axis, meas)
        if high_um <= low_um:
            yield (
                f"{where}.margin_mm: {meas.margin_mm:.15g} mm from both ends leaves no usable "
                f"travel on axis {axis.name} (travel {high - low:.15g} mm)"
            )
        if meas.window_duration_s > MAX_WINDOW_S:
            yield (
                f"{where}.window_samples: {meas.window_samples} samples of "
                f"{meas.sample_period_ms:.15g} ms make a window of "
                f"{meas.window_duration_s:.15g} s, more than {MAX_WINDOW_S:.15g} s"
            )
        count = len(meas.positions) if isinstance(meas.positions, list) else meas.positions
        if count > 1 and high_um - low_um < count - 1:
            yield (
                f"{where}.positions: {count} positions need at least {count - 1} µm of usable "
                f"travel; axis {axis.name} has {max(high_um - low_um, 0)} µm"
            )
        if isinstance(meas.positions, list):
            micrometres = [to_um(p) for p in meas.positions]  # as the planner places them
            for number in range(1, len(micrometres)):
                if micrometres[number] == micrometres[number - 1]:
                    yield (
                        f"{where}.positions[{number}]: {meas.positions[number]:.15g} mm and "
                        f"{meas.positions[number - 1]:.15g} mm are the same micrometre; the "
                        "programs place positions on whole micrometres"
                    )
            for number, position in enumerate(meas.positions):
                if not low_um <= micrometres[number] <= high_um:
                    yield (
                        f"{where}.positions[{number}]: {position:.15g} mm is outside the "
                        f"usable travel of axis {axis.name} "
                        f"[{low_um / 1000:.15g}, {high_um / 1000:.15g}] mm"
                    )


def parse_machine(data: Mapping[str, Any], source: str = "machine file") -> MachineConfig:
    """Validate a machine description already parsed from TOML.

    Raises:
        ConfigError: with one ``location: message`` line per problem.
    """
    try:
        config = MachineConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(
            f"{source} is not valid",
            format_validation_error(
                exc, schema_hint="`ncmeasure schema machine`", tables=("controller_options",)
            ),
        ) from exc
    problems = list(dict.fromkeys(_cross_checks(config)))  # one line per problem
    if problems:
        raise ConfigError(f"{source} is not valid", problems)
    return config


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The tables of a TOML file, or a ``ConfigError`` that names the file and the problem.

    The file must be a regular file of at most 1 MiB (:data:`~ncmeasure.inputs.MAX_TOML_BYTES`).

    Args:
        path: The file.
        what: What the file should be, for the message (``a machine file``).
    """
    text = read_text(path, f"{what} (.toml)", MAX_TOML_BYTES)
    return parse_toml(text, str(path))


def load_machine(path: str | Path) -> MachineConfig:
    """Read and validate a machine file.

    Raises:
        ConfigError: the file is missing, is not TOML, or does not describe a valid machine.
    """
    return parse_machine(read_toml(path, "a machine file"), str(path))


_LATER_MACHINE_KEYS: dict[str, object] = {
    "confirm_start": True,
    "ready_input": None,
    "ready_timeout_s": READY_TIMEOUT_S,
}
_LATER_AXIS_KEYS: dict[str, object] = {
    "control_axis": None,
    "retract_first": False,
    "safe_end": None,
}


def config_hash(config: MachineConfig) -> str:
    """A short, stable fingerprint of a validated machine description.

    Two files that describe the same machine and measurement get the same
    hash whatever their layout or comments, so programs, schedules and
    recordings can be matched.
    """
    # The link settings say how to record and the limits how large a program may be,
    # not what the program does: they stay out.
    data = config.model_dump(
        mode="json", exclude={"link": True, "limits": True, "axes": {"__all__": {"link"}}}
    )
    # Keys added after the first release count only where a file sets them otherwise
    # than their default: a machine file keeps its hash (and its machine type in the
    # fleet store) across an upgrade.
    for key, default in _LATER_MACHINE_KEYS.items():
        if data["machine"].get(key) == default:
            del data["machine"][key]
    for axis in data["axes"]:
        for key, default in _LATER_AXIS_KEYS.items():
            if axis.get(key) == default:
                del axis[key]
    canonical = json.dumps(data, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()[:16]


def parse_assignments(
    items: Iterable[str],
    what: str,
    *,
    form: str = "KEY=VALUE",
    example: str,
    problems: list[str] | None = None,
) -> list[tuple[str, str]]:
    """``KEY=VALUE`` texts (command-line options, variations) into stripped pairs, in order.

    The one parser of such pairs; callers convert and check the values.

    Args:
        items: The texts, e.g. ``["X=1", "Y=2"]``.
        what: How a message names an item's origin (``--unit``, ``variation``).
        form: The expected form, for the message (``AXIS=NUMBER``).
        example: A correct item, for the message.
        problems: Collect a malformed item's message here instead of raising.

    Raises:
        ConfigError: an item without ``=``, without a key or without a value (one
            line per such item), unless ``problems`` collects them.
    """
    pairs: list[tuple[str, str]] = []
    found: list[str] = []
    for text in items:
        key, sep, value = text.partition("=")
        if not sep or not key.strip() or not value.strip():
            found.append(f"{what} {text!r}: expected {form}, e.g. {example}")
            continue
        pairs.append((key.strip(), value.strip()))
    if problems is not None:
        problems += found
    elif len(found) == 1:
        raise ConfigError(found[0])
    elif found:
        raise ConfigError(f"{what}: expected {form}", found)
    return pairs
