"""The simulated CiA 402 drives of a machine on one python-can bus, served by one thread.

:class:`SimulatedDrives` gives every SYNC, NMT command and SDO request on the
bus to its drives and sends what they answer. On python-can's ``virtual`` bus
the drives can also answer SYNC *on the bus* (``answer="on_send"``), within
the sender's ``send`` call; in lockstep with a link on a
:class:`~ncmeasure.samples.SimulatedClock` they report every SYNC answered.
:func:`serve` is the blocking form for ``ncmeasure simulate-drive``: it takes
the CANopen link's settings (:class:`~ncmeasure.links.canopen.settings.CanOpenSettings`),
as ``record`` reads them from the machine file.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import queue
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, Self

import can

from ncmeasure.links.canopen.bus import open_bus
from ncmeasure.links.canopen.objects import ObjectMap, load_object_map
from ncmeasure.links.canopen.settings import CanOpenSettings
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.cia402.drive import DriveScaling, SimulatedDrive
from ncmeasure.sim.signals import PatternSource, SignalSource

__all__ = ["VIRTUAL_BUS_REACH", "SimulatedDrives", "serve"]

log = logging.getLogger(__name__)

#: The SYNC counter runs 1.._SYNC_COUNTER_MAX (the largest overflow value of CiA 301 0x1019).
_SYNC_COUNTER_MAX = 240


def _make_drive(
    node_id: int, axis: int, object_map: ObjectMap, scaling: DriveScaling, eds: Path | None
) -> SimulatedDrive:
    if eds is not None:
        return SimulatedDrive.from_eds(eds, node_id, axis, object_map, scaling)
    return SimulatedDrive.builtin(node_id, axis, object_map, scaling)


class _Frame(can.Message):
    """A frame the drives send: a standard data frame whose copy is cheap.

    python-can's virtual bus deep-copies every frame for every receiver, and
    :meth:`can.Message.__deepcopy__` copies its data through :func:`copy.deepcopy`: a
    third of the drives' time per SYNC. The copy here is as deep (new data, the same
    immutable fields).
    """

    __slots__ = ()

    def __deepcopy__(self, memo: dict[int, Any] | None) -> can.Message:
        return can.Message(
            timestamp=self.timestamp,
            arbitration_id=self.arbitration_id,
            is_extended_id=self.is_extended_id,
            is_remote_frame=self.is_remote_frame,
            is_error_frame=self.is_error_frame,
            channel=self.channel,
            dlc=self.dlc,
            data=bytes(self.data),
            is_fd=self.is_fd,
            is_rx=self.is_rx,
            bitrate_switch=self.bitrate_switch,
            error_state_indicator=self.error_state_indicator,
        )


class _AnsweringQueue(queue.Queue[can.Message]):
    """The drives' receive queue on python-can's virtual bus, answering SYNC as it is put.

    The virtual bus delivers a frame by putting a copy into every other bus'
    queue, one after the other, in the sender's thread. Kept behind every other
    queue of the channel (:class:`_DrivesLast`), this one receives the SYNC
    last and answers it at once: the answers reach the others after the SYNC
    and before the sender's next frame.
    """

    def __init__(self, host: SimulatedDrives) -> None:
        super().__init__()
        self.host = host

    def put(self, item: can.Message, block: bool = True, timeout: float | None = None) -> None:
        if self.host.clock is not None:
            # Lockstep: every frame in its turn, so a SYNC never overtakes the NMT
            # command or SDO request sent before it (the drives' thread runs only timers).
            self.host._dispatch(item)
            return
        if (
            item.arbitration_id == 0x080
            and not item.is_extended_id
            and not item.is_remote_frame
            and not item.is_error_frame
        ):
            self.host._answer_on_send(item)
            return
        super().put(item, block, timeout)


class _DrivesLast(list[Any]):
    """A virtual channel's queues, with the drives' answering queues always last."""

    def append(self, item: Any) -> None:
        hooks = sum(isinstance(q, _AnsweringQueue) for q in self)
        self.insert(len(self) - hooks, item)


def _answer_on_the_bus(bus: can.BusABC, host: SimulatedDrives) -> None:
    """Give the drives' virtual bus a queue that answers SYNC as it is put (see above).

    Raises:
        ValueError: Not python-can's virtual bus, or other buses joined the channel
            first (their frames could not be kept ahead of the answers).
    """
    from can.interfaces import virtual

    if not isinstance(bus, virtual.VirtualBus):
        raise ValueError(
            "answering SYNC on the bus needs python-can's virtual bus; "
            f"this is {type(bus).__name__}"
        )
    with virtual.channels_lock:
        channel = bus.channel
        if len(channel) != 1 or channel[0] is not bus.queue:
            raise ValueError(
                "answering SYNC on the bus needs the drives to open the virtual channel "
                f"{bus.channel_id!r} first, before any other bus"
            )
        hook = _AnsweringQueue(host)
        ordered = _DrivesLast([hook])
        virtual.channels[bus.channel_id] = ordered
        bus.channel = ordered
        bus.queue = hook


class SimulatedDrives:
    """The simulated drives of a machine on one bus, served by one thread.

    Use :meth:`start` (a context manager) or :func:`serve`::

        with SimulatedDrives.start("test-bus", {0: 1, 1: 2}, PatternSource()) as drives:
            drives[1].stop_answering()

    Args:
        bus: The bus to serve on.
        drives: The drives, each with its own node id.
        source: Values of the axes.
        period_s: SYNC period used until the master writes 0x1006.
        own_bus: Shut the bus down on :meth:`stop`.
        clock: The link's :class:`~ncmeasure.samples.SimulatedClock`: answer in
            lockstep with it (every SYNC reported done). ``None``: real time.
        answer: ``thread``: the drives' thread answers SYNC as it receives it;
            ``on_send``: the SYNC's sender answers it within its ``send``
            (python-can's virtual bus only, the drives first on the channel); in
            lockstep (``clock``) every frame is answered so, in the order sent, and the
            drives' thread only runs timers (a delayed answer).
    """

    def __init__(
        self,
        bus: can.BusABC,
        drives: Sequence[SimulatedDrive],
        source: SignalSource,
        *,
        period_s: float = 0.004,
        own_bus: bool = False,
        clock: SimulatedClock | None = None,
        answer: Literal["thread", "on_send"] = "thread",
    ) -> None:
        if not drives:
            raise ValueError("no drives to simulate")
        ids = [d.node_id for d in drives]
        if len(set(ids)) != len(ids):
            raise ValueError(f"node ids repeat: {ids}")
        self.bus = bus
        self.drives = tuple(drives)
        self.source = source
        self.period_s = period_s
        self.clock = clock
        self.frames_sent = 0
        """Frames sent on the bus so far (all kinds)."""
        self.late_answers = 0
        """SYNCs answered (their TPDOs sent) after the next SYNC was sent, by the time
        stamps python-can gives the frames: the host ran the drives' thread too late, as a
        real drive never is. The master then sees the frames after the next SYNC and drops
        that cycle (and may doubt the next): a stall of the host, not a fault of the master."""
        self._answered_at: float | None = None
        self.answer_cpu_s = 0.0
        """CPU time the senders' threads spent answering SYNC (``answer="on_send"``)."""
        self._answer = answer
        self._at_sync: dict[int, list[Callable[[], None]]] = {}
        self.started = time.monotonic()
        self._own_bus = own_bus
        self._by_node = {d.node_id: d for d in drives}
        self._sync_count = 0
        self._sync_index = -1
        self._sync_cond = threading.Condition()
        self._stop = threading.Event()
        self._send_lock = threading.Lock()
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._timer_ids = itertools.count()
        self._timer_lock = threading.Lock()
        for drive in drives:
            drive._host = self
        self._thread = threading.Thread(
            target=self._run, name="simulated-cia402-drives", daemon=True
        )

    @classmethod
    def start(
        cls,
        bus_or_channel: can.BusABC | str,
        nodes: Mapping[int, int],
        source: SignalSource | None = None,
        *,
        interface: str | None = "virtual",
        period_s: float = 0.004,
        eds: str | Path | Mapping[int, str | Path] | None = None,
        object_map: str | ObjectMap = "cia402",
        scaling: DriveScaling | Mapping[int, DriveScaling] | None = None,
        bus_options: Mapping[str, Any] | None = None,
        clock: SimulatedClock | None = None,
        answer: Literal["thread", "on_send"] = "thread",
    ) -> SimulatedDrives:
        """Create the drives, open the bus if a channel name is given, and start serving.

        Args:
            bus_or_channel: A python-can bus, or a channel name to open with ``interface``.
            nodes: ``{axis index: node id}``.
            source: Values of the axes (default :class:`PatternSource`).
            interface: python-can interface for a channel name.
            period_s: SYNC period until the master writes 0x1006.
            eds: EDS/DCF file for all drives, or per axis index; None = built-in CiA 402.
            object_map: Object map name/path, or a loaded map.
            scaling: For all drives, or per axis index.
            bus_options: Extra python-can arguments for a channel name.
            clock: The link's :class:`~ncmeasure.samples.SimulatedClock` (lockstep).
            answer: Who answers SYNC (see the class): ``thread`` or ``on_send``.
        """
        the_map = object_map if isinstance(object_map, ObjectMap) else load_object_map(object_map)
        drives = []
        for axis, node_id in nodes.items():
            axis_scaling = (
                scaling.get(axis, DriveScaling())
                if isinstance(scaling, Mapping)
                else (scaling or DriveScaling())
            )
            axis_eds = eds.get(axis) if isinstance(eds, Mapping) else eds
            drives.append(
                _make_drive(
                    node_id,
                    axis,
                    the_map,
                    axis_scaling,
                    Path(axis_eds) if axis_eds is not None else None,
                )
            )
        own = not isinstance(bus_or_channel, can.BusABC)
        if isinstance(bus_or_channel, can.BusABC):
            bus = bus_or_channel
        else:
            kwargs: dict[str, Any] = dict(bus_options or {})
            if interface is not None:
                kwargs["interface"] = interface
            bus = can.Bus(channel=bus_or_channel, **kwargs)
        drives_host = cls(
            bus,
            drives,
            source or PatternSource(),
            period_s=period_s,
            own_bus=own,
            clock=clock,
            answer=answer,
        )
        try:
            drives_host.run()
        except ValueError:
            if own:
                bus.shutdown()
            raise
        return drives_host

    def run(self) -> None:
        """Start serving in the background thread."""
        filters: list[can.typechecking.CanFilter] = [
            {"can_id": 0x000, "can_mask": 0x7FF, "extended": False},
            {"can_id": 0x080, "can_mask": 0x7FF, "extended": False},
            {"can_id": 0x600, "can_mask": 0x780, "extended": False},
        ]
        self.bus.set_filters(filters)
        if self._answer == "on_send":
            _answer_on_the_bus(self.bus, self)
        self._thread.start()

    def __getitem__(self, axis: int) -> SimulatedDrive:
        for drive in self.drives:
            if drive.axis == axis:
                return drive
        raise KeyError(axis)

    def node(self, node_id: int) -> SimulatedDrive:
        """The drive with node id ``node_id``."""
        return self._by_node[node_id]

    @property
    def sync_count(self) -> int:
        """SYNC messages seen since start."""
        return self._sync_count

    @property
    def sync_index(self) -> int:
        """Index of the newest SYNC (its sample time is index × period); -1 before the first."""
        return self._sync_index

    def at_sync(self, index: int, action: Callable[[], None]) -> None:
        """Run ``action`` when SYNC ``index`` arrives, before the drives answer it.

        A fault at a moment of simulated time, e.g.
        ``drives.at_sync(100, drives[1].stop_answering)``.
        """
        with self._sync_cond:
            self._at_sync.setdefault(index, []).append(action)

    def wait_for_sync(self, count: int, timeout_s: float) -> bool:
        """Wait until ``count`` SYNC messages were seen; False on timeout."""
        with self._sync_cond:
            return self._sync_cond.wait_for(lambda: self._sync_count >= count, timeout_s)

    def stop(self) -> None:
        """Stop serving (and shut the bus down if it was opened here). Idempotent."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        if self._own_bus:
            self._own_bus = False
            self.bus.shutdown()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # --- internals --------------------------------------------------------------------

    def _schedule(self, delay_s: float, action: Callable[[], None]) -> None:
        with self._timer_lock:
            heapq.heappush(
                self._timers, (time.monotonic() + delay_s, next(self._timer_ids), action)
            )

    def _send(self, can_id: int, data: bytes, delay_s: float = 0.0) -> None:
        if delay_s > 0:
            self._schedule(delay_s, lambda: self._send(can_id, data))
            return
        message = _Frame(arbitration_id=can_id, data=data, is_extended_id=False)
        try:
            with self._send_lock:
                self.bus.send(message)
                self.frames_sent += 1
        except can.CanError as exc:
            if not self._stop.is_set():
                log.warning("simulated drives: cannot send 0x%03X: %s", can_id, exc)

    def _run_timers(self) -> float:
        """Run due timers; return the time until the next one (at most 50 ms)."""
        while True:
            with self._timer_lock:
                if not self._timers:
                    return 0.05
                due, _, action = self._timers[0]
                wait = due - time.monotonic()
                if wait > 0:
                    return min(wait, 0.05)
                heapq.heappop(self._timers)
            action()

    def _run(self) -> None:
        while not self._stop.is_set():
            wait = self._run_timers()
            try:
                msg = self.bus.recv(wait)
            except (can.CanError, ValueError, OSError):
                if not self._stop.is_set():
                    log.exception("simulated drives: bus failed")
                return
            if msg is not None:
                self._dispatch(msg)

    def _dispatch(self, msg: can.Message) -> None:
        """Give one received frame to the drives: SYNC, NMT or an SDO request."""
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        can_id = msg.arbitration_id
        try:
            if can_id == 0x080:
                answered = self._answered_at
                if answered is not None and msg.timestamp and msg.timestamp < answered:
                    self.late_answers += 1  # the previous SYNC's answer came after this one
                self._on_sync(bytes(msg.data))
                self._answered_at = time.time()
            elif can_id == 0x000 and len(msg.data) >= 2:
                for drive in self.drives:
                    if msg.data[1] in (0, drive.node_id):
                        drive._on_nmt(msg.data[0])
            elif 0x600 < can_id < 0x680:
                target = self._by_node.get(can_id - 0x600)
                if target is not None:
                    target._on_sdo(bytes(msg.data))
        except Exception:  # a simulator bug must not kill the bus for the others
            log.exception("simulated drives: frame 0x%03X not handled", can_id)

    def _answer_on_send(self, message: can.Message) -> None:
        """Answer a SYNC in its sender's thread (``answer="on_send"``)."""
        if self._stop.is_set():
            return
        start = time.thread_time()
        try:
            self._on_sync(bytes(message.data))
        except Exception:  # a simulator bug must not break the sender's send
            log.exception("simulated drives: SYNC not answered")
        self.answer_cpu_s += time.thread_time() - start

    def _on_sync(self, data: bytes = b"") -> None:
        with self._sync_cond:
            index = self._sync_index + 1
            if data and 1 <= data[0] <= _SYNC_COUNTER_MAX:
                index += (data[0] - 1 - index) % _SYNC_COUNTER_MAX
            self._sync_index = index
            self._sync_count += 1
            actions = self._at_sync.pop(index, [])
            self._sync_cond.notify_all()
        for action in actions:
            action()
        frames: list[tuple[int, bytes]] = []
        for drive in self.drives:
            frames += drive._on_sync(index, self.source)
        for can_id, data in frames:
            self._send(can_id, data)
        if self.clock is not None:
            with self._send_lock:
                sent = self.frames_sent
            self.clock.step_done(index, sent)


VIRTUAL_BUS_REACH = (
    "python-can's virtual bus reaches only this process: a `ncmeasure record` in another "
    "terminal cannot see these drives. For two processes use an interface that crosses them, "
    "e.g. --interface socketcan --channel vcan0 (a vcan device: `ip link add dev vcan0 type "
    "vcan && ip link set up vcan0`, as root) or --interface udp_multicast --channel "
    "239.74.163.2 (needs msgpack: pip install 'ncmeasure[udp-multicast]')"
)
"""What to say when simulated drives serve on python-can's in-process ``virtual`` bus."""


def serve(
    settings: CanOpenSettings,
    nodes: Sequence[int] | Mapping[int, int] = (1,),
    *,
    source: SignalSource | None = None,
    scaling: DriveScaling | None = None,
    duration_s: float | None = None,
    stop: threading.Event | None = None,
    on_ready: Callable[[SimulatedDrives], None] | None = None,
) -> int:
    """Simulate drives on a bus until ``duration_s`` passed, ``stop`` is set or Ctrl-C.

    This is what ``ncmeasure simulate-drive --link canopen --interface I --channel C
    --node 1 --node 2 ...`` runs.

    Args:
        settings: The CANopen link's settings, as the link would read these drives:
            ``channel``, ``interface`` (None lets python-can's configuration decide),
            ``bitrate`` (only when it is set; else python-can's default),
            ``bus_options``, ``eds`` (the drives' EDS/DCF file; None = the built-in
            CiA 402 dictionary), ``object_map``, and ``sync_hz`` (the SYNC period
            until the master writes 0x1006).
        nodes: Node ids, axis 0, 1, ... in order; or ``{axis index: node id}``.
        source: Values of the axes (default :class:`PatternSource`).
        scaling: Encoder, lead, rated current, velocity unit of every drive.
        duration_s: Stop after this long; None = until stopped.
        stop: Event that ends serving when set.
        on_ready: Called with the running drives (to print their node ids, ...).

    Returns:
        The number of SYNC messages served.

    Raises:
        ConfigError: python-can knows no such interface.
        LinkError: The interface cannot be opened.
    """
    mapping = dict(nodes) if isinstance(nodes, Mapping) else dict(enumerate(nodes))
    kwargs = settings.bus_kwargs()
    if "bitrate" not in settings.model_fields_set:
        del kwargs["bitrate"]  # python-can's default, as a drive simulator always had
    bus = open_bus(settings.channel, kwargs, "--interface")
    try:
        drives = SimulatedDrives.start(
            bus,
            mapping,
            source,
            period_s=1.0 / settings.sync_hz,
            eds=settings.eds,
            object_map=settings.object_map,
            scaling=scaling,
        )
    except BaseException:
        bus.shutdown()
        raise
    stop = stop or threading.Event()
    deadline = None if duration_s is None else time.monotonic() + duration_s
    try:
        if on_ready is not None:
            on_ready(drives)
        while not stop.is_set():
            remaining = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
            if remaining <= 0:
                break
            stop.wait(remaining)
    except KeyboardInterrupt:
        pass
    finally:
        drives.stop()
        bus.shutdown()
    return drives.sync_count
