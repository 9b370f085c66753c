"""The Modbus link against the simulated drive: exact values over TCP and RTU, faults, bad input.

The TCP server runs in another process (``running_server``); the RTU server
runs in a thread on one end of a pseudo-terminal null modem. The servers are
deterministic: the n-th answered request of a unit shows the source's state
at ``n × STEP_S``, so every decoded value is compared exactly with the
source's state quantised by the register map.
"""

from __future__ import annotations

import contextlib
import itertools
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ncmeasure.config import AxisConfig
from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError
from ncmeasure.links import link_class
from ncmeasure.links.modbus import link as modbus_link
from ncmeasure.links.modbus.link import ModbusLink, next_slot
from ncmeasure.links.modbus.registers import (
    EXCEPTION_MEANINGS,
    builtin_register_maps,
    decode_words,
    encode_value,
    load_register_map,
)
from ncmeasure.links.modbus.settings import ModbusMarker, ModbusSettings, settings_from_tables
from ncmeasure.samples import LinkEvent, SampleBlock, SimulatedClock
from ncmeasure.sim.modbus_drive import (
    Fault,
    ServerHandle,
    SimulatedModbusDrive,
    SimulatedUnit,
    pty_null_modem,
    running_server,
)
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.signals import AxisState, PatternSource

STEP_S = 0.01
SOURCE = PatternSource()
AXES = ("X", "Y", "Z")
LEAD_MM = 10.0
RATED_A = 8.0

# Link settings for fault tests: short timeouts so every test stays bounded. In lockstep a
# silent drive says so on the clock, and the link waits for every other answer however late.
FAST = {"timeout_s": 0.2, "retries": 0, "reconnect_delay_s": 0.1, "max_outage_s": 1.0}
# Real time, where every answer comes: a time-out no busy host reaches, only a guard.
PATIENT = {**FAST, "timeout_s": 30.0}


def axis(name: str, screw_lead_mm: float | None = LEAD_MM) -> AxisConfig:
    return AxisConfig(
        name=name,
        travel_mm=(0.0, 500.0),
        park_mm=10.0,
        max_velocity_mm_min=20_000.0,
        max_acceleration_m_s2=2.0,
        max_jerk_m_s3=50.0,
        screw_lead_mm=screw_lead_mm,
        rated_current_a=RATED_A,
    )


def tcp_link(server: ServerHandle, **settings: Any) -> ModbusLink:
    table = {"port": server.port, "register_map": "generic", **settings}
    return ModbusLink.from_tables(
        table, [(axis(n), {"unit_id": i + 1}) for i, n in enumerate(AXES)]
    )


def f32(value: float) -> float:
    return float(struct.unpack(">f", struct.pack(">f", value))[0])


def quantised(value: float, factor: float) -> float:
    return round(value / factor) * factor


def generic_row(state: AxisState) -> list[float]:
    """Channels of one axis with the generic map: current, velocity, position, command."""
    return [
        f32(state.current_a),
        quantised(state.velocity_mm_min, 0.01),
        quantised(state.position_mm, 0.001),
        quantised(state.velocity_cmd_mm_min, 0.01),
    ]


def read_rows(
    link: ModbusLink, count: int, limit_s: float = 60.0
) -> list[tuple[float, list[float]]]:
    rows: list[tuple[float, list[float]]] = []
    deadline = time.monotonic() + limit_s
    while len(rows) < count and time.monotonic() < deadline:
        block = link.read(timeout_s=0.5)
        assert block is not None
        rows += block_rows(block)
    assert len(rows) >= count, f"only {len(rows)} rows in {limit_s} s"
    return rows


def read_for(link: ModbusLink, seconds: float) -> list[tuple[float, list[float]]]:
    rows: list[tuple[float, list[float]]] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        block = link.read(timeout_s=0.05)
        assert block is not None
        rows += block_rows(block)
    return rows


def block_rows(block: SampleBlock) -> list[tuple[float, list[float]]]:
    return [
        (float(t), [float(v) for v in row])
        for t, row in zip(block.time_s, block.values, strict=True)
    ]


def request_numbers(
    rows: Sequence[tuple[float, list[float]]],
    columns: slice,
    expected: Callable[[int], list[float]],
    start: int = 0,
) -> list[int]:
    """For each row, the request number n whose state the row's columns show exactly."""
    numbers: list[int] = []
    n = start
    for _, values in rows:
        for candidate in range(n, n + 300):  # the pattern repeats only after 400 steps
            if values[columns] == expected(candidate):
                numbers.append(candidate)
                n = candidate + 1
                break
        else:
            pytest.fail(f"row {values[columns]} is no quantised state after request {n}")
    return numbers


def generic_numbers(
    rows: Sequence[tuple[float, list[float]]], axis_index: int, start: int = 0
) -> list[int]:
    return request_numbers(
        rows,
        slice(4 * axis_index, 4 * axis_index + 4),
        lambda n: generic_row(SOURCE.state(axis_index, n * STEP_S)),
        start,
    )


def events_of(link: ModbusLink, kind: str, events: list[LinkEvent]) -> list[LinkEvent]:
    events += link.events()
    return [e for e in events if e.kind == kind]


@pytest.fixture(scope="module")
def lockstep() -> Iterator[tuple[ServerHandle, SimulatedClock]]:
    """A server in lockstep with the links of a test: faults at moments of simulated time."""
    clock = SimulatedClock()
    with running_server(dict(zip(AXES, (1, 2, 3), strict=True)), clock=clock) as handle:
        yield handle, clock


@pytest.fixture
def stepped(lockstep: tuple[ServerHandle, SimulatedClock]) -> tuple[ServerHandle, SimulatedClock]:
    server, clock = lockstep
    server.reset()
    clock.advance_to(0.0)
    return server, clock


def stepped_link(stepped: tuple[ServerHandle, SimulatedClock], **settings: Any) -> ModbusLink:
    server, clock = stepped
    link = tcp_link(server, **settings)
    link.use_clock(clock)
    return link


def lockstep_rows(rows: Sequence[tuple[float, list[float]]], axis_index: int) -> None:
    """Every row is the state of the PatternSource at its time stamp, quantised by the map."""
    for t, values in rows:
        expected = generic_row(SOURCE.state(axis_index, t))
        assert values[4 * axis_index : 4 * axis_index + 4] == expected, t


def read_until(
    link: ModbusLink, time_s: float, events: list[LinkEvent], limit_s: float = 60.0
) -> list[tuple[float, list[float]]]:
    """Rows up to the first one at ``time_s`` or later (a guard of ``limit_s`` against a hang).

    The link polls ahead of the reader (in lockstep too: the next cycle waits only for
    the previous one), so the last block may hold rows after that one: they are left out.
    """
    rows: list[tuple[float, list[float]]] = []
    deadline = time.monotonic() + limit_s
    while not rows or rows[-1][0] < time_s:
        assert time.monotonic() < deadline, "the link stopped delivering rows"
        block = link.read(timeout_s=0.5)
        assert block is not None
        rows += block_rows(block)
        events += link.events()
    last = next(i for i, (t, _) in enumerate(rows) if t >= time_s)
    return rows[: last + 1]


@pytest.fixture(scope="module")
def module_server() -> Iterator[ServerHandle]:
    with running_server(dict(zip(AXES, (1, 2, 3), strict=True)), step_s=STEP_S) as handle:
        yield handle


@pytest.fixture
def server(module_server: ServerHandle) -> ServerHandle:
    module_server.reset()
    return module_server


# --- values ------------------------------------------------------------------------------


def test_registered_as_modbus() -> None:
    assert link_class("modbus") is ModbusLink


def test_values_arrive_exactly_over_tcp(server: ServerHandle) -> None:
    link = tcp_link(server, timeout_s=PATIENT["timeout_s"])
    assert [c.name for c in link.channels[:4]] == [
        "X_current_a",
        "X_velocity_mm_min",
        "X_position_mm",
        "X_velocity_cmd_mm_min",
    ]
    assert [c.unit for c in link.channels[:4]] == ["A", "mm/min", "mm", "mm/min"]
    assert link.nominal_period_s == pytest.approx(0.01)
    assert link.requests_per_cycle == 3
    with link:
        rows = read_rows(link, 40)
    times = [t for t, _ in rows]
    assert all(b > a for a, b in itertools.pairwise(times))
    assert times[0] >= 0
    for index in range(3):
        # Request 0 of every unit is the check read of open(); rows start at 1.
        assert generic_numbers(rows, index) == list(range(1, len(rows) + 1))
    # The link keeps polling until closed: the server answered at least these requests.
    assert all(count >= len(rows) + 1 for count in server.stats().values())


def test_rtu_values_arrive_exactly_with_the_real_drive_maps() -> None:
    # the drives move the axes the link reads: the same mechanics
    units = [
        SimulatedUnit("X", 1, "iai-robo-cylinder", 0, rig_mechanics(axis("X").mechanics())),
        SimulatedUnit("Y", 2, "kinetix3", 1, rig_mechanics(axis("Y").mechanics()), 8192),
        SimulatedUnit("Z", 3, "ats-rt20", 2, rig_mechanics(axis("Z").mechanics()), 10_000),
    ]
    drive = SimulatedModbusDrive(units, step_s=STEP_S)
    with pty_null_modem() as (server_port, client_port):
        stop = threading.Event()
        ready = threading.Event()
        line = ModbusSettings(
            serial_port=server_port, baudrate=115200, parity="N", register_map="generic"
        )
        thread = threading.Thread(
            target=drive.serve_forever,
            args=(line,),
            kwargs={"ready": lambda _: ready.set(), "stop": stop},
            daemon=True,
        )
        thread.start()
        try:
            assert ready.wait(10)
            link = ModbusLink.from_tables(
                {
                    "mode": "rtu",
                    "serial_port": client_port,
                    "baudrate": 115200,
                    "parity": "N",
                    "register_map": "iai-robo-cylinder",
                    "poll_hz": 20,
                    "timeout_s": PATIENT["timeout_s"],
                },
                [
                    (axis("X"), {"unit_id": 1}),
                    (axis("Y"), {"unit_id": 2, "register_map": "kinetix3", "counts_per_rev": 8192}),
                    (
                        axis("Z"),
                        {"unit_id": 3, "register_map": "ats-rt20", "counts_per_rev": 10_000},
                    ),
                ],
            )
            with link:
                rows = read_rows(link, 12)
        finally:
            stop.set()
            thread.join(timeout=10)
    names = [c.name for c in link.channels]
    assert names == [
        "X_current_a",
        "X_velocity_mm_min",
        "X_position_mm",
        "Y_current_a",
        "Y_velocity_mm_min",
        "Y_position_mm",
        "Y_velocity_cmd_mm_min",
        "Z_current_a",
        "Z_velocity_mm_min",
        "Z_position_mm",
        "Z_velocity_cmd_mm_min",
    ]

    def iai(n: int) -> list[float]:  # 1 mA, 0.01 mm/s = 0.6 mm/min, 0.01 mm
        s = SOURCE.state(0, n * STEP_S)
        return [
            quantised(s.current_a, 0.001),
            quantised(s.velocity_mm_min, 0.01 * 60.0),
            quantised(s.position_mm, 0.01),
        ]

    def rotary(axis_index: int, counts: int) -> Callable[[int], list[float]]:
        def expected(n: int) -> list[float]:  # 0.1 % of rated, rpm × lead, counts / rev × lead
            s = SOURCE.state(axis_index, n * STEP_S)
            return [
                quantised(s.current_a, 0.001 * RATED_A),
                quantised(s.velocity_mm_min, 1.0 * LEAD_MM),
                quantised(s.position_mm, 1.0 * (LEAD_MM / counts)),
                quantised(s.velocity_cmd_mm_min, 1.0 * LEAD_MM),
            ]

        return expected

    expected_numbers = list(range(1, len(rows) + 1))
    assert request_numbers(rows, slice(0, 3), iai) == expected_numbers
    assert request_numbers(rows, slice(3, 7), rotary(1, 8192)) == expected_numbers
    assert request_numbers(rows, slice(7, 11), rotary(2, 10_000)) == expected_numbers


# --- the link clock ------------------------------------------------------------------------


@dataclass(frozen=True)
class TimeSource:
    """Positions that encode the server's time: 10 mm per second (picklable for the server)."""

    def state(self, axis: int, time_s: float) -> AxisState:
        return AxisState(position_mm=10.0 * time_s, velocity_mm_min=600.0, current_a=1.0)


@contextlib.contextmanager
def time_stamped_link(poll_hz: float) -> Iterator[tuple[ModbusLink, SimulatedClock]]:
    """A link to axis X in lockstep with a server whose position says its time
    (:class:`TimeSource`), and their clock."""
    clock = SimulatedClock()
    with running_server({"X": 1}, source=TimeSource(), clock=clock) as handle:
        link = ModbusLink.from_tables(
            {"port": handle.port, "register_map": "generic", "poll_hz": poll_hz},
            [(axis("X"), {"unit_id": 1})],
        )
        link.use_clock(clock)
        yield link, clock


def test_in_lockstep_a_row_is_the_server_state_at_its_time_stamp() -> None:
    with time_stamped_link(50) as (link, clock):
        assert link.describe()["clock"] == "simulated"
        with link:
            rows = read_rows(link, 400)
            assert link.now_s() == pytest.approx(clock.now())
    times = np.array([t for t, _ in rows])
    # every cycle, none skipped however slow the computer: row k at k × 20 ms
    np.testing.assert_allclose(times, np.arange(len(rows)) * 0.02, rtol=0, atol=1e-12)
    positions = np.array([values[2] for _, values in rows])
    np.testing.assert_allclose(positions, 10.0 * times, atol=0.0005)  # the register's 1 µm


def test_in_lockstep_the_polling_runs_at_most_max_ahead_of_the_reader() -> None:
    """What the reader has not taken when it stops is simulated time gone: a series that
    ends a run at its end must find the clock where the run ended, not far past the next
    start, however long the reader was busy."""
    with time_stamped_link(100) as (link, _), link:
        taken = read_rows(link, 10)[-1][0]  # the last row the reader took
        # the reader busy: the polling fills what it may hold, then waits (bounded)
        deadline = time.monotonic() + 60.0
        ahead = -1.0
        while time.monotonic() < deadline:
            time.sleep(0.5)
            if link.now_s() == ahead:
                break  # it stopped
            ahead = link.now_s()
        assert link.now_s() == ahead, "the polling never stopped for the reader"
    # the rows it holds span MAX_AHEAD_S (a cycle more at most: the one being polled)
    assert ModbusLink.MAX_AHEAD_S - 0.02 <= ahead - taken <= ModbusLink.MAX_AHEAD_S + 0.02


# --- faults ------------------------------------------------------------------------------


def test_server_stops_answering_gives_up_after_max_outage(
    stepped: tuple[ServerHandle, SimulatedClock],
) -> None:
    server, _ = stepped
    server.set_fault(Fault(silent=True, from_s=0.2))
    events: list[LinkEvent] = []
    rows: list[tuple[float, list[float]]] = []
    with stepped_link(stepped, **{**FAST, "max_outage_s": 0.1}) as link:
        with pytest.raises(LinkTimeoutError) as info:
            for _ in range(1000):  # bounded; gives up after 0.1 s of link time
                block = link.read(timeout_s=0.5)
                assert block is not None
                rows += block_rows(block)
        events_of(link, "gap", events)
    assert "gave up after 0.1 s" in str(info.value)
    assert "no valid answer" in str(info.value)
    assert len(rows) == 20  # every cycle before the fault, exact
    for index in range(3):
        lockstep_rows(rows, index)
    gaps = [e for e in events if e.kind == "gap"]
    assert gaps and gaps[0].time_s == pytest.approx(0.2)
    assert any(e.kind == "fault" and "gave up" in e.message for e in events)


def test_silent_drive_that_comes_back_leaves_a_gap(
    stepped: tuple[ServerHandle, SimulatedClock],
) -> None:
    server, _ = stepped
    server.set_fault(Fault(silent=True, units=frozenset({2}), from_s=0.1, until_s=0.15))
    events: list[LinkEvent] = []
    with stepped_link(stepped, **{**FAST, "max_outage_s": 5.0}) as link:
        rows = read_until(link, 0.3, events)
    gaps = [e for e in events if e.kind == "gap"]
    assert [(g.time_s, g.lost_samples) for g in gaps] == [(pytest.approx(0.1), 5)]
    assert "no valid answer" in gaps[0].message and "axis Y" in gaps[0].message
    assert gaps[0].details["skipped_cycles"] == 0  # lost to the drive, not skipped
    times = [t for t, _ in rows]
    assert times == pytest.approx([k * 0.01 for k in range(31) if not 10 <= k < 15])
    for index in range(3):  # exact and in order, before and after the gap
        lockstep_rows(rows, index)


def test_in_lockstep_an_answer_later_than_the_timeout_is_no_timeout(
    stepped: tuple[ServerHandle, SimulatedClock],
) -> None:
    """In lockstep a request times out in simulated time, when the drive stays silent;
    an answer a busy computer delivers late on the wall clock is an answer."""
    server, _ = stepped
    server.set_fault(Fault(delay_s=0.3, from_s=0.05, until_s=0.07))  # timeout_s is 0.2
    events: list[LinkEvent] = []
    with stepped_link(stepped, **FAST) as link:
        rows = read_until(link, 0.2, events)
    assert [e for e in events if e.kind in ("gap", "fault", "reconnect")] == []
    assert [t for t, _ in rows] == pytest.approx([k * 0.01 for k in range(21)])
    for index in range(3):
        lockstep_rows(rows, index)


def test_dropped_connection_reconnects_and_data_continues(
    stepped: tuple[ServerHandle, SimulatedClock],
) -> None:
    server, _ = stepped
    server.set_fault(Fault(disconnect=True, from_s=0.1, until_s=0.105))
    events: list[LinkEvent] = []
    with stepped_link(stepped, **FAST) as link:
        rows = read_until(link, 0.4, events)
    reconnects = [e for e in events if e.kind == "reconnect"]
    gaps = [e for e in events if e.kind == "gap"]
    assert len(reconnects) == 1
    assert f"127.0.0.1:{server.port}" in reconnects[0].message
    # the cycle at 0.1 s fails; reconnect_delay_s = 0.1 s of link time is 10 poll periods
    assert [(g.time_s, g.lost_samples) for g in gaps] == [(pytest.approx(0.1), 10)]
    assert gaps[0].details["skipped_cycles"] == 0  # an outage: nothing skipped
    assert reconnects[0].time_s == pytest.approx(0.2)
    for index in range(3):
        lockstep_rows(rows, index)


def test_exception_response_is_a_fault_event_with_its_meaning(
    stepped: tuple[ServerHandle, SimulatedClock],
) -> None:
    server, _ = stepped
    server.set_fault(Fault(exception_code=6, units=frozenset({2}), from_s=0.05, until_s=0.08))
    events: list[LinkEvent] = []
    with stepped_link(stepped, **{**FAST, "max_outage_s": 5.0}) as link:
        rows = read_until(link, 0.2, events)
    faults = [e for e in events if e.kind == "fault"]
    assert len(faults) == 1  # reported once, not once per cycle
    assert faults[0].axis == "Y" and faults[0].time_s == pytest.approx(0.05)
    assert faults[0].details["exception_code"] == 6
    assert "exception 6 (server device busy" in faults[0].message
    assert any(e.kind == "info" and "axis Y answers again" in e.message for e in events)
    assert [(e.time_s, e.lost_samples) for e in events if e.kind == "gap"] == [
        (pytest.approx(0.05), 3)
    ]
    for index in range(3):
        lockstep_rows(rows, index)


def test_persistent_exception_ends_in_a_link_error_with_the_meaning(
    stepped: tuple[ServerHandle, SimulatedClock],
) -> None:
    server, _ = stepped
    server.set_fault(Fault(exception_code=4, from_s=0.05))
    with stepped_link(stepped, **FAST) as link, pytest.raises(LinkError) as info:
        for _ in range(1000):
            link.read(timeout_s=0.5)
    assert not isinstance(info.value, LinkTimeoutError)
    assert "exception 4 (server device failure" in str(info.value)


@pytest.mark.parametrize("code", [1, 2, 3, 4, 5, 6, 10, 11])
def test_exception_at_open_says_what_it_means(server: ServerHandle, code: int) -> None:
    server.set_fault(Fault(exception_code=code, units=frozenset({3})))
    link = tcp_link(server, **PATIENT)
    with pytest.raises(LinkError) as info:
        link.open()
    assert not link.is_open
    text = str(info.value)
    assert f"exception {code} ({EXCEPTION_MEANINGS[code]})" in text
    assert "unit 3 (axis Z)" in text
    assert "Traceback" not in text


def test_paced_polling_gives_every_row_this_cycles_answers(server: ServerHandle) -> None:
    """Paced (poll_hz well below what the loop can do): no row holds an older answer.

    The server numbers the answers of each unit; every row must show each unit's
    next answer, in order, none repeated and none left out. Whether the host keeps
    the pace is not asserted (a loaded computer may not): late cycles are gaps.
    """
    with tcp_link(server, **{**PATIENT, "poll_hz": 200.0}) as link:
        rows = read_rows(link, 60)
    for index in range(3):
        assert generic_numbers(rows, index) == list(range(1, len(rows) + 1))
    times = [t for t, _ in rows]
    assert times == sorted(times)


def test_slow_answers_are_late_cycles_not_errors(server: ServerHandle) -> None:
    events: list[LinkEvent] = []
    with tcp_link(server, **PATIENT) as link:
        rows = read_rows(link, 5)
        server.set_fault(Fault(delay_s=0.02))  # 3 requests: 60 ms per cycle at 10 ms period
        # Row k holds request k of every unit (request 0 is open()'s check): the rows from
        # the first request every unit answers late are the slow ones, however many rows
        # the link had polled ahead of the reader when the fault came.
        first_slow = max(server.stats().values())
        while len(rows) < first_slow + 2:
            rows += read_rows(link, 1)
        server.clear_faults()
        before, slow = rows[: first_slow - 1], rows[first_slow - 1 :]
        after = read_rows(link, 5)
        gaps = events_of(link, "gap", events)
    rows = before + slow + after
    for index in range(3):  # every answer arrived: no request is missing
        assert generic_numbers(rows, index) == list(range(1, len(rows) + 1))
    assert gaps and all("slow answers" in e.message for e in gaps)
    assert sum(e.lost_samples for e in gaps) > len(slow)
    # cycles the link skipped because it fell behind: counted as skipped, not hidden
    assert [e.details["skipped_cycles"] for e in gaps] == [e.lost_samples for e in gaps]
    assert not [e for e in events if e.kind in ("fault", "reconnect")]


@pytest.mark.parametrize(
    ("slot", "now", "catch_up", "expected"),
    [
        (4, 4.3, 5.0, 5),  # on time: the next slot, after a wait
        (4, 5.2, 5.0, 5),  # the next one is due: at once, no wait
        (4, 8.9, 5.0, 5),  # a stall of 3.9 periods, within the catch-up: none skipped
        (4, 12.5, 5.0, 7),  # 7.5 periods behind: 5 and 6 skipped, 7 onward caught up
        (4, 8.9, 0.0, 8),  # no catch-up (after an outage): the newest due, 5 to 7 skipped
        (4, 4.0, 0.0, 5),
    ],
)
def test_next_slot_catches_up_on_a_short_stall(
    slot: int, now: float, catch_up: float, expected: int
) -> None:
    assert next_slot(slot, now, catch_up) == expected


def test_a_stall_within_the_catch_up_costs_no_row(
    server: ServerHandle, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A late cycle (a loaded computer, a slow answer) is caught up, not skipped.

    The catch-up is widened so that no other stall of a busy test machine can
    reach past it: the cycles behind the 60 ms one are all polled, back to back.
    """
    monkeypatch.setattr(modbus_link, "CATCH_UP_S", 30.0)
    events: list[LinkEvent] = []
    with tcp_link(server, **PATIENT) as link:
        before = read_rows(link, 5)
        server.set_fault(Fault(delay_s=0.02))  # 3 requests: 60 ms per cycle at 10 ms period
        slow = read_rows(link, 2)
        server.clear_faults()
        after = read_rows(link, 20)
        gaps = events_of(link, "gap", events)
    rows = before + slow + after
    for index in range(3):
        assert generic_numbers(rows, index) == list(range(1, len(rows) + 1))
    assert gaps == []
    assert not [e for e in events if e.kind in ("fault", "reconnect")]


def test_close_never_raises_even_when_the_server_is_gone() -> None:
    with running_server({"X": 1}, step_s=STEP_S) as handle:
        link = ModbusLink.from_tables(
            {"port": handle.port, "register_map": "generic", **FAST}, [(axis("X"), {"unit_id": 1})]
        )
        link.open()
        read_rows(link, 3)
    link.close()
    link.close()
    assert not link.is_open
    with pytest.raises(LinkError):
        link.read()


# --- bad input ---------------------------------------------------------------------------


def free_closed_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def test_unreachable_host_names_host_port_and_reason() -> None:
    port = free_closed_port()
    link = ModbusLink.from_tables(
        {"port": port, "register_map": "generic", "timeout_s": 0.5}, [(axis("X"), {"unit_id": 1})]
    )
    with pytest.raises(LinkError) as info:
        link.open()
    text = str(info.value)
    assert f"127.0.0.1:{port}" in text
    assert "refused" in text.lower()
    assert "\n" not in text


def test_server_port_in_use_is_a_clear_error() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(LinkError) as info, running_server({"X": 1}, port=port):
            pass
    assert f"127.0.0.1:{port}" in str(info.value)
    assert "in use" in str(info.value)


def link_problems(
    link_table: dict[str, Any],
    axis_tables: list[dict[str, Any]],
    axes: list[AxisConfig] | None = None,
) -> list[str]:
    configs = axes or [axis(n) for n in AXES[: len(axis_tables)]]
    with pytest.raises(ConfigError) as info:
        ModbusLink.from_tables(link_table, list(zip(configs, axis_tables, strict=True)))
    return list(info.value.problems)


def test_bad_axis_settings_are_located() -> None:
    problems = link_problems(
        {"register_map": "generic"},
        [{"unit_id": 0}, {"node_id": 3, "unit_id": 2}, {}],
    )
    assert any(p.startswith("axes[0].link.unit_id: ") for p in problems)
    assert any(p.startswith("axes[1].link.node_id: unknown key") for p in problems)
    assert "axes[2].link.unit_id: required key is missing" in problems
    problems = link_problems({"register_map": "generic"}, [{"unit_id": 248}])
    assert problems[0].startswith("axes[0].link.unit_id: Input should be less than or equal to 247")


def test_bad_link_settings_are_located() -> None:
    problems = link_problems({"mode": "rtu", "poll_hz": 0}, [{"unit_id": 1}])
    assert "link.serial_port: required when mode is 'rtu'" in problems
    assert "link.register_map: required key is missing" in problems
    assert any(p.startswith("link.poll_hz: ") for p in problems)


def test_a_serial_port_means_rtu_never_tcp() -> None:
    """A serial port alone selects RTU; with mode 'tcp' it is refused, never ignored."""
    table = {"serial_port": "/dev/ttyX", "baudrate": 9600, "register_map": "generic"}
    link = ModbusLink.from_tables(table, [(axis("X"), {"unit_id": 1})])
    assert isinstance(link.settings, ModbusSettings) and link.settings.mode == "rtu"
    problems = link_problems({**table, "mode": "tcp"}, [{"unit_id": 1}])
    assert problems == [
        "link.serial_port: a serial port is for mode 'rtu', but mode is 'tcp': set mode = "
        "'rtu' (or leave mode out) to use the serial line, or leave serial_port out for TCP"
    ]


def test_duplicate_unit_ids_and_missing_axis_data() -> None:
    problems = link_problems({"register_map": "generic"}, [{"unit_id": 4}, {"unit_id": 4}])
    assert problems == ["axes[1].link.unit_id: unit 4 is already used by axis X"]
    problems = link_problems(
        {"register_map": "kinetix3"}, [{"unit_id": 1}], axes=[axis("X", screw_lead_mm=None)]
    )
    assert any(
        p.startswith("axes[0].screw_lead_mm: the register map gives velocity_mm_min in rpm")
        for p in problems
    )
    problems = link_problems({"register_map": "kinetix3"}, [{"unit_id": 1}])
    assert any(p.startswith("axes[0].link.counts_per_rev: ") for p in problems)


def test_unknown_register_map_lists_the_built_in_ones() -> None:
    problems = link_problems({"register_map": "nope"}, [{"unit_id": 1}])
    assert problems[0].startswith("link.register_map: unknown register map 'nope'; built-in maps: ")
    assert "generic" in problems[0] and "kinetix3" in problems[0]
    problems = link_problems({"register_map": "generic"}, [{"unit_id": 1, "register_map": "nope"}])
    assert problems[0].startswith("axes[0].link.register_map: unknown register map 'nope'")


def test_rtu_poll_rate_beyond_the_line_is_refused_or_lowered() -> None:
    table = {"mode": "rtu", "serial_port": "/dev/null", "baudrate": 9600, "register_map": "generic"}
    problems = link_problems({**table, "poll_hz": 100}, [{"unit_id": 1}])
    assert problems[0].startswith(
        "link.poll_hz: 100 Hz is too fast: 1 request(s) per cycle at 9600 baud"
    )
    link = ModbusLink.from_tables(
        table, [(axis(n), {"unit_id": i + 1}) for i, n in enumerate(AXES)]
    )
    assert 1 / link.nominal_period_s < 100  # the default was lowered to what the line carries
    assert link.describe()["poll_hz"] == pytest.approx(1 / link.nominal_period_s)


MAP_HEAD = """
name = "test"
drive = "test drive"
[source]
title = "test document"
"""

GOOD_SIGNALS = {
    "current_a": 'address = 0\nfunction = "input"\ntype = "int16"\nscale = 0.01\nunit = "A"',
    "velocity_mm_min": 'address = 1\nfunction = "input"\ntype = "int32"\nunit = "mm/min"',
    "position_mm": 'address = 3\nfunction = "input"\ntype = "int32"\nunit = "mm"',
}


FLOAT_AT_END = 'address = 65535\nfunction = "input"\ntype = "float32"\nunit = "mm/min"'


def write_map(tmp_path: Path, **changes: str | None) -> Path:
    signals = {**GOOD_SIGNALS, **changes}
    text = MAP_HEAD + "".join(
        f"\n[signals.{name}]\n{body}\n" for name, body in signals.items() if body is not None
    )
    path = tmp_path / "drive.toml"
    path.write_text(text, encoding="utf-8")
    return path


def map_problems(path: Path) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_register_map(path)
    assert str(path) in info.value.message
    return [line.removeprefix(f"{path}: ") for line in info.value.problems]


def test_a_good_map_file_loads(tmp_path: Path) -> None:
    reg_map = load_register_map(write_map(tmp_path))
    assert [name for name, _ in reg_map.ordered_signals()] == [
        "current_a",
        "velocity_mm_min",
        "position_mm",
    ]


def test_map_with_overlapping_registers(tmp_path: Path) -> None:
    problems = map_problems(
        write_map(
            tmp_path, position_mm='address = 2\nfunction = "input"\ntype = "int32"\nunit = "mm"'
        )
    )
    assert problems == [
        "signals.position_mm: input registers 2..3 overlap signals.velocity_mm_min (1..2)"
    ]


def test_same_address_in_holding_and_input_does_not_overlap(tmp_path: Path) -> None:
    load_register_map(
        write_map(
            tmp_path, position_mm='address = 1\nfunction = "holding"\ntype = "int32"\nunit = "mm"'
        )
    )


def test_map_with_impossible_entries(tmp_path: Path) -> None:
    problems = map_problems(
        write_map(
            tmp_path,
            current_a='address = 70000\nfunction = "input"\ntype = "int16"\nunit = "A"',
            velocity_mm_min=FLOAT_AT_END,
            position_mm='address = 3\nfunction = "coil"\ntype = "int64"\nunit = "mm"',
        )
    )
    assert any(
        p.startswith("signals.current_a.address: Input should be less than or equal to 65535")
        for p in problems
    )
    assert any(
        p.startswith("signals.position_mm.function: Input should be 'holding' or 'input'")
        for p in problems
    )
    assert any(p.startswith("signals.position_mm.type: Input should be 'int16'") for p in problems)
    problems = map_problems(
        write_map(
            tmp_path,
            velocity_mm_min=FLOAT_AT_END,
        )
    )
    assert (
        "signals.velocity_mm_min.address: a float32 at 65535 needs registers 65535..65536, "
        "past the last address 65535"
    ) in problems


def test_map_with_missing_signal_bad_unit_and_wide_span(tmp_path: Path) -> None:
    problems = map_problems(
        write_map(
            tmp_path,
            current_a=None,
            velocity_mm_min='address = 200\nfunction = "input"\ntype = "int16"\nunit = "rps"',
        )
    )
    assert "signals.current_a: required signal is missing" in problems
    assert "signals.velocity_mm_min.unit: 'rps' is not one of 'mm/min', 'mm/s', 'rpm'" in problems
    assert (
        "signals: the input registers span 3..200 (198 registers), more than the 125 one "
        "Modbus request can read"
    ) in problems


def test_map_with_unknown_key_and_zero_scale(tmp_path: Path) -> None:
    problems = map_problems(
        write_map(
            tmp_path,
            current_a='address = 0\nfunction = "input"\ntype = "int16"\nunit = "A"\n'
            "scale = 0\nsigned = true",
        )
    )
    assert any(
        p.startswith("signals.current_a.scale: must be a finite number other than 0")
        for p in problems
    )
    assert any(p.startswith("signals.current_a.signed: unknown key") for p in problems)


def test_map_that_is_not_toml(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text("name = ", encoding="utf-8")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_register_map(path)
    with pytest.raises(ConfigError, match="no such file"):
        load_register_map(tmp_path / "missing.toml")


@pytest.mark.parametrize("name", builtin_register_maps())
def test_shipped_maps_are_valid_and_cite_their_source(name: str) -> None:
    reg_map = load_register_map(name)
    assert reg_map.name == name
    assert reg_map.source.title
    if name != "generic":
        assert reg_map.source.url.startswith("https://")
        assert reg_map.source.section


def test_shipped_maps() -> None:
    assert {"generic", "iai-robo-cylinder", "kinetix3", "ats-rt20"} <= set(builtin_register_maps())


def test_describe_names_the_maps_their_sources_and_scales(server: ServerHandle) -> None:
    link = ModbusLink.from_tables(
        {"port": server.port, "register_map": "generic"},
        [
            (axis("X"), {"unit_id": 1}),
            (
                axis("Y"),
                {
                    "unit_id": 2,
                    "register_map": "kinetix3",
                    "counts_per_rev": 4096,
                    "scales": {"current_a": 0.002},
                },
            ),
        ],
    )
    info = link.describe()
    assert info["link"]["register_map"] == "generic"
    assert info["axes"]["Y"]["counts_per_rev"] == 4096
    maps = info["register_maps"]
    assert maps["X"]["name"] == "generic"
    assert maps["X"]["signals"]["position_mm"]["scale"] == 0.001
    assert maps["Y"]["source"]["title"].startswith("Kinetix 3")
    assert maps["Y"]["signals"]["velocity_mm_min"]["factor"] == LEAD_MM
    assert maps["Y"]["signals"]["position_mm"]["factor"] == pytest.approx(LEAD_MM / 4096)
    assert maps["Y"]["signals"]["current_a"]["factor"] == pytest.approx(0.002 * RATED_A)
    assert "midpoint" in info["time_s"]


# --- encoding ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("data_type", "order", "raw", "words"),
    [
        ("int16", "big", -2, [0xFFFE]),
        ("uint16", "big", 65535, [0xFFFF]),
        ("int32", "big", -2, [0xFFFF, 0xFFFE]),
        ("int32", "little", 0x12345678, [0x5678, 0x1234]),
        ("uint32", "big", 0x12345678, [0x1234, 0x5678]),
        ("float32", "big", 1.5, [0x3FC0, 0x0000]),
        ("float32", "little", 1.5, [0x0000, 0x3FC0]),
        ("int16", "big", 40000, [0x7FFF]),  # saturates
    ],
)
def test_encode_and_decode_words(data_type: str, order: str, raw: float, words: list[int]) -> None:
    assert encode_value(raw, data_type, order) == words
    expected = min(raw, 32767) if data_type == "int16" else raw
    assert decode_words(words, data_type, order) == expected


@given(st.integers(-(2**31), 2**31 - 1), st.sampled_from(["big", "little"]))
def test_int32_round_trip(raw: int, order: str) -> None:
    assert decode_words(encode_value(raw, "int32", order), "int32", order) == raw


# --- the marker ----------------------------------------------------------------------------


def test_a_marker_input_is_validated_like_the_other_settings() -> None:
    with pytest.raises(ConfigError) as info:
        settings_from_tables(
            {"register_map": "generic"},
            {
                "X": {"unit_id": 1, "marker": {"function": "holding", "address": 5}},
                "Y": {"unit_id": 2, "marker": {"function": "coil", "address": 5, "bit": 1}},
                "Z": {"unit_id": 3, "marker": {"function": "output", "address": 5}},
            },
        )
    problems = "\n".join(info.value.problems)
    assert "axes[0].link.marker: a register marker needs the bit" in problems
    assert "axes[1].link.marker: bit is for a register" in problems
    assert "axes[2].link.marker.function" in problems


@pytest.mark.parametrize(
    "marker",
    [
        {"function": "discrete", "address": 21},
        {"function": "coil", "address": 3},
        {"function": "holding", "address": 40, "bit": 5},
        {"function": "input", "address": 9, "bit": 15},
    ],
)
def test_the_marker_is_read_from_the_input_the_axis_names(marker: dict[str, int | str]) -> None:
    """Each kind of input serves the source's marker; the link records it as 0 or 1."""
    clock = SimulatedClock()
    settings = ModbusMarker.model_validate(marker)
    unit = SimulatedUnit("X", 1, marker=settings)
    with running_server([unit], source=MarkerSource(), clock=clock) as handle:
        link = ModbusLink.from_tables(
            {"port": handle.port, "register_map": "generic", "poll_hz": 50},
            [(axis("X"), {"unit_id": 1, "marker": marker})],
        )
        link.use_clock(clock)
        assert [c.name for c in link.channels][-1] == "X_marker"
        with link:
            rows = read_rows(link, 40)
    values = [v[-1] for _, v in rows]
    expected = [float(MarkerSource().state(0, t).marker > 0) for t, _ in rows]
    assert values == expected and set(values) == {0.0, 1.0}


@dataclass(frozen=True)
class MarkerSource:
    """The marker on for 0.1 s, off for 0.1 s (picklable for the server)."""

    def state(self, axis: int, time_s: float) -> AxisState:
        return AxisState(10.0 * time_s, 600.0, 1.0, marker=float(round(time_s * 1000) // 100 % 2))
