"""A simulated Modbus drive: a pymodbus server that serves axis states in a register map.

Each served unit id stands for one axis. When a client reads its registers,
the unit asks a :class:`~ncmeasure.sim.signals.SignalSource` for the axis'
state and encodes it the way the register map says (data type, word order,
scale, unit conversion), so a :class:`~ncmeasure.links.modbus.link.ModbusLink`
reading them gets the source's values quantised by the map.

Time: by default the state is taken at the server's elapsed wall-clock time.
With a :class:`~ncmeasure.samples.SimulatedClock` (``clock``) shared with the
link, the server is in lockstep with it: the link sets the simulated time of
each poll cycle before it asks, and every answer shows the state at that time,
however slow the computer is (a server in another process reads the same
clock through shared memory). With ``step_s`` the server is deterministic on
its own: the n-th read request a unit answers for a register type (counting
from 0) gets the state at ``n × step_s``. Requests that are not answered
(faults) do not count.

Fault switches (:class:`Fault`, thread-safe through :class:`DriveFaults`):
stop answering, answer with a Modbus exception code, answer late, and drop
the TCP connections. :func:`running_server` runs a server in another process
and controls it through a pipe; :func:`serve` is the blocking entry point
behind ``ncmeasure simulate-drive --link modbus``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from ncmeasure.errors import ConfigError, LinkError
from ncmeasure.links.modbus.registers import (
    RegisterMap,
    encode_value,
    load_register_map,
    signal_factor,
)
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.signals import AxisState, PatternSource, SignalSource

__all__ = [
    "DriveFaults",
    "Fault",
    "ServerHandle",
    "ServerInfo",
    "SimulatedModbusDrive",
    "SimulatedUnit",
    "pty_null_modem",
    "running_server",
    "serve",
]

log = logging.getLogger(__name__)

_FUNCTION_OF_CODE = {3: "holding", 4: "input"}
_VALID_EXCEPTION_CODES = frozenset(int(code) for code in ExcCodes)


@dataclass(frozen=True)
class SimulatedUnit:
    """One axis served as one Modbus unit.

    Args:
        axis: Axis name (for messages).
        unit_id: Modbus unit id, 1..247.
        register_map: Built-in map name or path of a TOML map.
        axis_index: Which axis of the signal source (0-based).
        screw_lead_mm: For maps in rpm, revolutions or encoder counts.
        counts_per_rev: For maps in encoder counts.
        rated_current_a: For maps giving current in parts of the rated current.
    """

    axis: str
    unit_id: int
    register_map: str = "generic"
    axis_index: int = 0
    screw_lead_mm: float = 10.0
    counts_per_rev: int = 10_000
    rated_current_a: float = 10.0


@dataclass(frozen=True)
class Fault:
    """A misbehaviour of the simulated drives.

    Args:
        silent: Read requests get no answer at all.
        exception_code: Answer with this Modbus exception code (1-8, 10, 11).
        delay_s: Answer this late (wall-clock).
        disconnect: Close the TCP connection instead of answering.
        units: The unit ids affected; ``None``: all.
        from_s: The fault starts at this server time (``None``: at once). On a
            :class:`~ncmeasure.samples.SimulatedClock` this is simulated time, so a
            test sets a fault for exactly the poll cycles it means, however slow the
            computer is.
        until_s: The fault ends at this server time (``None``: when cleared).
    """

    silent: bool = False
    exception_code: int | None = None
    delay_s: float = 0.0
    disconnect: bool = False
    units: frozenset[int] | None = None
    from_s: float | None = None
    until_s: float | None = None

    def __post_init__(self) -> None:
        if self.exception_code is not None and self.exception_code not in _VALID_EXCEPTION_CODES:
            known = ", ".join(str(c) for c in sorted(_VALID_EXCEPTION_CODES))
            raise ValueError(f"exception code {self.exception_code} is not one of {known}")
        if self.delay_s < 0:
            raise ValueError("delay_s must not be negative")

    def applies_to(self, unit_id: int, time_s: float | None = None) -> bool:
        """Whether the fault affects ``unit_id`` (at server time ``time_s``, when given)."""
        if self.units is not None and unit_id not in self.units:
            return False
        if time_s is None:
            return True
        return (self.from_s is None or time_s >= self.from_s) and (
            self.until_s is None or time_s < self.until_s
        )


NO_FAULT = Fault()


class DriveFaults:
    """The current fault of a server; safe to change from any thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._fault = NO_FAULT
        self._drop: Callable[[], None] | None = None

    def set(self, fault: Fault) -> None:
        """Replace the current fault."""
        with self._lock:
            self._fault = fault

    def clear(self) -> None:
        """Back to normal answers."""
        self.set(NO_FAULT)

    def current(self) -> Fault:
        """The fault in force."""
        with self._lock:
            return self._fault

    def drop_connections(self) -> None:
        """Close every open TCP connection (clients must reconnect)."""
        with self._lock:
            drop = self._drop
        if drop is not None:
            drop()

    def _attach(self, drop: Callable[[], None] | None) -> None:
        with self._lock:
            self._drop = drop


@dataclass(frozen=True)
class ServerInfo:
    """Where a running server listens."""

    host: str | None
    port: int | None
    serial_port: str | None
    units: Mapping[str, int]

    @property
    def endpoint(self) -> str:
        """``host:port`` or the serial port."""
        return f"{self.host}:{self.port}" if self.port is not None else str(self.serial_port)


@dataclass
class _UnitRuntime:
    unit: SimulatedUnit
    register_map: RegisterMap
    factors: dict[str, float]
    counters: dict[int, int] = field(default_factory=lambda: {3: 0, 4: 0})
    answered: int = 0


class SimulatedModbusDrive:
    """The register side of the simulated drives: units, counters, faults.

    Args:
        units: The axes to serve, one unit id each.
        source: The axis states; default :class:`PatternSource`.
        step_s: Deterministic mode: n-th request of a unit and register type
            gets the state at ``n × step_s``. ``None``: the server time.
        faults: Shared fault switches; a new set when ``None``.
        clock: A :class:`~ncmeasure.samples.SimulatedClock` shared with the link:
            every answer shows the state at the simulated time the link set for
            its poll cycle (lockstep). ``None``: the elapsed wall-clock time.

    Raises:
        ConfigError: a unit id twice or out of range, or an invalid register map.
    """

    def __init__(
        self,
        units: Sequence[SimulatedUnit],
        *,
        source: SignalSource | None = None,
        step_s: float | None = None,
        faults: DriveFaults | None = None,
        clock: SimulatedClock | None = None,
    ) -> None:
        if not units:
            raise ConfigError("the simulated drive needs at least one unit")
        if step_s is not None and not step_s > 0:
            raise ConfigError("step_s must be positive")
        self.source: SignalSource = source or PatternSource()
        self.step_s = step_s
        self.clock = clock
        self.faults = faults or DriveFaults()
        self._lock = threading.Lock()
        self._units: dict[int, _UnitRuntime] = {}
        for unit in units:
            if not 1 <= unit.unit_id <= 247:
                raise ConfigError(f"unit id {unit.unit_id} of axis {unit.axis} is not in 1..247")
            if unit.unit_id in self._units:
                raise ConfigError(f"unit id {unit.unit_id} is given twice")
            reg_map = load_register_map(unit.register_map)
            factors = {
                signal: signal_factor(
                    signal,
                    entry,
                    screw_lead_mm=unit.screw_lead_mm,
                    rated_current_a=unit.rated_current_a,
                    counts_per_rev=unit.counts_per_rev or reg_map.counts_per_rev,
                )
                for signal, entry in reg_map.ordered_signals()
            }
            self._units[unit.unit_id] = _UnitRuntime(unit, reg_map, factors)
        self._start = self._now()
        self._suppress: set[int] = set()
        self._server: ModbusTcpServer | ModbusSerialServer | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def units(self) -> dict[str, int]:
        """Axis name -> unit id."""
        return {rt.unit.axis: uid for uid, rt in self._units.items()}

    def reset(self) -> None:
        """Clear the faults, restart the request counters and the clock."""
        self.faults.clear()
        with self._lock:
            for runtime in self._units.values():
                runtime.counters = {3: 0, 4: 0}
                runtime.answered = 0
            self._start = self._now()

    def stats(self) -> dict[int, int]:
        """Answered read requests per unit id."""
        with self._lock:
            return {uid: rt.answered for uid, rt in self._units.items()}

    def _now(self) -> float:
        return self.clock.now() if self.clock is not None else time.monotonic()

    def _time_s(self) -> float:
        """The server time: the link's simulated time in lockstep, else time since start."""
        if self.clock is not None and self.clock.lockstep:
            return self.clock.now()
        with self._lock:
            start = self._start
        return self._now() - start

    def elapsed_s(self) -> float:
        """The server time (the state time without ``step_s``): the simulated time in
        lockstep, else the time since start or :meth:`reset`."""
        return self._time_s()

    def registers(self, unit_id: int, function: str, state: AxisState) -> dict[int, int]:
        """The registers (address -> value) a unit shows for ``state``."""
        runtime = self._units[unit_id]
        words: dict[int, int] = {}
        for signal, entry in runtime.register_map.ordered_signals():
            if entry.function != function:
                continue
            raw = getattr(state, signal) / runtime.factors[signal]
            for i, word in enumerate(encode_value(raw, entry.type, entry.word_order)):
                words[entry.address + i] = word
        return words

    # --- pymodbus plumbing ----------------------------------------------------------------

    def _state_time(self, runtime: _UnitRuntime, function_code: int) -> float:
        with self._lock:
            count = runtime.counters[function_code]
            runtime.counters[function_code] = count + 1
            runtime.answered += 1
        if self.step_s is not None:
            return count * self.step_s
        return self._time_s()

    def _action(self, unit_id: int) -> Callable[..., Any]:
        runtime = self._units[unit_id]

        async def action(
            function_code: int,
            start_address: int,
            address: int,
            count: int,
            registers: list[int],
            values: Any,
        ) -> ExcCodes | None:
            del address, count
            fault = self.faults.current()
            if fault.applies_to(unit_id, self._time_s()):
                if fault.delay_s > 0:
                    await asyncio.sleep(fault.delay_s)
                if fault.silent or fault.disconnect:
                    self._suppress.add(unit_id)
                    if fault.disconnect:
                        self._drop_now()
                    return None
                if fault.exception_code is not None:
                    return ExcCodes(fault.exception_code)
            function = _FUNCTION_OF_CODE.get(function_code)
            if function is None or values is not None:
                return ExcCodes.ILLEGAL_FUNCTION
            t = self._state_time(runtime, function_code)
            state = self.source.state(runtime.unit.axis_index, t)
            for addr, word in self.registers(unit_id, function, state).items():
                registers[addr - start_address] = word
            return None

        return action

    def _catch_all(self, rtu: bool) -> Callable[..., Any]:
        async def action(*_: Any) -> ExcCodes | None:
            if rtu:  # nobody answers an unknown unit on a serial line
                self._suppress.add(0)
                return None
            return ExcCodes.GATEWAY_NO_RESPONSE  # what a TCP gateway answers

        return action

    def _devices(self, rtu: bool) -> list[SimDevice]:
        devices: list[SimDevice] = []
        bits = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        for unit_id, runtime in self._units.items():
            blocks: dict[str, list[SimData]] = {}
            for function in ("holding", "input"):
                used = [
                    e for _, e in runtime.register_map.ordered_signals() if e.function == function
                ]
                if used:
                    low = min(e.address for e in used)
                    high = max(e.last_address for e in used)
                    blocks[function] = [
                        SimData(
                            low,
                            count=high - low + 1,
                            values=0,
                            datatype=DataType.REGISTERS,
                            readonly=True,
                        )
                    ]
                else:
                    blocks[function] = [SimData(0, datatype=DataType.INVALID)]
            devices.append(
                SimDevice(
                    unit_id,
                    simdata=(list(bits), list(bits), blocks["holding"], blocks["input"]),
                    action=self._action(unit_id),
                )
            )
        devices.append(
            SimDevice(
                0,
                simdata=(
                    list(bits),
                    list(bits),
                    [SimData(0, count=65535, datatype=DataType.REGISTERS)],
                    [SimData(0, count=65535, datatype=DataType.REGISTERS)],
                ),
                action=self._catch_all(rtu),
            )
        )
        return devices

    def _trace_packet(self, rtu: bool) -> Callable[[bool, bytes], bytes]:
        def trace(sending: bool, data: bytes) -> bytes:
            if not sending or not self._suppress or not data:
                return data
            unit = data[0] if rtu else (data[6] if len(data) > 6 else -1)
            if unit in self._suppress:
                self._suppress.discard(unit)
                return b""  # the answer was built but is never sent
            if 0 in self._suppress and unit not in self._units:
                self._suppress.discard(0)
                return b""
            return data

        return trace

    def _drop_now(self) -> None:
        server = self._server
        if server is None:
            return
        for connection in list(server.active_connections.values()):
            with contextlib.suppress(Exception):
                connection.close()

    def _request_drop(self) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self._drop_now)

    async def run(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 5020,
        serial_port: str | None = None,
        baudrate: int = 19200,
        parity: str = "E",
        stopbits: int = 1,
        bytesize: int = 8,
        ready: Callable[[ServerInfo], None] | None = None,
        stop: threading.Event | None = None,
    ) -> None:
        """Serve until ``stop`` is set (or the task is cancelled).

        Raises:
            LinkError: the TCP port is in use or the serial port cannot be opened.
        """
        rtu = serial_port is not None
        if not rtu:
            _check_port_free(host, port)
        self._loop = asyncio.get_running_loop()
        if rtu:
            server: ModbusTcpServer | ModbusSerialServer = ModbusSerialServer(
                self._devices(True),
                framer=FramerType.RTU,
                port=str(serial_port),
                baudrate=baudrate,
                parity=parity,
                stopbits=stopbits,
                bytesize=bytesize,
                trace_packet=self._trace_packet(True),
            )
        else:
            server = ModbusTcpServer(
                self._devices(False), address=(host, port), trace_packet=self._trace_packet(False)
            )
        self._server = server
        try:
            await server.serve_forever(background=True)
        except Exception as exc:  # pyserial and termios raise their own types
            where = serial_port if rtu else f"{host}:{port}"
            raise LinkError(f"the simulated Modbus drive cannot serve on {where}: {exc}") from exc
        if rtu:
            info = ServerInfo(None, None, serial_port, self.units)
        else:
            listener: Any = server.transport
            bound = listener.sockets[0].getsockname()[1]
            info = ServerInfo(host, int(bound), None, self.units)
        self.faults._attach(self._request_drop)
        log.info("simulated Modbus drive serving units %s on %s", self.units, info.endpoint)
        if ready is not None:
            ready(info)
        try:
            while stop is None or not stop.is_set():
                await asyncio.sleep(0.05)
        finally:
            self.faults._attach(None)
            await server.shutdown()  # type: ignore[no-untyped-call]
            self._server = None

    def serve_forever(self, **kwargs: Any) -> None:
        """Blocking :meth:`run` in a new event loop; Ctrl-C stops it."""
        with contextlib.suppress(KeyboardInterrupt):
            asyncio.run(self.run(**kwargs))


def _check_port_free(host: str, port: int) -> None:
    """Fail early and clearly when the TCP port is taken (pymodbus only logs it)."""
    if port == 0:
        return
    probe = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        probe.bind((host, port))
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise LinkError(
            f"the simulated Modbus drive cannot listen on {host}:{port}: {reason.lower()} "
            "(is another server running there? choose another port)"
        ) from exc
    finally:
        probe.close()


def serve(
    *,
    units: Mapping[str, int] | None = None,
    host: str = "127.0.0.1",
    port: int = 5020,
    register_map: str = "generic",
    register_maps: Mapping[str, str] | None = None,
    source: SignalSource | None = None,
    step_s: float | None = None,
    serial_port: str | None = None,
    baudrate: int = 19200,
    parity: str = "E",
    stopbits: int = 1,
    bytesize: int = 8,
    screw_lead_mm: float = 10.0,
    counts_per_rev: int = 10_000,
    rated_current_a: float = 10.0,
    faults: DriveFaults | None = None,
    ready: Callable[[ServerInfo], None] | None = None,
    stop: threading.Event | None = None,
    clock: SimulatedClock | None = None,
) -> None:
    """Run simulated Modbus drives until interrupted (blocking).

    This is what ``ncmeasure simulate-drive --link modbus --port N --unit X=1``
    calls. Axes are served in the order given; axis ``i`` shows state ``i`` of
    the source.

    Args:
        units: Axis name -> unit id; default ``{"X": 1}``.
        host: TCP address to listen on.
        port: TCP port (0: any free port, see ``ready``).
        register_map: Map of every unit (built-in name or TOML path).
        register_maps: Per-axis map replacing ``register_map``.
        source: Axis states; default :class:`PatternSource`.
        step_s: Deterministic mode (see the module docstring).
        serial_port: Serve Modbus RTU on this serial device instead of TCP.
        baudrate: RTU baud rate.
        parity: RTU parity, ``N``, ``E`` or ``O``.
        stopbits: RTU stop bits.
        bytesize: RTU data bits.
        screw_lead_mm: For maps in rpm, revolutions or counts.
        counts_per_rev: For maps in encoder counts.
        rated_current_a: For maps in parts of the rated current.
        faults: Fault switches to control the server from another thread.
        ready: Called with the :class:`ServerInfo` once the server listens.
        stop: Serve until this event is set.
        clock: A :class:`~ncmeasure.samples.SimulatedClock` shared with the link
            (lockstep); ``None``: wall-clock.

    Raises:
        ConfigError: invalid units or register maps.
        LinkError: the port is in use or the serial port cannot be opened.
    """
    unit_map = dict(units or {"X": 1})
    simulated = [
        SimulatedUnit(
            axis,
            unit_id,
            (register_maps or {}).get(axis, register_map),
            index,
            screw_lead_mm,
            counts_per_rev,
            rated_current_a,
        )
        for index, (axis, unit_id) in enumerate(unit_map.items())
    ]
    drive = SimulatedModbusDrive(
        simulated, source=source, step_s=step_s, faults=faults, clock=clock
    )
    drive.serve_forever(
        host=host,
        port=port,
        serial_port=serial_port,
        baudrate=baudrate,
        parity=parity,
        stopbits=stopbits,
        bytesize=bytesize,
        ready=ready,
        stop=stop,
    )


# --- a server in another process ----------------------------------------------------------


@dataclass(frozen=True)
class _ProcessConfig:
    units: tuple[SimulatedUnit, ...]
    source: SignalSource | None
    step_s: float | None
    host: str
    port: int
    clock: SimulatedClock | None = None


def _child_main(config: _ProcessConfig, conn: Connection) -> None:
    """Entry of the server process: serve, and obey commands from the pipe."""
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # this process' own console
    stop = threading.Event()
    try:
        drive = SimulatedModbusDrive(
            config.units, source=config.source, step_s=config.step_s, clock=config.clock
        )
    except ConfigError as exc:
        conn.send(("error", str(exc)))
        return

    def obey() -> None:
        while not stop.is_set():
            try:
                if not conn.poll(0.1):
                    continue
                command, argument = conn.recv()
            except (EOFError, OSError):
                stop.set()
                return
            payload: Any = None
            if command == "fault":
                drive.faults.set(argument)
            elif command == "drop":
                drive.faults.drop_connections()
            elif command == "reset":
                drive.reset()
            elif command == "stats":
                payload = drive.stats()
            elif command == "stop":
                stop.set()
            conn.send(("ok", payload))

    def ready(info: ServerInfo) -> None:
        conn.send(("ready", info.port))
        threading.Thread(target=obey, daemon=True).start()

    try:
        drive.serve_forever(host=config.host, port=config.port, ready=ready, stop=stop)
    except LinkError as exc:
        conn.send(("error", str(exc)))


class ServerHandle:
    """Control of a simulated drive server running in another process."""

    def __init__(
        self,
        process: multiprocessing.process.BaseProcess,
        conn: Connection,
        host: str,
        port: int,
        units: Mapping[str, int],
    ) -> None:
        self.process = process
        self.host = host
        self.port = port
        self.units = dict(units)
        self._conn = conn
        self._lock = threading.Lock()

    def _command(self, command: str, argument: Any = None, timeout_s: float = 10.0) -> Any:
        with self._lock:
            self._conn.send((command, argument))
            if not self._conn.poll(timeout_s):
                raise LinkError(f"the simulated drive did not confirm {command!r}")
            status, payload = self._conn.recv()
        if status != "ok":
            raise LinkError(f"the simulated drive refused {command!r}: {payload}")
        return payload

    def set_fault(self, fault: Fault) -> None:
        """Make the drives misbehave (see :class:`Fault`)."""
        self._command("fault", fault)

    def clear_faults(self) -> None:
        """Back to normal answers."""
        self._command("fault", NO_FAULT)

    def drop_connections(self) -> None:
        """Close every TCP connection the server has open."""
        self._command("drop")

    def reset(self) -> None:
        """Clear faults and restart the request counters and the clock."""
        self._command("reset")

    def stats(self) -> dict[int, int]:
        """Answered read requests per unit id."""
        result: dict[int, int] = self._command("stats")
        return result


_PROCESS_NAME = "ncmeasure-modbus-drive"
_MAIN_REIMPORTED_EXIT = 86
"""Exit code of a drive process that found itself starting a server while importing the
main module (a script without the ``if __name__ == "__main__":`` guard)."""
_MAIN_GUARD = (
    "running_server() was called while the simulated drive process imported your main "
    "module again (multiprocessing starts it with 'spawn', which runs the script's top "
    'level once more): call it under `if __name__ == "__main__":` in the script'
)


def _importing_main_in_child() -> bool:
    """True in a spawned process while it still imports the parent's main module."""
    return bool(getattr(multiprocessing.current_process(), "_inheriting", False))


@contextlib.contextmanager
def running_server(
    units: Mapping[str, int] | Sequence[SimulatedUnit] | None = None,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    register_map: str = "generic",
    source: SignalSource | None = None,
    step_s: float | None = None,
    start_timeout_s: float = 30.0,
    clock: SimulatedClock | None = None,
) -> Iterator[ServerHandle]:
    """A simulated Modbus TCP drive server in another process, for tests and benchmarks.

    Waits until the server accepts connections, yields a :class:`ServerHandle`
    and stops the process afterwards.

    Args:
        units: Axis name -> unit id (all with ``register_map``), or
            :class:`SimulatedUnit` entries; default ``{"X": 1}``.
        host: Address to listen on.
        port: TCP port; 0 picks a free one (``handle.port``).
        register_map: Map for units given by name.
        source: Axis states (must be picklable); default :class:`PatternSource`.
        step_s: Deterministic mode.
        start_timeout_s: How long to wait for the server to listen.
        clock: A :class:`~ncmeasure.samples.SimulatedClock` shared with the link
            (lockstep, through shared memory); ``None``: wall-clock.

    A script that uses it must call it under ``if __name__ == "__main__":``:
    the server process is started with ``spawn``, which imports the script
    again; without the guard this is refused at once with that remedy.

    Raises:
        LinkError: the server did not start (port in use, ...), or the script
            calls it without the ``__main__`` guard.
    """
    if _importing_main_in_child():
        # Inside the new process, importing the script again: starting a server
        # here would fail in multiprocessing's bootstrapping. Leave quietly; the
        # parent sees the exit code and says why.
        raise SystemExit(_MAIN_REIMPORTED_EXIT)
    if units is None:
        units = {"X": 1}
    if isinstance(units, Mapping):
        unit_list = tuple(
            SimulatedUnit(axis, uid, register_map, i) for i, (axis, uid) in enumerate(units.items())
        )
    else:
        unit_list = tuple(units)
    config = _ProcessConfig(unit_list, source, step_s, host, port, clock)
    context = multiprocessing.get_context("spawn")
    parent, child = context.Pipe()
    process = context.Process(
        target=_child_main, args=(config, child), name=_PROCESS_NAME, daemon=True
    )
    process.start()
    child.close()
    try:
        deadline = time.monotonic() + start_timeout_s
        message: tuple[str, Any] | None = None
        while time.monotonic() < deadline:
            if parent.poll(0.1):
                with contextlib.suppress(EOFError, OSError):
                    message = parent.recv()
                break
            if not process.is_alive():
                break
        if message is None:
            process.join(timeout=5)  # a closed pipe comes before the exit code
            if process.exitcode == _MAIN_REIMPORTED_EXIT:
                raise LinkError(_MAIN_GUARD)
            if process.exitcode is None:
                raise LinkError(
                    f"the simulated Modbus drive process did not start within "
                    f"{start_timeout_s:g} s (a script that starts it must do so under "
                    '`if __name__ == "__main__":`, or the process imports it again)'
                )
            raise LinkError(
                f"the simulated Modbus drive process did not start (exit code {process.exitcode})"
            )
        status, payload = message
        if status != "ready":
            raise LinkError(str(payload))
        bound = int(payload)
        _wait_for_port(host, bound, deadline)
        yield ServerHandle(process, parent, host, bound, {u.axis: u.unit_id for u in unit_list})
    finally:
        with contextlib.suppress(OSError, EOFError, ValueError):
            parent.send(("stop", None))
        process.join(timeout=5)
        if process.is_alive():
            process.terminate()
            process.join(timeout=5)
        if process.is_alive():
            process.kill()
            process.join(timeout=5)
        parent.close()


def _wait_for_port(host: str, port: int, deadline: float) -> None:
    while True:
        try:
            with socket.create_connection((host, port), timeout=1.0):
                return
        except OSError as exc:
            if time.monotonic() > deadline:
                raise LinkError(
                    f"the simulated Modbus drive does not answer on {host}:{port}: {exc}"
                ) from exc
            time.sleep(0.05)


# --- a serial null modem for RTU without hardware -----------------------------------------


@contextlib.contextmanager
def pty_null_modem() -> Iterator[tuple[str, str]]:
    """Two pseudo-terminals wired to each other, like a null-modem cable (POSIX).

    Yields the two device paths: a server opens one, a client the other.
    Bytes written to either arrive at the other; the baud rate is not emulated.
    """
    master_a, slave_a = os.openpty()
    master_b, slave_b = os.openpty()
    for fd in (slave_a, slave_b):
        tty.setraw(fd)
    stop = threading.Event()

    def relay() -> None:
        while not stop.is_set():
            try:
                readable, _, _ = select.select([master_a, master_b], [], [], 0.05)
            except (OSError, ValueError):
                return
            for fd in readable:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                with contextlib.suppress(OSError):
                    os.write(master_b if fd == master_a else master_a, data)

    thread = threading.Thread(target=relay, name="ncmeasure-null-modem", daemon=True)
    thread.start()
    try:
        yield os.ttyname(slave_a), os.ttyname(slave_b)
    finally:
        stop.set()
        thread.join(timeout=2)
        for fd in (master_a, slave_a, master_b, slave_b):
            with contextlib.suppress(OSError):
                os.close(fd)
