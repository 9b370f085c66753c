"""Opening a python-can bus, its failures told apart: a wrong name, or an interface that fails.

The link and the simulated drives (:mod:`ncmeasure.sim.cia402`) open their buses here,
and the link shuts its network down here (:func:`shut_down`).

On python-can's ``virtual`` interface a bus that receives its own messages gets them
back before any other bus on the channel sees them, as on a real bus, where the
controller's echo of a frame precedes every answer to it. python-can's own
:class:`~can.interfaces.virtual.VirtualBus` delivers in the order the buses were
opened: a simulated drive opened before the link could then answer a SYNC, on a
loaded computer, before the link's echo of that SYNC arrived, and the link would
put the answer into the previous cycle.
"""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Mapping
from copy import deepcopy
from typing import Any

import can
import canopen
from can.interfaces.virtual import VirtualBus

from ncmeasure.errors import ConfigError, LinkError

__all__ = ["open_bus", "shut_down"]

log = logging.getLogger(__name__)


class _EchoFirstVirtualBus(VirtualBus):
    """A virtual bus whose own echo is queued before the other buses get the frame."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self.receive_own_messages:
            super().send(msg, timeout)
            return
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        receivers = [self.queue] + [q for q in list(self.channel) if q is not self.queue]
        all_sent = True
        for bus_queue in receivers:
            copy = deepcopy(msg)
            copy.timestamp = timestamp
            copy.channel = self.channel_id
            copy.is_rx = bus_queue is not self.queue
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


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
        if interface == "virtual" and options.get("receive_own_messages"):
            rest = {key: value for key, value in options.items() if key != "interface"}
            return _EchoFirstVirtualBus(channel=channel or "channel-0", **rest)
        return can.Bus(channel=channel, **options)
    except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
        raise LinkError(
            f"cannot open the CAN interface {interface or '(python-can config)'} "
            f"channel {channel or '(default)'}: {exc}"
        ) from exc


def shut_down(network: canopen.Network | None, bus: can.BusABC | None) -> None:
    """Disconnect the network (and so its bus), else shut the bus down; never raises."""
    if network is not None:
        try:
            network.disconnect()
        except Exception as exc:
            log.info("canopen link: network shutdown: %s", exc)
    elif bus is not None:
        try:
            bus.shutdown()
        except Exception as exc:
            log.info("canopen link: bus shutdown: %s", exc)
