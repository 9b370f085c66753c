"""The program commands: init, schema, controllers, plan, generate, check."""

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NamedTuple

import typer

from ncmeasure.cli._app import app, console, handle_errors, schema_app, warn
from ncmeasure.cli._options import ControllersDir, TemplatesDir
from ncmeasure.errors import OutputError

if TYPE_CHECKING:
    from ncmeasure.formats.schedule import Schedule

MachineArgument = Annotated[Path, typer.Argument(help="Machine file (TOML).")]


@app.command()
@handle_errors
def init(
    controller: Annotated[
        str, typer.Option(help="Controller dialect of the example (see `ncmeasure controllers`).")
    ] = "sinumerik-840d",
    controllers_dir: ControllersDir = None,
) -> None:
    """Print a commented example machine file; redirect it into a file and edit it.

    Example: ncmeasure init --controller linuxcnc > machine.toml
    """
    from ncmeasure.examples import example_machine
    from ncmeasure.resources import available_dialects, builtin_dir

    found = available_dialects(controllers_dir or ())
    if found.get(controller) != builtin_dir("controllers") / f"{controller}.toml":
        # An unknown name, or a definition of the user's own: read and check it (its
        # errors). A built-in one is known valid (tests/test_startup.py loads each) and
        # needs no loading: its pydantic models are most of init's start-up.
        from ncmeasure.program import load_dialect

        controller = load_dialect(controller, controllers_dir or ()).name
    sys.stdout.write(example_machine(controller))


SCHEMAS = {
    "machine": "ncmeasure.config:MachineConfig",
    "schedule": "ncmeasure.formats.schedule:Schedule",
    "results": "ncmeasure.formats.results:Results",
}
"""The file formats ``ncmeasure schema`` describes, and the model of each."""


def schema_text(name: str) -> str:
    """The JSON Schema of the format ``name`` of :data:`SCHEMAS`, as the command prints it.

    The package carries each schema as a file (``data/schemas/NAME.json``), written from
    its model: the models of a format are most of the command's start-up, and a test
    compares each file with its model's schema (``pytest --update-golden`` rewrites them).
    """
    from importlib import resources

    return (
        resources.files("ncmeasure")
        .joinpath("data", "schemas", f"{name}.json")
        .read_text(encoding="utf-8")
    )


@schema_app.command("machine")
@handle_errors
def schema_machine() -> None:
    """JSON Schema of the machine file (point your editor's TOML support at it)."""
    sys.stdout.write(schema_text("machine"))


@schema_app.command("schedule")
@handle_errors
def schema_schedule() -> None:
    """JSON Schema of schedule.json, the velocity file generate writes."""
    sys.stdout.write(schema_text("schedule"))


@schema_app.command("results")
@handle_errors
def schema_results() -> None:
    """JSON Schema of results.json, what `ncmeasure analyze` writes."""
    sys.stdout.write(schema_text("results"))


@app.command()
@handle_errors
def controllers(
    details: Annotated[
        bool,
        typer.Option("--details", help="Show marker mechanism, options and what was left out."),
    ] = False,
    controllers_dir: ControllersDir = None,
) -> None:
    """List the controller dialects ncmeasure can write programs for."""
    from rich.table import Table

    from ncmeasure.resources import available_dialects

    table = Table("name", "controller", "files", "marker", show_lines=details)
    for name, path in available_dialects(controllers_dir or ()).items():
        dialect = _listed(name, path, controllers_dir or ())
        files = f"{Path(dialect.main_file).suffix} / {Path(dialect.sub_file).suffix}"
        if not dialect.subprograms:
            files = f"{Path(dialect.main_file).suffix} (one program)"
        marker: str = dialect.scope
        if details:
            marker = f"{dialect.scope}: {dialect.mechanism}"
            if dialect.options:
                marker += "\noptions: " + ", ".join(f"{k}={v}" for k, v in dialect.options.items())
            marker += f"\nprogram memory: {dialect.program_kb} kB"
            if dialect.note:
                marker += f" ({dialect.note})"
            if dialect.left_out:
                marker += "\nleft out: " + "; ".join(dialect.left_out)
        table.add_row(name, dialect.title, files, marker)
    console().print(table)


class _Listed(NamedTuple):
    """What ``ncmeasure controllers`` shows of a dialect."""

    title: str
    main_file: str
    sub_file: str
    subprograms: bool
    scope: str
    mechanism: str
    options: dict[str, int | bool]
    program_kb: int
    note: str
    left_out: Sequence[str]


# The defaults of the dialect's models (program/dialect.py) for what the list shows; a
# test compares this list with the models' for every built-in dialect.
_NAMES_DEFAULTS = {"main_file": "{name}.nc", "sub_file": "{name}.nc"}
_MEMORY_DEFAULTS = {"program_kb": 2048, "note": ""}


def _listed(name: str, path: Path, user_dirs: Sequence[Path]) -> _Listed:
    """The dialect ``name`` (its file ``path``) as the list shows it.

    A built-in definition is known valid (tests/test_startup.py loads each) and is read
    as TOML: its pydantic models are most of the command's start-up. A definition of the
    user's own is read and checked (its errors).
    """
    from ncmeasure.resources import builtin_dir

    if path != builtin_dir("controllers") / f"{name}.toml":
        from ncmeasure.program import load_dialect

        dialect = load_dialect(name, user_dirs)
        return _Listed(
            dialect.title,
            dialect.names.main_file,
            dialect.names.sub_file,
            dialect.subprograms,
            dialect.marker.scope,
            dialect.marker.mechanism,
            dialect.options,
            dialect.memory.program_kb,
            dialect.memory.note,
            dialect.left_out,
        )
    import tomllib

    data = tomllib.loads(path.read_text(encoding="utf-8"))
    names = {**_NAMES_DEFAULTS, **data.get("names", {})}
    memory = {**_MEMORY_DEFAULTS, **data.get("memory", {})}
    return _Listed(
        data["title"],
        names["main_file"],
        names["sub_file"],
        data.get("subprograms", True),
        data["marker"]["scope"],
        data["marker"]["mechanism"],
        data.get("options", {}),
        memory["program_kb"],
        memory["note"],
        data.get("left_out", ()),
    )


def _print_plan(schedule: "Schedule") -> None:
    from rich.table import Table
    from rich.text import Text

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
    console().print(
        Text.assemble(
            (schedule.machine, "bold"), f" · {schedule.controller} · config {schedule.config_hash}"
        )
    )
    console().print(table)
    saving = 1 - schedule.duration_s / schedule.full_travel_duration_s
    console().print(
        f"total {_duration(schedule.duration_s)}, {schedule.blocks} blocks (full travel at "
        f"every step: {_duration(schedule.full_travel_duration_s)}, saving {saving:.0%})"
    )
    for axis in schedule.axes:
        if axis.shifted_positions_mm:
            shifted = ", ".join(f"{p:g}" for p in axis.shifted_positions_mm)
            console().print(
                f"note: axis {axis.name}: windows at {shifted} mm move inward at high velocities, "
                "where the run-up would not fit (schedule.json has each window's position)"
            )
    for warning in schedule.warnings:
        warn(warning)


def _duration(seconds: float) -> str:
    minutes, rest = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    if hours:
        return f"{hours}h{minutes:02d}m"
    return f"{minutes}m{rest:02d}s" if minutes else f"{seconds:.1f}s"


@app.command()
@handle_errors
def plan(
    machine: MachineArgument,
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
    from ncmeasure.config import load_machine
    from ncmeasure.program import generate_programs

    config = load_machine(machine)
    result = generate_programs(config, controllers_dirs=controllers_dir or ())
    schedule = result.schedule
    if as_json:
        summary = schedule.model_dump(mode="json")
        for axis in summary["axes"]:
            axis["windows"] = len(axis["windows"])
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    else:
        _print_plan(schedule)


@app.command()
@handle_errors
def generate(
    machine: MachineArgument,
    output: Annotated[
        Path,
        typer.Option(
            "--output",
            "-o",
            help="Folder for the programs, schedule.json and the setup sheet (created if missing).",
        ),
    ],
    controllers_dir: ControllersDir = None,
    templates_dir: TemplatesDir = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing on success.")] = False,
) -> None:
    """Write the main program, one subprogram per axis, schedule.json and the setup sheet.

    The setup sheet (SETUP.md, and setup.html to print) tells the technician at the
    machine where each axis goes, how long it takes, what to do before cycle start,
    how to record and where the marker is.

    Example: ncmeasure generate machine.toml -o programs/
    """
    from rich.text import Text

    from ncmeasure.config import load_machine
    from ncmeasure.program import generate_programs
    from ncmeasure.program.setup import SETUP_HTML, SETUP_MD

    config = load_machine(machine)
    if output.exists() and not output.is_dir():
        raise OutputError(f"{output}: exists and is not a directory")
    result = generate_programs(
        config, controllers_dirs=controllers_dir or (), templates_dirs=templates_dir or ()
    )
    written = result.write(output)
    if quiet:
        return None
    for path in written:
        console().print(f"wrote {path}")
    _print_plan(result.schedule)
    console().print(
        "checked before writing: every position inside the soft limits, every feed within "
        "the maximum, every window as planned"
    )
    console().print(
        Text.assemble(
            "next: ", (f"ncmeasure check {output}", "bold"), " (again after copying or editing)"
        )
    )
    if result.setup is not None:
        console().print(
            Text.assemble(
                "at the machine: read ",
                (str(output / SETUP_MD), "bold"),
                f" (or print {SETUP_HTML}) before cycle start",
            )
        )


@app.command()
@handle_errors
def check(
    directory: Annotated[Path, typer.Argument(help="Folder written by `ncmeasure generate`.")],
    controllers_dir: ControllersDir = None,
) -> None:
    """Re-read generated programs and verify limits, feeds and windows against schedule.json.

    Also verifies that every move lands at the same machine position whatever work
    offset, G92 shift or tool offset the operator left active (the prolog cancels or
    bypasses each, as the controller's manual says; an unknown word is an error), that
    a vertical axis parks first and nothing traverses while it is away from its park,
    and that the main program stops with a message before its first move.

    Exit code 0: all holds; 1: a program breaks a limit or its schedule; 2: unreadable input.
    """
    from rich.text import Text

    from ncmeasure.program import check_programs

    report = check_programs(directory, tuple(controllers_dir or ()))
    coordinates = (
        "every move in work coordinates proved equal to the machine's, or a stop before it"
        if report.verifies_offsets
        else "every move in machine coordinates whatever offset is active"
    )
    console().print(
        Text.assemble(
            ("ok", "green"),
            f": {directory} ({report.controller}): {report.motions} moves, "
            f"{report.feeds} feeds, {report.windows_found}/{report.windows_expected} windows; "
            "every position inside the soft limits, every feed within the maximum, "
            f"{coordinates}",
        )
    )
