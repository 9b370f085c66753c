"""The ``ncmeasure`` command: a thin translation of arguments into library calls.

The CLI owns the console (rich) and is the only place that turns errors into
exit codes: 0 success, 1 a check found problems, 2 bad input (machine file,
options, paths). ``--debug`` shows tracebacks; nobody else ever sees one.
"""

import contextlib
import functools
import importlib.util
import inspect
import json
import logging
import os
import signal
import sys
import threading
import time
import tomllib
import traceback
import types
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, get_args

import typer

from ncmeasure._version import __version__
from ncmeasure.errors import ConfigError, LinkError, NcMeasureError, OutputError, ProgramCheckError

if TYPE_CHECKING:
    import importlib.machinery

    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    from ncmeasure.acquire import Progress
    from ncmeasure.analysis.compare import Comparison
    from ncmeasure.analysis.results import Results
    from ncmeasure.analysis.summary import AxisComparison, Headline
    from ncmeasure.plan import Schedule

__all__ = ["app", "main"]

ANALYSIS_SETTINGS = (
    "velocity_tolerance",
    "velocity_floor_mm_min",
    "settle_s",
    "min_window_s",
    "plateau_min_s",
    "plateau_filter_s",
    "standstill_mm_min",
    "step_tolerance",
    "step_floor_mm_min",
    "position_gap_mm",
    "position_gap_fraction",
    "max_velocity_mm_min",
    "duration_outlier_factor",
    "rapid_count_factor",
    "window_method",
)
"""The names ``analyze --set`` takes (those of AnalysisSettings; a test keeps them equal),
listed here so that ``--help`` need not import the analysis."""

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
"""A check found problems (check), a warning limit was crossed (compare)."""
EXIT_BAD_INPUT = 2
"""Bad input: a machine file, an option, a path, a file that cannot be read or written."""
EXIT_INTERRUPTED = 3
"""Stopped by Ctrl-C/SIGTERM (what was recorded is kept); compare: a critical limit crossed."""
EXIT_LINK = 4
"""A drive link failed (bus, network, drive, simulated drive)."""

Outcome = Literal["ok", "problems", "warning", "critical", "interrupted", "link_lost"]
"""What a command reports besides an error; :func:`_command` turns it into the exit code."""
_OUTCOME_EXIT: dict[str, int] = {
    "ok": EXIT_OK,
    "problems": EXIT_CHECK_FAILED,
    "warning": EXIT_CHECK_FAILED,
    "critical": EXIT_INTERRUPTED,
    "interrupted": EXIT_INTERRUPTED,
    "link_lost": EXIT_LINK,
}

app = typer.Typer(
    name="ncmeasure",
    help=(
        "Measure the friction of machine-tool feed axes with the machine's own drives.\n\n"
        "Typical use: `ncmeasure init --controller sinumerik-840d > machine.toml`, edit the "
        "axes, `ncmeasure plan machine.toml` to see how long it takes, then "
        "`ncmeasure generate machine.toml -o programs/` and `ncmeasure check programs/`.\n\n"
        "New here? `ncmeasure demo` runs the whole pipeline on a virtual machine in about 20 s.\n\n"
        "Exit codes: 0 done; 1 a check found problems or a warning limit was crossed; "
        "2 bad input; 3 stopped by Ctrl-C/SIGTERM or a critical limit crossed; 4 a drive link "
        "failed. --debug (anywhere on the line) shows tracebacks."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Plain help: typer's rich help imports rich and markdown-it, half the start-up time
    # of `--help`; the texts carry no markup (they name [link] tables literally).
    rich_markup_mode=None,
    # Wide enough for each command's first sentence in the list of commands.
    context_settings={"max_content_width": 100},
)
schema_app = typer.Typer(
    help="Print JSON Schemas of ncmeasure's files (for editors).",
    no_args_is_help=True,
    rich_markup_mode=None,
)
app.add_typer(schema_app, name="schema")


@functools.cache
def _console(stderr: bool = False) -> "Console":
    """The console on stdout (or stderr), made at its first use: ``--help`` needs no rich.

    No markup: messages carry user text (machine names, paths, controller names) that
    may hold square brackets; styled parts are rich Text objects.
    """
    from rich.console import Console

    return Console(stderr=stderr, highlight=False, soft_wrap=True, markup=False)


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

PublishOption = Annotated[
    str | None,
    typer.Option(
        "--publish",
        metavar="URL",
        help="After storing, publish the machine's axis summaries to this MQTT broker: "
        "mqtt://[USER@]HOST[:PORT][/PREFIX] or mqtts://... (password: "
        "$NCMEASURE_MQTT_PASSWORD; docs/shop-floor.md). Nothing is sent without it.",
        show_default=False,
    ),
]


def _exit_code(error: BaseException) -> int:
    """The exit code of an error (see the EXIT_ constants)."""
    if isinstance(error, ProgramCheckError):
        return EXIT_CHECK_FAILED
    if isinstance(error, LinkError):
        return EXIT_LINK
    if isinstance(error, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    return EXIT_BAD_INPUT


def _warn(message: str) -> None:
    """``warning: message`` on stderr (user text verbatim)."""
    from rich.text import Text

    _console(stderr=True).print(
        Text.assemble(("warning:", "yellow"), f" {message}"), soft_wrap=True
    )


def _note(message: str) -> None:
    """``note: message`` on stderr (user text verbatim)."""
    from rich.text import Text

    _console(stderr=True).print(Text.assemble(("note:", "bold"), f" {message}"), soft_wrap=True)


MAX_PRINTED_PROBLEMS = 50
"""Problems printed under an error; the rest are counted (the first ones say what is wrong)."""


def _report(error: NcMeasureError) -> None:
    """``error: message`` and one indented line per problem, on stderr (user text verbatim).

    At most :data:`MAX_PRINTED_PROBLEMS` problems are printed, then how many more there are.
    """
    from rich.text import Text

    _console(stderr=True).print(
        Text.assemble(("error:", "bold red"), f" {error.message}"), soft_wrap=True
    )
    shown = error.problems[:MAX_PRINTED_PROBLEMS]
    more = len(error.problems) - len(shown)
    lines = [f"  {line}" for line in shown] + ([f"  … and {more} more"] if more else [])
    if lines:
        _console(stderr=True).print(Text("\n".join(lines)), soft_wrap=True)


_DEBUG_OPTION = Annotated[
    bool,
    typer.Option(
        "--debug", help="Show tracebacks and debug logs (also before the command).", hidden=True
    ),
]


def _command(func: Callable[..., Outcome | None]) -> Callable[..., None]:
    """Run a command's body: the one place where errors and outcomes become exit codes.

    A command body raises :class:`~ncmeasure.errors.NcMeasureError` for anything
    that goes wrong and may return an :data:`Outcome`; no command decides an exit
    code itself. ``--debug`` is accepted after the command name too, and shows
    the traceback of an error without changing its exit code.
    """

    @functools.wraps(func)
    def run(*args: Any, debug: bool = False, **kwargs: Any) -> None:
        if debug:
            _set_debug(True)
        previous = _interrupt_on_sigterm()
        try:
            outcome = func(*args, **kwargs)
        except NcMeasureError as exc:
            _report(exc)
            if _state["debug"]:
                from rich.text import Text

                trace = Text("".join(traceback.format_exception(exc)))
                _console(stderr=True).print(trace, soft_wrap=True)
            raise typer.Exit(_exit_code(exc)) from None
        except KeyboardInterrupt:
            _console(stderr=True).print("interrupted")
            raise typer.Exit(EXIT_INTERRUPTED) from None
        finally:
            _restore_signals(previous)
        code = _OUTCOME_EXIT[outcome or "ok"]
        if code != EXIT_OK:
            raise typer.Exit(code)

    signature = inspect.signature(func, eval_str=True)
    debug = inspect.Parameter(
        "debug", inspect.Parameter.KEYWORD_ONLY, default=False, annotation=_DEBUG_OPTION
    )
    run.__signature__ = signature.replace(  # type: ignore[attr-defined]
        parameters=[*signature.parameters.values(), debug], return_annotation=None
    )
    run.__annotations__ = {**func.__annotations__, "debug": _DEBUG_OPTION, "return": None}
    return run


def _version(value: bool) -> None:
    if value:
        _console().print(f"ncmeasure {__version__}")
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
    _set_debug(debug)


def _set_debug(debug: bool) -> None:
    _state["debug"] = debug
    logging.basicConfig(
        level=logging.DEBUG if debug else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
        force=True,
    )
    # The bus and protocol libraries log what ncmeasure already reports as events
    # and errors; their own lines would only repeat it less clearly.
    for name in ("can", "canopen", "pymodbus", "asyncua"):
        logging.getLogger(name).setLevel(logging.NOTSET if debug else logging.CRITICAL)


@app.command()
@_command
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
    from ncmeasure.program import load_dialect

    dialect = load_dialect(controller, controllers_dir or ())
    sys.stdout.write(example_machine(dialect.name))


@schema_app.command("machine")
@_command
def schema_machine() -> None:
    """JSON Schema of the machine file (point your editor's TOML support at it)."""
    from ncmeasure.config import MachineConfig

    sys.stdout.write(json.dumps(MachineConfig.model_json_schema(), indent=2) + "\n")


@schema_app.command("schedule")
@_command
def schema_schedule() -> None:
    """JSON Schema of schedule.json, the velocity file generate writes."""
    from ncmeasure.plan import Schedule

    sys.stdout.write(json.dumps(Schedule.model_json_schema(), indent=2) + "\n")


@app.command()
@_command
def controllers(
    details: Annotated[
        bool,
        typer.Option("--details", help="Show marker mechanism, options and what was left out."),
    ] = False,
    controllers_dir: ControllersDir = None,
) -> None:
    """List the controller dialects ncmeasure can write programs for."""
    from rich.table import Table

    from ncmeasure.program import available_dialects, load_dialect

    table = Table("name", "controller", "files", "marker", show_lines=details)
    for name in available_dialects(controllers_dir or ()):
        dialect = load_dialect(name, controllers_dir or ())
        files = f"{Path(dialect.names.main_file).suffix} / {Path(dialect.names.sub_file).suffix}"
        if not dialect.subprograms:
            files = f"{Path(dialect.names.main_file).suffix} (one program)"
        marker: str = dialect.marker.scope
        if details:
            marker = f"{dialect.marker.scope}: {dialect.marker.mechanism}"
            if dialect.options:
                marker += "\noptions: " + ", ".join(f"{k}={v}" for k, v in dialect.options.items())
            marker += f"\nprogram memory: {dialect.memory.program_kb} kB"
            if dialect.memory.note:
                marker += f" ({dialect.memory.note})"
            if dialect.left_out:
                marker += "\nleft out: " + "; ".join(dialect.left_out)
        table.add_row(name, dialect.title, files, marker)
    _console().print(table)


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
    _console().print(
        Text.assemble(
            (schedule.machine, "bold"), f" · {schedule.controller} · config {schedule.config_hash}"
        )
    )
    _console().print(table)
    saving = 1 - schedule.duration_s / schedule.full_travel_duration_s
    _console().print(
        f"total {_duration(schedule.duration_s)}, {schedule.blocks} blocks (full travel at "
        f"every step: {_duration(schedule.full_travel_duration_s)}, saving {saving:.0%})"
    )
    for axis in schedule.axes:
        if axis.shifted_positions_mm:
            shifted = ", ".join(f"{p:g}" for p in axis.shifted_positions_mm)
            _console().print(
                f"note: axis {axis.name}: windows at {shifted} mm move inward at high velocities, "
                "where the run-up would not fit (schedule.json has each window's position)"
            )
    for warning in schedule.warnings:
        _warn(warning)


def _duration(seconds: float) -> str:
    minutes, rest = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    if hours:
        return f"{hours}h{minutes:02d}m"
    return f"{minutes}m{rest:02d}s" if minutes else f"{seconds:.1f}s"


@app.command()
@_command
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
@_command
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
    from rich.text import Text

    from ncmeasure.config import load_machine
    from ncmeasure.program import generate_programs

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
        _console().print(f"wrote {path}")
    _print_plan(result.schedule)
    _console().print(
        "checked before writing: every position inside the soft limits, every feed within "
        "the maximum, every window as planned"
    )
    _console().print(
        Text.assemble(
            "next: ", (f"ncmeasure check {output}", "bold"), " (again after copying or editing)"
        )
    )


@app.command()
@_command
def check(
    directory: Annotated[Path, typer.Argument(help="Folder written by `ncmeasure generate`.")],
    controllers_dir: ControllersDir = None,
) -> None:
    """Re-read generated programs and verify limits, feeds and windows against schedule.json.

    Exit code 0: all holds; 1: a program breaks a limit or its schedule; 2: unreadable input.
    """
    from rich.text import Text

    from ncmeasure.program import check_programs

    report = check_programs(directory, tuple(controllers_dir or ()))
    _console().print(
        Text.assemble(
            ("ok", "green"),
            f": {directory} ({report.controller}): {report.motions} moves, "
            f"{report.feeds} feeds, {report.windows_found}/{report.windows_expected} windows; "
            "every position inside the soft limits, every feed within the maximum",
        )
    )


class _CanWithoutMdf:
    """Imports python-can, the first time a command needs it, without its MF4 log support.

    ``import can`` imports asammdf, and with it pandas, whenever the ``mdf`` extra is
    installed: about half a second, for MF4 CAN logs that ncmeasure never reads
    (:mod:`ncmeasure.traces.canlog` takes .blf, .asc, .log and .trc). While python-can
    loads, asammdf looks absent to it; ncmeasure's own MF4 import and export import
    asammdf as usual. Installed by :func:`main` only: a program that imports ncmeasure
    as a library keeps python-can as it is.
    """

    def find_spec(
        self, name: str, path: Sequence[str] | None, target: types.ModuleType | None = None
    ) -> "importlib.machinery.ModuleSpec | None":
        if name != "can":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None or "asammdf" in sys.modules:
            return spec
        loader = spec.loader

        class _Loader:  # a loader by protocol (importlib.abc costs --help 15 ms)
            def create_module(
                self, spec: "importlib.machinery.ModuleSpec"
            ) -> types.ModuleType | None:
                return loader.create_module(spec)

            def exec_module(self, module: types.ModuleType) -> None:
                sys.modules["asammdf"] = None  # type: ignore[assignment]  # "not installed"
                try:
                    loader.exec_module(module)
                finally:
                    del sys.modules["asammdf"]

        spec.loader = _Loader()  # type: ignore[assignment]
        return spec


def main() -> None:
    """Entry point of the console script."""
    if "can" not in sys.modules:
        sys.meta_path.insert(0, _CanWithoutMdf())
    app()


# --- acquisition -------------------------------------------------------------------------


def _pairs(values: list[str], option: str, key: str) -> dict[str, dict[str, Any]]:
    """``X=1`` options into per-axis settings ``{"X": {key: 1}}``."""
    from ncmeasure.config import parse_assignments

    form, example = "AXIS=NUMBER", f"{option} X=1"
    result: dict[str, dict[str, Any]] = {}
    for axis, value in parse_assignments(values, option, form=form, example=example):
        if not value.isdigit():
            raise ConfigError(f"{option} '{axis}={value}': expected {form}, e.g. {example}")
        result.setdefault(axis, {})[key] = int(value)
    return result


def _settings(values: list[str], example: str = "--set sync_hz=500") -> dict[str, Any]:
    """``--set key=value`` options; values are read as TOML (numbers, true/false, strings)."""
    from ncmeasure.config import parse_assignments

    result: dict[str, Any] = {}
    for key, value in parse_assignments(values, "--set", example=example):
        try:
            result[key] = tomllib.loads(f"v = {value}")["v"]
        except (ValueError, RecursionError):  # not TOML (or beyond what Python reads): text
            result[key] = value
    return result


def _axis_settings(values: list[str], axes: list[str]) -> dict[str, dict[str, Any]]:
    """``--axis-set [AXIS.]KEY=VALUE`` options into per-axis link settings.

    Without ``AXIS.`` a setting is for every axis; one for a named axis wins over it,
    whatever the order. Values are read as TOML (numbers, true/false, strings).

    Raises:
        ConfigError: an item not of that form, or an axis the machine lacks.
    """
    from ncmeasure.config import parse_assignments

    result: dict[str, dict[str, Any]] = {}
    form, example = "[AXIS.]KEY=VALUE", "--axis-set X.increments_per_rev=10000"
    pairs = parse_assignments(values, "--axis-set", form=form, example=example)
    pairs.sort(key=lambda pair: "." in pair[0])  # every axis first, then named ones
    for target, text in pairs:
        axis, dot, key = target.rpartition(".")
        if dot and axis not in axes:
            raise ConfigError(
                f"--axis-set '{target}={text}': the machine has no axis {axis} "
                f"(it has {', '.join(axes)})"
            )
        if not key:
            raise ConfigError(f"--axis-set '{target}={text}': expected {form}, e.g. {example}")
        value = _settings([f"{key}={text}"], example=example)[key]
        for name in [axis] if dot else axes:
            result.setdefault(name, {})[key] = value
    return result


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _interrupt_on_sigterm() -> dict[int, Any]:
    """SIGTERM (a timeout, CI, systemd) stops a command like Ctrl-C: its cleanup runs
    (no staging folder is left) and it exits with code 3. Returns the handler to restore."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {signal.SIGTERM: signal.signal(signal.SIGTERM, _interrupt)}


def _stop_on_signals(stop: threading.Event) -> dict[int, Any]:
    """Ctrl-C and SIGTERM set ``stop``; returns the handlers to restore.

    Signal handlers belong to the main thread; elsewhere (an embedding
    program) the caller's own handling stays in place.
    """
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)
    }


def _restore_signals(previous: dict[int, Any]) -> None:
    for sig, handler in previous.items():
        signal.signal(sig, handler)


def _progress_table(progress: "Progress") -> "Table":
    from rich.table import Table

    table = Table(
        title=f"recording · {progress.elapsed_s:.0f} s · {progress.rows} samples · "
        f"{progress.rows_per_s:.0f} samples/s",
        box=None,
        header_style="bold",
    )
    table.add_column("axis")
    table.add_column("current A", justify="right")
    table.add_column("velocity mm/min", justify="right")
    table.add_column("position mm", justify="right")
    axes = list(dict.fromkeys(name.split("_", 1)[0] for name in progress.latest))
    for axis in axes:
        values = [
            progress.latest.get(f"{axis}_{s}")
            for s in ("current_a", "velocity_mm_min", "position_mm")
        ]
        table.add_row(axis, *("—" if v is None else f"{v:.3f}" for v in values))
    table.caption = (
        f"gaps {progress.gaps} ({progress.lost_samples} samples lost) · "
        f"faults {progress.faults}"
        + (f" · last: {progress.last_event}" if progress.last_event else "")
    )
    return table


@app.command("record")
@_command
def record_command(
    machine: Annotated[
        Path,
        typer.Argument(
            help="Machine file; its [link] table and the axes' link settings are the defaults."
        ),
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="New recording directory.")],
    link: Annotated[
        str | None,
        typer.Option(help="canopen, modbus, replay, or a registered link (default: [link] type)."),
    ] = None,
    interface: Annotated[
        str | None,
        typer.Option(
            help="CANopen: python-can interface (virtual, socketcan, pcan, slcan, ...).",
            rich_help_panel="CANopen",
        ),
    ] = None,
    channel: Annotated[
        str | None, typer.Option(help="CANopen: python-can channel.", rich_help_panel="CANopen")
    ] = None,
    bitrate: Annotated[
        int | None, typer.Option(help="CANopen: bit rate in bit/s.", rich_help_panel="CANopen")
    ] = None,
    node: Annotated[
        list[str] | None,
        typer.Option(
            help="CANopen: AXIS=NODE_ID, repeat per axis.",
            rich_help_panel="CANopen",
            metavar="AXIS=NODE_ID",
        ),
    ] = None,
    sync_hz: Annotated[
        float | None, typer.Option(help="CANopen: SYNC rate in Hz.", rich_help_panel="CANopen")
    ] = None,
    eds: Annotated[
        Path | None,
        typer.Option(help="CANopen: the drives' EDS/DCF file.", rich_help_panel="CANopen"),
    ] = None,
    host: Annotated[
        str | None, typer.Option(help="Modbus TCP: host.", rich_help_panel="Modbus")
    ] = None,
    port: Annotated[
        int | None, typer.Option(help="Modbus TCP: port.", rich_help_panel="Modbus")
    ] = None,
    unit: Annotated[
        list[str] | None,
        typer.Option(
            help="Modbus: AXIS=UNIT_ID, repeat per axis.",
            rich_help_panel="Modbus",
            metavar="AXIS=UNIT_ID",
        ),
    ] = None,
    register_map: Annotated[
        str | None,
        typer.Option(
            help="Modbus: register map (built-in name or TOML file).", rich_help_panel="Modbus"
        ),
    ] = None,
    poll_hz: Annotated[
        float | None, typer.Option(help="Modbus: polls per second.", rich_help_panel="Modbus")
    ] = None,
    serial_port: Annotated[
        str | None, typer.Option(help="Modbus RTU: serial port.", rich_help_panel="Modbus")
    ] = None,
    source: Annotated[
        Path | None,
        typer.Option(help="Replay: the recording to play back.", rich_help_panel="Replay"),
    ] = None,
    speed: Annotated[
        float | None,
        typer.Option(
            help="Replay: 1 = recorded speed, 0 = as fast as possible.", rich_help_panel="Replay"
        ),
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="Any other link setting, KEY=VALUE.", metavar="KEY=VALUE"),
    ] = None,
    axis_set: Annotated[
        list[str] | None,
        typer.Option(
            "--axis-set",
            help="A per-axis link setting (what an axis' link table holds): KEY=VALUE for "
            "every axis, AXIS.KEY=VALUE for one, e.g. --axis-set increments_per_rev=10000 "
            "--axis-set Z.gear_ratio=2. Over the machine file's; --node and --unit go last.",
            metavar="[AXIS.]KEY=VALUE",
        ),
    ] = None,
    duration: Annotated[
        float | None, typer.Option(help="Seconds to record (positive, finite).")
    ] = None,
    schedule: Annotated[
        Path | None,
        typer.Option(help="schedule.json of the program: stop after its end plus a margin."),
    ] = None,
    raw_log: Annotated[
        Path | None, typer.Option(help="CANopen: also log every frame (.blf/.asc).")
    ] = None,
    notes: Annotated[str, typer.Option(help="Free text stored with the recording.")] = "",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No live display.")] = False,
) -> Outcome:
    """Record motor current, velocity and position from the drives into a recording.

    Stops after --duration, at the end of --schedule, at the end of a replay, or on
    Ctrl-C/SIGTERM; every way of stopping closes the recording with what was received.
    Exit code 0: complete; 2: bad input; 3: stopped by Ctrl-C/SIGTERM; 4: the link failed.

    A file from `ncmeasure init` names no drives: --node (CANopen) or --unit (Modbus)
    gives each axis its drive, --axis-set the rest of its link table.

    Example: ncmeasure record m.toml --link canopen --interface socketcan --channel can0
    --node X=1 --node Y=2 --node Z=3 --axis-set increments_per_rev=10000 --sync-hz 250
    --duration 60 -o run1
    """
    from rich.live import Live

    from ncmeasure.acquire import record
    from ncmeasure.config import load_machine
    from ncmeasure.program import load_schedule

    config = load_machine(machine)
    overrides: dict[str, Any] = {
        key: value
        for key, value in {
            "interface": interface,
            "channel": channel,
            "bitrate": bitrate,
            "sync_hz": sync_hz,
            "eds": eds,
            "host": host,
            "port": port,
            "register_map": register_map,
            "poll_hz": poll_hz,
            "serial_port": serial_port,
            "source": source,
            "speed": speed,
            "raw_log": raw_log,
        }.items()
        if value is not None
    }
    overrides.update(_settings(set_ or []))
    axis_overrides = _axis_settings(axis_set or [], [a.name for a in config.axes])
    for option, key, values in (("--node", "node_id", node), ("--unit", "unit_id", unit)):
        for axis, pair in _pairs(values or [], option, key).items():
            axis_overrides.setdefault(axis, {}).update(pair)
    unknown = set(axis_overrides) - {a.name for a in config.axes}
    if unknown:
        raise ConfigError(
            f"--node/--unit name axes the machine lacks: {', '.join(sorted(unknown))}"
        )
    plan_schedule = load_schedule(schedule) if schedule else None

    stop = threading.Event()
    previous = _stop_on_signals(stop)
    live: Live | None = None

    def show(progress: "Progress") -> None:
        if live is not None:
            live.update(_progress_table(progress))

    try:
        if not quiet:
            live = Live(console=_console(stderr=True), refresh_per_second=4, transient=True)
            live.start()
        result = record(
            config,
            out=output,
            link=link,
            link_settings=overrides,
            axis_settings=axis_overrides,
            duration_s=duration,
            schedule=plan_schedule,
            notes=notes,
            stop=stop,
            on_progress=None if quiet else show,
        )
    finally:
        if live is not None:
            live.stop()  # before any message, so the display does not overwrite it
        _restore_signals(previous)
    if result.moved_aside is not None:
        _note(
            f"the unfinished earlier attempt in {result.directory} was moved to "
            f"{result.moved_aside}, whole"
        )
    if not quiet or result.status != "complete":
        _console(stderr=True).print(
            f"{result.status}: {result.rows} samples over {result.link_time_s:.1f} s in "
            f"{result.directory}" + (f"; {result.error}" if result.error else ""),
            soft_wrap=True,
        )
    if result.gaps:
        _warn(
            f"{result.lost_samples} samples lost in {result.gaps} gap(s), "
            f"{100 * result.lost_share:.2g} % of the recording; the gap events in "
            f"{result.directory} say when and why, and the analysis reports them"
        )
    if result.status == "interrupted":
        return "interrupted"
    if result.status == "link_lost":
        return "link_lost"
    return "ok"  # complete, or incomplete with the warning above


_FORMATS = {"csv": ".csv", "mdf4": ".mf4"}


@app.command("export")
@_command
def export_command(
    run: Annotated[Path, typer.Argument(help="Recording directory.")],
    fmt: Annotated[str, typer.Option("--format", "-f", help="csv or mdf4.")] = "csv",
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Output file (default: next to RUN).")
    ] = None,
) -> None:
    """Write a recording as one CSV (time_s, then <AXIS>_<signal> columns) or MDF4 file."""
    from ncmeasure.recording import RecordingHead
    from ncmeasure.traces.csv import export_csv
    from ncmeasure.traces.mdf4 import export_mdf4

    if fmt not in _FORMATS:
        raise ConfigError(f"--format {fmt!r}: expected one of {', '.join(_FORMATS)}")
    target = output or run.with_suffix(_FORMATS[fmt])
    head = RecordingHead.open(run)  # the samples are read chunk by chunk while written
    if fmt == "csv":
        export_csv(head, target)
    else:
        export_mdf4(head, target)
    # what was wrong with the recording is logged as a warning when read, as for analyze
    _console().print(f"wrote {target} ({head.rows} samples)")


@app.command("import")
@_command
def import_command(
    file: Annotated[Path, typer.Argument(help="Trace or exported file to import.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="New recording directory.")],
    fmt: Annotated[
        str | None,
        typer.Option(
            "--format",
            "-f",
            help="sinumerik-xml, sinumerik-csv, twincat-csv, tncscope, csv, mdf4, can-log "
            "(default: detected from the content; CAN logs by their ending .blf, .asc, "
            ".log, .trc).",
        ),
    ] = None,
    machine: Annotated[
        Path | None,
        typer.Option(
            help="Machine file: axis names, screw lead and torque constant for unit conversion."
        ),
    ] = None,
    axis: Annotated[
        list[str] | None,
        typer.Option(
            help="Map a trace's axis to a machine axis, e.g. --axis 1=X --axis 2=Y.",
            metavar="TRACE_AXIS=AXIS",
        ),
    ] = None,
    columns: Annotated[
        Path | None,
        typer.Option(
            "--columns",
            help="Column map (TOML): read FILE as any CSV whose columns it names "
            "(channel = column, scale, offset; period_s or a time column). "
            "Not with --format or --axis.",
        ),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress, no report.")] = False,
) -> None:
    """Turn a controller trace or an exported CSV/MDF4 file into a recording.

    Reads SINUMERIK trace XML and CSV, TwinCAT Scope CSV, TNCscope text and the
    CSV of `ncmeasure export`, any CSV through a column map (--columns), and CAN logs
    of a CANopen bus (.blf, .asc, .log, .trc: decoded with the machine file's [link]
    settings, as the CANopen link reads the live bus); reports what was mapped,
    converted and left out.
    Examples: ncmeasure import trace.xml --machine machine.toml --axis 1=X -o run1
    ·  ncmeasure import capture.blf --machine machine.toml -o run2
    """
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn

    from ncmeasure.config import load_machine, parse_assignments
    from ncmeasure.traces import import_trace
    from ncmeasure.traces.mdf4 import import_mdf4

    axis_names = dict(
        parse_assignments(axis or [], "--axis", form="TRACE_AXIS=MACHINE_AXIS", example="1=X")
    )
    report: list[str] = []
    config = load_machine(machine) if machine else None
    if columns is None and (
        fmt == "mdf4" or (fmt is None and file.suffix.lower() in (".mf4", ".mdf"))
    ):
        recording = import_mdf4(file, output, machine=config)
        report = list(recording.meta.link.get("report", []))
        samples, channels = len(recording.time_s), len(recording.channels)
    else:
        bar = (
            None
            if quiet
            else Progress(
                TextColumn("importing {task.description}", markup=False),
                BarColumn(),
                DownloadColumn(),
                console=_console(stderr=True),
                transient=True,
            )
        )
        task = bar.add_task(file.name, total=None) if bar else None

        def progress(done: int, total: int) -> None:
            if bar is not None and task is not None:
                bar.update(task, completed=done, total=total)

        if bar is not None:
            bar.start()
        try:
            result = import_trace(
                file,
                output,
                format=fmt,
                machine=config,
                axis_names=axis_names or None,
                progress=progress,
                columns=columns,
            )
        finally:
            if bar is not None:
                bar.stop()
        # the counts from meta.json: reading a large recording back would cost its size in memory
        report, samples = result.report, result.meta.samples or 0
        channels = len(result.meta.channels)
    if not quiet:
        for line in report:
            _console(stderr=True).print(f"  {line}")
    _console().print(f"wrote {output} ({samples} samples, {channels} channels)")


@app.command("simulate-drive")
@_command
def simulate_drive_command(
    link: Annotated[str, typer.Option(help="canopen or modbus.")],
    interface: Annotated[
        str | None,
        typer.Option(
            help="CANopen: python-can interface. The default, virtual, reaches only this "
            "process; for `record` in another terminal use socketcan (with a vcan device) "
            "or udp_multicast.",
            rich_help_panel="CANopen",
        ),
    ] = "virtual",
    channel: Annotated[
        str | None, typer.Option(help="CANopen: python-can channel.", rich_help_panel="CANopen")
    ] = "ncmeasure",
    node: Annotated[
        list[str] | None,
        typer.Option(
            help="CANopen: AXIS=NODE_ID per simulated drive (default X=1 Y=2 Z=3).",
            metavar="AXIS=NODE_ID",
            rich_help_panel="CANopen",
        ),
    ] = None,
    eds: Annotated[
        Path | None,
        typer.Option(
            help="CANopen: build the drives' object dictionary from this EDS/DCF.",
            rich_help_panel="CANopen",
        ),
    ] = None,
    host: Annotated[
        str, typer.Option(help="Modbus TCP: address to listen on.", rich_help_panel="Modbus")
    ] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Modbus TCP: port.", rich_help_panel="Modbus")] = 5020,
    unit: Annotated[
        list[str] | None,
        typer.Option(
            help="Modbus: AXIS=UNIT_ID per simulated drive (default X=1 Y=2 Z=3).",
            metavar="AXIS=UNIT_ID",
            rich_help_panel="Modbus",
        ),
    ] = None,
    register_map: Annotated[
        str, typer.Option(help="Modbus: register map served.", rich_help_panel="Modbus")
    ] = "generic",
    serial_port: Annotated[
        str | None,
        typer.Option(
            help="Modbus RTU: serve on this serial port instead of TCP.", rich_help_panel="Modbus"
        ),
    ] = None,
    baudrate: Annotated[
        int, typer.Option(help="Modbus RTU: baud rate.", rich_help_panel="Modbus")
    ] = 19200,
    parity: Annotated[
        str,
        typer.Option(help="Modbus RTU: parity N, E or O.", rich_help_panel="Modbus"),
    ] = "E",
    duration: Annotated[
        float | None, typer.Option(help="Seconds to run (default: until Ctrl-C).")
    ] = None,
) -> None:
    """Run simulated servo drives, for trying `ncmeasure record` without a machine.

    The drives report a smooth test motion of every axis. Example, in two terminals:
    `ncmeasure simulate-drive --link modbus --port 5020` and
    `ncmeasure record m.toml --link modbus --host 127.0.0.1 --port 5020 --unit X=1 ...`.
    Exit code 0: stopped; 2: bad input (an interface python-can does not know); 4: the
    drives cannot serve there (port in use, a CAN interface that cannot be opened).
    """
    stop = threading.Event()
    previous = _stop_on_signals(stop)
    default = {"X": 1, "Y": 2, "Z": 3}
    if duration is not None:
        threading.Timer(duration, stop.set).start()
    try:
        if link == "modbus":
            from ncmeasure.links.modbus.settings import settings_from_tables
            from ncmeasure.sim.modbus_drive import ServerInfo, serve

            units = {a: v["unit_id"] for a, v in _pairs(unit or [], "--unit", "unit_id").items()}

            def ready(info: ServerInfo) -> None:
                units_text = ", ".join(f"{a}={u}" for a, u in info.units.items())
                _console(stderr=True).print(
                    f"simulated Modbus drives on {info.endpoint}, units {units_text}; Ctrl-C stops",
                    soft_wrap=True,
                )

            settings, axes = settings_from_tables(
                {
                    "host": host,
                    "port": port or 502,  # 0: a free port (free_port)
                    "register_map": register_map,
                    "serial_port": serial_port,
                    "baudrate": baudrate,
                    "parity": parity,
                },
                {axis: {"unit_id": unit_id} for axis, unit_id in (units or default).items()},
            )
            serve(settings, axes, free_port=port == 0, ready=ready, stop=stop)
        elif link == "canopen":
            from ncmeasure.sim.cia402 import VIRTUAL_BUS_REACH
            from ncmeasure.sim.cia402 import serve as serve_canopen

            nodes = {a: v["node_id"] for a, v in _pairs(node or [], "--node", "node_id").items()}
            ids = list((nodes or default).values())

            def canopen_ready(_: object) -> None:
                _console(stderr=True).print(
                    f"simulated CiA 402 drives, nodes {ids}, on {interface}:{channel}; "
                    "Ctrl-C stops",
                    soft_wrap=True,
                )
                if interface == "virtual":
                    _note(VIRTUAL_BUS_REACH)

            serve_canopen(
                channel=channel,
                interface=interface,
                nodes=ids,
                eds=eds,
                stop=stop,
                on_ready=canopen_ready,
            )
        else:
            raise ConfigError(f"--link {link!r}: simulated drives exist for canopen and modbus")
    finally:
        stop.set()
        _restore_signals(previous)


# --- analysis ----------------------------------------------------------------------------


def _progress_bar(quiet: bool, *, stages: bool = False) -> tuple[Any, Any]:
    """A rich progress bar and a ``progress(stage, fraction)`` callback feeding it.

    ``fraction`` None starts a stage without a figure. With ``stages``, every
    finished stage stays on the console as a line with its duration.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.text import Text

    if quiet:
        return None, None
    bar = Progress(
        TextColumn("{task.description}", markup=False),
        BarColumn(),
        TimeElapsedColumn(),
        console=_console(stderr=True),
        transient=True,
    )
    task = bar.add_task("starting", total=1.0)
    current: dict[str, Any] = {"stage": None, "since": time.monotonic()}

    def update(stage: str, fraction: float | None) -> None:
        if stage != current["stage"]:
            if stages and current["stage"] is not None:
                took = time.monotonic() - current["since"]
                bar.console.print(
                    Text.assemble(("✓", "green"), f" {current['stage']} ({took:.1f} s)")
                )
            current.update(stage=stage, since=time.monotonic())
            bar.update(task, description=stage, completed=0.0)
        if fraction is not None:
            bar.update(task, completed=max(0.0, min(1.0, fraction)))

    return bar, update


@app.command("analyze")
@_command
def analyze_command(
    run: Annotated[Path, typer.Argument(help="Recording directory (recorded or imported).")],
    schedule: Annotated[
        Path | None,
        typer.Option(
            help="schedule.json of the program: labels every window with its step and position."
        ),
    ] = None,
    machine: Annotated[
        Path | None,
        typer.Option(
            help="Machine file: torque constant, screw lead, fixed-bearing end, vertical axes."
        ),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="results.json to write (default: RUN.results.json)."),
    ] = None,
    report: Annotated[Path | None, typer.Option(help="Also write this HTML report.")] = None,
    only: Annotated[
        list[str] | None,
        typer.Option(
            "--axis",
            help="Analyse only this axis (repeat for several; default: every axis).",
            metavar="AXIS",
        ),
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            metavar="KEY=VALUE",
            help="An analysis setting, KEY=VALUE, e.g. --set settle_s=0.2 --set "
            f"window_method=command. Settings: {', '.join(ANALYSIS_SETTINGS)} "
            "(docs/analysis.md, Settings).",
        ),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress, no summary.")] = False,
    store: Annotated[
        str | None,
        typer.Option(
            "--store",
            metavar="URL",
            help="Also add the results to this fleet store (needs --serial; see "
            "`ncmeasure store --help`).",
            show_default=False,
        ),
    ] = None,
    serial: Annotated[
        str | None, typer.Option(help="The machine's serial number, for --store.")
    ] = None,
    label: Annotated[
        str | None, typer.Option(help="For --store: delivery, service, after-repair, ...")
    ] = None,
    publish: PublishOption = None,
) -> None:
    """Friction per position, direction and velocity; fits; position diagnosis; a verdict.

    Windows come from the marker when recorded, else from commanded vs actual velocity,
    else from constant-velocity plateaus. An axis that cannot be analysed (a dead
    channel, no motion) is skipped with the reason; the others are analysed (exit 0).
    Example: ncmeasure analyze run1 --schedule programs/schedule.json --report run1.html
    """
    from pydantic import ValidationError

    from ncmeasure.analysis.analyze import AnalysisSettings, analyze, write_results
    from ncmeasure.config import format_validation_error, load_machine
    from ncmeasure.program import load_schedule
    from ncmeasure.recording import RecordingHead

    target = output or run.with_name(run.name + ".results.json")
    if (store is None) != (serial is None) or (label is not None and store is None):
        raise ConfigError("--store, --serial and --label go together: give --store and --serial")
    if publish is not None and store is None:
        raise ConfigError("--publish sends what --store stored: give --store and --serial too")
    broker = _mqtt_target(publish)
    info = (
        _measurement_info(serial=serial, label=label, recording_location=str(run.absolute()))
        if serial is not None
        else None
    )
    try:
        settings = AnalysisSettings.model_validate(
            _settings(set_ or [], example="--set settle_s=0.2")
        )
    except ValidationError as exc:
        raise ConfigError(
            "--set: not valid analysis settings", format_validation_error(exc)
        ) from exc
    # Read chunk by chunk: memory follows the windows, not the recording's length.
    recording = RecordingHead.open(run)
    plan_schedule = load_schedule(schedule) if schedule else None
    config = load_machine(machine) if machine else None
    traces = None
    if report is not None:
        # The raw-data figures' data is gathered on the analysis' own readings.
        from ncmeasure.report.traces import RawTraces

        traces = RawTraces(recording)
    bar, update = _progress_bar(quiet)
    if bar is not None:
        bar.start()
    windows: dict[str, list[tuple[float, float]]] = {}
    try:
        results = analyze(
            recording,
            schedule=plan_schedule,
            machine=config,
            settings=settings,
            axes=only or None,
            progress=update,
            window_times=windows,
            on_windows=traces.watch if traces is not None else None,
        )
    finally:
        if bar is not None:
            bar.stop()
    write_results(results, target)
    if report is not None:
        from ncmeasure.report import write_report

        write_report(
            results,
            report,
            recording=recording,
            windows=windows,
            traces=traces.found if traces is not None else None,
        )
    if info is not None:
        with _open_store(store, write=True) as fleet:
            added = fleet.add(results, info)
        if not quiet:
            state = "stored as" if added.new else "already stored as"
            _console().print(f"{state} measurement {added.measurement_id} of {serial}")
        _publish_added(broker, store, added, quiet)
    if quiet:
        return None
    _print_verdicts(results)
    _print_warnings(results)
    _console().print(f"wrote {target}" + (f" and {report}" if report else ""))


_LEVEL_STYLE = {"ok": "bold green", "check": "bold yellow", "fault": "bold red"}


def _verdict_line(name: str, headline: "Headline") -> "Text":
    """``axis X: fault · Coulomb friction 1.58 Nm (...); spread ...; why; what to do``.

    The Coulomb figure is :attr:`Headline.coulomb_text`, the report's headline.
    """
    from rich.text import Text

    verdict = headline.verdict
    line = Text(f"axis {name}: ")
    line.append(verdict.level, style=_LEVEL_STYLE.get(verdict.level, "bold"))
    line.append(
        f" · Coulomb friction {headline.coulomb_text}; {headline.travel_text}. {verdict.reason}"
    )
    if verdict.level != "ok":
        action = verdict.action.rstrip(".")
        line.append(f" What to do: {action[:1].upper()}{action[1:]}.")
    return line


def _print_verdicts(
    results: "Results", comparison: "Comparison | None" = None, indent: str = ""
) -> None:
    """One line per analysed axis, verdict first; then the axes not analysed and why.

    With a comparison, the verdict is combined with the axis' change against
    its base (the last compared run's, as the report shows it).
    """
    for name in results.axes:
        _print_verdict(results, name, comparison, indent)
    _print_skipped(results, indent)


def _print_verdict(
    results: "Results", name: str, comparison: "Comparison | None" = None, indent: str = ""
) -> None:
    from rich.text import Text

    from ncmeasure.analysis.summary import axis_comparison, axis_headline

    against = axis_comparison(comparison, name) if comparison is not None else None
    headline = axis_headline(results.axes[name], against)
    line = Text(indent).append_text(_verdict_line(name, headline))
    if against is not None:
        _append_change(line, headline, against)
    _console().print(line)


def _append_change(line: "Text", headline: "Headline", against: "AxisComparison") -> None:
    """The change against the base, unless the verdict says it already, and its likely cause."""
    from ncmeasure.report.words import CAUSE_TITLES

    if against.change not in headline.verdict.reason:
        line.append(f" Against {against.base!r}: {against.status}, {against.change}.")
    if against.cause is not None and against.cause.cause != "none":
        title = CAUSE_TITLES.get(against.cause.cause, against.cause.cause)
        line.append(f" Likely cause of the change: {title} (score {against.cause.score:.2f}).")


def _print_skipped(results: "Results", indent: str = "") -> None:
    from rich.text import Text

    for name, reason in results.skipped.items():
        line = Text(f"{indent}axis {name}: ")
        line.append("not analysed", style="bold")
        line.append(f" · {reason}")
        _console().print(line)


def _print_warnings(results: "Results") -> None:
    """Analysis warnings on stderr; one shared by every axis once.

    The recording's own problems (a torn tail, missing samples) are not repeated
    here: the reader logs each as it reads the recording, before the results.
    """
    from rich.text import Text

    lists = [axis.warnings for axis in results.axes.values()]
    shared = set.intersection(*(set(w) for w in lists)) if len(lists) > 1 else set()
    for warning in lists[0] if lists else []:
        if warning in shared:
            _console(stderr=True).print(Text.assemble(("warning:", "yellow"), f" {warning}"))
    for name, axis in results.axes.items():
        for warning in axis.warnings:
            if warning not in shared:
                _console(stderr=True).print(
                    Text.assemble(("warning:", "yellow"), f" axis {name}: {warning}")
                )


WarningOption = Annotated[
    float | None,
    typer.Option(help="Warning limit of the change against the baseline, in % (default 20)."),
]
CriticalOption = Annotated[
    float | None,
    typer.Option(help="Critical limit of the change against the baseline, in % (default 40)."),
]


@app.command("compare")
@_command
def compare_command(
    base: Annotated[
        Path,
        typer.Argument(
            help="results.json of the reference (the machine at delivery, or the fleet's first)."
        ),
    ],
    others: Annotated[list[Path], typer.Argument(help="results.json files to compare with it.")],
    warning: WarningOption = None,
    critical: CriticalOption = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Write the comparison as JSON.")
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option(help="Write an HTML report of the last run with the comparison."),
    ] = None,
    label: Annotated[
        list[str] | None,
        typer.Option(
            "--label",
            metavar="LABEL",
            help="Name of a compared file in the output; repeat in order, one per file "
            "after BASE (or one per file, BASE's first). Default: the file name, with its "
            "folders where names clash (m17/results, m18/results).",
        ),
    ] = None,
) -> Outcome:
    """Compare runs: the same machine over its life, or identical machines (fleet).

    Exit code 0: every deviation within the warning limit; 1: a warning limit crossed;
    3: a critical limit crossed; 2: bad input (also an output that cannot be written).

    Example: ncmeasure compare m17/results.json m18/results.json m19/results.json
    """
    from ncmeasure.analysis.analyze import load_results
    from ncmeasure.analysis.compare import compare_results, write_comparison

    labels = _compare_labels(base, others, label)
    reference = load_results(base)
    runs = [load_results(path) for path in others]
    limits = _limits(warning, critical)
    comparison = compare_results(reference, runs, labels=labels, limits=limits)
    if output is not None:
        write_comparison(comparison, output)
    if report is not None:
        from ncmeasure.report import write_report

        write_report(runs[-1], report, comparison=comparison)
        _console().print(f"wrote {report}")
    _print_comparison(comparison, runs)
    return comparison.status


def _file_labels(paths: list[Path]) -> list[str]:
    """A label per results file: its name without ``.json``; where names clash, with as
    many of its folders as tell them apart (``m17/results``), else numbered (``#2``)."""

    def label(path: Path, depth: int) -> str:
        folders = path.absolute().parent.parts[1:]
        return "/".join([*folders[len(folders) - depth :], path.stem]) if depth else path.stem

    depths = [0] * len(paths)
    labels = [path.stem for path in paths]
    while True:
        grown = False
        for name in {name for name in labels if labels.count(name) > 1}:
            group = [i for i, other in enumerate(labels) if other == name]
            if len({paths[i].absolute() for i in group}) == 1:
                continue  # the same file: only a number tells them apart
            for index in group:
                if depths[index] < len(paths[index].absolute().parent.parts) - 1:
                    depths[index] += 1
                    labels[index] = label(paths[index], depths[index])
                    grown = True
        if not grown:
            break
    doubled = {name for name in labels if labels.count(name) > 1}
    counts: dict[str, int] = {}
    for index, name in enumerate(labels):
        if name in doubled:
            counts[name] = counts.get(name, 0) + 1
            labels[index] = f"{name} #{counts[name]}"
    return labels


def _compare_labels(base: Path, others: list[Path], given: list[str] | None) -> list[str]:
    """The labels of the compared files: ``--label`` checked, or from the file names.

    Raises:
        ConfigError: ``--label`` given neither once per file after BASE nor once per
            file, empty, or twice the same.
    """
    if not given:
        return _file_labels([base, *others])[1:]
    if len(given) not in (len(others), len(others) + 1):
        raise ConfigError(
            f"--label: {len(given)} label{'s' if len(given) != 1 else ''} for "
            f"{len(others)} compared file{'s' if len(others) != 1 else ''}: give one per "
            "file after BASE, in order (or one per file, BASE's first)"
        )
    if any(not text.strip() for text in given):
        raise ConfigError("--label: a label is empty; every compared file needs a name")
    doubled = next((text for text in given if given.count(text) > 1), None)
    if doubled is not None:
        raise ConfigError(f"--label: {doubled!r} is given twice; labels must be unique")
    return list(given)


def _print_comparison(comparison: "Comparison", runs: "list[Results]") -> None:
    """Per compared run and axis: its verdict with the change, the report's headline figure."""
    from rich.text import Text

    from ncmeasure.analysis.summary import axis_comparison, axis_headline, format_number

    for label, results in zip(comparison.others, runs, strict=True):
        for name, axis in results.axes.items():
            against = axis_comparison(comparison, name, label)
            headline = axis_headline(axis, against)
            line = Text(f"{label}: ").append_text(_verdict_line(name, headline))
            if against is None:
                line.append(f" Not compared with {comparison.base}.")
            else:
                _append_change(line, headline, against)
            _console().print(line)
        for name, reason in results.skipped.items():
            _console().print(Text(f"{label}: axis {name}: not analysed · {reason}"))
    for fleet in comparison.fleet:
        outliers = ", ".join(fleet.outliers) or "none"
        _console().print(
            Text(
                f"fleet, axis {fleet.axis}: mean friction {format_number(fleet.mean)} "
                f"{fleet.unit} over {len(fleet.runs)} runs, spread {fleet.spread_percent:.1f} %, "
                f"outliers: {outliers}"
            )
        )
    if comparison.problems:
        _console().print(
            f"{len(comparison.problems)} matching problem(s): not every point was compared "
            "(the comparison file and the report list them)"
        )


store_app = typer.Typer(
    help="The fleet store: every measurement of every machine over its life, in SQLite "
    "(a file, the default) or PostgreSQL. Name it with --store URL or NCMEASURE_STORE: "
    "sqlite:///fleet.db, postgresql://user@host/db, or a file path. Default: "
    "~/.local/share/ncmeasure/fleet.db.\n\n"
    "Typical use: `ncmeasure store add m17.results.json --serial M17 --label delivery`, "
    "years later the same with --label service, then `ncmeasure store check M17`.",
    no_args_is_help=True,
    rich_markup_mode=None,
)
app.add_typer(store_app, name="store")

StoreOption = Annotated[
    str | None,
    typer.Option(
        "--store",
        metavar="URL",
        help="The store: sqlite:///FILE, postgresql://USER@HOST/DB, or a file path "
        "(default: $NCMEASURE_STORE, else ~/.local/share/ncmeasure/fleet.db).",
        show_default=False,
    ),
]


def _open_store(url: str | None, *, write: bool) -> Any:
    """The store module's ``open_store`` context on the resolved URL; a clear error
    naming the extra when SQLAlchemy is missing."""
    try:
        from ncmeasure.store import open_store, store_url
    except ImportError as exc:
        from ncmeasure.errors import DependencyError

        raise DependencyError(
            f"the fleet store needs the package {exc.name!r}, which is missing "
            "(pip install 'ncmeasure[store]')"
        ) from exc
    return open_store(store_url(url), write=write)


def _measurement_info(**fields: Any) -> Any:
    from ncmeasure.store import MeasurementInfo

    return MeasurementInfo(**fields).checked()


def _limits(warning: float | None, critical: float | None) -> Any:
    """The limits of --warning/--critical; bad ones in one line, named as options."""
    from pydantic import ValidationError

    from ncmeasure.analysis.compare import Limits

    options = {"warning_percent": "--warning", "critical_percent": "--critical"}
    updates = {
        k: v for k, v in {"warning_percent": warning, "critical_percent": critical}.items()
        if v is not None
    }  # fmt: skip
    try:
        return Limits.model_validate(updates)
    except ValidationError as exc:
        problems = []
        for error in exc.errors(include_url=False):
            text = str(error["msg"]).removeprefix("Value error, ")
            for field, option in options.items():
                text = text.replace(field, option)
            field = str(error["loc"][0]) if error["loc"] else ""
            problems.append(f"{options[field]} {updates[field]:g}: {text}" if field else text)
        raise ConfigError("; ".join(problems)) from exc


@store_app.command("add")
@_command
def store_add_command(
    results_file: Annotated[Path, typer.Argument(help="results.json of `ncmeasure analyze`.")],
    serial: Annotated[str, typer.Option(help="The machine's serial number.")],
    label: Annotated[
        str | None,
        typer.Option(help="What the measurement is: delivery, service, after-repair, ..."),
    ] = None,
    site: Annotated[str | None, typer.Option(help="Where the machine stands.")] = None,
    machine_type: Annotated[
        str | None,
        typer.Option("--type", help="The machine type (default: the machine name in the results)."),
    ] = None,
    operator: Annotated[str | None, typer.Option(help="Who measured.")] = None,
    temperature_c: Annotated[
        float | None, typer.Option("--temperature-c", help="Machine temperature in °C.")
    ] = None,
    operating_hours: Annotated[
        float | None, typer.Option(help="The machine's operating hours.")
    ] = None,
    recording: Annotated[
        str | None,
        typer.Option(help="Where the raw recording is kept (default: its folder in the results)."),
    ] = None,
    store: StoreOption = None,
    publish: PublishOption = None,
) -> None:
    """Add a measurement's results to the store (the same results twice are stored once).

    Example: ncmeasure store add m17.results.json --serial M17 --label delivery --temperature-c 21.5
    """
    from ncmeasure.analysis.analyze import load_results

    info = _measurement_info(
        serial=serial,
        label=label,
        site=site,
        machine_type=machine_type,
        operator=operator,
        temperature_c=temperature_c,
        operating_hours=operating_hours,
        recording_location=recording,
    )
    target = _mqtt_target(publish)
    results = load_results(results_file)
    with _open_store(store, write=True) as fleet:
        added = fleet.add(results, info)
        where = fleet.where
    if added.new:
        _console().print(f"stored as measurement {added.measurement_id} of {serial} in {where}")
    else:
        _console().print(
            f"already stored as measurement {added.measurement_id} of {serial}; nothing added"
        )
    _publish_added(target, store, added, quiet=False)


@store_app.command("list")
@_command
def store_list_command(store: StoreOption = None) -> None:
    """The machines in the store: type, site, measurements, the latest verdicts."""
    from rich.table import Table

    with _open_store(store, write=False) as fleet:
        machines = fleet.machines()
        where = fleet.where
    if not machines:
        _console().print(f"no machines in {where}")
        return
    table = Table(title=f"{len(machines)} machine(s) in {where}", title_justify="left")
    for column in ("serial", "type", "site", "measurements", "latest", "label", "verdicts"):
        table.add_column(column)
    for m in machines:
        table.add_row(
            m.serial,
            m.machine_type,
            m.site or "",
            str(m.measurements),
            (m.latest_utc or "")[:16].replace("T", " "),
            m.latest_label or "",
            _verdict_text(m.latest_verdicts),
        )
    _console().print(table)


def _verdict_text(verdicts: dict[str, str]) -> "Text":
    from rich.text import Text

    text = Text()
    for index, (axis, level) in enumerate(verdicts.items()):
        if index:
            text.append(" ")
        text.append(f"{axis} ")
        text.append(level, style=_LEVEL_STYLE.get(level, "bold"))
    return text


@store_app.command("show")
@_command
def store_show_command(
    serial: Annotated[str, typer.Argument(help="The machine's serial number.")],
    store: StoreOption = None,
) -> None:
    """A machine and its measurements, oldest first."""
    from rich.table import Table
    from rich.text import Text

    with _open_store(store, write=False) as fleet:
        machine, measurements = fleet.machine(serial)
    _console().print(
        Text.assemble(
            (machine.serial, "bold"),
            f" · type {machine.machine_type} (config {machine.config_hash or 'unknown'})"
            + (f" · {machine.site}" if machine.site else ""),
        )
    )
    table = Table()
    for column in ("id", "measured (UTC)", "label", "°C", "hours", "link", "verdicts"):
        table.add_column(column)
    for m in measurements:
        table.add_row(
            str(m.id),
            m.measured_utc[:19].replace("T", " "),
            m.label or "",
            "" if m.temperature_c is None else f"{m.temperature_c:g}",
            "" if m.operating_hours is None else f"{m.operating_hours:g}",
            m.link or "",
            _verdict_text(m.verdicts),
        )
    _console().print(table)


@store_app.command("trend")
@_command
def store_trend_command(
    serial: Annotated[str, typer.Argument(help="The machine's serial number.")],
    axis: Annotated[str, typer.Option(help="The axis, e.g. X.")],
    plot: Annotated[
        Path | None, typer.Option(help="Also draw the trend with its limits as a PNG.")
    ] = None,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    store: StoreOption = None,
) -> None:
    """Coulomb, viscous friction and the spread along the travel over the machine's life.

    Example: ncmeasure store trend M17 --axis X --plot m17-x.png
    """
    from rich.table import Table
    from rich.text import Text

    from ncmeasure.analysis.summary import format_number

    limits = _limits(warning, critical)
    with _open_store(store, write=False) as fleet:
        points = fleet.trend(serial, axis)
    unit = points[0].unit
    table = Table(title=f"{serial} axis {axis}", title_justify="left")
    for column in (
        "id", "measured (UTC)", "label", "hours", f"Coulomb [{unit}]",
        f"viscous [{unit} per m/min]", "spread [%]", "verdict",
    ):  # fmt: skip
        table.add_column(column)
    for p in points:
        table.add_row(
            str(p.measurement_id),
            p.measured_utc[:16].replace("T", " "),
            p.label or "",
            "" if p.operating_hours is None else f"{p.operating_hours:g}",
            format_number(p.coulomb),
            format_number(p.viscous_per_m_min),
            format_number(p.spread_percent),
            Text(p.verdict, style=_LEVEL_STYLE.get(p.verdict, "bold")),
        )
    _console().print(table)
    if plot is not None:
        from ncmeasure.report.plots import save_png
        from ncmeasure.store.report import trend_figure

        figure = trend_figure(axis, points, limits)
        save_png(figure, plot)
        _console().print(f"wrote {plot}")


@store_app.command("check")
@_command
def store_check_command(
    serial: Annotated[str, typer.Argument(help="The machine's serial number.")],
    warning: WarningOption = None,
    critical: CriticalOption = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Also write the check as JSON.")
    ] = None,
    store: StoreOption = None,
) -> Outcome:
    """The latest measurement against the machine's delivery baseline and its fleet.

    The baseline is the first measurement labelled delivery (else the first). The fleet
    is the latest measurement of every other machine of the type: per axis and
    characteristic its median and range, and the machine's robust z-score (an outlier
    beyond 3.5, with at least 3 other machines). What differs between baseline and
    latest (program, positions, velocities, temperature, link) is said first.

    Exit code 0: within the limits; 1: a warning limit crossed or an outlier of its type;
    3: a critical limit crossed; 2: bad input.
    """
    from rich.text import Text

    from ncmeasure.store.check import check_machine, write_check

    limits = _limits(warning, critical)
    with _open_store(store, write=False) as fleet:
        found = check_machine(fleet, serial, limits)
    if output is not None:
        write_check(found, output)
    latest = found.latest
    _console().print(
        Text.assemble(
            (serial, "bold"),
            f" · latest measurement {latest.id} ({latest.label or 'no label'}, "
            f"{latest.measured_utc[:16].replace('T', ' ')} UTC)",
        )
    )
    if found.baseline is not None:
        base = found.baseline
        _console().print(
            f"baseline: measurement {base.id} ({base.label or 'no label'}, "
            f"{base.measured_utc[:16].replace('T', ' ')} UTC)"
        )
    if found.comparability is not None:
        for difference in found.comparability.differences:
            _warn(difference)
    for finding in found.findings:
        _console().print(Text(finding))
    line = Text("status: ")
    line.append(found.status, style=_STATUS_STYLE[found.status])
    _console().print(line)
    return found.status


_STATUS_STYLE = {"ok": "bold green", "warning": "bold yellow", "critical": "bold red"}


@store_app.command("report")
@_command
def store_report_command(
    output: Annotated[Path, typer.Option("--output", "-o", help="The HTML file to write.")],
    trends: Annotated[
        int,
        typer.Option(min=0, max=200, help="Trend plots of the axes that moved most."),
    ] = 12,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    store: StoreOption = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> Outcome:
    """The fleet at a glance as one HTML file: machines × axes, outliers, trends.

    Each cell is an axis of a machine's latest measurement: its verdict and the change
    since the machine's baseline, coloured by the worst of the verdict (check, fault),
    the change against the limits, and an outlier of the machine's type. Then the
    outliers, then the trends of the axes that moved most. The file opens offline (no
    script, images inside).

    Exit code 0: every axis ok; 1: a warning (verdict check, a change beyond the warning
    limit, an outlier); 3: critical (verdict fault, a change beyond the critical limit);
    2: bad input.

    Example: ncmeasure store report -o fleet.html
    """
    from ncmeasure.analysis.compare import worst_status
    from ncmeasure.store.overview import fleet_overview
    from ncmeasure.store.report import write_fleet_report

    limits = _limits(warning, critical)
    bar, update = _progress_bar(quiet)
    if bar is not None:
        bar.start()
    try:
        with _open_store(store, write=False) as fleet:
            if update is not None:
                update("reading the fleet", None)
            overview = fleet_overview(fleet, limits)
            written = write_fleet_report(
                fleet,
                overview,
                output,
                trends=trends,
                progress=None if update is None else lambda d, n: update("trend plots", d / n),
            )
    finally:
        if bar is not None:
            bar.stop()
    counts = ", ".join(f"{overview.count(s)} {s}" for s in ("ok", "warning", "critical"))
    _console().print(
        f"{len(overview.machines)} machine(s): {counts}; {len(overview.outliers)} outlier(s)"
    )
    _console().print(f"wrote {written}")
    return worst_status(m.status for m in overview.machines)


@store_app.command("export")
@_command
def store_export_command(
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="JSON-lines file (default: stdout).")
    ] = None,
    store: StoreOption = None,
) -> None:
    """Write the whole store as JSON lines: a backup, or to move it (SQLite → PostgreSQL).

    Example: ncmeasure store export -o fleet.jsonl; ncmeasure store import fleet.jsonl
    --store postgresql://ncm@db/fleet
    """
    from ncmeasure.files import replace_text
    from ncmeasure.store.transfer import export_lines

    with _open_store(store, write=False) as fleet:
        if output is None:
            for line in export_lines(fleet):
                sys.stdout.write(line + "\n")
            return
        with replace_text(output) as file:
            count = 0
            for line in export_lines(fleet):
                file.write(line + "\n")
                count += 1
    _console(stderr=True).print(f"wrote {count - 1} measurement(s) to {output}")


@store_app.command("import")
@_command
def store_import_command(
    source: Annotated[Path, typer.Argument(help="JSON-lines file of `store export`.")],
    store: StoreOption = None,
) -> None:
    """Add every measurement of an export (those already stored are skipped)."""
    from ncmeasure.store.transfer import import_lines

    try:
        stream = source.open("rb")
    except OSError as exc:
        raise ConfigError(f"{source}: cannot be read ({exc.strerror or exc})") from exc
    with stream, _open_store(store, write=True) as fleet:
        added, existing = import_lines(fleet, stream, str(source))
        where = fleet.where
    _console().print(f"added {added} measurement(s) to {where}; {existing} were already stored")


@app.command("serve")
@_command
def serve_command(
    store: StoreOption = None,
    host: Annotated[
        str,
        typer.Option(help="Address to listen on; anything but loopback needs a token."),
    ] = "127.0.0.1",
    port: Annotated[
        int, typer.Option(min=0, max=65535, help="TCP port (0: a free one, printed).")
    ] = 8000,
    token_file: Annotated[
        Path | None,
        typer.Option(
            help="A file holding the token clients must send (at least 16 characters). "
            "Or set NCMEASURE_TOKEN. Needed for any address but loopback.",
        ),
    ] = None,
) -> None:
    """The fleet store as a web dashboard and a JSON REST API, until Ctrl-C.

    The dashboard: the fleet grid, a page per machine and per axis with the trends.
    The API lives under /api/v1 (machines, measurements, results, checks; POST adds a
    measurement), described at /openapi.json and /docs. On a loopback address (the
    default) it is open to this computer only; any other address needs a token, which
    clients send as "Authorization: Bearer TOKEN" (a browser opens URL?token=TOKEN once).
    The token is read from a file or the environment, never from the command line,
    where other users could see it.

    Example: ncmeasure serve --store postgresql://ncm@db/fleet --host 0.0.0.0
    --token-file /etc/ncmeasure/token
    """
    try:
        from ncmeasure.web import ServerInfo, serve
    except ImportError as exc:
        from ncmeasure.errors import DependencyError

        raise DependencyError(
            f"ncmeasure serve needs the package {exc.name!r}, which is missing "
            "(pip install 'ncmeasure[serve]')"
        ) from exc
    from ncmeasure.store import store_url

    token = _token(token_file)
    url = store_url(store)

    def ready(info: ServerInfo) -> None:
        access = "token required" if info.token else "this computer only"
        _console().print(f"serving {url} at {info.url} ({access}); Ctrl-C stops")

    stop = threading.Event()
    previous = _stop_on_signals(stop)
    try:
        serve(
            url, host=host, port=port, token=token, on_ready=ready, stop=stop, log_level="warning"
        )
    finally:
        _restore_signals(previous)
    _console().print("stopped")


TOKEN_ENV = "NCMEASURE_TOKEN"


def _token(path: Path | None) -> str | None:
    """The server's token: from ``--token-file``, else ``$NCMEASURE_TOKEN``, else None."""
    from ncmeasure.inputs import read_text

    if path is not None:
        return read_text(path, "a token file", 4096).strip() or _no_token(str(path))
    value = os.environ.get(TOKEN_ENV)
    if value is None:
        return None
    return value.strip() or _no_token(f"${TOKEN_ENV}")


def _no_token(where: str) -> str:
    raise ConfigError(f"{where}: empty, expected the token (at least 16 characters)")


publish_app = typer.Typer(
    help="The fleet store on the shop floor: MQTT messages and an OPC UA server "
    "(docs/shop-floor.md).",
    no_args_is_help=True,
)
app.add_typer(publish_app, name="publish")


def _mqtt_target(url: str | None) -> Any:
    """The broker of ``--publish``/``publish mqtt`` (None: none), checked before anything
    is stored or read; paho-mqtt's absence is found here too."""
    if url is None:
        return None
    from ncmeasure.publish.mqtt import MqttTarget, paho

    paho()
    return MqttTarget.from_url(url)


def _publish_stored(
    target: Any, store: str | None, serials: list[str] | None, limits: Any = None
) -> Any:
    from ncmeasure.publish import axis_summaries
    from ncmeasure.publish.mqtt import publish_summaries
    from ncmeasure.store.overview import fleet_overview

    with _open_store(store, write=False) as fleet:
        summaries = axis_summaries(fleet_overview(fleet, limits), serials)
    return publish_summaries(target, summaries)


def _publish_added(target: Any, store: str | None, added: Any, quiet: bool) -> None:
    """Publish the machine just stored; a failure says that the measurement stays stored."""
    if target is None:
        return
    from ncmeasure.errors import PublishError

    try:
        published = _publish_stored(target, store, [added.serial])
    except PublishError as exc:
        raise PublishError(
            f"measurement {added.measurement_id} of {added.serial} is stored, but was not "
            f"published: {exc.message} (`ncmeasure publish mqtt` sends it later)"
        ) from exc
    if not quiet:
        _console().print(f"published {len(published.topics)} axis summaries to {published.target}")


@publish_app.command("mqtt")
@_command
def publish_mqtt_command(
    url: Annotated[
        str,
        typer.Argument(
            help="The broker: mqtt://[USER@]HOST[:PORT][/PREFIX][?site=S&client_id=C&"
            "topic=T&protocol=5] or mqtts://...[?ca=FILE]. The password comes from "
            "$NCMEASURE_MQTT_PASSWORD, never from the command line.",
            show_default=False,
        ),
    ],
    serials: Annotated[
        list[str] | None,
        typer.Option(
            "--serial",
            metavar="SERIAL",
            help="Only this machine (repeat for several; default: all).",
        ),
    ] = None,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    store: StoreOption = None,
) -> None:
    """Publish the latest fingerprint of every machine and axis of the store (retained, QoS 1).

    One JSON message per axis to PREFIX/SITE/SERIAL/AXIS/fingerprint (default prefix:
    ncmeasure): verdict, Coulomb and viscous friction, spread, their change since the
    baseline, DeviceHealth; docs/shop-floor.md describes every field. The status and
    health are those of `store report` with the same --warning/--critical.

    A broker that cannot be reached, refuses the user or a message: one line, exit 4.

    Example: NCMEASURE_MQTT_PASSWORD=... ncmeasure publish mqtt
    mqtts://line3@broker.plant?site=hall-2 --serial M17
    """
    limits = _limits(warning, critical)
    published = _publish_stored(_mqtt_target(url), store, serials, limits)
    _console().print(f"published {len(published.topics)} axis summaries to {published.target}")


@publish_app.command("opcua")
@_command
def publish_opcua_command(
    store: StoreOption = None,
    endpoint: Annotated[
        str,
        typer.Option(help="Where to listen; anything but loopback needs --user and a certificate."),
    ] = "opc.tcp://127.0.0.1:4840",
    refresh_s: Annotated[
        float, typer.Option("--refresh-s", help="Read the store again every so many seconds.")
    ] = 10.0,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    user: Annotated[
        str | None,
        typer.Option(
            help="The user clients log in as; the password from $NCMEASURE_OPCUA_PASSWORD."
        ),
    ] = None,
    certificate: Annotated[
        Path | None,
        typer.Option(
            help="The server's certificate (RSA, PEM or DER): the only endpoint is then "
            "Basic256Sha256, sign and encrypt."
        ),
    ] = None,
    private_key: Annotated[
        Path | None, typer.Option(help="The certificate's private key (PEM).")
    ] = None,
    trusted_clients: Annotated[
        Path | None,
        typer.Option(
            metavar="FOLDER",
            help="Only clients whose certificate, or the CA that issued it, is in this folder "
            "(*.pem, *.der, *.crt, *.cer) may connect; without it any client certificate "
            "opens the encrypted channel and the password decides.",
        ),
    ] = None,
) -> None:
    """The fleet store as an OPC UA server, until Ctrl-C: Machines → Machine → Axes → Axis.

    Each axis has its latest characteristics with engineering units and the measurement's
    time, and a DeviceHealth (OPC UA DI); docs/shop-floor.md draws the address space.
    The store is read again every --refresh-s: a new measurement reaches subscribers as
    a data change.

    Access: anonymous and read-only on loopback (the default endpoint). Any other address
    needs --user (password from $NCMEASURE_OPCUA_PASSWORD) and --certificate/--private-key;
    --trusted-clients limits who may connect. Nobody can write.

    Example: ncmeasure publish opcua --store postgresql://ncm@db/fleet

    Example: NCMEASURE_OPCUA_PASSWORD=... ncmeasure publish opcua --endpoint
    opc.tcp://0.0.0.0:4840 --user line3 --certificate server.pem --private-key server-key.pem
    --trusted-clients clients/
    """
    from ncmeasure.publish.opcua import PASSWORD_ENV, OpcUaSettings, serve_opcua
    from ncmeasure.store import store_url

    settings = OpcUaSettings(
        endpoint=endpoint,
        refresh_s=refresh_s,
        username=user,
        password=os.environ.get(PASSWORD_ENV),
        certificate=certificate,
        private_key=private_key,
        trusted_clients=trusted_clients,
    ).checked()
    limits = _limits(warning, critical)
    url = store_url(store)
    stop = threading.Event()
    previous = _stop_on_signals(stop)
    try:
        serve_opcua(
            url,
            settings,
            limits=limits,
            on_ready=lambda at: _console().print(f"serving {url} at {at}; Ctrl-C stops"),
            stop=stop,
        )
    finally:
        _restore_signals(previous)
    _console().print("stopped")


@app.command("simulate")
@_command
def simulate_command(
    machine: Annotated[Path, typer.Argument(help="Machine file.")],
    variation: Annotated[
        list[str] | None,
        typer.Option(
            metavar="KEY=VALUE",
            help="An assembly variation, e.g. loose_bearing_shift_um=20 or "
            "'nut_shift_um=20, bearing_preload_change=-0.3'; repeat for side by side.",
        ),
    ] = None,
    axis: Annotated[str | None, typer.Option(help="Axis to study (default: the first).")] = None,
    plot: Annotated[Path | None, typer.Option(help="Write contour plots (PNG).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the study as JSON.")] = False,
) -> None:
    """The axis friction model alone: what does each assembly variation do along the travel?

    Example: ncmeasure simulate machine.toml --variation loose_bearing_shift_um=20
    --variation nut_shift_um=20 --plot variations.png
    """
    from rich.table import Table

    from ncmeasure.config import load_machine
    from ncmeasure.sim.explore import plot_study, study

    config = load_machine(machine)
    names = [a.name for a in config.axes]
    if axis is not None and axis not in names:
        raise ConfigError(f"--axis {axis}: the machine has axes {', '.join(names)}")
    chosen = config.axis(axis or names[0])
    result = study(chosen, config.measurement_for(chosen), variation or [])
    if plot is not None:
        plot_study(result, plot)
    if as_json:
        sys.stdout.write(result.model_dump_json(indent=2) + "\n")
        return None
    table = Table(box=None, header_style="bold")
    table.add_column("variation", overflow="fold")
    table.add_column("mean Nm", justify="right")
    table.add_column("spread", justify="right")
    for position in result.positions_mm[:: max(1, len(result.positions_mm) // 5)]:
        table.add_column(f"{position:g} mm", justify="right")
    step = max(1, len(result.positions_mm) // 5)
    for scenario in result.scenarios:
        table.add_row(
            scenario.name,
            f"{scenario.mean_nm:.3f}",
            f"{scenario.spread_percent:.1f} %",
            *(f"{c:+.1f} %" for c in scenario.change_percent[::step]),
        )
    _console().print(
        f"axis {result.axis}: friction change against the nominal axis, averaged over velocities"
    )
    _console().print(table)
    if plot is not None:
        _console().print(f"wrote {plot}")


def _variation(texts: list[str] | None) -> Any:
    """One variation from repeated --variation options (their keys merged)."""
    from ncmeasure.sim.axis import parse_variation

    return parse_variation(" ".join(texts or []))


@app.command("demo")
@_command
def demo_command(
    outdir: Annotated[
        Path, typer.Argument(help="Folder to write everything into (new or empty).")
    ] = Path("ncmeasure-demo"),
    link: Annotated[
        str,
        typer.Option(
            help="Drive link to record through: canopen (simulated CiA 402 drives on a "
            "python-can virtual bus) or modbus (a simulated drive server on 127.0.0.1)."
        ),
    ] = "canopen",
    variation: Annotated[
        list[str] | None,
        typer.Option(
            metavar="KEY=VALUE",
            help="Assemble every axis of the virtual machine with this fault, e.g. "
            "loose_bearing_shift_um=500 or nut_preload_change=1.5; repeat to combine. "
            "The machine is then measured twice: assembled correctly, and with the fault. "
            "Keys: see `ncmeasure simulate --help` and docs/axis-model.md.",
        ),
    ] = None,
    controller: Annotated[
        str, typer.Option(help="Dialect of the programs the virtual machine runs.")
    ] = "linuxcnc",
    reference: Annotated[
        Path | None,
        typer.Option(
            help="An earlier demo folder without variation: compare with it instead of "
            "measuring the correctly assembled machine again."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the simulated noise.")] = 0,
    force: Annotated[bool, typer.Option(help="Replace an earlier demo in OUTDIR.")] = False,
    quiet: Annotated[
        bool, typer.Option("--quiet", "-q", help="Print only the report path.")
    ] = False,
) -> None:
    """The whole pipeline on a virtual machine: program, drives, recording, analysis, report.

    Writes a machine file, generates its NC programs, runs them on a virtual machine tool
    whose axes follow the programs (friction from a physical model of the feed axis),
    records the simulated drives through the real link, analyses the recording and writes
    an HTML report. Link and simulated drives run in lockstep on simulated time, as fast
    as the computer allows: the same seed gives the same recording on an idle and on a
    busy computer. Takes well under a minute.

    Examples: ncmeasure demo  ·  ncmeasure demo --variation loose_bearing_shift_um=500
    ·  ncmeasure demo demo-modbus --link modbus
    """
    from rich.text import Text

    from ncmeasure.demo import run_demo

    chosen = _variation(variation)
    bar, progress = _progress_bar(quiet, stages=True)

    started = time.monotonic()
    with bar or contextlib.nullcontext():
        result = run_demo(
            outdir,
            link=link,
            variation=chosen,
            controller=controller,
            reference=reference,
            seed=seed,
            force=force,
            progress=progress,
        )
        if progress is not None:
            progress("done", None)
    if quiet:
        _console().print(str(result.report))
        return None
    _console().print(
        f"virtual machine: axes {', '.join(result.runs[-1].results.axes)}, "
        f"{controller} programs, recorded through {result.link} in lockstep with the "
        "simulated drives"
    )
    for run in result.runs:
        acquisition = run.acquisition
        if acquisition is None:
            _console().print(f"{run.label}: reused from {run.directory}")
            continue
        _console().print(
            f"{run.label}: {run.machine_time_s:.0f} s of machine time in "
            f"{run.wall_time_s:.0f} s, {acquisition.rows} samples"
            + ("" if acquisition.gaps else ", no sample lost")
        )
        if acquisition.gaps:
            _warn(
                f"{run.label}: {acquisition.lost_samples} samples lost in {acquisition.gaps} "
                f"gap(s) ({100 * acquisition.lost_share:.2g} %): the recording is marked "
                "incomplete, the analysis measured the windows that stayed whole and counts "
                "the rest in its report"
            )
        compared = result.comparison if run is result.measured else None
        for name in run.results.axes:
            _print_verdict(run.results, name, compared, indent="  ")
            found = run.accuracy.get(name)
            if found is not None:
                _console().print(
                    f"    axis {name} against the virtual machine's own friction (mean over "
                    f"{found.points} points, all velocities): {found.measured_mean_nm:.3f} Nm "
                    f"measured, {found.simulated_mean_nm:.3f} Nm simulated (bias "
                    f"{found.median_error_percent:+.1f} %, worst point "
                    f"{found.max_error_percent:.1f} %)"
                )
        _print_skipped(run.results, indent="  ")
    took = time.monotonic() - started
    _console().print(
        Text.assemble(f"finished in {took:.0f} s. Open ", (str(result.report), "bold"))
    )
    _console().print(
        f"files: {result.directory}/ (machine.toml, programs/, recording/, results.json"
        + (", reference/" if (result.directory / "reference").is_dir() else "")
        + (", comparison.json" if result.comparison is not None else "")
        + ")"
    )


@app.command("compensation")
@_command
def compensation_command(
    results_file: Annotated[
        Path, typer.Argument(help="results.json of the measurement (`ncmeasure analyze`).")
    ],
    controller: Annotated[
        str,
        typer.Option(
            help="twincat: TwinCAT CNC friction table (frict_comp.*); linuxcnc: HAL snippet "
            "(ddt -> lincurve -> sum2); cia402: torque offset 0x60B2 of vertical axes as SDO "
            "writes."
        ),
    ],
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="File to write (default: print it).")
    ] = None,
    only: Annotated[
        list[str] | None,
        typer.Option(
            "--axis",
            metavar="AXIS",
            help="Compensate only this axis (repeat for several; default: every analysed axis, "
            "cia402: every vertical one).",
        ),
    ] = None,
    points: Annotated[
        int | None,
        typer.Option(
            help="Table points per axis: twincat 3–1000 (default 20, the 0 entry included; "
            "more than 20 needs frict_comp.max_points), linuxcnc 5–16 (default 15)."
        ),
    ] = None,
    machine: Annotated[
        Path | None,
        typer.Option(help="Machine file; cia402 takes node_id and rated_current_a from it."),
    ] = None,
    units_per_a: Annotated[
        float,
        typer.Option(
            help="twincat: drive current units of table[i].out per ampere (1000: mA); check "
            "the unit of dig_drv.act_torque for your drive."
        ),
    ] = 1000.0,
) -> None:
    """Friction compensation for the controller, from a measurement, with sources and limits.

    Per axis and direction the friction the analysis found (its model, the measured points
    in the Stribeck region), averaged over the positions, at speeds between the slowest
    and the fastest measured (denser at low speed), as motor current. The header of the
    file names the manual pages behind every parameter and what the file leaves out;
    docs/shop-floor.md explains how to apply each. Review before loading it; a cia402 file
    is then written to the drives by `ncmeasure apply-compensation FILE --machine M --yes`.

    An axis the analysis could not fit in both directions, or not vertical for cia402, is
    refused in one line (exit 2).

    Example: ncmeasure compensation run1.results.json --controller twincat --axis X -o X.lis
    """
    from ncmeasure.analysis.analyze import load_results
    from ncmeasure.compensation import render_compensation
    from ncmeasure.config import load_machine
    from ncmeasure.files import write_whole

    results = load_results(results_file)
    text = render_compensation(
        results,
        controller,
        axes=only,
        points=points,
        machine=load_machine(machine) if machine is not None else None,
        units_per_a=units_per_a,
        source=results_file.name,
    )
    if output is None:
        sys.stdout.write(text)
        return
    write_whole(output, text, newline="\n")
    _console().print(f"wrote {output}")


@app.command("apply-compensation")
@_command
def apply_compensation_command(
    file: Annotated[
        Path,
        typer.Argument(
            help="The torque offsets to write: the file of `ncmeasure compensation "
            "--controller cia402`, reviewed."
        ),
    ],
    machine: Annotated[
        Path,
        typer.Option(
            help="Machine file: its [link] (type canopen) and the axes' node ids, as for "
            "`ncmeasure record`.",
            show_default=False,
        ),
    ],
    yes: Annotated[
        bool,
        typer.Option("--yes", help="Write. Without it nothing is sent: the writes are listed."),
    ] = False,
    interface: Annotated[
        str | None,
        typer.Option(
            help="python-can interface (socketcan, pcan, ...), over the machine file's.",
            rich_help_panel="CANopen",
        ),
    ] = None,
    channel: Annotated[
        str | None, typer.Option(help="python-can channel.", rich_help_panel="CANopen")
    ] = None,
    bitrate: Annotated[
        int | None, typer.Option(help="Bit rate in bit/s.", rich_help_panel="CANopen")
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Any other link setting, KEY=VALUE (e.g. sdo_timeout_s=2).",
            metavar="KEY=VALUE",
        ),
    ] = None,
) -> None:
    """Write the torque offset 0x60B2 of vertical axes to their CiA 402 drives over SDO.

    Reads the reviewed file of `ncmeasure compensation --controller cia402`, checks it
    against the machine file (CANopen link, each axis with the node id the file names)
    and lists what it would write. With --yes it writes each axis: the value before is
    read, the new one written, and read back; another value read back is an error. Only
    0x60B2:00 is ever written; no NMT, no SYNC, no "store parameters": a drive keeps the
    offset until it is switched off unless you store it (its manual says how).

    Exit code 0: listed, or written and read back; 2: bad input; 4: the bus or a drive
    failed (the line says what was written before).

    Example: ncmeasure apply-compensation z-offset.toml --machine machine.toml --yes
    """
    from ncmeasure.compensation.apply import (
        apply_offsets,
        link_for_offsets,
        read_offset_file,
    )
    from ncmeasure.config import load_machine

    writes = read_offset_file(file)
    overrides: dict[str, Any] = {
        key: value
        for key, value in {"interface": interface, "channel": channel, "bitrate": bitrate}.items()
        if value is not None
    }
    overrides.update(_settings(set_ or [], example="--set sdo_timeout_s=2"))
    settings = link_for_offsets(writes, load_machine(machine), overrides)
    bus = (
        f"interface {settings.interface or '(python-can config)'}, channel "
        f"{settings.channel or '(default)'}, {settings.bitrate} bit/s"
    )
    console = _console()
    if not yes:
        console.print(f"{len(writes)} torque offset(s) of {file} over CANopen ({bus}):")
        for write in writes:
            console.print(
                f"  axis {write.axis}: node {write.node_id}, 0x60B2:00 = {write.value} "
                f"(‰ of the rated torque, {write.value / 10:g} %)"
            )
        console.print(
            "nothing was sent: review the file, then add --yes to write (each value is read "
            "before and read back after)"
        )
        return

    def written(done: Any) -> None:
        w = done.write
        console.print(
            f"axis {w.axis}: node {w.node_id}, 0x60B2:00 was {done.before}, wrote {w.value}, "
            f"read back {done.after}"
        )

    done = apply_offsets(writes, settings, on_written=written)
    console.print(
        f"wrote {len(done)} torque offset(s) over CANopen ({bus}); a drive keeps them until "
        "it is switched off unless it stores them"
    )


@schema_app.command("results")
@_command
def schema_results() -> None:
    """JSON Schema of results.json, what `ncmeasure analyze` writes."""
    from ncmeasure.analysis.results import Results

    sys.stdout.write(json.dumps(Results.model_json_schema(), indent=2) + "\n")


def _reflow(text: str) -> str:
    """Join the lines of each paragraph: the console wraps them to its width."""
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(" ".join(line.strip() for line in p.splitlines()) for p in paragraphs)


def _polish_help(info: typer.models.CommandInfo, done: set[int]) -> None:
    """Help texts as paragraphs, and metavars.

    Arguments show their name in capitals, flags no type; options shared by
    several commands are polished once.
    """
    doc = info.help or (info.callback.__doc__ if info.callback else None)
    if doc:
        info.help = _reflow(doc)
    if info.callback is None:
        return
    for param in inspect.signature(info.callback).parameters.values():
        hint, *extras = get_args(param.annotation) or (None,)
        for meta in extras:
            if not isinstance(meta, typer.models.ParameterInfo) or id(meta) in done:
                continue
            done.add(id(meta))
            if isinstance(meta, typer.models.ArgumentInfo) and meta.metavar is None:
                meta.metavar = param.name.upper()
            elif hint is bool and meta.metavar is None:
                meta.metavar = ""


_polished: set[int] = set()
for _info in [
    *app.registered_commands,
    *schema_app.registered_commands,
    *store_app.registered_commands,
    *publish_app.registered_commands,
]:
    _polish_help(_info, _polished)
