"""The link clock: real time, or a virtual machine's time running faster than real time."""

from __future__ import annotations

import math
import pickle
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
from ncmeasure.samples import SampleBlock, channels_for
from tests.conftest import example_data


@pytest.mark.parametrize("speed", [0.0, -1.0, math.nan, math.inf])
def test_speed_must_be_finite_and_positive(speed: float) -> None:
    with pytest.raises(ValueError, match="finite and positive"):
        LinkClock(speed)


def test_real_time_is_speed_one_and_exported() -> None:
    assert links.REAL_TIME is REAL_TIME and links.LinkClock is LinkClock
    assert REAL_TIME.speed == 1.0 and REAL_TIME.real_time
    assert LinkClock() == REAL_TIME
    assert not LinkClock(4).real_time


def test_now_runs_at_its_speed_on_the_perf_counter() -> None:
    clock = LinkClock(4)
    before = time.perf_counter()
    reading = clock.now()
    after = time.perf_counter()
    assert 4 * before <= reading <= 4 * after


def test_sleep_and_wall_convert_to_wall_clock_seconds() -> None:
    clock = LinkClock(4)
    assert clock.wall(2.0) == 0.5
    assert REAL_TIME.wall(2.0) == 2.0
    start = clock.now()
    clock.sleep(0.2)  # 0.05 s of wall-clock time
    assert clock.now() - start >= 0.2
    clock.sleep(0.0)
    clock.sleep(-1.0)  # nothing to wait for


def test_a_clock_pickles_for_a_server_process() -> None:
    clock = pickle.loads(pickle.dumps(LinkClock(2.5)))
    assert clock == LinkClock(2.5) and clock.speed == 2.5


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
    assert "clock_speed" not in link.describe()
    link.use_clock(LinkClock(4))
    assert link.clock.speed == 4
    assert link.describe()["clock_speed"] == 4
    link.use_clock(REAL_TIME)
    assert "clock_speed" not in link.describe()
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
    link.use_clock(LinkClock(2))
    with link:
        with pytest.raises(LinkError, match="cannot change while it is open"):
            link.use_clock(REAL_TIME)
        assert link.clock.speed == 2
