"""An SLCAN (Lawicel) USB-CAN adapter on a loopback TCP socket, bridged to a virtual bus.

python-can's ``slcan`` interface opens ``socket://127.0.0.1:PORT`` through pyserial's
``serial_for_url``, so this emulator stands where a CANable, USBtin or Lawicel adapter
would: it speaks the ASCII protocol (``O``/``L``/``C`` open and close, ``S<n>``/``s``
bit rate, ``V``/``N`` version and serial number, ``t<id><dlc><data>`` frames, ``\\r``
for ok, ``\\a`` for an error) and, like those adapters, never returns the host's own
frames. Frames go between the socket and a python-can ``virtual`` channel, where
simulated CiA 402 drives live.

Faults are injected per SYNC cycle and COB-ID (``faults[(cycle, cob_id)]``): ``drop``
(never forwarded), ``double`` (forwarded twice), ``late`` (held and forwarded after
the next SYNC arrived from the host, before the drives see it). The cycle is the number
of SYNCs forwarded so far, minus one: the drives' SYNC index.

Lockstep: :meth:`drive_clock` is the clock to give the drives. They report each SYNC
answered to it; the emulator reports the step to the link's clock only once it has
forwarded what they sent, with the number of frames the link will receive (drops and
doubles counted, held frames in the step in which they go out).
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Mapping
from types import TracebackType
from typing import Literal, Self

import can

from ncmeasure.samples import SimulatedClock

Fault = Literal["drop", "double", "late"]


class _Relay(SimulatedClock):
    """The drives' clock: their step reports go to the emulator, not to the link."""

    def __init__(self, adapter: SlcanAdapter) -> None:
        super().__init__()
        self._adapter = adapter

    def step_done(self, step: int, frames_sent: int) -> None:
        self._adapter._drives_done(step, frames_sent)


class SlcanAdapter:
    """The emulated adapter; a context manager. ``url`` is the channel for python-can."""

    def __init__(
        self,
        channel: str,
        faults: Mapping[tuple[int, int], Fault] | None = None,
        clock: SimulatedClock | None = None,
    ) -> None:
        self.faults = dict(faults or {})
        self._clock = clock
        self._bus = can.Bus(interface="virtual", channel=channel)
        self._server = socket.create_server(("127.0.0.1", 0))
        self._server.settimeout(0.1)
        self.url = f"socket://127.0.0.1:{self._server.getsockname()[1]}"
        self._conn: socket.socket | None = None
        self._lock = threading.Condition()
        self._stop = threading.Event()
        self.opened = False
        self.commands: list[str] = []
        self.syncs = 0
        """SYNCs forwarded to the drives."""
        self.handled = 0
        """Frames read from the drives' bus and forwarded (or dropped, held)."""
        self.forwarded = 0
        """Frames written to the host."""
        self.injected: list[tuple[int, int, Fault]] = []
        self._held: list[can.Message] = []
        self._threads = [
            threading.Thread(target=self._serve_host, name="slcan-host", daemon=True),
            threading.Thread(target=self._serve_bus, name="slcan-bus", daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def drive_clock(self) -> SimulatedClock:
        """The clock for the simulated drives (lockstep through the emulator)."""
        return _Relay(self)

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5.0)
        if self._conn is not None:
            self._conn.close()
        self._server.close()
        self._bus.shutdown()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # --- the host side: the ASCII protocol --------------------------------------------

    def _serve_host(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            conn.settimeout(0.1)
            with self._lock:
                if self._conn is not None:
                    self._conn.close()
                self._conn = conn
            self._read_commands(conn)

    def _read_commands(self, conn: socket.socket) -> None:
        buffer = b""
        while not self._stop.is_set():
            try:
                chunk = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not chunk:
                return
            buffer += chunk
            while b"\r" in buffer:
                line, buffer = buffer.split(b"\r", 1)
                self._command(line.decode("ascii"))

    def _command(self, line: str) -> None:
        if not line:
            return
        kind = line[0]
        if kind in "tT":
            if not self.opened:
                self._write(b"\a")
                return
            self._write(b"\r")  # the Lawicel "ok" (some adapters say z\r)
            extended = kind == "T"
            id_len = 8 if extended else 3
            can_id = int(line[1 : 1 + id_len], 16)
            dlc = int(line[1 + id_len])
            data = bytes.fromhex(line[2 + id_len : 2 + id_len + 2 * dlc])
            if can_id == 0x80 and not extended:
                self._release_held()  # a late frame: after the next SYNC, before its answers
                with self._lock:
                    self.syncs += 1
            self._bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=extended))
            return
        self.commands.append(line)
        if kind in "OL":
            self.opened = True
        elif kind == "C":
            self.opened = False
        if kind == "V":
            self._write(b"V1013\r")
        elif kind == "N":
            self._write(b"NA123\r")
        elif kind in "OLCSsZ":
            self._write(b"\r")
        else:
            self._write(b"\a")

    def _write(self, data: bytes) -> None:
        with self._lock:
            conn = self._conn
            if conn is None:
                return
            with contextlib.suppress(OSError):  # the host went away
                conn.sendall(data)

    # --- the bus side -----------------------------------------------------------------

    def _serve_bus(self) -> None:
        while not self._stop.is_set():
            msg = self._bus.recv(0.05)
            if msg is not None:
                self._forward(msg)
                with self._lock:
                    self.handled += 1
                    self._lock.notify_all()

    def _forward(self, msg: can.Message) -> None:
        with self._lock:
            cycle = self.syncs - 1
        fault = self.faults.get((cycle, msg.arbitration_id)) if cycle >= 0 else None
        if fault is not None:
            self.injected.append((cycle, msg.arbitration_id, fault))
        if fault == "drop":
            return
        if fault == "late":
            with self._lock:
                self._held.append(msg)
            return
        for _ in range(2 if fault == "double" else 1):
            self._send_frame(msg)

    def _send_frame(self, msg: can.Message) -> None:
        if not self.opened:
            return
        line = f"t{msg.arbitration_id:03X}{msg.dlc}{bytes(msg.data).hex().upper()}\r"
        with self._lock:
            self.forwarded += 1
        self._write(line.encode("ascii"))

    def _release_held(self) -> None:
        with self._lock:
            held, self._held = self._held, []
        for msg in held:
            self._send_frame(msg)

    def _drives_done(self, step: int, frames_sent: int) -> None:
        """Lockstep (the drives' thread): the step is done once its frames were handled."""
        with self._lock:
            self._lock.wait_for(lambda: self.handled >= frames_sent or self._stop.is_set(), 30.0)
            forwarded = self.forwarded
        if self._clock is not None:
            self._clock.step_done(step, forwarded)
