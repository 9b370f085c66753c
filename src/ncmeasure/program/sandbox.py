"""The template sandbox: what a (user's) template may do while it renders a program.

Templates come from the built-in folder or from a user's ``--templates-dir``;
both render in the same sandbox, so a user template can choose words but
cannot hang the generator, fill the memory, or change what was planned:

* **Steps.** Every iteration of every ``for`` loop (the parsed template is
  rewritten so each loop's iterable is counted), every call, filter, attribute
  or item access and every operator counts against one budget per
  ``generate``: a constant allowance plus a generous factor times the planned
  moves. Work on long values costs more: a step per 256 characters or items
  an operation or filter reads or builds. A template beyond the budget stops
  with "template file:line: ... steps". The budget is a count, not a clock, so
  the same template stops at the same step on an idle and on a loaded
  computer; a CPU-time backstop (``time.process_time``, a few dozen seconds
  for the whole ``generate``) catches anything the count does not reach.
* **Sizes.** ``range`` is capped; ``*``, ``**``, ``~``, ``join`` and
  ``string`` are checked before they compute, everything else after: no
  string or list a template builds may exceed ``MAX_TEXT`` characters or
  items, no number ``MAX_INT_BITS`` bits. And everything a template builds or
  writes (every value an operation, call or filter returns, every piece of
  text it outputs, into a file, a ``{% set %}`` block or a macro) counts
  against one total per ``generate``: a constant allowance plus an amount per
  planned move. The program files themselves are also counted byte by byte
  against the program memory while they are written.
* **Words.** What a template writes (``{{ }}``, ``~``, ``string``, ``join``)
  is text, numbers, true/false or none, never a list, mapping or object,
  whose printed form could be of any length; ``%`` formatting of strings is
  not available.
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
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any

import jinja2
from jinja2 import nodes
from jinja2.runtime import Context, LoopContext
from jinja2.sandbox import ImmutableSandboxedEnvironment
from jinja2.utils import Namespace
from jinja2.visitor import NodeTransformer

__all__ = [
    "BUILT_PER_MOVE",
    "MAX_BUILT",
    "MAX_RANGE",
    "MAX_TEXT",
    "STEPS_PER_MOVE",
    "TemplateLimitError",
    "TemplateSandbox",
]

MAX_RANGE = 100_000
"""Largest ``range`` a template may make."""
MAX_TEXT = 1_000_000
"""Longest string or list a template may build (characters or items)."""
MAX_INT_BITS = 4096
"""Largest integer a template may compute (about 1233 decimal digits)."""
STEPS_PER_MOVE = 200
"""Budget per planned move; the built-in templates take about 20."""
BASE_STEPS = 1_000_000
"""Budget every ``generate`` gets on top of its moves."""
MAX_BUILT = 50_000_000
"""Characters or items every ``generate`` may build or write on top of its moves."""
BUILT_PER_MOVE = 1_000
"""Characters or items per planned move; the built-in templates take about 70."""
CHARACTERS_PER_STEP = 256
"""Work on long values: an operation or filter costs a step per this many characters."""
MAX_CPU_S = 30.0
"""CPU seconds one ``generate`` may take to render all its files (a backstop; the
steps stop first)."""

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
_WORDS = (str, int, float, bool, type(None), jinja2.Undefined)
"""What a template may write: text, numbers, true/false, none (an undefined name raises
its own error when it is written)."""
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


def _filter(node: nodes.Node, name: str, *args: nodes.Expr, lineno: int) -> nodes.Filter:
    return nodes.Filter(node, name, list(args), [], None, None, lineno=lineno)


class _Count(NodeTransformer):
    """Rewrites a parsed template so the sandbox sees what it does.

    Every loop's iterable is counted, every ``~`` is joined by the sandbox (which
    checks its parts first), and every piece of output, expression or template text,
    is counted against the total a template may build.
    """

    def visit_For(self, node: nodes.For) -> nodes.Node:  # noqa: N802 (the visitor's naming)
        loop = self.generic_visit(node)
        assert isinstance(loop, nodes.For)
        loop.iter = _filter(loop.iter, "_ncm_steps", lineno=loop.lineno)
        return loop

    def visit_Concat(self, node: nodes.Concat) -> nodes.Node:  # noqa: N802
        joined = self.generic_visit(node)
        assert isinstance(joined, nodes.Concat)
        parts = nodes.List(joined.nodes, lineno=node.lineno)
        return _filter(parts, "_ncm_concat", lineno=node.lineno)

    def visit_Output(self, node: nodes.Output) -> nodes.Node:  # noqa: N802
        output = self.generic_visit(node)
        assert isinstance(output, nodes.Output)
        data = sum(
            len(child.data) for child in output.nodes if isinstance(child, nodes.TemplateData)
        )
        children: list[nodes.Expr] = [
            child
            if isinstance(child, nodes.TemplateData)
            else _filter(child, "_ncm_out", lineno=child.lineno)
            for child in output.nodes
        ]
        if data:  # template text: counted once per time the block runs
            count = _filter(nodes.Const(""), "_ncm_data", nodes.Const(data), lineno=node.lineno)
            children.insert(0, count)
        output.nodes = children
        return output


def _size(value: Any) -> int:
    return len(value) if isinstance(value, str | bytes | list | tuple) else 0


class TemplateSandbox(ImmutableSandboxedEnvironment):
    """A sandboxed, immutable Jinja environment with step and size budgets."""

    intercepted_binops = frozenset({"*", "**", "+", "%"})

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self.max_steps = BASE_STEPS
        self.max_built = MAX_BUILT
        self.max_cpu_s = MAX_CPU_S
        self._steps = 0
        self._built = 0
        self._next_cpu_check = 0
        self._cpu_start = time.process_time()
        self.filters = {
            name: self._guarded(function)
            for name, function in self.filters.items()
            if name in _FILTERS and name not in ("join", "string")
        }
        self.filters.update(join=self._guarded(self._join), string=self._guarded(self._string))
        # The sandbox's own filters take the context: Jinja never runs them at compile time.
        self.filters.update(
            _ncm_steps=jinja2.pass_context(lambda _, iterable: self._count_steps(iterable)),
            _ncm_concat=jinja2.pass_context(lambda _, parts: self._concat(parts)),
            _ncm_out=jinja2.pass_context(lambda _, value: self._out(value)),
            _ncm_data=jinja2.pass_context(lambda _, empty, size: self._data(empty, size)),
        )
        self.globals = {"range": self._range, "namespace": Namespace}

    def add_filters(self, **filters: Callable[..., Any]) -> None:
        """Make ``filters`` available, each counted and size-checked like Jinja's own."""
        self.filters.update({name: self._guarded(f) for name, f in filters.items()})

    def start(self, moves: int) -> None:
        """Fresh budgets for one ``generate`` that renders ``moves`` planned moves."""
        self.max_steps = BASE_STEPS + STEPS_PER_MOVE * moves
        self.max_built = MAX_BUILT + BUILT_PER_MOVE * moves
        self._steps = 0
        self._built = 0
        self._next_cpu_check = 0
        self._cpu_start = time.process_time()

    @property
    def used(self) -> tuple[int, int]:
        """Steps taken and characters or items built since :meth:`start`."""
        return self._steps, self._built

    # --- budgets ---------------------------------------------------------------------------

    def _step(self, count: int = 1) -> None:
        self._steps += count
        if self._steps > self.max_steps:
            raise TemplateLimitError(
                f"the template's loops, calls and operations exceed {self.max_steps} steps "
                "(a loop without end, loops nested too deep, or work on long values)"
            )
        if self._steps >= self._next_cpu_check:
            self._next_cpu_check = self._steps + 4096
            if time.process_time() - self._cpu_start > self.max_cpu_s:
                raise TemplateLimitError(
                    f"the templates take more than {self.max_cpu_s:g} s of CPU"
                )

    def _work(self, *values: Any) -> None:
        """Steps for an operation on ``values``: one, and one per 256 characters or items."""
        self._step(1 + sum(_size(v) for v in values) // CHARACTERS_PER_STEP)

    def _build(self, size: int) -> None:
        self._built += size
        if self._built > self.max_built:
            raise TemplateLimitError(
                f"the templates build more than {self.max_built} characters in all "
                "(values and text, every file together)"
            )

    def _text(self, value: Any) -> Any:
        """A value an operation, call or filter returned: within the limits, counted."""
        size = _size(value)
        if size > MAX_TEXT:
            raise TemplateLimitError(
                f"the template builds a value of {size} characters or items, more than {MAX_TEXT}"
            )
        if isinstance(value, int) and value.bit_length() > MAX_INT_BITS:
            raise TemplateLimitError(
                f"the template computes a number of more than {MAX_INT_BITS * 3 // 10} digits"
            )
        self._build(size)
        return value

    def _word(self, value: Any) -> Any:
        """A value a template writes: text, a number, true/false or none."""
        if not isinstance(value, _WORDS):
            raise TemplateLimitError(
                f"the template writes words and numbers, not {type(value).__name__} values "
                "(write their items)"
            )
        return value

    # --- the sandbox's own filters -------------------------------------------------------------

    def _guarded(self, function: Callable[..., Any]) -> Callable[..., Any]:
        """``function`` as a filter that counts steps by the size of what it reads and
        builds, and checks what it returns."""

        @functools.wraps(function)  # keeps Jinja's pass_context / pass_eval_context mark
        def guarded(*args: Any, **kwargs: Any) -> Any:
            self._work(*args)
            result = function(*args, **kwargs)
            self._work(result)
            return self._text(result)

        return guarded

    def _join(self, value: Iterable[Any], d: str = "", attribute: Any = None) -> str:
        """Jinja's ``join``, its length checked before it is built."""
        items = list(self._count_steps(value))
        if attribute is not None:
            items = [self.getitem(item, attribute) for item in items]
        parts = [str(self._word(item)) for item in items]
        separator = str(self._word(d))
        size = sum(map(len, parts)) + len(separator) * max(len(parts) - 1, 0)
        if size > MAX_TEXT:
            raise TemplateLimitError(f"the template joins {size} characters, more than {MAX_TEXT}")
        return separator.join(parts)

    def _string(self, value: Any) -> str:
        return str(self._word(value))

    def _concat(self, parts: list[Any]) -> str:
        """``a ~ b``: the length checked before the text is built."""
        texts = [str(self._word(part)) for part in parts]
        self._work(*texts)
        size = sum(map(len, texts))
        if size > MAX_TEXT:
            raise TemplateLimitError(
                f"the template builds a value of {size} characters or items, more than {MAX_TEXT}"
            )
        return "".join(texts)

    def _out(self, value: Any) -> Any:
        """What ``{{ }}`` writes: a word, counted."""
        self._word(value)
        if isinstance(value, str):
            self._work(value)
            self._build(len(value))
        return value

    def _data(self, empty: str, size: int) -> str:
        """Template text written: counted each time its block runs."""
        self._step(1 + size // CHARACTERS_PER_STEP)
        self._build(size)
        return empty

    def _count_steps(self, iterable: Iterable[Any]) -> Iterator[Any]:
        for item in iterable:
            self._step()
            yield item

    def _range(self, *args: int) -> range:
        self._step()
        numbers = range(*args)
        if len(numbers) > MAX_RANGE:
            raise TemplateLimitError(f"range of {len(numbers)} numbers, more than {MAX_RANGE}")
        return numbers

    # --- what Jinja's sandbox intercepts -----------------------------------------------------

    def call_binop(self, context: Context, operator: str, left: Any, right: Any) -> Any:
        self._work(left, right)
        if operator == "*":
            for seq, times in ((left, right), (right, left)):
                if _size(seq) and isinstance(times, int) and _size(seq) * times > MAX_TEXT:
                    raise TemplateLimitError(
                        f"the template repeats a value {times} times, more than {MAX_TEXT} "
                        "characters or items"
                    )
        if operator == "**" and isinstance(right, int | float) and abs(right) > 64:
            raise TemplateLimitError(f"the template raises to the power {right}, more than 64")
        if operator == "%" and isinstance(left, str):
            raise TemplateLimitError(
                "'%' formatting of text is not available (it builds text of any width); "
                "use the filters"
            )
        result = super().call_binop(context, operator, left, right)
        self._work(result)
        return self._text(result)

    def call(__self, __context: Context, __obj: Any, *args: Any, **kwargs: Any) -> Any:  # noqa: N805
        __self._step()
        result = super().call(__context, __obj, *args, **kwargs)
        __self._work(result)
        return __self._text(result)

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
        result = super().getitem(obj, argument)
        if isinstance(argument, slice):  # a new string or list
            self._work(result)
            return self._text(result)
        return result

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
