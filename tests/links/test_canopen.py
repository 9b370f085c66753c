"""The CANopen link against simulated CiA 402 drives on python-can's virtual bus.

Every test has its own virtual channel; every wait is bounded. Link and drives
run in lockstep on a :class:`~ncmeasure.samples.SimulatedClock`, so what a test
sees does not depend on how busy the computer is; faults happen at SYNC
indices (:meth:`SimulatedDrives.at_sync`), not after sleeps. Expected values
are computed here from the signal source, quantised the way a drive encodes
them, independently of the link's and the simulator's scaling code. A few
tests run in real time and assert only what holds however late the host is.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np
import pytest
from pydantic import ValidationError

from ncmeasure.acquire import Progress, acquire
from ncmeasure.config import AxisConfig
from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError
from ncmeasure.links import REAL_TIME, make_link
from ncmeasure.links.canopen.busload import bus_load, frame_bits
from ncmeasure.links.canopen.link import CanOpenLink
from ncmeasure.links.canopen.objects import (
    build_dictionary,
    emcy_text,
    load_object_map,
    sdo_error_text,
)
from ncmeasure.links.canopen.settings import CanOpenAxis
from ncmeasure.links.canopen.sync import CycleAssembler, raise_priority, run_sync_schedule
from ncmeasure.recording import RecordingWriter, read_recording
from ncmeasure.samples import LinkClock, LinkEvent, SimulatedClock
from ncmeasure.sim.cia402 import DriveScaling, SimulatedDrive, SimulatedDrives
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.signals import AxisState, PatternSource
from tests.conftest import shared_fixture

LEAD_MM = 20.0
IPR = 10_000
RATED_A = 10.0
MECHANICS = rig_mechanics(screw_lead_mm=LEAD_MM, rated_current_a=RATED_A)
SCALING = DriveScaling(mechanics=MECHANICS, increments_per_rev=IPR)
SOURCE = PatternSource()
TIMEOUT_S = 60.0
"""A guard against a hang, never part of what a test asserts."""
SDO_ANSWER_S = 30.0
"""How long the link waits for an SDO answer of the simulated drives: they answer from this
process' threads, so only a guard, however busy the host (as the demo does); the tests
of a time-out set their own."""


def needs_fixture(name: str) -> Path:
    """A drive's EDS/DCF from ../shared/fixtures/eds: under CI=true its absence fails."""
    return shared_fixture("eds", name)


@pytest.fixture
def channel() -> str:
    # no digits at the end: python-can's BLF writer reads them as a channel number
    return f"ncm-canopen-{uuid.uuid4().hex}-bus"


def axis_config(name: str, **changes: Any) -> AxisConfig:
    data: dict[str, Any] = {
        "name": name,
        "travel_mm": (0.0, 500.0),
        "park_mm": 10.0,
        "max_velocity_mm_min": 20_000,
        "max_acceleration_m_s2": 1.0,
        "max_jerk_m_s3": 10.0,
        "screw_lead_mm": LEAD_MM,
        "rated_current_a": RATED_A,
    }
    data.update(changes)
    return AxisConfig.model_validate(data)


def make(
    channel: str,
    n_axes: int = 3,
    axis_table: dict[str, Any] | None = None,
    axis_changes: dict[str, Any] | None = None,
    clock: SimulatedClock | None = None,
    **link: Any,
) -> CanOpenLink:
    table = {"channel": channel, "sync_hz": 250, "sdo_timeout_s": SDO_ANSWER_S, **link}
    axes = [
        (
            axis_config(name, **(axis_changes or {})),
            {"node_id": i + 1, "increments_per_rev": IPR, **(axis_table or {})},
        )
        for i, name in enumerate("XYZ"[:n_axes])
    ]
    made = CanOpenLink.from_tables(table, axes)
    if clock is not None:
        made.use_clock(clock)
    return made


@pytest.fixture
def clock() -> SimulatedClock:
    return SimulatedClock()


@pytest.fixture
def drives(channel: str, clock: SimulatedClock) -> Iterator[SimulatedDrives]:
    with SimulatedDrives.start(
        channel, {0: 1, 1: 2, 2: 3}, SOURCE, scaling=SCALING, clock=clock
    ) as sim:
        yield sim


def eventually(condition: Callable[[], bool], timeout_s: float = TIMEOUT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def quantise(value: float, step: float) -> float:
    return round(value / step) * step


def expected(
    t: float,
    axis: int,
    velocity_cmd: bool = False,
    current_step_a: float = RATED_A / 1000,
    velocity_step: float = LEAD_MM / IPR * 60,
) -> list[float]:
    """current_a, velocity_mm_min, position_mm (, velocity_cmd_mm_min) as the drive encodes them."""
    state = SOURCE.state(axis, t)
    row = [
        quantise(state.current_a, current_step_a),
        quantise(state.velocity_mm_min, velocity_step),
        quantise(state.position_mm, LEAD_MM / IPR),
    ]
    if velocity_cmd:
        row.append(quantise(state.velocity_cmd_mm_min, velocity_step))
    return row


class Recorder:
    """Reads a link until a condition holds, keeping rows and events; bounded."""

    def __init__(self, link: CanOpenLink) -> None:
        self.link = link
        self.times: list[float] = []
        self.rows: list[np.ndarray] = []
        self.events: list[LinkEvent] = []

    def until(self, done: Callable[[], bool], timeout_s: float = TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            assert time.monotonic() < deadline, "timed out waiting for the link"
            block = self.link.read(0.05)
            assert block is not None  # a live link never ends
            self.events += self.link.events()
            self.times += block.time_s.tolist()
            self.rows += list(block.values)

    def rows_at_least(self, n: int) -> None:
        self.until(lambda: len(self.times) >= n)

    def past_cycle(self, cycle: int) -> None:
        self.until(lambda: bool(self.times) and self.cycles[-1] > cycle)

    @property
    def cycles(self) -> np.ndarray:
        return np.rint(np.asarray(self.times) * self.link.settings.sync_hz).astype(int)

    def kinds(self, kind: str) -> list[LinkEvent]:
        return [e for e in self.events if e.kind == kind]


def assert_exact(rec: Recorder, cmd_axes: tuple[int, ...] = (), **steps: float) -> None:
    values = np.asarray(rec.rows)
    for row, t in zip(values, rec.times, strict=True):
        want: list[float] = []
        for axis in range(len(rec.link.axes)):
            want += expected(t, axis, axis in cmd_axes, **steps)
        np.testing.assert_allclose(row, want, rtol=1e-12, atol=1e-9, err_msg=f"t = {t}")


def assert_gaps_match(rec: Recorder, axis: str | None) -> int:
    """The gap events cover exactly the cycles without a row; returns the lost samples."""
    cycles = rec.cycles
    assert np.all(np.diff(cycles) > 0), "rows out of order or repeated"
    missing = set(range(cycles[0], cycles[-1] + 1)) - set(cycles.tolist())
    covered: set[int] = set()
    for gap in rec.kinds("gap"):
        span = range(gap.details["first_cycle"], gap.details["last_cycle"] + 1)
        assert gap.lost_samples == len(span)
        assert gap.axis == axis
        covered |= set(span)
    # A busy computer may lose the first cycles before any row arrives: those gaps are
    # reported too, and lie before the first row.
    assert covered - missing <= set(range(cycles[0])), sorted(covered - missing)[:10]
    assert missing <= covered
    return len(missing)


# --- values -------------------------------------------------------------------------------


def test_three_axes_arrive_exact_in_order_without_gaps(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    link = make(channel, clock=clock, axis_table={"read_velocity_demand": True})
    assert link.nominal_period_s == pytest.approx(0.004)
    with link:
        rec = Recorder(link)
        rec.rows_at_least(300)
        stats = link.statistics()
    assert [c.name for c in link.channels[:4]] == [
        "X_current_a",
        "X_velocity_mm_min",
        "X_position_mm",
        "X_velocity_cmd_mm_min",
    ]
    assert [c.unit for c in link.channels[:4]] == ["A", "mm/min", "mm", "mm/min"]
    assert rec.cycles[0] == 0
    assert np.array_equal(rec.cycles, np.arange(len(rec.cycles)))
    assert_exact(rec, cmd_axes=(0, 1, 2))
    assert rec.kinds("gap") == []
    assert stats["lost_rows"] == 0
    assert stats["pdo_frames"] >= 9 * 300  # 3 TPDOs per node on every SYNC
    for drive in drives.drives:
        tpdos = {t.number: t for t in drive.tpdos()}
        assert tpdos[1].valid and tpdos[1].transmission_type == 1
        assert tpdos[1].mapping == ((0x6064, 0, 32), (0x6041, 0, 16))
        assert tpdos[2].mapping == ((0x606C, 0, 32), (0x6078, 0, 16))
        assert tpdos[3].mapping == ((0x606B, 0, 32),)
        assert drive.value(0x1006) == (4000).to_bytes(4, "little")  # cycle period in µs
    # close() leaves the nodes pre-operational
    assert eventually(lambda: all(d.nmt_state == "PRE-OPERATIONAL" for d in drives.drives))


def test_describe_gives_the_scale_factors(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    with make(channel, clock=clock, n_axes=1, axis_table={"gear_ratio": 2.0}) as link:
        info = link.describe()
    x = info["scales"]["X"]
    assert x["position_mm_per_increment"] == pytest.approx(LEAD_MM / (IPR * 2.0))
    assert x["velocity_mm_min_per_unit"] == pytest.approx(60 * LEAD_MM / (IPR * 2.0))
    assert x["current_a_per_unit"] == pytest.approx(RATED_A / 1000)
    assert x["objects"]["current"]["index"] == "0x6078"
    assert [t["cob_id"] for t in x["tpdos"]] == ["0x181", "0x281"]
    assert info["mode"] == "pdo"
    assert info["link"]["sync_hz"] == 250


# What every real drive's EDS/DCF in ../shared/fixtures/eds does (its README, "Known quirks"):
# the current object the link maps (0x6077 where the drive has no 0x6078), and the mode.
EDS_FILES: dict[str, tuple[int, str]] = {
    "elmo_gold.dcf": (0x6078, "pdo"),
    "elmo_whistle_gold.dcf": (0x6078, "pdo"),
    "pilz_prbt.dcf": (0x6077, "pdo"),
    "schunk_module.eds": (0x6077, "sdo_polling"),  # writing its TPDO2 mapping aborts
    "schunk_module_0_63.dcf": (0x6077, "pdo"),
    "schunk_prl120.eds": (0x6077, "pdo"),
    "technosoft_ipos.eds": (0x6077, "pdo"),
}
EDS_REFUSED = {
    "technosoft_isd860.eds": "has no current actual value 0x6078:00 and no torque actual "
    "value 0x6077:00; choose another object_map",
}


def test_every_eds_fixture_has_its_expectation() -> None:
    folder = shared_fixture("eds", "README.md").parent
    found = {p.name for p in folder.iterdir() if p.suffix.lower() in (".eds", ".dcf")}
    assert found == set(EDS_FILES) | set(EDS_REFUSED)


@pytest.mark.parametrize("eds", sorted(EDS_FILES))
def test_every_real_drives_eds_records_against_the_simulated_drive(
    channel: str, clock: SimulatedClock, eds: str
) -> None:
    """The file is the dictionary of the simulated drive and of the link."""
    path = needs_fixture(eds)
    current_index, mode = EDS_FILES[eds]
    with SimulatedDrives.start(
        channel, {0: 1, 1: 2}, SOURCE, scaling=SCALING, eds=path, clock=clock
    ) as sim:
        # no rated current in the machine file: the link reads 0x6075 (mA) over SDO
        link = make(
            channel, n_axes=2, eds=str(path), axis_changes={"rated_current_a": None}, clock=clock
        )
        with link:
            rec = Recorder(link)
            rec.rows_at_least(100)
        assert link.mode == mode
        if mode == "pdo":
            for drive in sim.drives:
                tpdo2 = next(t for t in drive.tpdos() if t.number == 2)
                assert tpdo2.mapping == ((0x606C, 0, 32), (current_index, 0, 16))
    assert np.array_equal(rec.cycles, np.arange(len(rec.cycles)))
    assert_exact(rec)
    infos = " | ".join(e.message for e in rec.kinds("info"))
    assert "rated current 10 A read from motor rated current 0x6075" in infos
    if current_index == 0x6077:
        assert "has no current actual value 0x6078:00" in infos and "0x6077" in infos
    if mode == "sdo_polling":
        assert "falling back to SDO polling" in infos


@pytest.mark.parametrize("eds", sorted(EDS_REFUSED))
def test_a_drive_without_a_current_object_is_refused_with_the_reason(eds: str) -> None:
    path = needs_fixture(eds)
    with pytest.raises(ConfigError) as info:
        make("unused", n_axes=1, eds=str(path))
    assert f"link.eds: {path} {EDS_REFUSED[eds]}" in info.value.problems


def test_maxon_map_reads_current_in_ma_and_velocity_in_rpm(
    channel: str, clock: SimulatedClock
) -> None:
    scaling = DriveScaling(mechanics=MECHANICS, increments_per_rev=IPR, velocity_unit="rpm")
    with SimulatedDrives.start(
        channel, {0: 5}, SOURCE, scaling=scaling, object_map="maxon_epos4", clock=clock
    ) as sim:
        link = CanOpenLink.from_tables(
            {"channel": channel, "object_map": "maxon_epos4"},
            [(axis_config("X"), {"node_id": 5, "increments_per_rev": IPR})],
        )
        link.use_clock(clock)
        with link:
            rec = Recorder(link)
            rec.rows_at_least(100)
        tpdo2 = next(t for t in sim.drives[0].tpdos() if t.number == 2)
    assert tpdo2.mapping == ((0x606C, 0, 32), (0x30D1, 1, 32))
    assert_exact(rec, current_step_a=0.001, velocity_step=LEAD_MM)  # 1 mA, 1 rpm


def test_current_object_missing_on_the_drive_falls_back_to_torque(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drives[1].abort_sdo(0x6078, 0x06020000)
    with make(channel, clock=clock) as link:
        rec = Recorder(link)
        rec.rows_at_least(100)
    assert_exact(rec)  # the simulated torque is the same per mille as the current
    messages = [e.message for e in rec.kinds("info") if e.axis == "Y"]
    assert any("0x6078" in m and "Object does not exist" in m and "0x6077" in m for m in messages)
    tpdo2 = next(t for t in drives[1].tpdos() if t.number == 2)
    assert tpdo2.mapping[1] == (0x6077, 0, 16)


def test_make_link_builds_it_from_a_machine(make_config: Callable[..., Any], channel: str) -> None:
    config = make_config()
    data = config.model_dump()
    data["link"] = {"type": "canopen", "channel": channel}
    for i, axis in enumerate(data["axes"]):
        axis["link"] = {"node_id": i + 1, "increments_per_rev": IPR}
    link = make_link(type(config).model_validate(data))
    assert isinstance(link, CanOpenLink)
    assert [c.name for c in link.channels][:3] == [
        "X_current_a",
        "X_velocity_mm_min",
        "X_position_mm",
    ]


# --- the link clock ---------------------------------------------------------------------------


@dataclass(frozen=True)
class TimeSource:
    """Axis positions that encode the source's time: 10 mm per second, axis k offset k mm."""

    def state(self, axis: int, time_s: float) -> AxisState:
        return AxisState(position_mm=10.0 * time_s + axis, velocity_mm_min=600.0, current_a=1.0)


def test_in_lockstep_a_sample_is_the_source_at_its_time_stamp(
    channel: str, clock: SimulatedClock
) -> None:
    with SimulatedDrives.start(channel, {0: 1, 1: 2}, TimeSource(), scaling=SCALING, clock=clock):
        link = make(channel, n_axes=2, clock=clock)
        with link:
            rec = Recorder(link)
            rec.until(lambda: bool(rec.times) and rec.times[-1] >= 4.0)
            with pytest.raises(LinkError, match="cannot change while it is open"):
                link.use_clock(REAL_TIME)
            assert link.now_s() == pytest.approx(clock.now())
    assert np.array_equal(rec.cycles, np.arange(len(rec.cycles)))
    times = np.asarray(rec.times)
    positions = np.asarray(rec.rows)[:, [2, 5]]
    for axis in range(2):  # exact to the drive's position quantum
        expected_mm = np.rint((10.0 * times + axis) / (LEAD_MM / IPR)) * (LEAD_MM / IPR)
        np.testing.assert_allclose(positions[:, axis], expected_mm, atol=1e-9)
    assert link.describe()["clock"] == "simulated"


def test_in_real_time_rows_are_exact_up_to_the_first_lost_cycle(
    channel: str,
) -> None:
    """Real drives: SYNC on the wall clock, in bus order.

    A busy host may skip SYNC cycles, and the simulated drive (a thread of this
    process) may answer a SYNC after the next one, which no real drive does; either
    shows as a lost cycle. Up to the first one every row is exact, whatever the load.
    """
    with SimulatedDrives.start(channel, {0: 1, 1: 2}, TimeSource(), scaling=SCALING):
        link = make(channel, n_axes=2)
        assert link.clock is REAL_TIME
        with link:
            rec = Recorder(link)
            rec.until(lambda: len(rec.times) >= 50)
            now = link.now_s()
    assert now is not None and now >= rec.times[-1]
    times = np.asarray(rec.times)
    assert np.all(np.diff(rec.cycles) > 0)
    lost = [g.time_s for g in rec.kinds("gap")]
    keep = times < lost[0] if lost else np.ones(len(times), dtype=bool)
    positions = np.asarray(rec.rows)[keep][:, [2, 5]]
    for axis in range(2):
        expected_mm = np.rint((10.0 * times[keep] + axis) / (LEAD_MM / IPR)) * (LEAD_MM / IPR)
        np.testing.assert_allclose(positions[:, axis], expected_mm, atol=1e-9)
    assert_gaps_match(rec, axis=None)


def test_sync_is_the_plain_cia301_sync(channel: str, clock: SimulatedClock) -> None:
    """No counter byte: real drives take SYNC without data (DLC 0), simulated ones too."""
    with can.Bus(interface="virtual", channel=channel) as bus:
        with (
            SimulatedDrives.start(channel, {0: 1}, SOURCE, scaling=SCALING, clock=clock),
            make(channel, n_axes=1, clock=clock) as link,
        ):
            Recorder(link).rows_at_least(20)
        data = [bytes(m.data) for m in frames_on(bus) if m.arbitration_id == 0x80]
    assert len(data) >= 20 and set(data) == {b""}


def frames_on(bus: can.BusABC) -> list[can.Message]:
    """Every frame a watching virtual bus has received, read from its queue.

    Read afterwards, not by a notifier thread, which a loaded computer may not have
    let read the last frames by the time it is stopped.
    """
    frames = []
    while (msg := bus.recv(timeout=0)) is not None:
        frames.append(msg)
    return frames


def test_sync_period_is_whole_microseconds_as_written_to_the_drive(channel: str) -> None:
    link = make(channel, n_axes=1, sync_hz=300)
    assert link.nominal_period_s == pytest.approx(3333e-6, rel=1e-12)
    assert link.describe()["link"]["sync_hz"] == 300


# --- faults -------------------------------------------------------------------------------


def test_drive_that_stops_answering_leaves_a_reported_gap(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drives.at_sync(100, drives[1].stop_answering)
    drives.at_sync(160, drives[1].resume)
    with make(channel, clock=clock) as link:
        rec = Recorder(link)
        rec.past_cycle(250)
    lost = assert_gaps_match(rec, axis="Y")
    assert lost == 60  # exactly the cycles 100 .. 159, however busy the computer is
    assert np.array_equal(rec.cycles[:100], np.arange(100))  # complete before the fault
    assert_exact(rec)  # before and after: the link never invents or shifts a row
    gap = rec.kinds("gap")[0]
    assert gap.details["first_cycle"] == 100 and gap.details["last_cycle"] == 159
    assert "no PDOs from axis Y (node 2)" in gap.message
    assert "60 samples dropped between 0.400 s and 0.636 s" in gap.message


def test_rebooted_drive_is_configured_again_and_data_continues(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drives.at_sync(100, drives[2].reboot)
    with make(channel, clock=clock) as link:
        rec = Recorder(link)
        rec.past_cycle(200)
    reboot = rec.kinds("reboot")[0]
    assert reboot.axis == "Z" and "node 3 (axis Z) rebooted" in reboot.message
    assert reboot.time_s == pytest.approx(0.4)
    assert any("configured again" in e.message for e in rec.kinds("info"))
    assert drives[2].boots == 1
    tpdo1 = next(t for t in drives[2].tpdos() if t.number == 1)
    assert tpdo1.valid and tpdo1.mapping == ((0x6064, 0, 32), (0x6041, 0, 16))
    # in lockstep no SYNC goes out while the drive is configured again: only the cycle of
    # the reboot is lost
    assert assert_gaps_match(rec, axis="Z") == 1
    assert 100 not in rec.cycles
    assert_exact(rec)


def test_emcy_is_reported_with_its_meaning(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drives.at_sync(20, lambda: drives[0].send_emcy(0x2310, register=0x03, data=b"\x12\x34"))
    drives.at_sync(30, lambda: drives[1].send_emcy(0x8611))
    with make(channel, clock=clock) as link:
        rec = Recorder(link)
        rec.past_cycle(40)
    x, y = sorted(rec.kinds("emcy"), key=lambda e: str(e.axis))
    assert x.axis == "X" and "0x2310 continuous over-current (motor side)" in x.message
    assert "error register 0x03, data 12 34" in x.message
    assert x.details["code"] == 0x2310
    assert (x.time_s, y.time_s) == (pytest.approx(20 * 0.004), pytest.approx(30 * 0.004))
    assert y.axis == "Y" and "following error" in y.message
    assert rec.kinds("gap") == []
    assert_exact(rec)


def test_fault_bit_of_the_statusword_is_reported(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drives.at_sync(20, lambda: drives[2].set_fault(True))
    drives.at_sync(45, lambda: drives[2].set_fault(False))
    with make(channel, clock=clock) as link:
        rec = Recorder(link)
        rec.past_cycle(60)
    fault = rec.kinds("fault")[0]
    assert fault.axis == "Z" and "statusword 0x0238" in fault.message
    assert fault.time_s == pytest.approx(20 * 0.004)
    cleared = next(e for e in rec.kinds("info") if "fault cleared" in e.message)
    assert cleared.time_s == pytest.approx(45 * 0.004)


def test_refused_pdo_mapping_falls_back_to_sdo_polling(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drives[1].abort_sdo(0x1A01, 0x06040041)
    with make(channel, clock=clock, n_axes=2) as link:
        rec = Recorder(link)
        rec.rows_at_least(30)
        assert link.mode == "sdo_polling"
        stats = link.statistics()
    info = next(e for e in rec.kinds("info") if "SDO polling" in e.message)
    assert "0x06040041 (Object cannot be mapped to the PDO)" in info.message
    assert info.axis == "Y"
    assert stats["pdo_frames"] == 0 and stats["sdo_polls"] >= 30
    assert not any(t.valid for t in drives[0].tpdos()[:1])  # node 1's TPDO1 switched off
    # in lockstep every cycle is polled before the next SYNC: each row is that cycle's
    assert np.array_equal(rec.cycles, np.arange(len(rec.cycles)))
    assert_exact(rec)


def test_abort_on_a_mandatory_object_is_a_link_error(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drives[2].abort_sdo(0x6064, 0x06020000)
    link = make(channel, clock=clock)
    with pytest.raises(LinkError) as info:
        link.open()
    assert (
        "node 3 (axis Z): reading position actual value 0x6064:00 failed: SDO abort "
        "0x06020000 (Object does not exist)" in str(info.value)
    )
    assert not link.is_open
    link.close()  # idempotent, never raises


def test_drive_that_answers_too_late_times_out(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drives[0].slow(1.0)
    link = make(channel, clock=clock, sdo_timeout_s=0.1)
    with pytest.raises(LinkTimeoutError, match=r"node 1 \(axis X\).*no SDO answer within 0.1 s"):
        link.open()


def test_missing_node_is_a_timeout_naming_it(channel: str, drives: SimulatedDrives) -> None:
    link = CanOpenLink.from_tables(
        {"channel": channel, "sdo_timeout_s": 0.1},
        [(axis_config("X"), {"node_id": 42, "increments_per_rev": IPR})],
    )
    with pytest.raises(LinkTimeoutError, match="node 42"):
        link.open()


def test_external_sync_is_counted_and_missing_sync_reported(
    channel: str, clock: SimulatedClock
) -> None:
    period = 0.01
    skipped = range(50, 53)

    def produce(stop: threading.Event) -> None:
        # the time stamps are what the link counts cycles by; each SYNC waits until the
        # drives answered it, so nothing here depends on how busy the computer is
        with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as bus:
            sent = 0
            for cycle in range(400):
                if stop.is_set():
                    return
                if cycle in skipped:
                    continue
                bus.send(
                    can.Message(
                        arbitration_id=0x80,
                        data=b"",
                        is_extended_id=False,
                        timestamp=1000.0 + cycle * period,
                    )
                )
                assert clock.wait_step(sent, TIMEOUT_S) is not None
                sent += 1

    with SimulatedDrives.start(
        channel, {0: 1}, SOURCE, scaling=SCALING, period_s=period, clock=clock
    ):
        link = make(channel, n_axes=1, sync_hz=1 / period, sync_producer=False)
        stop = threading.Event()
        with link:
            producer = threading.Thread(target=produce, args=(stop,), daemon=True)
            producer.start()
            rec = Recorder(link)
            try:
                rec.past_cycle(80)
            finally:
                stop.set()
                producer.join(TIMEOUT_S)
    cycles = rec.cycles
    assert np.array_equal(cycles[cycles < 50], np.arange(50))
    assert set(cycles.tolist()).isdisjoint(skipped)
    gap = rec.kinds("gap")[0]
    assert gap.lost_samples == 3 and gap.details["missing_sync"] == 3
    assert "3 SYNC cycles missing on the bus" in gap.message
    keep = cycles < 50  # the drive saw no SYNC in the gap: afterwards its clock is behind
    rec.times = [t for t, k in zip(rec.times, keep, strict=True) if k]
    rec.rows = [r for r, k in zip(rec.rows, keep, strict=True) if k]
    assert_exact(rec)


def test_raw_log_has_every_frame(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock, tmp_path: Path
) -> None:
    log_path = tmp_path / "raw" / "bus.blf"
    with make(channel, clock=clock, n_axes=1, raw_log=str(log_path)) as link:
        Recorder(link).rows_at_least(20)
    ids = [m.arbitration_id for m in can.BLFReader(log_path)]
    assert ids.count(0x80) >= 20  # own SYNC frames
    assert ids.count(0x181) >= 20 and ids.count(0x281) >= 20  # TPDOs of node 1
    assert 0x601 in ids and 0x581 in ids  # SDO configuration


def test_a_failing_raw_log_never_stops_the_measurement(
    tmp_path: Path, clock: SimulatedClock, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The log's disk is full (``/dev/full``: every write that reaches it fails, ENOSPC)."""
    full = Path("/dev/full").open("w", encoding="ascii")  # noqa: SIM115 (the writer closes it)
    monkeypatch.setattr(CanOpenLink, "_make_logger", staticmethod(lambda path: can.ASCWriter(full)))
    channel = f"ncm-canopen-{uuid.uuid4().hex}"
    with (
        SimulatedDrives.start(channel, {0: 1}, SOURCE, scaling=SCALING, clock=clock),
        make(channel, n_axes=1, raw_log=str(tmp_path / "bus.asc"), clock=clock) as link,
    ):
        rec = Recorder(link)
        rec.rows_at_least(300)  # more frames than the file's buffer holds
    assert np.array_equal(rec.cycles, np.arange(len(rec.cycles)))
    assert_exact(rec)
    fault = rec.kinds("fault")[0]
    assert f"the raw CAN log {tmp_path / 'bus.asc'} stopped" in fault.message
    assert "No space left on device" in fault.message
    assert channel not in can.interfaces.virtual.channels  # the link's bus closed all the same


# --- listen only: the controller owns the bus ---------------------------------------------------

TPDOS = {1: (0x60640020, 0x60410010), 2: (0x606C0020, 0x60780010)}
"""The layout the 'controller' of these tests configured: position + statusword, velocity +
current (per mille of the rated current)."""


def configured_dcf(folder: Path, node_id: int) -> Path:
    """A DCF of a drive whose TPDOs the controller configured (as ParameterValue)."""
    od = build_dictionary(load_object_map("cia402"), node_id, rated_current_ma=int(RATED_A * 1000))
    for number, entries in TPDOS.items():
        comm, mapping = od[0x1800 + number - 1], od[0x1A00 + number - 1]
        comm[1].value = 0x180 + 0x100 * (number - 1) + node_id
        comm[2].value = 1  # on every SYNC
        mapping[0].value = len(entries)
        for k, entry in enumerate(entries, start=1):
            mapping[k].value = entry
    path = folder / f"drive{node_id}.dcf"
    canopen.export_od(od, str(path), doc_type="dcf")
    return path


class Controller:
    """The CANopen master of a machine: starts the nodes, then SYNC every period.

    SYNC k carries the time stamp 1000 s + k × period (the link counts cycles by the time
    stamps of another master's SYNC) and waits until the simulated drives answered it, so
    that what the listening link sees does not depend on how busy the computer is.
    """

    def __init__(self, channel: str, clock: SimulatedClock, cycles: int) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
        self.clock = clock
        self.cycles = cycles
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _send(self, can_id: int, data: bytes, timestamp: float) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False,
                                  timestamp=timestamp))  # fmt: skip

    def _run(self) -> None:
        self._send(0x000, b"\x01\x00", 999.0)  # NMT start, all nodes
        for cycle in range(self.cycles):
            self._send(0x080, b"", 1000.0 + cycle * 0.004)
            assert self.clock.wait_step(cycle, TIMEOUT_S) is not None

    def __enter__(self) -> Controller:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.thread.join(TIMEOUT_S)
        self.bus.shutdown()


def listener(
    channel: str, n_axes: int, axis_tables: list[dict[str, Any]], **link: Any
) -> CanOpenLink:
    axes = [
        (axis_config(name, rated_current_a=None), {"node_id": i + 1, "increments_per_rev": IPR,
                                                    **axis_tables[i]})
        for i, name in enumerate("XYZ"[:n_axes])
    ]  # fmt: skip
    return CanOpenLink.from_tables(
        {"channel": channel, "sync_hz": 250, "listen_only": True, **link}, axes
    )


@pytest.mark.parametrize("layout", ["dcf", "table"])
def test_a_listening_link_reads_the_controllers_pdos_and_sends_nothing(
    channel: str, clock: SimulatedClock, tmp_path: Path, layout: str
) -> None:
    dcfs = [configured_dcf(tmp_path, node) for node in (1, 2)]
    if layout == "dcf":
        tables: list[dict[str, Any]] = [{"eds": str(path)} for path in dcfs]
        link = listener(channel, 2, tables)
    else:  # the layout written into the machine file; the rated current from it too
        tables = [
            {
                "rated_current_a": RATED_A,
                "tpdo": [
                    {"cob_id": 0x180 + 0x100 * (n - 1) + node, "mapping": list(e)}
                    for n, e in TPDOS.items()
                ],
            }
            for node in (1, 2)
        ]
        link = listener(channel, 2, tables)
    drives = [SimulatedDrive.from_eds(path, node, node - 1, load_object_map("cia402"), SCALING)
              for node, path in zip((1, 2), dcfs, strict=True)]  # fmt: skip
    with (
        can.Bus(interface="virtual", channel=channel) as watch,
        SimulatedDrives(
            can.Bus(interface="virtual", channel=channel), drives, SOURCE, own_bus=True, clock=clock
        ) as sim,
    ):
        sim.run()
        with link, Controller(channel, clock, cycles=120):
            rec = Recorder(link)
            rec.until(lambda: len(rec.times) >= 119)
        ids = [msg.arbitration_id for msg in frames_on(watch)]
    assert np.array_equal(rec.cycles, np.arange(119))
    assert_exact(rec)
    assert rec.kinds("gap") == []
    assert link.describe()["link"]["listen_only"] is True
    assert ids.count(0x000) == 1 and ids.count(0x080) == 120  # the controller's only
    assert not [i for i in ids if 0x600 <= i <= 0x67F]  # no SDO request from the link


def test_listening_needs_the_controllers_layout_and_sends_nothing_of_its_own() -> None:
    problems = problems_of(
        {"listen_only": True}, [(axis_config("X"), {"node_id": 1, "increments_per_rev": IPR})]
    )
    assert problems[0].startswith("axes[0].link: listen_only needs the drive's TPDO layout")
    problems = problems_of(
        {"listen_only": True, "sync_producer": True},
        [(axis_config("X"), {"node_id": 1, "increments_per_rev": IPR})],
    )
    assert problems == [
        "link: Value error, listen_only: the link sends nothing, so sync_producer must be false"
    ]
    problems = problems_of(
        {"listen_only": True},
        [
            (
                axis_config("X", rated_current_a=None),
                {
                    "node_id": 1,
                    "increments_per_rev": IPR,
                    "tpdo": [{"cob_id": 0x181, "mapping": [0x60640020, 0x606C0020]}],
                },
            )
        ],
    )
    assert problems == [
        "axes[0].link: the drive's TPDOs as configured (the link.tpdo table) carry no "
        "current object; listen_only reads what the controller maps and cannot map more"
    ]


# --- bus load -------------------------------------------------------------------------------


def test_frame_bits_by_hand() -> None:
    assert frame_bits(0) == 47 and frame_bits(0, worst_case=True) == 47 + 8
    assert frame_bits(8) == 111 and frame_bits(8, worst_case=True) == 135
    assert frame_bits(6) == 95 and frame_bits(6, worst_case=True) == 95 + 20
    assert frame_bits(4, worst_case=True) == 79 + 16
    with pytest.raises(ValueError):
        frame_bits(9)


def test_bus_load_by_hand() -> None:
    one = bus_load([8], 1000, 1_000_000)
    assert (one.bits_per_cycle, one.worst_bits_per_cycle) == (47 + 111, 55 + 135)
    assert one.load == pytest.approx(0.158) and one.worst_load == pytest.approx(0.190)
    # 3 nodes with TPDOs of 6, 6 and 4 bytes: 3 × (95 + 95 + 79) + 47 = 854 bits
    three = bus_load([6, 6, 4] * 3, 250, 1_000_000)
    assert three.frames_per_cycle == 10
    assert three.bits_per_cycle == 854 and three.worst_bits_per_cycle == 1030
    assert three.load == pytest.approx(0.2135) and three.worst_load == pytest.approx(0.2575)
    assert three.max_sync_hz(0.9) == pytest.approx(0.9e6 / 1030)
    no_sync = bus_load([8, 8], 500, 500_000, sync_frame=False)
    assert no_sync.bits_per_cycle == 222 and no_sync.load == pytest.approx(0.222)


def test_open_refuses_a_layout_over_the_bus_load(channel: str) -> None:
    link = make(channel, sync_hz=1000, axis_table={"read_velocity_demand": True})
    assert link.planned_bus_load().worst_load == pytest.approx(1.03)
    with can.Bus(interface="virtual", channel=channel) as watch:
        with pytest.raises(ConfigError) as info:
            link.open()
        assert watch.recv(0.05) is None  # refused before anything was sent
    text = str(info.value)
    assert "854 bits (1030 with worst-case bit stuffing) at 1000 Hz" in text
    assert "85.4 % (103.0 % worst case), above max_bus_load 90 %" in text
    assert "link.sync_hz: lower it to at most 873 Hz" in text
    assert (
        make(channel, sync_hz=1000, max_bus_load=1.2, axis_table={"read_velocity_demand": True})
        .planned_bus_load()
        .frames_per_cycle
        == 10
    )


# --- settings -------------------------------------------------------------------------------


def problems_of(
    link_table: dict[str, Any], axes: list[tuple[AxisConfig, dict[str, Any]]]
) -> list[str]:
    with pytest.raises(ConfigError) as info:
        CanOpenLink.from_tables(link_table, axes)
    return list(info.value.problems)


def test_bad_settings_are_located() -> None:
    x, y = axis_config("X"), axis_config("Y")
    assert problems_of({}, [(x, {"increments_per_rev": IPR})]) == [
        "axes[0].link.node_id: required key is missing"
    ]
    problems = problems_of(
        {"sync_hz": 0, "bitrat": 5, "raw_log": "bus.txt"},
        [
            (x, {"node_id": 1, "increments_per_rev": IPR}),
            (y, {"node_id": 200, "increments_per_rev": 0}),
        ],
    )
    assert any(p.startswith("link.sync_hz:") for p in problems)
    assert any(p.startswith("link.bitrat: unknown key") for p in problems)
    assert any(p.startswith("link.raw_log:") for p in problems)
    assert any(p.startswith("axes[1].link.node_id:") for p in problems)
    assert any(p.startswith("axes[1].link.increments_per_rev:") for p in problems)
    assert problems_of(
        {"bus_options": {"bitrate": 5}}, [(x, {"node_id": 1, "increments_per_rev": IPR})]
    ) == ["link.bus_options: Value error, set bitrate as link settings, not in bus_options"]


def test_cross_checks_are_located() -> None:
    no_lead = axis_config("X", screw_lead_mm=None)
    problems = problems_of(
        {},
        [
            (no_lead, {"node_id": 1, "increments_per_rev": IPR}),
            (axis_config("Y"), {"node_id": 1, "increments_per_rev": IPR}),
        ],
    )
    assert (
        "axes[0].screw_lead_mm: needed by the canopen link to convert increments to mm" in problems
    )
    assert "axes[1].link.node_id: node 1 is already used by axis X" in problems


def test_unparsable_eds_is_named(tmp_path: Path) -> None:
    broken = tmp_path / "broken.eds"
    broken.write_text("this is not\nan EDS [file\n", encoding="utf-8")
    problems = problems_of(
        {"eds": str(broken)}, [(axis_config("X"), {"node_id": 1, "increments_per_rev": IPR})]
    )
    assert len(problems) == 1
    assert problems[0].startswith(f"link.eds: {broken}: not a readable EDS/DCF file")
    missing = tmp_path / "missing.dcf"
    problems = problems_of(
        {}, [(axis_config("X"), {"node_id": 1, "increments_per_rev": IPR, "eds": str(missing)})]
    )
    assert problems == [f"axes[0].link.eds: {missing}: no such EDS/DCF file"]


def test_object_maps_are_checked(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"unknown object map 'nope'.*cia402, maxon_epos4"):
        load_object_map("nope")
    custom = tmp_path / "drive.toml"
    custom.write_text(
        (
            Path(__file__).parents[2]
            / "src"
            / "ncmeasure"
            / "links"
            / "canopen"
            / "objectmaps"
            / "cia402.toml"
        )
        .read_text(encoding="utf-8")
        .replace('["velocity", "current"]', '["velocity", "current", "velocity_demand"]')
        .replace('    ["velocity_demand"],\n', ""),
        encoding="utf-8",
    )
    with pytest.raises(ConfigError) as info:
        load_object_map(custom)
    assert "needs 10 bytes, a PDO holds 8" in str(info.value)
    with pytest.raises(ConfigError, match="no such object map file"):
        load_object_map(tmp_path / "absent.toml")


# --- pure pieces ------------------------------------------------------------------------------


def test_assembler_gives_each_frame_to_the_sync_before_it() -> None:
    asm = CycleAssembler(slots=2, groups=[1, 1])
    asm.frame(0, b"early")  # before the first SYNC: no cycle of this link
    asm.sync(0)
    asm.frame(0, b"a0")
    asm.frame(1, b"b0")
    asm.sync(1)
    asm.frame(1, b"b1")  # a frame lost on the bus: cycle 1 is incomplete
    asm.sync(2)
    asm.frame(0, b"a2")
    asm.frame(1, b"b2")
    asm.sync(5)  # cycles 3 and 4 had no SYNC on the bus
    rows, lost = asm.take()
    assert rows == [(0, [b"a0", b"b0"]), (2, [b"a2", b"b2"])]
    assert [(x.cycle, set(x.missing), x.reason) for x in lost] == [
        (1, {0}, "missing"),
        (3, {0, 1}, "no_sync"),
        (4, {0, 1}, "no_sync"),
    ]
    assert asm.early_frames == 1
    with pytest.raises(ValueError, match="after 5"):
        asm.sync(5)


def test_a_frame_that_straddles_the_next_sync_never_mixes_two_cycles() -> None:
    """The order of the bug report: one TPDO of a drive after the next SYNC, the other before.

    Drive 1 sends TPDO1 (a) and TPDO2 (b); from cycle 1 on its b comes a cycle late.
    Every later cycle would look complete with the b of the cycle before: the order
    of the drive's frames tells, and those cycles are dropped, not shifted.
    """
    asm = CycleAssembler(slots=3, groups=[1, 1, 2])
    asm.sync(0)
    for slot, data in ((0, b"a0"), (1, b"b0"), (2, b"c0")):
        asm.frame(slot, data)
    asm.sync(1)
    asm.frame(0, b"a1")
    asm.frame(2, b"c1")
    for k in (2, 3):  # b of the cycle before arrives after SYNC k, before a of cycle k
        asm.sync(k)
        asm.frame(1, f"b{k - 1}".encode())
        asm.frame(0, f"a{k}".encode())
        asm.frame(2, f"c{k}".encode())
    asm.sync(4)  # on time again: the held b3 first, then the frames of cycle 4
    for slot, data in ((1, b"b3"), (0, b"a4"), (1, b"b4"), (2, b"c4")):
        asm.frame(slot, data)
    asm.sync(5)
    for slot, data in ((0, b"a5"), (1, b"b5"), (2, b"c5")):
        asm.frame(slot, data)
    asm.sync(6)
    rows, lost = asm.take()
    assert rows == [(0, [b"a0", b"b0", b"c0"]), (5, [b"a5", b"b5", b"c5"])]
    assert [(x.cycle, x.reason) for x in lost] == [
        (1, "missing"),
        (2, "doubled"),
        (3, "doubled"),
        (4, "doubled"),
    ]
    for _, row in rows:  # every row is one cycle's
        assert len({value[1:] for value in row}) == 1


def test_a_drive_answering_late_loses_cycles_and_never_shifts_a_row(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    """At link level, in lockstep: node 2's TPDO2 goes out after the next SYNC."""
    drives.at_sync(100, lambda: drives[1].send_late(0x282))
    drives.at_sync(150, lambda: drives[1].send_late(None))
    with make(channel, clock=clock) as link:
        rec = Recorder(link)
        rec.past_cycle(250)
    assert_exact(rec)  # no row pairs values of two cycles
    lost = assert_gaps_match(rec, axis="Y")
    assert set(range(100, 151)).isdisjoint(rec.cycles.tolist())
    assert lost == 51  # 100: its TPDO2 missing; 101 .. 150: a TPDO2 of the cycle before
    messages = " ".join(g.message for g in rec.kinds("gap"))
    assert "node 2 (axis Y) TPDO2" in messages and "cannot be told apart" in messages


def test_drives_that_fall_silent_end_the_link_after_the_outage_limit(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    for drive in drives.drives:
        drives.at_sync(50, drive.stop_answering)
    with make(channel, clock=clock, max_outage_s=0.5) as link:
        rec = Recorder(link)
        with pytest.raises(LinkTimeoutError, match=r"gave up after 0.5 s without a complete"):
            rec.until(lambda: False)
        rec.events += link.events()
    assert len(rec.times) == 50
    fault = rec.kinds("fault")[-1]
    assert "no PDOs from axis X, Y, Z" in fault.message


def test_readable_texts() -> None:
    assert emcy_text(0x7121) == "motor blocked"
    assert emcy_text(0x8130) == "life guard or heartbeat error"
    assert emcy_text(0xFF42).startswith("device-specific")
    assert emcy_text(0x2399) == "current error"
    from canopen.sdo.exceptions import SdoAbortedError

    assert (
        sdo_error_text(SdoAbortedError(0x06010002))
        == "SDO abort 0x06010002 (Attempt to write a read only object)"
    )


# --- the SYNC schedule and block reads -----------------------------------------------------


def test_sync_schedule_skips_after_a_stall_and_never_bursts() -> None:
    """An injected clock: the producer stalls 4.5 periods after cycle 3, then runs on time."""
    period = 0.001
    now = [0.0]
    sent: list[tuple[int, float]] = []
    skipped: list[tuple[int, int]] = []

    def wait(seconds: float) -> bool:
        now[0] += seconds
        return len(sent) >= 12  # stop

    def send(cycle: int) -> None:
        sent.append((cycle, now[0]))
        if cycle == 3:
            now[0] += 4.5 * period  # the host stalls after sending cycle 3

    run_sync_schedule(period, lambda: now[0], wait, send, lambda a, n: skipped.append((a, n)))
    cycles = [c for c, _ in sent]
    assert cycles == [0, 1, 2, 3, 7, 8, 9, 10, 11, 12, 13, 14]
    assert skipped == [(4, 3)]  # 4, 5, 6: due during the stall, skipped and counted
    times = np.array([t for _, t in sent])
    # on its absolute schedule except the one sent late, and never two for one period
    on_time = [k for k, (c, t) in enumerate(sent) if c != 7]
    np.testing.assert_allclose(times[on_time], np.array(cycles)[on_time] * period, atol=1e-12)
    assert np.all(np.diff(times) >= 0.5 * period - 1e-12)


def test_sync_schedule_keeps_the_period_on_average_through_late_wake_ups() -> None:
    """Every wake-up 0.6 periods late: no cycle skipped, k-th SYNC still due at k × period."""
    period = 0.001
    now = [0.0]
    sent: list[tuple[int, float]] = []

    def wait(seconds: float) -> bool:
        now[0] += seconds + 0.6 * period
        return len(sent) >= 100

    run_sync_schedule(
        period,
        lambda: now[0],
        wait,
        lambda c: sent.append((c, now[0])),
        lambda a, n: pytest.fail("nothing is skipped"),
    )
    cycles = np.array([c for c, _ in sent])
    times = np.array([t for _, t in sent])
    assert np.array_equal(cycles, np.arange(len(sent)))
    assert np.all(times - cycles * period < period)  # late, never drifting


def test_the_sync_thread_asks_for_real_time_priority_and_a_short_switch_interval(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Granted: SCHED_FIFO for the calling thread and the GIL handed over within half a
    period, the interval restored after; 0 asks for nothing."""
    asked: list[tuple[int, int, int]] = []

    def setscheduler(pid: int, policy: int, param: os.sched_param) -> None:
        asked.append((pid, policy, param.sched_priority))

    monkeypatch.setattr(os, "sched_setscheduler", setscheduler)
    before = sys.getswitchinterval()
    assert before > 0.0005
    refused, restore = raise_priority(20, 0.001)
    try:
        assert refused is None and asked == [(0, os.SCHED_FIFO, 20)]
        assert sys.getswitchinterval() == pytest.approx(0.0005)
    finally:
        restore()
    assert sys.getswitchinterval() == before
    assert raise_priority(0, 0.001)[0] is None and len(asked) == 1


def test_a_refused_priority_is_an_info_event_and_the_link_records_on(
    channel: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without the right to real-time priority the link says so once and goes on."""

    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    before = sys.getswitchinterval()
    with SimulatedDrives.start(channel, {0: 1}, SOURCE, scaling=SCALING):
        link = make(channel, n_axes=1)
        with link:
            rec = Recorder(link)
            rec.rows_at_least(10)
        rec.events += link.events()
    notes = [e.message for e in rec.kinds("info") if "normal priority" in e.message]
    assert notes == [
        "the SYNC thread runs at normal priority: real-time priority 20 refused (Operation "
        "not permitted); allow it with an rtprio limit (limits.conf) or CAP_SYS_NICE, or set "
        "link.sync_priority = 0; on a busy host it skips cycles (counted as gaps)"
    ]
    assert sys.getswitchinterval() == before  # left alone when refused


def assert_gaps_cover_missing_rows(rec: Recorder) -> None:
    """From the first row on, the gap events cover exactly the cycles without a row.

    In real time the first cycles may be lost before the first row (the simulated
    drives are a thread of this busy process), so those are not compared.
    """
    cycles = rec.cycles
    missing = set(range(cycles[0], cycles[-1] + 1)) - set(cycles.tolist())
    covered: set[int] = set()
    for gap in rec.kinds("gap"):
        span = range(gap.details["first_cycle"], gap.details["last_cycle"] + 1)
        assert gap.lost_samples == len(span)
        covered |= set(span)
    assert {c for c in covered if cycles[0] <= c <= cycles[-1]} == missing


class StallClock(LinkClock):
    """Real time that jumps ahead once: a host stall, as the SYNC producer sees it."""

    __slots__ = ("jumped", "offset_s")

    def __init__(self) -> None:
        self.offset_s = 0.0
        self.jumped = threading.Event()

    def now(self) -> float:
        return time.perf_counter() + self.offset_s

    def stall(self, seconds: float) -> None:
        self.offset_s += seconds
        self.jumped.set()


def test_a_stalled_sync_producer_reports_the_cycles_it_skipped(channel: str) -> None:
    """The producer skips the cycles of a stall, counts them, and a gap event says so."""
    clock = StallClock()
    with SimulatedDrives.start(channel, {0: 1}, SOURCE, scaling=SCALING):
        link = make(channel, n_axes=1)
        link.use_clock(clock)
        with link:
            rec = Recorder(link)
            rec.rows_at_least(10)
            clock.stall(0.2)  # 50 cycles at 250 Hz
            rec.until(lambda: bool(rec.times) and rec.times[-1] > 0.2 + 0.1)
        rec.events += link.events()
        stats = link.statistics()
    not_sent = [g for g in rec.kinds("gap") if "SYNC cycles not sent" in g.message]
    reported = sum(g.details["missing_sync"] for g in not_sent)
    # a busy host may skip more; each skipped cycle is counted, and reported once its
    # next SYNC is on the bus
    assert 49 <= reported <= stats["sync_skipped"]
    assert reported <= stats["lost_no_sync"] <= stats["sync_skipped"]  # seen: counted as lost
    assert np.all(np.diff(rec.cycles) > 0)  # rows in order, none repeated
    assert_gaps_cover_missing_rows(rec)


class StallOnceClock(StallClock):
    """Real time that jumps ``stall_s`` ahead once ``after_s`` have passed: a host stall at a
    set point, whatever the load."""

    __slots__ = ("after_s", "stall_s", "start_s")

    def __init__(self, after_s: float, stall_s: float) -> None:
        super().__init__()
        self.after_s, self.stall_s = after_s, stall_s
        self.start_s: float | None = None

    def now(self) -> float:
        real = time.perf_counter()
        if self.start_s is None:
            self.start_s = real
        elif not self.jumped.is_set() and real - self.start_s > self.after_s:
            self.stall(self.stall_s)
        return real + self.offset_s


def test_skipped_sync_cycles_are_a_share_of_the_recording(channel: str, tmp_path: Path) -> None:
    """The cycles a stalled producer skipped are counted in the gap events and in the
    recording's metadata as a share of the recording, apart from other losses."""
    clock = StallOnceClock(after_s=0.3, stall_s=0.2)  # 50 cycles at 250 Hz
    with SimulatedDrives.start(channel, {0: 1}, SOURCE, scaling=SCALING):
        link = make(channel, n_axes=1)
        link.use_clock(clock)
        with link:
            writer = RecordingWriter.create(
                tmp_path / "run", link.channels, nominal_period_s=link.nominal_period_s
            )
            seen: list[Progress] = []
            result = acquire(
                link, writer, duration_s=1.0, on_progress=seen.append, progress_interval_s=0.0
            )
            stats = link.statistics()
    assert clock.jumped.is_set()
    gaps = [e for e in result.events if e.kind == "gap"]
    skipped = sum(e.details["skipped_cycles"] for e in gaps)
    # a busy host may skip more; every one seen on the bus is counted, the stall's 49 at least
    assert 49 <= skipped <= stats["lost_no_sync"] <= stats["sync_skipped"]
    assert result.skipped_cycles == skipped
    assert result.skipped_share == pytest.approx(skipped / (result.rows + result.lost_samples))
    meta = read_recording(tmp_path / "run").meta
    assert meta.skipped_cycles == skipped
    assert meta.skipped_share == pytest.approx(result.skipped_share)
    assert meta.lost_samples is not None and meta.lost_samples >= skipped  # within the lost
    assert seen[-1].skipped_cycles == skipped  # the live display shows them too


def test_block_reads_deliver_every_row_in_order(channel: str) -> None:
    """In real time the reader is woken per block: rows come in order, each cycle once,
    and what is missing is a gap; rows are counted as they are handed out."""
    with SimulatedDrives.start(channel, {0: 1, 1: 2}, TimeSource(), scaling=SCALING):
        link = make(channel, n_axes=2, sync_hz=1000)
        with link:
            rec = Recorder(link)
            rec.rows_at_least(300)
            stats = link.statistics()
    assert stats["rows"] == len(rec.times)
    assert np.all(np.diff(rec.cycles) > 0)
    assert_gaps_cover_missing_rows(rec)
    lost = [g.time_s for g in rec.kinds("gap")]
    times = np.asarray(rec.times)
    keep = times < lost[0] if lost else np.ones(len(times), dtype=bool)
    positions = np.asarray(rec.rows)[keep][:, [2, 5]]
    for axis in range(2):  # exact up to the first lost cycle, however the blocks fell
        expected_mm = np.rint((10.0 * times[keep] + axis) / (LEAD_MM / IPR)) * (LEAD_MM / IPR)
        np.testing.assert_allclose(positions[:, axis], expected_mm, atol=1e-9)


def test_marker_input_bit_is_one_of_the_manufacturer_inputs() -> None:
    """Bits 0-15 of 0x60FD are CiA 402's own (limit and home switches): refused."""
    table = {"node_id": 1, "increments_per_rev": 10000}
    assert CanOpenAxis.model_validate({**table, "marker_input_bit": 16}).marker_input_bit == 16
    for bit in (2, 32):
        with pytest.raises(ValidationError):
            CanOpenAxis.model_validate({**table, "marker_input_bit": bit})
