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
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import ProgramCheckError, ProgramError
from ncmeasure.formats.schedule import SCHEDULE_FILE, load_schedule
from ncmeasure.program import check_programs, generate_programs, load_dialect
from ncmeasure.program.reader import Motion, ProgramSet, ProgramTrace, Stop
from tests.conftest import DIALECTS, FIXED_TIME

Make = Callable[..., MachineConfig]

# What the operator left active, in mm: a work offset, a G92 / G52 shift, a tool length.
OPERATOR = {
    "work": {"X": 325.0, "Y": -40.0, "Z": -612.5},
    "shift": {"X": 101.6, "Y": 12.0, "Z": 5.0},
    "length": {"Z": 148.2},
}

# Per dialect: (main program file, the prolog's cancelling line, a motion line of the
# main program, that line without its machine-coordinate word or None, a line that
# selects a work offset, a line that sets a shift).
CASES: dict[str, tuple[str, str, str, str | None, str, str]] = {
    "linuxcnc": (
        "friction.ngc",
        r"^G17 G21 G90 G94 G40 G49 G80$",
        r"^G53 G0 Z-5\.000$",
        "G0 Z-5.000",
        "G55",
        "G92 X100",
    ),
}


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
    return files.run(schedule.main_program, axes, offsets=offsets)


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
    main, prolog, _, _, _, _ = CASES[dialect]
    folder = _generate(make_config, dialect, tmp_path)
    _edit(folder / main, prolog, "")
    with pytest.raises(ProgramCheckError, match="may still act on it"):
        check_programs(folder)


@pytest.mark.parametrize("dialect", [d for d in sorted(CASES) if CASES[d][3] is not None])
def test_a_move_without_its_machine_coordinate_word_is_refused(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    main, _, motion, bare, _, _ = CASES[dialect]
    folder = _generate(make_config, dialect, tmp_path)
    assert bare is not None
    _edit(folder / main, motion, bare)
    with pytest.raises(ProgramCheckError, match=r"a work offset .*may still act|may still act.*work"):
        check_programs(folder)
    assert _positions(_run(folder, OPERATOR)) != _positions(_run(folder))


@pytest.mark.parametrize("which", ["work", "shift"])
@pytest.mark.parametrize("dialect", sorted(CASES))
def test_an_offset_slipped_in_before_a_move_is_refused(
    dialect: str, which: str, make_config: Make, tmp_path: Path
) -> None:
    main, _, motion, _, work, shift = CASES[dialect]
    folder = _generate(make_config, dialect, tmp_path)
    line = work if which == "work" else shift
    text = (folder / main).read_text(encoding="utf-8")
    found = re.search(motion, text, flags=re.M)
    assert found
    (folder / main).write_text(text[: found.start()] + line + "\n" + text[found.start() :])
    code = re.escape(line.split()[0])
    with pytest.raises(ProgramError, match=rf"{code} \(.*\) selects"):
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
