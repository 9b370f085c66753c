"""``ncmeasure measure`` end to end on the virtual machine, over CANopen and over Modbus.

The harness is in-process: the user's generated programs run on the
:class:`~ncmeasure.sim.machine.VirtualMachine` with a standstill before the program
starts (``lead_in_s``) and a long one after it ends, simulated drives serve that run
(:func:`ncmeasure.virtual_run.serving`, as the demo and the dry run serve theirs) and
the command's link reads them in lockstep: the one seam is
:func:`ncmeasure.cli.measure.link_clock`, which gives the link the drives'
:class:`~ncmeasure.samples.SimulatedClock`. Nothing depends on the computer's speed.

What is shown: the recording starts at the program's start (its first row a short
pre-roll before the first motion, none of the lead-in's earlier standstill), ends at
the program's end (not at the bound, and long before the drives' standstill ends),
is stored with the serial at the program's start, compared with the machine's
baseline (the second measurement), reported, and the exit code is the verdict's.
The watch itself is shown on rows made by hand: the marker's first edge starts it
and its fall after the last window ends it; the override stretches the bound.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import load_machine
from ncmeasure.formats.results import load_results
from ncmeasure.formats.schedule import load_schedule
from ncmeasure.measure import PRE_ROLL_S, SERIES_LOG, ProgramWatch, read_series_log
from ncmeasure.recording import read_recording
from ncmeasure.samples import SampleBlock, SimulatedClock
from ncmeasure.sim.axis import Variation
from ncmeasure.sim.machine import MachineRun, VirtualMachine
from ncmeasure.virtual_run import serving, simulated_link
from tests.conftest import machine_toml
from tests.test_dryrun import SHORT

runner = CliRunner()

LEAD_IN_S = 6.0
"""Standstill before cycle start: longer than the pre-roll, so the wait is exercised."""
LEAD_OUT_S = 300.0
"""Standstill after the program: far beyond the schedule's bound, so only the end ends it."""
EXIT = {"ok": 0, "warning": 1, "critical": 3}


def _generated(
    folder: Path,
    kind: str,
    controller: str = "sinumerik-840d",
    extra: Callable[[dict[str, Any]], None] | None = None,
) -> tuple[Path, Path, dict[str, Any]]:
    """An example machine with a short measurement, its link the simulated drives' (then
    changed by ``extra``), and its generated programs."""
    init = runner.invoke(app, ["init", "--controller", controller])
    assert init.exit_code == 0, init.output
    data = tomllib.loads(init.stdout)
    data["measurement"].update(SHORT)
    folder.mkdir(parents=True, exist_ok=True)
    machine = folder / "machine.toml"
    machine.write_text(machine_toml(data), encoding="utf-8")
    link = simulated_link(load_machine(machine), kind)
    data["link"] = {"type": kind, **{k: v for k, v in link.table.items() if v not in (None, {})}}
    for axis in data["axes"]:
        axis["link"] = dict(link.axes[axis["name"]])
    if extra is not None:
        extra(data)
    machine.write_text(machine_toml(data), encoding="utf-8")  # the link keeps the hash
    programs = folder / "programs"
    generated = runner.invoke(app, ["generate", str(machine), "-o", str(programs), "-q"])
    assert generated.exit_code == 0, generated.output
    return machine, programs, data


@contextlib.contextmanager
def _machine_running(
    machine: Path,
    programs: Path,
    kind: str,
    monkeypatch: pytest.MonkeyPatch,
    variations: dict[str, Variation] | None = None,
    servers: list[Any] | None = None,
) -> Iterator[tuple[list[str], VirtualMachine, MachineRun]]:
    """The programs on the virtual machine behind simulated drives, from before cycle
    start; yields the transport options for the command's link, the machine and its run."""
    config = load_machine(machine)
    vm = VirtualMachine.from_programs(
        config, programs, lead_in_s=LEAD_IN_S, lead_out_s=LEAD_OUT_S, variations=variations
    )
    clock = SimulatedClock()
    monkeypatch.setattr("ncmeasure.cli.measure.link_clock", lambda: clock)
    run = vm.run()
    link = simulated_link(config, kind)
    with serving(config, run, link, clock, servers=servers) as transport:
        options = [f"--{key}={value}" for key, value in transport.items()]
        yield options, vm, run


def _measure(machine: Path, programs: Path, out: Path, store: Path, *extra: str) -> Any:
    return runner.invoke(
        app,
        [
            "measure", str(machine), "--programs", str(programs), "--serial", "M17",
            "--store", f"sqlite:///{store}", "-o", str(out), *extra,
        ],
    )  # fmt: skip


@pytest.mark.parametrize("kind", ["canopen", "modbus"])
def test_measure_from_cycle_start_to_the_verdict(
    tmp_path: Path, kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    machine, programs, _ = _generated(tmp_path, kind)
    schedule = load_schedule(programs / "schedule.json")
    store = tmp_path / "fleet.db"
    with _machine_running(machine, programs, kind, monkeypatch) as (transport, vm, run):
        first = _measure(machine, programs, tmp_path / "m1", store, *transport, "--label=delivery")
    assert first.exit_code in EXIT.values(), first.output
    recording = read_recording(tmp_path / "m1" / "recording")
    time_s = recording.time_s
    # Started by the program's start, with a pre-roll: the marker's first edge, which the
    # demo's link settings wire to the drives' inputs (else the first motion).
    assert "X_marker" in [c.name for c in recording.channels]
    program_start_s = min(span.start_s for span in run.spans)
    assert program_start_s > vm.lead_in_s  # after the parking and the warm-up
    assert program_start_s - PRE_ROLL_S - 0.05 <= time_s[0] <= program_start_s - PRE_ROLL_S + 0.05
    # Ended by the program's end: standing still at the parks a moment after it,
    # long before the bound (the schedule's duration + 30 s) and the drives' standstill.
    program_end_s = vm.lead_in_s + vm.program_duration_s
    assert program_end_s < time_s[-1] < program_end_s + 5.0, (time_s[-1], program_end_s)
    assert time_s[-1] < program_start_s + schedule.duration_s + 30.0
    assert "recorded" in first.output and "windows seen" in first.output
    windows = sum(len(a.windows) for a in schedule.axes)
    assert f"{windows} of {windows} windows seen" in first.output
    # Analysed, stored, reported; the first measurement is the baseline.
    results = load_results(tmp_path / "m1" / "results.json")
    assert set(results.axes) == {a.name for a in schedule.axes}
    assert results.recording.serial == "M17" and recording.meta.serial == "M17"
    assert (tmp_path / "m1" / "report.html").is_file()
    assert "stored as measurement 1 of M17" in first.output
    assert "its baseline from now on" in first.output
    with sqlite3.connect(store) as db:
        (measured,) = db.execute("select measured_utc from measurements").fetchone()
    assert measured  # the program's start, not the link's opening (shown by the library)

    # A second measurement of the same machine, its X axis' bearings loosened: compared
    # with the baseline, and the exit code is the verdict's.
    loose = {"X": Variation(bearing_preload_change=-0.6, loose_bearing_shift_um=30)}
    with _machine_running(machine, programs, kind, monkeypatch, loose) as (transport, _vm, _run):
        second = _measure(machine, programs, tmp_path / "m2", store, *transport)
    assert "stored as measurement 2 of M17" in second.output, second.output
    checked = tmp_path / "check.json"
    check = runner.invoke(
        app, ["store", "check", "M17", "--store", f"sqlite:///{store}", "-o", str(checked)]
    )
    status = json.loads(checked.read_text())["status"]
    assert check.exit_code == EXIT[status]
    levels = {a["verdict"]["level"] for a in json.loads(
        (tmp_path / "m2" / "results.json").read_text())["axes"].values()}  # fmt: skip
    worst = max([EXIT[status]] + [{"ok": 0, "check": 1, "fault": 3}[level] for level in levels])
    assert second.exit_code == worst, second.output
    assert "its baseline from now on" not in second.output


def test_programs_of_another_machine_file_are_refused(tmp_path: Path) -> None:
    _, programs, data = _generated(tmp_path, "canopen")
    low, high = data["axes"][0]["travel_mm"]
    data["axes"][0]["travel_mm"] = [low, high - 10]
    other = tmp_path / "other.toml"
    other.write_text(machine_toml(data), encoding="utf-8")
    result = _measure(other, programs, tmp_path / "m", tmp_path / "db")
    assert result.exit_code == 2, result.output
    assert "is not the machine file the programs in" in result.output
    assert not (tmp_path / "m").exists()


def _names(schedule: Any) -> list[str]:
    signals = ("velocity_mm_min", "position_mm", "marker")
    return [f"{a.name}_{signal}" for a in schedule.axes for signal in signals]


def _rows(schedule: Any, time_s: np.ndarray, marker: np.ndarray) -> SampleBlock:
    axes = [a.name for a in schedule.axes]
    values = np.zeros((len(time_s), 3 * len(axes)))
    for i, axis in enumerate(schedule.axes):
        values[:, 3 * i + 1] = axis.park_mm
        values[:, 3 * i + 2] = marker if i == 0 else 0.0
    # the first axis moves while the marker is on (its windows), 1 mm per row
    values[:, 1] += np.cumsum(marker > 0)
    return SampleBlock(time_s, values)


def test_the_marker_starts_and_ends_the_recording(tmp_path: Path) -> None:
    _, programs, _ = _generated(tmp_path, "canopen")
    schedule = load_schedule(programs / "schedule.json")
    names = _names(schedule)
    watch = ProgramWatch(names, schedule, real_time=False)
    assert watch.by_marker and "marker's first edge" in watch.state().text
    first = schedule.axes[0].windows
    period = 0.01
    time_s = np.arange(0, 100, period)
    marker = np.zeros_like(time_s)
    for k, window in enumerate(first):  # one marked stretch per window, from 10 s on
        marker[(time_s >= 10 + 2 * k) & (time_s < 10.5 + 2 * k)] = window.id
    rows = _rows(schedule, time_s, marker)
    kept = []
    ended = None
    for lo in range(0, len(time_s), 50):
        block = SampleBlock(rows.time_s[lo : lo + 50], rows.values[lo : lo + 50])
        part, ended = watch.pass_rows(block, float(block.time_s[-1]))
        kept.append(part.time_s)
        if ended:
            break
    time_kept = np.concatenate(kept)
    assert time_kept[0] == pytest.approx(10 - PRE_ROLL_S, abs=period)
    assert watch.start_s == pytest.approx(10.0)
    # other axes' windows never come: the bound ends it, and says what it is made of
    assert ended == "schedule"
    assert "the schedule's" in watch.bound_text


def test_a_slow_program_stretches_the_bound(tmp_path: Path) -> None:
    _, programs, _ = _generated(tmp_path, "canopen")
    schedule = load_schedule(programs / "schedule.json")
    names = _names(schedule)
    watch = ProgramWatch(names, schedule, real_time=False, margin_s=5.0)
    windows = schedule.axes[0].windows
    offset = windows[0].t_window_start_s
    period = 0.01
    # every window of X at twice its planned program time: override 50 %
    time_s = np.arange(0, 10 + 2 * (windows[-1].t_window_end_s - offset) + 1, period)
    marker = np.zeros_like(time_s)
    for window in windows:
        on = 10 + 2 * (window.t_window_start_s - offset), 10 + 2 * (window.t_window_end_s - offset)
        marker[(time_s >= on[0]) & (time_s < on[1])] = window.id
    rows = _rows(schedule, time_s, marker)
    watch.pass_rows(rows, None)
    assert watch.slowing == pytest.approx(2.0, rel=0.02)
    assert watch.bound_s == pytest.approx(
        10 + (schedule.duration_s - offset) * watch.slowing + 5.0, rel=1e-6
    )
    assert "override ≈ 50 %" in watch.bound_text


def _sampled_run(
    tmp_path: Path, lead_out_s: float
) -> tuple[Any, VirtualMachine, list[str], SampleBlock]:
    """The example machine's programs run on the virtual machine, sampled every 10 ms: the
    schedule, the machine, the channels' names and the rows."""
    machine, programs, _ = _generated(tmp_path, "canopen")
    schedule = load_schedule(programs / "schedule.json")
    vm = VirtualMachine.from_programs(
        load_machine(machine), programs, lead_in_s=LEAD_IN_S, lead_out_s=lead_out_s
    )
    channels, rows = vm.run().sample(0.01)
    return schedule, vm, [c.name for c in channels], rows


def test_a_marker_that_never_rises_leaves_the_start_to_the_motion(tmp_path: Path) -> None:
    """The drives' marker input is recorded but not wired (or not set): the program runs
    all the same; after the schedule's time to the first window and a grace the first
    motion is the start, the windows pass by position and the end is seen."""
    schedule, vm, names, rows = _sampled_run(tmp_path, lead_out_s=30.0)
    values = rows.values.copy()
    values[:, [i for i, n in enumerate(names) if n.endswith("_marker")]] = 0.0
    watch = ProgramWatch(names, schedule, real_time=False)
    assert watch.by_marker
    kept, ended = [], None
    for lo in range(0, len(rows.time_s), 100):
        block = SampleBlock(rows.time_s[lo : lo + 100], values[lo : lo + 100])
        part, ended = watch.pass_rows(block, None)
        kept.append(part.time_s)
        if ended:
            break
    assert ended == "program" and watch.marker_missing
    time_kept = np.concatenate(kept)
    moving = np.flatnonzero(
        np.any(np.abs(values[:, [names.index(f"{a.name}_velocity_mm_min") for a in schedule.axes]])
               > 1.0, axis=1))  # fmt: skip
    first_motion_s = rows.time_s[moving[0]]
    assert watch.start_s == pytest.approx(first_motion_s, abs=0.05)
    assert time_kept[0] == pytest.approx(first_motion_s - PRE_ROLL_S, abs=0.05)
    program_end_s = vm.lead_in_s + vm.program_duration_s
    assert program_end_s < time_kept[-1] < program_end_s + 5.0
    assert watch.windows_passed == watch.windows_total


def test_the_recorder_tells_the_program_it_is_ready(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The machine wires a Modbus coil back to the control's input 2: the LinuxCNC main
    program waits for it (M66) before its first move; measure sets it on once it waits
    for the start and off when the recording ends."""

    def ready(data: dict[str, Any]) -> None:
        data["machine"]["ready_input"] = 2
        data["machine"]["ready_timeout_s"] = 30.0
        data["axes"][0]["link"]["ready"] = {"function": "holding", "address": 900, "bit": 0}

    machine, programs, data = _generated(tmp_path, "modbus", "linuxcnc", ready)
    main = programs / "friction.ngc"  # the main program
    assert "M66 P2 L3 Q30" in main.read_text(encoding="utf-8")
    servers: list[Any] = []
    with _machine_running(machine, programs, "modbus", monkeypatch, servers=servers) as (
        transport,
        _vm,
        _run,
    ):
        result = _measure(machine, programs, tmp_path / "m", tmp_path / "db", *transport)
        writes = servers[0].output_writes()
    assert result.exit_code in EXIT.values(), result.output
    unit = data["axes"][0]["link"]["unit_id"]
    assert writes[unit] == [1, 0], writes  # on while it waited and recorded, then off


@pytest.mark.parametrize("series", [False, True])
def test_no_start_within_the_time_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, series: bool
) -> None:
    """Nobody pressed cycle start: a single run and a series without any run end alike,
    with the reason, not as a link failure."""
    machine, programs, _ = _generated(tmp_path, "modbus")
    extra = ["--start-timeout", "2", *(["--series"] if series else [])]
    with _machine_running(machine, programs, "modbus", monkeypatch) as (transport, _vm, _run):
        result = _measure(machine, programs, tmp_path / "m", tmp_path / "db", *transport, *extra)
    assert result.exit_code == 2, result.output
    assert "did not start within 2 s" in result.output
    if series:
        outcomes = [row["outcome"] for row in read_series_log(tmp_path / "m" / SERIES_LOG)]
        assert outcomes == ["no start", "series ended"]


@pytest.mark.parametrize("block_rows", [100, 10**9])
def test_the_end_is_seen_whatever_follows_it_in_the_same_block(
    tmp_path: Path, block_rows: int
) -> None:
    """A run, a short standstill at the parks, the next run: the first run's end is where
    the standstill has lasted STILL_S, whether its rows come in small blocks or in one
    (a link far behind its reader hands over seconds of rows at once)."""
    schedule, vm, names, rows = _sampled_run(tmp_path, lead_out_s=3.0)
    period = float(rows.time_s[1] - rows.time_s[0])
    again = rows.time_s + rows.time_s[-1] + period  # the next run, straight after
    time_s = np.concatenate((rows.time_s, again))
    values = np.concatenate((rows.values, rows.values))
    watch = ProgramWatch(names, schedule, real_time=False)
    kept, ended = [], None
    for lo in range(0, len(time_s), block_rows):
        block = SampleBlock(time_s[lo : lo + block_rows], values[lo : lo + block_rows])
        part, ended = watch.pass_rows(block, None)
        kept.append(part.time_s)
        if ended:
            break
    assert ended == "program"
    assert watch.windows_passed == watch.windows_total
    last_s = float(np.concatenate(kept)[-1])
    program_end_s = vm.lead_in_s + vm.program_duration_s
    still_s = 1.0 + 1.0  # STILL_S at the parks, then POST_ROLL_S
    assert program_end_s + still_s - 0.05 <= last_s <= program_end_s + still_s + 1.0
    assert last_s < float(again[0])  # nothing of the next run
