"""LinuxCNC's own interpreter (rs274, package linuxcnc-uspace) runs the generated G-code.

Every STRAIGHT_TRAVERSE / STRAIGHT_FEED it emits must stay inside the soft
limits, every feed within the axis maximum, the marked feeds must be the
windows of schedule.json, and ncmeasure's own reader must see the same moves.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.examples import demo_machine, example_machine
from ncmeasure.program import GeneratedPrograms, generate_programs
from ncmeasure.program.reader import read_programs
from tests.conftest import FIXED_TIME, example_data
from tests.program.rs274 import (
    AXES,
    RS274,
    Canon,
    check_against_schedule,
    fanuc_lines,
    run_rs274,
)

if RS274 is None and os.environ.get("CI"):
    pytest.fail("rs274 (Debian package linuxcnc-uspace) is required in CI", pytrace=False)
pytestmark = [
    pytest.mark.rs274,
    pytest.mark.skipif(
        RS274 is None,
        reason="rs274 not installed (apt-get install linuxcnc-uspace); CI installs it",
    ),
]


def assert_reader_agrees(
    moves: list[Canon], folder: Path, result: GeneratedPrograms, main: str
) -> None:
    trace = read_programs(result.dialect, folder, main, set(AXES))
    position = dict.fromkeys(AXES, 0.0)
    ours = []
    for motion in trace.motions:
        position.update(motion.target)
        ours.append((motion.kind, tuple(position[a] for a in AXES)))
    theirs = [(m.kind, m.position) for m in moves]
    assert len(ours) == len(theirs)
    for a, b in zip(ours, theirs, strict=True):
        assert a[0] == b[0]
        assert a[1] == pytest.approx(b[1], abs=1e-4)


def test_linuxcnc_output_runs_in_rs274(
    make_config: Callable[..., MachineConfig], tmp_path: Path
) -> None:
    result = generate_programs(make_config("linuxcnc"), generated=FIXED_TIME)
    result.write(tmp_path)
    moves = run_rs274(tmp_path, result.main_file)
    assert len(moves) > 3000
    check_against_schedule(moves, result.schedule, markers=True)
    assert_reader_agrees(moves, tmp_path, result, result.main_file)


def test_position_order_runs_in_rs274(
    make_config: Callable[..., MachineConfig], tmp_path: Path
) -> None:
    result = generate_programs(make_config("linuxcnc", order="position"), generated=FIXED_TIME)
    result.write(tmp_path)
    moves = run_rs274(tmp_path, result.main_file)
    check_against_schedule(moves, result.schedule, markers=True)
    assert_reader_agrees(moves, tmp_path, result, result.main_file)


def test_fanuc_output_runs_in_rs274_fanuc_style(
    make_config: Callable[..., MachineConfig], tmp_path: Path
) -> None:
    """LinuxCNC reads FANUC-style O-number programs with M98/M99 from one file."""
    result = generate_programs(make_config("fanuc"), generated=FIXED_TIME)
    result.write(tmp_path)
    combined = ["%"]
    for name in sorted(result.files):  # O1000 (main) first, then its subprograms
        combined += fanuc_lines(result.files[name])
    combined.append("%")
    (tmp_path / "all.ngc").write_text("\n".join(combined) + "\n")
    moves = run_rs274(tmp_path, "all.ngc")
    check_against_schedule(moves, result.schedule, markers=False)
    # the combined file is FANUC too: ncmeasure's reader splits it by O-numbers
    single = tmp_path / "single"
    single.mkdir()
    (single / "O1000.nc").write_text("\n".join(combined) + "\n")
    assert_reader_agrees(moves, single, result, "O1000.nc")


@pytest.mark.parametrize("tiny", [False, True], ids=["realistic", "tiny"])
def test_a_runout_that_is_the_next_window_runs_as_planned(tiny: bool, tmp_path: Path) -> None:
    from tests.program.test_check import _runout_is_next_window

    result = generate_programs(parse_machine(_runout_is_next_window(tiny)), generated=FIXED_TIME)
    result.write(tmp_path)
    moves = run_rs274(tmp_path, result.main_file)
    check_against_schedule(moves, result.schedule, markers=True)
    assert_reader_agrees(moves, tmp_path, result, result.main_file)


# The operator's settings as a LinuxCNC parameter file: G54 active (5220 = 1) with a work
# offset, and a G92 offset applied (5210 = 1). rs274 reads the file's lengths in inches.
OPERATOR_OFFSETS = """\
5210 1.0
5211 4.0
5212 -2.5
5213 1.5
5220 1.0
5221 12.795
5222 3.0
5223 -7.25
"""


@pytest.mark.parametrize("machine", ["example", "demo"])
def test_machine_positions_do_not_depend_on_the_operators_offsets(
    machine: str, tmp_path: Path
) -> None:
    """Every canonical move lands at the same machine position (canonical position plus
    the active G5x and G92 offsets) with a G54 and a G92 offset active as without."""
    text = example_machine("linuxcnc") if machine == "example" else demo_machine("linuxcnc")
    result = generate_programs(parse_machine(tomllib.loads(text)), generated=FIXED_TIME)
    result.write(tmp_path)
    plain = run_rs274(tmp_path, result.main_file)
    shifted = run_rs274(tmp_path, result.main_file, OPERATOR_OFFSETS)
    assert len(shifted) == len(plain) > 100
    # the offsets really are active: the program coordinates differ from the machine's
    assert shifted[0].position != shifted[0].machine
    for ours, theirs in zip(plain, shifted, strict=True):
        assert ours.position == ours.machine
        assert theirs.machine == pytest.approx(ours.machine, abs=1e-4)
        assert theirs.kind == ours.kind
    check_against_schedule(plain, result.schedule, markers=True)


def test_the_ready_wait_runs_in_rs274_and_its_time_out_ends_the_program(tmp_path: Path) -> None:
    """LinuxCNC's interpreter accepts the recorder-ready wait (M66 … L3 Q…); with the input
    high the program moves as without the wait, and on a time-out (#5399 = -1) the main
    program ends before its first move."""
    plain = example_data("linuxcnc")
    waiting = example_data("linuxcnc")
    waiting["machine"]["ready_input"] = 2
    folders = {}
    for name, data in (("plain", plain), ("waiting", waiting)):
        result = generate_programs(parse_machine(data), generated=FIXED_TIME)
        folders[name] = tmp_path / name
        result.write(folders[name])
    main = result.main_file
    text = (folders["waiting"] / main).read_text(encoding="utf-8")
    assert "M66 P2 L3 Q60" in text
    moves = run_rs274(folders["waiting"], main)
    assert moves and moves == run_rs274(folders["plain"], main)
    # the recorder never answered: M66 sets #5399 to -1, the branch ends the program
    (folders["waiting"] / main).write_text(
        text.replace("M66 P2 L3 Q60\n", "M66 P2 L3 Q60\n#5399=-1\n"), encoding="utf-8"
    )
    assert run_rs274(folders["waiting"], main) == []
