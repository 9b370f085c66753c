"""Machine coordinates whatever the operator left active, and the stop before the first move.

On a real control the operator's work offset (G54...) is almost never zero, a G92
shift or a tool length may be active. Every dialect's programs must move to the same
machine positions whatever is active (or stop with a message before the first move
where the control cannot feed in machine coordinates), and ``check`` must refuse a
program that would not: its prolog removed, a machine-coordinate word dropped, an
offset selected in between. LinuxCNC's own interpreter proves it for LinuxCNC
(tests/program/test_rs274.py); here ncmeasure's reader, which applies the codes as
each controller's manual says (cited in controllers/<name>.toml), proves it for all.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import ConfigError, ProgramCheckError, ProgramError
from ncmeasure.formats.schedule import SCHEDULE_FILE, load_schedule
from ncmeasure.program import check_programs, generate_programs, load_dialect
from ncmeasure.program.check import axis_numbers
from ncmeasure.program.reader import Motion, ProgramSet, ProgramTrace, Stop
from tests.conftest import DIALECTS, FIXED_TIME

Make = Callable[..., MachineConfig]

# What the operator left active, in mm: a work offset, a G92 / G52 shift, a tool length.
OPERATOR = {
    "work": {"X": 325.0, "Y": -40.0, "Z": -612.5},
    "shift": {"X": 101.6, "Y": 12.0, "Z": 5.0},
    "length": {"Z": 148.2},
}


@dataclass(frozen=True)
class Case:
    main: str
    """The main program's file."""
    prolog: tuple[str, str]
    """A prolog line (pattern) and what it becomes without its cancelling codes."""
    motion: str
    """The main program's first motion line (pattern)."""
    bare: str | None
    """That line without its machine-coordinate word (None: the dialect has none)."""
    work: tuple[str, str]
    """A line that selects a work offset, and its code."""
    shift: tuple[str, str]
    """A line that sets a shift, and its code."""


CASES = {
    "linuxcnc": Case(
        "friction.ngc",
        (r"^G17 G21 G90 G94 G40 G49 G80$", "G17 G21 G90 G94"),
        r"^G53 G0 Z-5\.000$",
        "G0 Z-5.000",
        ("G55", "G55"),
        ("G92 X100", "G92"),
    ),
    "sinumerik-840d": Case(
        "FRICTION.MPF",
        (r"^G40 D0$", ""),
        r"^SUPA G0 Z-5\.000$",
        "G0 Z-5.000",
        ("G54", "G54"),
        ("TRANS X100", "TRANS"),
    ),
    "fanuc": Case(
        "O1000.nc",
        (r"^G40 G49 G80$", ""),
        r"^G00 Z-5\.000$",
        None,
        ("G55", "G55"),
        ("G92 X100.", "G92"),
    ),
    "heidenhain-iso": Case(
        "FRICTION.I",
        (r"^N30 G00 G40 Z", "N30 G00 Z"),
        r"^N30 G00 G40 Z-5\.000 M91 \*$",
        "N30 G00 G40 Z-5.000 *",
        ("N25 M92 *", "M92"),
        ("N25 G54 X+100 *", "G54"),
    ),
    "twincat": Case(
        "FRICTION.nc",
        (r"^G40 D0$", ""),
        r"^#SUPPRESS OFFSETS Z-5\.000$",
        "Z-5.000",
        ("G54", "G54"),
        ("G92 X100", "G92"),
    ),
}
assert sorted(CASES) == sorted(DIALECTS)


def _generate(make_config: Make, dialect: str, folder: Path, **machine: object) -> Path:
    config = make_config(dialect, small=True)
    if machine:
        data = config.model_dump()
        data["machine"].update(machine)
        config = MachineConfig.model_validate(data)
    generate_programs(config, generated=FIXED_TIME).write(folder)
    return folder


def _run(folder: Path, offsets: dict[str, dict[str, float]] | None = None) -> ProgramTrace:
    schedule = load_schedule(folder / SCHEDULE_FILE)
    dialect = load_dialect(schedule.controller)
    files = ProgramSet(dialect, folder, schedule.controller_options)
    axes = {axis.name for axis in schedule.axes}
    return files.run(
        schedule.main_program, axes, offsets=offsets, axis_numbers=axis_numbers(schedule)
    )


def _edit(path: Path, pattern: str, replacement: str) -> None:
    text = path.read_text(encoding="utf-8")
    new, n = re.subn(pattern, replacement, text, count=1, flags=re.M)
    assert n == 1, f"pattern {pattern!r} not found in {path.name}"
    path.write_text(new, encoding="utf-8")


def _positions(trace: ProgramTrace) -> list[tuple[str, dict[str, float]]]:
    return [(m.kind, m.target) for m in trace.motions]


@pytest.mark.parametrize("dialect", DIALECTS)
def test_the_operators_offsets_do_not_move_the_program(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    plain = _run(folder)
    shifted = _run(folder, OPERATOR)
    assert len(plain.motions) > 50
    if shifted.stopped:
        # a control that cannot feed in machine coordinates stops before the first move
        assert not shifted.motions, shifted.stopped
    else:
        assert _positions(shifted) == _positions(plain)


@pytest.mark.parametrize("dialect", sorted(CASES))
def test_without_the_prolog_the_offsets_would_move_it(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    """The reader's model is not vacuous: the same program without its prolog and its
    machine-coordinate words lands elsewhere, and check refuses it."""
    case = CASES[dialect]
    folder = _generate(make_config, dialect, tmp_path)
    _edit(folder / case.main, *case.prolog)
    with pytest.raises(ProgramCheckError, match="may still act on it"):
        check_programs(folder)


@pytest.mark.parametrize("dialect", [d for d in sorted(CASES) if CASES[d].bare is not None])
def test_a_move_without_its_machine_coordinate_word_is_refused(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    case = CASES[dialect]
    folder = _generate(make_config, dialect, tmp_path)
    assert case.bare is not None
    _edit(folder / case.main, case.motion, case.bare)
    with pytest.raises(
        ProgramCheckError, match=r"a work offset .*may still act|may still act.*work"
    ):
        check_programs(folder)
    assert _positions(_run(folder, OPERATOR)) != _positions(_run(folder))


@pytest.mark.parametrize("which", ["work", "shift"])
@pytest.mark.parametrize("dialect", sorted(CASES))
def test_an_offset_slipped_in_before_a_move_is_refused(
    dialect: str, which: str, make_config: Make, tmp_path: Path
) -> None:
    case = CASES[dialect]
    folder = _generate(make_config, dialect, tmp_path)
    line, code = case.work if which == "work" else case.shift
    main = folder / case.main
    text = main.read_text(encoding="utf-8")
    found = re.search(case.motion, text, flags=re.M)
    assert found
    main.write_text(text[: found.start()] + line + "\n" + text[found.start() :])
    with pytest.raises(ProgramError, match=rf"{re.escape(code)} \(.*\) selects"):
        check_programs(folder)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_the_main_program_stops_with_a_message_before_its_first_move(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, dialect, tmp_path / "attended")
    steps = _run(folder).steps
    first_stop = next(i for i, s in enumerate(steps) if isinstance(s, Stop))
    first_move = next(i for i, s in enumerate(steps) if isinstance(s, Motion))
    assert first_stop < first_move
    stop = steps[first_stop]
    assert isinstance(stop, Stop) and stop.message and stop.calls == 0
    assert load_schedule(folder / SCHEDULE_FILE).confirm_start
    # unattended series: no stop at all, and check does not ask for one
    folder = _generate(make_config, dialect, tmp_path / "series", confirm_start=False)
    assert not any(isinstance(s, Stop) for s in _run(folder).steps)
    assert check_programs(folder).ok


@pytest.mark.parametrize("dialect", DIALECTS)
def test_a_program_whose_stop_was_removed_is_refused(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    schedule = load_schedule(folder / SCHEDULE_FILE)
    dialect_data = load_dialect(dialect)
    main = folder / schedule.main_program
    stop = re.compile(dialect_data.start.stop[0].strip("^$"), re.I)
    lines = main.read_text(encoding="utf-8").split("\n")
    index = next(i for i, line in enumerate(lines) if stop.search(line.rstrip(" *")))
    del lines[index]
    main.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(ProgramCheckError, match="before the programmed stop"):
        check_programs(folder)


def test_fanuc_proves_every_axis_before_the_first_move(make_config: Make, tmp_path: Path) -> None:
    """FANUC feeds in work coordinates (its G53 is rapid only): the prolog compares the
    machine and work position of every axis and stops with an alarm unless they agree.
    A verification that leaves an axis out proves nothing, and check says so."""
    folder = _generate(make_config, "fanuc", tmp_path)
    main = folder / "O1000.nc"
    text = main.read_text(encoding="utf-8")
    verify = re.compile(
        r"^IF\[ABS\[#502(\d)-#504(\d)\]GT0\.001\]THEN#3000=1\(WORK OFFSET NOT ZERO\)$"
    )
    lines = text.split("\n")
    found = [(i, m.groups()) for i, line in enumerate(lines) if (m := verify.match(line))]
    assert [groups for _, groups in found] == [("1", "1"), ("2", "2"), ("3", "3")]
    assert _run(folder, OPERATOR).stopped == f"O1000.nc:{found[-1][0] + 1}"
    assert _run(folder, {"work": {"X": 0.0, "Y": 0.0, "Z": 0.0}}).motions
    # Y's check replaced by a second one of X: Y is not proved
    main.write_text(text.replace("#5022-#5042", "#5021-#5041"), encoding="utf-8")
    with pytest.raises(ProgramCheckError, match="may still act on it"):
        check_programs(folder)


def test_fanuc_checks_the_axes_by_their_number_in_the_control(
    make_config: Make, tmp_path: Path
) -> None:
    """A machine file that lists only Y and Z: their numbers in the control (2, 3) are
    checked, not 1 and 2."""
    config = make_config("fanuc", small=True)
    data = config.model_dump()
    data["axes"] = data["axes"][1:]
    data["axes"][0]["control_axis"] = 2
    data["axes"][1]["control_axis"] = 3
    generate_programs(MachineConfig.model_validate(data), generated=FIXED_TIME).write(tmp_path)
    text = (tmp_path / "O1000.nc").read_text(encoding="utf-8")
    assert re.findall(r"^IF\[ABS\[#(\d+)-#(\d+)\]", text, re.M) == [
        ("5022", "5042"),
        ("5023", "5043"),
    ]
    data["axes"][1]["control_axis"] = 2
    with pytest.raises(
        ConfigError, match=r"axes\[1\].control_axis: axis Z would be control axis 2"
    ):
        parse_machine(data)


@pytest.mark.parametrize(
    ("dialect", "file", "pattern", "replacement", "problem"),
    [
        # words hidden behind an operator message are words: a move in work coordinates
        ("linuxcnc", "friction.ngc", r"^M0$", "M0\n(MSG,x) G0 Z-400 (y)", "may still act"),
        ("linuxcnc", "friction.ngc", r"^M0$", "M0\nG53", "moves no axis"),
        # a cleared message is no message
        ("sinumerik-840d", "FRICTION.MPF", r'^MSG\(".*"\)$', "MSG()", "shows the operator no"),
        ("fanuc", "O1000.nc", r"^#3006=1\(.*\)$", "#3006=1", "shows the operator no"),
        ("twincat", "FRICTION.nc", r'^#MSG SYN \[".*"\]$', '#MSG SYN [" "]', "cannot read"),
        # a transformation left on changes what every axis word means
        ("sinumerik-840d", "FRICTION.MPF", r"^TRAFOOF$", "", "kinematic transformation"),
    ],
)
def test_what_only_looks_like_the_prolog_is_refused(
    dialect: str,
    file: str,
    pattern: str,
    replacement: str,
    problem: str,
    make_config: Make,
    tmp_path: Path,
) -> None:
    folder = _generate(make_config, dialect, tmp_path)
    if "TRAFOOF" in pattern:  # every program of the set switches it off: remove them all
        for path in folder.glob("*.?PF"):
            _edit(path, pattern, replacement)
    else:
        _edit(folder / file, pattern, replacement)
    with pytest.raises((ProgramCheckError, ProgramError), match=problem):
        check_programs(folder)


@pytest.mark.parametrize(
    ("dialect", "said"),
    [
        ("linuxcnc", "every move in machine coordinates whatever offset is active"),
        ("fanuc", "every move in work coordinates proved equal to the machine's, or a stop"),
    ],
)
def test_check_says_how_the_moves_are_safe(
    dialect: str, said: str, make_config: Make, tmp_path: Path
) -> None:
    from tests.test_cli import run

    folder = _generate(make_config, dialect, tmp_path)
    code, stdout, _ = run("check", folder)
    assert code == 0 and said in " ".join(stdout.split()), stdout
