"""How long ``ncmeasure demo`` takes, per link, beside the same pipeline without a link.

For each link (CANopen on the virtual bus, Modbus TCP on 127.0.0.1) the demo
without variation runs in lockstep with its simulated drives, as fast as the
computer allows, and prints its wall time, the machine time it recorded, the
speed reached (machine seconds per wall-clock second), and the samples lost
(none: lockstep loses nothing, however loaded the computer is). The
baseline, measured in the same run: the identical virtual-machine run sampled
directly into a recording (no drives, no bus, no link), analysed — what the
pipeline costs without the acquisition. The goal:
the demo stays under a minute on two cores, with the reference run included
(``--variation``: twice the recording).

Run: python benchmarks/demo.py [--links canopen,modbus]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tomllib
from pathlib import Path

from ncmeasure.analysis.analyze import analyze
from ncmeasure.config import parse_machine
from ncmeasure.demo import run_demo
from ncmeasure.examples import demo_machine
from ncmeasure.program import generate_programs
from ncmeasure.recording import RecordingWriter, read_recording
from ncmeasure.sim.machine import VirtualMachine


def baseline(folder: Path) -> tuple[float, float]:
    """Wall time of program → virtual machine → recording → analysis without a link."""
    started = time.perf_counter()
    config = parse_machine(tomllib.loads(demo_machine("linuxcnc", "canopen")))
    generated = generate_programs(config)
    generated.write(folder / "programs")
    run = VirtualMachine.from_programs(config, folder / "programs").run()
    channels, block = run.sample(0.004)
    writer = RecordingWriter.create(
        folder / "recording", channels, nominal_period_s=0.004, machine=config
    )
    writer.append(block)
    writer.close(status="complete")
    analyze(read_recording(folder / "recording"), schedule=generated.schedule, machine=config)
    return time.perf_counter() - started, run.duration_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--links", default="canopen,modbus")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base_s, machine_s = baseline(Path(tmp) / "baseline")
        print(f"baseline (no link): {base_s:5.1f} s for {machine_s:.0f} s of machine time")
        for link in args.links.split(","):
            started = time.perf_counter()
            result = run_demo(Path(tmp) / link, link=link)
            wall = time.perf_counter() - started
            run = result.measured
            assert run.acquisition is not None
            recorded = run.acquisition.link_time_s
            period = 0.004 if link == "canopen" else 0.008
            lost = sum(e.lost_samples for e in run.acquisition.events)
            print(
                f"demo --link {link:8s}: {wall:5.1f} s wall "
                f"(recording {run.acquisition.wall_time_s:5.1f} s, "
                f"{recorded / run.acquisition.wall_time_s:4.1f}x real time), "
                f"{run.acquisition.rows} samples of ~{recorded / period:.0f}, {lost} lost; "
                f"with a reference: ~{wall + run.wall_time_s:.0f} s; "
                f"{wall / base_s:.1f}x the baseline"
            )


if __name__ == "__main__":
    main()
