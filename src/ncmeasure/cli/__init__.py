"""The ``ncmeasure`` command: a thin translation of arguments into library calls.

One module per group of commands, each declaring its options and calling the library:

- :mod:`~ncmeasure.cli.program`       init, schema, controllers, plan, generate, check
- :mod:`~ncmeasure.cli.record`        record, simulate-drive
- :mod:`~ncmeasure.cli.measure`       measure (wait for the start, record, analyse, store)
- :mod:`~ncmeasure.cli.traces`        import, export
- :mod:`~ncmeasure.cli.analysis`      analyze, compare, simulate
- :mod:`~ncmeasure.cli.store`         store add, list, show, trend, check, report, export, import
- :mod:`~ncmeasure.cli.serve`         serve
- :mod:`~ncmeasure.cli.publish`       publish mqtt, publish opcua
- :mod:`~ncmeasure.cli.demo`          demo, dryrun
- :mod:`~ncmeasure.cli.compensation`  compensation, apply-compensation

:mod:`~ncmeasure.cli._app` holds the typer apps, the exit codes, the console and the
one error wrapper every command runs in; :mod:`~ncmeasure.cli._options` the options
several commands share and the reading of their values; :mod:`~ncmeasure.cli._fleet`
the store and the broker as analyze, store and publish open them;
:mod:`~ncmeasure.cli._verdicts` the verdict lines analyze, compare and demo print;
:mod:`~ncmeasure.cli._startup` the start-up tricks.
Registering the commands imports typer only: every command imports what it works with
when it runs, so that ``ncmeasure --help`` starts fast. ``ncmeasure COMMAND`` registers
the module of COMMAND only (:func:`main`); ``from ncmeasure.cli import app`` gives the
app with every command.
"""

import sys
from typing import TYPE_CHECKING, Any

from ncmeasure.cli._startup import (
    coerce_common_values_without_pydantic,
    load_python_can_without_mdf,
    polish_help,
)

if TYPE_CHECKING:
    from ncmeasure.cli._app import app

__all__ = ["app", "main"]

# `ncmeasure --help` lists the commands in the order of the README's command table,
# the pipeline's, whatever the order the modules register them in.
_ORDER = [
    "init", "controllers", "plan", "generate", "check", "dryrun", "record", "export", "import",
    "simulate-drive", "measure", "analyze", "compare", "serve", "simulate", "demo", "compensation",
    "apply-compensation",
]  # fmt: skip
_MODULES = {
    "init": "program", "controllers": "program", "plan": "program", "generate": "program",
    "check": "program", "schema": "program", "dryrun": "demo", "demo": "demo",
    "record": "record", "simulate-drive": "record", "export": "traces", "import": "traces",
    "measure": "measure", "analyze": "analysis", "compare": "analysis", "simulate": "analysis",
    "serve": "serve", "store": "store", "publish": "publish", "compensation": "compensation",
    "apply-compensation": "compensation",
}  # fmt: skip
"""The module (of this package) that registers each command and group of commands."""


def _position(info: Any) -> int:
    name = info.name or (info.callback.__name__ if info.callback else "")
    return _ORDER.index(name) if name in _ORDER else len(_ORDER)


def register(*modules: str) -> None:
    """Import the command modules ``modules`` (all without any), registering their commands
    with the apps of :mod:`~ncmeasure.cli._app`, in the command table's order and their
    help polished (see :mod:`~ncmeasure.cli._startup`). Importing a module twice is free."""
    import importlib

    from ncmeasure.cli._app import app, publish_app, schema_app, store_app

    for module in modules or sorted(set(_MODULES.values())):
        importlib.import_module(f"ncmeasure.cli.{module}")
    app.registered_commands.sort(key=_position)
    polish_help([app, schema_app, store_app, publish_app])
    coerce_common_values_without_pydantic()


def __getattr__(name: str) -> Any:
    """``app``: the app with every command registered (tests, programs that embed it)."""
    if name != "app":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from ncmeasure.cli._app import app

    register()
    return app


def _invoked(args: list[str]) -> str | None:
    """The module of the command ``args`` name, or None (no command, or not one of ours).

    The app's own options (``--debug``, ``--help``, ``--version``) take no value: the first
    word that is not an option names the command.
    """
    for arg in args:
        if arg == "--":
            return None
        if not arg.startswith("-"):
            return _MODULES.get(arg)
    return None


def main() -> None:
    """Entry point of the console script."""
    from ncmeasure.cli._app import app

    load_python_can_without_mdf()
    invoked = _invoked(sys.argv[1:])
    if invoked is None:  # the list of commands, or click's message for an unknown one
        register()
    else:
        register(invoked)
    app()
