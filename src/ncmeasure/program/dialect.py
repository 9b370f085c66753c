"""Controller dialects: the facts of one NC language, read from ``controllers/<name>.toml``.

A dialect file says how programs are named and stored, how numbers, words,
comments and block numbers are written, which marker mechanism the programs
use, which machine-specific options a machine file may set, and how
ncmeasure's own program reader recognises calls, returns and markers. The
G-code shapes themselves live in the dialect's templates.
"""

from __future__ import annotations

import re
import string
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from ncmeasure.errors import ConfigError, DialectError
from ncmeasure.inputs import (
    MAX_TOML_BYTES,
    format_validation_error,
    parse_toml,
    plain_file_name,
    read_text,
)
from ncmeasure.resources import available_dialects

if TYPE_CHECKING:  # the machine-file models: `init` and `controllers` read no machine file
    from ncmeasure.config import MachineConfig

__all__ = [
    "Dialect",
    "available_dialects",
    "dialect_warnings",
    "load_dialect",
    "marker_m_functions",
    "marker_scope",
    "option_problems",
    "ready_problems",
    "validate_for_dialect",
]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


OPTION_PLACEHOLDER = re.compile(r"<<(\w+)>>")
"""``<<option>>`` in a reader pattern: the value of a controller option."""
MAX_FORMAT_WIDTH = 32
"""Widest field a naming format may ask for (``O{number:08d}`` asks for 8)."""


def _invalid(message: str) -> PydanticCustomError:
    """A validation error whose message is ``message`` as written (braces included)."""
    return PydanticCustomError("dialect", "{message}", {"message": message})


def _regex(value: str, group: str | None = None) -> str:
    """A regular expression, ``<<option>>`` standing for a number; ``group`` is required."""
    try:
        compiled = re.compile(OPTION_PLACEHOLDER.sub("1", value), re.I)
    except re.error as exc:
        raise _invalid(f"invalid regular expression {value!r}: {exc}") from exc
    if group is not None and group not in compiled.groupindex:
        raise _invalid(f"needs the group (?P<{group}>...): {value!r}")
    return value


Regex = Annotated[str, AfterValidator(_regex)]
"""A regular expression (checked when the definition is loaded)."""


def _no_control(value: str) -> str:
    for char in value:
        if not char.isprintable():
            raise _invalid(f"{char!r} is a control character")
    return value


# What each naming format may use, and a value to try it with.
_FIELDS: dict[str, tuple[str, ...]] = {
    "number_format": ("number",),
    "main": ("program", "axis"),
    "sub": ("program", "axis"),
    "main_file": ("name",),
    "sub_file": ("name",),
    "axis_word": ("axis", "value"),
    "long_axis_word": ("axis", "value"),
}
_SAMPLES: dict[str, object] = {
    "number": 1234,
    "program": "FRICTION",
    "axis": "X",
    "name": "FRICTION_X",
    "value": "-100.000",
}
_SPEC = re.compile(
    r"(?:(?P<fill>.)?[<>=^])?[+\- ]?z?#?(?P<width>\d*)[,_]?(?:\.(?P<precision>\d+))?[A-Za-z%]?"
)
# Characters the literal text of a format may hold: program names, file names, words.
_NAME_CHARACTERS = re.compile(r"[A-Za-z0-9_]")
_WORD_CHARACTERS = re.compile(r"[ -~]")
_FILE_NAME = re.compile(r"[A-Za-z0-9_.\-]+")


def _format_problem(key: str, value: str) -> str | None:
    """What is wrong with the naming format ``key`` = ``value``, or None."""
    fields = _FIELDS[key]
    allowed = ", ".join("{" + name + "}" for name in fields)
    try:
        parsed = list(string.Formatter().parse(value))
    except ValueError as exc:
        return f"not a format string ({exc}): {value!r}"
    characters, what = (
        (_WORD_CHARACTERS, "a program word")
        if "word" in key
        else (_NAME_CHARACTERS, "a program name")
    )
    for literal, field, spec, conversion in parsed:
        if not key.endswith("_file"):
            for char in literal:
                if not characters.fullmatch(char):
                    return f"{char!r} is not a character of {what}"
        if field is None:
            continue
        if field not in fields:
            return f"{{{field}}} is not one of {allowed}"
        if conversion:
            return f"no conversion (!{conversion}) in {{{field}}}"
        if not spec:
            continue
        if "{" in spec:
            return f"a field inside a format spec: {{{field}:{spec}}}"
        match = _SPEC.fullmatch(spec)
        if not match:
            return f"{spec!r} is not a format spec"
        fill = match.group("fill")
        if fill is not None and not _NAME_CHARACTERS.fullmatch(fill):
            return f"fill character {fill!r}: use a letter, digit or underscore"
        for part in ("width", "precision"):
            number = match.group(part)
            if number and (len(number) > 3 or int(number) > MAX_FORMAT_WIDTH):
                return f"{part} {number} is more than {MAX_FORMAT_WIDTH}"
    try:
        sample = value.format(**{name: _SAMPLES[name] for name in fields})
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        return str(exc)
    if key.endswith("_file"):
        if not plain_file_name(sample) or not _FILE_NAME.fullmatch(sample):
            return f"{sample!r} is not a plain file name (letters, digits, '_', '-', '.')"
        suffix = Path(sample).suffix.lower()
        if not re.fullmatch(r"\.[a-z0-9]+", suffix):
            return f"needs an extension that tells program files from others: {value!r}"
        if suffix == ".json":
            return ".json is the schedule's extension"
        if suffix in (".md", ".html"):
            return f"{suffix} is the setup sheet's extension (SETUP.md, setup.html)"
    return None


class Names(_Strict):
    """How programs and their files are named."""

    numbered: bool = False
    """Programs are numbers (Fanuc O-numbers): name = number_format."""
    number_format: str = "O{number:04d}"
    max_number: int = Field(9999, ge=1, le=99_999_999)
    main: str = "{program}"
    sub: str = "{program}_{axis}"
    case: Literal["upper", "lower", "keep"] = "upper"
    pattern: Regex = r"^[A-Z][A-Z0-9_]*$"
    max_length: int = Field(24, ge=1, le=255)
    main_file: str = "{name}.nc"
    sub_file: str = "{name}.nc"
    axis_pattern: Regex = r"^[XYZ]$"
    axis_word: str = "{axis}{value}"
    """How an axis word is written."""
    long_axis_word: str = "{axis}={value}"
    """How the word of an axis whose name has more than one character is written."""

    @field_validator(*_FIELDS)
    @classmethod
    def _check_format(cls, value: str, info: ValidationInfo) -> str:
        assert info.field_name is not None
        problem = _format_problem(info.field_name, value)
        if problem:
            raise _invalid(problem)
        return value


class Numbers(_Strict):
    """How numbers are written."""

    decimals: int = Field(3, ge=0, le=6)
    plus_sign: bool = False
    feed_decimals: int = Field(3, ge=0, le=6)
    feed_trailing_point: bool = False
    """Write 'F1000.' rather than 'F1000' for whole feeds."""
    decimal_point: bool = False
    """Every axis word and dwell time carries a decimal point: without one FANUC reads
    the number in its least input increment (X100 is 0.1 mm, G04 X1 is 1 ms). The
    checker refuses an axis word or dwell without one."""


class Blocks(_Strict):
    """Block numbers added after rendering."""

    numbered: bool = False
    start: int = Field(10, ge=0, le=99_999_999)
    step: int = Field(10, ge=1, le=99_999_999)
    skip: Regex = r"^(%|N)"
    """Lines that get no block number (regular expression)."""


class Comments(_Strict):
    """Comment syntax, or none."""

    supported: bool = True
    open: Annotated[str, AfterValidator(_no_control)] = "("
    close: Annotated[str, AfterValidator(_no_control)] = ")"
    forbidden: str = "()"
    """Characters removed from comment text."""
    upper: bool = False


class Marker(_Strict):
    """How the programs mark a measuring window."""

    scope: Literal["window", "run", "none"]
    """'window': the marker is on exactly during the window block; 'run': it is
    written at standstill before and after the whole run (run-up to stop);
    'none': the dialect has no usable marker, windows come from positions."""
    values: Literal["window_id", "flag"] = "window_id"
    requires_options: Sequence[str] = ()
    """The marker exists only when these options are all set (non-zero); with none of
    them set the scope is 'none', with only some set the machine file is refused."""
    mechanism: str
    """What the marker is and why it is synchronous with motion."""


class Reader(_Strict):
    """Patterns ncmeasure's program reader uses for this dialect (case-insensitive).

    ``<<option>>`` in a pattern stands for the value of a controller option; a
    pattern whose option is 0 or false is not used.
    """

    comments: Sequence[Regex] = (r"\(.*?\)", r";.*$")
    ignore: Sequence[Regex] = ()
    """Whole lines to skip (program headers and the like)."""
    tape: Regex | None = None
    """The tape mark ('%' on FANUC and LinuxCNC), matched against a whole line: a file
    whose first non-blank line is one ends at the next one (text after it is refused);
    anywhere else it is refused."""
    program_start: Annotated[str, AfterValidator(lambda v: _regex(v, "key"))] | None = None
    """Splits a file into programs; group 'key' names the program."""
    program_key: Literal["stem", "file"] = "stem"
    call: Annotated[str, AfterValidator(lambda v: _regex(v, "key"))] | None = None
    """A subprogram call; group 'key' names the called program."""
    ret: Regex | None = None
    end: Regex = r"^M(30|0?2)$"
    marker: Sequence[Regex] = ()
    """Set the marker; optional group 'value' (default 1)."""
    marker_off: Sequence[Regex] = ()
    dwell: Annotated[str, AfterValidator(lambda v: _regex(v, "seconds"))] | None = None
    """A dwell block written without G4 (e.g. '#TIME 1.5'); group 'seconds'."""
    dwell_word: str = Field("P", pattern=r"^[A-Z]$")
    dwell_scale: float = Field(1.0, gt=0, le=1e6)
    """Seconds per unit of the dwell word."""
    integer_unit_mm: float = Field(1.0, gt=0, le=1e6)
    """Value of an axis word written without decimal point (Fanuc: 0.001 mm)."""
    block_end: Regex | None = None
    accepted: Sequence[str] = ()
    """G and M words (e.g. 'G64', 'M30') that are accepted and do not move an axis."""
    parameter_words: str = "PQEHRDLST"
    """Address letters that are parameters of another word in the same block."""


class OptionRule(_Strict):
    """What a numeric controller option is, and which values the control allows for it."""

    kind: Literal["m", "variable", "output"]
    """An M function, a variable the program writes, or an output it sets."""
    meaning: str
    """What the option is, for messages (``common macro variable``)."""
    allowed: Sequence[tuple[int, int]]
    """Allowed values as inclusive ranges."""
    zero_is_off: bool = False
    """0 means "not used" and is always allowed."""
    uses: Sequence[Annotated[str, AfterValidator(lambda v: _regex(v, "n"))]] = ()
    """Patterns (group 'n') that find where a program uses a number of this kind;
    for kind 'm' every M word is found anyway."""
    source: str = ""


class Codes(_Strict):
    """The M functions, variables and outputs a program of the dialect may use."""

    program_m: Sequence[int]
    """M functions the programs write for their own structure (end, call, return, outputs)."""
    reserved_m: Sequence[tuple[int, int]] = ()
    """M functions with a fixed meaning on every control of the kind: never a marker."""
    m_meaning: dict[str, str] = Field(default_factory=dict)
    """What reserved M functions do, by number, for messages."""
    m_range: tuple[int, int] = (0, 99)
    """M numbers the control reads at all."""
    ascii_only: bool = False
    """The control reads ISO/EIA code only: every character of a program is ASCII."""
    sources: Sequence[str] = ()
    options: dict[str, OptionRule] = Field(default_factory=dict)
    """One rule per numeric controller option."""

    def reserved(self, number: int) -> bool:
        """True for an M function with a fixed meaning."""
        return any(low <= number <= high for low, high in self.reserved_m)

    def meaning(self, number: int) -> str:
        """What an M function does, where the dialect says."""
        return self.m_meaning.get(str(number), "")


OffsetKind = Literal["work", "shift", "length", "radius", "cycle", "transform"]
"""What an operator may leave active that moves a programmed position or path:
``work`` a work offset (G54…G59, G54.1 P, a settable frame, an external offset),
``shift`` a coordinate shift (G92, G52, a programmable frame, DRF, PRESET),
``length`` / ``radius`` tool length and radius compensation, ``cycle`` a modal
canned cycle, ``transform`` a kinematic transformation (TRAORI, TRANSMIT)."""
OFFSET_KINDS: tuple[OffsetKind, ...] = ("work", "shift", "length", "radius", "cycle")
"""The kinds every control has; ``transform`` only where the dialect names it."""
OFFSET_MEANING: dict[str, str] = {
    "work": "a work offset (G54..G59, frame)",
    "shift": "a coordinate shift (G92, G52, programmable frame)",
    "length": "tool length compensation",
    "radius": "tool radius compensation",
    "cycle": "a modal canned cycle",
    "transform": "a kinematic transformation",
}


class CodeEffect(_Strict):
    """What one code of the prolog or a motion block does to the operator's offsets."""

    meaning: str
    """What the code is, for messages and the docs."""
    cancels: Sequence[OffsetKind] = ()
    """Modal: from this block on, these offsets are off."""
    bypasses: Sequence[OffsetKind] = ()
    """Non-modal: the positions of this block ignore these offsets."""
    sets: Sequence[OffsetKind] = ()
    """Selects or sets these offsets: refused in a program (its moves would shift)."""
    source: str = ""
    """The manual page that says so."""


class Verification(_Strict):
    """Prolog blocks that read the active offsets and stop with an alarm unless they are
    zero, where the control cannot feed in machine coordinates (FANUC's G53 is rapid
    only): one block per axis, each self-contained (no jumps a hand edit could
    reorder), the axis' number in the control in group ``n``. Once every axis has its
    block the named offsets are known to be zero, or the program stopped."""

    pattern: Annotated[str, AfterValidator(lambda v: _regex(v, "n"))]
    """One axis' block (after comments are removed, in capitals); group ``n``."""
    proves: Sequence[OffsetKind] = ()
    """Offsets known to be zero once every axis has been verified."""


class Coordinates(_Strict):
    """How every move lands at the same machine position whatever the operator left
    active, read by ``ncmeasure check`` from the codes themselves.

    At the start of a program every offset kind the control has may be active. A
    ``cancels`` code turns it off, a ``bypasses`` code in a motion block ignores it
    for that block, a verification proves it zero; a motion block while an offset may
    still act is refused, and so is any code that ``sets`` one.
    """

    offsets: Sequence[OffsetKind] = OFFSET_KINDS
    """The offsets the control has."""
    codes: dict[str, CodeEffect] = Field(default_factory=dict)
    """Codes by their written form (G53, SUPA, D0, M91), upper case, no leading zeros."""
    verify: Verification | None = None
    prolog: str = ""
    """The prolog and each motion block as written, and why they are safe (the docs)."""
    operator: str = (
        "The program works in machine coordinates, whatever work offset or tool is active: "
        "it selects them itself."
    )
    """What the setup sheet tells the operator about offsets before cycle start."""
    sources: Sequence[str] = ()


START_MESSAGE = "ncmeasure: table clear, no tool, feed override 100? Cycle start to measure"
"""The operator message of the stop before the first move."""


class Start(_Strict):
    """The programmed stop and operator message before the first move."""

    text: str = START_MESSAGE
    """The message as the dialect's programs show it (FANUC's #3006 shows 26 characters)."""
    stop: Sequence[Regex] = (r"^M0?0$",)
    """Blocks that stop the program until cycle start."""
    message: Sequence[Regex] = ()
    """Whole lines, matched before comments are removed, that show the operator a
    non-empty message."""
    clear: Sequence[Regex] = ()
    """Whole lines that clear the message (SINUMERIK ``MSG()``): read, no message."""
    stop_message: Sequence[Regex] = ()
    """Whole lines, matched before comments are removed, that stop with their own
    non-empty message (FANUC ``#3006=1(TEXT)``)."""
    without_message: str = ""
    """Why the dialect's stop shows no message (none could be verified); the setup
    sheet tells the operator what the stop means instead."""
    source: str = ""


READY_MESSAGE = "RECORDER NOT READY"
"""What a program shows when the recorder's ready signal did not come in time."""


class Ready(_Strict):
    """How the main program waits for the recorder's ready signal before its first move.

    The machine file's ``ready_input`` names the controller's digital input the
    recorder's ready output is wired to; the program waits until it is high, at most
    ``ready_timeout_s``, and on a time-out shows :data:`READY_MESSAGE` and ends, so a
    cycle start never moves the machine while nothing records. The templates write the
    blocks; the reader recognises them by these patterns (matched against whole
    lines, block numbers removed, before comments are removed): the wait, then the
    time-out branch line by line. A dialect without a verified way to wait says why
    in ``unsupported``, and ``generate`` refuses ``ready_input`` for it.
    """

    unsupported: str = ""
    """Why the dialect's programs cannot wait for an input (nothing verified)."""
    wait: Regex | None = None
    """The block that waits; groups ``input`` (the input's number) and ``timeout``
    (seconds)."""
    any_wait: Regex | None = None
    """Any block that waits on an input: one ``wait`` does not match lacks its
    time-out (or is malformed) and is refused."""
    on_timeout: Sequence[Regex] = ()
    """The lines right after the wait, in order: the branch taken on a time-out, which
    shows the message and ends the program."""
    inputs: Sequence[tuple[int, int]] = ()
    """Input numbers the control has, as inclusive ranges."""
    input_meaning: str = "digital input"
    wiring: str = ""
    """How the recorder's ready output reaches the input, for the setup sheet."""
    source: str = ""

    @model_validator(mode="after")
    def _complete(self) -> Ready:
        if not self.unsupported and (self.wait is None or not self.inputs):
            raise ValueError("[ready] needs wait and inputs, or unsupported saying why not")
        if self.wait is not None:
            _regex(self.wait, "input")
            _regex(self.wait, "timeout")
        return self


class Memory(_Strict):
    """How much program text the control is assumed to hold."""

    program_kb: int = Field(2048, ge=1, le=1_000_000)
    """Default of the machine file's ``limits.max_program_kb``."""
    note: str = ""
    """Where the figure comes from, or why it is a conservative assumption."""


class Dialect(_Strict):
    """One controller dialect."""

    name: str
    title: str
    description: str
    sources: Sequence[str]
    """Manual pages and documents the dialect was verified against."""
    left_out: Sequence[str] = ()
    """Constructs that could not be verified and are therefore not used."""
    subprograms: bool = True
    """False: the main program holds every axis' measurement inline."""
    dwell: bool = True
    names: Names = Names()
    numbers: Numbers = Numbers()
    blocks: Blocks = Blocks()
    comments: Comments = Comments()
    marker: Marker
    codes: Codes
    memory: Memory = Memory()
    coordinates: Coordinates = Coordinates()
    start: Start = Start()
    ready: Ready = Ready(
        unsupported="no way for a program to wait on an input was verified for this controller"
    )
    options: dict[str, int | bool] = Field(default_factory=dict)
    """Machine-specific settings with their defaults; a machine file may override them
    in [machine.controller_options]."""
    option_help: dict[str, str] = Field(default_factory=dict)
    option_warnings: dict[str, str] = Field(default_factory=dict)
    """Warning shown when an option is left at 0 / false."""
    reader: Reader = Reader()

    @model_validator(mode="after")
    def _every_option_has_a_rule(self) -> Dialect:
        for key, value in self.options.items():
            if (
                isinstance(value, int)
                and not isinstance(value, bool)
                and key not in self.codes.options
            ):
                raise ValueError(f"option {key} has no rule in [codes.options.{key}]")
        low, high = self.codes.m_range
        for key, rule in self.codes.options.items():
            if key not in self.options:
                raise ValueError(f"[codes.options.{key}] names no option of the dialect")
            if rule.kind == "m" and any(a < low or b > high for a, b in rule.allowed):
                raise ValueError(
                    f"[codes.options.{key}] allows M functions outside m_range {low}-{high}"
                )
        return self

    def program_name(self, template: str, program: str, axis: str = "", number: int = 0) -> str:
        """A program name in the dialect's spelling."""
        if self.names.numbered:
            return self.names.number_format.format(number=number)
        name = template.format(program=program, axis=axis)
        if self.names.case == "upper":
            return name.upper()
        if self.names.case == "lower":
            return name.lower()
        return name

    @property
    def program_extensions(self) -> set[str]:
        """File extensions of the dialect's program files, lower case (``.nc``)."""
        return {
            Path(self.names.main_file).suffix.lower(),
            Path(self.names.sub_file).suffix.lower(),
        }


def load_dialect(name: str, user_dirs: Iterable[Path] = ()) -> Dialect:
    """Read and validate the dialect called ``name``.

    Raises:
        DialectError: unknown dialect, or a broken dialect file.
    """
    dialects = available_dialects(user_dirs)
    if name not in dialects:
        known = ", ".join(dialects) or "none"
        raise DialectError(f"unknown controller {name!r}; known controllers: {known}")
    path = dialects[name]
    text = read_text(path, "a controller definition (.toml)", MAX_TOML_BYTES, DialectError)
    data = parse_toml(text, str(path), DialectError)
    try:
        dialect = Dialect.model_validate(data)
    except ValidationError as exc:
        raise DialectError(
            f"{path} is not a valid controller definition", format_validation_error(exc)
        ) from exc
    if dialect.name != name:
        raise DialectError(f"{path}: name = {dialect.name!r} does not match the file name")
    return dialect


def validate_for_dialect(config: MachineConfig, dialect: Dialect) -> dict[str, int | bool]:
    """Check what only the dialect can judge; return the effective controller options.

    Raises:
        ConfigError: with a ``location: message`` line per problem.
    """
    problems: list[str] = []
    names = dialect.names
    for index, axis in enumerate(config.axes):
        if not re.fullmatch(names.axis_pattern, axis.name):
            problems.append(
                f"axes[{index}].name: {axis.name!r} is not an axis name {dialect.title} allows "
                f"(pattern {names.axis_pattern})"
            )
    if names.numbered:
        last = config.machine.program_number + len(config.axes)
        if last > names.max_number:
            problems.append(
                f"machine.program_number: {config.machine.program_number} leaves no room for "
                f"{len(config.axes)} subprograms below {names.max_number}"
            )
    else:
        candidates = [("machine.program", dialect.program_name(names.main, config.machine.program))]
        if dialect.subprograms:
            candidates += [
                (f"axes[{i}].name", dialect.program_name(names.sub, config.machine.program, a.name))
                for i, a in enumerate(config.axes)
            ]
        for where, program in candidates:
            if len(program) > names.max_length or not re.fullmatch(names.pattern, program):
                problems.append(
                    f"{where}: program name {program!r} breaks the {dialect.title} naming rule "
                    f"(at most {names.max_length} characters matching {names.pattern})"
                )
    options = dict(dialect.options)
    for key, value in config.machine.controller_options.items():
        where = f"machine.controller_options.{key}"
        if key not in options:
            known = ", ".join(options) or "none"
            problems.append(f"{where}: unknown option for {dialect.name} (options: {known})")
        elif type(value) is not type(options[key]):
            problems.append(f"{where}: expected {type(options[key]).__name__}, got {value!r}")
        else:
            options[key] = value
    if not dialect.dwell and any(config.measurement_for(axis).dwell_s > 0 for axis in config.axes):
        problems.append(
            f"measurement.dwell_s: {dialect.title} programs use no dwell (not verified for this "
            "dialect); set dwell_s = 0"
        )
    required = dialect.marker.requires_options
    given = [name for name in required if options.get(name)]
    if given and len(given) < len(required):
        missing = ", ".join(name for name in required if name not in given)
        problems.append(
            f"machine.controller_options: the marker needs {' and '.join(required)} "
            f"together; {missing} is not set"
        )
    for key, value in options.items():
        if isinstance(value, int) and not isinstance(value, bool) and value < 0:
            problems.append(f"machine.controller_options.{key}: must not be negative")
    problems += option_problems(dialect, options)
    problems += ready_problems(config, dialect)
    if problems:
        raise ConfigError(f"the machine does not fit controller {dialect.name}", problems)
    return options


def ready_problems(config: MachineConfig, dialect: Dialect) -> list[str]:
    """What stops the main program from waiting for the recorder's ready signal."""
    number = config.machine.ready_input
    if number is None:
        return []
    ready = dialect.ready
    if ready.unsupported:
        return [
            f"machine.ready_input: {dialect.title} programs cannot wait for the recorder's "
            f"ready signal ({ready.unsupported}); remove ready_input and have the "
            "technician press cycle start once the recorder waits (ncmeasure measure shows "
            "when it does)"
        ]
    if not any(low <= number <= high for low, high in ready.inputs):
        source = f"; {ready.source}" if ready.source else ""
        return [
            f"machine.ready_input: {number} is not {_article(ready.input_meaning)} "
            f"{dialect.title} has ({_ranges(ready.inputs)}{source})"
        ]
    return []


def _article(noun: str) -> str:
    """'a' or 'an' as the noun is spoken: an M function, an R parameter, an analog output."""
    first = noun.split()[0] if noun.strip() else noun
    spoken_vowel = first[:1].lower() in "aeiou" or (len(first) == 1 and first in "AEFHILMNORSX")
    return f"{'an' if spoken_vowel else 'a'} {noun}"


def _ranges(ranges: Sequence[tuple[int, int]]) -> str:
    return ", ".join(f"{low}" if low == high else f"{low}-{high}" for low, high in ranges)


def option_problems(
    dialect: Dialect, options: Mapping[str, int | bool], place: str = "machine.controller_options"
) -> list[str]:
    """What is wrong with numeric controller options, judged by the dialect's [codes].

    Every value must be one the control allows for its kind; an M function must not
    be reserved or one of the program's own; the marker's M functions must differ.
    """
    codes = dialect.codes
    problems: list[str] = []
    m_values: dict[int, str] = {}
    for key, rule in codes.options.items():
        value = options.get(key)
        if value is None or isinstance(value, bool) or (value == 0 and rule.zero_is_off):
            continue
        where = f"{place}.{key}"
        source = f"; {rule.source}" if rule.source else ""
        shown = f"M{value}" if rule.kind == "m" else str(value)
        if not any(low <= value <= high for low, high in rule.allowed):
            problems.append(
                f"{where}: {shown} is not {_article(rule.meaning)} {dialect.title} allows "
                f"({_ranges(rule.allowed)}{' or 0 for none' if rule.zero_is_off else ''}{source})"
            )
            continue
        if rule.kind != "m":
            continue
        meaning = codes.meaning(value)
        does = f" ({meaning})" if meaning else ""
        if codes.reserved(value):
            problems.append(
                f"{where}: M{value} is reserved on {dialect.title}{does}; use an M function "
                "the machine builder set aside for the marker"
            )
        elif value in codes.program_m:
            problems.append(
                f"{where}: M{value} is one the programs use themselves{does}; use another"
            )
        elif value in m_values:
            problems.append(
                f"{where}: M{value} is also {place}.{m_values[value]}: the marker's M "
                "functions must differ"
            )
        m_values.setdefault(value, key)
    return problems


def marker_m_functions(dialect: Dialect, options: Mapping[str, int | bool]) -> set[int]:
    """M functions the options make part of the program (the marker's, when set)."""
    return {
        int(options[key])
        for key, rule in dialect.codes.options.items()
        if rule.kind == "m" and not isinstance(options.get(key), bool) and options.get(key)
    }


def marker_scope(dialect: Dialect, options: dict[str, int | bool]) -> str:
    """The marker scope the programs really have with these options."""
    if not all(options.get(name) for name in dialect.marker.requires_options):
        return "none"
    return dialect.marker.scope


def dialect_warnings(dialect: Dialect, options: dict[str, int | bool]) -> list[str]:
    """Warnings that the chosen options deserve (e.g. a marker left unsynchronised)."""
    return [
        f"{dialect.name}: {message}"
        for key, message in dialect.option_warnings.items()
        if not options.get(key)
    ]
