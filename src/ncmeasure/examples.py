"""The example machines: what ``ncmeasure init`` prints and the machine of ``ncmeasure demo``.

Both are data files of the package (``data/example-machine.toml``,
``data/demo-machine.toml``, ``data/demo-links.toml``): commented, valid machine
files with ``${controller}`` (and for the demo its link) left to fill in.
"""

from __future__ import annotations

import functools
import tomllib
from importlib import resources
from string import Template
from typing import Any

__all__ = ["DEMO_LINKS", "demo_link_tables", "demo_machine", "example_machine"]


@functools.cache
def _data(name: str) -> str:
    return resources.files("ncmeasure").joinpath("data", name).read_text(encoding="utf-8")


@functools.cache
def _demo_links() -> dict[str, dict[str, str]]:
    links: dict[str, dict[str, str]] = tomllib.loads(_data("demo-links.toml"))
    return links


DEMO_LINKS: tuple[str, ...] = ("canopen", "modbus")
"""The links ``ncmeasure demo`` can record through (``data/demo-links.toml``)."""


def example_machine(controller: str) -> str:
    """The example machine file for ``controller``."""
    return Template(_data("example-machine.toml")).substitute(controller=controller)


def demo_machine(controller: str = "linuxcnc", link: str = "canopen") -> str:
    """The machine file of ``ncmeasure demo`` for ``controller`` and ``link``."""
    chosen = _demo_links()[link]
    axis = Template(chosen["axis"])
    return Template(_data("demo-machine.toml")).substitute(
        controller=controller,
        link_table=chosen["table"],
        x_link=axis.substitute(node=1),
        z_link=axis.substitute(node=2),
    )


def demo_link_tables(link: str, axes: int) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The demo's ``[link]`` table for ``link`` (``type`` included) and its axes' ``link`` tables.

    The settings ``ncmeasure dryrun`` records a machine file with, where the file has none:
    axis ``i`` (0-based) gets node or unit id ``i + 1``.
    """
    chosen = _demo_links()[link]
    table: dict[str, Any] = tomllib.loads(chosen["table"])["link"]
    axis = Template(chosen["axis"])
    tables = [
        tomllib.loads(f"link = {{ {axis.substitute(node=i + 1)} }}")["link"] for i in range(axes)
    ]
    return table, tables
