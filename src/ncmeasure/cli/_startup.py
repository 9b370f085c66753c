"""The command line's start-up tricks, in one place: why each exists is said where it is.

Three things the command line does besides its commands:

- :func:`coerce_common_values_without_pydantic` converts the values of the options
  ncmeasure declares (text, paths, numbers given as defaults, lists of them) as typer
  would, without the pydantic TypeAdapter typer builds for each: pydantic's schema
  machinery is a tenth of a second, more than all the rest of ``init``'s start-up.
- :class:`CanWithoutMdf` keeps python-can from importing asammdf (and pandas) when a
  command needs python-can: half a second of every CANopen command's start-up, for
  MF4 CAN logs ncmeasure never reads.
- :func:`polish_help` makes typer's plain help read as the docstrings are written
  (paragraphs) and names arguments in capitals. The plain help itself is a start-up
  choice (``rich_markup_mode=None`` in :mod:`ncmeasure.cli._app`): typer's rich help
  imports rich and markdown-it, half of ``--help``'s start-up time.
"""

import functools
import importlib.util
import inspect
import sys
import types
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, get_args, get_origin

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


_NOT_COMMON = object()
"""What :func:`_common_value` returns for a value it leaves to typer."""


def _common_value(
    annotation: Any, info: typer.models.ParameterInfo, value: Any, coerce_path: Callable[..., Any]
) -> Any:
    """``value`` as typer's TypeAdapter for ``annotation`` returns it, or :data:`_NOT_COMMON`.

    Only where the result is plainly the same: text as it is; a path through typer's own
    checks (:func:`coerce_path`), made a :class:`~pathlib.Path` as pydantic makes it; a
    number that is already one (a default) within its bounds. Anything else (a number
    typed on the command line, a choice, a bad value whose message pydantic words) is
    typer's.
    """
    if info.parser is not None:
        return _NOT_COMMON
    if annotation is str and isinstance(value, str):
        return value
    if isinstance(annotation, type) and issubclass(annotation, Path):
        if info.path_type is not None or info.allow_dash or not isinstance(value, str | Path):
            return _NOT_COMMON
        checked = coerce_path(value, info, path_type=None)
        return checked if isinstance(checked, annotation) else annotation(checked)
    if annotation in (int, float) and type(value) is annotation and not info.clamp:
        low, high = info.min, info.max
        if (low is None or value >= low) and (high is None or value <= high):
            return value
    return _NOT_COMMON


@functools.cache  # once: typer's own conversion is wrapped, never a wrapper
def coerce_common_values_without_pydantic() -> None:
    """Typer (0.2x) converts every option's value through a pydantic TypeAdapter it builds
    on first use; this converts the common values (:func:`_common_value`) without one, and
    builds none for a value that is not there (typer returns None or an empty tuple for it
    before the adapter is used). Other values, and older typers without adapters, are
    left as they are.
    """
    try:
        from typer import _coercion, _param_types, core

        typers: Callable[[_coercion.TypeDescriptor], _coercion.RuntimeParam] = (
            core.build_runtime_param  # type: ignore[attr-defined]
        )
        coerce_path = _param_types.coerce_cli_path
        runtime_param = _coercion.RuntimeParam
    except (ImportError, AttributeError):  # a typer without pydantic adapters, or other ones
        return
    try:  # the click typer converts with: its own copy (typer 0.2x) or click itself
        from typer._click.exceptions import ClickException
    except ImportError:  # pragma: no cover - a typer that imports click
        from click import ClickException  # type: ignore[assignment]

    @dataclass(frozen=True)
    class Common(runtime_param):  # type: ignore[valid-type,misc]
        """Typer's conversion of one parameter, built when a value is not a common one."""

        descriptor: _coercion.TypeDescriptor
        built: list[_coercion.RuntimeParam]

        def _coerce_value(self, value: Any, param: Any, ctx: Any) -> Any:
            try:
                done = self._common(value, param, ctx)
            except ClickException:
                raise  # the value is wrong: typer's own message (coerce_cli_path's checks)
            except Exception:  # a typer whose private parts differ: its own conversion
                done = _NOT_COMMON
            if done is not _NOT_COMMON:
                return done
            if not self.built:
                self.built.append(typers(self.descriptor))
            return self.built[0]._coerce_value(value, param=param, ctx=ctx)

        def _common(self, value: Any, param: Any, ctx: Any) -> Any:
            origin: Any = get_origin(self.annotation)
            if origin is list and len(get_args(self.annotation)) == 1:
                (item_type,) = get_args(self.annotation)
                items = value if isinstance(value, list | tuple) else [value]
                done = [self._one(item_type, item, param, ctx) for item in items]
                return _NOT_COMMON if any(item is _NOT_COMMON for item in done) else done
            return self._one(self.annotation, value, param, ctx)

        def _one(self, annotation: Any, value: Any, param: Any, ctx: Any) -> Any:
            def path(value: Any, info: Any, *, path_type: Any) -> Any:
                return coerce_path(value, info, path_type=path_type, param=param, ctx=ctx)

            return _common_value(annotation, self.parameter_info, value, path)

    def build(descriptor: _coercion.TypeDescriptor) -> _coercion.RuntimeParam:
        try:
            if descriptor.file_annotation is not None:
                return typers(descriptor)
            return Common(
                parameter_info=descriptor.parameter_info,
                annotation=descriptor.annotation,
                descriptor=descriptor,
                built=[],
            )
        except (AttributeError, TypeError):  # a descriptor or RuntimeParam of another typer
            return typers(descriptor)

    core.build_runtime_param = build  # type: ignore[attr-defined]
