"""Modbus TCP/RTU drives: the link and the register maps it shares.

- :mod:`.registers`  register maps (``registermaps/``), the register codec,
  Modbus exception texts
- :mod:`.settings`   :class:`ModbusSettings`, :class:`ModbusAxis`: the link's
  settings, which the simulated drive serves with too
- :mod:`.plan`       the poll plan: the requests of a poll cycle, their decoding,
  the RTU line's timing
- :mod:`.transport`  the socket or serial port and one read request on it
- :mod:`.link`       :class:`ModbusLink`, the drive link: open/read/close, the
  polling thread, gaps and outages

The simulated drive (:mod:`ncmeasure.sim.modbus_drive`) imports the register
knowledge and the settings, not the link; so this package imports its modules
only when one of their names is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["ModbusAxis", "ModbusLink", "ModbusSettings"]

_MODULE_OF = {
    "ModbusAxis": "ncmeasure.links.modbus.settings",
    "ModbusLink": "ncmeasure.links.modbus.link",
    "ModbusSettings": "ncmeasure.links.modbus.settings",
}


def __getattr__(name: str) -> Any:
    if name in _MODULE_OF:
        return getattr(importlib.import_module(_MODULE_OF[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
