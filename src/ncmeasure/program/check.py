"""The program checker: re-read generated programs and hold them against limits and schedule.

``check_programs`` reads ``schedule.json`` in a program folder, reads the
programs with :mod:`ncmeasure.program.reader` (which knows nothing of the
templates), and verifies that

* the main program parks every axis, one at a time, before anything else;
* every move targets one axis only and stays inside that axis' soft limits;
* every feed is at most the axis' maximum velocity;
* every window of the schedule is driven, in order, from its start to its end
  at its velocity, and the marker is on exactly where the dialect says;
* the program ends with every axis back at its park position.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ncmeasure.errors import ConfigError, ProgramCheckError, ProgramError
from ncmeasure.formats.schedule import SCHEDULE_FILE, AxisSummary, Schedule, load_schedule
from ncmeasure.program.dialect import (
    Dialect,
    load_dialect,
    marker_m_functions,
    option_problems,
)
from ncmeasure.program.reader import (
    CodeUse,
    Motion,
    ProgramSet,
    ProgramTrace,
    ReadyWait,
    Stop,
    read_programs,
)

if TYPE_CHECKING:  # the machine-file models: `check` reads no machine file
    from ncmeasure.config import MachineConfig

__all__ = [
    "CheckReport",
    "axis_numbers",
    "check_programs",
    "check_trace",
    "code_problems",
    "read_generated",
]

_TOL_MM = 0.0005
_TOL_FEED = 0.0005
_MAX_LISTED = 20


@dataclass
class CheckReport:
    """What the checker read and what it found."""

    directory: Path
    controller: str
    motions: int = 0
    feeds: int = 0
    windows_expected: int = 0
    windows_found: int = 0
    verifies_offsets: bool = False
    """The programs cannot feed in machine coordinates (FANUC): they prove the work
    coordinates equal them, or stop before the first move."""
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when no problem was found."""
        return not self.problems


def _num(value: float) -> str:
    """A number for a message: short, but never shorter than what tells it from a limit."""
    short = f"{value:g}"
    return short if float(short) == value else repr(value)


def _where(motion: Motion) -> str:
    return f"{motion.program}:{motion.line}"


def _drives(motion: Motion, axis: str, start: float, end: float, speed: float) -> bool:
    """True when ``motion`` feeds ``axis`` from ``start`` to ``end`` at ``speed``."""
    first = motion.start.get(axis)
    return (
        first is not None
        and abs(first - start) <= _TOL_MM
        and abs(motion.target[axis] - end) <= _TOL_MM
        and motion.feed_mm_min is not None
        and abs(motion.feed_mm_min - speed) <= _TOL_FEED
    )


def _check_window_markers(
    schedule: Schedule, axis: AxisSummary, feeds: list[Motion], report: CheckReport
) -> None:
    windows = axis.windows
    report.windows_expected += len(windows)
    scope = schedule.marker_scope
    expected_marker = [0.0] * len(feeds)
    next_feed = 0
    for window in windows:
        speed = abs(window.velocity_mm_min)
        # A window is found with its run: run-up, window and run-out, three feed blocks in a
        # row at its velocity. Matched alone, a run-out could pass for the next window.
        points = (window.start_mm, window.window_start_mm, window.window_end_mm, window.stop_mm)
        found = next(
            (
                index
                for index in range(next_feed, len(feeds) - 2)
                if all(
                    _drives(feeds[index + k], axis.name, points[k], points[k + 1], speed)
                    for k in range(3)
                )
            ),
            None,
        )
        if found is None:
            report.problems.append(
                f"axis {axis.name}: window {window.id} ({window.window_start_mm:g} -> "
                f"{window.window_end_mm:g} mm at {speed:g} mm/min) is not driven in order, "
                "with its run-up and run-out"
            )
            return
        report.windows_found += 1
        value = float(window.id if schedule.marker_values == "window_id" else 1)
        run = (found, found + 1, found + 2)
        for index in run if scope == "run" else run[1:2]:
            expected_marker[index] = value
        next_feed = found + 3
    if scope == "none":
        return
    for motion, expected in zip(feeds, expected_marker, strict=True):
        if motion.marker != expected:
            report.problems.append(
                f"{_where(motion)}: marker is {motion.marker:g} during this feed, "
                f"expected {expected:g}"
            )


def check_trace(schedule: Schedule, trace: ProgramTrace, report: CheckReport) -> None:
    """Hold a read program against its schedule; append problems to ``report``."""
    axes = {axis.name: axis for axis in schedule.axes}
    report.motions = len(trace.motions)
    problems = report.problems
    problems.extend(trace.problems)
    if not trace.ended:
        problems.append("the main program never reaches its end (M30/M2)")
    parking = trace.motions[: len(axes)]
    parked = {
        axis
        for motion in parking
        if motion.kind == "rapid" and len(motion.target) == 1
        for axis, target in motion.target.items()
        if axis in axes and abs(target - axes[axis].park_mm) <= _TOL_MM
    }
    if parked != set(axes):
        missing = ", ".join(sorted(set(axes) - parked)) or "?"
        problems.append(
            f"the program does not start by parking every axis alone (not parked first: {missing})"
        )
    if any(m.calls > 0 for m in parking):
        problems.append("a subprogram is called before every axis is parked")
    problems.extend(_start_problems(schedule, trace))
    problems.extend(_ready_problems(schedule, trace))
    problems.extend(_retract_problems(schedule, trace))
    feeds_by_axis: dict[str, list[Motion]] = {name: [] for name in axes}
    for motion in trace.motions:
        if len(motion.target) != 1:
            problems.append(f"{_where(motion)}: moves several axes at once")
        for name, target in motion.target.items():
            axis = axes.get(name)
            if axis is None:
                problems.append(f"{_where(motion)}: moves axis {name}, which the schedule lacks")
                continue
            low, high = axis.travel_mm
            # as written, no tolerance: what the control reads must lie inside the limits
            if not low <= target <= high:
                problems.append(
                    f"{_where(motion)}: axis {name} to {_num(target)} mm, outside the soft limits "
                    f"[{_num(low)}, {_num(high)}]"
                )
            if motion.kind == "feed":
                assert motion.feed_mm_min is not None
                if motion.feed_mm_min > axis.max_velocity_mm_min:  # as written, no tolerance
                    problems.append(
                        f"{_where(motion)}: feed {_num(motion.feed_mm_min)} mm/min exceeds the "
                        f"maximum of axis {name} ({_num(axis.max_velocity_mm_min)} mm/min)"
                    )
                feeds_by_axis[name].append(motion)
            elif motion.marker != 0 and schedule.marker_scope != "none":
                problems.append(f"{_where(motion)}: marker on during a rapid move")
    report.feeds = sum(len(f) for f in feeds_by_axis.values())
    for name, axis in axes.items():
        _check_window_markers(schedule, axis, feeds_by_axis[name], report)
    final: dict[str, float] = {}
    for motion in trace.motions:
        final.update(motion.target)
    for name, axis in axes.items():
        if name in final and abs(final[name] - axis.park_mm) > _TOL_MM:
            problems.append(
                f"axis {name} ends at {final[name]:g} mm, not at its park position "
                f"{axis.park_mm:g} mm"
            )


def axis_numbers(schedule: Schedule) -> dict[str, int]:
    """The axes' numbers in the control, by name (schedules that do not know them: none)."""
    return {axis.name: axis.number for axis in schedule.axes if axis.number}


def _start_problems(schedule: Schedule, trace: ProgramTrace) -> list[str]:
    """With ``confirm_start`` the main program stops, with a message, before any move."""
    if not schedule.confirm_start:
        return []
    for step in trace.steps:
        if isinstance(step, Stop):
            if step.calls == 0 and step.message:
                return []
            if step.calls == 0:
                return [
                    f"{step.file or step.program}:{step.line}: the stop before the first move "
                    "shows the operator no message"
                ]
        if isinstance(step, Motion):
            return [
                f"{_where(step)}: an axis moves before the programmed stop that asks the "
                "operator to confirm the start (the machine file's confirm_start)"
            ]
    return []


def _ready_problems(schedule: Schedule, trace: ProgramTrace) -> list[str]:
    """With ``ready_input`` the main program waits for the recorder before any move,
    after the start confirmation, on that input, with that time-out; without it, never."""
    waits = [step for step in trace.steps if isinstance(step, ReadyWait)]
    wanted = schedule.ready_input
    if wanted is None:
        return [
            f"{w.file or w.program}:{w.line}: waits for the recorder's ready signal on input "
            f"{w.input}, but the machine file names no ready_input"
            for w in waits
        ]
    confirmed = not schedule.confirm_start
    for step in trace.steps:
        if isinstance(step, Stop) and step.calls == 0:
            confirmed = True
        elif isinstance(step, ReadyWait):
            where = f"{step.file or step.program}:{step.line}"
            problems: list[str] = []
            if step.calls or not confirmed:
                problems.append(
                    f"{where}: the wait for the recorder's ready signal must be in the main "
                    "program after the start confirmation, before the first move"
                )
            if step.input != wanted:
                problems.append(
                    f"{where}: waits on input {step.input}, but the machine file's "
                    f"ready_input is {wanted}"
                )
            timeout = schedule.ready_timeout_s
            if timeout is not None and abs(step.timeout_s - timeout) > 1e-9:
                problems.append(
                    f"{where}: waits at most {step.timeout_s:g} s, but the machine file's "
                    f"ready_timeout_s is {timeout:g} s"
                )
            return problems
        elif isinstance(step, Motion):
            return [
                f"{_where(step)}: an axis moves before the program waits for the recorder's "
                f"ready signal (the machine file's ready_input = {wanted})"
            ]
    return [
        "the main program never waits for the recorder's ready signal (the machine "
        f"file's ready_input = {wanted})"
    ]


def _retract_problems(schedule: Schedule, trace: ProgramTrace) -> list[str]:
    """Vertical and retract_first axes park first; no axis moves while another of them is
    away from its park (while they park, one after the other, the rest are not yet)."""
    retracts = {axis.name: axis.park_mm for axis in schedule.axes if axis.retracts}
    if not retracts:
        return []
    position: dict[str, float | None] = dict.fromkeys(retracts)
    for motion in trace.motions:
        moved = set(motion.target)
        parking = moved <= set(retracts)  # a retracting axis may park before the next one
        away = sorted(
            name
            for name, here in position.items()
            if name not in moved
            and (
                (here is None and not parking)
                or (here is not None and abs(here - retracts[name]) > _TOL_MM)
            )
        )
        if away:
            state = ", ".join(
                f"{name} not yet parked"
                if position[name] is None
                else f"{name} at {_num(position[name] or 0.0)} mm, park {_num(retracts[name])}"
                for name in away
            )
            return [
                f"{_where(motion)}: {', '.join(sorted(moved))} moves while a vertical or "
                f"retract_first axis is away from its park ({state}); it must retract first"
            ]  # the first one says it; the rest follow from it
        for name in moved & set(retracts):
            position[name] = motion.target[name]
    return []


def _check_names(schedule: Schedule, dialect: Dialect, path: Path) -> None:
    """The schedule's program files are files of the dialect, the main program among them.

    Raises:
        ProgramError: a name that is no program file of the dialect (a hand edit).
    """
    problems = [
        f"program_files[{number}]: {name!r} is not a {dialect.name} program file "
        f"({', '.join(sorted(dialect.program_extensions))})"
        for number, name in enumerate(schedule.program_files)
        if Path(name).suffix.lower() not in dialect.program_extensions
    ]
    if schedule.program_files and schedule.main_program not in schedule.program_files:
        problems.insert(
            0, f"main_program: {schedule.main_program!r} is not one of its program_files"
        )
    if problems:
        raise ProgramError(f"{path}: not a valid schedule", problems)


def _file_problems(directory: Path, schedule: Schedule, dialect: Dialect) -> list[str]:
    """Program files in the folder that schedule.json does not name, and named ones missing."""
    if not schedule.program_files:
        return [
            f"{SCHEDULE_FILE} names no program files (written by an older ncmeasure): "
            "generate the programs again"
        ]
    named = set(schedule.program_files)
    problems = [
        f"{path.name}: a program file that {SCHEDULE_FILE} does not name (left from another "
        "generation?); remove it or generate into an empty folder"
        for path in sorted(directory.iterdir())
        if path.suffix.lower() in dialect.program_extensions and path.name not in named
    ]
    for name in schedule.program_files:
        path = directory / name
        if not path.exists():
            problems.append(f"{name}: named in {SCHEDULE_FILE} but missing")
        elif not path.is_file():
            problems.append(f"{name}: not a regular file (a folder, device, pipe or socket)")
    return problems


def code_problems(schedule: Schedule, dialect: Dialect, uses: list[CodeUse]) -> list[str]:
    """M functions, variables and outputs the dialect does not allow.

    Every M word must be one of the dialect's own or a marker option's value that
    passes the dialect's rules; every variable or output must be its option's value.
    """
    codes = dialect.codes
    options = schedule.controller_options
    problems = [
        f"{SCHEDULE_FILE}: {p}" for p in option_problems(dialect, options, "controller_options")
    ]
    marker_m = marker_m_functions(dialect, options) if not problems else set()
    allowed_m = set(codes.program_m) | marker_m
    for use in uses:
        where = f"{use.file}:{use.line}"
        if use.kind == "m":
            if use.number not in allowed_m:
                meaning = codes.meaning(use.number)
                does = f" ({meaning})" if meaning else ""
                reserved = " is reserved" if codes.reserved(use.number) else " is not allowed"
                problems.append(
                    f"{where}: M{use.shown}{does}{reserved}: {dialect.title} programs of "
                    f"ncmeasure use only M{', M'.join(str(m) for m in sorted(allowed_m))}"
                )
            continue
        rule = codes.options[use.kind]
        value = options.get(use.kind)
        if not any(low <= use.number <= high for low, high in rule.allowed):
            allowed = ", ".join(f"{low}-{high}" for low, high in rule.allowed)
            problems.append(
                f"{where}: {rule.meaning} {use.shown} is not one {dialect.title} allows ({allowed})"
            )
        elif use.number != value:
            problems.append(
                f"{where}: {rule.meaning} {use.shown} is written, but the marker is "
                f"controller_options.{use.kind} = {value}"
            )
    return problems


def read_generated(
    directory: str | Path, controllers_dirs: tuple[Path, ...] = ()
) -> tuple[Schedule, Dialect, ProgramTrace]:
    """Read generated programs the way a controller would, with their schedule.json.

    Raises:
        ProgramError: not a folder of programs, no readable schedule, a program
            that cannot be read.
        DialectError: the schedule's controller is unknown.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise ProgramError(f"{directory}: not a directory of generated programs")
    schedule = load_schedule(directory / SCHEDULE_FILE)
    dialect = load_dialect(schedule.controller, controllers_dirs)
    _check_names(schedule, dialect, directory / SCHEDULE_FILE)
    trace = read_programs(
        dialect,
        directory,
        schedule.main_program,
        {axis.name for axis in schedule.axes},
        schedule.controller_options,
        axis_numbers(schedule),
    )
    return schedule, dialect, trace


def programs_of(programs: Path, machine_file: Path) -> tuple[Schedule, MachineConfig]:
    """The schedule of the programs in ``programs`` and the machine file, checked to
    belong together (the machine file's config hash is the one schedule.json carries).

    Raises:
        ProgramError: no such folder, or no readable schedule.json in it.
        ConfigError: an unreadable machine file, or not the one of the programs.
    """
    if not programs.is_dir():
        what = "is not a folder" if programs.exists() else "no such folder"
        raise ProgramError(
            f"{programs}: {what}; name the folder `ncmeasure generate MACHINE -o FOLDER` wrote"
        )
    from ncmeasure.config import config_hash, load_machine

    schedule = load_schedule(programs / SCHEDULE_FILE)
    config = load_machine(machine_file)
    found = config_hash(config)
    if found != schedule.config_hash:
        raise ConfigError(
            f"{machine_file} is not the machine file the programs in {programs} were "
            f"generated from (config hash {found}, {SCHEDULE_FILE} says "
            f"{schedule.config_hash}): generate them again from it "
            f"(ncmeasure generate {machine_file} -o {programs}) and load them into the "
            "control, or name the file they came from"
        )
    return schedule, config


def check_programs(directory: str | Path, controllers_dirs: tuple[Path, ...] = ()) -> CheckReport:
    """Check the generated programs in ``directory`` against their schedule.json.

    Returns:
        The report; its ``problems`` list is empty when everything holds.

    Raises:
        ProgramError: the folder holds no readable schedule or program.
        ProgramCheckError: a program leaves its limits or its schedule.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise ProgramError(f"{directory}: not a directory of generated programs")
    schedule = load_schedule(directory / SCHEDULE_FILE)
    dialect = load_dialect(schedule.controller, controllers_dirs)
    _check_names(schedule, dialect, directory / SCHEDULE_FILE)
    report = CheckReport(
        directory=directory,
        controller=dialect.name,
        verifies_offsets=dialect.coordinates.verify is not None,
    )
    report.problems.extend(_file_problems(directory, schedule, dialect))
    files = ProgramSet(dialect, directory, schedule.controller_options)
    report.problems.extend(code_problems(schedule, dialect, files.scan()))
    report.problems.extend(files.problems)
    try:
        axes = {axis.name for axis in schedule.axes}
        trace = files.run(
            schedule.main_program,
            axes,
            schedule.blocks or None,
            axis_numbers=axis_numbers(schedule),
        )
    except ProgramError as exc:
        if not report.problems:
            raise
        # a block the reader cannot follow, beside what the scan already found
        report.problems.append(exc.message)
    else:
        check_trace(schedule, trace, report)
    if report.problems:
        listed = report.problems[:_MAX_LISTED]
        more = len(report.problems) - len(listed)
        if more:
            listed.append(f"... and {more} more")
        raise ProgramCheckError(f"{directory}: {len(report.problems)} problem(s) found", listed)
    return report
