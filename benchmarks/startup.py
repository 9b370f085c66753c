"""How long ``ncmeasure --version`` and ``ncmeasure --help`` take to start, beside bare Python.

Each command runs as a new process, as a user or a script runs it, in interleaved
rounds: ``python -c pass`` (the baseline: the interpreter alone), ``ncmeasure
--version``, ``ncmeasure --help``, and, for information, ``ncmeasure record --help``
(a command's own help; it builds the command's options and imports what typer needs
to convert them). Printed per command: the median wall time with its range, the
ratio to the baseline, and the goal (≤ 0.15 s for ``--version`` and ``--help``).

The byte code of ncmeasure is written once before the rounds (a wheel install does
this at install time; an editable install or ``PYTHONDONTWRITEBYTECODE`` would
otherwise compile the sources on every start).

Run: python benchmarks/startup.py [--rounds 20] [--short]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

GOAL_S = 0.15


def _ncmeasure() -> list[str]:
    """The console script beside this interpreter, else ``python -m ncmeasure``."""
    script = Path(sys.executable).parent / "ncmeasure"
    if script.exists():
        return [str(script)]
    found = shutil.which("ncmeasure")
    return [found] if found else [sys.executable, "-m", "ncmeasure"]


def _run(command: list[str], env: dict[str, str]) -> float:
    """Wall time from start to exit. ``os.wait4`` blocks until the exit: a wait with a
    time-out polls with growing sleeps, which would round the figure up by milliseconds."""
    started = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, env=env)
    _, status, _ = os.wait4(process.pid, 0)
    took = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode:
        raise SystemExit(f"{' '.join(command)} exited with {process.returncode}")
    return took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--short", action="store_true", help="one round: checks it runs")
    args = parser.parse_args()
    rounds = 1 if args.short else args.rounds

    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    tool = _ncmeasure()
    commands = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "ncmeasure --version": [*tool, "--version"],
        "ncmeasure --help": [*tool, "--help"],
        "ncmeasure record --help": [*tool, "record", "--help"],
    }
    goals = {"ncmeasure --version": GOAL_S, "ncmeasure --help": GOAL_S}
    for command in commands.values():  # byte code written, files in the page cache
        _run(command, env)

    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(rounds):
        for name, command in commands.items():
            times[name].append(_run(command, env))

    baseline = statistics.median(times["python -c pass"])
    print(f"start-up, {rounds} interleaved rounds, {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    print(f"{'command':26s} {'median':>8s} {'range':>17s} {'× python':>9s}  goal")
    met = True
    for name, values in times.items():
        median = statistics.median(values)
        goal = goals.get(name)
        ok = goal is None or median <= goal
        verdict = "" if goal is None else f"≤ {goal:.2f} s " + ("met" if ok else "MISSED")
        met &= ok
        print(f"{name:26s} {median:7.3f}s {min(values):7.3f}–{max(values):.3f} s "
              f"{median / baseline:8.1f}×  {verdict}")  # fmt: skip
    print(f"goal {'met' if met else 'missed'}")


if __name__ == "__main__":
    main()
