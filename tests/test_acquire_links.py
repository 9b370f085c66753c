"""Faults while recording through the real links: the recording keeps every sample
before the fault and marks the gap."""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ncmeasure.acquire import AcquisitionResult, record
from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.links import LinkClock
from ncmeasure.recording import Recording, read_recording
from ncmeasure.sim.cia402 import DriveScaling, SimulatedDrives
from ncmeasure.sim.modbus_drive import Fault, running_server
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


def record_while(
    config: MachineConfig, out: Path, duration_s: float, during: Callable[[], None]
) -> tuple[AcquisitionResult, Recording]:
    """Record for ``duration_s`` (link clock) while ``during`` runs in this thread."""
    results: list[AcquisitionResult] = []
    worker = threading.Thread(
        target=lambda: results.append(record(config, out=out, duration_s=duration_s)),
        daemon=True,
    )
    worker.start()
    during()
    worker.join(timeout=60)
    assert not worker.is_alive() and results
    return results[0], read_recording(out)


def assert_contiguous_until(recording: Recording, period_s: float, until_s: float) -> int:
    before = recording.time_s[recording.time_s < until_s]
    steps = np.diff(before)
    assert len(before) > 20
    assert np.allclose(steps, period_s, rtol=1e-6), "a sample before the fault is missing"
    return len(before)


@contextlib.contextmanager
def canopen_machine(
    source: SignalSource | None = None,
) -> Iterator[tuple[MachineConfig, SimulatedDrives]]:
    """Three simulated CiA 402 drives on a fresh virtual bus, and a machine to record them."""
    channel = f"acq-{uuid.uuid4().hex[:8]}"
    config = machine(
        {"type": "canopen", "interface": "virtual", "channel": channel, "sync_hz": 250}, "node_id"
    )
    scaling = DriveScaling(increments_per_rev=10_000, screw_lead_mm=20.0, rated_current_a=17.7)
    with SimulatedDrives.start(
        channel, {0: 1, 1: 2, 2: 3}, source or PatternSource(), scaling=scaling
    ) as drives:
        yield config, drives


def test_canopen_drive_that_goes_silent_leaves_a_marked_gap(tmp_path: Path) -> None:
    with canopen_machine() as (config, drives):
        fault_at: list[float] = []

        def fault() -> None:
            time.sleep(1.0)
            fault_at.append(time.monotonic())
            drives[1].stop_answering()
            time.sleep(0.5)
            drives[1].resume()

        result, recording = record_while(config, tmp_path / "run", 3.0, fault)
    assert result.status == "complete"
    gaps = [e for e in recording.events if e.kind == "gap"]
    assert gaps and gaps[0].lost_samples > 50 and gaps[0].axis == "Y"
    assert_contiguous_until(recording, 0.004, gaps[0].time_s)
    assert recording.time_s[-1] > gaps[0].time_s + 0.5  # recording went on after it
    assert recording.meta.status == "complete"


def test_canopen_reboot_is_recorded(tmp_path: Path) -> None:
    with canopen_machine() as (config, drives):

        def fault() -> None:
            time.sleep(1.0)
            drives[2].reboot(downtime_s=0.2)

        _, recording = record_while(config, tmp_path / "run", 3.0, fault)
    kinds = [e.kind for e in recording.events]
    assert "reboot" in kinds
    reboot = next(e for e in recording.events if e.kind == "reboot")
    assert reboot.axis == "Z"
    assert_contiguous_until(recording, 0.004, reboot.time_s - 0.05)
    assert recording.time_s[-1] > reboot.time_s + 1.0


def test_modbus_dropped_connection_reconnects_and_marks_it(tmp_path: Path) -> None:
    with running_server({"X": 1, "Y": 2, "Z": 3}) as server:
        config = machine(
            {"type": "modbus", "port": server.port, "register_map": "generic", "poll_hz": 100},
            "unit_id",
        )

        def fault() -> None:
            time.sleep(1.0)
            server.set_fault(Fault(silent=True))
            time.sleep(0.6)
            server.clear_faults()
            time.sleep(0.4)
            server.drop_connections()

        result, recording = record_while(config, tmp_path / "run", 4.0, fault)
    assert result.status == "complete"
    kinds = [e.kind for e in recording.events]
    assert "gap" in kinds and "reconnect" in kinds
    first_gap = next(e for e in recording.events if e.kind == "gap")
    assert first_gap.lost_samples > 0
    before = recording.time_s[recording.time_s < first_gap.time_s]
    assert len(before) > 50 and np.all(np.diff(before) < 0.1)
    assert recording.time_s[-1] > 3.0


class TimeSource:
    """Positions that encode the machine's time: 10 mm per second."""

    def state(self, axis: int, time_s: float) -> AxisState:
        return AxisState(position_mm=10.0 * time_s, velocity_mm_min=600.0, current_a=1.0)


def test_canopen_faster_than_real_time_records_machine_time(tmp_path: Path) -> None:
    with canopen_machine(TimeSource()) as (config, _):
        result = record(config, out=tmp_path / "run", duration_s=4.0, clock=LinkClock(4))
    recording = read_recording(tmp_path / "run")
    assert result.status == "complete"
    assert recording.meta.faster_than_real_time is True
    assert recording.meta.time_scale == 4.0
    assert recording.meta.link["clock_speed"] == 4.0
    assert recording.time_s[-1] - recording.time_s[0] >= 3.9
    assert result.wall_time_s < 4.0 / 2  # 4 s of machine time at 4 x real time
    for axis in "XYZ":  # every sample shows the machine at its time stamp, within a period
        error_s = np.abs(recording.column(f"{axis}_position_mm") - 10.0 * recording.time_s) / 10
        assert error_s.max() <= recording.meta.nominal_period_s + 0.002 / 10


def test_real_time_recording_says_so(tmp_path: Path) -> None:
    with canopen_machine() as (config, _):
        record(config, out=tmp_path / "run", duration_s=0.2)
    meta = read_recording(tmp_path / "run").meta
    assert meta.faster_than_real_time is False and meta.time_scale == 1.0
    assert "clock_speed" not in meta.link
