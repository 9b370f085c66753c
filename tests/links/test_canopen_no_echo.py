"""The CANopen link producing SYNC on interfaces that do not return its own SYNC frames.

slcan through an emulated Lawicel adapter on a loopback socket (:mod:`.slcan_emulator`),
python-can's virtual bus with ``sync_echo = false``, and udp_multicast on the loopback.
Link and drives run in lockstep on a :class:`~ncmeasure.samples.SimulatedClock`, so what
a test sees does not depend on how busy the computer is; the emulator drops, doubles
and delays frames at SYNC indices. Every row must be the drives' values of its own
cycle, exactly; the cycles that cannot be told apart are lost and counted.
"""

from __future__ import annotations

import uuid
from typing import Any

import numpy as np
import pytest

from ncmeasure.links.canopen.link import CanOpenLink
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.cia402 import SimulatedDrives
from tests.links.slcan_emulator import Fault, SlcanAdapter
from tests.links.test_canopen import IPR, LEAD_MM, SCALING, Recorder, TimeSource, make

CYCLES = 300
SYNC_HZ = 100


def assert_rows_are_their_cycles(rec: Recorder, n_axes: int = 2) -> None:
    """Every position is the source's at the row's own time: no row holds another cycle."""
    times = np.asarray(rec.times)
    positions = np.asarray(rec.rows)[:, [3 * axis + 2 for axis in range(n_axes)]]
    step = LEAD_MM / IPR
    for axis in range(n_axes):
        want = np.rint((10.0 * times + axis) / step) * step
        np.testing.assert_allclose(positions[:, axis], want, atol=1e-9)


def lost_cycles(rec: Recorder) -> set[int]:
    """The cycles up to the last row without a row; the gap events must cover exactly them."""
    cycles = rec.cycles
    assert np.all(np.diff(cycles) > 0), "rows out of order or repeated"
    missing = set(range(cycles[-1] + 1)) - set(cycles.tolist())
    covered: set[int] = set()
    for gap in rec.kinds("gap"):
        span = range(gap.details["first_cycle"], gap.details["last_cycle"] + 1)
        assert gap.lost_samples == len(span)
        covered |= set(span)
    assert missing <= covered
    return missing


def record(link: CanOpenLink) -> Recorder:
    with link:
        rec = Recorder(link)
        rec.until(lambda: bool(rec.times) and rec.cycles[-1] >= CYCLES - 1)
        rec.stats = link.statistics()  # type: ignore[attr-defined]
    return rec


def slcan_link(adapter: SlcanAdapter, clock: SimulatedClock, **settings: Any) -> CanOpenLink:
    return make(
        adapter.url,
        n_axes=2,
        clock=clock,
        sync_hz=SYNC_HZ,
        interface="slcan",
        bus_options={"sleep_after_open": 0},
        **settings,
    )


def test_slcan_rows_are_exact_and_faulty_cycles_lost_never_shifted() -> None:
    """300 cycles at 100 Hz over an emulated SLCAN adapter: values exact against the drives.

    A dropped frame loses its cycle and the next (the next frame of that TPDO could be its
    late one); a frame delivered after the next SYNC loses both cycles; a doubled frame
    loses its cycle. Before this change the link refused slcan at open ("does not return
    the link's own SYNC frames").
    """
    channel = f"ncm-slcan-{uuid.uuid4().hex}-bus"
    faults: dict[tuple[int, int], Fault] = {
        (50, 0x182): "drop",
        (100, 0x281): "late",
        (150, 0x181): "double",
        (200, 0x182): "late",
        (201, 0x182): "late",
        (250, 0x182): "double",
        (250, 0x282): "drop",
    }
    clock = SimulatedClock()
    with SlcanAdapter(channel, faults, clock=clock) as adapter:
        drive_clock = adapter.drive_clock()
        with SimulatedDrives.start(
            channel, {0: 1, 1: 2}, TimeSource(), scaling=SCALING, clock=drive_clock
        ):
            rec = record(slcan_link(adapter, clock))
        assert {(c, cob) for c, cob, _ in adapter.injected} == set(faults)
        assert adapter.commands[-1] == "C"  # the link closed the adapter
        assert "O" in adapter.commands
    assert_rows_are_their_cycles(rec)
    lost = lost_cycles(rec)
    assert lost == {50, 51, 100, 101, 150, 200, 201, 202, 250, 251}
    stats = rec.stats  # type: ignore[attr-defined]
    assert stats["lost_rows"] == len(lost)
    assert stats["rows"] == len(rec.times) >= CYCLES - len(lost)
    texts = " ".join(e.message for e in rec.kinds("gap"))
    assert "cannot be told apart" in texts and "returns no own SYNC" in texts


def test_virtual_bus_without_own_frames_is_exact_and_a_silent_drive_is_a_counted_gap() -> None:
    """python-can's virtual bus with receive_own_messages off (sync_echo = false)."""
    channel = f"ncm-noecho-{uuid.uuid4().hex}-bus"
    clock = SimulatedClock()
    with SimulatedDrives.start(
        channel, {0: 1, 1: 2}, TimeSource(), scaling=SCALING, clock=clock
    ) as drives:
        drives.at_sync(100, drives[1].stop_answering)
        drives.at_sync(110, drives[1].resume)
        link = make(channel, n_axes=2, clock=clock, sync_hz=SYNC_HZ, sync_echo=False)
        assert not link._make_bus().receive_own_messages  # type: ignore[attr-defined]
        rec = record(link)
    assert_rows_are_their_cycles(rec)
    lost = lost_cycles(rec)
    # The silent cycles; the first answer after them could be the last silent cycle's.
    assert set(range(100, 110)) <= lost <= set(range(100, 112))
    assert rec.stats["lost_rows"] == len(lost)  # type: ignore[attr-defined]
    assert all(e.axis == "Y" for e in rec.kinds("gap") if "no PDOs" in e.message)


def test_udp_multicast_records_exact_rows() -> None:
    """udp_multicast on the loopback (needs msgpack; its own frames come back as received)."""
    pytest.importorskip("msgpack")
    group = f"239.74.{uuid.uuid4().int % 250 + 1}.{uuid.uuid4().int % 250 + 1}"
    options = {"port": 43000 + uuid.uuid4().int % 2000}
    clock = SimulatedClock()
    with SimulatedDrives.start(
        group,
        {0: 1, 1: 2},
        TimeSource(),
        interface="udp_multicast",
        bus_options=options,
        scaling=SCALING,
        clock=clock,
    ):
        link = make(
            group,
            n_axes=2,
            clock=clock,
            sync_hz=SYNC_HZ,
            interface="udp_multicast",
            bus_options=options,
        )
        rec = record(link)
    assert_rows_are_their_cycles(rec)
    assert lost_cycles(rec) == set()
