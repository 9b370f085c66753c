"""The ``ncmeasure`` command: a thin translation of arguments into library calls.

The CLI owns the console (rich) and is the only place that turns errors into
exit codes: 0 success, 1 a check found problems, 2 bad input (machine file,
options, paths). ``--debug`` shows tracebacks; nobody else ever sees one.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.table import Table

from ncmeasure import __version__
from ncmeasure.config import MachineConfig, load_machine
from ncmeasure.errors import NcMeasureError, OutputError, ProgramCheckError
from ncmeasure.examples import example_machine
from ncmeasure.plan import Schedule
from ncmeasure.program import available_dialects, check_programs, generate_programs, load_dialect

__all__ = ["app", "main"]

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2

app = typer.Typer(
    name="ncmeasure",
    help=(
        "Measure the friction of machine-tool feed axes with the machine's own drives.\n\n"
        "Typical use: `ncmeasure init --controller sinumerik-840d > machine.toml`, edit the "
        "axes, `ncmeasure plan machine.toml` to see how long it takes, then "
        "`ncmeasure generate machine.toml -o programs/` and `ncmeasure check programs/`."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
schema_app = typer.Typer(
    help="Print JSON Schemas of ncmeasure's files (for editors).", no_args_is_help=True
)
app.add_typer(schema_app, name="schema")

console = Console(highlight=False)
err_console = Console(stderr=True, highlight=False)
_state = {"debug": False}

ControllersDir = Annotated[
    list[Path] | None,
    typer.Option(
        "--controllers-dir",
        help="Folder of your own controller definitions "
        "(<name>.toml), searched before the built-in ones.",
        show_default=False,
    ),
]
TemplatesDir = Annotated[
    list[Path] | None,
    typer.Option(
        "--templates-dir",
        help="Folder of your own templates (<dialect>/main.j2, "
        "sub.j2), searched before the built-in ones.",
        show_default=False,
    ),
]


def _fail(exc: NcMeasureError) -> NoReturn:
    code = EXIT_CHECK_FAILED if isinstance(exc, ProgramCheckError) else EXIT_BAD_INPUT
    err_console.print(f"[bold red]error:[/] {exc.message}", markup=True, soft_wrap=True)
    for line in exc.problems:
        err_console.print(f"  {line}", markup=False, soft_wrap=True)
    if _state["debug"]:
        raise exc
    raise typer.Exit(code)


def _version(value: bool) -> None:
    if value:
        console.print(f"ncmeasure {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks and debug logs.")] = False,
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    _state["debug"] = debug
    logging.basicConfig(
        level=logging.DEBUG if debug else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )


def _load(machine: Path) -> MachineConfig:
    try:
        return load_machine(machine)
    except NcMeasureError as exc:
        _fail(exc)


@app.command()
def init(
    controller: Annotated[
        str, typer.Option(help="Controller dialect of the example (see `ncmeasure controllers`).")
    ] = "sinumerik-840d",
    controllers_dir: ControllersDir = None,
) -> None:
    """Print a commented example machine file; redirect it into a file and edit it.

    Example: ncmeasure init --controller linuxcnc > machine.toml
    """
    try:
        dialect = load_dialect(controller, controllers_dir or ())
    except NcMeasureError as exc:
        _fail(exc)
    sys.stdout.write(example_machine(dialect.name))


@schema_app.command("machine")
def schema_machine() -> None:
    """JSON Schema of the machine file (point your editor's TOML support at it)."""
    sys.stdout.write(json.dumps(MachineConfig.model_json_schema(), indent=2) + "\n")


@schema_app.command("schedule")
def schema_schedule() -> None:
    """JSON Schema of schedule.json, the velocity file generate writes."""
    sys.stdout.write(json.dumps(Schedule.model_json_schema(), indent=2) + "\n")


@app.command()
def controllers(
    details: Annotated[
        bool,
        typer.Option("--details", help="Show marker mechanism, options and what was left out."),
    ] = False,
    controllers_dir: ControllersDir = None,
) -> None:
    """List the controller dialects ncmeasure can write programs for."""
    table = Table("name", "controller", "files", "marker", show_lines=details)
    try:
        for name in available_dialects(controllers_dir or ()):
            dialect = load_dialect(name, controllers_dir or ())
            files = (
                f"{Path(dialect.names.main_file).suffix} / {Path(dialect.names.sub_file).suffix}"
            )
            if not dialect.subprograms:
                files = f"{Path(dialect.names.main_file).suffix} (one program)"
            marker: str = dialect.marker.scope
            if details:
                marker = f"{dialect.marker.scope}: {dialect.marker.mechanism}"
                if dialect.options:
                    marker += "\noptions: " + ", ".join(
                        f"{k}={v}" for k, v in dialect.options.items()
                    )
                if dialect.left_out:
                    marker += "\nleft out: " + "; ".join(dialect.left_out)
            table.add_row(name, dialect.title, files, marker)
    except NcMeasureError as exc:
        _fail(exc)
    console.print(table)


def _print_plan(schedule: Schedule) -> None:
    table = Table(box=None, header_style="bold")
    for column in (
        "axis",
        "positions mm",
        "steps",
        "mm/min",
        "run-up",
        "windows",
        "time",
        "full travel",
    ):
        table.add_column(column, no_wrap=True)
    for axis in schedule.axes:
        velocities = axis.velocities_mm_min
        table.add_row(
            axis.name,
            ", ".join(f"{p:g}" for p in axis.nominal_positions_mm),
            str(len(velocities)),
            f"{velocities[0]:g} … {velocities[-1]:g}",
            f"{axis.runup_at_max_velocity_mm:g}mm",
            str(len(axis.windows)),
            _duration(axis.duration_s),
            _duration(axis.full_travel_duration_s),
        )
    console.print(
        f"[bold]{schedule.machine}[/] · {schedule.controller} · config {schedule.config_hash}"
    )
    console.print(table)
    saving = 1 - schedule.duration_s / schedule.full_travel_duration_s
    console.print(
        f"total {_duration(schedule.duration_s)} (full travel at every step: "
        f"{_duration(schedule.full_travel_duration_s)}, saving {saving:.0%})"
    )
    for axis in schedule.axes:
        if axis.shifted_positions_mm:
            shifted = ", ".join(f"{p:g}" for p in axis.shifted_positions_mm)
            console.print(
                f"note: axis {axis.name}: windows at {shifted} mm move inward at high velocities, "
                "where the run-up would not fit (schedule.json has each window's position)"
            )
    for warning in schedule.warnings:
        err_console.print(f"[yellow]warning:[/] {warning}", soft_wrap=True)


def _duration(seconds: float) -> str:
    minutes, rest = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    if hours:
        return f"{hours}h{minutes:02d}m"
    return f"{minutes}m{rest:02d}s" if minutes else f"{seconds:.1f}s"


@app.command()
def plan(
    machine: Annotated[Path, typer.Argument(help="Machine file (TOML).")],
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print the plan as JSON (duration_s and full_travel_duration_s at the top).",
        ),
    ] = False,
    controllers_dir: ControllersDir = None,
) -> None:
    """Show what the measurement will do and how long it takes, without writing anything."""
    config = _load(machine)
    try:
        result = generate_programs(config, controllers_dirs=controllers_dir or ())
    except NcMeasureError as exc:
        _fail(exc)
    schedule = result.schedule
    if as_json:
        summary = schedule.model_dump(mode="json")
        for axis in summary["axes"]:
            axis["windows"] = len(axis["windows"])
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    else:
        _print_plan(schedule)


@app.command()
def generate(
    machine: Annotated[Path, typer.Argument(help="Machine file (TOML).")],
    output: Annotated[
        Path,
        typer.Option(
            "--output", "-o", help="Folder for the programs and schedule.json (created if missing)."
        ),
    ],
    controllers_dir: ControllersDir = None,
    templates_dir: TemplatesDir = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing on success.")] = False,
) -> None:
    """Write the main program, one subprogram per axis, and schedule.json.

    Example: ncmeasure generate machine.toml -o programs/
    """
    config = _load(machine)
    if output.exists() and not output.is_dir():
        _fail(OutputError(f"{output}: exists and is not a directory"))
    try:
        result = generate_programs(
            config, controllers_dirs=controllers_dir or (), templates_dirs=templates_dir or ()
        )
        written = result.write(output)
    except NcMeasureError as exc:
        _fail(exc)
    if quiet:
        return
    for path in written:
        console.print(f"wrote {path}")
    _print_plan(result.schedule)
    console.print(f"next: [bold]ncmeasure check {output}[/]")


@app.command()
def check(
    directory: Annotated[Path, typer.Argument(help="Folder written by `ncmeasure generate`.")],
    controllers_dir: ControllersDir = None,
) -> None:
    """Re-read generated programs and verify limits, feeds and windows against schedule.json.

    Exit code 0: all holds; 1: a program breaks a limit or its schedule; 2: unreadable input.
    """
    try:
        report = check_programs(directory, tuple(controllers_dir or ()))
    except NcMeasureError as exc:
        _fail(exc)
    console.print(
        f"[green]ok[/]: {directory} ({report.controller}): {report.motions} moves, "
        f"{report.feeds} feeds, {report.windows_found}/{report.windows_expected} windows; "
        "every position inside the soft limits, every feed within the maximum"
    )


def main() -> None:
    """Entry point of the console script."""
    app()
