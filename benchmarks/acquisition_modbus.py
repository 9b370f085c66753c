"""How fast the Modbus link polls 3 axes over TCP, against a bare pymodbus client.

A simulated drive server (3 units, generic register map) runs in another
process on 127.0.0.1. For N seconds each, in the same run:

- ``ModbusLink`` polls the 3 axes at a poll rate far above what the loop can
  do (``poll_hz = 10000``), so it runs flat out: one request per axis and
  cycle, decode, scale, timestamp, queue; rows are read as they come;
- the baseline, a bare ``pymodbus`` ``ModbusTcpClient``, reads the same
  registers of the same 3 units in a tight loop without decoding.

Printed: poll cycles (rows) per second and Modbus requests per second of
both, and their ratio. Both run on one machine with the server, so the
figures measure the software path, not a network or a drive.

Run: python benchmarks/acquisition_modbus.py [seconds]
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

from pymodbus.client import ModbusTcpClient

from ncmeasure.config import AxisConfig
from ncmeasure.links.modbus.link import ModbusLink
from ncmeasure.sim.modbus_drive import ServerHandle, running_server

AXES = {"X": 1, "Y": 2, "Z": 3}


@dataclass(frozen=True)
class Figures:
    """Throughput of one way of polling."""

    name: str
    seconds: float
    cycles: int
    requests: int

    @property
    def cycles_per_s(self) -> float:
        return self.cycles / self.seconds

    @property
    def requests_per_s(self) -> float:
        return self.requests / self.seconds


def _axis(name: str) -> AxisConfig:
    return AxisConfig(
        name=name,
        travel_mm=(0.0, 500.0),
        park_mm=10.0,
        max_velocity_mm_min=20_000.0,
        max_acceleration_m_s2=2.0,
        max_jerk_m_s3=50.0,
    )


def poll_with_link(server: ServerHandle, seconds: float) -> Figures:
    """Rows per second through ModbusLink, polling as fast as it can."""
    link = ModbusLink.from_tables(
        {"port": server.port, "register_map": "generic", "poll_hz": 10_000, "timeout_s": 1.0},
        [(_axis(name), {"unit_id": unit}) for name, unit in AXES.items()],
    )
    rows = 0
    with link:
        link.read(timeout_s=1.0)  # warm up
        start = time.perf_counter()
        while (elapsed := time.perf_counter() - start) < seconds:
            block = link.read(timeout_s=0.1)
            rows += len(block) if block is not None else 0
    return Figures("ModbusLink", elapsed, rows, rows * link.requests_per_cycle)


def poll_bare(server: ServerHandle, seconds: float) -> Figures:
    """The baseline: the same reads with a bare pymodbus client in a tight loop."""
    client = ModbusTcpClient(server.host, port=server.port, timeout=1.0, retries=0)
    client.connect()  # type: ignore[no-untyped-call]
    cycles = 0
    try:
        start = time.perf_counter()
        while (elapsed := time.perf_counter() - start) < seconds:
            for unit in AXES.values():
                response = client.read_input_registers(0, count=8, device_id=unit)
                if response.isError():
                    raise RuntimeError(f"unit {unit} answered {response}")
            cycles += 1
    finally:
        client.close()  # type: ignore[no-untyped-call]
    return Figures("bare pymodbus", elapsed, cycles, cycles * len(AXES))


def measure(seconds: float = 5.0) -> tuple[Figures, Figures]:
    """Poll with ModbusLink and with the bare client for ``seconds`` each."""
    with running_server(AXES) as server:
        baseline = poll_bare(server, seconds)
        server.reset()
        link = poll_with_link(server, seconds)
    return link, baseline


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 5.0
    link, baseline = measure(seconds)
    print(
        f"Modbus TCP, 3 axes (3 requests of 8 registers per cycle), {seconds:g} s each, "
        "server in another process on 127.0.0.1"
    )
    print(f"{'':>14} {'cycles/s':>10} {'requests/s':>11}")
    for figures in (link, baseline):
        print(f"{figures.name:>14} {figures.cycles_per_s:10.0f} {figures.requests_per_s:11.0f}")
    ratio = link.cycles_per_s / baseline.cycles_per_s
    print(
        f"link_cycles_per_s={link.cycles_per_s:.0f} link_requests_per_s={link.requests_per_s:.0f} "
        f"bare_cycles_per_s={baseline.cycles_per_s:.0f} "
        f"bare_requests_per_s={baseline.requests_per_s:.0f} ratio={ratio:.3f}"
    )


if __name__ == "__main__":
    main()
