"""Rendering: a planned measurement -> NC program files, through a dialect's templates.

Templates get a frozen view model whose numbers were planned and checked in
Python; they only choose the words. Number formatting is a filter, so every
coordinate of a dialect is written the same way. The Jinja environment is
sandboxed, strict about undefined names, and searches user template folders
before the built-in ones.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import io
import os
import re
import shutil
import tempfile
import unicodedata
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import jinja2
from jinja2.loaders import split_template_path

from ncmeasure._version import __version__
from ncmeasure.config import MachineConfig, config_hash
from ncmeasure.errors import (
    DialectError,
    NcMeasureError,
    OutputError,
    PlanError,
    ProgramCheckError,
    ProgramError,
)
from ncmeasure.formats.schedule import SCHEDULE_FILE, Schedule
from ncmeasure.inputs import plain_file_name, read_text
from ncmeasure.plan import SMALLER, AxisPlan, Move, SizeLimit, plan_machine
from ncmeasure.program.dialect import (
    READY_MESSAGE,
    Dialect,
    dialect_warnings,
    load_dialect,
    marker_scope,
    validate_for_dialect,
)
from ncmeasure.program.reader import MAX_PROGRAM_BYTES, MAX_PROGRAM_FILE_BYTES
from ncmeasure.program.sandbox import TemplateSandbox
from ncmeasure.program.setup import (
    SETUP_FILES,
    SETUP_HTML,
    SETUP_MD,
    SetupSheet,
    render_setup_html,
    render_setup_markdown,
    setup_sheet,
)
from ncmeasure.resources import builtin_dir

__all__ = ["GeneratedPrograms", "ProgramRef", "generate_programs", "generation_time"]


@dataclass(frozen=True)
class ProgramRef:
    """A program as the dialect names it."""

    name: str
    file_name: str
    number: int | None = None


@dataclass(frozen=True)
class AxisView:
    """One axis as the templates see it."""

    name: str
    number: int
    """Its place in the machine file (1 for the first): its number in the control where
    a dialect addresses axes by number."""
    park_mm: float
    vertical: bool
    sub: ProgramRef | None
    moves: tuple[Move, ...]
    windows: int


@dataclass(frozen=True)
class ReadyView:
    """The wait for the recorder's ready signal, as the templates write it."""

    input: int
    """The controller's digital input (machine.ready_input)."""
    timeout: str
    """The time-out in seconds, as the dialect writes a number of seconds."""
    message: str
    """What the program shows on a time-out."""


def _timeout_text(seconds: float) -> str:
    """Seconds without a trailing zero or point: 60, 2.5."""
    return f"{seconds:.3f}".rstrip("0").rstrip(".") or "0"


@dataclass(frozen=True)
class ProgramView:
    """Everything the templates of one machine get."""

    machine: str
    program: str
    controller: str
    title: str
    generated: str
    version: str
    config_hash: str
    main: ProgramRef
    park: tuple[AxisView, ...]
    measure: tuple[AxisView, ...]
    axes: tuple[AxisView, ...]
    """Every axis in the machine file's order."""
    options: Mapping[str, int | bool]
    marker_scope: str
    marker_values: str
    confirm_start: bool
    """The main program stops before its first move with an operator message."""
    start_message: str
    """The operator message of that stop."""
    ready: ReadyView | None = None
    """The wait for the recorder before the first move (None: no wait)."""


class _Output:
    """Counts the bytes of every program file against the program-memory limit, and of
    each file against the largest program file ``check`` reads."""

    def __init__(self, limit_bytes: int, what: str) -> None:
        self.limit_bytes = limit_bytes
        self.what = what
        self.bytes = 0
        self.file_bytes = 0

    def next_file(self) -> None:
        self.file_bytes = 0

    def add(self, data: bytes) -> bytes:
        self.bytes += len(data)
        self.file_bytes += len(data)
        if self.bytes > self.limit_bytes:
            raise PlanError(
                f"the programs grow beyond {self.what}; nothing was written",
                [SMALLER],
            )
        if self.file_bytes > MAX_PROGRAM_FILE_BYTES or self.bytes > MAX_PROGRAM_BYTES:
            largest, what = (
                (MAX_PROGRAM_FILE_BYTES, "a program file grows")
                if self.file_bytes > MAX_PROGRAM_FILE_BYTES
                else (MAX_PROGRAM_BYTES, "the program files grow")
            )
            raise PlanError(
                f"{what} beyond {largest // (1024 * 1024)} MiB, more than `ncmeasure check` "
                "reads; nothing was written",
                [SMALLER],
            )
        return data


class _BlockNumbers:
    """Adds block numbers line by line to streamed program text (dialects that number blocks)."""

    def __init__(self, dialect: Dialect) -> None:
        self.blocks = dialect.blocks
        self.skip = re.compile(self.blocks.skip)
        self.number = self.blocks.start
        self.pending = ""

    def _line(self, line: str) -> str:
        if line and not self.skip.search(line):
            line = f"N{self.number} {line}"
            self.number += self.blocks.step
        return line

    def feed(self, chunk: str) -> str:
        if not self.blocks.numbered:
            return chunk
        *lines, self.pending = (self.pending + chunk).split("\n")
        return "".join(self._line(line) + "\n" for line in lines)

    def close(self) -> str:
        rest, self.pending = self.pending, ""
        return self._line(rest) if self.blocks.numbered else rest


@dataclass
class GeneratedPrograms:
    """A planned measurement program, rendered when it is written.

    :meth:`write` streams every file into a staging folder, checks the result
    with ncmeasure's own checker and only then moves it into place; ``files``
    renders the same text into memory (for small programs and tests). Beside
    the programs go schedule.json and, when ``setup`` is given, the setup sheet
    (SETUP.md and setup.html).
    """

    dialect: Dialect
    schedule: Schedule
    plans: list[AxisPlan]
    main_file: str = ""
    setup: SetupSheet | None = None
    """The setup sheet the technician reads before cycle start."""
    _renders: list[tuple[str, Callable[[], Iterator[str]]]] = field(
        default_factory=list, repr=False
    )
    _limit_bytes: int = 0
    _limit_what: str = ""
    _controllers_dirs: tuple[Path, ...] = ()
    _files: dict[str, str] | None = field(default=None, repr=False)
    _env: TemplateSandbox | None = field(default=None, repr=False)
    _moves: int = 0
    """Planned moves of all files: the sandbox's budgets for one rendering of them."""

    def _start(self) -> None:
        """One rendering of every file begins: the template budgets start afresh."""
        if self._env is not None:
            self._env.start(self._moves)

    @property
    def program_files(self) -> list[str]:
        """File names of the programs, the main program first."""
        return [name for name, _ in self._renders]

    @property
    def files(self) -> dict[str, str]:
        """The program texts by file name, rendered into memory on first use.

        Raises:
            DialectError: a template fails or breaks one of its limits.
            PlanError: the programs exceed the program-memory limit.
        """
        if self._files is None:
            self._start()
            output = _Output(self._limit_bytes, self._limit_what)
            files = {}
            for name, render in self._renders:
                buffer = io.StringIO()
                self._stream(render, output, buffer.write)
                files[name] = buffer.getvalue()
            self._files = files
        return self._files

    def _stream(
        self,
        render: Callable[[], Iterator[str]],
        output: _Output,
        write: Callable[[str], object],
    ) -> None:
        numbers = _BlockNumbers(self.dialect)
        output.next_file()
        try:
            for chunk in render():
                text = numbers.feed(chunk)
                output.add(text.encode("utf-8"))
                write(text)
            text = numbers.close()
            output.add(text.encode("utf-8"))
            write(text)
        except (NcMeasureError, OSError):
            raise  # ncmeasure's own (program memory, a comment the dialect lacks), or the disk
        except Exception as exc:  # whatever a template does wrong: a TypeError is its error too
            what = str(exc) or type(exc).__name__
            if isinstance(exc, MemoryError):
                what = "out of memory"
            elif isinstance(exc, RecursionError):
                what = "macros call themselves too deep"
            elif not isinstance(exc, jinja2.TemplateError):
                what = f"{type(exc).__name__}: {what}"
            raise DialectError(f"template {_template_place(exc, self.dialect)}: {what}") from exc

    @property
    def setup_files(self) -> dict[str, str]:
        """The setup sheet's files by name (none without a sheet)."""
        if self.setup is None:
            return {}
        return {
            SETUP_MD: render_setup_markdown(self.setup),
            SETUP_HTML: render_setup_html(self.setup),
        }

    def _render_into(self, folder: Path) -> None:
        schedule = self.schedule.model_dump_json(indent=2) + "\n"
        (folder / SCHEDULE_FILE).write_text(schedule, encoding="utf-8", newline="\n")
        del schedule
        for name, text in self.setup_files.items():
            (folder / name).write_text(text, encoding="utf-8", newline="\n")
        self._start()
        output = _Output(self._limit_bytes, self._limit_what)
        for name, render in self._renders:
            with (folder / name).open("w", encoding="utf-8", newline="\n") as file:
                self._stream(render, output, file.write)

    def _check(self, folder: Path) -> None:
        # Imported here: the checker reads schedule.json with this module's file name.
        from ncmeasure.program.check import check_programs

        try:
            check_programs(folder, self._controllers_dirs)
        except ProgramError as exc:
            found = [*exc.problems] if isinstance(exc, ProgramCheckError) else [exc.message]
            raise DialectError(
                "the rendered programs fail ncmeasure's own check, so nothing was written "
                "(a template or the controller definition writes what check refuses)",
                [line.replace(f"{folder}{os.sep}", "") for line in found],
            ) from exc

    def write(self, directory: str | Path) -> list[Path]:
        """Render, check and write every file into ``directory`` (created if missing).

        The files are streamed into a hidden staging folder (inside ``directory``,
        or beside it while it does not exist), checked
        with :func:`~ncmeasure.program.check.check_programs`, and only then
        moved into place, replacing the files of an earlier generation (those
        its schedule.json names) and nothing else. Any failure leaves
        ``directory`` as it was.

        Raises:
            OutputError: the directory cannot be created or written, or it holds
                program files no schedule names.
            DialectError: a template fails, or the rendered programs fail the check.
            PlanError: the programs exceed the program-memory limit.
        """
        directory = Path(directory)
        if directory.exists() and not directory.is_dir():
            raise OutputError(f"{directory}: exists and is not a directory")
        new = [*self.program_files, SCHEDULE_FILE, *(SETUP_FILES if self.setup else ())]
        for name in new:  # whatever named the files: nothing lands outside the folder
            if not plain_file_name(name):
                raise OutputError(
                    f"{directory}: {name!r} is not a plain file name; nothing was written"
                )
        previous = _previous_generation(directory, self.dialect, new)
        # Staged inside the folder when it exists (same file system, nothing needed
        # beside it), else beside it in the nearest folder that exists.
        anchor = directory.absolute()
        while not anchor.is_dir():
            anchor = anchor.parent
        try:
            staging = Path(tempfile.mkdtemp(prefix=".ncmeasure-new-", dir=anchor))
        except OSError as exc:
            raise OutputError(f"{anchor}: cannot create a staging folder ({exc.strerror})") from exc
        try:
            try:
                self._render_into(staging)
            except OSError as exc:
                raise OutputError(f"{staging}: cannot write programs ({exc.strerror})") from exc
            self._check(staging)
            return _move_into_place(staging, directory, previous, new)
        finally:
            shutil.rmtree(staging, ignore_errors=True)

    def all_files(self) -> dict[str, str]:
        """Program files, schedule.json and the setup sheet, by file name (rendered into
        memory)."""
        schedule = self.schedule.model_dump_json(indent=2) + "\n"
        return {**self.files, SCHEDULE_FILE: schedule, **self.setup_files}


def _previous_generation(directory: Path, dialect: Dialect, new: list[str]) -> list[str]:
    """Files of an earlier generation in ``directory`` that the new one replaces.

    Raises:
        OutputError: the folder holds program files that no schedule.json names,
            or a file the new generation would overwrite that is not ncmeasure's.
    """
    if not directory.is_dir():
        return []
    present = {path.name for path in directory.iterdir() if path.is_file()}
    previous: set[str] = set()
    schedule_path = directory / SCHEDULE_FILE
    if SCHEDULE_FILE in present:
        # Imported here: check imports this module.
        from ncmeasure.formats.schedule import load_schedule

        try:
            old = load_schedule(schedule_path)
        except ProgramError as exc:
            raise OutputError(
                f"{schedule_path}: not a readable schedule, so the programs beside it cannot "
                "be told from others; remove the folder's programs or choose another folder",
                [exc.message],
            ) from exc
        previous.add(SCHEDULE_FILE)
        previous.update(SETUP_FILES)  # the sheet beside a schedule is its generation's
        if old.program_files:
            previous.update(old.program_files)
        else:  # written before schedules listed their files: every program file is theirs
            previous.update(
                name for name in present if Path(name).suffix.lower() in dialect.program_extensions
            )
    foreign = sorted(
        name
        for name in present - previous
        if name in new or Path(name).suffix.lower() in dialect.program_extensions
    )
    if foreign:
        shown = ", ".join(foreign[:5]) + (
            f" and {len(foreign) - 5} more" if len(foreign) > 5 else ""
        )
        raise OutputError(
            f"{directory}: holds program files that no schedule.json there names ({shown}); "
            "check would refuse the folder, and generate overwrites only its own files. "
            "Move them away or choose another folder",
        )
    return sorted(previous & present)


def _move_into_place(
    staging: Path, directory: Path, previous: list[str], new: list[str]
) -> list[Path]:
    """Replace the earlier generation's files in ``directory`` by the staged ones."""
    if not directory.exists():
        try:
            directory.parent.mkdir(parents=True, exist_ok=True)
            umask = os.umask(0)
            os.umask(umask)
            staging.chmod(0o777 & ~umask)  # as mkdir would have made it, not private
            staging.rename(directory)
        except OSError as exc:
            raise OutputError(
                f"{directory}: cannot create the output folder ({exc.strerror})"
            ) from exc
        return [directory / name for name in new]
    try:
        backup = Path(tempfile.mkdtemp(prefix=".ncmeasure-old-", dir=directory))
    except OSError as exc:
        raise OutputError(f"{directory}: cannot write programs ({exc.strerror})") from exc
    moved_old: list[str] = []
    moved_new: list[str] = []
    try:
        # schedule.json goes first and comes last: programs never sit beside a stale schedule
        for name in sorted(previous, key=lambda n: n != SCHEDULE_FILE):
            (directory / name).replace(backup / name)
            moved_old.append(name)
        for name in new:
            (staging / name).replace(directory / name)
            moved_new.append(name)
    except BaseException as exc:  # an error, or Ctrl-C / SIGTERM between two renames
        for name in reversed(moved_new):
            with contextlib.suppress(OSError):
                (directory / name).replace(staging / name)
        for name in reversed(moved_old):
            with contextlib.suppress(OSError):
                (backup / name).replace(directory / name)
        moved_new.clear()
        if isinstance(exc, OSError):
            raise OutputError(f"{directory}: cannot write programs ({exc.strerror})") from exc
        raise
    finally:
        if len(moved_new) == len(new):
            shutil.rmtree(backup, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                backup.rmdir()  # stays (with the old files) only if restoring failed
    return [directory / name for name in new]


def generation_time() -> dt.datetime:
    """Now, or SOURCE_DATE_EPOCH when set (reproducible builds)."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch and epoch.isdigit():
        return dt.datetime.fromtimestamp(int(epoch), tz=dt.UTC)
    return dt.datetime.now(tz=dt.UTC).replace(microsecond=0)


def _number(value: float, decimals: int, plus: bool) -> str:
    text = f"{value:.{decimals}f}"
    if text.startswith("-") and float(text) == 0.0:
        text = text[1:]
    if plus and not text.startswith("-"):
        text = "+" + text
    return text


MAX_TEMPLATE_BYTES = 1024 * 1024
"""Largest template file read (the built-in ones are a few kB)."""


class _TemplateLoader(jinja2.BaseLoader):
    """Templates from folders searched in order, each a regular file of at most 1 MiB.

    A name found in an earlier folder hides the later ones, whatever the file is: a
    FIFO or a device there is an error, not a reason to fall back to the built-in.
    """

    def __init__(self, folders: Iterable[Path]) -> None:
        self.folders = list(folders)

    def get_source(
        self, environment: jinja2.Environment, template: str
    ) -> tuple[str, str, Callable[[], bool]]:
        pieces = split_template_path(template)
        for folder in self.folders:
            path = folder.joinpath(*pieces)
            if path.exists() or path.is_symlink():
                source = read_text(path, "a template", MAX_TEMPLATE_BYTES, DialectError)
                return source, str(path), lambda: True  # read once per run
        raise jinja2.TemplateNotFound(
            template, f"{template!r} not found in {', '.join(map(str, self.folders))}"
        )


def _environment(dialect: Dialect, template_dirs: Iterable[Path]) -> TemplateSandbox:
    folders = [Path(d) / dialect.name for d in template_dirs]
    folders.append(builtin_dir("templates") / dialect.name)
    env = TemplateSandbox(
        loader=_TemplateLoader(folders),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
    )
    numbers, names, comments = dialect.numbers, dialect.names, dialect.comments

    def coord(value: float) -> str:
        text = _number(value, numbers.decimals, numbers.plus_sign)
        return text + "." if numbers.decimal_point and "." not in text else text

    def feed(value: float) -> str:
        text = f"{value:.{numbers.feed_decimals}f}"
        if "." in text:
            text = text.rstrip("0")
            if text.endswith(".") and not numbers.feed_trailing_point:
                text = text[:-1]
        elif numbers.feed_trailing_point:
            text += "."
        return text

    def seconds(value: float) -> str:
        text = f"{value:.3f}".rstrip("0").rstrip(".") or "0"
        return text + "." if numbers.decimal_point and "." not in text else text

    def word(value: float, axis: str) -> str:
        form = names.axis_word if len(axis) == 1 else names.long_axis_word
        return form.format(axis=axis, value=coord(value))

    def comment(text: str) -> str:
        if not comments.supported:
            raise DialectError(
                f"{dialect.name}: a template writes a comment, but the dialect has none"
            )
        clean = str(text)
        if dialect.codes.ascii_only:  # ISO/EIA code: "Fräse" becomes "Frase", "机床" nothing
            clean = unicodedata.normalize("NFKD", clean).encode("ascii", "ignore").decode()
        clean = "".join(c for c in clean if c not in comments.forbidden and c.isprintable())
        if comments.upper:
            clean = clean.upper()
        return f"{comments.open}{clean}{comments.close}"

    env.add_filters(coord=coord, feed=feed, seconds=seconds, word=word, comment=comment)
    return env


def _template_place(exc: BaseException, dialect: Dialect) -> str:
    """'file:line' of the template a rendering error comes from."""
    filename = getattr(exc, "filename", None)
    line = getattr(exc, "lineno", None)
    # Jinja rewrites tracebacks so that template frames carry the template's file and line.
    frame = exc.__traceback__
    while frame is not None:
        code = frame.tb_frame.f_code
        if code.co_filename.endswith(".j2"):
            filename, line = code.co_filename, frame.tb_lineno
        frame = frame.tb_next
    place = filename or dialect.name
    return f"{place}:{line}" if line else place


def generate_programs(
    config: MachineConfig,
    *,
    controllers_dirs: Iterable[Path] = (),
    templates_dirs: Iterable[Path] = (),
    generated: dt.datetime | None = None,
) -> GeneratedPrograms:
    """Plan the measurement of ``config`` and render its programs.

    Nothing is written; call :meth:`GeneratedPrograms.write`.

    Raises:
        ConfigError: the machine does not fit the dialect.
        PlanError: a velocity step does not fit an axis.
        DialectError: a dialect file or template is broken.
    """
    dialect = load_dialect(config.machine.controller, controllers_dirs)
    options = validate_for_dialect(config, dialect)
    limit, limit_kb, memory = _size_limit(config, dialect)
    schedule, plans = plan_machine(config, limit)
    main, subs = _program_refs(config, dialect, plans)
    by_name = {p.axis.name: p for p in plans}

    def view_of(axis_name: str) -> AxisView:
        plan = by_name[axis_name]
        return AxisView(
            name=axis_name,
            number=plan.summary.number,
            park_mm=plan.summary.park_mm,
            vertical=plan.axis.vertical,
            sub=subs[axis_name],
            moves=tuple(plan.moves),
            windows=len(plan.summary.windows),
        )

    when = (generated or generation_time()).astimezone(dt.UTC)
    view = ProgramView(
        machine=config.machine.name,
        program=config.machine.program,
        controller=dialect.name,
        title=dialect.title,
        generated=when.strftime("%Y-%m-%d %H:%M UTC"),
        version=__version__,
        config_hash=config_hash(config),
        main=main,
        park=tuple(view_of(a.name) for a in config.park_sequence()),
        measure=tuple(view_of(a.name) for a in config.measure_sequence()),
        axes=tuple(view_of(a.name) for a in config.axes),
        options=MappingProxyType(dict(options)),
        marker_scope=marker_scope(dialect, options),
        marker_values=dialect.marker.values,
        confirm_start=config.machine.confirm_start,
        start_message=dialect.start.text,
        ready=None
        if config.machine.ready_input is None
        else ReadyView(
            input=config.machine.ready_input,
            timeout=_timeout_text(config.machine.ready_timeout_s),
            message=READY_MESSAGE,
        ),
    )
    env = _environment(dialect, templates_dirs)
    total_moves = sum(len(plan.moves) for plan in plans)
    renders: list[tuple[str, Callable[[], Iterator[str]]]] = [
        (main.file_name, functools.partial(_generate, env, "main.j2", v=view))
    ]
    if dialect.subprograms:
        for axis_view in view.measure:
            assert axis_view.sub is not None
            sub = functools.partial(_generate, env, "sub.j2", v=view, axis=axis_view)
            renders.append((axis_view.sub.file_name, sub))
    schedule = schedule.model_copy(
        update={
            "main_program": main.file_name,
            "program_files": [name for name, _ in renders],
            "marker_scope": marker_scope(dialect, options),
            "controller_options": options,
            "marker_values": dialect.marker.values,
            "confirm_start": config.machine.confirm_start,
            "ready_input": config.machine.ready_input,
            "ready_timeout_s": (
                None if config.machine.ready_input is None else config.machine.ready_timeout_s
            ),
            "warnings": [*schedule.warnings, *dialect_warnings(dialect, options)],
        }
    )
    programs = [("main program", main.name, main.file_name)] + [
        (f"subprogram of axis {a.name}", a.sub.name, a.sub.file_name)
        for a in view.measure
        if a.sub is not None and dialect.subprograms
    ]
    sheet = setup_sheet(config, dialect, schedule, plans, programs, view.generated)
    return GeneratedPrograms(
        dialect=dialect,
        schedule=schedule,
        plans=plans,
        main_file=main.file_name,
        setup=sheet,
        _renders=renders,
        _limit_bytes=limit_kb * 1024,
        _limit_what=memory,
        _controllers_dirs=tuple(controllers_dirs),
        _env=env,
        _moves=total_moves,
    )


def _size_limit(config: MachineConfig, dialect: Dialect) -> tuple[SizeLimit, int, str]:
    """What the programs must fit: duration, blocks of program memory, windows.

    Returns:
        The limit for the planner, the program memory in kB and where that
        figure comes from (for the messages).
    """
    limit_kb = config.limits.max_program_kb or dialect.memory.program_kb
    if config.limits.max_program_kb:
        memory = f"limits.max_program_kb = {limit_kb}"
    else:
        memory = (
            f"the {limit_kb} kB of program memory assumed for {dialect.title} "
            "(limits.max_program_kb; `ncmeasure controllers --details`)"
        )
    # Every block holds at least an axis word (letter, number with the dialect's decimals)
    # and a line end: a floor no rendered program stays under.
    decimals = dialect.numbers.decimals
    block_floor = 3 + decimals + (1 if decimals else 0)
    limit = SizeLimit(
        config.limits.max_duration_h * 3600,
        limit_kb * 1024 // block_floor,
        memory,
        config.limits.max_windows,
    )
    return limit, limit_kb, memory


def _program_refs(
    config: MachineConfig, dialect: Dialect, plans: Sequence[AxisPlan]
) -> tuple[ProgramRef, dict[str, ProgramRef | None]]:
    """The main program's name and file, and each axis' subprogram's (None without them).

    Raises:
        DialectError: Two programs would get the same file (or the schedule's).
    """
    names = dialect.names
    program = config.machine.program
    number = config.machine.program_number

    def ref(template: str, axis: str = "", offset: int = 0) -> ProgramRef:
        name = dialect.program_name(template, program, axis, number + offset)
        file_template = names.main_file if not axis else names.sub_file
        return ProgramRef(
            name, file_template.format(name=name), number + offset if names.numbered else None
        )

    main = ref(names.main)
    subs = {
        p.axis.name: ref(names.sub, p.axis.name, i + 1) if dialect.subprograms else None
        for i, p in enumerate(plans)
    }
    taken = {SCHEDULE_FILE: "schedule", **{name.lower(): "setup sheet" for name in SETUP_FILES}}
    for key, named in [("main_file", main)] + [("sub_file", s) for s in subs.values() if s]:
        if named.file_name.lower() in taken:
            raise DialectError(
                f"controller {dialect.name}: two files of the same name",
                [
                    f"names.{key}: {named.file_name!r} is the file of two programs "
                    "(a name given twice); each program needs its own"
                ],
            )
        taken[named.file_name.lower()] = named.name
    return main, subs


def _generate(env: TemplateSandbox, name: str, **context: object) -> Iterator[str]:
    """The text of one template, chunk by chunk (nothing is held in memory).

    The sandbox's budgets are those of the whole rendering (see ``GeneratedPrograms._start``).
    """
    return env.get_template(name).generate(**context)
