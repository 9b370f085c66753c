"""Rendering: a planned measurement -> NC program files, through a dialect's templates.

Templates get a frozen view model whose numbers were planned and checked in
Python; they only choose the words. Number formatting is a filter, so every
coordinate of a dialect is written the same way. The Jinja environment is
sandboxed, strict about undefined names, and searches user template folders
before the built-in ones.
"""

from __future__ import annotations

import datetime as dt
import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import jinja2
from jinja2.sandbox import SandboxedEnvironment

from ncmeasure import __version__
from ncmeasure.config import MachineConfig, config_hash
from ncmeasure.errors import DialectError, OutputError
from ncmeasure.plan import AxisPlan, Move, Schedule, plan_machine
from ncmeasure.program.dialect import (
    Dialect,
    dialect_warnings,
    load_dialect,
    marker_scope,
    validate_for_dialect,
)
from ncmeasure.resources import builtin_dir

__all__ = ["GeneratedPrograms", "ProgramRef", "generate_programs", "generation_time"]

SCHEDULE_FILE = "schedule.json"


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
    park_mm: float
    vertical: bool
    sub: ProgramRef | None
    moves: tuple[Move, ...]
    windows: int


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
    options: Mapping[str, int | bool]
    marker_scope: str
    marker_values: str


@dataclass
class GeneratedPrograms:
    """The files of one generated measurement program, in memory until written."""

    dialect: Dialect
    schedule: Schedule
    plans: list[AxisPlan]
    files: dict[str, str] = field(default_factory=dict)
    main_file: str = ""

    def write(self, directory: str | Path) -> list[Path]:
        """Write every file into ``directory`` (created if missing).

        The files are first written into a temporary folder beside the target
        and then moved into place, so a failure leaves no partial program.

        Raises:
            OutputError: the directory cannot be created or written.
        """
        directory = Path(directory)
        if directory.exists() and not directory.is_dir():
            raise OutputError(f"{directory}: exists and is not a directory")
        try:
            directory.mkdir(parents=True, exist_ok=True)
            staging = Path(tempfile.mkdtemp(prefix=".ncmeasure-", dir=directory))
        except OSError as exc:
            raise OutputError(
                f"{directory}: cannot create output directory ({exc.strerror})"
            ) from exc
        written: list[Path] = []
        try:
            for name, text in self.all_files().items():
                (staging / name).write_text(text, encoding="utf-8", newline="\n")
            for name in self.all_files():
                target = directory / name
                (staging / name).replace(target)
                written.append(target)
        except OSError as exc:
            raise OutputError(f"{directory}: cannot write programs ({exc.strerror})") from exc
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        return written

    def all_files(self) -> dict[str, str]:
        """Program files plus schedule.json, by file name."""
        schedule = self.schedule.model_dump_json(indent=2) + "\n"
        return {**self.files, SCHEDULE_FILE: schedule}


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


def _environment(dialect: Dialect, template_dirs: Iterable[Path]) -> SandboxedEnvironment:
    loaders: list[jinja2.BaseLoader] = [
        jinja2.FileSystemLoader(str(Path(d) / dialect.name)) for d in template_dirs
    ]
    loaders.append(jinja2.FileSystemLoader(str(builtin_dir("templates") / dialect.name)))
    env = SandboxedEnvironment(
        loader=jinja2.ChoiceLoader(loaders),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
    )
    numbers, names, comments = dialect.numbers, dialect.names, dialect.comments

    def coord(value: float) -> str:
        return _number(value, numbers.decimals, numbers.plus_sign)

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
        return f"{value:.3f}".rstrip("0").rstrip(".") or "0"

    def word(value: float, axis: str) -> str:
        form = names.axis_word if len(axis) == 1 else names.long_axis_word
        return form.format(axis=axis, value=coord(value))

    def comment(text: str) -> str:
        if not comments.supported:
            raise DialectError(
                f"{dialect.name}: a template writes a comment, but the dialect has none"
            )
        clean = "".join(c for c in str(text) if c not in comments.forbidden and c.isprintable())
        if comments.upper:
            clean = clean.upper()
        return f"{comments.open}{clean}{comments.close}"

    env.filters.update(coord=coord, feed=feed, seconds=seconds, word=word, comment=comment)
    return env


def _template_place(exc: jinja2.TemplateError, dialect: Dialect) -> str:
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


def _number_blocks(text: str, dialect: Dialect) -> str:
    blocks = dialect.blocks
    if not blocks.numbered:
        return text
    skip = re.compile(blocks.skip)
    number = blocks.start
    lines = []
    for line in text.split("\n"):
        if line and not skip.search(line):
            line = f"N{number} {line}"
            number += blocks.step
        lines.append(line)
    return "\n".join(lines)


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
    schedule, plans = plan_machine(config)
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
    by_name = {p.axis.name: p for p in plans}

    def view_of(axis_name: str) -> AxisView:
        plan = by_name[axis_name]
        return AxisView(
            name=axis_name,
            park_mm=plan.summary.park_mm,
            vertical=plan.axis.vertical,
            sub=subs[axis_name],
            moves=tuple(plan.moves),
            windows=len(plan.summary.windows),
        )

    when = (generated or generation_time()).astimezone(dt.UTC)
    view = ProgramView(
        machine=config.machine.name,
        program=program,
        controller=dialect.name,
        title=dialect.title,
        generated=when.strftime("%Y-%m-%d %H:%M UTC"),
        version=__version__,
        config_hash=config_hash(config),
        main=main,
        park=tuple(view_of(a.name) for a in config.park_sequence()),
        measure=tuple(view_of(a.name) for a in config.measure_sequence()),
        options=options,
        marker_scope=marker_scope(dialect, options),
        marker_values=dialect.marker.values,
    )
    env = _environment(dialect, templates_dirs)
    schedule = schedule.model_copy(
        update={
            "main_program": main.file_name,
            "marker_scope": marker_scope(dialect, options),
            "controller_options": options,
            "marker_values": dialect.marker.values,
            "warnings": [*schedule.warnings, *dialect_warnings(dialect, options)],
        }
    )
    result = GeneratedPrograms(
        dialect=dialect, schedule=schedule, plans=plans, main_file=main.file_name
    )
    try:
        result.files[main.file_name] = _number_blocks(
            env.get_template("main.j2").render(v=view), dialect
        )
        if dialect.subprograms:
            sub_template = env.get_template("sub.j2")
            for axis_view in view.measure:
                assert axis_view.sub is not None
                result.files[axis_view.sub.file_name] = _number_blocks(
                    sub_template.render(v=view, axis=axis_view), dialect
                )
    except jinja2.TemplateError as exc:
        raise DialectError(f"template {_template_place(exc, dialect)}: {exc}") from exc
    return result
