"""The command line's start-up tricks, in one place: why each exists is said where it is.

Two things the command line does besides its commands:

- :class:`CanWithoutMdf` keeps python-can from importing asammdf (and pandas) when a
  command needs python-can: half a second of every CANopen command's start-up, for
  MF4 CAN logs ncmeasure never reads.
- :func:`polish_help` makes typer's plain help read as the docstrings are written
  (paragraphs) and names arguments in capitals. The plain help itself is a start-up
  choice (``rich_markup_mode=None`` in :mod:`ncmeasure.cli._app`): typer's rich help
  imports rich and markdown-it, half of ``--help``'s start-up time.
"""

import importlib.util
import inspect
import sys
import types
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, get_args

import typer

if TYPE_CHECKING:
    import importlib.machinery


class CanWithoutMdf:
    """Imports python-can, the first time a command needs it, without its MF4 log support.

    ``import can`` imports asammdf, and with it pandas, whenever the ``mdf`` extra is
    installed: about half a second, for MF4 CAN logs that ncmeasure never reads
    (:mod:`ncmeasure.traces.canlog` takes .blf, .asc, .log and .trc). While python-can
    loads, asammdf looks absent to it; ncmeasure's own MF4 import and export import
    asammdf as usual. Installed by :func:`ncmeasure.cli.main` only: a program that
    imports ncmeasure as a library keeps python-can as it is.
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


def load_python_can_without_mdf() -> None:
    """Install :class:`CanWithoutMdf` unless python-can is imported already."""
    if "can" not in sys.modules:
        sys.meta_path.insert(0, CanWithoutMdf())


def reflow(text: str) -> str:
    """Join the lines of each paragraph: the console wraps them to its width."""
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(" ".join(line.strip() for line in p.splitlines()) for p in paragraphs)


def _polish_command(info: typer.models.CommandInfo, done: set[int]) -> None:
    """Help texts as paragraphs, and metavars.

    Arguments show their name in capitals, flags no type; options shared by
    several commands are polished once.
    """
    doc = info.help or (info.callback.__doc__ if info.callback else None)
    if doc:
        info.help = reflow(doc)
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


def polish_help(apps: Iterable[typer.Typer]) -> None:
    """Polish the help of every command of ``apps`` (see :func:`_polish_command`)."""
    done: set[int] = set()
    for each in apps:
        for info in each.registered_commands:
            _polish_command(info, done)
