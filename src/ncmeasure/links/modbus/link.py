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
as ``gap`` events with their number; the cycles skipped because the link fell
behind its schedule are the event's ``skipped_cycles`` (counted in the
recording's ``skipped_share``, as a CANopen producer's). A dropped TCP connection is re-opened
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
the rows are then stamped exactly ``slot × period``. A request then waits for
its answer until it comes, and times out only when the simulated drive says it
stays silent (see :mod:`~ncmeasure.links.modbus.transport`).

The parts: :mod:`~ncmeasure.links.modbus.settings` (the settings models),
:mod:`~ncmeasure.links.modbus.plan` (the requests of a cycle and their
decoding), :mod:`~ncmeasure.links.modbus.transport` (socket or serial port, one
request); this module keeps open/read/close, the polling thread and the
accounting of gaps and outages.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Final

from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError
from ncmeasure.links.base import AxisBinding, AxisLinkSettings, DriveLink, LinkSettings
from ncmeasure.links.modbus.plan import build_plan, poll_rate
from ncmeasure.links.modbus.settings import ModbusAxis, ModbusSettings
from ncmeasure.links.modbus.transport import CycleError, Failure, ModbusTransport
from ncmeasure.samples import Channel, LinkEvent, SampleBlock, SimulatedClock

__all__ = ["CATCH_UP_S", "ModbusLink", "next_slot"]

log = logging.getLogger(__name__)


@dataclass
class _Outage:
    start: float
    failure: Failure
    reconnected: bool = False
    reported: set[tuple[str | None, int | None]] = field(default_factory=set)


@dataclass
class _PendingGap:
    time_s: float
    lost: int
    causes: list[str]
    #: Of ``lost``, the cycles the link skipped because it fell behind its schedule (slow
    #: answers or a stalled computer), as against cycles lost to an outage.
    skipped: int = 0


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
    #: Lockstep: how far (simulated seconds) the polling may run ahead of the reader. What
    #: the reader has not taken when it stops is simulated time gone: a measurement series
    #: that stopped a run at its end found the clock up to 20,000 rows (160 s at 125 Hz)
    #: further on a busy computer, past the next program start.
    MAX_AHEAD_S: ClassVar[float] = 2.0

    def __init__(self, settings: LinkSettings, axes: Sequence[AxisBinding]) -> None:
        super().__init__(settings, axes)
        if not isinstance(settings, ModbusSettings):
            raise ConfigError("the modbus link needs ModbusSettings")
        self.modbus: ModbusSettings = settings
        self._plan = build_plan(settings, self.axes)
        self._poll_hz = poll_rate(settings, self._plan.requests)
        self._period_s = 1.0 / self._poll_hz
        self._transport = ModbusTransport(settings)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._rows: queue.Queue[tuple[float, list[float]] | None] = queue.Queue()
        self._fatal: LinkError | None = None
        self._ended = False
        self._t0 = 0.0
        self._pending_gap: _PendingGap | None = None

    # --- contract -----------------------------------------------------------------------

    @property
    def channels(self) -> tuple[Channel, ...]:
        return self._plan.channels

    @property
    def nominal_period_s(self) -> float:
        return self._period_s

    @property
    def requests_per_cycle(self) -> int:
        """Modbus requests one poll cycle sends (one per axis and register type)."""
        return len(self._plan.requests)

    @property
    def endpoint(self) -> str:
        """``host:port`` or the serial port, for messages."""
        return self._transport.endpoint

    def describe(self) -> dict[str, Any]:
        info = super().describe()
        info["poll_hz"] = self._poll_hz
        info["requests_per_cycle"] = len(self._plan.requests)
        info["time_s"] = (
            "midpoint between sending a poll cycle's first request and "
            "receiving its last answer, s since polling started on the link clock"
        )
        info["register_maps"] = self._plan.describe_maps(self.axes)
        return info

    # --- the recorder's ready signal -------------------------------------------------

    @property
    def signals_ready(self) -> bool:
        """True when an axis names ``ready`` (a coil or register bit)."""
        return any(getattr(b.settings, "ready", None) is not None for b in self.axes)

    def _set_ready(self, on: bool) -> None:
        for binding in self.axes:
            settings = binding.settings
            assert isinstance(settings, ModbusAxis)
            if settings.ready is not None:
                unit = settings.ready.unit_id or settings.unit_id
                self._transport.write_ready(settings.ready, unit, on)
                log.info("ready output %s (axis %s)", "on" if on else "off", binding.name)
                return

    # --- one poll cycle -----------------------------------------------------------------

    def _poll_once(self) -> list[float]:
        row = [0.0] * len(self._plan.channels)
        for request in self._plan.requests:
            self._plan.decode(request, self._transport.execute(request), row)
        return row

    # --- open / read / close ----------------------------------------------------------

    def _open(self) -> None:
        clock = self.clock
        self._transport.lockstep = clock if isinstance(clock, SimulatedClock) else None
        self._transport.connect()
        problems: list[str] = []
        timeouts = 0
        for request in self._plan.requests:
            try:
                self._transport.execute(request)
            except CycleError as exc:
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
        return SampleBlock.from_rows(times, rows, len(self._plan.channels))

    def _close(self) -> None:
        self._stop.set()
        thread = self._thread
        if thread is not None:
            s = self.modbus
            thread.join(
                timeout=(s.retries + 1) * s.timeout_s * max(1, len(self._plan.requests)) + 2
            )
            if thread.is_alive():
                log.warning("modbus polling thread did not stop in time")
        self._flush_gap()
        self._transport.disconnect()

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
                details={
                    "causes": list(dict.fromkeys(gap.causes)),
                    "skipped_cycles": gap.skipped,
                },
            )
        )

    def _note_missing(self, first_slot: int, lost: int, cause: str, skipped: bool) -> None:
        if lost <= 0:
            return
        if self._pending_gap is None:
            self._pending_gap = _PendingGap(first_slot * self._period_s, 0, [])
        self._pending_gap.lost += lost
        if skipped:
            self._pending_gap.skipped += lost
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
            failure: Failure | None = None
            t_start = clock.now()
            if not self._transport.connected():
                if t_start >= next_connect:
                    try:
                        self._transport.connect()
                        if outage is not None:
                            outage.reconnected = True
                    except LinkError as exc:
                        failure = Failure("disconnected", exc.message)
                        next_connect = t_start + reconnect_delay
                else:
                    failure = outage.failure if outage else Failure("disconnected", "not connected")
            row: list[float] | None = None
            if failure is None:
                t_start = clock.now()
                try:
                    row = self._poll_once()
                except CycleError as exc:
                    failure = exc.failure
            now = clock.now()
            if row is not None:
                time_s = 0.5 * (t_start + now) - self._t0
                missed = slot - last_row_slot - 1
                cause = outage.failure.message if outage is not None else late
                self._note_missing(last_row_slot + 1, missed, cause, skipped=outage is None)
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
                if s.mode == "tcp" and failure.kind != "exception" and self._transport.connected():
                    self._transport.disconnect()
                if not self._transport.connected() and next_connect <= now:
                    next_connect = now + (
                        reconnect_delay if failure.kind == "disconnected" else 0.0
                    )
                if now - outage.start >= s.max_outage_s:
                    current = max(slot, math.ceil((now - self._t0) / period))
                    self._note_missing(
                        last_row_slot + 1, current - last_row_slot, failure.message, skipped=False
                    )
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
            if not self._transport.connected() and next_connect > now:
                slot = max(slot, math.ceil((next_connect - self._t0) / period))

    def _wait_for_reader(self) -> bool:
        """Lockstep: hold the next cycle while the reader has many rows to take (more than
        :attr:`MAX_AHEAD_S` of them); False: stop."""
        most = max(1, min(self.MAX_QUEUED_ROWS, math.ceil(self.MAX_AHEAD_S / self._period_s)))
        while self._rows.qsize() >= most:
            if self._stop.wait(0.01):
                return False
        return not self._stop.is_set()

    def _report_failure(self, outage: _Outage, failure: Failure) -> None:
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
