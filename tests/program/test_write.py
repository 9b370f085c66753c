"""Writing programs: size limits before rendering, streaming, check before moving into place.

A failed ``generate`` leaves the output folder exactly as it was; a new
generation replaces the files of the earlier one (and only those), and
``check`` refuses program files that schedule.json does not name.
"""

from __future__ import annotations

import json
import shutil
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import (
    ConfigError,
    DialectError,
    OutputError,
    PlanError,
    ProgramCheckError,
)
from ncmeasure.plan import machine as planner
from ncmeasure.program import GeneratedPrograms, check_programs, generate_programs
from ncmeasure.program.check import read_generated
from ncmeasure.resources import builtin_dir
from tests.conftest import DIALECTS, FIXED_TIME, example_data, machine_toml, small_data

Make = Callable[..., MachineConfig]
runner = CliRunner()


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` (hidden ones too) with its content."""
    return {
        str(path.relative_to(folder)): path.read_bytes()
        for path in sorted(folder.rglob("*"))
        if path.is_file()
    }


def config_of(data: dict[str, Any]) -> MachineConfig:
    return parse_machine(data)


# --- the plan's size, before anything is rendered ----------------------------------------


def test_a_week_long_plan_is_refused_before_rendering(tmp_path: Path) -> None:
    """50 positions x 500 steps x 5 repetitions: about a week and millions of blocks."""
    data = example_data("linuxcnc")
    data["measurement"].update(positions=50, velocity_steps=500, repetitions=5)
    config = config_of(data)
    with pytest.raises(PlanError) as caught:
        generate_programs(config)  # plans only; nothing is rendered
    error = caught.value
    assert "blocks" in error.message and "days" in error.message
    text = "\n".join(error.problems)
    assert "limits.max_duration_h" in text and "more than 8 h" in text
    assert "measurement.positions" in text and "measurement.velocity_steps" in text

    machine = tmp_path / "m.toml"
    machine.write_text(machine_toml(data), encoding="utf-8")
    code, _, stderr = run("generate", machine, "-o", tmp_path / "out")
    assert code == 2 and "limits.max_duration_h" in stderr and "Traceback" not in stderr
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.toml"], "no staging folder left"


def _tiny_and_fine(repetitions: int = 3, axes: int = 1) -> dict[str, Any]:
    """One millimetre of travel, 50 positions x 500 steps of 1 ms windows: quick to run,
    huge to write (150 000 windows at 3 repetitions)."""
    axis = {
        "travel_mm": [0.0, 1.0],
        "park_mm": 0.5,
        "max_velocity_mm_min": 1_000_000,
        "max_acceleration_m_s2": 200,
        "max_jerk_m_s3": 100_000,
    }
    return {
        "machine": {"name": "big", "controller": "linuxcnc"},
        "axes": [{"name": name, **axis} for name in "XYZABC"[:axes]],
        "measurement": {
            "positions": 50,
            "velocity_steps": 500,
            "spacing": "linear",
            "min_velocity_mm_min": 100,
            "max_velocity_mm_min": 600,
            "window_s": 0.001,
            "settle_s": 0,
            "dynamics_safety": 1,
            "margin_mm": 0,
            "warmup_strokes": 0,
            "repetitions": repetitions,
        },
    }


@pytest.mark.parametrize(
    ("repetitions", "axes", "limits", "windows"),
    [
        (3, 1, {}, 150_000),
        (15, 1, {}, 750_000),
        (100, 6, {"max_duration_h": 720, "max_program_kb": 1_000_000}, 30_000_000),
    ],
)
def test_too_many_windows_are_refused_before_any_window_is_planned(
    repetitions: int,
    axes: int,
    limits: dict[str, Any],
    windows: int,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A plan that would take minutes and gigabytes to write is refused from its counts."""
    data = _tiny_and_fine(repetitions, axes)
    data["limits"] = limits
    config = config_of(data)

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("a window was planned")

    monkeypatch.setattr(planner, "plan_axis", never)
    with pytest.raises(PlanError) as caught:
        generate_programs(config)
    text = "\n".join(caught.value.problems)
    assert f"limits.max_windows: {windows} windows, more than 20000" in text, text


def test_the_window_limit_is_configurable_up_to_its_ceiling() -> None:
    data = _tiny_and_fine(1)
    data["measurement"]["velocity_steps"] = 300  # 30 000 windows
    with pytest.raises(PlanError, match="plan is too large"):
        generate_programs(config_of(data))
    data["limits"] = {"max_windows": 30_000}
    assert len(generate_programs(config_of(data)).schedule.axes[0].windows) == 30_000
    data["limits"] = {"max_windows": 50_001}
    with pytest.raises(ConfigError, match=r"limits\.max_windows"):
        config_of(data)


def test_the_duration_limit_is_configurable() -> None:
    data = example_data("linuxcnc")
    data["limits"] = {"max_duration_h": 0.1}  # the example takes about 19 minutes
    with pytest.raises(PlanError, match="plan is too large") as caught:
        generate_programs(config_of(data))
    assert "more than 0.1 h" in "\n".join(caught.value.problems)
    data["limits"] = {"max_duration_h": 0.5}
    assert generate_programs(config_of(data)).schedule.duration_s > 0.1 * 3600


@pytest.mark.parametrize("dialect", DIALECTS)
def test_the_plan_states_its_blocks_and_they_are_the_programs_blocks(
    dialect: str, tmp_path: Path
) -> None:
    result = generate_programs(config_of(small_data(dialect)), generated=FIXED_TIME)
    result.write(tmp_path)
    schedule, _, trace = read_generated(tmp_path)
    blocks = len(trace.motions) + len(trace.dwells_s) + len(trace.calls)
    calls = 0 if result.dialect.subprograms else len(schedule.axes)  # one program, no calls
    assert schedule.blocks == blocks + calls
    assert schedule.blocks == 2 * len(schedule.axes) + sum(a.blocks for a in schedule.axes)


def test_plan_prints_blocks_and_size(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(machine_toml(example_data("fanuc")), encoding="utf-8")
    code, out, _ = run("plan", machine)
    assert code == 0
    assert "blocks" in out
    code, out, _ = run("plan", machine, "--json")
    assert json.loads(out)["blocks"] > 3000


def test_a_program_memory_too_small_for_the_plan_is_refused_before_rendering() -> None:
    data = example_data("fanuc")
    data["limits"] = {"max_program_kb": 10}
    with pytest.raises(PlanError) as caught:
        generate_programs(config_of(data))
    assert "limits.max_program_kb" in "\n".join(caught.value.problems)


def test_the_default_program_memory_is_the_dialects() -> None:
    """FANUC assumes 512 kB: the example fits, five times its steps and positions do not."""
    data = example_data("fanuc")
    generate_programs(config_of(data))
    data["measurement"].update(velocity_steps=250, positions=15)
    data["limits"] = {"max_duration_h": 100, "max_windows": 30_000}
    with pytest.raises(PlanError) as caught:
        generate_programs(config_of(data))
    assert "512 kB of program memory assumed for FANUC" in "\n".join(caught.value.problems)


def test_programs_that_grow_beyond_the_limit_while_rendering_leave_the_folder_alone(
    tmp_path: Path,
) -> None:
    data = small_data("linuxcnc")
    out = tmp_path / "out"
    generate_programs(config_of(data), generated=FIXED_TIME).write(out)
    size = sum(len(t.encode()) for t in generate_programs(config_of(data)).files.values())
    (out / "notes.txt").write_text("kept")
    before = snapshot(out)
    data["measurement"]["velocity_steps"] = 5  # a little larger than before
    data["limits"] = {"max_program_kb": size // 1024 + 1}
    result = generate_programs(config_of(data), generated=FIXED_TIME)  # the floor fits
    with pytest.raises(PlanError, match=r"grow beyond limits\.max_program_kb"):
        result.write(out)
    assert snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"], "no staging folder left"


def test_rendering_streams_to_the_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Writing a few MB of programs never holds them in memory."""
    data = example_data("sinumerik-840d")
    data["measurement"].update(velocity_steps=400, positions=8)
    data["limits"] = {"max_duration_h": 100, "max_program_kb": 10_000}
    result = generate_programs(config_of(data), generated=FIXED_TIME)
    env = result._renders[0][1].args[0]  # type: ignore[attr-defined]
    for name in ("main.j2", "sub.j2", "_moves.j2"):
        env.get_template(name)  # compiled beforehand: the peak is the rendering's own
    peaks = []
    stream = GeneratedPrograms._stream

    def from_here(self: GeneratedPrograms, *args: Any) -> None:
        if not peaks:  # schedule.json is written: the programs' rendering starts
            tracemalloc.reset_peak()
            peaks.append(tracemalloc.get_traced_memory()[0])
        stream(self, *args)

    def measured(self: GeneratedPrograms, folder: Path) -> None:
        peaks.append(tracemalloc.get_traced_memory()[1])  # the rendering's peak
        # the check itself is tested elsewhere; this test is about the rendering

    monkeypatch.setattr(GeneratedPrograms, "_stream", from_here)
    monkeypatch.setattr(GeneratedPrograms, "_check", measured)
    tracemalloc.start()
    try:
        result.write(tmp_path / "out")
    finally:
        tracemalloc.stop()
    written = sum(
        p.stat().st_size for p in (tmp_path / "out").iterdir() if p.name != "schedule.json"
    )
    assert written > 1_500_000  # a few MB: about 60 bytes per block
    # held in memory, the text alone would take its size (and again encoded);
    # streamed, the rendering needs a fixed few hundred kB whatever the size
    assert peaks[1] - peaks[0] < written / 4, (peaks, written)


# --- check before moving into place ------------------------------------------------------


def own_templates(tmp_path: Path, dialect: str, edit: Callable[[str], str]) -> Path:
    folder = tmp_path / "templates"
    shutil.copytree(builtin_dir("templates") / dialect, folder / dialect)
    main = folder / dialect / "main.j2"
    text = main.read_text()
    new = edit(text)
    assert new != text
    main.write_text(new)
    return folder


def test_programs_check_refuses_are_not_written(tmp_path: Path) -> None:
    """A template that forgets to park: the rendered programs fail check, nothing is written."""
    templates = own_templates(
        tmp_path, "linuxcnc", lambda t: t.replace("G53 G0 {{ axis.park_mm | word(axis.name) }}", "")
    )
    out = tmp_path / "out"
    config = config_of(small_data("linuxcnc"))
    generate_programs(config, generated=FIXED_TIME).write(out)
    before = snapshot(out)
    with pytest.raises(DialectError, match="fail ncmeasure's own check") as caught:
        generate_programs(config, templates_dirs=[templates]).write(out)
    assert any("parking every axis" in p for p in caught.value.problems)
    assert snapshot(out) == before

    machine = tmp_path / "m.toml"
    machine.write_text(machine_toml(small_data("linuxcnc")))
    code, _, stderr = run("generate", machine, "-o", out, "--templates-dir", templates)
    assert code == 2 and "fail ncmeasure's own check" in stderr and "Traceback" not in stderr
    assert snapshot(out) == before


# --- replacing an earlier generation -----------------------------------------------------


def test_fewer_axes_leave_no_stale_subprogram(tmp_path: Path) -> None:
    out = tmp_path / "out"
    data = small_data("linuxcnc")
    generate_programs(config_of(data), generated=FIXED_TIME).write(out)
    assert (out / "friction_z.ngc").is_file()
    (out / "machine.toml").write_text("# the user's own file")
    data["axes"] = data["axes"][:2]
    generate_programs(config_of(data), generated=FIXED_TIME).write(out)
    assert sorted(p.name for p in out.iterdir()) == [
        "SETUP.md",
        "friction.ngc",
        "friction_x.ngc",
        "friction_y.ngc",
        "machine.toml",
        "schedule.json",
        "setup.html",
    ]
    assert check_programs(out).ok


def test_check_refuses_program_files_the_schedule_does_not_name(tmp_path: Path) -> None:
    out = tmp_path / "out"
    data = small_data("linuxcnc")
    data["axes"] = data["axes"][:2]
    generate_programs(config_of(data), generated=FIXED_TIME).write(out)
    shutil.copy(out / "friction_y.ngc", out / "friction_z.ngc")  # a stale subprogram
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(out)
    assert any(
        "friction_z.ngc: a program file that schedule.json does not name" in p
        for p in caught.value.problems
    )
    code, _, stderr = run("check", out)
    assert code == 1 and "friction_z.ngc" in stderr


def test_check_refuses_a_schedule_that_names_no_files(tmp_path: Path) -> None:
    out = tmp_path / "out"
    generate_programs(config_of(small_data("linuxcnc")), generated=FIXED_TIME).write(out)
    schedule = json.loads((out / "schedule.json").read_text())
    del schedule["program_files"]
    (out / "schedule.json").write_text(json.dumps(schedule))
    with pytest.raises(ProgramCheckError, match="1 problem") as caught:
        check_programs(out)
    assert "names no program files" in caught.value.problems[0]


def test_generate_refuses_a_folder_with_foreign_programs(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "part42.ngc").write_text("G0 X0\nM2\n")
    (out / "friction.ngc").write_text("(someone else's)\nM2\n")
    before = snapshot(out)
    with pytest.raises(OutputError, match=r"no schedule\.json there names") as caught:
        generate_programs(config_of(small_data("linuxcnc"))).write(out)
    assert "friction.ngc, part42.ngc" in caught.value.message
    assert snapshot(out) == before


def test_a_failure_while_moving_into_place_restores_the_earlier_programs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    data = small_data("linuxcnc")
    generate_programs(config_of(data), generated=FIXED_TIME).write(out)
    before = snapshot(out)
    data["axes"] = data["axes"][:2]
    result = generate_programs(config_of(data), generated=FIXED_TIME)
    calls = {"n": 0}
    replace = Path.replace

    def failing(self: Path, target: Any) -> Any:
        calls["n"] += 1
        if calls["n"] == 9:  # the 7 old files moved aside, 2 new ones in place
            raise OSError(28, "No space left on device")
        return replace(self, target)

    monkeypatch.setattr(Path, "replace", failing)
    with pytest.raises(OutputError, match="No space left on device"):
        result.write(out)
    monkeypatch.undo()
    assert snapshot(out) == before
    assert check_programs(out).ok
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_new_output_folder_gets_the_usual_permissions(tmp_path: Path) -> None:
    """The staging folder is private while it is filled; the output folder is not."""
    out = tmp_path / "new" / "programs"
    generate_programs(config_of(small_data("linuxcnc"))).write(out)
    probe = tmp_path / "probe"
    probe.mkdir()
    assert out.stat().st_mode & 0o777 == probe.stat().st_mode & 0o777
    file = tmp_path / "probe.txt"
    file.write_text("")
    assert (out / "friction.ngc").stat().st_mode & 0o777 == file.stat().st_mode & 0o777


def test_generate_into_the_current_folder_stages_inside_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`-o .` needs nothing beside the folder, whose parent may not be writable."""
    work = tmp_path / "work"
    work.mkdir()
    (work / "machine.toml").write_text(machine_toml(small_data("linuxcnc")))
    monkeypatch.chdir(work)
    code, _, stderr = run("generate", "machine.toml", "-o", ".", "-q")
    assert code == 0, stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work"]
    assert sorted(p.name for p in work.iterdir()) == [
        "SETUP.md",
        "friction.ngc",
        "friction_x.ngc",
        "friction_y.ngc",
        "friction_z.ngc",
        "machine.toml",
        "schedule.json",
        "setup.html",
    ]
    assert run("generate", "machine.toml", "-o", ".", "-q")[0] == 0  # again, replacing
    assert run("check", ".")[0] == 0


def test_no_program_file_grows_beyond_what_check_reads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from ncmeasure.program import render

    monkeypatch.setattr(render, "MAX_PROGRAM_FILE_BYTES", 1024 * 1024)
    data = example_data("linuxcnc")
    data["measurement"]["velocity_steps"] = 30
    data["limits"] = {"max_program_kb": 1_000_000}
    templates = tmp_path / "templates"
    shutil.copytree(builtin_dir("templates") / "linuxcnc", templates / "linuxcnc")
    moves = templates / "linuxcnc" / "_moves.j2"  # a long comment in front of every move
    moves.write_text(moves.read_text().replace("{% if", "{{ ('x' * 4000) | comment }}\n{% if", 1))
    result = generate_programs(config_of(data), templates_dirs=[templates])
    with pytest.raises(PlanError, match=r"a program file grows beyond 1 MiB"):
        result.write(tmp_path / "out")
    assert not (tmp_path / "out").exists()
