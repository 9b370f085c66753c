"""The typer apps, the exit codes, the console and the one error wrapper of every command.

The CLI owns the console (rich) and is the only place that turns errors into
exit codes: 0 success, 1 a check found problems (or a warning limit crossed),
2 bad input (machine file, options, paths), 3 a critical limit crossed, 4 a
drive link failed, 70 a bug (an error nobody foresaw), 130 stopped by
Ctrl-C/SIGTERM, 141 the reader of the output went away (``| head``). ``--debug``
shows tracebacks; nobody else ever sees one.
"""

import functools
import inspect
import logging
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Any, Literal

import typer

from ncmeasure._version import __version__
from ncmeasure.errors import LinkError, NcMeasureError, ProgramCheckError

if TYPE_CHECKING:
    from rich.console import Console

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
"""A check found problems (check), a warning limit was crossed (compare)."""
EXIT_BAD_INPUT = 2
"""Bad input: a machine file, an option, a path, a file that cannot be read or written."""
EXIT_CRITICAL = 3
"""A critical limit was crossed (compare, store check, store report)."""
EXIT_LINK = 4
"""A drive link failed (bus, network, drive, simulated drive)."""
EXIT_SOFTWARE = 70
"""An error nobody foresaw: a bug of ncmeasure or an error of a library it did not wrap
(EX_SOFTWARE of sysexits.h). Never 1: a script gating on ``compare`` must not read a
crash as a warning."""
EXIT_INTERRUPTED = 130
"""Stopped by Ctrl-C/SIGTERM (what was recorded is kept): 128 + SIGINT, as shells say it."""
EXIT_CLOSED_OUTPUT = 141
"""The reader of the output went away (``ncmeasure store list | head``): 128 + SIGPIPE,
what a shell tool ends with there; nothing is printed."""

BUG_REPORT = (
    "this is a bug: please report it to the ncmeasure maintainers with the output of "
    "the same command with --debug"
)
"""What the one line of an unexpected error asks for (the project names no issue tracker)."""

Outcome = Literal["ok", "problems", "warning", "critical", "interrupted", "link_lost"]
"""What a command reports besides an error; :func:`handle_errors` turns it into the exit code."""
_OUTCOME_EXIT: dict[str, int] = {
    "ok": EXIT_OK,
    "problems": EXIT_CHECK_FAILED,
    "warning": EXIT_CHECK_FAILED,
    "critical": EXIT_CRITICAL,
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
        "New here? `ncmeasure demo` runs the whole pipeline on a virtual machine in about "
        "15 s on two cores.\n\n"
        "Exit codes: 0 done; 1 a check found problems or a warning limit was crossed; "
        "2 bad input; 3 a critical limit crossed; 4 a drive link failed; 70 a bug in "
        "ncmeasure (please report it); 130 stopped by Ctrl-C/SIGTERM; 141 the output's "
        "reader went away (| head). --debug (anywhere on the line) shows tracebacks."
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
publish_app = typer.Typer(
    help="The fleet store on the shop floor: MQTT messages and an OPC UA server "
    "(docs/shop-floor.md).",
    no_args_is_help=True,
)
app.add_typer(publish_app, name="publish")

NOT_A_TERMINAL_WIDTH = 1_000_000
"""The console's width when its output is not a terminal (a file, a pipe): so wide that
a table is never cut. A terminal keeps its own width."""


@functools.cache
def console(stderr: bool = False) -> "Console":
    """The console on stdout (or stderr), made at its first use: ``--help`` needs no rich.

    No markup: messages carry user text (machine names, paths, controller names) that
    may hold square brackets; styled parts are rich Text objects. Output that is not
    a terminal (``ncmeasure plan m.toml > plan.txt``) is never cut to a width: rich
    would fit tables to 80 columns and shorten their cells to ``ti…``.
    """
    from rich.console import Console

    made = Console(stderr=stderr, highlight=False, soft_wrap=True, markup=False)
    if not made.is_terminal:
        made.width = NOT_A_TERMINAL_WIDTH
    return made


_state = {"debug": False}


def _exit_code(error: BaseException) -> int:
    """The exit code of an error (see the EXIT_ constants)."""
    if isinstance(error, ProgramCheckError):
        return EXIT_CHECK_FAILED
    if isinstance(error, LinkError):
        return EXIT_LINK
    if isinstance(error, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    return EXIT_BAD_INPUT


def warn(message: str) -> None:
    """``warning: message`` on stderr (user text verbatim)."""
    from rich.text import Text

    console(stderr=True).print(Text.assemble(("warning:", "yellow"), f" {message}"), soft_wrap=True)


def note(message: str) -> None:
    """``note: message`` on stderr (user text verbatim)."""
    from rich.text import Text

    console(stderr=True).print(Text.assemble(("note:", "bold"), f" {message}"), soft_wrap=True)


MAX_PRINTED_PROBLEMS = 50
"""Problems printed under an error; the rest are counted (the first ones say what is wrong)."""


def need_matplotlib(option: str) -> None:
    """Check, before any work, that the PNG ``option`` asks for can be drawn.

    Raises:
        DependencyError: matplotlib is missing; the message names the extra.
    """
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:
        from ncmeasure.errors import DependencyError

        raise DependencyError(
            f"{option} draws a PNG with matplotlib, which is missing "
            "(pip install 'ncmeasure[plot]')"
        ) from exc


def report_error(error: NcMeasureError) -> None:
    """``error: message`` and one indented line per problem, on stderr (user text verbatim).

    At most :data:`MAX_PRINTED_PROBLEMS` problems are printed, then how many more there are.
    """
    from rich.text import Text

    console(stderr=True).print(
        Text.assemble(("error:", "bold red"), f" {error.message}"), soft_wrap=True
    )
    shown = error.problems[:MAX_PRINTED_PROBLEMS]
    more = len(error.problems) - len(shown)
    lines = [f"  {line}" for line in shown] + ([f"  … and {more} more"] if more else [])
    if lines:
        console(stderr=True).print(Text("\n".join(lines)), soft_wrap=True)


def _report_bug(error: Exception) -> None:
    """One line for an error nobody foresaw: what happened, and the bug report to file.

    The error's own text may run over several lines: it is joined into one.
    """
    from rich.text import Text

    text = " ".join(str(error).split())
    what = f"{type(error).__name__}: {text}" if text else type(error).__name__
    console(stderr=True).print(
        Text.assemble(("error:", "bold red"), f" unexpected {what}; {BUG_REPORT}"),
        soft_wrap=True,
    )


def _print_traceback(error: BaseException) -> None:
    from rich.text import Text

    trace = Text("".join(traceback.format_exception(error)))
    console(stderr=True).print(trace, soft_wrap=True)


_DEBUG_OPTION = Annotated[
    bool,
    typer.Option(
        "--debug", help="Show tracebacks and debug logs (also before the command).", hidden=True
    ),
]

_TYPER_EXITS = (typer.Exit, typer.Abort, typer.BadParameter)
"""How typer ends a command itself: these pass the wrapper untouched."""


def handle_errors(func: Callable[..., Outcome | None]) -> Callable[..., None]:
    """Run a command's body: the one place where errors and outcomes become exit codes.

    A command body raises :class:`~ncmeasure.errors.NcMeasureError` for anything
    that goes wrong and may return an :data:`Outcome`; no command decides an exit
    code itself. Any other exception is a bug: one line asks for a report, exit
    code :data:`EXIT_SOFTWARE`. ``--debug`` is accepted after the command name too,
    and shows the traceback of an error without changing its exit code.
    """

    @functools.wraps(func)
    def run(*args: Any, debug: bool = False, **kwargs: Any) -> None:
        if debug:
            set_debug(True)
        previous = _interrupt_on_sigterm()
        try:
            outcome = func(*args, **kwargs)
            sys.stdout.flush()  # a reader that went away is found here, not at exit
        except BrokenPipeError:
            _drop_output()
            raise typer.Exit(EXIT_CLOSED_OUTPUT) from None
        except NcMeasureError as exc:
            report_error(exc)
            if _state["debug"]:
                _print_traceback(exc)
            raise typer.Exit(_exit_code(exc)) from None
        except KeyboardInterrupt:
            console(stderr=True).print("interrupted")
            raise typer.Exit(EXIT_INTERRUPTED) from None
        except _TYPER_EXITS:
            raise
        except Exception as exc:  # a bug, or a library's error that nobody wrapped
            if _state["debug"]:
                _print_traceback(exc)
            _report_bug(exc)
            raise typer.Exit(EXIT_SOFTWARE) from None
        finally:
            restore_signals(previous)
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


def _drop_output() -> None:
    """Point stdout at nothing: the reader is gone, and Python's flush at exit must not fail."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def _version(value: bool) -> None:
    if value:
        console().print(f"ncmeasure {__version__}")
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
    set_debug(debug)


def set_debug(debug: bool) -> None:
    """Tracebacks and debug logs on (``--debug``) or off; the bus libraries' logs quiet."""
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


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _interrupt_on_sigterm() -> dict[int, Any]:
    """SIGTERM (a timeout, CI, systemd) stops a command like Ctrl-C: its cleanup runs
    (no staging folder is left) and it exits with code 130. Returns the handler to restore."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {signal.SIGTERM: signal.signal(signal.SIGTERM, _interrupt)}


def stop_on_signals(stop: threading.Event) -> dict[int, Any]:
    """Ctrl-C and SIGTERM set ``stop``; returns the handlers to restore.

    Signal handlers belong to the main thread; elsewhere (an embedding
    program) the caller's own handling stays in place.
    """
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)
    }


def restore_signals(previous: dict[int, Any]) -> None:
    """Put back the signal handlers :func:`stop_on_signals` replaced."""
    for sig, handler in previous.items():
        signal.signal(sig, handler)


class _ShownOnFirstProgress:
    """A progress display as a context, shown from the first progress on: an error before
    any work (bad input) leaves the console as it was, without an empty line."""

    def __init__(self, bar: Any) -> None:
        self._bar = bar
        self._shown = False

    def show(self) -> None:
        if not self._shown:
            self._bar.start()
            self._shown = True

    def __enter__(self) -> "_ShownOnFirstProgress":
        return self

    def __exit__(self, *_exc: object) -> None:
        if self._shown:
            self._bar.stop()


def progress_bar(quiet: bool, *, stages: bool = False) -> tuple[Any, Any]:
    """A rich progress bar (a context) and a ``progress(stage, fraction)`` callback feeding it.

    ``fraction`` None starts a stage without a figure. With ``stages``, every
    finished stage stays on the console as a line with its duration. The bar shows
    from the first call of the callback on.
    """
    if quiet:
        return None, None
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.text import Text

    bar = Progress(
        TextColumn("{task.description}", markup=False),
        BarColumn(),
        TimeElapsedColumn(),
        console=console(stderr=True),
        transient=True,
    )
    task = bar.add_task("starting", total=1.0)
    current: dict[str, Any] = {"stage": None, "since": time.monotonic()}
    display = _ShownOnFirstProgress(bar)

    def update(stage: str, fraction: float | None) -> None:
        display.show()
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

    return display, update
