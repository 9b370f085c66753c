"""The command line: what a technician types, what comes back, and the exit codes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.examples import example_machine
from tests.conftest import machine_toml

runner = CliRunner()


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def test_init_generate_check_round_trip(tmp_path: Path) -> None:
    code, text, _ = run("init", "--controller", "linuxcnc")
    assert code == 0 and 'controller = "linuxcnc"' in text
    machine = tmp_path / "m.toml"
    machine.write_text(text)
    code, out, _ = run("generate", machine, "-o", tmp_path / "out")
    assert code == 0, out
    assert "friction_x.ngc" in out and "next: ncmeasure check" in out
    assert "SETUP.md" in out and "setup.html" in out
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == [
        "SETUP.md",
        "friction.ngc",
        "friction_x.ngc",
        "friction_y.ngc",
        "friction_z.ngc",
        "schedule.json",
        "setup.html",
    ]
    code, out, _ = run("check", tmp_path / "out")
    assert code == 0 and "900/900 windows" in out


def test_plan_json_has_totals_at_the_top(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("sinumerik-840d"))
    code, out, _ = run("plan", machine, "--json")
    assert code == 0
    plan = json.loads(out)
    assert 0 < plan["duration_s"] < plan["full_travel_duration_s"]
    assert [a["name"] for a in plan["axes"]] == ["X", "Y", "Z"]
    assert plan["axes"][0]["windows"] == 300
    code, out, _ = run("plan", machine)
    assert code == 0 and "saving" in out and "run-up" in out


def test_controllers_and_schema() -> None:
    code, out, _ = run("controllers")
    assert code == 0
    for name in ("sinumerik-840d", "fanuc", "heidenhain-iso", "twincat", "linuxcnc"):
        assert name in out
    code, out, _ = run("controllers", "--details")
    assert code == 0 and "MOS_TS" in out and "left out" in out
    code, out, _ = run("schema", "machine")
    schema = json.loads(out)
    assert code == 0 and {"machine", "axes", "measurement"} <= set(schema["properties"])
    code, out, _ = run("schema", "schedule")
    assert code == 0 and "windows" in out


def test_help_teaches() -> None:
    code, out, _ = run("--help")
    assert code == 0 and "generate" in out and "check" in out
    code, out, _ = run("generate", "--help")
    assert code == 0 and "schedule.json" in out


# --- bad input: a clear message with its place, exit code 2, no traceback, no output ---

BAD_MACHINES: dict[str, tuple[Callable[[str], str], str]] = {
    "invalid TOML": (
        lambda t: t.replace('program = "FRICTION"', 'program = "FRICTION'),
        "invalid TOML",
    ),
    "unknown key": (
        lambda t: t.replace("vertical = false", "vertikal = false"),
        "axes[0].vertikal: unknown key",
    ),
    "wrong unit or range": (
        lambda t: t.replace("max_velocity_mm_min = 30000\n", "max_velocity_mm_min = -30000\n", 1),
        "axes[0].max_velocity_mm_min: Input should be greater than or equal to 0.01",
    ),
    "wrong type": (
        lambda t: t.replace("max_acceleration_m_s2 = 2.0", 'max_acceleration_m_s2 = "2 m/s2"', 1),
        "axes[0].max_acceleration_m_s2",
    ),
    "min >= max": (
        lambda t: t.replace("travel_mm = [0.0, 750.0]", "travel_mm = [750.0, 0.0]"),
        "axes[0].travel_mm: min (750) must be below max (0)",
    ),
    "velocity min >= max": (
        lambda t: t.replace("min_velocity_mm_min = 10", "min_velocity_mm_min = 20000"),
        "measurement.min_velocity_mm_min",
    ),
    "park outside travel": (
        lambda t: t.replace("park_mm = 375.0", "park_mm = 800.0"),
        "axes[0].park_mm: 800 mm is outside the travel [0, 750] mm",
    ),
    "axis name the dialect refuses": (
        lambda t: t.replace('name = "Z"', 'name = "Z1"'),
        "axes[2].name: 'Z1' is not an axis name LinuxCNC allows",
    ),
    "newline in a name": (lambda t: t.replace('"HMX-400"', '"HMX\\nM30"'), "machine.name"),
    "semicolon in a name": (lambda t: t.replace('"HMX-400"', '"HMX;M30"'), "machine.name"),
    "parenthesis in a name": (lambda t: t.replace('"HMX-400"', '"HMX (x)"'), "machine.name"),
    "percent in a name": (lambda t: t.replace('"HMX-400"', '"HMX%"'), "machine.name"),
    "dollar in a name": (lambda t: t.replace('"HMX-400"', '"$R1"'), "machine.name"),
    "slash in a program": (
        lambda t: t.replace('program = "FRICTION"', 'program = "A/B"'),
        "machine.program",
    ),
    "dot-dot in a program": (
        lambda t: t.replace('program = "FRICTION"', 'program = "..X"'),
        "machine.program",
    ),
    "injection in an axis name": (
        lambda t: t.replace('name = "X"', 'name = "X\\nM2"'),
        "axes[0].name",
    ),
    "unknown controller": (
        lambda t: t.replace('"linuxcnc"', '"heidenhain"'),
        "unknown controller 'heidenhain'",
    ),
    "unknown controller option": (
        lambda t: t.replace(
            'program = "FRICTION"', 'program = "FRICTION"\ncontroller_options = {bit = 3}'
        ),
        "machine.controller_options.bit: unknown option for linuxcnc",
    ),
    "step does not fit": (
        lambda t: t.replace("travel_mm = [0.0, 750.0]", "travel_mm = [0.0, 150.0]").replace(
            "park_mm = 375.0", "park_mm = 75.0"
        ),
        "axis X: the step at",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_MACHINES))
def test_bad_machine_files(case: str, tmp_path: Path) -> None:
    mutate, expected = BAD_MACHINES[case]
    text = example_machine("linuxcnc")
    bad = mutate(text)
    assert bad != text, "the mutation did not apply"
    machine = tmp_path / "m.toml"
    machine.write_text(bad)
    out = tmp_path / "out"
    code, stdout, stderr = run("generate", machine, "-o", out)
    assert code == 2, stdout + stderr
    assert expected in stderr, stderr
    assert "Traceback" not in stdout + stderr
    assert not out.exists(), "nothing may be written for a bad machine file"


def test_output_directory_that_is_a_file(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    target = tmp_path / "out"
    target.write_text("precious")
    code, _, stderr = run("generate", machine, "-o", target)
    assert code == 2 and "exists and is not a directory" in stderr
    assert target.read_text() == "precious"


def test_existing_programs_survive_a_failed_generate(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    out = tmp_path / "out"
    assert run("generate", machine, "-o", out)[0] == 0
    before = {p.name: p.read_text() for p in out.iterdir()}
    machine.write_text(example_machine("linuxcnc").replace("park_mm = 375.0", "park_mm = 900.0"))
    assert run("generate", machine, "-o", out)[0] == 2
    assert {p.name: p.read_text() for p in out.iterdir()} == before


def test_missing_machine_file_and_check_of_nothing(tmp_path: Path) -> None:
    code, _, stderr = run("generate", tmp_path / "none.toml", "-o", tmp_path / "o")
    assert code == 2 and "none.toml: no such file" in stderr
    code, _, stderr = run("check", tmp_path / "nowhere")
    assert code == 2 and "not a directory" in stderr


def test_check_failure_exits_1(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    out = tmp_path / "out"
    run("generate", machine, "-o", out)
    sub = out / "friction_y.ngc"
    sub.write_text(sub.read_text().replace("G1 Y595.000 F15000", "G1 Y650.000 F15000", 1))
    code, _, stderr = run("check", out)
    assert code == 1
    assert "friction_y" in stderr.lower() and "outside the soft limits [0, 600]" in stderr


def test_console_script_shows_no_traceback(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text("[machine]\nname = 'x'\ncontroller = 'linuxcnc'\n")
    done = subprocess.run(
        [sys.executable, "-m", "ncmeasure", "generate", str(machine), "-o", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert done.returncode == 2
    assert "axes: required key is missing" in done.stderr
    assert "Traceback" not in done.stderr


# --- user text, --debug, exit codes in one place (issue: the CLI owns the console) ------------


@pytest.mark.parametrize("text", ["[/]", "[red]evil", "a[bold]b[/bold]"])
def test_user_text_is_printed_as_written(text: str, tmp_path: Path) -> None:
    """Square brackets in a machine file or a path are text, not console markup."""
    machine = tmp_path / "m.toml"
    machine.write_text(
        example_machine("linuxcnc").replace('controller = "linuxcnc"', f'controller = "{text}"')
    )
    code, _, err = run("plan", machine)
    assert code == 2 and text in err and "Traceback" not in err
    folder = tmp_path / text.replace("/", "_")
    code, _, err = run("check", folder)
    assert code == 2 and str(folder) in err and "Traceback" not in err


def test_a_path_with_markup_is_checked_and_printed_whole(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    out = tmp_path / "run[/]x"
    code, _, err = run("generate", machine, "-o", out, "-q")
    assert code == 0, err
    code, text, _ = run("check", out)
    assert code == 0 and f"ok: {out} (linuxcnc)" in text


def test_generate_into_a_folder_with_markup_prints_its_name(tmp_path: Path) -> None:
    """The success path names the folder as written: every 'wrote' line and the next step."""
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    out = tmp_path / "o[/]"
    code, text, err = run("generate", machine, "-o", out)
    assert code == 0, err
    assert f"wrote {out / 'friction.ngc'}" in text and f"wrote {out / 'schedule.json'}" in text
    assert f"next: ncmeasure check {out} " in text and "Traceback" not in text + err


def test_help_keeps_square_brackets() -> None:
    code, out, _ = run("record", "--help")
    assert code == 0 and "[link] table" in " ".join(out.split())
    code, out, _ = run("export", "--help")
    assert code == 0
    assert "--format" in out


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_anywhere_shows_the_traceback_and_keeps_the_exit_code(
    where: str, tmp_path: Path
) -> None:
    args = ["check", str(tmp_path / "nothing")]
    args = ["--debug", *args] if where == "before" else [*args, "--debug"]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert "Traceback" in result.stderr and "not a directory of generated programs" in (
        result.stderr
    )


BUG_LINE = (
    "error: unexpected KeyError: 'axes'; this is a bug: please report it to the ncmeasure "
    "maintainers with the output of the same command with --debug"
)


@pytest.mark.parametrize(
    ("target", "args"),
    [
        ("ncmeasure.program.check_programs", ["check", "out"]),
        ("ncmeasure.formats.results.load_results", ["compare", "a.json", "b.json"]),
    ],
    ids=["check", "compare"],
)
def test_a_bug_has_its_own_exit_code_and_asks_for_a_report(
    target: str, args: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """An error nobody wrapped (a bug) is not 1, what check and compare say about the
    machine: a script gating on `compare` must not read a crash as a warning."""

    def broken(*_: object, **__: object) -> None:
        {}["axes"]  # the bug

    monkeypatch.setattr(target, broken)
    result = runner.invoke(app, args)
    assert result.exit_code == 70, result.output
    assert result.stderr.splitlines() == [BUG_LINE]
    result = runner.invoke(app, [*args, "--debug"])
    assert result.exit_code == 70, result.output
    assert "Traceback" in result.stderr and result.stderr.splitlines()[-1] == BUG_LINE
    assert "in broken" in result.stderr


@pytest.mark.parametrize(
    ("error", "what"),
    [
        (ValueError("first line\n  second line"), "ValueError: first line second line"),
        (AssertionError(), "AssertionError"),
    ],
    ids=["two lines", "no text"],
)
def test_a_bug_is_one_line_whatever_its_text(
    error: Exception, what: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*_: object, **__: object) -> None:
        raise error

    monkeypatch.setattr("ncmeasure.program.check_programs", broken)
    result = runner.invoke(app, ["check", "out"])
    assert result.exit_code == 70, result.output
    assert result.stderr.splitlines() == [BUG_LINE.replace("KeyError: 'axes'", what)]


def test_a_reader_that_went_away_is_no_bug(tmp_path: Path) -> None:
    """`ncmeasure schema machine | head -1`: the pipe closes before the output is written.

    The read end is closed before the command starts, so every write fails (EPIPE),
    however fast or slow the host: the command ends quietly with 141, as shell tools do.
    """
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "ncmeasure", "schema", "machine"],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,
            check=False,
        )
    finally:
        os.close(write_end)
    assert done.returncode == 141, done.stderr
    assert done.stderr == ""


def test_a_table_is_whole_when_the_output_is_not_a_terminal(tmp_path: Path) -> None:
    """`ncmeasure plan m.toml > plan.txt` cut the table to 80 columns (cells like `ti…`);
    CliRunner's output is not a terminal either. 40 positions: a cell of 300 characters."""
    machine = tmp_path / "m.toml"
    text = example_machine("sinumerik-840d")
    machine.write_text(text.replace("positions = 3 ", "positions = 40 ", 1))
    code, out, _ = run("plan", machine, "--json")
    assert code == 0
    axes = json.loads(out)["axes"]
    code, out, _ = run("plan", machine)
    assert code == 0, out
    lines = out.splitlines()
    assert lines[1].split() == [
        "axis", "positions", "mm", "steps", "mm/min", "run-up", "windows", "time", "full",
        "travel",
    ]  # fmt: skip
    for axis, line in zip(axes, lines[2:5], strict=True):
        positions = ", ".join(f"{p:g}" for p in axis["nominal_positions_mm"])
        assert len(positions) > 250 and positions in line, line
        assert line.count("…") == 1, line  # the velocity range's own: 10 … 15000


def test_example_machines_are_data_files_that_validate() -> None:
    """init's and the demo's machines come from data files of the package and are valid."""
    import tomllib

    from ncmeasure.config import parse_machine
    from ncmeasure.examples import DEMO_LINKS, _demo_links, demo_machine

    assert set(DEMO_LINKS) == set(_demo_links())
    for link in DEMO_LINKS:
        config = parse_machine(tomllib.loads(demo_machine("linuxcnc", link)))
        assert config.link is not None and config.link["type"] == link
    config = parse_machine(tomllib.loads(example_machine("fanuc")))
    assert config.machine.controller == "fanuc"


def test_set_values_python_cannot_read_as_toml_stay_text() -> None:
    from ncmeasure.cli._options import settings

    huge, deep = "1" * 5000, "[" * 1000 + "]" * 1000
    assert settings([f"a={huge}", f"b={deep}", "c=5"]) == {"a": huge, "b": deep, "c": 5}


def _edit_schedule(folder: Path, **changes: object) -> None:
    data = json.loads((folder / "schedule.json").read_text())
    data.update(changes)
    (folder / "schedule.json").write_text(json.dumps(data))


HAND_EDITS: dict[str, tuple[Callable[[Path], None], int, str]] = {
    "main program is schedule.json": (
        lambda o: _edit_schedule(o, main_program="schedule.json"),
        2,
        "main_program: 'schedule.json' is not one of its program_files",
    ),
    "main program outside the folder": (
        lambda o: _edit_schedule(o, main_program="../x.ngc"),
        2,
        "main_program: '../x.ngc' is not a plain file name",
    ),
    "schedule nested 100 000 deep": (
        lambda o: (o / "schedule.json").write_text("[" * 100_000),
        2,
        "schedule.json: invalid JSON: arrays or tables nested too deep (at line 1)",
    ),
    "schedule with a 5000-digit number": (
        lambda o: (o / "schedule.json").write_text("1" * 5000),
        2,
        "schedule.json: invalid JSON: an integer of more than 4300 digits",
    ),
    "M word of 5000 digits": (
        lambda o: (o / "friction_x.ngc").open("a").write("M" + "9" * 5000 + "\n"),
        1,
        "M999999999999… (5000 digits) is not allowed",
    ),
}


@pytest.mark.parametrize("case", sorted(HAND_EDITS))
def test_check_of_hand_edited_folders_locates_the_problem(case: str, tmp_path: Path) -> None:
    edit, exit_code, expected = HAND_EDITS[case]
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    out = tmp_path / "out"
    assert run("generate", machine, "-o", out, "-q")[0] == 0
    edit(out)
    code, stdout, stderr = run("check", out)
    assert code == exit_code, stdout + stderr
    assert expected in stderr and "Traceback" not in stdout + stderr


def test_generate_into_a_folder_with_an_unreadable_schedule_leaves_it(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    out = tmp_path / "out"
    out.mkdir()
    (out / "schedule.json").write_text("[" * 100_000)
    code, _, stderr = run("generate", machine, "-o", out)
    assert code == 2 and "schedule.json: not a readable schedule" in stderr
    assert "nested too deep" in stderr and "Traceback" not in stderr
    assert [p.name for p in tmp_path.iterdir()] == ["m.toml", "out"]
    assert [p.name for p in out.iterdir()] == ["schedule.json"]


def test_a_flood_of_problems_is_printed_capped(tmp_path: Path) -> None:
    text = example_machine("linuxcnc").replace(
        "\n[measurement]\n",
        "\n[measurement]\n" + "".join(f"margin_mn{n} = 5.0\n" for n in range(10_000)),
    )
    machine = tmp_path / "m.toml"
    machine.write_text(text)
    code, _, stderr = run("generate", machine, "-o", tmp_path / "out")
    assert code == 2
    lines = stderr.splitlines()
    assert lines[0] == f"error: {machine} is not valid"
    assert lines[1].startswith("  measurement.margin_mn0: unknown key")
    assert lines[50].startswith("  measurement.margin_mn49: unknown key")
    assert lines[51:] == ["  … and 9950 more"]


def _interruptible() -> None:
    """In the child before it runs: Ctrl-C (SIGINT) at its default, as in a terminal."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_stopped_generate_leaves_the_folder_as_it_was(sig: int, tmp_path: Path) -> None:
    """Stopped while it renders (timeout, CI, systemd, Ctrl-C): exit 130, no staging folder."""
    data = tomllib.loads(example_machine("linuxcnc"))
    data["axes"] = data["axes"][:1]
    data["measurement"].update(velocity_steps=500, positions=20)  # 20 000 windows
    data["limits"] = {"max_duration_h": 100}
    machine = tmp_path / "m.toml"
    machine.write_text(machine_toml(data))
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("kept")
    process = subprocess.Popen(
        [sys.executable, "-m", "ncmeasure", "generate", str(machine), "-o", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # as from a terminal: a suite started in the background (`pytest &`) passes on
        # an ignored SIGINT, and Python then never raises KeyboardInterrupt
        preexec_fn=_interruptible,
    )
    try:
        while not any(  # wait for the event: programs being written in the staging folder
            p.stat().st_size > 100_000 for p in out.glob(".ncmeasure-new-*/friction_x.ngc")
        ):
            assert process.poll() is None, process.communicate()
            time.sleep(0.01)
        process.send_signal(sig)
        _, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 130, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.toml", "out"]
