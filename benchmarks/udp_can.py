"""A CAN bus between two processes over UDP on 127.0.0.1, for the CANopen benchmark.

python-can's ``virtual`` interface only reaches buses of the same process, so
simulated drives on it share the link's interpreter (and its GIL) — unlike
real drives, which answer from their own hardware. Here the drives run in a
child process and the frames cross over loopback UDP: one datagram per frame
(COB-ID, flags, DLC, data), to the peer and, for a bus that receives its own
messages, first to itself, so its own echo is queued before any answer to the
frame can arrive, as on a real bus.

The drives' side answers whoever sent to it last; the link's side sends to the
drives' port (the channel ``"127.0.0.1:PORT"``). The interface is registered
for python-can under the name :data:`INTERFACE` in this process only
(:func:`register`); nothing of it is part of ncmeasure.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import select
import socket
import struct
import time
from collections.abc import Iterator, Mapping
from multiprocessing.connection import Connection
from typing import Any

import can

INTERFACE = "bench-udp"
_FRAME = struct.Struct("<IBB8s")  # arbitration id, flags, dlc, data
_EXTENDED, _REMOTE, _ERROR = 1, 2, 4


class UdpPeerBus(can.BusABC):
    """One end of a two-process CAN bus over UDP on 127.0.0.1."""

    def __init__(
        self,
        channel: str | None = None,
        receive_own_messages: bool = False,
        **kwargs: Any,
    ) -> None:
        self.channel_info = f"udp {channel or 'listening'}"
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self._socket.bind(("127.0.0.1", 0))
        self._own = self._socket.getsockname()
        self._peer: tuple[str, int] | None = None
        if channel:
            host, _, port = channel.rpartition(":")
            self._peer = (host or "127.0.0.1", int(port))
        self._receive_own = receive_own_messages
        super().__init__(channel=channel, **kwargs)

    @property
    def port(self) -> int:
        return int(self._own[1])

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        flags = (
            (_EXTENDED if msg.is_extended_id else 0)
            | (_REMOTE if msg.is_remote_frame else 0)
            | (_ERROR if msg.is_error_frame else 0)
        )
        datagram = _FRAME.pack(msg.arbitration_id, flags, msg.dlc, bytes(msg.data))
        if self._receive_own:  # the echo first: it is queued before any answer
            self._socket.sendto(datagram, self._own)
        if self._peer is not None:
            self._socket.sendto(datagram, self._peer)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if timeout is not None:
            ready, _, _ = select.select([self._socket], [], [], timeout)
            if not ready:
                return None, False
        try:
            datagram, sender = self._socket.recvfrom(64)
        except OSError:
            return None, False
        own = sender == self._own
        if not own:
            self._peer = sender  # answer whoever spoke last
        arbitration_id, flags, dlc, data = _FRAME.unpack(datagram)
        message = can.Message(
            timestamp=time.time(),
            arbitration_id=arbitration_id,
            is_extended_id=bool(flags & _EXTENDED),
            is_remote_frame=bool(flags & _REMOTE),
            is_error_frame=bool(flags & _ERROR),
            dlc=dlc,
            data=data[:dlc],
            is_rx=not own,
            channel=self.channel_info,
        )
        return message, False

    def fileno(self) -> int:
        return self._socket.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._socket.close()


def register() -> None:
    """Make :data:`INTERFACE` known to python-can (and to ncmeasure's check) in this process."""
    can.interfaces.BACKENDS[INTERFACE] = (__name__, "UdpPeerBus")
    valid = frozenset({*can.interfaces.VALID_INTERFACES, INTERFACE})
    can.interfaces.VALID_INTERFACES = valid
    can.util.VALID_INTERFACES = valid  # type: ignore[attr-defined]  # checked there too


def _serve(nodes: Mapping[int, int], scaling: Any, ready: Connection, stop: Any) -> None:
    from ncmeasure.sim.cia402 import SimulatedDrives
    from ncmeasure.sim.signals import PatternSource

    bus = UdpPeerBus()
    with SimulatedDrives.start(bus, nodes, PatternSource(), scaling=scaling):
        ready.send(bus.port)
        stop.wait()
    bus.shutdown()


@contextlib.contextmanager
def drives_in_a_process(nodes: Mapping[int, int], scaling: Any) -> Iterator[str]:
    """Simulated CiA 402 drives in a child process; yields the channel to reach them."""
    context = multiprocessing.get_context("spawn")
    ours, theirs = context.Pipe()
    stop = context.Event()
    process = context.Process(
        target=_serve, args=(dict(nodes), scaling, theirs, stop), name="bench-drives"
    )
    process.start()
    try:
        if not ours.poll(60):
            raise RuntimeError("the simulated drives' process did not start within 60 s")
        yield f"127.0.0.1:{ours.recv()}"
    finally:
        stop.set()
        process.join(10)
        if process.is_alive():
            process.kill()
            process.join()
