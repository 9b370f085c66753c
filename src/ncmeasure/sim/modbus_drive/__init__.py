"""A simulated Modbus drive: a pymodbus server that serves axis states in a register map.

Each served unit id stands for one axis and shows the state of a
:class:`~ncmeasure.sim.signals.SignalSource` encoded the way its register map
says, so a :class:`~ncmeasure.links.modbus.link.ModbusLink` reading it gets the
source's values quantised by the map; the server takes the link's own settings
models. Time is the server's wall clock, a deterministic request count
(``step_s``), or a :class:`~ncmeasure.samples.SimulatedClock` shared with the
link (lockstep).

- :mod:`.drive`       :class:`SimulatedModbusDrive`, :class:`SimulatedUnit`,
  :class:`ModbusDriveScaling`, :class:`ServerInfo` and :func:`serve`, the
  blocking entry point behind ``ncmeasure simulate-drive --link modbus``
- :mod:`.faults`      :class:`Fault` switches (silent, exception, late,
  disconnect), thread-safe through :class:`DriveFaults`
- :mod:`.process`     :func:`running_server`: a server in another process,
  controlled through a :class:`ServerHandle`
- :mod:`.null_modem`  :func:`pty_null_modem`: Modbus RTU without hardware

Every name is importable from this package.
"""

from __future__ import annotations

from ncmeasure.sim.modbus_drive.drive import (
    ModbusDriveScaling,
    ServerInfo,
    SimulatedModbusDrive,
    SimulatedUnit,
    serve,
)
from ncmeasure.sim.modbus_drive.faults import NO_FAULT, DriveFaults, Fault
from ncmeasure.sim.modbus_drive.null_modem import pty_null_modem
from ncmeasure.sim.modbus_drive.process import ServerHandle, running_server

__all__ = [
    "NO_FAULT",
    "DriveFaults",
    "Fault",
    "ModbusDriveScaling",
    "ServerHandle",
    "ServerInfo",
    "SimulatedModbusDrive",
    "SimulatedUnit",
    "pty_null_modem",
    "running_server",
    "serve",
]
