"""ncmeasure's own small G-code reader, independent of the templates.

It reads the files of a generated program the way a controller would:
starting at the main program, following subprogram calls and returns,
tracking the modal motion (G0/G1), the feed, every axis position (absolute
only) and the marker. Everything else it meets must be a word the dialect
declares harmless; anything unknown is an error, so a template that starts
writing something new cannot slip past the checker unread.

Every line of every program file is read or refused: lines are split at
``\n`` only (as controls read them), each must hold only characters the
control reads, a ``%`` tape mark is honoured where FANUC and LinuxCNC honour
it (a file whose first line is one ends at the next), and text outside every
program (before the first program number, after the closing ``%``) or a
program number given twice is a problem, not something left unread.

The result is the list of motions the program would command, which
:mod:`ncmeasure.program.check` compares with the limits and the schedule.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from ncmeasure.errors import ProgramError
from ncmeasure.inputs import read_text
from ncmeasure.program.dialect import OFFSET_MEANING, OPTION_PLACEHOLDER, Dialect

__all__ = [
    "CodeUse",
    "Dwell",
    "Motion",
    "ProgramSet",
    "ProgramTrace",
    "ReadyWait",
    "Stop",
    "read_programs",
    "scan_codes",
]

_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)"
_WORD = re.compile(
    rf"\s*(?:(?P<long>[A-Z]+\d+)\s*=\s*(?P<lval>{_NUMBER})|(?P<addr>[A-Z])\s*(?P<val>{_NUMBER}))"
)
_MAX_STEPS = 1_000_000
"""Blocks a run may take (the largest plan the limits allow runs about 300 000)."""
MAX_PROGRAM_FILE_BYTES = 16 * 1024 * 1024
"""Largest program file read (generate writes none larger)."""
MAX_PROGRAM_BYTES = 32 * 1024 * 1024
"""Most program text read from one folder (generate writes no more)."""


@dataclass(frozen=True, slots=True)
class Motion:
    """One commanded straight move."""

    kind: Literal["rapid", "feed"]
    program: str
    line: int
    start: dict[str, float | None]
    """Positions of the moved axes before the move (None: not yet known)."""
    target: dict[str, float]
    feed_mm_min: float | None
    marker: float
    calls: int
    """How many subprogram calls had been made when the move started."""
    file: str = ""
    """File name of the program."""


@dataclass(frozen=True, slots=True)
class Dwell:
    """A dwell: the axes stand still for ``seconds``."""

    program: str
    line: int
    seconds: float
    marker: float
    file: str = ""


@dataclass(frozen=True, slots=True)
class CodeUse:
    """An M function, or a number of a controller option's kind, written in a program."""

    kind: str
    """'m', or the name of the controller option whose kind the number is."""
    number: int
    """The number; one of more than 18 digits counts as 10¹⁸, beyond every range."""
    file: str
    line: int
    written: str = ""
    """The digits as a message shows them (long ones cut)."""

    @property
    def shown(self) -> str:
        """The number for a message."""
        return self.written or str(self.number)


@dataclass(frozen=True, slots=True)
class Stop:
    """A programmed stop: the program waits for cycle start."""

    program: str
    line: int
    message: bool
    """An operator message was shown with it (in its block or just before)."""
    calls: int
    """How many subprogram calls had been made."""
    file: str = ""


@dataclass(frozen=True, slots=True)
class ReadyWait:
    """A wait for the recorder's ready signal: the program goes on once the input is
    high, or shows a message and ends after ``timeout_s`` (the dialect's time-out branch,
    which the reader skips: the recorder it assumes is ready)."""

    program: str
    line: int
    input: int
    """The controller's input waited on."""
    timeout_s: float
    calls: int
    """How many subprogram calls had been made."""
    file: str = ""


# An M word: 'M', spaces allowed, digits; not inside a name (FRICTION_M3, o<m3_x>, %M3).
_M_WORD = re.compile(r"(?<![A-Z0-9_<%$.\[])M\s*(?P<n>\d+)", re.I)


@dataclass
class ProgramTrace:
    """What a program commands, in order."""

    motions: list[Motion] = field(default_factory=list)
    dwells_s: list[float] = field(default_factory=list)
    steps: list[Motion | Dwell | Stop | ReadyWait] = field(default_factory=list)
    """Motions, dwells, stops and ready waits in the order the program commands them."""
    calls: list[str] = field(default_factory=list)
    ended: bool = False
    stopped: str = ""
    """Where the program stopped itself because an offset it verifies was not zero."""
    problems: list[str] = field(default_factory=list)
    """Rules the program files break where they can still be read, one
    ``file:line: message`` each (text outside every program, a program number
    given twice, a character the control cannot read)."""


@dataclass
class _Program:
    key: str
    file: str
    line: int
    """Line of its program number (0: the program is the file)."""
    texts: list[str]
    """Every line of its file as the reader sees it (comments removed, capitals)."""
    first: int
    """Index in ``texts`` of its first block."""
    end: int = -1
    """Index in ``texts`` after its last block (-1 while the file is read)."""


def _digits(text: str) -> str:
    """The digits of a whole number without leading zeros ('0' for zero)."""
    return text.lstrip("0") or "0"


_LONGEST = 18
_BEYOND = 10**_LONGEST
"""What a number of more digits counts as: beyond every range a dialect allows."""


def _whole(text: str) -> int:
    """A whole number written as digits; one of more than 18 digits counts as 10¹⁸
    (converting thousands of digits is slow, and Python refuses more than 4300)."""
    digits = _digits(text)
    return int(digits) if len(digits) <= _LONGEST else _BEYOND


def _shown(text: str, width: int = 12) -> str:
    """Text for a message: a long number or word cut, with its length."""
    if len(text) <= _LONGEST:
        return text
    unit = "digits" if text.isdigit() else "characters"
    return f"{text[:width]}… ({len(text)} {unit})"


def _program_key(name: str) -> str:
    """How a program is looked up: names in capitals, numbers without leading zeros
    (FANUC's M98 P2 calls O0002)."""
    return _digits(name) if name.isdigit() else name.upper()


def _patterns(patterns: Iterable[str], options: Mapping[str, int | bool]) -> list[re.Pattern[str]]:
    """Compile patterns, filling in ``<<option>>``; drop those whose option is unset."""
    compiled = []
    for pattern in patterns:
        names = OPTION_PLACEHOLDER.findall(pattern)
        if any(not options.get(name) for name in names):
            continue
        text = OPTION_PLACEHOLDER.sub(lambda m: str(int(options[m.group(1)])), pattern)
        compiled.append(re.compile(text, re.I))
    return compiled


def _pattern(pattern: str | None, options: Mapping[str, int | bool]) -> re.Pattern[str] | None:
    found = _patterns([pattern] if pattern else [], options)
    return found[0] if found else None


_ADDRESS_CODE = re.compile(r"[A-Z]\d+(\.\d+)?", re.I)
"""A code that is an address and a number (G53, D0, M91); others are keywords (SUPA)."""


def _keyword(code: str) -> re.Pattern[str]:
    """A keyword code as a whole word, spaces between its parts as the control reads them."""
    parts = r"\s+".join(re.escape(part) for part in code.split())
    return re.compile(rf"(?<![A-Z0-9_#$]){parts}(?![A-Z0-9_])", re.I)


def _code_name(address: str, value_text: str) -> str:
    """How a code is looked up: 'G053' is G53, 'G92.1' stays, 'D00' is D0."""
    whole, point, fraction = value_text.lstrip("+").partition(".")
    fraction = fraction.rstrip("0")
    return f"{address}{_digits(whole)}{'.' + fraction if point and fraction else ''}"


def _use(kind: str, digits: str, file: str, line: int) -> CodeUse:
    if not digits.isdigit():  # a user's pattern may find anything: beyond every range
        return CodeUse(kind, _BEYOND, file, line, repr(_shown(digits, 40)))
    return CodeUse(kind, _whole(digits), file, line, _shown(_digits(digits)))


_BLOCK_NUMBER = re.compile(r"^N\d+\s*", re.I)
_MESSAGE = "\x00MESSAGE"
"""What the reader keeps of a block that shows the operator a message."""
_STOP_MESSAGE = "\x00STOP MESSAGE"
"""What the reader keeps of a stop that shows its own message."""
_READY = "\x00READY "
"""What the reader keeps of a ready wait: the prefix, then input and time-out."""
_READY_BRANCH = "\x00READY BRANCH"
"""A line of a ready wait's time-out branch (not run: the recorder is ready)."""
_READY_BROKEN = "\x00READY BROKEN "
"""A ready wait the reader refuses, then why."""
_MAX_FILE_PROBLEMS = 5
"""Problems of one kind reported per file (the first ones say what is wrong)."""


def _character(char: str) -> str:
    return f"{char!r} (U+{ord(char):04X})"


class ProgramSet:
    """The program files of a folder, read once: split into programs, every line kept.

    :meth:`scan` finds every M word and option number of every line, :meth:`run`
    follows the main program the way a control would.

    Raises:
        ProgramError: a program file cannot be read (not a regular file, too large,
            not UTF-8).
    """

    def __init__(
        self,
        dialect: Dialect,
        directory: str | Path,
        options: Mapping[str, int | bool] | None = None,
    ) -> None:
        self.dialect = dialect
        self.reader = dialect.reader
        effective = dict(dialect.options)
        effective.update(options or {})
        self.options = effective
        r = self.reader
        self.comments = _patterns(r.comments, effective)
        self.ignore = _patterns(r.ignore, effective)
        self.call = _pattern(r.call, effective)
        self.ret = _pattern(r.ret, effective)
        self.end = re.compile(r.end, re.I)
        self.marker = _patterns(r.marker, effective)
        self.marker_off = _patterns(r.marker_off, effective)
        self.dwell = _pattern(r.dwell, effective)
        self.tape = _pattern(r.tape, effective)
        self.start = _pattern(r.program_start, effective)
        self.block_end = re.compile(r.block_end + r"\s*$") if r.block_end else None
        self.accepted = {w.upper() for w in r.accepted}
        self.stops = _patterns(dialect.start.stop, effective)
        self.messages = _patterns(dialect.start.message, effective)
        self.clears = _patterns(dialect.start.clear, effective)
        self.stop_messages = _patterns(dialect.start.stop_message, effective)
        ready = dialect.ready
        self.ready_wait = _pattern(ready.wait, effective)
        self.ready_any = _pattern(ready.any_wait, effective)
        self.ready_branch = _patterns(ready.on_timeout, effective)
        verify = dialect.coordinates.verify
        self.verify = re.compile(verify.pattern, re.I) if verify else None
        self.programs: dict[str, _Program] = {}
        self.first_program: dict[str, str] = {}
        """File name -> key of its first program."""
        self.files: dict[str, list[str]] = {}
        """Every line of every file as the reader sees it (comments removed, capitals)."""
        self.bytes_read = 0
        self.problems: list[str] = []
        directory = Path(directory)
        for path in sorted(directory.iterdir()):
            if path.suffix.lower() in dialect.program_extensions and path.is_file():
                self._read_file(path)

    # --- reading the files --------------------------------------------------------------

    def _read_file(self, path: Path) -> None:
        text = read_text(path, "a program file", MAX_PROGRAM_FILE_BYTES, ProgramError)
        self.bytes_read += len(text)
        if self.bytes_read > MAX_PROGRAM_BYTES:
            raise ProgramError(
                f"{path}: the program files hold more than {MAX_PROGRAM_BYTES // (1024 * 1024)} "
                "MiB together, more than ncmeasure reads"
            )
        raw_lines = text.split("\n")  # a control ends lines at LF only (U+2028 is no end)
        del text
        if raw_lines[-1] == "":
            raw_lines.pop()
        file = path.name
        texts: list[str] = []
        self.files[file] = texts
        key = _program_key(path.stem if self.reader.program_key == "stem" else file)
        default = _Program(key, file, 0, texts, 0)  # the file is its program
        current: _Program | None = None if self.start else default
        found: list[_Program] = []
        outside: list[int] = []  # lines before the first program number
        problems: dict[str, list[str]] = {}
        blank_so_far, tape_line, closed_at = True, 0, 0
        after: list[int] = []  # lines with text after the closing tape mark
        branch: list[re.Pattern[str]] = []  # the time-out branch lines still expected
        wait_index = 0
        for index, raw in enumerate(raw_lines):
            number = index + 1
            raw = raw.removesuffix("\r")  # CR LF line ends
            bad = self._bad_character(raw)
            if bad:
                problems.setdefault("character", []).append(f"{file}:{number}: character {bad}")
            stripped = raw.strip()
            block = _BLOCK_NUMBER.sub("", stripped)
            if branch and branch[0].search(block):
                branch.pop(0)
                texts.append(_READY_BRANCH)
                continue
            if branch:  # the wait is not followed by its time-out branch
                texts[wait_index] = _READY_BROKEN + f"branch {number}"
                branch = []
            if self.ready_wait and (match := self.ready_wait.search(block)):
                texts.append(f"{_READY}{match.group('input')} {match.group('timeout')}")
                branch, wait_index = list(self.ready_branch), index
            elif self.ready_any and self.ready_any.search(block):
                texts.append(_READY_BROKEN + "wait")
            # a message's text is the operator's, not words
            elif any(p.search(stripped) for p in self.messages):
                texts.append(_MESSAGE)
            elif any(p.search(stripped) for p in self.stop_messages):
                texts.append(_STOP_MESSAGE)
            elif any(p.search(stripped) for p in self.clears):
                texts.append("")
            else:
                texts.append(self._clean(raw))
            if closed_at:
                if stripped:
                    after.append(number)
                continue
            if self.tape and self.tape.search(stripped):
                if blank_so_far:
                    tape_line = number  # the tape starts: the file ends at the next mark
                    default.first = number
                elif tape_line:
                    closed_at = number
                else:
                    problems.setdefault("tape", []).append(
                        f"{file}:{number}: '%' where the file did not start with one: "
                        f"{self.dialect.title} refuses it (it may only start and end the tape)"
                    )
                blank_so_far = False  # a misplaced mark is refused here and skipped in a run
                continue
            blank_so_far = blank_so_far and not stripped
            match = self.start.search(stripped) if self.start else None
            if match:
                if current is not None:
                    current.end = index
                current = self._program(match.group("key"), file, number, texts, problems)
                found.append(current)
            elif current is None:
                outside.append(index)
        if branch:
            texts[wait_index] = _READY_BROKEN + "end"
        end = closed_at - 1 if closed_at else len(texts)
        if current is None or current is default:  # no program number: the file is its program
            default.end = end
            found.append(default)
            outside.clear()
        else:
            current.end = end
        for index in outside:
            line = texts[index]
            if line and not any(p.search(line) for p in self.ignore):
                problems.setdefault("outside", []).append(
                    f"{file}:{index + 1}: {_shown(line, 40)!r} stands before the first program "
                    "number: it belongs to no program; remove it"
                )
        if after:
            where = f"{after[0]}" if len(after) == 1 else f"{after[0]}-{after[-1]}"
            problems["after"] = [
                f"{file}:{where}: text after the closing '%' of line {closed_at}: "
                "the control does not read it; remove it"
            ]
        for kind in ("outside", "tape", "after", "character"):
            found_here = problems.get(kind, [])
            self.problems += found_here[:_MAX_FILE_PROBLEMS]
            if len(found_here) > _MAX_FILE_PROBLEMS:
                more = len(found_here) - _MAX_FILE_PROBLEMS
                self.problems.append(f"{file}: {more} more such lines")
        self.problems += problems.get("number", [])
        for program in found:
            known = self.programs.get(program.key)
            if known is None:
                self.programs[program.key] = program
            else:
                first = f"{known.file}:{known.line}" if known.line else known.file
                self.problems.append(
                    f"{file}:{program.line}: program {program.key} again (first in {first}); "
                    "a control keeps one program of a name or number"
                )
        self.first_program[file] = found[0].key

    def _program(
        self,
        written: str,
        file: str,
        number: int,
        texts: list[str],
        problems: dict[str, list[str]],
    ) -> _Program:
        key = _program_key(written)
        names = self.dialect.names
        if names.numbered and key.isdigit() and _whole(key) > names.max_number:
            problems.setdefault("number", []).append(
                f"{file}:{number}: program number {_shown(key)} is beyond the "
                f"{self.dialect.title} range (at most {names.max_number})"
            )
        return _Program(key, file, number, texts, number)

    def _bad_character(self, raw: str) -> str | None:
        """A character of ``raw`` the control cannot read, described, or None.

        Printable ASCII everywhere; in comments also other printable characters,
        unless the dialect reads ASCII only (ISO/EIA code).
        """
        if raw.isascii() and raw.isprintable():
            return None
        outside = raw
        for pattern in self.comments:
            outside = pattern.sub(" ", outside)
        for char in outside:
            if not " " <= char <= "~":
                return f"{_character(char)} outside a comment: {self._characters()}"
        for char in raw:
            if self.dialect.codes.ascii_only and not char.isascii():
                return f"{_character(char)} is not ASCII: {self._characters()}"
            if not char.isprintable():
                return f"{_character(char)} is not printable: {self._characters()}"
        return None

    def _characters(self) -> str:
        if self.dialect.codes.ascii_only:
            return f"{self.dialect.title} reads printable ASCII only (ISO/EIA code)"
        return (
            f"{self.dialect.title} programs hold printable ASCII, comments also other "
            "printable characters"
        )

    def _clean(self, raw: str) -> str:
        text = raw.strip()
        for pattern in self.comments:
            text = pattern.sub(" ", text)
        text = text.strip()
        if self.block_end:
            text = self.block_end.sub("", text)
        text = _BLOCK_NUMBER.sub("", text)
        return text.strip().upper()

    # --- what the files hold --------------------------------------------------------------

    def scan(self) -> list[CodeUse]:
        """Every M word and option-kind number of every line, run or not."""
        uses = {
            key: [re.compile(pattern, re.I) for pattern in rule.uses]
            for key, rule in self.dialect.codes.options.items()
        }
        found: list[CodeUse] = []
        # the dialect's own blocks: #3006, #5021 are no marker
        fixed = self.stops + ([self.verify] if self.verify else [])
        for file, texts in self.files.items():
            for index, text in enumerate(texts):
                if text.startswith("\x00"):  # messages, ready waits: not words
                    continue
                if self.call and (match := self.call.search(text)):
                    # the called program's name is a name, not words
                    text = text[: match.start("key")] + " " + text[match.end("key") :]
                for match in _M_WORD.finditer(text):
                    found.append(_use("m", match.group("n"), file, index + 1))
                if any(p.search(text) for p in fixed):
                    continue
                for key, patterns in uses.items():
                    for pattern in patterns:
                        for match in pattern.finditer(text):
                            found.append(_use(key, match.group("n"), file, index + 1))
        return found

    def run(
        self,
        main_file: str,
        axes: set[str],
        max_blocks: int | None = None,
        offsets: Mapping[str, Mapping[str, float]] | None = None,
        axis_numbers: Mapping[str, int] | None = None,
    ) -> ProgramTrace:
        """Follow the main program in ``main_file``, moving ``axes``.

        ``offsets`` are what the operator left active when the program starts, by kind
        (``work``, ``shift``, ``length``; see :data:`~ncmeasure.program.dialect.OffsetKind`)
        and axis, in mm: the motions' targets are then where the axes really go (the
        written position plus every offset still acting on the block), and a
        verification that finds one of them non-zero stops the run
        (:attr:`ProgramTrace.stopped`). ``axis_numbers`` are the axes' numbers in the
        control, for a verification that checks each axis by its number.

        The trace's problems are those of the run; the files' own are :attr:`problems`.
        A run that commands more than ``max_blocks`` moves, dwells and calls (what the
        schedule plans) stops there with a problem: it is not the planned program, and
        reading on would only fill the memory.

        Raises:
            ProgramError: the main file is not among the program files, or a block
                cannot be read.
        """
        if main_file not in self.first_program:
            raise ProgramError(f"{main_file}: main program not found among the program files")
        interpreter = _Interpreter(self, axes, max_blocks, offsets, axis_numbers)
        return interpreter.run(self.first_program[main_file])


class _Interpreter:
    def __init__(
        self,
        files: ProgramSet,
        axes: set[str],
        max_blocks: int | None,
        offsets: Mapping[str, Mapping[str, float]] | None,
        axis_numbers: Mapping[str, int] | None = None,
    ) -> None:
        self.files = files
        self.max_blocks = max_blocks
        self.dialect = files.dialect
        self.reader = files.reader
        self.programs = files.programs
        self.axes = axes
        self.ignore = files.ignore
        self.call = files.call
        self.ret = files.ret
        self.end = files.end
        self.marker = files.marker
        self.marker_off = files.marker_off
        self.dwell = files.dwell
        self.tape = files.tape
        self.accepted = files.accepted
        self.stops = files.stops
        self.verify = files.verify
        self.verified_numbers: set[int] = set()
        """Axis numbers a verification block checked."""
        self.axis_numbers = dict(axis_numbers or {})
        self.stop_run = False
        coordinates = files.dialect.coordinates
        self.codes = coordinates.codes
        self.keywords = [
            (_keyword(code), code) for code in self.codes if not _ADDRESS_CODE.fullmatch(code)
        ]
        self.active: set[str] = set(coordinates.offsets)
        """Offsets the operator may have left active (not yet cancelled or proved zero)."""
        self.offsets = {kind: dict(values) for kind, values in (offsets or {}).items()}
        """The operator's offsets still in force, by kind and axis (mm)."""
        self.reported_offsets = False
        self.message_shown = False
        self.position: dict[str, float | None] = dict.fromkeys(axes)
        self.mode: Literal["rapid", "feed"] | None = None
        self.feed: float | None = None
        self.marker_value = 0.0
        self.trace = ProgramTrace()

    def _error(self, program: _Program, line: int, message: str) -> ProgramError:
        return ProgramError(f"{program.file}:{line}: {message}")

    def run(self, main_key: str) -> ProgramTrace:
        main = self.programs[main_key]
        stack: list[tuple[_Program, int]] = [(main, main.first)]
        steps = 0
        while stack:
            program, index = stack.pop()
            if index >= program.end:
                if len(stack) == 0:
                    break  # main program ran off its end
                continue  # a subprogram without explicit return
            steps += 1
            if steps > _MAX_STEPS:
                raise ProgramError(f"{program.file}: more than {_MAX_STEPS} blocks; endless loop?")
            number, text = index + 1, program.texts[index]
            trace = self.trace
            blocks = len(trace.motions) + len(trace.dwells_s) + len(trace.calls)
            if self.max_blocks is not None and blocks > self.max_blocks:
                trace.problems.append(
                    f"{program.file}:{number}: more than the {self.max_blocks} moves, dwells "
                    "and calls the schedule plans; the rest is not read"
                )
                break
            stack.append((program, index + 1))
            if not text or any(p.search(text) for p in self.ignore):
                continue
            if self.tape and self.tape.search(text):
                continue  # a misplaced tape mark: refused when the file was read
            if (
                self.call
                and (match := self.call.search(text))
                and match.group("key").upper() not in self.codes  # TRAFOOF is no call
            ):
                key = _program_key(match.group("key"))
                if key not in self.programs:
                    raise self._error(program, number, f"calls {key}, which is not among the files")
                if len(stack) > 16:
                    raise self._error(program, number, "subprograms nested deeper than 16")
                self.trace.calls.append(key)
                called = self.programs[key]
                stack.append((called, called.first))
                continue
            if self.ret and self.ret.search(text):
                stack.pop()
                if not stack:
                    raise self._error(program, number, "return from the main program")
                continue
            if self.end.search(text):
                if len(stack) > 1:
                    raise self._error(program, number, "program end inside a subprogram")
                self.trace.ended = True
                break
            if text == _MESSAGE:
                self.message_shown = True
                continue
            if text == _READY_BRANCH:
                continue  # the time-out branch: the recorder is ready
            if text.startswith(_READY):
                self._ready(program, number, text)
                continue
            if text == _STOP_MESSAGE or any(p.search(text) for p in self.stops):
                silent = bool(self.dialect.start.without_message)  # none can be shown
                shown = self.message_shown or text == _STOP_MESSAGE or silent
                stop = Stop(program.key, number, shown, len(self.trace.calls), program.file)
                self.trace.steps.append(stop)
                self.message_shown = False
                continue
            if self._verification(text):
                if self.stop_run:
                    self.trace.stopped = f"{program.file}:{number}"
                    break
                continue
            self._block(program, number, text)
        return self.trace

    def _ready(self, program: _Program, number: int, text: str) -> None:
        """A wait for the recorder's ready signal: a step; a broken one is refused."""
        if text.startswith(_READY_BROKEN):
            why = text.removeprefix(_READY_BROKEN)
            title = self.dialect.title
            if why == "wait":
                message = (
                    "waits for an input, but not as a wait for the recorder's ready signal "
                    f"with its time-out ({title}: {self.dialect.ready.wait}): a wait without "
                    "a time-out would hold the program for ever; generate the programs again"
                )
            else:
                found = "the file ends" if why == "end" else f"line {why} is something else"
                message = (
                    "the wait for the recorder's ready signal is not followed by its time-out "
                    f"branch (message and program end), {found}: without it a time-out would "
                    "go on to move the machine; generate the programs again"
                )
            raise self._error(program, number, message)
        written_input, written_timeout = text.removeprefix(_READY).split()
        self.trace.steps.append(
            ReadyWait(
                program.key,
                number,
                _whole(written_input),
                self._number(program, number, written_timeout),
                len(self.trace.calls),
                program.file,
            )
        )

    def _verification(self, text: str) -> bool:
        """True for an axis' block of the dialect's offset verification.

        Once every axis has been verified by its number, the offsets the verification
        proves are known to be zero: if the operator left one of them non-zero on a
        verified axis, the program stops there (:attr:`ProgramTrace.stopped`).
        """
        verification = self.dialect.coordinates.verify
        match = self.verify.search(text) if self.verify else None
        if verification is None or match is None:
            return False
        self.verified_numbers.add(int(match.group("n")))
        numbers = self.axis_numbers
        if numbers and all(numbers.get(axis) in self.verified_numbers for axis in self.axes):
            proves = set(verification.proves)
            self.active.difference_update(proves)
            for kind in proves:
                values = self.offsets.pop(kind, {})
                if any(value != 0.0 for value in values.values()):
                    self.stop_run = True
        return True

    def _code(self, program: _Program, number: int, code: str, bypassed: set[str]) -> bool:
        """Apply a code of the dialect's [coordinates.codes]; False if it is none."""
        effect = self.codes.get(code)
        if effect is None:
            return False
        if effect.sets:
            what = " and ".join(OFFSET_MEANING[kind] for kind in effect.sets)
            raise self._error(
                program,
                number,
                f"{code} ({effect.meaning}) selects {what}: every position after it would "
                "move with the operator's offsets; ncmeasure programs work in machine "
                "coordinates",
            )
        self.active.difference_update(effect.cancels)
        for kind in effect.cancels:
            self.offsets.pop(kind, None)
        bypassed.update(effect.bypasses)
        return True

    def _offsets(self, program: _Program, number: int, bypassed: set[str]) -> None:
        """A move while an offset the operator may have left active still acts: a problem."""
        acting = sorted(self.active - bypassed)
        if acting and not self.reported_offsets:
            self.reported_offsets = True  # once: every later move has the same cause
            what = "; ".join(OFFSET_MEANING[kind] for kind in acting)
            self.trace.problems.append(
                f"{program.file}:{number}: an axis moves while the operator's setting may "
                f"still act on it ({what}): the block would land elsewhere under a non-zero "
                "offset; the prolog must cancel it or the block select machine coordinates"
            )

    def _block(self, program: _Program, number: int, text: str) -> None:
        bypassed: set[str] = set()
        for pattern, code in self.keywords:
            if pattern.search(text):
                self._code(program, number, code, bypassed)
                text = pattern.sub(" ", text).strip()
        for pattern in self.marker_off:
            if pattern.search(text):
                self.marker_value = 0.0
                text = pattern.sub(" ", text).strip()
        for pattern in self.marker:
            match = pattern.search(text)
            if match:
                value = match.groupdict().get("value")
                self.marker_value = 1.0 if value is None else self._number(program, number, value)
                text = pattern.sub(" ", text).strip()
        if not text:
            return
        if self.dwell and (match := self.dwell.search(text)):
            self._dwell(program, number, self._number(program, number, match.group("seconds")))
            return
        targets: dict[str, float] = {}
        dwell = False
        dwell_s: float | None = None
        position = 0
        while position < len(text):
            match = _WORD.match(text, position)
            if not match:
                rest = _shown(text[position:].strip(), 40)
                raise self._error(program, number, f"cannot read {rest!r}")
            position = match.end()
            if match.group("long"):
                address, value_text = match.group("long"), match.group("lval")
                code = f"{address}={_shown(value_text)}"  # R5=1, not R51
            else:
                address, value_text = match.group("addr"), match.group("val")
                code = f"{address}{_shown(value_text)}"
            value = float(value_text)
            if dwell and address == self.reader.dwell_word.upper():
                self._decimal_point(program, number, code, value_text)
                dwell_s = value * self.reader.dwell_scale
            elif address in self.axes:
                if "." not in value_text:
                    self._decimal_point(program, number, code, value_text)
                    value *= self.reader.integer_unit_mm
                if address in targets:
                    raise self._error(program, number, f"axis {address} twice in one block")
                targets[address] = value
            elif address == "F":
                self.feed = value
            elif address == "G" and value in (0.0, 1.0) and "." not in value_text.lstrip("0"):
                self.mode = "rapid" if value == 0 else "feed"
            elif address == "G" and value == 4.0:
                dwell = True
            elif address == "G" and value == 91.0:
                raise self._error(program, number, "incremental positioning (G91) is not read")
            elif self._code(program, number, _code_name(address, value_text), bypassed) or (
                (address == "G" and value == 90.0)
                or self._accepted(address, value_text)
                or address in self.reader.parameter_words.upper()
            ):
                pass
            else:
                raise self._error(program, number, f"unexpected word {code}")
        if dwell:
            if targets or dwell_s is None:
                raise self._error(program, number, "a dwell needs its time and no axis words")
            self._dwell(program, number, dwell_s)
            return
        if not targets:
            if bypassed:
                raise self._error(
                    program, number, "a machine-coordinate word in a block that moves no axis"
                )
            return
        if self.mode is None:
            raise self._error(program, number, "axis move before any G0/G1")
        if self.mode == "feed" and not self.feed:
            raise self._error(program, number, "feed move without a feed (F)")
        self._offsets(program, number, bypassed)
        for kind, values in self.offsets.items():
            if kind not in bypassed:
                for axis in targets:
                    targets[axis] += values.get(axis, 0.0)
        start = {axis: self.position[axis] for axis in targets}
        motion = Motion(
            kind=self.mode,
            program=program.key,
            line=number,
            start=start,
            target=targets,
            feed_mm_min=self.feed if self.mode == "feed" else None,
            marker=self.marker_value,
            calls=len(self.trace.calls),
            file=program.file,
        )
        self.trace.motions.append(motion)
        self.trace.steps.append(motion)
        self.position.update(targets)

    def _decimal_point(self, program: _Program, line: int, code: str, value_text: str) -> None:
        """An axis word or dwell without decimal point, where the dialect needs one."""
        if self.dialect.numbers.decimal_point and "." not in value_text:
            self.trace.problems.append(
                f"{program.file}:{line}: {code} has no decimal point: {self.dialect.title} "
                "reads it in its least input increment (0.001 mm, 0.001 s); write "
                f"{code}."
            )

    def _number(self, program: _Program, line: int, text: str) -> float:
        """A number a dialect's pattern found (a user's pattern may find anything)."""
        try:
            return float(text)
        except ValueError:
            raise self._error(program, line, f"{_shown(text, 40)!r} is not a number") from None

    def _dwell(self, program: _Program, number: int, seconds: float) -> None:
        self.trace.dwells_s.append(seconds)
        self.trace.steps.append(
            Dwell(program.key, number, seconds, self.marker_value, program.file)
        )

    def _accepted(self, address: str, value_text: str) -> bool:
        if address not in "GM":
            return False
        value = value_text.lstrip("+")
        candidates = {f"{address}{value}"}
        if "." not in value and not value.startswith("-"):
            digits = _digits(value)
            candidates.add(f"{address}{digits}")
            candidates.add(f"{address}{digits:0>2}")
        return bool(candidates & self.accepted)


def read_programs(
    dialect: Dialect,
    directory: str | Path,
    main_file: str,
    axes: set[str],
    options: Mapping[str, int | bool] | None = None,
    axis_numbers: Mapping[str, int] | None = None,
) -> ProgramTrace:
    """Read the program whose main file is ``main_file`` in ``directory``.

    Args:
        dialect: The dialect the programs are written in.
        directory: Folder holding the main program and its subprograms.
        main_file: File name of the main program.
        axes: Axis names the programs may move.
        options: Controller options the programs were written with
            (default: the dialect's defaults).
        axis_numbers: The axes' numbers in the control (schedule.json's ``number``),
            for a dialect whose prolog verifies each axis by its number.

    Raises:
        ProgramError: a file is missing or a block cannot be read.
    """
    directory = Path(directory)
    main_path = directory / main_file
    if not main_path.is_file():
        raise ProgramError(f"{main_path}: main program not found")
    files = ProgramSet(dialect, directory, options)
    trace = files.run(main_file, axes, axis_numbers=axis_numbers)
    trace.problems[:0] = files.problems
    return trace


def scan_codes(
    dialect: Dialect, directory: str | Path, options: Mapping[str, int | bool] | None = None
) -> list[CodeUse]:
    """Every M word, variable and output written in the program files of ``directory``.

    Every line counts, whether it runs or not (after the program end, in a skipped
    block, outside every program); comments and the names of called programs do not.
    """
    return ProgramSet(dialect, directory, options).scan()
