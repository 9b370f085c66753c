"""How fast ``ncmeasure demo`` runs, per link, beside the same pipeline without a link.

For each link (CANopen on the virtual bus, Modbus TCP on 127.0.0.1) ``ncmeasure
demo DIR --link L -q`` runs as a new process, as a user starts it, in lockstep with
its simulated drives: the machine time it recorded (102 s), its wall and CPU time
(all its threads; ``os.wait4``), the real-time factor (machine seconds per
wall-clock second, and per CPU second) and the samples lost (none: lockstep loses
nothing, however loaded the computer is). The baseline, measured in the same
rounds, also a new process: the identical virtual-machine run sampled directly
into a recording (no drives, no bus, no link), analysed, its report written: what
the pipeline costs without the acquisition. Rounds interleave baseline and links;
median and range. The goal: the demo at ≥ 10 × real time on an idle 2-core machine.

Run: python benchmarks/demo.py [--links canopen,modbus] [--rounds 3] [--short]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

from ncmeasure.recording import read_recording

GOAL = 10.0
"""Machine seconds per wall-clock second."""


def baseline(folder: Path) -> None:
    """Program → virtual machine → recording → analysis → report, without a link."""
    from ncmeasure.analysis.analyze import analyze
    from ncmeasure.config import parse_machine
    from ncmeasure.examples import demo_machine
    from ncmeasure.program import generate_programs
    from ncmeasure.report import write_report
    from ncmeasure.sim.machine import VirtualMachine
    from ncmeasure.virtual_run import record_directly

    config = parse_machine(tomllib.loads(demo_machine("linuxcnc", "canopen")))
    generated = generate_programs(config)
    generated.write(folder / "programs")
    run = VirtualMachine.from_programs(config, folder / "programs").run()
    record_directly(config, run, generated.schedule, folder / "recording")
    recording = read_recording(folder / "recording")
    results = analyze(recording, schedule=generated.schedule, machine=config)
    write_report(results, folder / "report.html", recording=recording)


def _run(command: list[str]) -> tuple[float, float]:
    """Wall and CPU time (user + system, every thread) of one process."""
    started = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - started
    code = os.waitstatus_to_exitcode(status)
    if code:
        raise SystemExit(f"{' '.join(command)} exited with {code}")
    return wall, usage.ru_utime + usage.ru_stime


def _machine_s(recording: Path) -> tuple[float, int]:
    """Machine time covered by a recording, and its samples lost."""
    rec = read_recording(recording)
    lost = sum(e.lost_samples for e in rec.events)
    return float(rec.time_s[-1] - rec.time_s[0]), lost


def _figures(name: str, walls: list[float], cpus: list[float], machine_s: float) -> str:
    wall, cpu = statistics.median(walls), statistics.median(cpus)
    return (
        f"{name:22s} wall {wall:5.1f} s ({min(walls):.1f}-{max(walls):.1f}), "
        f"CPU {cpu:5.1f} s ({min(cpus):.1f}-{max(cpus):.1f}); "
        f"{machine_s / wall:5.1f} x real time ({machine_s / max(walls):.1f}-"
        f"{machine_s / min(walls):.1f}), {machine_s / cpu:5.1f} machine s per CPU s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--links", default="canopen,modbus")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--short", action="store_true", help="one round, canopen: it runs")
    parser.add_argument("--baseline-into", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.baseline_into is not None:  # the baseline's own process
        baseline(args.baseline_into)
        return
    links = ["canopen"] if args.short else args.links.split(",")
    rounds = 1 if args.short else args.rounds
    load = Path("/proc/loadavg").read_text(encoding="ascii").split()[0]
    print(f"load average at the start: {load}")
    times: dict[str, tuple[list[float], list[float]]] = {
        name: ([], []) for name in ["baseline (no link)", *links]
    }
    machine: dict[str, float] = {}
    lost: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(rounds):
            folder = Path(tmp) / f"baseline-{k}"
            folder.mkdir()
            wall, cpu = _run([sys.executable, __file__, "--baseline-into", str(folder)])
            times["baseline (no link)"][0].append(wall)
            times["baseline (no link)"][1].append(cpu)
            machine["baseline (no link)"], _ = _machine_s(folder / "recording")
            for link in links:
                folder = Path(tmp) / f"{link}-{k}"
                command = [sys.executable, "-m", "ncmeasure", "demo", str(folder), "-q"]
                wall, cpu = _run([*command, "--link", link])
                times[link][0].append(wall)
                times[link][1].append(cpu)
                machine[link], lost[link] = _machine_s(folder / "recording")
    base_wall = statistics.median(times["baseline (no link)"][0])
    for name, (walls, cpus) in times.items():
        is_link = name in links
        line = _figures(f"demo --link {name}" if is_link else name, walls, cpus, machine[name])
        if is_link:
            line += (
                f"; {lost[name]} samples lost; {statistics.median(walls) / base_wall:.1f}x "
                "the baseline's wall time"
            )
        print(line)
    print(f"goal: the demo at >= {GOAL:g} x real time (idle 2-core machine)")


if __name__ == "__main__":
    main()
