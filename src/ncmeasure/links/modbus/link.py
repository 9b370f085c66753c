"""The Modbus link: polls drive monitor registers over Modbus TCP or Modbus RTU.

Each axis is one Modbus unit (``unit_id``) whose registers are described by a
*register map*: a TOML file per drive type that says where current, velocity
and position live (address, holding or input register, data type, word order)
and how a raw value becomes A, mm/min or mm. Maps ship in
``ncmeasure/links/registermaps/`` (see :func:`builtin_register_maps`); a map
can also be a path to a user's own file. :func:`load_register_map` validates a
map strictly: overlapping registers, 32-bit values running past 65535, unknown
types or units are a :class:`~ncmeasure.errors.ConfigError` naming the file and
the entry.

A polling thread runs one *poll cycle* per poll period: for every axis, one
read request per register type covering all of that axis' signals of the type.
A cycle whose requests all succeed becomes one row; its ``time_s`` is the
midpoint between sending the cycle's first request and receiving its last
answer, in seconds since the link started polling. Cycles
that fail or are skipped because answers were late are missing rows, reported
as ``gap`` events with their number. A dropped TCP connection is re-opened
(``reconnect`` event); Modbus exception responses come back as ``fault`` events
with their meaning; after ``max_outage_s`` without a complete cycle the link
gives up with :class:`~ncmeasure.errors.LinkError`. See ``docs/modbus.md``.

Time is kept by the link's :class:`~ncmeasure.samples.LinkClock`: the
poll period, the time stamps, outage durations, the reconnect delay and
``max_outage_s`` are on that clock; the request timeout and the RTU line
silences are wall-clock time. Real time for real drives. With ncmeasure's own
simulated drive it runs on a :class:`~ncmeasure.samples.SimulatedClock`, in
lockstep: before each poll cycle the link sets the simulated time to
``slot × period``, the server answers with the machine state of that time, and
the next cycle follows when this one is done, however slow the computer is;
the rows are then stamped exactly ``slot × period``.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import socket
import struct
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar, Final, Literal

import serial  # type: ignore[import-untyped]
from pydantic import Field, ValidationInfo, field_validator, model_validator
from pydantic_core import PydanticCustomError
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.pdu import ModbusPDU

from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError
from ncmeasure.links.base import AxisBinding, AxisLinkSettings, DriveLink, LinkSettings
from ncmeasure.links.modbus.registers import (
    FUNCTION_NAMES,
    STRUCT,
    RegisterMap,
    exception_text,
    load_register_map,
    signal_factor,
)
from ncmeasure.samples import SIGNAL_UNITS, Channel, LinkEvent, SampleBlock, SimulatedClock

__all__ = ["ModbusAxis", "ModbusLink", "ModbusSettings"]

log = logging.getLogger(__name__)

# --- settings ---------------------------------------------------------------------------


class ModbusSettings(LinkSettings):
    """The ``[link]`` table of a Modbus link."""

    type: Literal["modbus"] = "modbus"
    mode: Literal["tcp", "rtu"] = Field(
        default="tcp",
        description="Modbus TCP (Ethernet, gateway) or Modbus RTU (serial line); "
        "default: rtu when a serial_port is given, else tcp.",
    )
    host: str = Field(default="127.0.0.1", min_length=1, description="TCP: drive or gateway.")
    port: Annotated[int, Field(ge=1, le=65535)] = Field(default=502, description="TCP port.")
    serial_port: str | None = Field(
        default=None,
        validate_default=True,
        description="RTU: device path (/dev/ttyUSB0, COM3) or pyserial URL.",
    )
    baudrate: Annotated[int, Field(ge=300, le=4_000_000)] = 19200
    parity: Literal["N", "E", "O"] = "E"
    stopbits: Literal[1, 2] = 1
    bytesize: Literal[7, 8] = 8
    register_map: str = Field(
        min_length=1, description="Built-in register map name or path of a TOML map."
    )
    poll_hz: Annotated[float, Field(gt=0, le=10_000)] = Field(
        default=100.0, description="Poll cycles per second (rows per second)."
    )
    timeout_s: Annotated[float, Field(gt=0, le=60)] = Field(
        default=0.5, description="How long to wait for an answer."
    )
    retries: Annotated[int, Field(ge=0, le=10)] = Field(
        default=1, description="Repetitions of an unanswered request within a cycle."
    )
    reconnect_delay_s: Annotated[float, Field(ge=0, le=60)] = Field(
        default=0.5, description="Wait before re-opening a lost connection or port."
    )
    max_outage_s: Annotated[float, Field(gt=0, le=3600)] = Field(
        default=10.0, description="Give up after this long without a complete poll cycle."
    )

    @model_validator(mode="before")
    @classmethod
    def _serial_port_means_rtu(cls, data: Any) -> Any:
        # A serial port given without a mode is a serial line: never poll TCP instead.
        if isinstance(data, dict) and "mode" not in data and data.get("serial_port"):
            return {**data, "mode": "rtu"}
        return data

    @field_validator("serial_port")
    @classmethod
    def _check_serial_port(cls, value: str | None, info: ValidationInfo) -> str | None:
        mode = info.data.get("mode")
        if mode == "rtu" and not value:
            raise PydanticCustomError("serial_port", "required when mode is 'rtu'")
        if mode == "tcp" and value:
            raise PydanticCustomError(
                "serial_port",
                "a serial port is for mode 'rtu', but mode is 'tcp': set mode = 'rtu' (or "
                "leave mode out) to use the serial line, or leave serial_port out for TCP",
            )
        return value


class ModbusAxis(AxisLinkSettings):
    """The ``link`` table of an axis on a Modbus link."""

    unit_id: Annotated[int, Field(ge=1, le=247)] = Field(
        description="Modbus unit (slave) id of the axis' drive."
    )
    register_map: str | None = Field(
        default=None, min_length=1, description="Register map of this axis' drive."
    )
    counts_per_rev: Annotated[int, Field(gt=0)] | None = Field(
        default=None, description="Encoder counts per motor revolution ('counts' units)."
    )
    scales: dict[
        Literal["current_a", "velocity_mm_min", "position_mm", "velocity_cmd_mm_min"], float
    ] = Field(default_factory=dict, description="Per-signal scale replacing the map's scale.")

    @field_validator("scales")
    @classmethod
    def _check_scales(cls, value: dict[str, float]) -> dict[str, float]:
        for number in value.values():
            if not math.isfinite(number) or number == 0:
                raise PydanticCustomError("scale", "scales must be finite numbers other than 0")
        return value


# --- the poll plan ----------------------------------------------------------------------


@dataclass(frozen=True)
class _FieldPlan:
    column: int
    offset: int
    words: int
    fmt: str
    little: bool
    factor: float


@dataclass(frozen=True)
class _Request:
    axis: str
    unit_id: int
    function: Literal["holding", "input"]
    address: int
    count: int
    fields: tuple[_FieldPlan, ...]

    def describe(self) -> str:
        last = self.address + self.count - 1
        return (
            f"{FUNCTION_NAMES[self.function]} {self.address}..{last} from unit "
            f"{self.unit_id} (axis {self.axis})"
        )


@dataclass(frozen=True)
class _Failure:
    kind: Literal["timeout", "disconnected", "exception", "error"]
    message: str
    axis: str | None = None
    code: int | None = None


class _CycleError(Exception):
    def __init__(self, failure: _Failure) -> None:
        super().__init__(failure.message)
        self.failure = failure


@dataclass
class _Outage:
    start: float
    failure: _Failure
    reconnected: bool = False
    reported: set[tuple[str | None, int | None]] = field(default_factory=set)


@dataclass
class _PendingGap:
    time_s: float
    lost: int
    causes: list[str]


def _rtu_char_s(settings: ModbusSettings) -> float:
    bits = 1 + settings.bytesize + (0 if settings.parity == "N" else 1) + settings.stopbits
    return bits / settings.baudrate


def _rtu_silence_s(settings: ModbusSettings) -> float:
    # Modbus over serial line V1.02, 2.5.1.1: 3.5 characters, fixed 1.75 ms above 19200 baud.
    return 3.5 * _rtu_char_s(settings) if settings.baudrate <= 19200 else 0.00175


#: Margin on the bare RTU frame times for the drives' own answer delay.
RTU_MARGIN = 1.25


#: How far behind its schedule a paced link still polls every cycle (catching up back
#: to back) after a stall of the computer or a slow answer; cycles further behind are
#: skipped and reported as a gap.
CATCH_UP_S: Final = 0.05


def next_slot(slot: int, now: float, catch_up: float) -> int:
    """The poll cycle to run after cycle ``slot``, ``now`` in poll periods since the start.

    Never a wait before a cycle that is due already. The cycles due within the
    last ``catch_up`` periods are polled back to back (each row has its own time
    stamp, so a stall of the computer costs no row where polling can go faster
    than the pace); only cycles further behind are skipped. ``catch_up`` 0: the
    next cycle is the newest one due.
    """
    return max(slot + 1, math.floor(now - catch_up))


class ModbusLink(DriveLink):
    """Drive signals read by polling Modbus TCP or RTU registers."""

    name: ClassVar[str] = "modbus"
    settings_model: ClassVar[type[LinkSettings]] = ModbusSettings
    axis_settings_model: ClassVar[type[AxisLinkSettings]] = ModbusAxis
    #: Lockstep: rows the link may hold before the next poll cycle waits for the reader.
    MAX_QUEUED_ROWS: ClassVar[int] = 20_000

    def __init__(self, settings: LinkSettings, axes: Sequence[AxisBinding]) -> None:
        super().__init__(settings, axes)
        if not isinstance(settings, ModbusSettings):
            raise ConfigError("the modbus link needs ModbusSettings")
        self.modbus: ModbusSettings = settings
        problems: list[str] = []
        maps: dict[str, RegisterMap] = {}
        self._maps: dict[str, RegisterMap] = {}
        self._factors: dict[str, dict[str, float]] = {}
        used_units: dict[int, str] = {}
        channels: list[Channel] = []
        requests: list[_Request] = []
        for index, binding in enumerate(self.axes):
            axis_settings = binding.settings
            if not isinstance(axis_settings, ModbusAxis):
                raise ConfigError(f"axes[{index}].link: not Modbus axis settings")
            if axis_settings.unit_id in used_units:
                problems.append(
                    f"axes[{index}].link.unit_id: unit {axis_settings.unit_id} is already "
                    f"used by axis {used_units[axis_settings.unit_id]}"
                )
            used_units[axis_settings.unit_id] = binding.name
            map_name = axis_settings.register_map or settings.register_map
            where = (
                f"axes[{index}].link.register_map"
                if axis_settings.register_map
                else "link.register_map"
            )
            try:
                if map_name not in maps:
                    maps[map_name] = load_register_map(map_name)
            except ConfigError as exc:
                problems.append(f"{where}: {exc.message}")
                problems += [f"  {line}" for line in exc.problems]
                continue
            reg_map = maps[map_name]
            self._maps[binding.name] = reg_map
            factors: dict[str, float] = {}
            counts = axis_settings.counts_per_rev or reg_map.counts_per_rev
            for signal, entry in reg_map.ordered_signals():
                try:
                    factors[signal] = signal_factor(
                        signal,
                        entry,
                        screw_lead_mm=binding.axis.screw_lead_mm,
                        rated_current_a=binding.axis.rated_current_a,
                        counts_per_rev=counts,
                        scale=axis_settings.scales.get(signal),  # type: ignore[call-overload]
                    )
                except ValueError as exc:
                    key, _, message = str(exc).partition(": ")
                    loc = (
                        f"axes[{index}].link.{key}"
                        if key == "counts_per_rev"
                        else f"axes[{index}].{key}"
                    )
                    problems.append(f"{loc}: {message} ({reg_map.name})")
            for signal in axis_settings.scales:
                if signal not in reg_map.signals:
                    problems.append(
                        f"axes[{index}].link.scales.{signal}: register map "
                        f"{reg_map.name} has no {signal}"
                    )
            self._factors[binding.name] = factors
            first_column = len(channels)
            signals = [s for s, _ in reg_map.ordered_signals()]
            channels += [Channel(binding.name, s, SIGNAL_UNITS[s]) for s in signals]
            for function in ("holding", "input"):
                entries = [
                    (first_column + i, s, e)
                    for i, (s, e) in enumerate(reg_map.ordered_signals())
                    if e.function == function
                ]
                if not entries:
                    continue
                low = min(e.address for _, _, e in entries)
                high = max(e.last_address for _, _, e in entries)
                fields = tuple(
                    _FieldPlan(
                        column,
                        e.address - low,
                        e.words,
                        STRUCT[e.type],
                        e.word_order == "little",
                        factors.get(s, e.scale),
                    )
                    for column, s, e in entries
                )
                requests.append(
                    _Request(
                        binding.name, axis_settings.unit_id, function, low, high - low + 1, fields
                    )
                )
        if problems:
            raise ConfigError("the settings of the modbus link are not valid", problems)
        self._channels = tuple(channels)
        self._requests = tuple(requests)
        self._poll_hz = self._check_timing(settings)
        self._period_s = 1.0 / self._poll_hz
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._rows: queue.Queue[tuple[float, list[float]] | None] = queue.Queue()
        self._fatal: LinkError | None = None
        self._ended = False
        self._t0 = 0.0
        self._last_rx = 0.0
        self._pending_gap: _PendingGap | None = None

    # --- timing -------------------------------------------------------------------------

    def _rtu_cycle_s(self) -> float:
        """Shortest RTU poll cycle: request and answer frames plus silent intervals."""
        char_s = _rtu_char_s(self.modbus)
        silence = _rtu_silence_s(self.modbus)
        total = 0.0
        for request in self._requests:
            chars = 8 + 5 + 2 * request.count  # request frame + answer frame
            total += chars * char_s + 2 * silence
        return total * RTU_MARGIN

    def _check_timing(self, settings: ModbusSettings) -> float:
        if settings.mode != "rtu":
            return settings.poll_hz
        cycle_s = self._rtu_cycle_s()
        max_hz = 1.0 / cycle_s
        if settings.poll_hz <= max_hz:
            return settings.poll_hz
        why = (
            f"{len(self._requests)} request(s) per cycle at {settings.baudrate} baud need "
            f"{cycle_s * 1000:.1f} ms per cycle (frames, 3.5-character silences and "
            f"{RTU_MARGIN:g}x margin), so at most {max_hz:.1f} Hz"
        )
        if "poll_hz" in settings.model_fields_set or max_hz < 1.0:
            raise ConfigError(
                "the modbus link cannot poll that fast",
                [
                    f"link.poll_hz: {settings.poll_hz:g} Hz is too fast: {why}; "
                    "lower poll_hz or raise the baud rate"
                ],
            )
        adjusted = math.floor(max_hz * 10) / 10 if max_hz < 10 else math.floor(max_hz)
        log.warning(
            "modbus link: poll rate lowered from the default %g Hz to %g Hz: %s",
            settings.poll_hz,
            adjusted,
            why,
        )
        return float(adjusted)

    # --- contract -----------------------------------------------------------------------

    @property
    def channels(self) -> tuple[Channel, ...]:
        return self._channels

    @property
    def nominal_period_s(self) -> float:
        return self._period_s

    @property
    def requests_per_cycle(self) -> int:
        """Modbus requests one poll cycle sends (one per axis and register type)."""
        return len(self._requests)

    @property
    def endpoint(self) -> str:
        """``host:port`` or the serial port, for messages."""
        if self.modbus.mode == "tcp":
            return f"{self.modbus.host}:{self.modbus.port}"
        return str(self.modbus.serial_port)

    def describe(self) -> dict[str, Any]:
        info = super().describe()
        info["poll_hz"] = self._poll_hz
        info["requests_per_cycle"] = len(self._requests)
        info["time_s"] = (
            "midpoint between sending a poll cycle's first request and "
            "receiving its last answer, s since polling started on the link clock"
        )
        maps: dict[str, Any] = {}
        for binding in self.axes:
            reg_map = self._maps[binding.name]
            maps[binding.name] = {
                "name": reg_map.name,
                "drive": reg_map.drive,
                "source": reg_map.source.model_dump(mode="json"),
                "signals": {
                    signal: {
                        **entry.model_dump(mode="json"),
                        "factor": self._factors[binding.name][signal],
                    }
                    for signal, entry in reg_map.ordered_signals()
                },
            }
        info["register_maps"] = maps
        return info

    # --- connection ---------------------------------------------------------------------

    def _make_client(self) -> ModbusTcpClient | ModbusSerialClient:
        s = self.modbus
        if s.mode == "tcp":
            return ModbusTcpClient(s.host, port=s.port, timeout=s.timeout_s, retries=s.retries)
        return ModbusSerialClient(
            str(s.serial_port),
            baudrate=s.baudrate,
            bytesize=s.bytesize,
            parity=s.parity,
            stopbits=s.stopbits,
            timeout=s.timeout_s,
            retries=s.retries,
        )

    def _connect(self) -> None:
        """Open the socket or serial port ourselves, so a failure keeps its reason."""
        s = self.modbus
        client = self._client or self._make_client()
        self._client = client
        if isinstance(client, ModbusTcpClient):
            try:
                sock = socket.create_connection((s.host, s.port), timeout=s.timeout_s)
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
                    timeout=s.timeout_s,
                    write_timeout=s.timeout_s,
                )
            except (serial.SerialException, OSError, ValueError) as exc:
                raise LinkError(f"cannot open the serial port {s.serial_port}: {exc}") from exc
            port.inter_byte_timeout = client.inter_byte_timeout or None
            client.socket = port

    def _connected(self) -> bool:
        return self._client is not None and self._client.socket is not None

    def _disconnect(self) -> None:
        if self._client is not None:
            with contextlib.suppress(Exception):
                self._client.close()  # type: ignore[no-untyped-call]

    # --- one poll cycle -----------------------------------------------------------------

    def _execute(self, request: _Request) -> list[int]:
        client = self._client
        if client is None or client.socket is None:
            raise _CycleError(_Failure("disconnected", f"not connected to {self.endpoint}"))
        if self.modbus.mode == "rtu":
            # The line must stay silent 3.5 characters between frames.
            wait = self._last_rx + _rtu_silence_s(self.modbus) - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        try:
            if request.function == "holding":
                response: ModbusPDU = client.read_holding_registers(
                    request.address, count=request.count, device_id=request.unit_id
                )
            else:
                response = client.read_input_registers(
                    request.address, count=request.count, device_id=request.unit_id
                )
        except ConnectionException as exc:
            raise _CycleError(
                _Failure(
                    "disconnected",
                    f"connection to {self.endpoint} lost (closed by the other end)",
                    request.axis,
                )
            ) from exc
        except ModbusIOException as exc:
            raise _CycleError(
                _Failure(
                    "timeout",
                    f"no valid answer to {request.describe()} within {self.modbus.timeout_s:g} s",
                    request.axis,
                )
            ) from exc
        except (ModbusException, OSError, ValueError, struct.error) as exc:
            raise _CycleError(
                _Failure("error", f"{request.describe()} failed: {exc}", request.axis)
            ) from exc
        finally:
            self._last_rx = time.monotonic()
        if response.isError():
            code = int(getattr(response, "exception_code", 0))
            last = request.address + request.count - 1
            raise _CycleError(
                _Failure(
                    "exception",
                    f"unit {request.unit_id} (axis {request.axis}) answered "
                    f"{FUNCTION_NAMES[request.function]} {request.address}..{last} with "
                    f"{exception_text(code)}",
                    request.axis,
                    code,
                )
            )
        registers = list(response.registers)
        if len(registers) < request.count:
            raise _CycleError(
                _Failure(
                    "error",
                    f"{request.describe()}: {len(registers)} registers instead of "
                    f"{request.count} in the answer",
                    request.axis,
                )
            )
        return registers

    def _poll_once(self) -> list[float]:
        row = [0.0] * len(self._channels)
        for request in self._requests:
            registers = self._execute(request)
            for plan in request.fields:
                words = registers[plan.offset : plan.offset + plan.words]
                if plan.little:
                    words.reverse()
                data = b"".join(w.to_bytes(2, "big") for w in words)
                row[plan.column] = struct.unpack(plan.fmt, data)[0] * plan.factor
        return row

    # --- open / read / close ----------------------------------------------------------

    def _open(self) -> None:
        self._connect()
        problems: list[str] = []
        timeouts = 0
        for request in self._requests:
            try:
                self._execute(request)
            except _CycleError as exc:
                problems.append(exc.failure.message)
                timeouts += exc.failure.kind == "timeout"
                if exc.failure.kind == "disconnected":
                    break
        if problems:
            message = f"the drives behind {self.endpoint} do not answer as the register maps expect"
            if timeouts == len(problems):
                raise LinkTimeoutError(
                    message + " (check unit ids, wiring and baud rate)", problems
                )
            raise LinkError(message, problems)
        self._stop.clear()
        self._t0 = self.clock.now()
        self._thread = threading.Thread(target=self._run, name="ncmeasure-modbus-poll", daemon=True)
        self._thread.start()
        if self._poll_hz != self.modbus.poll_hz:
            self._event(
                LinkEvent(
                    0.0,
                    "info",
                    f"poll rate {self._poll_hz:g} Hz instead of "
                    f"{self.modbus.poll_hz:g} Hz: the RTU line at "
                    f"{self.modbus.baudrate} baud is not faster",
                )
            )

    def _read(self, timeout_s: float) -> SampleBlock | None:
        if self._ended and self._rows.empty():
            raise self._fatal or LinkError("the modbus polling stopped")
        try:
            first = self._rows.get(timeout=timeout_s)
        except queue.Empty:
            return self.empty_block()
        items = [first]
        with contextlib.suppress(queue.Empty):
            while True:
                items.append(self._rows.get_nowait())
        times: list[float] = []
        rows: list[list[float]] = []
        for item in items:
            if item is None:  # the polling thread ended
                self._ended = True
            else:
                times.append(item[0])
                rows.append(item[1])
        if not rows:
            raise self._fatal or LinkError("the modbus polling stopped")
        return SampleBlock.from_rows(times, rows, len(self._channels))

    def _close(self) -> None:
        self._stop.set()
        thread = self._thread
        if thread is not None:
            s = self.modbus
            thread.join(timeout=(s.retries + 1) * s.timeout_s * max(1, len(self._requests)) + 2)
            if thread.is_alive():
                log.warning("modbus polling thread did not stop in time")
        self._flush_gap()
        self._disconnect()

    # --- the polling thread -------------------------------------------------------------

    def _now_s(self) -> float:
        """Link time since polling started."""
        return self.clock.now() - self._t0

    def now_s(self) -> float | None:
        """The link time now, on the time axis of the rows; None before polling starts."""
        return self._now_s() if self._thread is not None else None

    def _flush_gap(self) -> None:
        gap = self._pending_gap
        if gap is None or gap.lost <= 0:
            return
        self._pending_gap = None
        causes = "; ".join(dict.fromkeys(gap.causes))
        self._event(
            LinkEvent(
                gap.time_s,
                "gap",
                f"{gap.lost} poll cycles without data: {causes}",
                lost_samples=gap.lost,
                details={"causes": list(dict.fromkeys(gap.causes))},
            )
        )

    def _note_missing(self, first_slot: int, lost: int, cause: str) -> None:
        if lost <= 0:
            return
        if self._pending_gap is None:
            self._pending_gap = _PendingGap(first_slot * self._period_s, 0, [])
        self._pending_gap.lost += lost
        if not self._pending_gap.causes or self._pending_gap.causes[-1] != cause:
            self._pending_gap.causes.append(cause)

    def _run(self) -> None:
        try:
            self._poll_loop()
        except Exception as exc:  # a bug must not leave the reader waiting forever
            log.exception("modbus polling thread failed")
            self._fatal = LinkError(f"the modbus polling failed: {exc}")
        finally:
            self._rows.put(None)

    def _poll_loop(self) -> None:
        s = self.modbus
        clock = self.clock
        period = self._period_s
        reconnect_delay = s.reconnect_delay_s  # in link seconds
        slot = 0
        last_row_slot = -1
        outage: _Outage | None = None
        next_connect = 0.0
        catch_up = CATCH_UP_S / period
        late = (
            f"poll cycles took longer than the poll period of {period * 1000:.3g} ms (slow answers)"
        )
        while not self._stop.is_set():
            if isinstance(clock, SimulatedClock):
                # Lockstep: this cycle is the machine at slot × period, however long it takes.
                if not self._wait_for_reader():
                    break
                clock.advance_to(self._t0 + slot * period)
            delay = self._t0 + slot * period - clock.now()
            if delay > 0 and self._stop.wait(clock.wall(delay)):
                break
            failure: _Failure | None = None
            t_start = clock.now()
            if not self._connected():
                if t_start >= next_connect:
                    try:
                        self._connect()
                        if outage is not None:
                            outage.reconnected = True
                    except LinkError as exc:
                        failure = _Failure("disconnected", exc.message)
                        next_connect = t_start + reconnect_delay
                else:
                    failure = (
                        outage.failure if outage else _Failure("disconnected", "not connected")
                    )
            row: list[float] | None = None
            if failure is None:
                t_start = clock.now()
                try:
                    row = self._poll_once()
                except _CycleError as exc:
                    failure = exc.failure
            now = clock.now()
            if row is not None:
                time_s = 0.5 * (t_start + now) - self._t0
                missed = slot - last_row_slot - 1
                cause = outage.failure.message if outage is not None else late
                self._note_missing(last_row_slot + 1, missed, cause)
                gap = self._pending_gap
                if gap is not None and (
                    outage is not None or missed == 0 or time_s - gap.time_s >= 1.0
                ):
                    self._flush_gap()
                if outage is not None:
                    self._end_outage(outage, time_s)
                    outage = None
                self._rows.put((time_s, row))
                last_row_slot = slot
            else:
                assert failure is not None
                if outage is None:
                    outage = _Outage(now, failure)
                outage.failure = failure
                self._report_failure(outage, failure)
                # TCP: a late answer must not be taken for the next request's: start afresh.
                if s.mode == "tcp" and failure.kind != "exception" and self._connected():
                    self._disconnect()
                if not self._connected() and next_connect <= now:
                    next_connect = now + (
                        reconnect_delay if failure.kind == "disconnected" else 0.0
                    )
                if now - outage.start >= s.max_outage_s:
                    current = max(slot, math.ceil((now - self._t0) / period))
                    self._note_missing(last_row_slot + 1, current - last_row_slot, failure.message)
                    self._flush_gap()
                    error_type = LinkTimeoutError if failure.kind == "timeout" else LinkError
                    self._fatal = error_type(
                        f"the modbus link gave up after {s.max_outage_s:g} s without a complete "
                        f"poll cycle: {failure.message}"
                    )
                    self._event(
                        LinkEvent(now - self._t0, "fault", self._fatal.message, axis=failure.axis)
                    )
                    return
            # After a complete cycle the link catches up on the cycles of a short stall; after
            # a failed one (an outage) the cycles missed are skipped.
            now = clock.now()
            slot = next_slot(slot, (now - self._t0) / period, catch_up if row is not None else 0.0)
            if not self._connected() and next_connect > now:
                slot = max(slot, math.ceil((next_connect - self._t0) / period))

    def _wait_for_reader(self) -> bool:
        """Lockstep: hold the next cycle while the reader has many rows to take; False: stop."""
        while self._rows.qsize() >= self.MAX_QUEUED_ROWS:
            if self._stop.wait(0.01):
                return False
        return not self._stop.is_set()

    def _report_failure(self, outage: _Outage, failure: _Failure) -> None:
        key = (failure.axis, failure.code)
        if failure.kind != "exception" or key in outage.reported:
            return
        outage.reported.add(key)
        self._event(
            LinkEvent(
                self._now_s(),
                "fault",
                failure.message,
                axis=failure.axis,
                details={"exception_code": failure.code},
            )
        )

    def _end_outage(self, outage: _Outage, time_s: float) -> None:
        duration = self.clock.now() - outage.start
        if outage.reconnected:
            self._event(
                LinkEvent(
                    time_s,
                    "reconnect",
                    f"reconnected to {self.endpoint} after "
                    f"{duration:.2f} s ({outage.failure.message})",
                )
            )
        elif outage.failure.kind == "exception":
            self._event(
                LinkEvent(
                    time_s,
                    "info",
                    f"axis {outage.failure.axis} answers again after {duration:.2f} s",
                    axis=outage.failure.axis,
                )
            )
