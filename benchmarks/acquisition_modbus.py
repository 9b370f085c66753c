"""Modbus TCP polling: the Modbus link beside a bare pymodbus async client doing the same work.

A simulated drive server (3 units, generic register map, deterministic: the
n-th answered request of a unit shows the machine at ``n × 1 ms``) runs in
another process on 127.0.0.1. Rounds alternate (A B A B …, the order swapped
every round), each polling flat out for N seconds:

- **link**: ``ModbusLink`` with ``poll_hz = 10000``, far above what a cycle
  can do: one request per axis and cycle, decode, scale, time stamp, queue;
  the main thread reads blocks with ``link.read``;
- **bare async**: pymodbus' ``AsyncModbusTcpClient`` reads the same registers
  of the same units back to back (pymodbus serialises the requests of one
  client: no pipelining on one connection), decodes and scales them with the
  link's own register plan into a row, and turns the rows into a numpy
  block, as the link's reader gets them.

A row counts when the step has it in hand (the link: read by the main thread).
Printed: rows per second of each round, median [min–max], the ratio link /
bare of each round and the goal. Then the link **paced** at half the bare
rate: rows, cycles skipped (gap events' lost samples), and stale rows — a row
whose value of a unit is not that unit's next answer (the server's answer
number, encoded in the position, must rise by exactly one per row).

Run: python benchmarks/acquisition_modbus.py [--seconds 3] [--rounds 5] [--short]
``--short`` (CI): one round of 1 s each; fails only on a crash, never on a figure.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import struct
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymodbus.client import AsyncModbusTcpClient

from ncmeasure.config import AxisConfig
from ncmeasure.links.modbus.link import ModbusLink
from ncmeasure.links.modbus.plan import build_plan
from ncmeasure.sim.modbus_drive import ServerHandle, running_server
from ncmeasure.sim.signals import AxisState

AXES = {"X": 1, "Y": 2, "Z": 3}
STEP_S = 0.001
MM_PER_S = 10.0
GOAL_RATIO = 0.9


@dataclass(frozen=True)
class AnswerNumber:
    """Positions that say which answer of its unit a value is: 10 mm per server step."""

    def state(self, axis: int, time_s: float) -> AxisState:
        return AxisState(position_mm=MM_PER_S * time_s, velocity_mm_min=600.0, current_a=1.0)


def _axis(name: str) -> AxisConfig:
    return AxisConfig(
        name=name,
        travel_mm=(0.0, 500.0),
        park_mm=10.0,
        max_velocity_mm_min=20_000.0,
        max_acceleration_m_s2=2.0,
        max_jerk_m_s3=50.0,
        screw_lead_mm=10.0,
        rated_current_a=8.0,
    )


def _link(server: ServerHandle, poll_hz: float) -> ModbusLink:
    return ModbusLink.from_tables(
        {"port": server.port, "register_map": "generic", "poll_hz": poll_hz, "timeout_s": 1.0},
        [(_axis(name), {"unit_id": unit}) for name, unit in AXES.items()],
    )


@dataclass
class Run:
    """One side's window: rows in hand, the time, what was skipped, stale rows."""

    side: str
    seconds: float
    rows: int
    skipped: int = 0
    stale: int = -1  # -1: not checked

    @property
    def rows_per_s(self) -> float:
        return self.rows / self.seconds


def _stale_rows(positions: np.ndarray) -> int:
    """Rows where a unit's answer number did not rise by exactly one (positions: rows × units)."""
    numbers = np.rint(positions / (MM_PER_S * STEP_S)).astype(np.int64)
    return int(np.count_nonzero(np.any(np.diff(numbers, axis=0) != 1, axis=1)))


def poll_with_link(server: ServerHandle, seconds: float, poll_hz: float = 10_000) -> Run:
    """Rows in hand through ModbusLink: flat out, or paced at ``poll_hz``."""
    link = _link(server, poll_hz)
    position_columns = [i for i, c in enumerate(link.channels) if c.signal == "position_mm"]
    blocks = []
    with link:
        link.read(timeout_s=1.0)  # warm up
        link.events()
        start = time.perf_counter()
        while (elapsed := time.perf_counter() - start) < seconds:
            block = link.read(timeout_s=0.1)
            if block is not None and len(block):
                blocks.append(block.values[:, position_columns])
        events = link.events()
    positions = np.concatenate(blocks) if blocks else np.empty((0, len(AXES)))
    skipped = sum(e.lost_samples for e in events if e.kind == "gap")
    return Run("link", elapsed, len(positions), skipped, _stale_rows(positions))


async def _poll_bare(server: ServerHandle, seconds: float, plan: Any, width: int) -> Run:
    client = AsyncModbusTcpClient(server.host, port=server.port, timeout=1.0, retries=0)
    await client.connect()
    rows: list[list[float]] = []
    done = 0
    try:
        start = time.perf_counter()
        while (elapsed := time.perf_counter() - start) < seconds:
            row = [0.0] * width
            for request in plan:
                read = (
                    client.read_holding_registers
                    if request.function == "holding"
                    else client.read_input_registers
                )
                response = await read(
                    request.address, count=request.count, device_id=request.unit_id
                )
                if response.isError():
                    raise RuntimeError(f"unit {request.unit_id} answered {response}")
                registers = response.registers
                for f in request.fields:  # the link's decoding, written out
                    words = registers[f.offset : f.offset + f.words]
                    if f.little:
                        words.reverse()
                    data = b"".join(w.to_bytes(2, "big") for w in words)
                    row[f.column] = struct.unpack(f.fmt, data)[0] * f.factor
            rows.append(row)
            if len(rows) >= 64:  # handed on as a block, as the link's reader gets them
                done += len(np.array(rows))
                rows = []
        done += len(np.array(rows).reshape(-1, width))
    finally:
        client.close()
    return Run("bare async", elapsed, done)


def poll_bare(server: ServerHandle, seconds: float) -> Run:
    """The baseline: pymodbus' async client, the same requests, decoding and scaling."""
    link = _link(server, 100.0)  # not opened: its settings only
    plan = build_plan(link.modbus, link.axes).requests  # the link's plan: units, registers
    return asyncio.run(_poll_bare(server, seconds, plan, len(link.channels)))


def _spread(values: list[float], fmt: str = "{:.0f}") -> str:
    median = statistics.median(values)
    if len(values) == 1:
        return fmt.format(median)
    return f"{fmt.format(median)} [{fmt.format(min(values))}–{fmt.format(max(values))}]"


def measure(seconds: float, rounds: int, show: bool = True) -> dict[str, Any]:
    """Interleaved flat-out rounds, then the link paced at half the bare rate."""
    results: dict[str, list[Run]] = {"link": [], "bare": []}
    with running_server(AXES, source=AnswerNumber(), step_s=STEP_S) as server:
        for index in range(rounds):
            order = ("link", "bare") if index % 2 == 0 else ("bare", "link")
            for side in order:
                server.reset()
                run = (
                    poll_with_link(server, seconds)
                    if side == "link"
                    else poll_bare(server, seconds)
                )
                results[side].append(run)
                if show:
                    print(
                        f"round {index + 1} {run.side:<10}: {run.rows_per_s:7.0f} rows/s",
                        flush=True,
                    )
        bare_rate = statistics.median(r.rows_per_s for r in results["bare"])
        paced_hz = max(1.0, round(bare_rate / 2, -1))
        server.reset()
        paced = poll_with_link(server, max(seconds, 1.0), paced_hz)
    ratios = [
        link.rows_per_s / bare.rows_per_s
        for link, bare in zip(results["link"], results["bare"], strict=True)
    ]
    return {**results, "ratios": ratios, "paced": paced, "paced_hz": paced_hz}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="per round and side")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--short", action="store_true", help="one round of 1 s (CI)")
    args = parser.parse_args()
    if args.short:
        args.seconds, args.rounds = 1.0, 1
    print(
        f"Modbus TCP, {len(AXES)} units × 1 request of 8 registers per cycle, server in another "
        f"process on 127.0.0.1; {args.rounds} rounds of {args.seconds:g} s per side, interleaved"
    )
    result = measure(args.seconds, args.rounds)
    for side in ("link", "bare"):
        runs: list[Run] = result[side]
        print(f"{runs[0].side:<10} rows/s {_spread([r.rows_per_s for r in runs]):>20}")
    link_stale = sum(r.stale for r in result["link"])
    print(f"link flat out: {link_stale} stale rows")
    print(
        f"ratio link/bare async rows per second: {_spread(result['ratios'], '{:.2f}')} "
        f"(goal ≥ {GOAL_RATIO:g}×)"
    )
    paced: Run = result["paced"]
    expected = paced.seconds * result["paced_hz"]
    print(
        f"link paced at {result['paced_hz']:g} Hz (half the bare rate) for {paced.seconds:.1f} s: "
        f"{paced.rows} rows of {expected:.0f} due, {paced.skipped} cycles skipped, "
        f"{paced.stale} stale (goal 0 and 0)"
    )


if __name__ == "__main__":
    main()
