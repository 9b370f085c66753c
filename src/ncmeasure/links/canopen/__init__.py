"""CANopen CiA 402 drives: the link and the protocol knowledge it shares.

- :mod:`.objects`   data types, units, object maps (``objectmaps/``), object
  dictionaries, EDS/DCF files, EMCY (``emcy.toml``) and SDO texts
- :mod:`.bus`       opening a python-can bus
- :mod:`.busload`   the bus load of a TPDO layout
- :mod:`.settings`  the link's settings: :class:`CanOpenSettings`, :class:`CanOpenAxis`
- :mod:`.layout`    object map / EDS / DCF -> the TPDO slots the link reads
- :mod:`.configure` SDO and NMT configuration of one drive (prepare, map, start)
- :mod:`.sync`      SYNC production, and rows from PDO frames, SYNC cycle by SYNC cycle
- :mod:`.receive`   the receiver, the raw log, rows decoded, SDO polling
- :mod:`.link`      :class:`CanOpenLink`, the drive link: open, read, close, gaps
- :mod:`.offsets`   the torque offset 0x60B2 written over SDO (``apply-compensation``)

The simulated drives (:mod:`ncmeasure.sim.cia402`) import the protocol
knowledge and the settings, not the link; so this package imports its modules
only when one of their names is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["CanOpenAxis", "CanOpenLink", "CanOpenSettings"]

_MODULES = {
    "CanOpenAxis": "ncmeasure.links.canopen.settings",
    "CanOpenLink": "ncmeasure.links.canopen.link",
    "CanOpenSettings": "ncmeasure.links.canopen.settings",
}


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        return getattr(importlib.import_module(_MODULES[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
