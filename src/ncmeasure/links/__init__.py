"""Drive links: the contract (:mod:`ncmeasure.links.base`) and the registry of backends.

Built-in links are imported only when used. Third-party links register
through the entry-point group ``ncmeasure.links``::

    [project.entry-points."ncmeasure.links"]
    mylink = "mypackage.link:MyLink"      # a DriveLink subclass
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from importlib.metadata import entry_points
from typing import Any

from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, DependencyError
from ncmeasure.links.base import AxisBinding, AxisLinkSettings, DriveLink, LinkSettings
from ncmeasure.samples import REAL_TIME, Channel, LinkClock, LinkEvent, SampleBlock

__all__ = [
    "REAL_TIME",
    "AxisBinding",
    "AxisLinkSettings",
    "Channel",
    "DriveLink",
    "LinkClock",
    "LinkEvent",
    "LinkSettings",
    "SampleBlock",
    "available_links",
    "link_class",
    "make_link",
]

ENTRY_POINT_GROUP = "ncmeasure.links"

#: name -> (module, class, pip extra that brings its dependencies, or None)
BUILTIN_LINKS: dict[str, tuple[str, str, str | None]] = {
    "canopen": ("ncmeasure.links.canopen.link", "CanOpenLink", None),
    "modbus": ("ncmeasure.links.modbus.link", "ModbusLink", None),
    "replay": ("ncmeasure.links.replay", "ReplayLink", None),
}


def available_links() -> list[str]:
    """Names of the built-in links and of those registered by other packages."""
    names = set(BUILTIN_LINKS)
    names.update(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))
    return sorted(names)


def link_class(name: str) -> type[DriveLink]:
    """The link class registered as ``name``, imported now.

    Raises:
        ConfigError: no link of that name.
        DependencyError: the link's package dependencies are missing.
    """
    if name in BUILTIN_LINKS:
        module_name, class_name, extra = BUILTIN_LINKS[name]
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            hint = f"pip install 'ncmeasure[{extra}]'" if extra else "reinstall ncmeasure"
            raise DependencyError(
                f"the {name} link needs the package {exc.name!r}, which is missing ({hint})"
            ) from exc
        cls = getattr(module, class_name)
    else:
        found = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
        if not found:
            known = ", ".join(available_links())
            raise ConfigError(f"unknown link {name!r}; known links: {known}")
        try:
            cls = found[0].load()
        except ImportError as exc:
            raise DependencyError(f"the {name} link cannot be imported: {exc}") from exc
    if not (isinstance(cls, type) and issubclass(cls, DriveLink)):
        raise ConfigError(f"link {name!r} is not a DriveLink")
    return cls


def make_link(
    config: MachineConfig,
    name: str | None = None,
    overrides: Mapping[str, Any] | None = None,
    axis_overrides: Mapping[str, Mapping[str, Any]] | None = None,
) -> DriveLink:
    """Build the link of a machine from its ``[link]`` table, with overrides.

    Args:
        config: The machine.
        name: Link type; default: ``link.type`` of the machine file.
        overrides: Link settings replacing those of the file (command line).
        axis_overrides: Per-axis settings by axis name replacing those of the file.

    Raises:
        ConfigError: no link named, unknown link, or invalid settings.
        DependencyError: the link's dependencies are missing.
    """
    table = dict(config.link or {})
    file_type = table.pop("type", None)
    link_type = name or file_type
    if not link_type:
        raise ConfigError("no link given: set [link] type in the machine file or use --link")
    if name and file_type and name != file_type:
        table = {}  # the file's settings belong to another link
    table.update(overrides or {})
    cls = link_class(str(link_type))
    axes = []
    for axis in config.axes:
        axis_table = dict(axis.link if file_type in (None, link_type) else {})
        axis_table.update((axis_overrides or {}).get(axis.name, {}))
        axes.append((axis, axis_table))
    return cls.from_tables(table, axes)
