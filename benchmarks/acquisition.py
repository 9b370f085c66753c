"""Acquisition throughput of both drive links, each beside a bare-library baseline.

1. CANopen: 3 simulated CiA 402 drives, 3 TPDOs each, SYNC at 1 kHz on
   python-can's virtual bus for 10 s, through ncmeasure's CanOpenLink —
   PDOs/s received, samples lost, CPU % of one core — beside a bare
   python-can listener decoding the same frames.
2. Modbus TCP: polls/s through ncmeasure's ModbusLink against the simulated
   drive server in another process, beside a bare pymodbus client.

Run: python benchmarks/acquisition.py [seconds]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import acquisition_canopen
import acquisition_modbus


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
    program = sys.argv[0]
    print(f"== CANopen CiA 402 over the virtual bus, SYNC 1 kHz, {seconds:g} s ==")
    sys.argv = [program, "--seconds", str(seconds), "--sync-hz", "1000"]
    acquisition_canopen.main()
    print()
    print("== Modbus TCP on 127.0.0.1 ==")
    sys.argv = [program, str(min(seconds, 5.0))]
    acquisition_modbus.main()


if __name__ == "__main__":
    main()
