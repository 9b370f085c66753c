"""A package's public names, imported on first use (PEP 562's module ``__getattr__``).

A package lists each public name with the module that defines it; the first
access imports that module and keeps the name in the package, so importing the
package costs nothing until a name is used (``ncmeasure --version`` stays
instant, ``ncmeasure controllers`` loads no Jinja, a number formatted by the
report's words loads no matplotlib).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_names"]


def lazy_names(
    package: str, modules: Mapping[str, str], namespace: dict[str, Any]
) -> Callable[[str], Any]:
    """The ``__getattr__`` of ``package``: a name of ``modules`` from its module, kept in
    ``namespace`` (the package's ``globals()``); any other name an AttributeError."""

    def attribute(name: str) -> Any:
        module = modules.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    return attribute
