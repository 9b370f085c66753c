"""The Modbus connection of a link: the socket or serial port, and one read request on it.

:class:`ModbusTransport` opens the TCP socket or the serial port itself (so a
failure keeps its reason), hands it to a pymodbus client, and runs one read
request (:meth:`ModbusTransport.execute`): the registers, or a
:class:`CycleError` that says what went wrong (no answer, connection lost, a
Modbus exception response, a malformed answer). On an RTU line it keeps the
3.5-character silence between frames.

In lockstep with ncmeasure's simulated drive (a
:class:`~ncmeasure.samples.SimulatedClock`), an answer is awaited until it
comes, however late a busy computer delivers it; a drive that stays silent on
purpose says so on the clock (:meth:`~ncmeasure.samples.SimulatedClock.leave_unanswered`)
and the wait ends at once. A request then times out in simulated time, not on
the wall clock; the wall-clock wait is only a guard (:data:`LOCKSTEP_GUARD_S`)
against a simulator that is gone.
"""

from __future__ import annotations

import contextlib
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final, Literal

import serial  # type: ignore[import-untyped]
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.pdu import ModbusPDU

from ncmeasure.errors import LinkError
from ncmeasure.links.modbus.plan import Request, rtu_silence_s
from ncmeasure.links.modbus.registers import FUNCTION_NAMES, exception_text
from ncmeasure.links.modbus.settings import ModbusReady, ModbusSettings
from ncmeasure.samples import SimulatedClock

__all__ = ["LOCKSTEP_GUARD_S", "CycleError", "Failure", "ModbusTransport"]

#: In lockstep, the longest wall-clock wait for an answer (and a connection): a guard
#: against a simulated drive that is gone or hangs, never part of the simulation.
LOCKSTEP_GUARD_S: Final = 60.0

#: In lockstep, how often the wait for an answer looks whether the drive said it is silent.
_WATCH_S: Final = 0.002


@dataclass(frozen=True)
class Failure:
    """Why a request (and so its poll cycle) failed."""

    kind: Literal["timeout", "disconnected", "exception", "error"]
    message: str
    axis: str | None = None
    code: int | None = None


class CycleError(Exception):
    """A request of a poll cycle failed; :attr:`failure` says how."""

    def __init__(self, failure: Failure) -> None:
        super().__init__(failure.message)
        self.failure = failure


class ModbusTransport:
    """The socket or serial port of a link, and the pymodbus client that speaks on it.

    Args:
        settings: The link's settings (endpoint, serial line, time-out, retries).
    """

    def __init__(self, settings: ModbusSettings) -> None:
        self.settings = settings
        #: Set before the first :meth:`connect` to wait for answers in lockstep.
        self.lockstep: SimulatedClock | None = None
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._last_rx = 0.0
        # one request on the line at a time: the polling thread's, or a write's
        self._lock = threading.Lock()

    @property
    def endpoint(self) -> str:
        """``host:port`` or the serial port, for messages."""
        if self.settings.mode == "tcp":
            return f"{self.settings.host}:{self.settings.port}"
        return str(self.settings.serial_port)

    @property
    def _wait_s(self) -> float:
        """How long to wait for an answer on the wall clock."""
        return LOCKSTEP_GUARD_S if self.lockstep is not None else self.settings.timeout_s

    def _make_client(self) -> ModbusTcpClient | ModbusSerialClient:
        s = self.settings
        clock = self.lockstep
        if s.mode == "tcp":
            if clock is not None:
                return _LockstepTcpClient(
                    clock, s.host, port=s.port, timeout=self._wait_s, retries=s.retries
                )
            return ModbusTcpClient(s.host, port=s.port, timeout=s.timeout_s, retries=s.retries)
        line: dict[str, Any] = {
            "baudrate": s.baudrate,
            "bytesize": s.bytesize,
            "parity": s.parity,
            "stopbits": s.stopbits,
            "timeout": self._wait_s,
            "retries": s.retries,
        }
        if clock is not None:
            return _LockstepSerialClient(clock, str(s.serial_port), **line)
        return ModbusSerialClient(str(s.serial_port), **line)

    def connect(self) -> None:
        """Open the socket or serial port ourselves, so a failure keeps its reason.

        Raises:
            LinkError: the host cannot be reached or the port cannot be opened.
        """
        s = self.settings
        client = self._client or self._make_client()
        self._client = client
        if isinstance(client, ModbusTcpClient):
            try:
                sock = socket.create_connection((s.host, s.port), timeout=self._wait_s)
            except OSError as exc:
                reason = exc.strerror or str(exc) or type(exc).__name__
                raise LinkError(
                    f"cannot connect to the Modbus TCP server {s.host}:{s.port}: {reason}"
                ) from exc
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client.socket = sock
        else:
            try:
                port = serial.serial_for_url(
                    str(s.serial_port),
                    baudrate=s.baudrate,
                    bytesize=s.bytesize,
                    parity=s.parity,
                    stopbits=s.stopbits,
                    timeout=self._wait_s,
                    write_timeout=self._wait_s,
                )
            except (serial.SerialException, OSError, ValueError) as exc:
                raise LinkError(f"cannot open the serial port {s.serial_port}: {exc}") from exc
            port.inter_byte_timeout = client.inter_byte_timeout or None
            client.socket = port

    def connected(self) -> bool:
        """True while the socket or port is open."""
        return self._client is not None and self._client.socket is not None

    def disconnect(self) -> None:
        """Close the socket or port; never raises."""
        if self._client is not None:
            with contextlib.suppress(Exception):
                self._client.close()  # type: ignore[no-untyped-call]

    def write_ready(self, ready: ModbusReady, unit_id: int, on: bool) -> None:
        """Set the ready output: write the coil, or read the holding register, change its
        bit and write it back (the other bits as they were).

        Raises:
            LinkError: not connected, no answer, or an exception response.
        """
        where = f"{ready.function} {ready.address} of unit {unit_id}"
        with self._lock:
            client = self._client
            if client is None or client.socket is None:
                raise LinkError(f"cannot set the ready output ({where}): not connected")
            try:
                if ready.function == "coil":
                    response: ModbusPDU = client.write_coil(ready.address, on, device_id=unit_id)
                else:
                    assert ready.bit is not None  # ModbusReady requires it
                    read = client.read_holding_registers(ready.address, count=1, device_id=unit_id)
                    if read.isError() or not read.registers:
                        code = int(getattr(read, "exception_code", 0))
                        raise LinkError(
                            f"cannot read the ready output ({where}): {exception_text(code)}"
                        )
                    mask = 1 << ready.bit
                    old = int(read.registers[0])
                    value = old | mask if on else old & ~mask
                    response = client.write_register(ready.address, value, device_id=unit_id)
            except (ModbusException, OSError, ValueError, struct.error) as exc:
                raise LinkError(f"cannot set the ready output ({where}): {exc}") from exc
            finally:
                self._last_rx = time.monotonic()
        if response.isError():
            code = int(getattr(response, "exception_code", 0))
            raise LinkError(f"cannot set the ready output ({where}): {exception_text(code)}")

    def execute(self, request: Request) -> list[int]:
        """Send ``request`` and return the registers of the answer.

        Raises:
            CycleError: not connected, no valid answer within the time-out, the
                connection lost, a Modbus exception response, a short answer.
        """
        with self._lock:
            return self._execute(request)

    def _execute(self, request: Request) -> list[int]:
        client = self._client
        if client is None or client.socket is None:
            raise CycleError(Failure("disconnected", f"not connected to {self.endpoint}"))
        if self.settings.mode == "rtu":
            # The line must stay silent 3.5 characters between frames.
            wait = self._last_rx + rtu_silence_s(self.settings) - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        try:
            if request.function == "holding":
                response: ModbusPDU = client.read_holding_registers(
                    request.address, count=request.count, device_id=request.unit_id
                )
            elif request.function == "discrete":
                response = client.read_discrete_inputs(
                    request.address, count=request.count, device_id=request.unit_id
                )
            elif request.function == "coil":
                response = client.read_coils(
                    request.address, count=request.count, device_id=request.unit_id
                )
            else:
                response = client.read_input_registers(
                    request.address, count=request.count, device_id=request.unit_id
                )
        except ConnectionException as exc:
            raise CycleError(
                Failure(
                    "disconnected",
                    f"connection to {self.endpoint} lost (closed by the other end)",
                    request.axis,
                )
            ) from exc
        except ModbusIOException as exc:
            raise CycleError(
                Failure(
                    "timeout",
                    f"no valid answer to {request.describe()} within {self.settings.timeout_s:g} s",
                    request.axis,
                )
            ) from exc
        except (ModbusException, OSError, ValueError, struct.error) as exc:
            raise CycleError(
                Failure("error", f"{request.describe()} failed: {exc}", request.axis)
            ) from exc
        finally:
            self._last_rx = time.monotonic()
        if response.isError():
            code = int(getattr(response, "exception_code", 0))
            last = request.address + request.count - 1
            raise CycleError(
                Failure(
                    "exception",
                    f"unit {request.unit_id} (axis {request.axis}) answered "
                    f"{FUNCTION_NAMES[request.function]} {request.address}..{last} with "
                    f"{exception_text(code)}",
                    request.axis,
                    code,
                )
            )
        if request.function in ("discrete", "coil"):  # bits, padded to whole bytes
            registers = [int(bit) for bit in response.bits[: request.count]]
        else:
            registers = list(response.registers)
        if len(registers) < request.count:
            raise CycleError(
                Failure(
                    "error",
                    f"{request.describe()}: {len(registers)} registers instead of "
                    f"{request.count} in the answer",
                    request.axis,
                )
            )
        return registers


# --- lockstep: answers awaited until they come, or until the drive says it is silent -----


class _AnswerWatch:
    """Whether the answer to the request sent last will come (lockstep)."""

    def __init__(self, clock: SimulatedClock) -> None:
        self._clock = clock
        self._unanswered = clock.unanswered()

    def sent(self) -> None:
        """A request goes out now: the drive has left none of its own unanswered yet."""
        self._unanswered = self._clock.unanswered()

    def coming(self, arrived: Callable[[float], bool]) -> bool:
        """Wait until ``arrived(wait_s)`` says bytes are there; False: none will come.

        None will come when the simulated drive has said so on the clock, or (a
        guard) after :data:`LOCKSTEP_GUARD_S` of wall-clock time.
        """
        deadline = time.monotonic() + LOCKSTEP_GUARD_S
        while not arrived(_WATCH_S):
            if self._clock.unanswered() != self._unanswered or time.monotonic() > deadline:
                return False
        return True


class _LockstepTcpClient(ModbusTcpClient):
    """A TCP client that waits for an answer until it comes or the drive says it is silent."""

    def __init__(self, clock: SimulatedClock, host: str, **kwargs: Any) -> None:
        super().__init__(host, **kwargs)
        self._watch = _AnswerWatch(clock)

    def send(self, request: bytes, addr: tuple[Any, ...] | None = None) -> int:
        self._watch.sent()
        return int(super().send(request, addr))

    def recv(self, size: int | None) -> bytes:
        sock = self.socket
        if sock is not None and not self._watch.coming(
            lambda wait_s: bool(select.select([sock], [], [], wait_s)[0])
        ):
            return b""  # pymodbus: no answer (a time-out)
        return bytes(super().recv(size))


class _LockstepSerialClient(ModbusSerialClient):
    """A serial client that waits for an answer until it comes or the drive says it is silent."""

    def __init__(self, clock: SimulatedClock, port: str, **kwargs: Any) -> None:
        super().__init__(port, **kwargs)
        self._watch = _AnswerWatch(clock)

    def send(self, request: bytes, addr: tuple[Any, ...] | None = None) -> int:
        self._watch.sent()
        return int(super().send(request, addr))

    def recv(self, size: int | None) -> bytes:
        if self.socket is not None and not self._watch.coming(self._input_waiting):
            return b""  # pymodbus: no answer (a time-out)
        return bytes(super().recv(size))

    def _input_waiting(self, wait_s: float) -> bool:
        port = self.socket
        if port is None or port.in_waiting:
            return True  # bytes to read (or a closed port, for pymodbus to report)
        time.sleep(wait_s)
        return False
