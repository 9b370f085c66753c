"""The link clocks: real time, and simulated time that the link advances in lockstep."""

from __future__ import annotations

import multiprocessing
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

import ncmeasure.links as links
from ncmeasure.config import parse_machine
from ncmeasure.errors import LinkError
from ncmeasure.links import REAL_TIME, LinkClock, link_class
from ncmeasure.recording import RecordingWriter
from ncmeasure.samples import SampleBlock, SimulatedClock, channels_for
from tests.conftest import example_data


def test_real_time_is_the_perf_counter_and_exported() -> None:
    assert links.REAL_TIME is REAL_TIME and links.LinkClock is LinkClock
    assert REAL_TIME.real_time and not REAL_TIME.lockstep
    assert LinkClock() == REAL_TIME
    before = time.perf_counter()
    reading = REAL_TIME.now()
    assert before <= reading <= time.perf_counter()
    assert REAL_TIME.wall(2.0) == 2.0
    REAL_TIME.sleep(0.0)
    REAL_TIME.sleep(-1.0)  # nothing to wait for


def test_simulated_time_moves_only_when_the_link_advances_it() -> None:
    clock = SimulatedClock()
    assert not clock.real_time and clock.lockstep
    assert clock.now() == 0.0
    clock.sleep(10.0)  # returns at once: waiting does not pass simulated time
    assert clock.now() == 0.0 and clock.wall(10.0) == 0.0
    clock.advance_to(1.25)
    assert clock.now() == 1.25
    assert clock != SimulatedClock() and clock == clock


def test_a_step_is_waited_for_until_the_simulator_reports_it() -> None:
    clock = SimulatedClock()
    assert clock.wait_step(0, 0.01) is None  # no simulator: the guard times out
    answered = threading.Event()

    def simulator() -> None:
        answered.wait(5.0)
        clock.step_done(0, frames_sent=7)

    thread = threading.Thread(target=simulator)
    thread.start()
    answered.set()
    assert clock.wait_step(0, 5.0) == 7
    thread.join()
    clock.step_done(3, frames_sent=9)
    assert clock.wait_step(1, 0.01) == 9  # later steps answer earlier ones too


def _read_time(clock: SimulatedClock, conn: multiprocessing.connection.Connection) -> None:
    conn.send(clock.now())


def test_a_simulator_in_another_process_reads_the_same_time() -> None:
    clock = SimulatedClock()
    clock.advance_to(42.5)
    context = multiprocessing.get_context("spawn")
    parent, child = context.Pipe()
    process = context.Process(target=_read_time, args=(clock, child))
    process.start()
    try:
        assert parent.poll(60), "the child process sent nothing"
        assert parent.recv() == 42.5
    finally:
        process.join(30)


def _leave_two_unanswered(
    clock: SimulatedClock, conn: multiprocessing.connection.Connection
) -> None:
    clock.leave_unanswered()
    clock.leave_unanswered()
    conn.send(clock.unanswered())


def test_a_simulator_in_another_process_says_which_requests_it_leaves_unanswered() -> None:
    clock = SimulatedClock()
    assert clock.unanswered() == 0
    clock.leave_unanswered()
    context = multiprocessing.get_context("spawn")
    parent, child = context.Pipe()
    process = context.Process(target=_leave_two_unanswered, args=(clock, child))
    process.start()
    try:
        assert parent.poll(60), "the child process sent nothing"
        assert parent.recv() == 3
    finally:
        process.join(30)
    assert clock.unanswered() == 3  # the link sees what the simulator counted


def _canopen_link() -> links.DriveLink:
    axes = [
        (a, {"node_id": i + 1, "increments_per_rev": 10_000})
        for i, a in enumerate(parse_machine(example_data()).axes)
    ]
    table = {"interface": "virtual", "channel": f"clock-{uuid.uuid4().hex[:8]}"}
    return link_class("canopen").from_tables(table, axes)


def test_a_link_runs_on_real_time_unless_told_otherwise() -> None:
    link = _canopen_link()
    assert link.clock is REAL_TIME
    assert link.describe()["clock"] == "real time"
    clock = SimulatedClock()
    link.use_clock(clock)
    assert link.clock is clock
    assert link.describe()["clock"] == "simulated"
    link.use_clock(REAL_TIME)
    assert link.describe()["clock"] == "real time"
    with pytest.raises(TypeError, match="LinkClock"):
        link.use_clock(4)  # type: ignore[arg-type]


def test_the_clock_cannot_change_while_the_link_is_open(tmp_path: Path) -> None:
    source = tmp_path / "source"
    axes = list(parse_machine(example_data()).axes)
    channels = channels_for([a.name for a in axes])
    with RecordingWriter.create(source, channels, nominal_period_s=0.01) as writer:
        time_s = np.arange(10, dtype=np.float64) / 100
        writer.append(SampleBlock(time_s, np.zeros((10, len(channels)))))
    link = link_class("replay").from_tables(
        {"source": str(source), "speed": 0}, [(a, {}) for a in axes]
    )
    clock = SimulatedClock()
    link.use_clock(clock)
    with link:
        with pytest.raises(LinkError, match="cannot change while it is open"):
            link.use_clock(REAL_TIME)
        assert link.clock is clock
