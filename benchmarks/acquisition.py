"""Acquisition of both drive links, each beside a bare-library baseline doing the same work.

1. CANopen (``acquisition_canopen.py``): 3 simulated CiA 402 drives, 3 TPDOs
   each, SYNC at 1 kHz on python-can's virtual bus: CPU per PDO of
   ``CanOpenLink`` against a bare python-can SYNC producer and receiver that
   decodes the same PDOs into rows (goal ≤ 1.2×), rows lost, SYNC skipped;
   the drives answer SYNC on the bus, as real drives in their synchronous
   window (``acquisition_canopen.py --drives thread``: from their own thread).
2. Modbus TCP (``acquisition_modbus.py``): rows per second of ``ModbusLink``
   polling flat out against pymodbus' async client reading, decoding and
   scaling the same registers (goal ≥ 0.9×); then paced: skipped and stale rows.

Rounds alternate link and baseline (A B A B …); each prints its rounds, the
median [min–max] and the ratio with its goal.

Run: python benchmarks/acquisition.py [--seconds 5] [--rounds 5] [--short]
``--short`` (CI): one short round of each; fails only on a crash, never on a figure.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import acquisition_canopen
import acquisition_modbus


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="per round and side")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--short", action="store_true", help="one round of 1 s each (CI)")
    args = parser.parse_args()
    program = sys.argv[0]
    common = (
        ["--short"]
        if args.short
        else ["--seconds", str(args.seconds), "--rounds", str(args.rounds)]
    )
    print("== CANopen CiA 402 over the virtual bus, SYNC 1 kHz ==")
    sys.argv = [program, *common]
    acquisition_canopen.main()
    print()
    print("== Modbus TCP on 127.0.0.1 ==")
    sys.argv = [program, *common]
    acquisition_modbus.main()


if __name__ == "__main__":
    main()
