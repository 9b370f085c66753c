"""CANopen CiA 402 drives: the link and the protocol knowledge it shares.

- :mod:`.objects`  data types, units, object maps (``objectmaps/``), object
  dictionaries, EDS/DCF files, EMCY (``emcy.toml``) and SDO texts
- :mod:`.busload`  the bus load of a TPDO layout
- :mod:`.sync`     rows from PDO frames, SYNC cycle by SYNC cycle
- :mod:`.link`     :class:`CanOpenLink`, the drive link

The simulated drives (:mod:`ncmeasure.sim.cia402`) import the protocol
knowledge, not the link; so this package imports its modules only when one of
their names is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["CanOpenAxis", "CanOpenLink", "CanOpenSettings"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("ncmeasure.links.canopen.link"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
