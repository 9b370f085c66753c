"""The setup sheet: what the technician at the machine reads before cycle start.

``generate`` writes it beside the programs twice, ``SETUP.md`` (Markdown, readable
as plain text) and ``setup.html`` (one self-contained page to print). Both come
from one frozen view model, :class:`SetupSheet`, whose every word and number is
decided here from the plan, the schedule, the machine file and the dialect; the
templates in ``setup_sheet/`` only lay it out. The envelope of an axis is taken
from the moves the programs make (park, warm-up strokes, every run from its
start to its stop), not from the soft limits.

Values from files (the machine's name, a dialect's words) are escaped for each
format: Jinja's autoescape for the HTML, a backslash before every Markdown
character for the Markdown, so neither can carry markup of its own.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import jinja2
from jinja2.sandbox import SandboxedEnvironment

from ncmeasure.config import MachineConfig
from ncmeasure.formats.schedule import SCHEDULE_FILE, SCHEDULE_MARGIN_S, AxisSummary, Schedule
from ncmeasure.plan import AxisPlan
from ncmeasure.program.dialect import Dialect, dialect_warnings

__all__ = [
    "SETUP_FILES",
    "SETUP_HTML",
    "SETUP_MD",
    "AxisEnvelope",
    "Code",
    "SetupSheet",
    "axis_envelope",
    "render_setup_html",
    "render_setup_markdown",
    "setup_sheet",
]

SETUP_MD = "SETUP.md"
SETUP_HTML = "setup.html"
SETUP_FILES = (SETUP_MD, SETUP_HTML)
"""The sheet's files, written beside the programs and schedule.json."""


@dataclass(frozen=True)
class Code:
    """Text shown as code: a command, a file name, a key of the machine file."""

    text: str


Line = tuple[str | Code, ...]
"""A sentence: plain text and code, in order."""


@dataclass(frozen=True)
class ProgramRow:
    role: str
    name: str
    file_name: str


@dataclass(frozen=True)
class AxisEnvelope:
    """Where one axis goes: the lowest and highest position any move of the programs
    reaches, and the fastest feed they program."""

    low_mm: float
    high_mm: float
    max_feed_mm_min: float


@dataclass(frozen=True)
class AxisRow:
    name: str
    low_mm: str
    high_mm: str
    park_mm: str
    soft_limits_mm: str
    max_feed_mm_min: str
    rapid_mm_min: str


@dataclass(frozen=True)
class SetupSheet:
    """Everything the sheet says, as text."""

    title: str
    subtitle: str
    duration: str
    programs: tuple[ProgramRow, ...]
    programs_note: Line
    axes: tuple[AxisRow, ...]
    axes_note: str
    order: tuple[Line, ...]
    before: tuple[Line, ...]
    recording: tuple[Line, ...]
    marker: tuple[Line, ...]


def _mm(value: float) -> str:
    """A position as the programs write it: micrometres, no minus zero."""
    text = f"{value:.3f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def _feed(value: float) -> str:
    text = f"{value:.3f}".rstrip("0").rstrip(".")
    return text or "0"


def duration_text(seconds: float) -> str:
    """``52 min 13 s (3133 s)``: minutes and seconds, and the seconds alone."""
    whole = round(seconds)
    minutes, rest = divmod(whole, 60)
    return f"{minutes} min {rest} s ({whole} s)"


def axis_envelope(plan: AxisPlan) -> AxisEnvelope:
    """The positions and feeds of one axis' moves, its park included."""
    park = plan.summary.park_mm
    positions = [park]
    feeds = [0.0]
    for move in plan.moves:
        if move.kind in ("rapid", "feed"):
            positions.append(move.target_mm)
        if move.kind == "feed":
            feeds.append(move.feed_mm_min)
        if move.kind == "run":
            positions += [move.start_mm, move.stop_mm]
            feeds.append(move.feed_mm_min)
    return AxisEnvelope(min(positions), max(positions), max(feeds))


def _axis_row(summary: AxisSummary, envelope: AxisEnvelope) -> AxisRow:
    low, high = summary.travel_mm
    rapid = summary.rapid_mm_min if summary.rapid_mm_min is not None else 0.0
    return AxisRow(
        name=summary.name,
        low_mm=_mm(envelope.low_mm),
        high_mm=_mm(envelope.high_mm),
        park_mm=_mm(summary.park_mm),
        soft_limits_mm=f"{_mm(low)} … {_mm(high)}",
        max_feed_mm_min=_feed(envelope.max_feed_mm_min),
        rapid_mm_min=_feed(rapid) if rapid else "–",
    )


def _names(names: Sequence[str]) -> str:
    if len(names) <= 1:
        return "".join(names)
    return ", ".join(names[:-1]) + " and " + names[-1]


def _order(config: MachineConfig, schedule: Schedule) -> tuple[Line, ...]:
    park = [axis.name for axis in config.park_sequence()]
    measured = [axis.name for axis in schedule.axes]
    retracting = [axis for axis in config.park_sequence() if axis.retracts]
    lines: list[Line] = []
    if retracting:
        why: list[str | Code]
        if len(retracting) == 1:
            why = [Code(_retract_key(retracting[0].vertical)), " in the machine file"]
        else:
            why = ["machine file: "]
            for number, axis in enumerate(retracting):
                why += [", " if number else "", f"{axis.name} ", Code(_retract_key(axis.vertical))]
        first = _names([a.name for a in retracting])
        one = len(retracting) == 1
        lines.append(
            (
                f"{first} {'parks' if one else 'park'} first, before any other axis moves (",
                *why,
                f"); {'it is' if one else 'they are'} measured last, when the others are done. "
                f"Parking order: {', '.join(park)}, one axis at a time, at rapid.",
            )
        )
    else:
        lines.append((f"Parking order: {', '.join(park)}, one axis at a time, at rapid.",))
    lines.append(
        (
            f"Then the axes are measured one after the other ({', '.join(measured)}); each "
            "goes back to its park before the next one moves. After the parking no axis "
            "moves while another is away from its park.",
        )
    )
    return tuple(lines)


def _retract_key(vertical: bool) -> str:
    return "vertical = true" if vertical else "retract_first = true"


def _before(config: MachineConfig, dialect: Dialect) -> tuple[Line, ...]:
    start: Line
    if config.machine.confirm_start and dialect.start.without_message:
        start = (
            "The program stops before its first move and waits for cycle start (machine file: ",
            Code("confirm_start = true"),
            f'). The control shows no text there: the stop asks "{dialect.start.text}".',
        )
    elif config.machine.confirm_start:
        start = (
            "The program stops before its first move with the message ",
            Code(dialect.start.text),
            " and waits for cycle start (machine file: ",
            Code("confirm_start = true"),
            ").",
        )
    else:
        start = (
            "The program does not stop: it starts moving at once on cycle start (machine file: ",
            Code("confirm_start = false"),
            ").",
        )
    return (
        (
            "Clear the work area: remove the workpiece, clamps and loose parts; take the tool "
            "out of the spindle.",
        ),
        (
            "Check that the controller's soft limits match ",
            Code("travel_mm"),
            " of the machine file (the table above). If they differ, do not start: correct "
            "the machine file and generate again.",
        ),
        (dialect.coordinates.operator,),
        start,
        (
            "Run the first blocks (the parking) at reduced rapid override and watch every "
            "axis reach its park; then rapid override up as you like, feed override at "
            "100 % for the whole program (the velocities are the measurement).",
        ),
        ("Stay at the emergency stop while the axes move.",),
    )


def _recording(config: MachineConfig, schedule: Schedule, dialect: Dialect) -> tuple[Line, ...]:
    measure = "ncmeasure measure <machine file> --programs <this folder> --serial <serial>"
    lines: list[Line] = [
        (
            "On the computer connected to the drives: ",
            Code(measure),
            " (link options as in ",
            Code("ncmeasure record --help"),
            " unless the machine file's ",
            Code("[link]"),
            " has them). It waits for the program's start, records to its end (also when "
            "the override slows it), analyses, stores and compares; its exit code is the "
            "verdict.",
        ),
    ]
    if config.machine.confirm_start:
        lines.append(
            (
                "Start the main program: it stops at its message before any axis moves. Then "
                "start ",
                Code("measure"),
                ", then press cycle start.",
            )
        )
    else:
        lines.append(
            (
                "Start ",
                Code("measure"),
                " first, then the main program (cycle start): it moves at once.",
            )
        )
    if schedule.ready_input is not None:
        lines.append(
            (
                f"The main program waits up to {schedule.ready_timeout_s or 0:g} s before its "
                f"first move for the recorder's ready signal on input {schedule.ready_input}; ",
                Code("measure"),
                " sets it while it records. On a time-out the program stops with RECORDER NOT "
                "READY and ends: start ",
                Code("measure"),
                ", then the program again. Wiring: " + dialect.ready.wiring,
            )
        )
    lines.append(
        (
            "Recording alone: ",
            Code(f"ncmeasure record ... --schedule <this folder>/{SCHEDULE_FILE}"),
            f" stops {round(schedule.duration_s + SCHEDULE_MARGIN_S)} s after it started unless ",
            Code("--duration"),
            " says longer; then ",
            Code("ncmeasure analyze"),
            ".",
        )
    )
    return tuple(lines)


_WHERE = {
    "variable": "add the variable to the controller's trace",
    "output": "wire the output to an input the trace or data logger records, or trace it",
    "m": "trace the PLC signal the M function sets, or wire the output it switches",
}
"""Where to pick the marker up, by the kind of the option that carries it."""


def _mechanism(dialect: Dialect, options: Mapping[str, int | bool]) -> str:
    """The dialect's marker mechanism with the options' values filled in."""
    text = dialect.marker.mechanism
    for key in sorted(options, key=len, reverse=True):
        value = str(int(options[key]))
        text = text.replace(f"<{key}>", value)
        text = re.sub(rf"\b{re.escape(key)}\b", value, text)
    return text


def _marker(dialect: Dialect, schedule: Schedule) -> tuple[Line, ...]:
    options = schedule.controller_options
    scope = schedule.marker_scope
    lines: list[Line] = []
    if scope == "none":
        line: list[str | Code] = [
            "The programs write no marker: the windows come from positions (the axis "
            f"positions and velocities, with {SCHEDULE_FILE}).",
        ]
        for number, key in enumerate(dialect.marker.requires_options):
            line += [" and " if number else " For a marker set ", Code(key)]
        if dialect.marker.requires_options:
            line += [" in ", Code("[machine] controller_options"), "."]
        lines.append(tuple(line))
    else:
        value = (
            "its value is the window number of " + SCHEDULE_FILE
            if schedule.marker_values == "window_id"
            else "its value is 1"
        )
        what = (
            "on exactly while the axis crosses a measuring window"
            if scope == "window"
            else "set at standstill before each run and cleared after it (run-up, window and "
            "run-out); the window inside the run is cut by position"
        )
        lines.append((f"Marker: {_mechanism(dialect, options)}. It is {what}; {value}.",))
        kinds: list[str] = []
        for key, rule in dialect.codes.options.items():
            if key not in options:
                continue
            setting = options[key]
            if rule.zero_is_off and not setting:
                lines.append((Code(f"{key} = {setting}"), ": not used."))
                continue
            meaning = dialect.option_help.get(key, rule.meaning)
            lines.append((Code(f"{key} = {setting}"), f": {meaning}."))
            if rule.kind not in kinds:
                kinds.append(rule.kind)
        where = " or ".join(_WHERE[kind] for kind in kinds) or "trace it"
        lines.append(
            (
                "To record it with the drives: wire it to a drive's digital input (",
                Code("marker_input_bit"),
                " in the axis' CANopen link table, ",
                Code("marker"),
                " for Modbus; docs/controllers.md); or ",
                f"{where}, together with the axis signals, and import that trace (",
                Code("ncmeasure import"),
                ", column ",
                Code("<AXIS>_marker"),
                "). Without a marker the analysis cuts the windows from the commanded "
                f"velocity or the constant-velocity stretches, with {SCHEDULE_FILE}.",
            )
        )
    lines += [(warning,) for warning in dialect_warnings(dialect, dict(options))]
    return tuple(lines)


def setup_sheet(
    config: MachineConfig,
    dialect: Dialect,
    schedule: Schedule,
    plans: Sequence[AxisPlan],
    programs: Sequence[tuple[str, str, str]],
    generated: str,
) -> SetupSheet:
    """The sheet of one generated set of programs.

    Args:
        config: The machine file.
        dialect: The programs' dialect.
        schedule: What the programs do (with their file names and marker).
        plans: The axes' moves, in measuring order.
        programs: ``(role, name, file name)`` of every program, the main program first.
        generated: When the programs were generated, as their headers say.
    """
    by_name = {plan.summary.name: plan for plan in plans}
    axes = tuple(
        _axis_row(summary, axis_envelope(by_name[summary.name])) for summary in schedule.axes
    )
    if len(programs) > 1:
        programs_note: Line = (
            "Copy every file into one folder of the control and start the main program; it "
            "calls the subprograms.",
        )
    else:
        programs_note = ("One program holds the whole measurement; copy it to the control.",)
    return SetupSheet(
        title=f"Setup sheet: friction measurement of {schedule.machine}",
        subtitle=f"{dialect.title} ({dialect.name}) · generated {generated} by ncmeasure "
        f"{schedule.ncmeasure_version}, config {schedule.config_hash}",
        duration=duration_text(schedule.duration_s),
        programs=tuple(ProgramRow(*program) for program in programs),
        programs_note=programs_note,
        axes=axes,
        axes_note="Machine positions. Lowest and highest: what any move of the programs "
        "reaches (parking, warm-up strokes, the start and stop of every run).",
        order=_order(config, schedule),
        before=_before(config, dialect),
        recording=_recording(config, schedule, dialect),
        marker=_marker(dialect, schedule),
    )


# --- rendering ------------------------------------------------------------------------------


class _Markdown(str):
    """Text that is Markdown already (a code span): not escaped again."""


_MARKDOWN_INLINE = re.compile(r"([\\`*_\[\]<>|~])")
_MARKDOWN_ENTITY = re.compile(r"&(?=#?\w+;)")
_MARKDOWN_BLOCK = re.compile(r"^([-+#])(?=[-+#]*(\s|$))|^(\d+)([.)])(?=\s|$)")
_MARKDOWN_CLOSING = re.compile(r"(\s)(#+)\s*$")


def _escape_markdown(value: object) -> str:
    """Every value the Markdown template writes, but code spans: literal text on one line.

    Characters that make inline markup anywhere (emphasis, links, code, HTML, a table's
    cell border, an entity) are escaped everywhere; those that start a block (a list, a
    heading, a quote) or close a heading only where they would.
    """
    if isinstance(value, _Markdown):
        return value
    text = re.sub(r"\s+", " ", str(value))
    text = _MARKDOWN_INLINE.sub(r"\\\1", text)
    text = _MARKDOWN_ENTITY.sub(r"\\&", text)
    text = _MARKDOWN_BLOCK.sub(
        lambda m: f"\\{m.group(1)}" if m.group(1) else f"{m.group(3)}\\{m.group(4)}", text
    )
    return _MARKDOWN_CLOSING.sub(lambda m: m.group(1) + "\\#" * len(m.group(2)), text)


def _code_span(value: str) -> _Markdown:
    text = " ".join(value.split())
    fence = "`" * (max((len(run) for run in re.findall(r"`+", text)), default=0) + 1)
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    return _Markdown(f"{fence}{pad}{text}{pad}{fence}")


def _markdown_line(parts: Line) -> _Markdown:
    return _Markdown(
        "".join(
            _code_span(part.text) if isinstance(part, Code) else _escape_markdown(part)
            for part in parts
        )
    )


@functools.cache
def _environment(markdown: bool) -> SandboxedEnvironment:
    env = SandboxedEnvironment(
        loader=jinja2.PackageLoader("ncmeasure.program", "setup_sheet"),
        autoescape=not markdown,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        finalize=_escape_markdown if markdown else None,
    )
    env.tests["code"] = lambda value: isinstance(value, Code)
    env.filters["code_span"] = _code_span
    env.filters["line"] = _markdown_line
    return env


def render_setup_markdown(sheet: SetupSheet) -> str:
    """SETUP.md."""
    return _environment(True).get_template("SETUP.md.j2").render(sheet=sheet)


def render_setup_html(sheet: SetupSheet) -> str:
    """setup.html: one page, its CSS inline, nothing loaded from elsewhere."""
    return _environment(False).get_template("setup.html.j2").render(sheet=sheet)
