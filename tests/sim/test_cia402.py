"""The simulated CiA 402 drive, driven by canopen's own master on python-can's virtual bus.

These tests do not use ncmeasure's link, so a mistake shared by the link and
the simulator cannot hide. Every test has its own channel; every wait is bounded.
"""

from __future__ import annotations

import struct
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from ncmeasure.errors import ConfigError
from ncmeasure.links.canopen.objects import load_object_map
from ncmeasure.links.canopen.settings import CanOpenSettings
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.cia402 import (
    OPERATION_ENABLED,
    DriveScaling,
    SimulatedDrive,
    SimulatedDrives,
    serve,
)
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.signals import PatternSource
from tests.conftest import shared_fixture

SOURCE = PatternSource()
SCALING = DriveScaling(
    mechanics=rig_mechanics(screw_lead_mm=10.0, rated_current_a=5.0), increments_per_rev=4096
)
PERIOD_S = 0.002
TIMEOUT_S = 60.0
"""A guard against a hang, never part of what a test asserts."""
ANSWER_S = 30.0
"""How long an SDO client waits for an answer that comes: a guard, however busy the host."""
SILENT_S = 0.3
"""How long an SDO client waits for an answer that does not come (a silent drive)."""


@pytest.fixture
def channel() -> str:
    # no digits at the end: python-can's BLF writer reads them as a channel number
    return f"ncm-sim-{uuid.uuid4().hex}-bus"


@pytest.fixture
def drives(channel: str) -> Iterator[SimulatedDrives]:
    with SimulatedDrives.start(
        channel, {0: 1, 1: 2}, SOURCE, scaling=SCALING, period_s=PERIOD_S
    ) as sim:
        yield sim


@pytest.fixture
def network(channel: str) -> Iterator[canopen.Network]:
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.1
    net.connect(interface="virtual", channel=channel)
    try:
        yield net
    finally:
        net.disconnect()


def node(network: canopen.Network, node_id: int = 1) -> canopen.RemoteNode:
    remote = canopen.RemoteNode(node_id, canopen.ObjectDictionary())  # type: ignore[no-untyped-call]
    remote.sdo.RESPONSE_TIMEOUT = ANSWER_S
    network.add_node(remote)
    return remote


def eventually(condition: Callable[[], bool], timeout_s: float = TIMEOUT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.002)
    return True


def u32(value: int) -> bytes:
    return struct.pack("<I", value)


def configure_tpdo(remote: canopen.RemoteNode, number: int, entries: list[int]) -> None:
    comm, mapping = 0x1800 + number - 1, 0x1A00 + number - 1
    cob = 0x180 + 0x100 * (number - 1) + (remote.id or 0)
    remote.sdo.download(comm, 1, u32(cob | 0x80000000))
    remote.sdo.download(comm, 2, b"\x01")
    remote.sdo.download(mapping, 0, b"\x00")
    for sub, entry in enumerate(entries, start=1):
        remote.sdo.download(mapping, sub, u32(entry))
    remote.sdo.download(mapping, 0, bytes([len(entries)]))
    remote.sdo.download(comm, 1, u32(cob))


class Frames(can.Listener):
    """Collects frames with given CAN ids (thread-safe enough for tests)."""

    def __init__(self, ids: set[int]) -> None:
        self.ids = ids
        self.frames: list[can.Message] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id in self.ids:
            self.frames.append(msg)


# --- SDO ---------------------------------------------------------------------------------


def test_sdo_expedited_and_segmented(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network)
    assert remote.sdo.upload(0x1000, 0) == u32(0x00020192)
    assert remote.sdo.upload(0x6075, 0) == u32(5000)  # rated current in mA
    remote.sdo.download(0x1017, 0, struct.pack("<H", 250))
    assert remote.sdo.upload(0x1017, 0) == struct.pack("<H", 250)
    remote.sdo.download(0x1017, 0, struct.pack("<H", 77), force_segment=True)
    assert drives[0].value(0x1017) == struct.pack("<H", 77)
    assert remote.sdo.upload(0x1008, 0) == b"ncmeasure CiA 402 drive"  # segmented upload
    assert drives[0].sdo_writes == 2


@pytest.mark.parametrize(
    ("action", "code"),
    [
        (lambda r: r.sdo.download(0x6041, 0, b"\x00\x00"), 0x06010002),  # read-only
        (lambda r: r.sdo.upload(0x5000, 0), 0x06020000),  # no such object
        (lambda r: r.sdo.upload(0x1018, 9), 0x06090011),  # no such sub-index
        (lambda r: r.sdo.download(0x1017, 0, b"\x01\x02\x03\x04"), 0x06070012),  # too long
        (lambda r: r.sdo.download(0x1A00, 1, u32(0x60640020)), 0x06010000),  # PDO still valid
    ],
)
def test_sdo_aborts_like_a_drive(
    drives: SimulatedDrives,
    network: canopen.Network,
    action: Callable[[canopen.RemoteNode], object],
    code: int,
) -> None:
    remote = node(network)
    with pytest.raises(SdoAbortedError) as info:
        action(remote)
    assert info.value.code == code


def test_pdo_mapping_rules(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network)
    remote.sdo.download(0x1800, 1, u32(0x80000181))
    remote.sdo.download(0x1A00, 1, u32(0x60640020))
    remote.sdo.download(0x1A00, 0, b"\x01")
    with pytest.raises(SdoAbortedError) as info:  # entries change only while the count is 0
        remote.sdo.download(0x1A00, 2, u32(0x60410010))
    assert info.value.code == 0x06010000
    remote.sdo.download(0x1A00, 0, b"\x00")
    remote.sdo.download(0x1A00, 1, u32(0x60750020))  # rated current: not mappable
    with pytest.raises(SdoAbortedError) as info:
        remote.sdo.download(0x1A00, 0, b"\x01")
    assert info.value.code == 0x06040041
    for sub in range(1, 4):
        remote.sdo.download(0x1A00, sub, u32(0x60640020))
    with pytest.raises(SdoAbortedError) as info:  # 96 bits
        remote.sdo.download(0x1A00, 0, b"\x03")
    assert info.value.code == 0x06040042
    remote.sdo.download(0x1800, 1, u32(0x181))
    with pytest.raises(SdoAbortedError) as info:  # a valid PDO keeps its COB-ID
        remote.sdo.download(0x1800, 1, u32(0x1A1))
    assert info.value.code == 0x06090030


# --- PDOs on SYNC -----------------------------------------------------------------------


def test_tpdos_on_sync_carry_the_source_encoded_like_a_drive(
    drives: SimulatedDrives, network: canopen.Network
) -> None:
    remote = node(network, 2)
    configure_tpdo(remote, 1, [0x60640020, 0x60410010])
    configure_tpdo(remote, 2, [0x606C0020, 0x60780010])
    frames = Frames({0x182, 0x282})
    network.notifier.add_listener(frames)  # type: ignore[union-attr]
    remote.nmt.state = "OPERATIONAL"
    assert eventually(lambda: drives[1].nmt_state == "OPERATIONAL")
    for _ in range(20):
        network.sync.transmit()
        time.sleep(0.001)
    assert eventually(lambda: len(frames.frames) == 40)
    tpdo1 = [f for f in frames.frames if f.arbitration_id == 0x182]
    tpdo2 = [f for f in frames.frames if f.arbitration_id == 0x282]
    for index, (f1, f2) in enumerate(zip(tpdo1, tpdo2, strict=True)):
        state = SOURCE.state(1, index * PERIOD_S)
        position, status = struct.unpack("<iH", f1.data)
        velocity, current = struct.unpack("<ih", f2.data)
        assert position == round(state.position_mm / 10.0 * 4096)
        assert status == OPERATION_ENABLED
        assert velocity == round(state.velocity_mm_min / 60 / 10.0 * 4096)
        assert current == round(state.current_a / 5.0 * 1000)
    assert drives.sync_count == 20


def test_a_sync_answered_after_the_next_one_was_sent_counts_as_late(
    drives: SimulatedDrives, channel: str
) -> None:
    """What a stalled host does to the simulation: a SYNC's answer goes out after the
    next SYNC. The SYNCs carry their send time stamps (python-can's), here set by hand:
    the second one was sent, by its stamp, before the first was answered."""
    now = time.time()
    sender = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    try:
        for count, stamp in enumerate((now - 100, now - 200, now + 1000, now + 2000), 1):
            sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
            sync.timestamp = stamp
            sender.send(sync)
            assert eventually(lambda count=count: drives.sync_count == count)
    finally:
        sender.shutdown()
    assert drives.late_answers == 1


def test_drives_answering_on_the_bus_put_every_answer_between_its_sync_and_the_next(
    channel: str,
) -> None:
    """``answer="on_send"``: the answer is on the bus before the SYNC's send returns, so
    a bus that joined later sees SYNC, TPDO, SYNC, TPDO ... however its threads run."""
    with SimulatedDrives.start(
        channel, {0: 1}, SOURCE, scaling=SCALING, period_s=PERIOD_S, answer="on_send"
    ) as sim:
        net = canopen.Network()
        net.connect(interface="virtual", channel=channel)
        probe = can.Bus(interface="virtual", channel=channel)
        try:
            remote = node(net)
            configure_tpdo(remote, 1, [0x60640020])
            remote.nmt.state = "OPERATIONAL"
            assert eventually(lambda: sim[0].nmt_state == "OPERATIONAL")
            while probe.recv(0) is not None:  # the set-up's frames
                pass
            seen = []
            for _ in range(200):
                net.sync.transmit()
                seen += [probe.recv(0), probe.recv(0)]  # no waiting: both are there
            assert probe.recv(0) is None
        finally:
            probe.shutdown()
            net.disconnect()
    assert [m.arbitration_id if m else None for m in seen] == [0x080, 0x181] * 200
    assert sim.sync_count == 200
    assert sim.late_answers == 0
    assert sim.answer_cpu_s > 0


def test_drives_in_lockstep_answering_on_the_bus_answer_every_frame_in_the_order_sent(
    channel: str,
) -> None:
    """In lockstep with ``answer="on_send"`` the NMT command and the SDO requests are
    answered within their send too: a SYNC sent right after the start command finds the
    drive operational, whatever the drives' thread is doing (the demo sends them so)."""
    clock = SimulatedClock()
    with SimulatedDrives.start(
        channel,
        {0: 1},
        SOURCE,
        scaling=SCALING,
        period_s=PERIOD_S,
        answer="on_send",
        clock=clock,
    ) as sim:
        net = canopen.Network()
        net.connect(interface="virtual", channel=channel)
        probe = can.Bus(interface="virtual", channel=channel)
        try:
            remote = node(net)
            configure_tpdo(remote, 1, [0x60640020])
            while probe.recv(0) is not None:  # the set-up's frames
                pass
            remote.nmt.state = "OPERATIONAL"
            net.sync.transmit()  # at once: no waiting for the drive
            seen = [probe.recv(0) for _ in range(3)]
            assert probe.recv(0) is None
        finally:
            probe.shutdown()
            net.disconnect()
    assert [m.arbitration_id if m else None for m in seen] == [0x000, 0x080, 0x181]
    assert clock.wait_step(0, 0.0) == sim.frames_sent  # SYNC 0 reported answered


def test_drives_answer_on_the_bus_only_when_first_on_a_virtual_channel(channel: str) -> None:
    first = can.Bus(interface="virtual", channel=channel)
    try:
        with pytest.raises(ValueError, match=r"open the virtual channel .* first"):
            SimulatedDrives.start(channel, {0: 1}, SOURCE, answer="on_send")
    finally:
        first.shutdown()
    assert channel not in can.interfaces.virtual.channels  # the refused drives' bus is shut


def test_cycle_period_written_by_the_master_sets_the_sample_time(
    drives: SimulatedDrives, network: canopen.Network
) -> None:
    remote = node(network)
    remote.sdo.download(0x1006, 0, u32(1000))  # 1 ms
    configure_tpdo(remote, 1, [0x60640020])
    frames = Frames({0x181})
    network.notifier.add_listener(frames)  # type: ignore[union-attr]
    remote.nmt.state = "OPERATIONAL"
    assert eventually(lambda: drives[0].nmt_state == "OPERATIONAL")
    for _ in range(5):
        network.sync.transmit()
    assert eventually(lambda: len(frames.frames) == 5)
    got = [struct.unpack("<i", f.data)[0] for f in frames.frames]
    assert got == [round(SOURCE.state(0, k * 0.001).position_mm / 10.0 * 4096) for k in range(5)]


def test_sync_counter_sets_the_sample_index(
    drives: SimulatedDrives, network: canopen.Network
) -> None:
    """A SYNC with a counter (cycle modulo 240, plus 1) skips the indices the master skipped."""
    remote = node(network)
    configure_tpdo(remote, 1, [0x60640020])
    frames = Frames({0x181})
    network.notifier.add_listener(frames)  # type: ignore[union-attr]
    remote.nmt.state = "OPERATIONAL"
    assert eventually(lambda: drives[0].nmt_state == "OPERATIONAL")
    sent = [(None, 0), (2, 1), (5, 4), (6, 5), (240, 239), (1, 240), (3, 242), (None, 243)]
    for number, (count, index) in enumerate(sent, start=1):
        network.sync.transmit(count)
        assert drives.wait_for_sync(number, TIMEOUT_S)
        assert drives.sync_index == index
    assert eventually(lambda: len(frames.frames) == len(sent))
    got = [struct.unpack("<i", f.data)[0] for f in frames.frames]
    want = [round(SOURCE.state(0, i * PERIOD_S).position_mm / 10.0 * 4096) for _, i in sent]
    assert got == want
    assert drives.sync_count == len(sent)


def test_no_pdos_unless_operational(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network)
    configure_tpdo(remote, 1, [0x60640020])
    frames = Frames({0x181})
    network.notifier.add_listener(frames)  # type: ignore[union-attr]
    network.sync.transmit()  # pre-operational: nothing
    remote.nmt.state = "OPERATIONAL"
    assert eventually(lambda: drives[0].nmt_state == "OPERATIONAL")
    network.sync.transmit()
    assert eventually(lambda: len(frames.frames) == 1)
    remote.nmt.state = "STOPPED"
    assert eventually(lambda: drives[0].nmt_state == "STOPPED")
    network.sync.transmit()
    remote.sdo.RESPONSE_TIMEOUT = SILENT_S
    with pytest.raises(SdoCommunicationError):  # stopped: no SDO either
        remote.sdo.upload(0x1000, 0)
    assert drives.sync_count == 3
    assert len(frames.frames) == 1


# --- fault switches -----------------------------------------------------------------------


def test_stop_answering_and_resume(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network)
    drives[0].stop_answering()
    remote.sdo.RESPONSE_TIMEOUT = SILENT_S
    with pytest.raises(SdoCommunicationError):
        remote.sdo.upload(0x1000, 0)
    drives[0].resume()
    remote.sdo.RESPONSE_TIMEOUT = ANSWER_S
    assert remote.sdo.upload(0x1000, 0) == u32(0x00020192)


def test_abort_sdo_switch(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network)
    drives[0].abort_sdo(0x1A01, 0x06040041, upload=False)
    assert remote.sdo.upload(0x1A01, 0) == b"\x00"  # uploads still answered
    with pytest.raises(SdoAbortedError) as info:
        remote.sdo.download(0x1A01, 0, b"\x00")
    assert info.value.code == 0x06040041
    drives[0].abort_sdo()  # everything, default code
    with pytest.raises(SdoAbortedError) as info:
        remote.sdo.upload(0x1000, 0)
    assert info.value.code == 0x08000000
    drives[0].resume()
    assert remote.sdo.upload(0x1000, 0) == u32(0x00020192)


def test_slow_answers(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network)
    remote.sdo.RESPONSE_TIMEOUT = 0.1
    drives[0].slow(0.3)
    with pytest.raises(SdoCommunicationError):
        remote.sdo.upload(0x1000, 0)
    drives[0].slow(0.02)
    remote.sdo.RESPONSE_TIMEOUT = ANSWER_S
    assert remote.sdo.upload(0x1000, 0) == u32(0x00020192)


def test_reboot_sends_boot_up_and_forgets_the_pdo_configuration(
    drives: SimulatedDrives, network: canopen.Network
) -> None:
    remote = node(network)
    configure_tpdo(remote, 1, [0x60640020])
    remote.nmt.state = "OPERATIONAL"
    assert eventually(lambda: drives[0].nmt_state == "OPERATIONAL")
    boots = Frames({0x701})
    network.notifier.add_listener(boots)  # type: ignore[union-attr]
    downtime_s = 1.0
    started = time.monotonic()
    drives[0].reboot(downtime_s=downtime_s)
    remote.sdo.RESPONSE_TIMEOUT = SILENT_S
    try:
        remote.sdo.upload(0x1000, 0)
    except SdoCommunicationError:
        pass  # silent while booting
    else:  # an answer is only right once the downtime is over (a busy host sent late)
        assert time.monotonic() - started >= downtime_s, "answered while booting"
    remote.sdo.RESPONSE_TIMEOUT = ANSWER_S
    assert eventually(lambda: len(boots.frames) == 1)
    assert bytes(boots.frames[0].data) == b"\x00"
    assert drives[0].nmt_state == "PRE-OPERATIONAL"
    tpdo1 = drives[0].tpdos()[0]
    assert tpdo1.mapping == () and tpdo1.transmission_type == 255
    assert remote.sdo.upload(0x1A00, 0) == b"\x00"


def test_nmt_reset_node_boots(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network, 2)
    remote.sdo.download(0x1017, 0, struct.pack("<H", 100))
    remote.nmt.state = "RESET"
    assert eventually(lambda: drives[1].boots == 1)
    assert remote.sdo.upload(0x1017, 0) == b"\x00\x00"
    assert drives[1].nmt_state == "PRE-OPERATIONAL"


def test_send_emcy(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network, 2)
    drives[1].send_emcy(0x7121, register=0x81, data=b"\x01")
    assert eventually(lambda: bool(remote.emcy.log))
    entry = remote.emcy.log[0]
    assert (entry.code, entry.register, entry.data[:1]) == (0x7121, 0x81, b"\x01")


def test_fault_bit(drives: SimulatedDrives, network: canopen.Network) -> None:
    remote = node(network)
    drives[0].set_fault(True)
    status = struct.unpack("<H", remote.sdo.upload(0x6041, 0))[0]
    assert status & 0x0008
    drives[0].set_fault(False)
    assert struct.unpack("<H", remote.sdo.upload(0x6041, 0))[0] == OPERATION_ENABLED


# --- dictionaries -------------------------------------------------------------------------


def fixture(name: str) -> Path:
    """A drive's EDS/DCF from ../shared/fixtures/eds: under CI=true its absence fails."""
    return shared_fixture("eds", name)


def test_technosoft_eds_drive(channel: str, network: canopen.Network) -> None:
    path = fixture("technosoft_ipos.eds")
    with SimulatedDrives.start(channel, {0: 3}, SOURCE, scaling=SCALING, eds=path):
        remote = node(network, 3)
        assert remote.sdo.upload(0x1008, 0) == b"iPOS"
        assert remote.sdo.upload(0x6075, 0) == u32(5000)
        with pytest.raises(SdoAbortedError) as info:  # this drive has no 0x6078
            remote.sdo.upload(0x6078, 0)
        assert info.value.code == 0x06020000
        torque = struct.unpack("<h", remote.sdo.upload(0x6077, 0))[0]
        assert abs(torque) < 1000  # per mille of the rated torque, within the pattern


def test_elmo_dcf_drive_copes_with_mapping_entries_without_defaults(
    channel: str, network: canopen.Network
) -> None:
    path = fixture("elmo_gold.dcf")
    with SimulatedDrives.start(channel, {0: 4}, SOURCE, scaling=SCALING, eds=path) as sim:
        remote = node(network, 4)
        assert remote.sdo.upload(0x1A01, 2) == u32(0)  # no DefaultValue in the DCF
        assert remote.sdo.upload(0x1A01, 0) == b"\x00"
        tpdo1 = sim.drives[0].tpdos()[0]  # the DCF's ParameterValue is the start state
        assert tpdo1.valid and tpdo1.transmission_type == 1
        assert tpdo1.mapping[0] == (0x6041, 0, 16)


def test_broken_eds_is_named(tmp_path: Path) -> None:
    broken = tmp_path / "drive.eds"
    broken.write_text("[FileInfo\nnot an eds", encoding="utf-8")
    with pytest.raises(ConfigError, match=str(broken)):
        SimulatedDrive.from_eds(broken, 1, 0, load_object_map("cia402"))


def test_node_ids_must_differ(channel: str) -> None:
    cia402 = load_object_map("cia402")
    twins = [SimulatedDrive.builtin(1, 0, cia402), SimulatedDrive.builtin(1, 1, cia402)]
    with (
        can.Bus(interface="virtual", channel=channel) as bus,
        pytest.raises(ValueError, match="node ids repeat"),
    ):
        SimulatedDrives(bus, twins, SOURCE)


# --- serve ---------------------------------------------------------------------------------


def test_serve_runs_until_stopped(channel: str) -> None:
    stop = threading.Event()
    running: list[SimulatedDrives] = []
    result: list[int] = []

    def run() -> None:
        settings = CanOpenSettings(type="canopen", channel=channel)
        result.append(serve(settings, [7, 8], stop=stop, on_ready=running.append))

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        assert eventually(lambda: bool(running))
        assert [d.node_id for d in running[0].drives] == [7, 8]
        net = canopen.Network()
        net.NOTIFIER_CYCLE = 0.1
        net.connect(interface="virtual", channel=channel)
        try:
            assert node(net, 8).sdo.upload(0x1000, 0) == u32(0x00020192)
            net.sync.transmit()
            net.sync.transmit()
            assert eventually(lambda: running[0].sync_count == 2)
        finally:
            net.disconnect()
    finally:
        stop.set()
        thread.join(TIMEOUT_S)
    assert not thread.is_alive()
    assert result == [2]


def test_serve_stops_after_its_duration(channel: str) -> None:
    assert serve(CanOpenSettings(type="canopen", channel=channel), {0: 1}, duration_s=0.05) == 0


def test_serve_takes_the_link_settings(channel: str) -> None:
    """The object map, the SYNC period until 0x1006 is written, the bus: the link's settings."""
    stop = threading.Event()
    running: list[SimulatedDrives] = []
    settings = CanOpenSettings(
        type="canopen", channel=channel, sync_hz=500, object_map="maxon_epos4"
    )
    thread = threading.Thread(
        target=serve,
        args=(settings, {1: 5}),
        kwargs={"stop": stop, "on_ready": running.append},
        daemon=True,
    )
    thread.start()
    try:
        assert eventually(lambda: bool(running))
        drives = running[0]
        assert drives.period_s == pytest.approx(0.002)
        assert [(d.node_id, d.axis, d.object_map.name) for d in drives.drives] == [
            (5, 1, "maxon_epos4")
        ]
    finally:
        stop.set()
        thread.join(TIMEOUT_S)
    assert not thread.is_alive()
