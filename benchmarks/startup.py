"""How long every ``ncmeasure`` command takes to start, beside bare Python.

Each command runs as a new process, as a user or a script runs it, in interleaved
rounds with ``python -c pass`` (the baseline: the interpreter alone, measured in the
same rounds):

- ``ncmeasure --version`` and ``ncmeasure --help``;
- the help of every command and subcommand (``ncmeasure store show --help``: the
  module of the command imported, its options built);
- cheap real invocations on small inputs made before the rounds (a machine file,
  generated programs, a short synthetic recording, two results files, a SQLite store
  with one machine measured twice): ``init``, ``plan``, ``store show`` and the like,
  and ``serve`` until it prints where it serves (then SIGTERM).

Printed per command: the median CPU time (user + system, of the process alone, from
``os.wait4``) and the median wall time, and the CPU ratio to ``python -c pass``
against the goal (≤ 10 ×); ``--version`` and ``--help`` also against their wall-time
goal (≤ 0.15 s). CPU is the figure to compare on a shared machine: wall time grows
with the load, CPU time much less.

The byte code of ncmeasure is written once before the rounds (a wheel install does
this at install time; an editable install or ``PYTHONDONTWRITEBYTECODE`` would
otherwise compile the sources on every start).

Run: python benchmarks/startup.py [--rounds 5] [--short]
"""

from __future__ import annotations

import argparse
import os
import queue
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

GOAL_RATIO = 10.0
"""Every command: CPU time ≤ 10 × that of ``python -c pass``."""
GOAL_WALL_S = 0.15
"""``--version`` and ``--help``: wall time ≤ 0.15 s."""
SERVE = "serve (until ready)"
WAIT_S = 120.0
"""The longest wait for one process (or for ``serve`` to be ready): a loaded machine."""


def _ncmeasure() -> list[str]:
    """The console script beside this interpreter, else ``python -m ncmeasure``."""
    script = Path(sys.executable).parent / "ncmeasure"
    if script.exists():
        return [str(script)]
    found = shutil.which("ncmeasure")
    return [found] if found else [sys.executable, "-m", "ncmeasure"]


@dataclass(frozen=True)
class Took:
    """One run of a process: its own CPU time (user + system) and the wall time."""

    cpu_s: float
    wall_s: float


def _run(command: list[str], env: dict[str, str], cwd: Path, codes: tuple[int, ...]) -> Took:
    """Run to its exit. ``os.wait4`` blocks until the exit and returns the process' own
    resource use: a wait with a time-out polls with growing sleeps, which would round the
    wall time up by milliseconds."""
    started = time.perf_counter()
    process = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=cwd
    )
    _, status, usage = os.wait4(process.pid, 0)
    took = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode not in codes:
        raise SystemExit(f"{' '.join(command)} exited with {process.returncode}")
    return Took(usage.ru_utime + usage.ru_stime, took)


def _serve(command: list[str], env: dict[str, str], cwd: Path) -> Took:
    """``serve`` until it prints where it serves, then SIGTERM: start-up and shutdown."""
    started = time.perf_counter()
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, cwd=cwd, text=True
    )
    lines: queue.Queue[str] = queue.Queue()
    assert process.stdout is not None
    stdout = process.stdout
    threading.Thread(target=lambda: lines.put(stdout.readline()), daemon=True).start()
    try:
        first = lines.get(timeout=WAIT_S)
    except queue.Empty:
        first = ""
    took = time.perf_counter() - started
    process.send_signal(signal.SIGTERM)
    hung = threading.Timer(WAIT_S, process.kill)
    hung.start()
    _, status, usage = os.wait4(process.pid, 0)
    hung.cancel()
    process.returncode = os.waitstatus_to_exitcode(status)
    stdout.close()
    if not first.startswith("serving "):
        raise SystemExit(f"{' '.join(command)} did not start: {first!r}")
    return Took(usage.ru_utime + usage.ru_stime, took)


def _help_paths() -> Iterator[tuple[str, ...]]:
    """Every command and subcommand, as the words that name it (``("store", "show")``)."""
    import typer.main

    from ncmeasure.cli import app

    def walk(command: object, prefix: tuple[str, ...]) -> Iterator[tuple[str, ...]]:
        for name, sub in sorted(getattr(command, "commands", {}).items()):
            yield (*prefix, name)
            yield from walk(sub, (*prefix, name))

    yield from walk(typer.main.get_command(app), ())


def _inputs(folder: Path, tool: list[str], env: dict[str, str]) -> str:
    """Small inputs for the real commands, in ``folder``; the store's URL."""
    from ncmeasure.analysis.analyze import analyze
    from ncmeasure.formats.results import write_results
    from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording

    def run(*args: str) -> str:
        done = subprocess.run(
            [*tool, *args], cwd=folder, env=env, capture_output=True, text=True, timeout=WAIT_S
        )
        if done.returncode:
            raise SystemExit(f"ncmeasure {' '.join(args)}: {done.stderr.strip()}")
        return done.stdout

    (folder / "machine.toml").write_text(run("init"))
    run("generate", "machine.toml", "-o", "programs", "--quiet")
    velocities = geometric_velocities(10.0, 15000.0, 8)
    store = f"sqlite:///{folder / 'fleet.db'}"
    for name, coulomb, seed in (("delivery", 2.0, 1), ("service", 2.6, 2)):
        axes = [SyntheticAxis(name="X", coulomb=coulomb, velocities_mm_min=velocities)]
        recording, schedule = synthetic_recording(folder / f"{name}-run", axes, seed=seed)
        write_results(analyze(recording, schedule=schedule), folder / f"{name}.json")
        run("store", "add", f"{name}.json", "--serial", "M1", "--label", name, "--store", store)
    return store


def _real(store: str) -> dict[str, tuple[list[str], tuple[int, ...]]]:
    """The real invocations: name, arguments (in the inputs' folder), allowed exit codes."""
    at = ["--store", store]
    return {
        "init": (["init"], (0,)),
        "controllers": (["controllers"], (0,)),
        "schema machine": (["schema", "machine"], (0,)),
        "plan machine.toml": (["plan", "machine.toml"], (0,)),
        "check programs": (["check", "programs"], (0,)),
        "export a recording": (["export", "delivery-run", "-o", "x.csv"], (0,)),
        "compare two results": (["compare", "delivery.json", "service.json"], (0, 1, 3)),
        "simulate machine.toml": (["simulate", "machine.toml"], (0,)),
        "compensation": (
            ["compensation", "delivery.json", "--controller", "twincat", "--axis", "X"],
            (0,),
        ),
        "store list": (["store", "list", *at], (0,)),
        "store show M1": (["store", "show", "M1", *at], (0,)),
        "store trend M1": (["store", "trend", "M1", "--axis", "X", *at], (0,)),
        "store check M1": (["store", "check", "M1", *at], (0, 1, 3)),
        "store export": (["store", "export", "-o", "x.jsonl", *at], (0,)),
        "store report": (["store", "report", "-o", "fleet.html", *at], (0, 1, 3)),
        SERVE: (["serve", *at, "--port", "0"], (0,)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument(
        "--short",
        action="store_true",
        help="one round, the help of one command only: checks it runs",
    )
    args = parser.parse_args()
    rounds = 1 if args.short else args.rounds

    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    # A relative PYTHONPATH (PYTHONPATH=src) would name another folder from the inputs'.
    paths = env.get("PYTHONPATH", "").split(os.pathsep)
    if any(paths):
        env["PYTHONPATH"] = os.pathsep.join(str(Path(p).resolve()) for p in paths if p)
    env["COLUMNS"] = "200"
    tool = _ncmeasure()

    with tempfile.TemporaryDirectory(prefix="ncmeasure-startup-") as tmp:
        folder = Path(tmp)
        store = _inputs(folder, tool, env)
        commands: dict[str, tuple[list[str], tuple[int, ...]]] = {
            "python -c pass": ([sys.executable, "-c", "pass"], (0,)),
            "--version": ([*tool, "--version"], (0,)),
            "--help": ([*tool, "--help"], (0,)),
        }
        helps = list(_help_paths())
        for path in helps[:1] if args.short else helps:
            commands[f"{' '.join(path)} --help"] = ([*tool, *path, "--help"], (0,))
        for name, (words, codes) in _real(store).items():
            commands[name] = ([*tool, *words], codes)

        def once(name: str) -> Took:
            command, codes = commands[name]
            if name == SERVE:
                return _serve(command, env, folder)
            return _run(command, env, folder, codes)

        if not args.short:  # byte code written, files in the page cache
            for name in commands:
                once(name)
        times: dict[str, list[Took]] = {name: [] for name in commands}
        for _ in range(rounds):
            for name in commands:
                times[name].append(once(name))

    base_cpu = statistics.median(t.cpu_s for t in times["python -c pass"])
    print(f"start-up, {rounds} interleaved rounds, {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.2f} at the end")  # fmt: skip
    print(f"{'command':42s} {'CPU':>7s} {'range':>13s} {'wall':>7s} {'× python':>9s}  goal")
    missed = []
    for name, values in times.items():
        cpu = statistics.median(t.cpu_s for t in values)
        wall = statistics.median(t.wall_s for t in values)
        low, high = min(t.cpu_s for t in values), max(t.cpu_s for t in values)
        ratio = cpu / base_cpu
        verdicts = []
        if name != "python -c pass":
            ok = ratio <= GOAL_RATIO
            verdicts.append(f"≤ {GOAL_RATIO:g} × {'met' if ok else 'MISSED'}")
            if not ok:
                missed.append(name)
        if name in ("--version", "--help"):
            ok = wall <= GOAL_WALL_S
            verdicts.append(f"wall ≤ {GOAL_WALL_S:.2f} s {'met' if ok else 'MISSED'}")
            if not ok and name not in missed:
                missed.append(name)
        print(f"{name:42s} {cpu:6.3f}s {low:6.3f}–{high:.3f}s {wall:6.3f}s "
              f"{ratio:8.1f}×  {', '.join(verdicts)}")  # fmt: skip
    print(f"goal met by {len(times) - 1 - len(missed)} of {len(times) - 1}; missed: "
          + (", ".join(missed) if missed else "none"))  # fmt: skip


if __name__ == "__main__":
    main()
