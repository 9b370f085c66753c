"""The simulated Modbus drive: a pymodbus server that serves axis states in a register map.

Each served unit id stands for one axis. When a client reads its registers,
the unit asks a :class:`~ncmeasure.sim.signals.SignalSource` for the axis'
state and encodes it the way the register map says (data type, word order,
scale, unit conversion), so a :class:`~ncmeasure.links.modbus.link.ModbusLink`
reading them gets the source's values quantised by the map. The server takes
the link's own settings models (:mod:`ncmeasure.links.modbus.settings`): it
listens where such a link connects, on the serial line it opens, with the
register maps it reads.

Time: by default the state is taken at the server's elapsed wall-clock time.
With a :class:`~ncmeasure.samples.SimulatedClock` (``clock``) shared with the
link, the server is in lockstep with it: the link sets the simulated time of
each poll cycle before it asks, and every answer shows the state at that time,
however slow the computer is (a server in another process reads the same
clock through shared memory). A request the server leaves unanswered on
purpose (a silent unit) it reports on that clock, so the link's wait for the
answer ends at once, not after a wall-clock time-out. With ``step_s`` the
server is deterministic on its own: the n-th read request a unit answers for a
register type (counting from 0) gets the state at ``n × step_s``. Requests that
are not answered (faults) do not count.

:func:`serve` is the blocking entry point behind ``ncmeasure simulate-drive
--link modbus``; the faults are in :mod:`~ncmeasure.sim.modbus_drive.faults`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from ncmeasure.errors import ConfigError, LinkError
from ncmeasure.formats.axis import StatedMechanics
from ncmeasure.links.modbus.registers import (
    RegisterMap,
    encode_value,
    load_register_map,
    signal_factor,
)
from ncmeasure.links.modbus.settings import ModbusAxis, ModbusMarker, ModbusReady, ModbusSettings
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.modbus_drive.faults import DriveFaults
from ncmeasure.sim.rig import RIG_MECHANICS
from ncmeasure.sim.signals import AxisState, PatternSource, SignalSource

__all__ = [
    "ModbusDriveScaling",
    "ServerInfo",
    "SimulatedModbusDrive",
    "SimulatedUnit",
    "serve",
]

log = logging.getLogger(__name__)

_FUNCTION_OF_CODE = {1: "coil", 2: "discrete", 3: "holding", 4: "input"}


@dataclass(frozen=True)
class SimulatedUnit:
    """One axis served as one Modbus unit.

    Args:
        axis: Axis name (for messages).
        unit_id: Modbus unit id, 1..247.
        register_map: Built-in map name or path of a TOML map.
        axis_index: Which axis of the signal source (0-based).
        mechanics: The axis the unit's drive moves (default: the method's test
            rig, :data:`~ncmeasure.sim.rig.RIG_MECHANICS`): its lead for maps in
            rpm, revolutions or encoder counts, its rated current for maps
            giving current in parts of the rated current.
        counts_per_rev: For maps in encoder counts.
        scales: Per-signal scale replacing the map's scale (as the link's
            ``ModbusAxis.scales``).
        marker: Where the program's marker (``AxisState.marker``) is wired: the
            link's ``ModbusAxis.marker``, an input, coil or register bit of this
            unit, 1 while the marker is set; None: not served.
        ready: The recorder's ready output (the link's ``ModbusAxis.ready``): a coil
            or holding register of this unit a link may write; the written value is
            held (:meth:`SimulatedModbusDrive.outputs`). None: writes are refused.
    """

    axis: str
    unit_id: int
    register_map: str = "generic"
    axis_index: int = 0
    mechanics: StatedMechanics = RIG_MECHANICS
    counts_per_rev: int = 10_000
    scales: Mapping[str, float] = field(default_factory=dict)
    marker: ModbusMarker | None = None
    ready: ModbusReady | None = None


@dataclass(frozen=True)
class ModbusDriveScaling:
    """What a map in motor units needs of the simulated drives (not a link setting).

    Args:
        mechanics: The axis every drive moves (default: the method's test rig,
            :data:`~ncmeasure.sim.rig.RIG_MECHANICS`): its lead for maps in rpm,
            revolutions or encoder counts, its rated current for maps giving
            current in parts of the rated current.
        counts_per_rev: Encoder counts per motor revolution, for maps in counts
            (an axis' ``ModbusAxis.counts_per_rev``, when given, wins).
    """

    mechanics: StatedMechanics = RIG_MECHANICS
    counts_per_rev: int = 10_000


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
    counters: dict[int, int] = field(default_factory=lambda: dict.fromkeys(_FUNCTION_OF_CODE, 0))
    answered: int = 0
    written: dict[str, int] = field(default_factory=dict)
    """The ready output's value as last written: 'coil <address>' or 'holding <address>'."""
    writes: list[int] = field(default_factory=list)
    """Every value written to the ready output, in order."""


_WRITES = {5: "coil", 15: "coil", 6: "holding", 16: "holding"}
"""Write function codes and the tables they write."""


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
            _check_marker(unit, reg_map)
            factors = {
                signal: signal_factor(
                    signal,
                    entry,
                    screw_lead_mm=unit.mechanics.screw_lead_mm,
                    rated_current_a=unit.mechanics.rated_current_a,
                    counts_per_rev=unit.counts_per_rev or reg_map.counts_per_rev,
                    scale=unit.scales.get(signal),
                )
                for signal, entry in reg_map.ordered_signals()
            }
            self._units[unit.unit_id] = _UnitRuntime(unit, reg_map, factors)
        self._start = self._now()
        # unit id (0: any unknown unit) -> whether to say on the clock that the answer
        # being built is not sent (a silent unit, not a dropped connection)
        self._suppress: dict[int, bool] = {}
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
                runtime.counters = dict.fromkeys(_FUNCTION_OF_CODE, 0)
                runtime.answered = 0
            self._start = self._now()

    def stats(self) -> dict[int, int]:
        """Answered read requests per unit id."""
        with self._lock:
            return {uid: rt.answered for uid, rt in self._units.items()}

    def output_writes(self) -> dict[int, list[int]]:
        """Per unit id, every value written to its ready output, in order."""
        with self._lock:
            return {uid: list(rt.writes) for uid, rt in self._units.items()}

    def outputs(self) -> dict[int, dict[str, int]]:
        """Per unit id, the values a link wrote to its ready output
        (``{'coil 40': 1}``, ``{'holding 200': 8}``)."""
        with self._lock:
            return {uid: dict(rt.written) for uid, rt in self._units.items()}

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
        marker = runtime.unit.marker
        if marker is not None and marker.function == function:
            on = state.marker > 0
            if marker.bit is not None:  # a register bit
                words[marker.address] = int(on) << marker.bit
            else:  # a coil or discrete input: bit (address % 16) of register (address // 16)
                words[marker.address // 16] = int(on) << (marker.address % 16)
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
                    self._suppress[unit_id] = not fault.disconnect
                    if fault.disconnect:
                        self._drop_now()
                    return None
                if fault.exception_code is not None:
                    return ExcCodes(fault.exception_code)
            if function_code in _WRITES:
                # pymodbus asks twice for a write: first without the values (the check of the
                # address), then with them; a value of 0 or False comes as it is, not as a list
                if values is None:
                    return self._writable(runtime, function_code)
                return self._write(runtime, function_code, values)
            function = _FUNCTION_OF_CODE.get(function_code)
            if function is None:
                return ExcCodes.ILLEGAL_FUNCTION
            t = self._state_time(runtime, function_code)
            state = self.source.state(runtime.unit.axis_index, t)
            for addr, word in self.registers(unit_id, function, state).items():
                registers[addr - start_address] = word
            return None

        return action

    @staticmethod
    def _writable(runtime: _UnitRuntime, function_code: int) -> ExcCodes | None:
        """None where a write of ``function_code`` reaches the unit's ready output."""
        ready = runtime.unit.ready
        if ready is None or _WRITES.get(function_code) != ready.function:
            return ExcCodes.ILLEGAL_FUNCTION
        return None

    def _write(self, runtime: _UnitRuntime, function_code: int, values: Any) -> ExcCodes | None:
        """A write to the unit's ready output: held; any other write is refused."""
        refused = self._writable(runtime, function_code)
        if refused is not None:
            return refused
        ready = runtime.unit.ready
        assert ready is not None
        first = values[0] if isinstance(values, list | tuple) else values
        value = int(bool(first)) if ready.function == "coil" else int(first)
        with self._lock:
            runtime.written[f"{ready.function} {ready.address}"] = value
            runtime.writes.append(value)
        return None

    def _catch_all(self, rtu: bool) -> Callable[..., Any]:
        async def action(*_: Any) -> ExcCodes | None:
            if rtu:  # nobody answers an unknown unit on a serial line
                self._suppress[0] = True
                return None
            return ExcCodes.GATEWAY_NO_RESPONSE  # what a TCP gateway answers

        return action

    def _devices(self, rtu: bool) -> list[SimDevice]:
        devices: list[SimDevice] = []
        bits = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        for unit_id, runtime in self._units.items():
            blocks: dict[str, list[SimData]] = {"coil": list(bits), "discrete": list(bits)}
            marker = runtime.unit.marker
            if marker is not None and marker.bit is None:
                blocks[marker.function] = [
                    SimData(marker.address // 16, values=[False] * 16, datatype=DataType.BITS)
                ]
            ready = runtime.unit.ready
            if ready is not None and ready.function == "coil":
                if marker is not None and marker.function == "coil" and marker.bit is None:
                    if marker.address // 16 != ready.address // 16:
                        raise ConfigError(
                            f"axis {runtime.unit.axis}: the simulated drive serves the marker "
                            "coil and the ready coil within the same 16 coils only"
                        )
                else:
                    blocks["coil"] = [
                        SimData(ready.address // 16, values=[False] * 16, datatype=DataType.BITS)
                    ]
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
                if marker is not None and marker.function == function:
                    register = SimData(marker.address, values=0, datatype=DataType.REGISTERS)
                    valid = [b for b in blocks[function] if b.datatype != DataType.INVALID]
                    blocks[function] = sorted([*valid, register], key=lambda b: b.address)
                if ready is not None and ready.function == function:
                    register = SimData(ready.address, values=0, datatype=DataType.REGISTERS)
                    valid = [b for b in blocks[function] if b.datatype != DataType.INVALID]
                    blocks[function] = sorted([*valid, register], key=lambda b: b.address)
            devices.append(
                SimDevice(
                    unit_id,
                    simdata=(
                        blocks["coil"],
                        blocks["discrete"],
                        blocks["holding"],
                        blocks["input"],
                    ),
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
                self._left_unanswered(self._suppress.pop(unit))
                return b""  # the answer was built but is never sent
            if 0 in self._suppress and unit not in self._units:
                self._left_unanswered(self._suppress.pop(0))
                return b""
            return data

        return trace

    def _left_unanswered(self, silent: bool) -> None:
        """In lockstep, a silent unit says so on the clock: the link stops waiting at once."""
        if silent and self.clock is not None:
            self.clock.leave_unanswered()

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
        settings: ModbusSettings,
        *,
        free_port: bool = False,
        ready: Callable[[ServerInfo], None] | None = None,
        stop: threading.Event | None = None,
    ) -> None:
        """Serve until ``stop`` is set (or the task is cancelled).

        Args:
            settings: Where a link reading these drives connects: TCP on
                ``host:port``, or RTU on ``serial_port`` with its line settings.
                The units bring their own register maps.
            free_port: TCP: listen on a free port instead of ``settings.port``
                (``ready`` is told which).
            ready: Called with the :class:`ServerInfo` once the server listens.
            stop: Serve until this event is set.

        Raises:
            LinkError: the TCP port is in use or the serial port cannot be opened.
        """
        rtu = settings.mode == "rtu"
        host, serial_port = settings.host, settings.serial_port
        port = 0 if free_port else settings.port
        if not rtu:
            _check_port_free(host, port)
        self._loop = asyncio.get_running_loop()
        if rtu:
            server: ModbusTcpServer | ModbusSerialServer = ModbusSerialServer(
                self._devices(True),
                framer=FramerType.RTU,
                port=str(serial_port),
                baudrate=settings.baudrate,
                parity=settings.parity,
                stopbits=settings.stopbits,
                bytesize=settings.bytesize,
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

    def serve_forever(self, settings: ModbusSettings, **kwargs: Any) -> None:
        """Blocking :meth:`run` in a new event loop; Ctrl-C stops it."""
        with contextlib.suppress(KeyboardInterrupt):
            asyncio.run(self.run(settings, **kwargs))


def _check_marker(unit: SimulatedUnit, reg_map: RegisterMap) -> None:
    """Refuse a marker the simulated unit cannot serve: another unit's, or on a signal."""
    marker = unit.marker
    if marker is None:
        return
    if marker.unit_id not in (None, unit.unit_id):
        raise ConfigError(
            f"axis {unit.axis}: the simulated drive serves the marker on the axis' own unit "
            f"{unit.unit_id}, not on unit {marker.unit_id}"
        )
    for signal, entry in reg_map.ordered_signals():
        if entry.function == marker.function and entry.address <= marker.address <= (
            entry.last_address
        ):
            raise ConfigError(
                f"axis {unit.axis}: the marker's {marker.function} register {marker.address} "
                f"is {signal}'s in register map {reg_map.name}"
            )


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
    settings: ModbusSettings,
    axes: Mapping[str, ModbusAxis],
    *,
    scaling: ModbusDriveScaling | None = None,
    source: SignalSource | None = None,
    step_s: float | None = None,
    free_port: bool = False,
    faults: DriveFaults | None = None,
    ready: Callable[[ServerInfo], None] | None = None,
    stop: threading.Event | None = None,
    clock: SimulatedClock | None = None,
) -> None:
    """Run simulated Modbus drives until interrupted (blocking).

    This is what ``ncmeasure simulate-drive --link modbus --port N --unit X=1``
    calls. The drives are what a :class:`~ncmeasure.links.modbus.link.ModbusLink`
    with the same settings reads: axis ``i`` of ``axes`` is served as its
    ``unit_id`` with its register map (or ``settings.register_map``) and
    shows state ``i`` of the source.

    Args:
        settings: The link settings: TCP ``host``/``port`` or RTU
            ``serial_port`` with ``baudrate``, ``parity``, ``stopbits``,
            ``bytesize``; ``register_map`` of every axis without its own.
        axes: Axis name -> the axis' link settings (``unit_id``,
            ``register_map``, ``counts_per_rev``, ``scales``), in axis order.
        scaling: What maps in motor units need of the drives (their axis'
            mechanics, counts per revolution); default :class:`ModbusDriveScaling`,
            the test rig's axis.
        source: Axis states; default :class:`PatternSource`.
        step_s: Deterministic mode (see the module docstring).
        free_port: TCP: listen on a free port instead of ``settings.port``
            (``ready`` is told which).
        faults: Fault switches to control the server from another thread.
        ready: Called with the :class:`ServerInfo` once the server listens.
        stop: Serve until this event is set.
        clock: A :class:`~ncmeasure.samples.SimulatedClock` shared with the link
            (lockstep); ``None``: wall-clock.

    Raises:
        ConfigError: invalid units or register maps.
        LinkError: the port is in use or the serial port cannot be opened.
    """
    scaling = scaling or ModbusDriveScaling()
    simulated = [
        SimulatedUnit(
            axis,
            link.unit_id,
            link.register_map or settings.register_map,
            index,
            scaling.mechanics,
            link.counts_per_rev or scaling.counts_per_rev,
            {str(signal): scale for signal, scale in link.scales.items()},
            link.marker,
            link.ready,
        )
        for index, (axis, link) in enumerate(axes.items())
    ]
    drive = SimulatedModbusDrive(
        simulated, source=source, step_s=step_s, faults=faults, clock=clock
    )
    drive.serve_forever(settings, free_port=free_port, ready=ready, stop=stop)
