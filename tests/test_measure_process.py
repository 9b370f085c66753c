"""``ncmeasure measure`` as its own process against simulated drives serving the user's programs.

The command runs in a process of its own (``ncmeasure.__main__.main`` with its
command line, started with ``spawn``, as a shell starts it); the simulated Modbus
drives run in a third process and serve the user's generated programs as the
virtual machine runs them. Their one shared seam is the lockstep clock
(:class:`~ncmeasure.samples.SimulatedClock`, in shared memory), handed to the
command's process through :func:`ncmeasure.cli.measure.link_clock`: the recording
is the same however slow or busy the computer is.

The series: the virtual machine's program is started three times, with a standstill
between the starts; after the first run is stored the drives go away (they drop every
connection from a set simulated time in the standstill, then the server process stops:
a power cut, a cable pulled) and come back on the same port once the series has said
that it cannot reach them. Three measurements are stored, each
complete, and the series log says what happened.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import sqlite3
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.config import load_machine
from ncmeasure.formats.results import load_results
from ncmeasure.formats.schedule import load_schedule
from ncmeasure.measure import PRE_ROLL_S, SERIES_LOG, read_series_log
from ncmeasure.recording import read_recording
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.machine import MachineRun, VirtualMachine, one_after_another
from ncmeasure.sim.modbus_drive.faults import Fault
from ncmeasure.virtual_run import serving, simulated_link
from tests.test_measure import EXIT, _generated

LEAD_IN_S = 6.0
PAUSE_S = 40.0
"""Standstill between two program starts of the series: longer than the link's outage
(it gives up after 10 s without an answer) so the next start is not missed."""
CUT_AFTER_S = 10.0
"""The drives go dark this long (simulated time) after the first run's program ends: after
the series has recorded that run (its recording ends within 5 s of the program's end)."""
LEAD_OUT_S = 300.0
BOUND_S = 900.0
"""The longest any wait of these tests may take (a safety net; nothing waits for it)."""


def _command(argv: list[str], clock: SimulatedClock, output: str) -> None:
    """The child process: ``ncmeasure`` with ``argv``, its link on the drives' clock."""
    import ncmeasure.cli.measure as measure_cli
    from ncmeasure.__main__ import main

    measure_cli.link_clock = lambda: clock
    with Path(output).open("w", encoding="utf-8") as out:
        sys.stdout = sys.stderr = out
        sys.argv = ["ncmeasure", *argv]
        main()


@contextlib.contextmanager
def _process(argv: list[str], clock: SimulatedClock, output: Path) -> Iterator[Any]:
    process = multiprocessing.get_context("spawn").Process(
        target=_command, args=(argv, clock, str(output)), daemon=True
    )
    process.start()
    try:
        yield process
    finally:
        if process.is_alive():
            process.terminate()
        process.join(timeout=30)


def _until(condition: Callable[[], bool], process: Any, what: str) -> None:
    """Wait (bounded) until ``condition``; fail at once when the process ended first."""
    deadline = time.monotonic() + BOUND_S
    while not condition():
        assert process.is_alive(), f"the command ended before {what}"
        assert time.monotonic() < deadline, f"no {what} within {BOUND_S:g} s"
        time.sleep(0.2)


def _argv(
    machine: Path, programs: Path, store: Path, out: Path, port: int, *extra: str
) -> list[str]:
    return [
        "measure", str(machine), "--programs", str(programs), "--serial", "M17",
        "--store", f"sqlite:///{store}", "-o", str(out), "--host", "127.0.0.1",
        "--port", str(port), "-q", *extra,
    ]  # fmt: skip


def _expected_exit(out: Path, store: Path) -> int:
    """The verdict's exit code: the worst of the axes' verdicts and the store's check."""
    from ncmeasure.store import open_store, store_url
    from ncmeasure.store.check import check_machine

    with open_store(store_url(f"sqlite:///{store}"), write=False) as fleet:
        status = check_machine(fleet, "M17").status
    levels = [a.verdict.level for a in load_results(out / "results.json").axes.values()]
    return max([EXIT[status]] + [{"ok": 0, "check": 1, "fault": 3}[level] for level in levels])


def test_measure_as_a_process(tmp_path: Path) -> None:
    machine, programs, _ = _generated(tmp_path, "modbus")
    config = load_machine(machine)
    vm = VirtualMachine.from_programs(config, programs, lead_in_s=LEAD_IN_S, lead_out_s=LEAD_OUT_S)
    run = vm.run()
    clock = SimulatedClock()
    store, out = tmp_path / "fleet.db", tmp_path / "m1"
    with serving(config, run, simulated_link(config, "modbus"), clock) as transport:
        argv = _argv(machine, programs, store, out, transport["port"], "--label=delivery")
        with _process(argv, clock, tmp_path / "output.txt") as process:
            process.join(timeout=BOUND_S)
            code = process.exitcode
    output = (tmp_path / "output.txt").read_text(encoding="utf-8")
    assert code in EXIT.values(), output
    recording = read_recording(out / "recording")
    # started by the marker's first edge (a pre-roll before it), ended by the program's end
    program_start_s = min(span.start_s for span in run.spans)
    assert recording.time_s[0] < program_start_s < recording.time_s[0] + 3.0
    assert "X_marker" in [c.name for c in recording.channels]
    program_end_s = vm.lead_in_s + vm.program_duration_s
    assert program_end_s < recording.time_s[-1] < program_end_s + 5.0
    assert (out / "report.html").is_file()
    with sqlite3.connect(store) as db:
        assert db.execute("select count(*) from measurements").fetchone() == (1,)
    assert code == _expected_exit(out, store), output


def _series_run(vm: VirtualMachine) -> MachineRun:
    """The program started three times, each run with its own measurement noise."""
    runs = []
    for k in range(3):
        vm.seed = 100 + k
        vm.lead_out_s = LEAD_OUT_S if k == 2 else PAUSE_S
        runs.append(vm.run())
    return one_after_another(runs)


def test_a_series_survives_a_link_outage(tmp_path: Path) -> None:
    machine, programs, _ = _generated(tmp_path, "modbus")
    config = load_machine(machine)
    schedule = load_schedule(programs / "schedule.json")
    vm = VirtualMachine.from_programs(config, programs, lead_in_s=LEAD_IN_S, lead_out_s=PAUSE_S)
    run = _series_run(vm)
    clock = SimulatedClock()
    link = simulated_link(config, "modbus")
    store, folder = tmp_path / "fleet.db", tmp_path / "series"
    log = folder / SERIES_LOG

    def lines(outcome: str) -> list[dict[str, str]]:
        return [r for r in read_series_log(log) if r["outcome"] == outcome] if log.exists() else []

    handles: list[Any] = []
    drives: Any = serving(config, run, link, clock, servers=handles)
    port = drives.__enter__()["port"]
    # The outage starts at a simulated time, not when this test sees the first run stored:
    # from then on the drives drop every connection, so the series, polling for the next
    # start as fast as the drives answer, cannot run past it (by 10 s, its give-up, per
    # attempt) however long this test takes to stop them. The next start stays ahead.
    cut_s = LEAD_IN_S + vm.program_duration_s + CUT_AFTER_S
    handles[0].set_fault(Fault(disconnect=True, from_s=cut_s))
    try:
        argv = _argv(machine, programs, store, folder, port, "--series", "--runs", "3")
        with _process(argv, clock, tmp_path / "output.txt") as process:
            _until(lambda: len(lines("stored")) >= 1, process, "a first stored run")
            drives.__exit__(None, None, None)  # the drives go away
            drives = None
            _until(lambda: len(lines("link down")) >= 1, process, "the outage in the log")
            drives = serving(config, run, link, clock, port=port)  # and come back
            drives.__enter__()
            process.join(timeout=BOUND_S)
            code = process.exitcode
    finally:
        if drives is not None:
            drives.__exit__(None, None, None)
    output = (tmp_path / "output.txt").read_text(encoding="utf-8")
    stored = lines("stored")
    assert [row["run"] for row in stored] == ["1", "2", "3"], output
    windows = sum(len(a.windows) for a in schedule.axes)
    assert all(row["windows"] == f"{windows}/{windows}" for row in stored), stored
    assert lines("link down"), output
    with sqlite3.connect(store) as db:
        measured = [m for (m,) in db.execute("select measured_utc from measurements")]
    assert len(measured) == 3 and len(set(measured)) == 3
    for number in (1, 2, 3):
        run_folder = folder / f"run-{number:03d}"
        assert (run_folder / "report.html").is_file()
        # each run recorded from its own program start (the marker's first edge, a
        # pre-roll after its first row) to its end, nothing of the standstill between them
        recording = read_recording(run_folder / "recording")
        time_s, marker = recording.time_s, recording.column("X_marker")
        rise_s = time_s[int(np.argmax(marker > 0))]
        assert rise_s - time_s[0] == pytest.approx(PRE_ROLL_S, abs=0.05), number
        assert vm.program_duration_s - 60.0 < time_s[-1] - rise_s < vm.program_duration_s + 5.0
    assert code in EXIT.values() and code == max(EXIT[row["verdict"]] for row in stored), output
    assert set(folder.iterdir()) == {log, *(folder / f"run-{n:03d}" for n in (1, 2, 3))}


@pytest.fixture(autouse=True)
def _spawned_children_see_the_tests() -> Iterator[None]:
    """The spawned command imports this module: the project root must be on its path."""
    root = str(Path(__file__).resolve().parents[1])
    added = root not in sys.path
    if added:
        sys.path.insert(0, root)
    yield
    if added:
        sys.path.remove(root)
