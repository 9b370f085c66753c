"""Opening a python-can bus, its failures told apart: a wrong name, or an interface that fails.

The link and the simulated drives (:mod:`ncmeasure.sim.cia402`) open their buses here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import can

from ncmeasure.errors import ConfigError, LinkError

__all__ = ["open_bus"]


def open_bus(channel: str | None, options: Mapping[str, Any], where: str) -> can.BusABC:
    """``can.Bus(channel=channel, **options)``, its failures as ncmeasure errors.

    Args:
        channel: The interface channel (None: python-can's configuration decides).
        options: The other arguments of ``can.Bus`` (``interface``, ``bitrate``, ...).
        where: How a message names the interface setting (``link.interface``,
            ``--interface``).

    Raises:
        ConfigError: The interface name is not one python-can knows (bad input).
        LinkError: The interface cannot be opened (no such device, a driver or
            package missing, no permission), naming interface and channel.
    """
    interface = options.get("interface")
    if interface is not None and interface not in can.interfaces.VALID_INTERFACES:
        known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
        raise ConfigError(
            f"{where} {interface}: python-can has no such interface (it knows {known})"
        )
    try:
        return can.Bus(channel=channel, **options)
    except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
        raise LinkError(
            f"cannot open the CAN interface {interface or '(python-can config)'} "
            f"channel {channel or '(default)'}: {exc}"
        ) from exc
