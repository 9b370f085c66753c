"""CANopen acquisition throughput: the canopen link beside a bare python-can listener.

Three simulated CiA 402 drives answer SYNC at 1 kHz with 3 TPDOs each
(position + statusword, velocity + current, velocity demand: 9 PDOs per
cycle) on python-can's virtual bus, for 10 s. In the same run and on the
same traffic two receivers listen:

- the canopen link (CanOpenLink: canopen's Network and notifier, PDO
  callbacks into the cycle assembler, rows decoded and scaled to A, mm/min,
  mm), which also produces the SYNC;
- the baseline: a can.Notifier with a minimal listener that decodes the same
  PDO frames with struct and counts them.

Printed: PDOs per second each receiver got, the rows (samples) the link
delivered and lost, and the CPU time of each part as a percentage of one core
(per-thread CPU time from /proc on Linux; process_time / wall for the whole
process, which also runs the simulated drives).

The virtual bus has no bitrate, so the bus-load check is relaxed here (9
PDOs at 1 kHz would need about 103 % of a real 1 Mbit/s bus, worst case).

Run: python benchmarks/acquisition_canopen.py [--seconds 10] [--sync-hz 1000]
"""

from __future__ import annotations

import argparse
import os
import struct
import threading
import time
import uuid
from pathlib import Path

import can

from ncmeasure.config import AxisConfig
from ncmeasure.links.canopen.link import CanOpenLink
from ncmeasure.sim.cia402 import DriveScaling, SimulatedDrives
from ncmeasure.sim.signals import PatternSource

AXES = ("X", "Y", "Z")
IPR = 10_000
LEAD_MM = 20.0
RATED_A = 10.0


class BareListener(can.Listener):
    """The baseline: decode each PDO of the layout with struct, count, keep the last values."""

    def __init__(self, nodes: int) -> None:
        self.formats: dict[int, struct.Struct] = {}
        for node in range(1, nodes + 1):
            self.formats[0x180 + node] = struct.Struct("<iH")  # position, statusword
            self.formats[0x280 + node] = struct.Struct("<ih")  # velocity, current
            self.formats[0x380 + node] = struct.Struct("<i")  # velocity demand
        self.frames = 0
        self.last: dict[int, tuple[int, ...]] = {}

    def on_message_received(self, msg: can.Message) -> None:
        fmt = self.formats.get(msg.arbitration_id)
        if fmt is not None:
            self.last[msg.arbitration_id] = fmt.unpack_from(msg.data)
            self.frames += 1


def _thread_cpu_s(threads: list[threading.Thread]) -> float | None:
    """CPU seconds (user + system) of the given threads, from /proc; None elsewhere."""
    ticks = os.sysconf("SC_CLK_TCK")
    total = 0
    for thread in threads:
        stat = Path(f"/proc/self/task/{thread.native_id}/stat")
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            return None
        total += int(fields[11]) + int(fields[12])
    return total / ticks


def _new_threads(before: set[threading.Thread]) -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t not in before]


def measure(seconds: float = 10.0, sync_hz: float = 1000.0) -> dict[str, float]:
    """Run the comparison once and return the figures (see the module docstring)."""
    channel = f"bench-canopen-{uuid.uuid4().hex}"
    nodes = {i: i + 1 for i in range(len(AXES))}
    scaling = DriveScaling(increments_per_rev=IPR, screw_lead_mm=LEAD_MM, rated_current_a=RATED_A)
    axes = [
        (
            AxisConfig(
                name=name,
                travel_mm=(0.0, 500.0),
                park_mm=10.0,
                max_velocity_mm_min=20_000,
                max_acceleration_m_s2=1.0,
                max_jerk_m_s3=10.0,
                screw_lead_mm=LEAD_MM,
                rated_current_a=RATED_A,
            ),
            {"node_id": i + 1, "increments_per_rev": IPR, "read_velocity_demand": True},
        )
        for i, name in enumerate(AXES)
    ]
    link = CanOpenLink.from_tables(
        {"channel": channel, "sync_hz": sync_hz, "max_bus_load": 2.0}, axes
    )
    before = set(threading.enumerate())
    with SimulatedDrives.start(channel, nodes, PatternSource(), scaling=scaling) as drives:
        sim_threads = _new_threads(before)
        before = set(threading.enumerate())
        bus = can.Bus(interface="virtual", channel=channel)
        bare = BareListener(len(AXES))
        notifier = can.Notifier(bus, [bare], timeout=0.1)
        bare_threads = _new_threads(before)
        before = set(threading.enumerate())
        try:
            with link:
                link_threads = [*_new_threads(before), threading.main_thread()]
                time.sleep(0.2)  # past the start
                link.read(0.0)  # rows of the start are not counted
                groups = {"link": link_threads, "baseline": bare_threads, "sim": sim_threads}
                cpu0 = {k: _thread_cpu_s(v) for k, v in groups.items()}
                stats0, frames0 = link.statistics(), bare.frames
                process0, wall0 = time.process_time(), time.perf_counter()
                rows = 0
                end = wall0 + seconds
                while time.perf_counter() < end:
                    block = link.read(0.1)
                    rows += 0 if block is None else len(block)
                wall = time.perf_counter() - wall0
                process = time.process_time() - process0
                cpu1 = {k: _thread_cpu_s(v) for k, v in groups.items()}
                stats1, frames1 = link.statistics(), bare.frames
                gaps = [e for e in link.events() if e.kind == "gap"]
                sync_seen = drives.sync_count
        finally:
            notifier.stop()
            bus.shutdown()

    def percent(group: str) -> float:
        start, stop = cpu0[group], cpu1[group]
        return float("nan") if start is None or stop is None else 100 * (stop - start) / wall

    cycles = stats1["sync_cycles"] - stats0["sync_cycles"]
    return {
        "seconds": wall,
        "sync_hz": sync_hz,
        "sync_cycles_per_s": cycles / wall,
        "pdos_per_s_expected": 3 * len(AXES) * cycles / wall,
        "link_pdos_per_s": (stats1["pdo_frames"] - stats0["pdo_frames"]) / wall,
        "baseline_pdos_per_s": (frames1 - frames0) / wall,
        "link_rows": float(rows),
        "link_rows_per_s": rows / wall,
        "link_rows_lost": float(stats1["lost_rows"] - stats0["lost_rows"]),
        "link_gap_events": float(len(gaps)),
        "link_late_frames": float(stats1["late_frames"] - stats0["late_frames"]),
        "link_cpu_percent": percent("link"),
        "baseline_cpu_percent": percent("baseline"),
        "link_cpu_us_per_pdo": 1e4 * percent("link") * wall / max(1, frames1 - frames0),
        "baseline_cpu_us_per_pdo": 1e4 * percent("baseline") * wall / max(1, frames1 - frames0),
        "simulator_cpu_percent": percent("sim"),
        "process_cpu_percent": 100 * process / wall,
        "simulator_sync_seen": float(sync_seen),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--sync-hz", type=float, default=1000.0)
    args = parser.parse_args()
    for name, value in measure(args.seconds, args.sync_hz).items():
        print(f"{name:<24} {value:12.1f}")


if __name__ == "__main__":
    main()
