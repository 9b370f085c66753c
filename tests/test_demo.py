"""``ncmeasure demo`` end to end, through both real links: the virtual machine runs the
generated program, simulated drives serve it, the link records it, the analysis must
find the friction the model put in and name the assembly fault that was injected.

Tolerances (also in docs/virtual-machine.md): per axis, the median relative error of the
measured friction against the model's is within ±1.5 % (a bias), every single point
(position, direction, velocity step) within 10 %; the injected cause ranks first,
in the single-run diagnosis for the local faults and in the comparison with the
correctly assembled machine for all of them (a preload shows only there).

Link and simulated drives run in lockstep: no sample is ever lost, and the recording
is the same whatever else the computer does (a test runs it beside two busy loops).
Every fault is measured through the CANopen link; two, a local and a global one, also
through Modbus: in lockstep a link adds nothing to the friction but its drives' counts.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.windows.find import windows_of
from ncmeasure.cli import app
from ncmeasure.config import load_machine
from ncmeasure.demo import DemoResult, run_demo
from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results
from ncmeasure.formats.schedule import load_schedule
from ncmeasure.recording import read_recording
from ncmeasure.sim.axis import EXAMPLE_VARIATIONS, Variation
from ncmeasure.sim.machine import VirtualMachine
from tests.analysis import oracle

BIAS_PERCENT = 1.5
POINT_PERCENT = 10.0
LINKS = ("canopen", "modbus")
VARIATIONS = [("canopen", cause) for cause in EXAMPLE_VARIATIONS] + [
    ("modbus", "loose_bearing"),
    ("modbus", "preload_or_carriage"),
]
LOCAL = ("loose_bearing", "fixed_bearing", "screw_nut", "guide_rail", "cover_or_seal")

runner = CliRunner()


def assert_recovers_the_simulated_friction(result: DemoResult) -> None:
    measured = result.measured
    acquisition = measured.acquisition
    assert acquisition is not None and acquisition.status == "complete"
    meta = read_recording(measured.recording).meta
    # lockstep: every cycle of the run is a row, none lost
    assert acquisition.gaps == 0 and meta.gaps == 0
    period = meta.nominal_period_s
    assert period == (0.004 if result.link == "canopen" else 0.008)  # 250 Hz SYNC, 125 Hz polls
    assert acquisition.rows == math.ceil(measured.machine_time_s / period - 1e-9)
    assert set(measured.accuracy) == {"X", "Z"}
    planned = 5 * 8 * 2  # positions, velocity steps, directions
    for name, axis in measured.results.axes.items():
        assert axis.windows >= 0.95 * planned, f"axis {name}: {axis.windows} of {planned} windows"
        found = measured.accuracy[name]
        assert found.points >= 0.95 * planned
        assert abs(found.median_error_percent) <= BIAS_PERCENT, found
        assert found.max_error_percent <= POINT_PERCENT, found
    assert meta.faster_than_real_time and meta.time_scale == 0.0
    assert meta.link["clock"] == "simulated"


@pytest.fixture(scope="module")
def nominals(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], DemoResult]:
    """The demo without variation, once per link: the reference of the variation tests."""
    done: dict[str, DemoResult] = {}

    def nominal(link: str) -> DemoResult:
        if link not in done:
            folder = tmp_path_factory.mktemp(f"demo-{link}") / "nominal"
            done[link] = run_demo(folder, link=link)
        return done[link]

    return nominal


@pytest.mark.parametrize("link", LINKS)
def test_demo_without_variation(nominals: Callable[[str], DemoResult], link: str) -> None:
    nominal = nominals(link)
    assert_recovers_the_simulated_friction(nominal)
    assert len(nominal.runs) == 1 and nominal.comparison is None
    results = nominal.measured.results
    assert results.skipped == {}
    for axis in results.axes.values():
        dependency = axis.position_dependency
        assert dependency is not None
        assert dependency.signature == "flat" and dependency.causes[0].cause == "none"
        # The healthy machine looks healthy: no alarm, and every curve says which model
        # describes it (the Stribeck hump is friction, not a fault).
        assert axis.verdict.level == "ok", axis.verdict
        for position in axis.positions:
            for direction in position.directions.values():
                assert direction is not None and direction.model_reason
                fit = direction.fit
                assert fit is not None and fit.coulomb is not None and fit.coulomb > 0
    assert nominal.measured.results.axes["Z"].offset is not None
    # gravity on the vertical axis: 500 kg, 20 mm lead
    assert nominal.measured.results.axes["Z"].offset.value == pytest.approx(15.6, rel=0.02)
    folder = nominal.directory
    for name in ("machine.toml", "programs/schedule.json", "results.json", "truth.json"):
        assert (folder / name).is_file(), name
    assert nominal.report is not None and nominal.report.is_file()
    html = nominal.report.read_text(encoding="utf-8")
    assert "virtual machine" in html and "Stribeck" in html
    truth = json.loads((folder / "truth.json").read_text(encoding="utf-8"))
    assert truth["axes"]["X"]["variation"] == {}


@pytest.mark.parametrize("link", LINKS)
def test_the_windows_come_from_the_marker_the_drives_report(
    nominals: Callable[[str], DemoResult], link: str
) -> None:
    """The program's marker reaches the recording through a drive input (CANopen: bit 16
    of the digital inputs 0x60FD; Modbus: discrete input 0), as a machine would wire the
    controller's marker output, and the analysis cuts the windows from it: every run of
    the marker is the scheduled window the program drove, in program order, its edges
    within two samples of where the program set and cleared the marker; every window
    found lies inside its own marked span, labelled with the schedule's id."""
    nominal = nominals(link)
    folder = nominal.directory
    recording = read_recording(nominal.measured.recording)
    schedule = load_schedule(folder / "programs" / "schedule.json")
    run = VirtualMachine.from_programs(
        load_machine(folder / "machine.toml"), folder / "programs"
    ).run()
    spans = [s for s in run.spans if s.axis]  # the program's marked windows, in order
    planned = [w for axis in schedule.axes for w in axis.windows]
    assert [(s.axis, s.marker) for s in spans] == [(w.axis, w.id) for w in planned]
    by_id = {(s.axis, round(s.marker)): s for s in spans}
    period = recording.meta.nominal_period_s
    time_s = recording.time_s
    for name in ("X", "Z"):
        marker = recording.axis_signal(name, "marker")
        assert set(np.unique(marker).tolist()) == {0.0, 1.0}  # an input: on or off
        edges = np.diff(np.concatenate(([0], (marker > 0).astype(np.int8), [0])))
        starts = time_s[np.flatnonzero(edges == 1)]
        ends = time_s[np.flatnonzero(edges == -1) - 1]  # the last sample with it set
        assert len(starts) == len(spans)  # the same wire reaches every drive
        for start, end, span in zip(starts, ends, spans, strict=True):
            assert abs(start - span.start_s) <= 2 * period, span
            assert abs(end - span.end_s) <= 2 * period, span
        assert nominal.measured.results.axes[name].window_source == "marker"
        found = windows_of(recording, name, schedule=schedule)
        own = [w for w in planned if w.axis == name]
        assert len(found.windows) >= 0.95 * len(own)
        assert len({w.window_id for w in found.windows}) == len(found.windows)
        for window in found.windows:
            assert window.source == "marker"
            assert window.window_id is not None
            span = by_id[(name, window.window_id)]
            assert span.start_s - period <= time_s[window.start]
            assert time_s[window.stop - 1] <= span.end_s + period


@pytest.mark.parametrize("link", LINKS)
def test_the_demo_analysis_is_the_oracle_s(
    nominals: Callable[[str], DemoResult], link: str
) -> None:
    """The analysis of a recording made through a link gives the results of the method on
    whole arrays (tests/analysis/oracle.py): in memory, as the demo reads it, and from its
    file; with the program's schedule and machine file, and without (clusters)."""
    nominal = nominals(link)
    recording = read_recording(nominal.measured.recording)
    folder = nominal.directory
    schedule = load_schedule(folder / "programs" / "schedule.json")
    machine = load_machine(folder / "machine.toml")

    def dump(results: Results) -> dict[str, object]:
        return results.model_dump(exclude={"created_utc"})

    expected = dump(oracle.analyze(recording, schedule=schedule, machine=machine))
    assert dump(nominal.measured.results) == expected
    found = analyze(recording.directory, schedule=schedule, machine=machine, rows=1000)
    assert dump(found) == expected
    assert dump(analyze(recording)) == dump(oracle.analyze(recording))


@pytest.mark.parametrize(("link", "cause"), VARIATIONS)
def test_demo_with_each_variation(
    nominals: Callable[[str], DemoResult], link: str, cause: str, tmp_path: Path
) -> None:
    nominal = nominals(link)
    variation = EXAMPLE_VARIATIONS[cause]
    result = run_demo(
        tmp_path / "varied",
        link=nominal.link,
        variation=variation,
        reference=nominal.directory,
        report=False,
    )
    assert_recovers_the_simulated_friction(result)
    assert [run.label for run in result.runs] == ["reference", "machine with the variation"]
    assert result.comparison is not None
    changes = {c.axis: c for c in result.comparison.changes}
    assert set(changes) == {"X", "Z"}
    for name, axis in result.measured.results.axes.items():
        ranked = [c.cause for c in changes[name].causes]
        assert ranked[0] == cause, f"axis {name}, change: {ranked}"
        dependency = axis.position_dependency
        assert dependency is not None
        single = [c.cause for c in dependency.causes]
        if cause in LOCAL:
            assert single[0] == cause, f"axis {name}, single run: {single}"
            assert axis.verdict.level in ("check", "fault"), axis.verdict
        else:  # a global offset: invisible in one run
            assert dependency.signature == "flat"
            assert changes[name].mean_change_percent > 5.0
    truth = json.loads((result.directory / "truth.json").read_text(encoding="utf-8"))
    assert truth["axes"]["X"]["variation"] == {k: v for k, v in vars(variation).items() if v}


def test_demo_command(nominals: Callable[[str], DemoResult], tmp_path: Path) -> None:
    nominal = nominals("canopen")
    out = tmp_path / "cli"
    result = runner.invoke(
        app,
        [
            "demo",
            str(out),
            "--variation",
            "loose_bearing_shift_um=500",
            "--reference",
            str(nominal.directory),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "Open" in result.output and str(out / "report.html") in result.output
    # the verdict per axis first, then the likely cause of the change against the reference
    for axis in ("X", "Z"):
        assert f"axis {axis}: fault · Coulomb friction " in result.output
    # the change's cause once, in the verdict's reason
    assert "along the travel: likely a shifted or tilted loose bearing" in result.output
    assert "Likely cause of the change" not in result.output
    assert (out / "comparison.json").is_file() and (out / "report.html").is_file()
    # a second run into the same folder needs --force; nothing is replaced without it
    again = runner.invoke(app, ["demo", str(out)])
    assert again.exit_code == 2
    assert "pass --force" in again.output and "Traceback" not in again.output
    assert (out / "comparison.json").is_file()


def test_a_realistic_demo_judges_the_change_not_the_fingerprint(tmp_path: Path) -> None:
    """--realistic: a healthy fingerprint along the travel, drift and the drives' noise. The
    machine is measured assembled correctly, then with its loose bearing shifted by 150 µm;
    the change names the bearing. Such a reference does not serve an ideal machine."""
    healthy = run_demo(tmp_path / "healthy", link="modbus", realistic=True, seed=3, report=False)

    def shifted(name: str, **machine: Any) -> DemoResult:
        """The loose bearing shifted by 150 µm, against the healthy demo as reference."""
        return run_demo(
            tmp_path / name,
            link="modbus",
            variation=Variation(loose_bearing_shift_um=150.0),
            reference=healthy.directory,
            report=False,
            **machine,
        )

    result = shifted("real", realistic=True, seed=3)
    truth = json.loads((result.directory / "truth.json").read_text(encoding="utf-8"))
    before = json.loads((healthy.directory / "truth.json").read_text(encoding="utf-8"))
    # the same machine twice: the same fingerprint, another day's drift (and the bearing)
    assert truth["realism"] == before["realism"] == {"machine_seed": 3}
    assert truth["axes"]["X"]["friction_nm"] != before["axes"]["X"]["friction_nm"]
    assert result.comparison is not None
    for change in result.comparison.changes:
        assert change.causes[0].cause == "loose_bearing", (change.axis, change.causes)
    assert set(result.comparison.runs[0].axis_status.values()) <= {"warning", "critical"}
    with pytest.raises(ConfigError, match="a reference must be the same machine"):
        shifted("mixed")
    (healthy.directory / "truth.json").unlink()
    with pytest.raises(ConfigError, match="cannot tell which machine that demo measured"):
        shifted("unknown", realistic=True, seed=3)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--variation", "loose_bearing=5"], "loose_bearing: unknown variation key"),
        (["--variation", "nut_shift_um=abc"], "nut_shift_um: 'abc' is not a number"),
        (["--link", "ethercat"], "the demo records through canopen or modbus"),
        (["--controller", "nonesuch"], "nonesuch"),
    ],
)
def test_demo_bad_input(tmp_path: Path, args: list[str], message: str) -> None:
    result = runner.invoke(app, ["demo", str(tmp_path / "out"), *args])
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output


def test_the_recording_is_the_same_beside_two_busy_loops(
    nominals: Callable[[str], DemoResult], tmp_path: Path
) -> None:
    """The acceptance of lockstep: same seed, same samples, however loaded the computer is."""
    nominal = nominals("canopen")
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        loaded = run_demo(tmp_path / "loaded", link="canopen", report=False)
    finally:
        for process in busy:
            process.kill()
            process.wait(30)
    quiet = read_recording(nominal.measured.recording)
    again = read_recording(loaded.measured.recording)
    assert np.array_equal(quiet.time_s, again.time_s)
    assert np.array_equal(quiet.values, again.values)
    assert again.meta.gaps == 0 and again.meta.status == "complete"


def test_demo_refuses_a_folder_that_is_not_its_own(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine\n", encoding="utf-8")
    result = runner.invoke(app, ["demo", str(tmp_path)])
    assert result.exit_code == 2
    assert "exists and is not empty" in result.output
    assert (tmp_path / "notes.txt").read_text(encoding="utf-8") == "mine\n"


def test_the_demo_says_when_a_run_lost_samples(
    nominals: Callable[[str], DemoResult], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Lockstep loses nothing; if a run ever did, the demo says so and what it did."""
    import dataclasses

    from ncmeasure.acquire import AcquisitionResult
    from ncmeasure.samples import LinkEvent

    nominal = nominals("canopen")
    run = nominal.measured
    assert run.acquisition is not None
    lossy = dataclasses.replace(
        run.acquisition,
        status="incomplete",
        events=[LinkEvent(1.0, "gap", "30 samples dropped", lost_samples=30)],
    )
    assert isinstance(lossy, AcquisitionResult)
    result = dataclasses.replace(nominal, runs=[dataclasses.replace(run, acquisition=lossy)])
    monkeypatch.setattr("ncmeasure.demo.run_demo", lambda *_args, **_kwargs: result)
    outcome = runner.invoke(app, ["demo", str(tmp_path / "d")])
    assert outcome.exit_code == 0, outcome.output
    share = f"{100 * lossy.lost_share:.2g}"  # of the demo's rows, about 0.1 %
    assert 0.05 <= float(share) <= 0.2
    assert f"warning: machine: 30 samples lost in 1 gap(s) ({share} %)" in outcome.stderr
    assert "the recording is marked incomplete" in outcome.stderr
    assert "no sample lost" not in outcome.stdout


def test_a_drive_answering_late_on_a_busy_computer_is_no_dead_drive(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The simulated drives answer on this computer's scheduler, not on a bus: with other
    work running, an answer can come a second late. The demo must wait for it, not stop
    with "no SDO answer" (a real drive's 0.5 s, even with canopen's one retry, is too
    short here). The first SDO answer is held back 1.5 s, as a loaded computer does."""
    import threading
    import time

    from ncmeasure.sim.cia402 import SimulatedDrive

    original = SimulatedDrive._on_sdo
    held: list[bytes] = []
    lock = threading.Lock()

    def late(self: SimulatedDrive, request: bytes) -> None:
        with lock:
            first = not held
            held.append(request)
        if first:
            time.sleep(1.5)  # the drives' thread gets no CPU for 1.5 s
        original(self, request)

    monkeypatch.setattr(SimulatedDrive, "_on_sdo", late)
    result = run_demo(tmp_path / "late", link="canopen", report=False)
    assert held, "no SDO request reached a simulated drive"
    acquisition = result.measured.acquisition
    assert acquisition is not None and acquisition.status == "complete"
    assert acquisition.gaps == 0
