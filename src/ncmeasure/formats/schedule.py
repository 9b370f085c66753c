"""schedule.json: what the generated programs do and when, for the analysis and ``check``.

Written by ``ncmeasure generate`` beside the programs (the planner,
:mod:`ncmeasure.plan`, builds it); read by ``check``, the recorder (to know
how long to record), the analysis (to label every window with its step,
position and direction) and the simulators. ``ncmeasure schema schedule``
prints its JSON Schema. Per axis (:class:`AxisSummary`): the axis' mechanics,
its velocity steps, positions and timing, and every :class:`Window`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, ClassVar, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator
from pydantic_core import PydanticCustomError

from ncmeasure.errors import ProgramError
from ncmeasure.formats.axis import StatedMechanics
from ncmeasure.formats.header import FileHeader, read_file
from ncmeasure.inputs import plain_file_name

__all__ = [
    "MAX_SCHEDULE_BYTES",
    "SCHEDULE_FILE",
    "SCHEDULE_FORMAT",
    "SCHEDULE_FORMAT_VERSION",
    "SCHEDULE_MARGIN_S",
    "AxisSummary",
    "FileName",
    "Schedule",
    "Window",
    "load_schedule",
]

SCHEDULE_FILE = "schedule.json"
MAX_SCHEDULE_BYTES = 64 * 1024 * 1024
"""Largest schedule.json read."""
SCHEDULE_MARGIN_S = 30.0
"""A recording given a schedule goes on this long after the schedule's estimated end
(``ncmeasure record --schedule``; the setup sheet tells the technician)."""


def _file_name(value: str) -> str:
    if not plain_file_name(value):
        raise PydanticCustomError(
            "file_name", "{name} is not a plain file name", {"name": repr(value)}
        )
    return value


FileName = Annotated[str, AfterValidator(_file_name)]
"""A file name that stays in its folder (see :func:`~ncmeasure.inputs.plain_file_name`)."""

SCHEDULE_FORMAT = "ncmeasure-schedule"
SCHEDULE_FORMAT_VERSION = 1


class Window(BaseModel):
    """One constant-velocity measuring window, as schedule.json lists it."""

    model_config = ConfigDict(frozen=True)

    id: int
    """Window number within the axis, starting at 1; the marker value."""
    axis: str
    repetition: int
    step: int
    """Velocity step index, 0 = slowest."""
    velocity_mm_min: float
    """Signed velocity: negative in negative direction."""
    direction: Literal[1, -1]
    position_index: int
    nominal_position_mm: float
    position_mm: float
    """Window centre; differs from the nominal position where the run-up did not fit."""
    start_mm: float
    """Where the run starts, at rest."""
    window_start_mm: float
    window_end_mm: float
    stop_mm: float
    """Where the run stops, at rest."""
    t_start_s: float
    t_window_start_s: float
    t_window_end_s: float
    t_stop_s: float
    """Expected times from the start of the main program."""


class AxisSummary(StatedMechanics):
    """Per-axis part of a schedule: the axis' mechanics, its steps, positions and windows."""

    model_config = ConfigDict(frozen=True)

    name: str
    usable_mm: tuple[float, float]
    park_mm: float
    number: int = 0
    """The axis' number in the control where a dialect addresses axes by number
    (FANUC's #5020 + n): the machine file's ``control_axis``, else its place there
    (1 for the first); 0 in older schedules."""
    retracts: bool = False
    """Vertical or retract_first: parked before any other axis moves, measured last;
    no other axis moves while it is away from its park."""
    max_velocity_mm_min: float
    rapid_mm_min: float | None = None
    """Rapid traverse velocity (the machine file's, or its maximum velocity)."""
    nominal_positions_mm: list[float]
    shifted_positions_mm: list[float]
    """Nominal positions whose windows move inward at high velocities, where the
    run-up would not fit; each window's own position_mm says where it is."""
    velocities_mm_min: list[float]
    dropped_velocities_mm_min: list[float]
    runup_at_max_velocity_mm: float
    window_s: float
    settle_s: float
    sample_period_ms: float
    warmup_strokes: int
    repetitions: int
    both_directions: bool
    order: Literal["velocity", "position"] = "velocity"
    """The order of the runs (the machine file's ``measurement.order``)."""
    t_start_s: float
    duration_s: float
    full_travel_duration_s: float
    blocks: int = 0
    """Motion and dwell blocks of the axis' measurement (a run is three feed blocks)."""
    windows: list[Window]


class Schedule(FileHeader):
    """What the programs do and when: the velocity file the analysis reads."""

    model_config = ConfigDict(frozen=True)

    FORMAT: ClassVar[str] = SCHEDULE_FORMAT
    FORMAT_VERSION: ClassVar[int] = SCHEDULE_FORMAT_VERSION
    WRITTEN_BY: ClassVar[str] = "ncmeasure generate"

    config_hash: str
    machine: str
    controller: str
    program: str
    duration_s: float
    """Estimated duration of the whole program (parking, warm-up, runs, rapids)."""
    full_travel_duration_s: float
    """The same measurement driving the full usable travel at every step."""
    blocks: int = 0
    """Motion, dwell and call blocks of all programs together: what the control must store."""
    warnings: list[str]
    main_program: Annotated[str, AfterValidator(lambda v: v and _file_name(v))] = ""
    """File name of the main program (set when programs are generated)."""
    program_files: list[FileName] = Field(default_factory=list)
    """Every program file of the generated set, the main program first; ``check``
    refuses a program file in the folder that is not listed here."""
    marker_scope: Literal["window", "run", "none"] = "window"
    """What the marker brackets in the generated programs (see the dialect)."""
    marker_values: Literal["window_id", "flag"] = "window_id"
    controller_options: dict[str, int | bool] = Field(default_factory=dict)
    """The dialect options the programs were written with."""
    confirm_start: bool = False
    """The main program stops before its first move until cycle start (the machine
    file's ``confirm_start``); schedules written before it was known say False."""
    ready_input: int | None = None
    """The controller input the main program waits on for the recorder's ready signal
    before its first move (the machine file's ``ready_input``); None: no wait."""
    ready_timeout_s: float | None = None
    """How long it waits (the machine file's ``ready_timeout_s``), with ``ready_input``."""
    axes: list[AxisSummary]

    @field_validator("program_files")
    @classmethod
    def _check_program_files(cls, value: list[str]) -> list[str]:
        if len({name.lower() for name in value}) != len(value):
            raise PydanticCustomError("file_names", "names a file twice")
        return value


def load_schedule(path: str | Path) -> Schedule:
    """Read a schedule.json.

    Raises:
        ProgramError: missing, not JSON, or not a schedule.
    """
    return read_file(
        path,
        Schedule,
        ProgramError,
        what="schedule",
        max_bytes=MAX_SCHEDULE_BYTES,
        missing=f"{path}: no schedule here (generate writes {SCHEDULE_FILE})",
    )
