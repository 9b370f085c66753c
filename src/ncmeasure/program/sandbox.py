"""The template sandbox: what a (user's) template may do while it renders a program.

Templates come from the built-in folder or from a user's ``--templates-dir``;
both render in the same sandbox, so a user template can choose words but
cannot hang the generator, fill the memory, or change what was planned:

* **Steps.** Every iteration of every ``for`` loop (the parsed template is
  rewritten so each loop's iterable is counted), every call, every attribute
  or item access and every operator counts against one budget per program
  file: a constant allowance plus a generous factor times the planned moves.
  A template beyond it stops with "template file:line: ... steps". The budget
  is a count, not a clock, so the same template stops at the same step on
  an idle and on a loaded computer; a CPU-time backstop (``time.process_time``)
  catches anything the count does not reach.
* **Sizes.** ``range`` is capped; ``*`` and ``**`` are checked before they
  compute, ``+`` and ``~`` after: no string or list a template builds may
  exceed ``MAX_TEXT`` characters. The program files themselves are counted
  byte by byte against the program memory while they are written.
* **Names.** Only the dialect's filters and a few harmless ones, only
  ``range`` and ``namespace`` as globals, attributes only of the view model's
  fields, of loop variables and namespaces, and a few string methods; nothing
  that starts with an underscore, no mutating method (the view model is
  frozen: tuples, read-only mappings, frozen dataclasses).

Every failure is a :class:`jinja2.TemplateRuntimeError`, which the renderer
reports with the template's file and line.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

import jinja2
from jinja2 import nodes
from jinja2.runtime import Context, LoopContext
from jinja2.sandbox import ImmutableSandboxedEnvironment
from jinja2.utils import Namespace
from jinja2.visitor import NodeTransformer

__all__ = ["MAX_RANGE", "MAX_TEXT", "STEPS_PER_MOVE", "TemplateLimitError", "TemplateSandbox"]

MAX_RANGE = 100_000
"""Largest ``range`` a template may make."""
MAX_TEXT = 1_000_000
"""Longest string or list a template may build (characters or items)."""
STEPS_PER_MOVE = 200
"""Budget per planned move; the built-in templates take about 15."""
BASE_STEPS = 1_000_000
"""Budget every program file gets on top of its moves."""
MAX_CPU_S = 300.0
"""CPU seconds one program file may take to render (a backstop; the steps stop first)."""

_FILTERS = {
    "upper",
    "lower",
    "trim",
    "length",
    "count",
    "int",
    "float",
    "round",
    "abs",
    "string",
    "default",
    "d",
    "first",
    "last",
    "join",
    "list",
}
"""Jinja's own filters a template may use beside the dialect's."""
_STR_METHODS = {"upper", "lower", "strip", "startswith", "endswith"}
_MAPPING_METHODS = {"items", "keys", "values", "get"}
_LOOP_FIELDS = {
    "index",
    "index0",
    "revindex",
    "revindex0",
    "first",
    "last",
    "length",
    "previtem",
    "nextitem",
    "depth",
    "depth0",
    "cycle",
    "changed",
}


@functools.cache
def _field_names(cls: type) -> frozenset[str]:
    return frozenset(f.name for f in dataclasses.fields(cls))


class TemplateLimitError(jinja2.TemplateRuntimeError):
    """A template went beyond what the sandbox allows."""


class _Count(NodeTransformer):
    """Rewrites a parsed template: every loop's iterable and every ``~`` is counted."""

    def visit_For(self, node: nodes.For) -> nodes.Node:  # noqa: N802 (the visitor's naming)
        loop = self.generic_visit(node)
        assert isinstance(loop, nodes.For)
        loop.iter = nodes.Filter(loop.iter, "_ncm_steps", [], [], None, None, lineno=loop.lineno)
        return loop

    def visit_Concat(self, node: nodes.Concat) -> nodes.Node:  # noqa: N802
        joined = self.generic_visit(node)
        assert isinstance(joined, nodes.Expr)
        return nodes.Filter(joined, "_ncm_text", [], [], None, None, lineno=node.lineno)


def _size(value: Any) -> int:
    return len(value) if isinstance(value, str | bytes | list | tuple) else 0


class TemplateSandbox(ImmutableSandboxedEnvironment):
    """A sandboxed, immutable Jinja environment with step and size budgets."""

    intercepted_binops = frozenset({"*", "**", "+"})

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self.max_steps = BASE_STEPS
        self.max_cpu_s = MAX_CPU_S
        self._steps = 0
        self._cpu_start = time.process_time()
        self.filters = {name: f for name, f in self.filters.items() if name in _FILTERS}
        self.filters.update(_ncm_steps=self._count_steps, _ncm_text=self._check_text)
        self.globals = {"range": self._range, "namespace": Namespace}

    def start(self, moves: int) -> None:
        """A fresh budget for one program file that renders ``moves`` planned moves."""
        self.max_steps = BASE_STEPS + STEPS_PER_MOVE * moves
        self._steps = 0
        self._cpu_start = time.process_time()

    def _step(self, count: int = 1) -> None:
        self._steps += count
        if self._steps > self.max_steps:
            raise TemplateLimitError(
                f"the template's loops, calls and operations exceed {self.max_steps} steps "
                "(a loop without end, or loops nested too deep)"
            )
        if self._steps & 0xFFF == 0 and time.process_time() - self._cpu_start > self.max_cpu_s:
            raise TemplateLimitError(f"the template takes more than {self.max_cpu_s:g} s of CPU")

    def _text(self, value: Any) -> Any:
        if _size(value) > MAX_TEXT:
            raise TemplateLimitError(
                f"the template builds a value of {_size(value)} characters or items, "
                f"more than {MAX_TEXT}"
            )
        return value

    def _count_steps(self, iterable: Iterable[Any]) -> Iterator[Any]:
        for item in iterable:
            self._step()
            yield item

    def _check_text(self, value: Any) -> Any:
        self._step()
        return self._text(value)

    def _range(self, *args: int) -> range:
        self._step()
        numbers = range(*args)
        if len(numbers) > MAX_RANGE:
            raise TemplateLimitError(f"range of {len(numbers)} numbers, more than {MAX_RANGE}")
        return numbers

    def call_binop(self, context: Context, operator: str, left: Any, right: Any) -> Any:
        self._step()
        if operator == "*":
            for seq, times in ((left, right), (right, left)):
                if _size(seq) and isinstance(times, int) and _size(seq) * times > MAX_TEXT:
                    raise TemplateLimitError(
                        f"the template repeats a value {times} times, more than {MAX_TEXT} "
                        "characters or items"
                    )
        if operator == "**" and isinstance(right, int | float) and abs(right) > 64:
            raise TemplateLimitError(f"the template raises to the power {right}, more than 64")
        return self._text(super().call_binop(context, operator, left, right))

    def call(__self, __context: Context, __obj: Any, *args: Any, **kwargs: Any) -> Any:  # noqa: N805
        __self._step()
        return __self._text(super().call(__context, __obj, *args, **kwargs))

    def getattr(self, obj: Any, attribute: str) -> Any:
        self._step()
        if isinstance(obj, str) and attribute not in _STR_METHODS:
            # str.format and its kin would build text of any width before a check
            raise TemplateLimitError(
                f"string method {attribute!r} is not available "
                f"(only {', '.join(sorted(_STR_METHODS))})"
            )
        return super().getattr(obj, attribute)

    def getitem(self, obj: Any, argument: Any) -> Any:
        self._step()
        return super().getitem(obj, argument)

    def is_safe_attribute(self, obj: Any, attr: str, value: Any) -> bool:
        if attr.startswith("_"):
            return False
        if isinstance(obj, str):
            return attr in _STR_METHODS
        if isinstance(obj, Namespace):
            return True
        if isinstance(obj, LoopContext):
            return attr in _LOOP_FIELDS
        if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
            return attr in _field_names(type(obj))
        if isinstance(obj, Mapping):
            return attr in _MAPPING_METHODS
        return False

    def _parse(self, source: str, name: str | None, filename: str | None) -> nodes.Template:
        tree = super()._parse(source, name, filename)
        counted = _Count().visit(tree)
        assert isinstance(counted, nodes.Template)
        return counted
