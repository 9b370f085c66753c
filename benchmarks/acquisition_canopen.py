"""CANopen acquisition CPU: the canopen link beside a bare python-can receiver, same work.

Three simulated CiA 402 drives answer SYNC at 1 kHz with 3 TPDOs each
(position + statusword, velocity + current, velocity demand: 9 PDOs per
cycle) on python-can's virtual bus. Rounds alternate (A B A B …, the order
swapped every round), each on a fresh bus with fresh drives:

- **link**: ``CanOpenLink`` produces SYNC, receives the PDOs, assembles the
  rows by SYNC cycle, decodes and scales them to A, mm/min, mm; the main
  thread reads blocks with ``link.read``;
- **bare**: the same work with python-can alone: a SYNC thread on the same
  absolute schedule (missed cycles skipped, never sent in a burst), a
  ``can.Notifier`` whose listener decodes each PDO of the same layout with
  ``struct`` into the row of its SYNC cycle (own SYNCs in bus order, as the
  link does), and the main thread taking the finished rows every 0.1 s as a
  scaled numpy block.

The drives are configured for both by the link (SDO, the same TPDO layout);
for the bare round the link is closed again and the drives started by NMT.

The simulated drives answer SYNC *on the bus* by default (``--drives
on_send``): within the SYNC's send, behind the SYNC and ahead of the next,
as real drives answer in their synchronous window whatever the host does.
A row lost is then one the receiving side lost. With ``--drives thread``
the drives' own thread answers, as the host schedules it; a Python thread
woken late answers after the next SYNC, and that row is lost on either side
("late drive answers").

CPU is taken per thread (``pthread_getcpuclockid``): the link's threads
(receive, SYNC, worker) plus the reading main thread, against the bare
receive, SYNC and main threads. The simulated drives' work counts on neither
side: their thread is left out, and the time spent answering SYNC within the
sender's thread (``SimulatedDrives.answer_cpu_s``) is taken off that side.
Printed per round and as median [min–max]: CPU % of one core, µs per PDO,
rows, rows lost, SYNC cycles skipped, late drive answers; the ratio link /
bare of each round, and the goal. First, how often a lone thread woken every
period wakes more than a period late on this computer.

The virtual bus has no bitrate, so the bus-load check is relaxed here (9
PDOs at 1 kHz would need about 103 % of a real 1 Mbit/s bus, worst case).

**The SYNC rate on a busy PC** (``--busy``): the achieved SYNC rate (SYNCs on
the bus per second), the share of cycles the producer skipped, and the rows
lost as this benchmark counted them before (skipped cycles left out: "0 rows
lost"), idle and under two busy loops (``python -c "while True: pass"``,
started and killed here). Three producers, interleaved: the link as it is
(``sync_priority`` 20: ``SCHED_FIFO`` and the GIL handed over within half a
period), the link's old producer (``sync_priority = 0``) and the bare
python-can SYNC thread. CPU of the measuring process as well as wall time.

Run: python benchmarks/acquisition_canopen.py [--seconds 5] [--rounds 5]
[--drives on_send|thread] [--busy] [--short]
``--short`` (CI): one round of 1 s each, and the SYNC rate for 0.5 s idle and under
the busy loops; fails only on a crash, never on a figure.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import struct
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import can
import numpy as np

from ncmeasure.config import AxisConfig
from ncmeasure.links.canopen.link import CanOpenLink
from ncmeasure.sim.cia402 import DriveScaling, SimulatedDrives
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.signals import PatternSource

Answer = Literal["on_send", "thread"]
AXES = ("X", "Y", "Z")
IPR = 10_000
LEAD_MM = 20.0
RATED_A = 10.0
GOAL_RATIO = 1.2
_STRUCT_CODES = {
    "int8": "b",
    "int16": "h",
    "int32": "i",
    "uint8": "B",
    "uint16": "H",
    "uint32": "I",
}


def _thread_cpu_s(threads: list[threading.Thread]) -> dict[str, float]:
    """CPU seconds (user + system) of each of the given live threads, by name."""
    cpu: dict[str, float] = {}
    for thread in threads:
        if thread.ident is None or not thread.is_alive():
            continue
        name = "main" if thread is threading.main_thread() else thread.name.split(" ")[0]
        with contextlib.suppress(OSError, ValueError):  # the thread ended meanwhile
            cpu[name] = time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
    return cpu


def _cpu_delta(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    return {name: after[name] - before.get(name, 0.0) for name in after}


def _new_threads(before: set[threading.Thread]) -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t not in before]


def _link(channel: str, sync_hz: float, priority: int | None = None) -> CanOpenLink:
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
    table: dict[str, Any] = {"channel": channel, "sync_hz": sync_hz, "max_bus_load": 2.0}
    if priority is not None:
        table["sync_priority"] = priority
    return CanOpenLink.from_tables(table, axes)


@dataclass
class Round:
    """What one side did in one measuring window."""

    side: str
    seconds: float
    cpu_s: float
    pdos: int
    rows: int
    lost: int
    skipped: int
    by_thread: dict[str, float]
    late: int = 0
    """SYNCs the simulated drives' thread answered after the next SYNC (host stalls)."""
    syncs: int = 0
    """SYNCs on the bus in the window."""
    process_cpu_s: float = 0.0
    """CPU of the whole measuring process in the window (``time.process_time``)."""

    @property
    def sync_hz(self) -> float:
        return self.syncs / self.seconds

    @property
    def skipped_share(self) -> float:
        return self.skipped / max(1, self.syncs + self.skipped)

    @property
    def cpu_percent(self) -> float:
        return 100 * self.cpu_s / self.seconds

    @property
    def us_per_pdo(self) -> float:
        return 1e6 * self.cpu_s / max(1, self.pdos)


def _window(seconds: float, step: Callable[[], None]) -> float:
    start = time.perf_counter()
    end = start + seconds
    while time.perf_counter() < end:
        step()
    return time.perf_counter() - start


def _drives(answer: Answer) -> tuple[str, SimulatedDrives]:
    """Fresh simulated drives, started on a fresh virtual channel, and that channel."""
    channel = f"bench-canopen-{uuid.uuid4().hex}"
    nodes = {i: i + 1 for i in range(len(AXES))}
    mechanics = rig_mechanics(screw_lead_mm=LEAD_MM, rated_current_a=RATED_A)
    scaling = DriveScaling(mechanics=mechanics, increments_per_rev=IPR)
    drives = SimulatedDrives.start(channel, nodes, PatternSource(), scaling=scaling, answer=answer)
    return channel, drives


def _drives_cost(drives: SimulatedDrives) -> tuple[int, float]:
    """The drives' late answers and the CPU seconds spent answering in the senders' threads."""
    return drives.late_answers, drives.answer_cpu_s


def run_link(
    seconds: float, sync_hz: float, priority: int | None = None, answer: Answer = "on_send"
) -> Round:
    """One round of the link: SYNC, PDOs, rows read in blocks by the main thread."""
    channel, drives = _drives(answer)
    with drives:
        link = _link(channel, sync_hz, priority)
        before = set(threading.enumerate())
        with link:
            threads = [*_new_threads(before), threading.main_thread()]
            time.sleep(0.2)  # past the start
            link.read(0.0)  # rows of the start are not counted
            rows = 0

            def step() -> None:
                nonlocal rows
                block = link.read(0.1)
                rows += 0 if block is None else len(block)

            stats0, cpu0, cost0 = link.statistics(), _thread_cpu_s(threads), _drives_cost(drives)
            process0 = time.process_time()
            wall = _window(seconds, step)
            process_cpu_s = time.process_time() - process0
            cpu1, stats1, cost1 = _thread_cpu_s(threads), link.statistics(), _drives_cost(drives)

    def delta(key: str) -> int:
        return stats1.get(key, 0) - stats0.get(key, 0)

    cpu = _cpu_delta(cpu0, cpu1)
    return Round(
        "link", wall, sum(cpu.values()) - (cost1[1] - cost0[1]), delta("pdo_frames"), rows,
        delta("lost_rows") - delta("lost_no_sync"),  # cycles without SYNC: skipped, apart
        delta("sync_skipped"), cpu, cost1[0] - cost0[0], delta("sync_cycles"), process_cpu_s,
    )  # fmt: skip


class BareReceiver(can.Listener):
    """The baseline's receive side: PDOs decoded with struct into the row of their SYNC cycle."""

    def __init__(self, layout: dict[int, tuple[int, struct.Struct]], width: int) -> None:
        self.layout = layout  # COB-ID -> (first raw column, decoder)
        self.slots = len(layout)
        self.width = width
        self.row: list[int] = [0] * width
        self.filled = 0
        self.started = False
        self.rows: list[list[int]] = []
        self.lock = threading.Lock()
        self.pdos = 0
        self.lost = 0

    def on_message_received(self, msg: can.Message) -> None:
        entry = self.layout.get(msg.arbitration_id)
        if entry is not None:
            first, decoder = entry
            values = decoder.unpack_from(msg.data)
            self.row[first : first + len(values)] = values
            self.filled += 1
            self.pdos += 1
        elif msg.arbitration_id == 0x80 and not msg.is_rx:  # own SYNC, in bus order
            if self.started:
                if self.filled == self.slots:
                    with self.lock:
                        self.rows.append(self.row)
                else:
                    self.lost += 1
            self.started = True
            self.row = [0] * self.width
            self.filled = 0

    def take(self) -> list[list[int]]:
        with self.lock:
            rows, self.rows = self.rows, []
        return rows


def _bare_layout(link: CanOpenLink) -> tuple[dict[int, tuple[int, struct.Struct]], list[float]]:
    """The PDO layout and scale of every raw column, as the link configured the drives."""
    layout: dict[int, tuple[int, struct.Struct]] = {}
    scales: list[float] = []
    for axis in link.describe()["scales"].values():
        factor = {
            "position": axis["position_mm_per_increment"],
            "velocity": axis["velocity_mm_min_per_unit"],
            "velocity_demand": axis["velocity_mm_min_per_unit"],
            "current": axis["current_a_per_unit"],
            "statusword": 1.0,
        }
        for tpdo in axis["tpdos"]:
            codes = "".join(_STRUCT_CODES[axis["objects"][r]["type"]] for r in tpdo["roles"])
            layout[int(tpdo["cob_id"], 16)] = (len(scales), struct.Struct("<" + codes))
            scales += [factor[r] for r in tpdo["roles"]]
    return layout, scales


def run_bare(seconds: float, sync_hz: float, answer: Answer = "on_send") -> Round:
    """One round of the baseline: the same SYNC, PDOs, rows and scaled blocks, python-can only."""
    channel, drives = _drives(answer)
    with drives:
        link = _link(channel, sync_hz)
        with link:  # configures the drives' TPDOs over SDO, as in the link's round
            layout, scales = _bare_layout(link)
        period = 1.0 / sync_hz
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=True)
        receiver = BareReceiver(layout, len(scales))
        stop = threading.Event()
        skipped = syncs = 0

        def produce_sync() -> None:
            nonlocal skipped, syncs
            start = time.perf_counter()
            cycle = 0
            sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
            while not stop.is_set():
                delay = start + cycle * period - time.perf_counter()
                if delay > 0 and stop.wait(delay):
                    return
                newest = int((time.perf_counter() - start) / period)
                if newest > cycle:  # the next one is due already: skip, never a burst
                    skipped += newest - cycle
                    cycle = newest
                bus.send(sync)
                syncs += 1
                cycle += 1

        before = set(threading.enumerate())
        notifier = can.Notifier(bus, [receiver], timeout=0.1)
        bus.send(can.Message(arbitration_id=0x000, data=b"\x01\x00", is_extended_id=False))
        sync_thread = threading.Thread(target=produce_sync, name="bare-sync", daemon=True)
        sync_thread.start()
        threads = [*_new_threads(before), threading.main_thread()]
        scale = np.array(scales)
        try:
            time.sleep(0.2)
            receiver.take()
            rows = 0

            def step() -> None:
                nonlocal rows
                time.sleep(0.1)
                taken = receiver.take()
                if taken:
                    _block = np.array(taken, dtype=np.float64) * scale
                    rows += len(taken)

            pdos0, lost0, skipped0, syncs0 = receiver.pdos, receiver.lost, skipped, syncs
            cpu0, cost0 = _thread_cpu_s(threads), _drives_cost(drives)
            process0 = time.process_time()
            wall = _window(seconds, step)
            process_cpu_s = time.process_time() - process0
            cpu1, cost1 = _thread_cpu_s(threads), _drives_cost(drives)
            pdos, lost, skip = receiver.pdos - pdos0, receiver.lost - lost0, skipped - skipped0
            sent = syncs - syncs0
        finally:
            stop.set()
            sync_thread.join(2.0)
            notifier.stop()
            bus.shutdown()
    cpu = _cpu_delta(cpu0, cpu1)
    cpu_s = sum(cpu.values()) - (cost1[1] - cost0[1])
    return Round(
        "bare", wall, cpu_s, pdos, rows, lost, skip, cpu, cost1[0] - cost0[0], sent, process_cpu_s
    )


def wake_ups(seconds: float, period_s: float) -> tuple[int, int, float]:
    """A lone Python thread waking on an absolute schedule of ``period_s``, as the SYNC
    producer and the drives' thread do: (wake-ups, those more than a period late,
    the latest in s). What this computer's scheduler allows any 1 kHz thread here."""
    wake = threading.Event()
    start = time.perf_counter()
    count = late = 0
    worst = 0.0
    while (due := start + count * period_s) < start + seconds:
        delay = due - time.perf_counter()
        if delay > 0:
            wake.wait(delay)
        behind = time.perf_counter() - due
        late += behind > period_s
        worst = max(worst, behind)
        count += 1
    return count, late, worst


def _spread(values: list[float], fmt: str = "{:.1f}") -> str:
    median = statistics.median(values)
    if len(values) == 1:
        return fmt.format(median)
    return f"{fmt.format(median)} [{fmt.format(min(values))}–{fmt.format(max(values))}]"


def measure(
    seconds: float,
    rounds: int,
    sync_hz: float,
    show: bool = True,
    threads: bool = False,
    answer: Answer = "on_send",
) -> dict[str, Any]:
    """Alternate link and bare rounds; return per-side rounds and the per-round ratios."""
    results: dict[str, list[Round]] = {"link": [], "bare": []}
    for index in range(rounds):
        order = ("link", "bare") if index % 2 == 0 else ("bare", "link")
        for side in order:
            run = run_link if side == "link" else run_bare
            result = run(seconds, sync_hz, answer=answer)
            results[side].append(result)
            if show:
                print(
                    f"round {index + 1} {side:<4}: {result.cpu_percent:5.1f} % CPU, "
                    f"{result.us_per_pdo:5.1f} µs/PDO, {result.rows} rows, "
                    f"{result.lost} lost, {result.skipped} SYNC skipped, "
                    f"{result.late} late drive answers",
                    flush=True,
                )
                if threads:
                    for name, cpu_s in sorted(result.by_thread.items()):
                        print(f"    {name:<28} {100 * cpu_s / result.seconds:5.1f} %")
    ratios = [
        link.cpu_s / link.pdos / (bare.cpu_s / bare.pdos)
        for link, bare in zip(results["link"], results["bare"], strict=True)
    ]
    return {**results, "ratios": ratios}


@contextlib.contextmanager
def busy_loops(count: int) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``count`` processes spinning ``while True: pass``, killed on the way out."""
    loops: list[subprocess.Popen[bytes]] = []
    try:
        for _ in range(count):
            loops.append(subprocess.Popen([sys.executable, "-c", "while True: pass"]))
        time.sleep(0.3)  # they run before the first round starts
        yield loops
    finally:
        for loop in loops:
            loop.kill()
        for loop in loops:
            loop.wait(timeout=10)


#: The producers the SYNC-rate section compares: name, what it is, how to run one round.
PRODUCERS: tuple[tuple[str, str, Callable[[float, float], Round]], ...] = (
    ("link", "the link (sync_priority 20)", lambda s, hz: run_link(s, hz)),
    ("old", "the link's old producer (sync_priority 0)", lambda s, hz: run_link(s, hz, 0)),
    ("bare", "bare python-can SYNC thread", lambda s, hz: run_bare(s, hz)),
)


def sync_rate(seconds: float, rounds: int, sync_hz: float, loops: int) -> dict[str, list[Round]]:
    """Rounds of every producer, interleaved (order rotated), under ``loops`` busy loops."""
    results: dict[str, list[Round]] = {name: [] for name, _, _ in PRODUCERS}
    with busy_loops(loops):
        for index in range(rounds):
            for offset in range(len(PRODUCERS)):
                name, _, run = PRODUCERS[(index + offset) % len(PRODUCERS)]
                results[name].append(run(seconds, sync_hz))
    return results


def _load() -> str:
    try:
        return Path("/proc/loadavg").read_text().split(" ", 1)[0]
    except OSError:
        return "unknown"


def print_sync_rate(seconds: float, rounds: int, sync_hz: float) -> None:
    """The achieved SYNC rate and skipped share, idle and under two busy loops."""
    print(
        f"\nSYNC rate at {sync_hz:g} Hz, {rounds} round(s) of {seconds:g} s per producer, "
        "interleaved; load average before: " + _load()
    )
    print(
        f"{'':<12} {'producer':<42} {'SYNC/s':>16} {'skipped %':>18} {'rows':>7} "
        f"{'rows lost (old figure)':>23} {'process CPU %':>14}"
    )
    for label, loops in (("idle", 0), ("2 busy loops", 2)):
        results = sync_rate(seconds, rounds, sync_hz, loops)
        for name, what, _ in PRODUCERS:
            got = results[name]
            print(
                f"{label:<12} {what:<42} {_spread([r.sync_hz for r in got], '{:.0f}'):>16} "
                f"{_spread([100 * r.skipped_share for r in got], '{:.2f}'):>18} "
                f"{sum(r.rows for r in got):>7} {sum(r.lost for r in got):>23} "
                f"{_spread([100 * r.process_cpu_s / r.seconds for r in got]):>14}"
            )
    print(
        "rows lost (old figure): rows lost with the skipped cycles left out, as this benchmark "
        "reported them before; every skipped cycle is a lost sample in the recording, counted "
        "apart (meta.json skipped_cycles, skipped_share). Goal: the configured rate under two "
        "busy loops"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="per round and side")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--sync-hz", type=float, default=1000.0)
    parser.add_argument("--short", action="store_true", help="one round of 1 s (CI)")
    parser.add_argument("--threads", action="store_true", help="CPU of each thread too")
    parser.add_argument(
        "--busy",
        action="store_true",
        help="only the SYNC rate: idle and under two busy loops, three producers",
    )
    parser.add_argument(
        "--drives",
        choices=("on_send", "thread"),
        default="on_send",
        help="who answers SYNC: the bus, within the SYNC's send, as real drives in their "
        "synchronous window (default); or the simulated drives' own thread, as the host "
        "schedules it",
    )
    args = parser.parse_args()
    if args.busy:
        print_sync_rate(args.seconds, args.rounds, args.sync_hz)
        return
    if args.short:
        args.seconds, args.rounds = 1.0, 1
    print(
        f"CANopen, {len(AXES)} drives × 3 TPDOs, SYNC {args.sync_hz:g} Hz, virtual bus; "
        f"{args.rounds} rounds of {args.seconds:g} s per side, interleaved"
    )
    probe_s = min(args.seconds, 5.0)
    count, late, worst = wake_ups(probe_s, 1.0 / args.sync_hz)
    print(
        f"this computer: a lone thread woken every {1e3 / args.sync_hz:g} ms for {probe_s:g} s "
        f"woke more than a period late {late} times in {count} (latest {worst * 1e3:.1f} ms)"
    )
    print(
        "simulated drives answer SYNC "
        + (
            "on the bus, within the SYNC's send (their CPU is counted on neither side)"
            if args.drives == "on_send"
            else "from their own thread, as the host schedules it"
        )
    )
    result = measure(
        args.seconds, args.rounds, args.sync_hz, threads=args.threads, answer=args.drives
    )
    print(
        f"{'':<6} {'CPU % of a core':>24} {'µs CPU per PDO':>24} {'lost':>6} {'skipped':>8} "
        f"{'late answers':>13}"
    )
    for side in ("link", "bare"):
        rounds: list[Round] = result[side]
        print(
            f"{side:<6} {_spread([r.cpu_percent for r in rounds]):>24} "
            f"{_spread([r.us_per_pdo for r in rounds], '{:.2f}'):>24} "
            f"{sum(r.lost for r in rounds):>6} {sum(r.skipped for r in rounds):>8} "
            f"{sum(r.late for r in rounds):>13}"
        )
        unexplained = sum(max(0, r.lost - 2 * r.late) for r in rounds)
        print(
            f"{'':<6} rows lost beyond two per late drive answer (the link's own losses): "
            f"{unexplained}"
        )
    print(
        f"ratio link/bare CPU per PDO: {_spread(result['ratios'], '{:.2f}')} "
        f"(goal ≤ {GOAL_RATIO:g}×, 0 rows lost on an idle machine)"
    )
    if args.short:
        print_sync_rate(0.5, 1, args.sync_hz)


if __name__ == "__main__":
    main()
