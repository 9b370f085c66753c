"""Faults while recording through the real links: the recording keeps every sample
before the fault and marks the gap."""

from __future__ import annotations

import contextlib
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.acquire import record
from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.recording import Recording, read_recording
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.cia402 import DriveScaling, SimulatedDrives
from ncmeasure.sim.modbus_drive import Fault, running_server
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.signals import AxisState, PatternSource, SignalSource
from tests.conftest import example_data


def machine(link: dict[str, Any], axis_key: str) -> MachineConfig:
    data = example_data()
    data["link"] = link
    for i, axis in enumerate(data["axes"]):
        axis["link"] = {axis_key: i + 1}
        if axis_key == "node_id":
            axis["link"]["increments_per_rev"] = 10_000
    return parse_machine(data)


def assert_contiguous_until(recording: Recording, period_s: float, until_s: float) -> int:
    before = recording.time_s[recording.time_s < until_s]
    steps = np.diff(before)
    assert len(before) > 20
    assert np.allclose(steps, period_s, rtol=1e-6), "a sample before the fault is missing"
    return len(before)


@contextlib.contextmanager
def canopen_machine(
    source: SignalSource | None = None,
    clock: SimulatedClock | None = None,
    channel: str | None = None,
) -> Iterator[tuple[MachineConfig, SimulatedDrives]]:
    """Three simulated CiA 402 drives on a fresh virtual bus, and a machine to record them."""
    channel = channel or f"acq-{uuid.uuid4().hex[:8]}"
    # the drives answer SDO from this process' threads: the time-out only guards against a
    # hang, however busy the host (as the demo does)
    config = machine(
        {
            "type": "canopen",
            "interface": "virtual",
            "channel": channel,
            "sync_hz": 250,
            "sdo_timeout_s": 30.0,
        },
        "node_id",
    )
    scaling = {  # the drives move the axes the link reads
        i: DriveScaling(mechanics=rig_mechanics(axis.mechanics()), increments_per_rev=10_000)
        for i, axis in enumerate(config.axes)
    }
    with SimulatedDrives.start(
        channel, {0: 1, 1: 2, 2: 3}, source or PatternSource(), scaling=scaling, clock=clock
    ) as drives:
        yield config, drives


def test_canopen_drive_that_goes_silent_leaves_a_marked_gap(tmp_path: Path) -> None:
    clock = SimulatedClock()
    with canopen_machine(clock=clock) as (config, drives):
        drives.at_sync(250, drives[1].stop_answering)  # at 1.0 s of machine time
        drives.at_sync(375, drives[1].resume)  # 0.5 s later
        result = record(config, out=tmp_path / "run", duration_s=3.0, clock=clock)
    recording = read_recording(tmp_path / "run")
    assert result.status == "incomplete"  # a recording that lost samples is not complete
    assert (result.gaps, result.lost_samples) == (1, 125)
    gap = next(e for e in recording.events if e.kind == "gap")
    assert gap.time_s == pytest.approx(1.0) and gap.axis == "Y"
    assert assert_contiguous_until(recording, 0.004, gap.time_s) == 250
    assert len(recording) == 750 - 125  # 3 s at 250 Hz, less the gap
    assert (recording.meta.status, recording.meta.gaps, recording.meta.lost_samples) == (
        "incomplete",
        1,
        125,
    )


def test_canopen_reboot_is_recorded(tmp_path: Path) -> None:
    clock = SimulatedClock()
    with canopen_machine(clock=clock) as (config, drives):
        drives.at_sync(250, drives[2].reboot)
        result = record(config, out=tmp_path / "run", duration_s=3.0, clock=clock)
    recording = read_recording(tmp_path / "run")
    reboot = next(e for e in recording.events if e.kind == "reboot")
    assert reboot.axis == "Z" and reboot.time_s == pytest.approx(1.0)
    assert assert_contiguous_until(recording, 0.004, reboot.time_s) == 250
    assert result.lost_samples == 1  # only the cycle of the reboot: no SYNC while reconfiguring
    assert len(recording) == 749


def test_modbus_outage_and_dropped_connection_are_marked(tmp_path: Path) -> None:
    clock = SimulatedClock()
    with running_server({"X": 1, "Y": 2, "Z": 3}, clock=clock) as server:
        config = machine(
            {
                "type": "modbus",
                "port": server.port,
                "register_map": "generic",
                "poll_hz": 100,
                "timeout_s": 0.1,
                "retries": 0,
            },
            "unit_id",
        )
        server.set_fault(Fault(silent=True, from_s=1.0, until_s=1.1))
        result = record(config, out=tmp_path / "silent", duration_s=2.0, clock=clock)
        server.clear_faults()
    recording = read_recording(tmp_path / "silent")
    gap = next(e for e in recording.events if e.kind == "gap")
    assert result.status == "incomplete" and gap.time_s == pytest.approx(1.0)
    assert result.lost_samples == 10  # the 10 poll cycles of the silent 0.1 s
    assert assert_contiguous_until(recording, 0.01, gap.time_s) == 100
    assert np.allclose(np.diff(recording.time_s[recording.time_s > 1.1]), 0.01)

    clock = SimulatedClock()
    with running_server({"X": 1, "Y": 2, "Z": 3}, clock=clock) as server:
        config = machine(
            {"type": "modbus", "port": server.port, "register_map": "generic", "poll_hz": 100},
            "unit_id",
        )
        server.set_fault(Fault(disconnect=True, from_s=1.0, until_s=1.005))
        result = record(config, out=tmp_path / "dropped", duration_s=3.0, clock=clock)
    recording = read_recording(tmp_path / "dropped")
    kinds = [e.kind for e in recording.events]
    assert "gap" in kinds and "reconnect" in kinds
    # the cycle at 1.0 s fails; the link waits reconnect_delay_s (0.5 s) of link time
    assert result.lost_samples == 50
    assert recording.time_s[-1] == pytest.approx(2.99)


class TimeSource:
    """Positions that encode the machine's time: 10 mm per second."""

    def state(self, axis: int, time_s: float) -> AxisState:
        return AxisState(position_mm=10.0 * time_s, velocity_mm_min=600.0, current_a=1.0)


def test_canopen_in_lockstep_records_machine_time(tmp_path: Path) -> None:
    clock = SimulatedClock()
    with canopen_machine(TimeSource(), clock=clock) as (config, _):
        result = record(config, out=tmp_path / "run", duration_s=4.0, clock=clock)
    recording = read_recording(tmp_path / "run")
    assert result.status == "complete" and result.rows == 1000
    assert recording.meta.faster_than_real_time is True
    assert recording.meta.time_scale == 0.0  # as fast as the computer allows
    assert recording.meta.link["clock"] == "simulated"
    np.testing.assert_allclose(recording.time_s, np.arange(1000) * 0.004, rtol=0, atol=1e-12)
    for axis in "XYZ":  # every sample is the machine at its time stamp
        position = recording.column(f"{axis}_position_mm")
        np.testing.assert_allclose(position, 10.0 * recording.time_s, atol=0.002)


def test_real_time_recording_says_so(tmp_path: Path) -> None:
    with canopen_machine() as (config, _):
        record(config, out=tmp_path / "run", duration_s=0.2)
    meta = read_recording(tmp_path / "run").meta
    assert meta.faster_than_real_time is False and meta.time_scale == 1.0
    assert meta.link["clock"] == "real time"
