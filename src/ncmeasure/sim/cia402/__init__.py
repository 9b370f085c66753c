"""Simulated CiA 402 servo drives on a python-can bus: SDO server, NMT, TPDOs on SYNC.

A frame-level responder, lean enough for 1 kHz SYNC with several drives in
one Python process (``canopen.LocalNode`` does not transmit mapped TPDOs on
SYNC by itself). Each :class:`SimulatedDrive` has an object dictionary, from
an EDS/DCF file (the real fixtures work, quirks included) or from the
built-in CiA 402 defaults, and:

- answers SDO uploads and downloads (expedited and segmented) like a drive:
  access rights, sizes, and the CiA 301 rules for changing a TPDO (mapping
  only while the PDO is disabled and its entry count is 0, mapped objects
  must exist, be mappable and fit 64 bits);
- follows NMT (start, stop, pre-operational, reset node/communication with a
  boot-up message);
- on every SYNC, while operational, sends its valid synchronous TPDOs
  (transmission type 1..240) with values of a :class:`~ncmeasure.sim.signals.SignalSource`
  at time = SYNC index × period, encoded like a real drive: int32
  increments, int32 velocity units, int16 per mille of the rated current,
  statusword 0x0237 "operation enabled". The period is the communication
  cycle period 0x1006 the master writes, else ``period_s``.

The SYNC index counts the SYNC messages from 0, so it equals the cycle number
of the CANopen link that produces them, and the sample of link time ``t`` is
the source's state at ``t``. A SYNC with a one-byte counter (1..240, CiA 301
0x1019) sets the index to the next one that is congruent to ``counter - 1``
modulo 240: cycles the producer skipped are skipped here too.

On python-can's ``virtual`` bus the drives can also answer SYNC *on the bus*
(``answer="on_send"``): within the sender's ``send`` call, right after the
SYNC reached every other bus and before that call returns, as a drive
answers in its synchronous window whatever the host does. The frames are
then behind their SYNC and ahead of the next one, however late the host runs
any thread. (The drives' thread still serves NMT and SDO.) The
time spent answering is the sender's thread's; :attr:`SimulatedDrives.answer_cpu_s`
says how much, for a benchmark that must not count it.

In lockstep with a link on a :class:`~ncmeasure.samples.SimulatedClock`
(``clock``), the drives report every SYNC answered, with the number of frames
they have sent, and the link sends the next SYNC only when it has received
them: the recording is the same on an idle and on a loaded computer. With
``answer="on_send"`` in lockstep the drives answer every frame (NMT and SDO
too) within its send, so a SYNC never overtakes the command sent before it,
and no thread of theirs stands between two cycles (the demo's way: a third
less time per cycle).

Fault switches for tests, all thread-safe: :meth:`SimulatedDrive.stop_answering`,
:meth:`~SimulatedDrive.resume`, :meth:`~SimulatedDrive.abort_sdo`,
:meth:`~SimulatedDrive.slow`, :meth:`~SimulatedDrive.reboot`,
:meth:`~SimulatedDrive.send_emcy`, :meth:`~SimulatedDrive.set_fault`. A test
that needs one at a given moment schedules it by SYNC index
(:meth:`SimulatedDrives.at_sync`), an event in simulated time, not a sleep.

:class:`SimulatedDrives` runs the drives of a machine on one bus in one
thread; :func:`serve` is the blocking form for ``ncmeasure simulate-drive``,
with the CANopen link's settings.

The package, one module each: :mod:`.dictionary` (the objects, their defaults
and the CiA 301 rules of a write), :mod:`.sdo` (the SDO server, abort codes),
:mod:`.drive` (:class:`SimulatedDrive`: NMT, TPDOs on SYNC, fault switches),
:mod:`.drives` (:class:`SimulatedDrives` on one bus, :func:`serve`).
"""

from __future__ import annotations

from ncmeasure.sim.cia402.dictionary import TpdoConfig
from ncmeasure.sim.cia402.drive import OPERATION_ENABLED, DriveScaling, SimulatedDrive
from ncmeasure.sim.cia402.drives import VIRTUAL_BUS_REACH, SimulatedDrives, serve
from ncmeasure.sim.cia402.sdo import (
    ABORT_COMMAND,
    ABORT_GENERAL,
    ABORT_INCOMPATIBLE,
    ABORT_LENGTH_HIGH,
    ABORT_LENGTH_LOW,
    ABORT_NO_DATA,
    ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX,
    ABORT_NOT_MAPPABLE,
    ABORT_PDO_LENGTH,
    ABORT_READ_ONLY,
    ABORT_TOGGLE,
    ABORT_UNSUPPORTED,
    ABORT_VALUE_RANGE,
    ABORT_WRITE_ONLY,
)

__all__ = [
    "ABORT_COMMAND",
    "ABORT_GENERAL",
    "ABORT_INCOMPATIBLE",
    "ABORT_LENGTH_HIGH",
    "ABORT_LENGTH_LOW",
    "ABORT_NOT_MAPPABLE",
    "ABORT_NO_DATA",
    "ABORT_NO_OBJECT",
    "ABORT_NO_SUBINDEX",
    "ABORT_PDO_LENGTH",
    "ABORT_READ_ONLY",
    "ABORT_TOGGLE",
    "ABORT_UNSUPPORTED",
    "ABORT_VALUE_RANGE",
    "ABORT_WRITE_ONLY",
    "OPERATION_ENABLED",
    "VIRTUAL_BUS_REACH",
    "DriveScaling",
    "SimulatedDrive",
    "SimulatedDrives",
    "TpdoConfig",
    "serve",
]
