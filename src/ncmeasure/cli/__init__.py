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
when it runs, so that ``ncmeasure --help`` starts fast.
"""

from typer.models import CommandInfo

from ncmeasure.cli import (  # noqa: F401  (importing a module registers its commands)
    analysis,
    compensation,
    demo,
    measure,
    program,
    publish,
    record,
    serve,
    store,
    traces,
)
from ncmeasure.cli._app import app, publish_app, schema_app, store_app
from ncmeasure.cli._startup import load_python_can_without_mdf, polish_help

__all__ = ["app", "main"]

# `ncmeasure --help` lists the commands in the order of the README's command table,
# the pipeline's, whatever the order the modules above register them in.
_ORDER = [
    "init", "controllers", "plan", "generate", "check", "dryrun", "record", "export", "import",
    "simulate-drive", "measure", "analyze", "compare", "serve", "simulate", "demo", "compensation",
    "apply-compensation",
]  # fmt: skip


def _position(info: CommandInfo) -> int:
    name = info.name or (info.callback.__name__ if info.callback else "")
    return _ORDER.index(name) if name in _ORDER else len(_ORDER)


app.registered_commands.sort(key=_position)
polish_help([app, schema_app, store_app, publish_app])


def main() -> None:
    """Entry point of the console script."""
    load_python_can_without_mdf()
    app()
