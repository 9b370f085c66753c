"""Modbus TCP/RTU drives: the link and the register maps it shares.

- :mod:`.registers`  register maps (``registermaps/``), the register codec,
  Modbus exception texts
- :mod:`.link`       :class:`ModbusLink`, the drive link

The simulated drive (:mod:`ncmeasure.sim.modbus_drive`) imports the register
knowledge, not the link; so this package imports its modules only when one of
their names is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["ModbusAxis", "ModbusLink", "ModbusSettings"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("ncmeasure.links.modbus.link"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
