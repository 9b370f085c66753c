"""``ncmeasure dryrun`` end to end: a user's generated programs run on the virtual machine,
are recorded through a real link from simulated drives, analysed and reported, and the
motion is held against the machine file's limits.

Every built-in controller's example machine (``ncmeasure init``), its measurement cut
down so the program takes about 30 s of machine time, goes through the CANopen link
(the default without a [link] table); one goes through Modbus, named by the machine
file's [link] table. The positions the link recorded stay inside the soft limits,
read from the recording itself, not from the dry run's own table. A program edited
beyond the travel and above the maximum feed is reported (exit code 1, the blocks
named), a machine file changed after generating is refused (exit code 2), and Ctrl-C
keeps what was recorded (exit code 130).
"""

from __future__ import annotations

import json
import re
import threading
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import parse_machine
from ncmeasure.formats.dryrun import load_dryrun
from ncmeasure.formats.schedule import load_schedule
from ncmeasure.recording import read_recording
from ncmeasure.virtual_run import simulated_link
from tests.conftest import DIALECTS, machine_toml

runner = CliRunner()

SHORT = {
    "positions": 2,
    "velocity_steps": 2,
    "min_velocity_mm_min": 500,
    "max_velocity_mm_min": 3000,
    "window_samples": 50,
    "warmup_strokes": 0,
}
"""A measurement of seconds: 2 positions × 2 velocity steps × 2 directions per axis."""


def _invoke(*args: str) -> Any:
    return runner.invoke(app, list(args))


def _example(
    folder: Path, controller: str, edit: Callable[[dict[str, Any]], None] | None = None
) -> tuple[Path, Path]:
    """`ncmeasure init --controller` with a short measurement, and its generated programs."""
    init = _invoke("init", "--controller", controller)
    assert init.exit_code == 0, init.output
    data = tomllib.loads(init.stdout)
    data["measurement"].update(SHORT)
    if edit is not None:
        edit(data)
    folder.mkdir(parents=True, exist_ok=True)
    machine = folder / "machine.toml"
    machine.write_text(machine_toml(data), encoding="utf-8")
    programs = folder / "programs"
    generated = _invoke("generate", str(machine), "-o", str(programs), "-q")
    assert generated.exit_code == 0, generated.output
    return machine, programs


def _assert_recorded_inside_the_soft_limits(machine: Path, recording: Path) -> None:
    """The positions the link recorded, read back from the recording: inside the travel."""
    config = parse_machine(tomllib.loads(machine.read_text(encoding="utf-8")))
    data = read_recording(recording)
    names = [channel.name for channel in data.meta.channels]
    for axis in config.axes:
        position = data.values[:, names.index(f"{axis.name}_position_mm")]
        low, high = axis.travel_mm
        assert low <= float(position.min()) and float(position.max()) <= high, axis.name
        # and it went somewhere: from near one end of the usable travel to near the other
        assert float(np.ptp(position)) > 0.9 * (high - low - 2 * 5.0), axis.name


def _assert_dry_run(machine: Path, programs: Path, output: str, link: str) -> None:
    folder = programs / "dryrun"
    assert "Traceback" not in output
    assert f"recorded through {link}" in output
    assert f"Open {folder / 'report.html'}" in output
    html = (folder / "report.html").read_text(encoding="utf-8")
    assert "ncmeasure dry run" in html
    schedule = load_schedule(programs / "schedule.json")
    reach = load_dryrun(folder / "dryrun.json")
    assert reach.within_limits and reach.excursions == [] and reach.config_hash
    assert [axis.name for axis in reach.axes] == [axis.name for axis in schedule.axes]
    for axis in reach.axes:
        low, high = axis.limits.travel_mm
        done = axis.commanded
        assert low <= done.min_position_mm <= done.max_position_mm <= high
        assert done.max_velocity_mm_min <= axis.limits.max_velocity_mm_min * (1 + 1e-9)
        assert done.max_acceleration_m_s2 <= axis.limits.max_acceleration_m_s2 * (1 + 1e-9)
        # the servo follows the setpoints: its actual motion is close to them
        assert abs(axis.actual.max_position_mm - done.max_position_mm) < 0.1
    results = json.loads((folder / "results.json").read_text(encoding="utf-8"))
    for summary in schedule.axes:
        # every window of the schedule is found and measured
        assert results["axes"][summary.name]["windows"] == len(summary.windows) == 8
        assert f"axis {summary.name}: 8 of 8 windows of schedule.json measured" in output
        assert re.search(rf"\n {summary.name} +.*ok", output), output
    meta = read_recording(folder / "recording").meta
    assert meta.status == "complete" and meta.gaps == 0
    assert meta.link["clock"] == "simulated"
    _assert_recorded_inside_the_soft_limits(machine, folder / "recording")


@pytest.mark.parametrize("controller", DIALECTS)
def test_dryrun_of_every_example_machine(tmp_path: Path, controller: str) -> None:
    machine, programs = _example(tmp_path, controller)
    result = _invoke("dryrun", str(programs), "--machine", str(machine))
    assert result.exit_code == 0, result.output
    _assert_dry_run(machine, programs, result.stdout, "canopen")
    assert "the demo's settings (the machine file has none for canopen)" in result.stdout


def test_dryrun_through_the_machine_file_s_modbus_link(tmp_path: Path) -> None:
    def modbus(data: dict[str, Any]) -> None:
        # a real drive's address: the dry run serves the simulated drives on 127.0.0.1
        data["link"] = {"type": "modbus", "host": "192.0.2.7", "port": 502}
        data["link"].update(register_map="generic", poll_hz=125)
        for number, axis in enumerate(data["axes"], start=1):
            axis["link"] = {"unit_id": 10 + number}

    machine, programs = _example(tmp_path, "sinumerik-840d", modbus)
    result = _invoke("dryrun", str(programs), "-m", str(machine))
    assert result.exit_code == 0, result.output
    _assert_dry_run(machine, programs, result.stdout, "modbus")
    assert "with the machine file's settings, over TCP on 127.0.0.1" in result.stdout
    assert read_recording(programs / "dryrun" / "recording").meta.nominal_period_s == 0.008


def test_a_program_beyond_the_limits_is_reported(tmp_path: Path) -> None:
    """Hand edits take X 10 mm beyond its soft limit and feed it above its maximum over a
    long move: the virtual machine follows, the table and dryrun.json say how far, the
    message names the blocks, the exit code is 1. The rest of the dry run still happens."""
    machine, programs = _example(tmp_path, "linuxcnc")
    sub = programs / "friction_x.ngc"
    text = sub.read_text(encoding="utf-8")
    text, moved = re.subn(r"X745\.0*(?![0-9])", "X760.000", text, count=1)
    # a rapid across the travel becomes a feed at 40 000 mm/min (X's maximum: 30 000)
    text, fed = re.subn(r"G0 (X7[0-4][0-9]\.[0-9]+)", r"G1 \1 F40000", text, count=1)
    assert moved == fed == 1
    sub.write_text(text, encoding="utf-8")
    output = tmp_path / "elsewhere"
    result = _invoke(
        "dryrun", str(programs), "--machine", str(machine), "-o", str(output), "--no-report"
    )
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    assert re.search(r"\n X +.*760\.000.*40000.*exceeded", result.stdout), result.stdout
    assert "error: the programs go beyond the limits of" in result.stderr
    assert "axis X: up to 760 mm, 10 mm beyond its soft limit 750 mm" in result.stderr
    assert "axis X: 40000 mm/min, above its max_velocity_mm_min 30000" in result.stderr
    assert re.search(r"at friction_x\.ngc:\d+: axis X to 760 mm, outside its travel", result.stderr)
    assert re.search(r"at friction_x\.ngc:\d+: axis X at 40000 mm/min, above", result.stderr)
    reach = load_dryrun(output / "dryrun.json")
    assert not reach.within_limits
    x = next(axis for axis in reach.axes if axis.name == "X")
    assert {e.limit for e in x.exceeded} == {"travel_max", "max_velocity_mm_min"}
    assert x.commanded.max_position_mm == pytest.approx(760.0)
    assert x.commanded.max_velocity_mm_min == pytest.approx(40000.0)
    assert all(not axis.exceeded for axis in reach.axes if axis.name != "X")
    # the machine went there: the recording says so too
    recorded = read_recording(output / "recording")
    names = [channel.name for channel in recorded.meta.channels]
    assert recorded.values[:, names.index("X_position_mm")].max() > 759.0
    assert not (programs / "dryrun").exists() and (output / "results.json").is_file()


def test_a_machine_file_changed_after_generating_is_refused(tmp_path: Path) -> None:
    machine, programs = _example(tmp_path, "linuxcnc")
    text = machine.read_text(encoding="utf-8")
    machine.write_text(
        text.replace("max_velocity_mm_min = 30000", "max_velocity_mm_min = 20000", 1),
        encoding="utf-8",
    )
    result = _invoke("dryrun", str(programs), "--machine", str(machine))
    assert result.exit_code == 2, result.output
    assert "is not the machine file the programs in" in result.stderr
    assert "generate them again from it" in result.stderr
    assert "Traceback" not in result.output and len(result.stderr.splitlines()) == 1
    assert not (programs / "dryrun").exists()


@pytest.mark.parametrize(
    ("where", "message"),
    [
        ("missing", "no such folder"),
        ("empty", "no schedule here"),
        ("no-machine", "no-machine.toml"),
        ("foreign-output", "exists and is not empty"),
        ("ethercat", "the virtual machine's simulated drives speak canopen or modbus"),
    ],
)
def test_dryrun_bad_input(tmp_path: Path, where: str, message: str) -> None:
    machine, programs = _example(tmp_path, "linuxcnc")
    args = [str(programs), "--machine", str(machine)]
    if where == "missing":
        args[0] = str(tmp_path / "nowhere")
    elif where == "empty":
        (tmp_path / "empty").mkdir()
        args[0] = str(tmp_path / "empty")
    elif where == "no-machine":
        args[2] = str(tmp_path / "no-machine.toml")
    elif where == "foreign-output":
        (tmp_path / "mine").mkdir()
        (tmp_path / "mine" / "notes.txt").write_text("mine\n", encoding="utf-8")
        args += ["--output", str(tmp_path / "mine")]
    else:
        args += ["--link", where]
    result = _invoke("dryrun", *args)
    assert result.exit_code == 2, result.output
    assert message in result.stderr and result.stderr.startswith("error: ")
    assert "Traceback" not in result.output
    if where == "foreign-output":
        assert (tmp_path / "mine" / "notes.txt").read_text(encoding="utf-8") == "mine\n"


class _StopAfter(threading.Event):
    """Ctrl-C as the acquisition sees it, at a fixed point: set from the ``calls``-th look on.

    The dry run looks once before recording, the acquisition once before every read; no
    clock decides when it comes.
    """

    def __init__(self, calls: int) -> None:
        super().__init__()
        self._left = calls

    def is_set(self) -> bool:
        self._left -= 1
        if self._left <= 0:
            self.set()
        return super().is_set()


def test_ctrl_c_keeps_what_was_recorded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import ncmeasure.dryrun

    machine, programs = _example(tmp_path, "linuxcnc")
    original = ncmeasure.dryrun.run_dryrun

    def interrupted(*args: Any, **kwargs: Any) -> Any:
        return original(*args, **{**kwargs, "stop": _StopAfter(4)})  # after two reads

    monkeypatch.setattr(ncmeasure.dryrun, "run_dryrun", interrupted)
    result = _invoke("dryrun", str(programs), "--machine", str(machine))
    assert result.exit_code == 130, result.output
    folder = programs / "dryrun"
    assert f"interrupted: kept dryrun.json, recording/ in {folder}/" in result.stderr
    assert "Traceback" not in result.output
    recording = read_recording(folder / "recording")
    assert recording.meta.status == "interrupted"
    assert load_dryrun(folder / "dryrun.json").within_limits
    assert not (folder / "results.json").exists() and not (folder / "report.html").exists()
    # the next dry run replaces the interrupted one
    monkeypatch.undo()
    again = _invoke("dryrun", str(programs), "--machine", str(machine), "--no-report")
    assert again.exit_code == 0, again.output
    assert "an earlier dry run replaced" in again.stdout
    assert read_recording(folder / "recording").meta.status == "complete"


def test_the_transport_is_the_simulated_drives_whatever_the_machine_file_says() -> None:
    """The machine file's settings of the link's kind are kept, its bus or address not."""
    data = tomllib.loads(
        """
        [machine]
        name = "m"
        controller = "linuxcnc"
        program = "P"
        [[axes]]
        name = "X"
        travel_mm = [0.0, 100.0]
        park_mm = 50.0
        max_velocity_mm_min = 10000
        max_acceleration_m_s2 = 1.0
        max_jerk_m_s3 = 10.0
        link = { node_id = 5, increments_per_rev = 4096 }
        [measurement]
        positions = 1
        velocity_steps = 2
        [link]
        type = "canopen"
        interface = "socketcan"
        channel = "can0"
        sync_hz = 500
        raw_log = "bus.blf"
        bus_options = { fd = true }
        listen_only = true
        sync_producer = false
        nmt_control = false
        """
    )
    config = parse_machine(data)
    canopen = simulated_link(config)
    assert canopen.kind == "canopen"
    assert canopen.source == "the machine file's settings, on a python-can virtual bus"
    assert canopen.table["interface"] == "virtual" and canopen.table["sync_hz"] == 500
    assert canopen.table["raw_log"] is None and canopen.table["bus_options"] == {}
    assert not canopen.table["listen_only"] and canopen.table["sync_producer"]
    assert canopen.axes["X"] == {"node_id": 5, "increments_per_rev": 4096}
    # another kind: the file's CANopen settings do not apply, the demo's do
    modbus = simulated_link(config, "modbus")
    assert modbus.source.startswith("the demo's settings (the machine file has none for modbus)")
    assert modbus.table["host"] == "127.0.0.1" and modbus.table["mode"] == "tcp"
    demo_axis = {"unit_id": 1, "marker": {"function": "discrete", "address": 0}}
    assert modbus.axes["X"] == demo_axis
    machine = modbus.machine(config)
    assert machine.link is not None and machine.link["type"] == "modbus"
    assert machine.axes[0].link == demo_axis
