"""LinuxCNC's own interpreter (rs274, package linuxcnc-uspace) runs the generated G-code.

Every STRAIGHT_TRAVERSE / STRAIGHT_FEED it emits must stay inside the soft
limits, every feed within the axis maximum, the marked feeds must be the
windows of schedule.json, and ncmeasure's own reader must see the same moves.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.plan import Schedule
from ncmeasure.program import GeneratedPrograms, generate_programs
from ncmeasure.program.reader import read_programs
from tests.conftest import FIXED_TIME

RS274 = shutil.which("rs274")
if RS274 is None and os.environ.get("CI"):
    pytest.fail("rs274 (Debian package linuxcnc-uspace) is required in CI", pytrace=False)
pytestmark = [
    pytest.mark.rs274,
    pytest.mark.skipif(
        RS274 is None,
        reason="rs274 not installed (apt-get install linuxcnc-uspace); CI installs it",
    ),
]

AXES = ("X", "Y", "Z")
_CALL = re.compile(r"^\s*\d+ N\S* (?P<name>[A-Z_]+)\((?P<args>.*)\)\s*$")


@dataclass(frozen=True)
class Canon:
    kind: str  # "rapid" | "feed"
    position: tuple[float, float, float]
    feed: float
    marker: float


def run_rs274(folder: Path, main: str) -> list[Canon]:
    assert RS274 is not None
    home = folder / "home"
    home.mkdir(exist_ok=True)
    done = subprocess.run(
        [RS274, "-g", main],
        cwd=folder,
        env={**os.environ, "HOME": str(home)},
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    output = done.stdout + done.stderr
    assert "PROGRAM_END()" in output, output[-2000:]
    moves: list[Canon] = []
    feed, marker = 0.0, 0.0
    for line in output.splitlines():
        match = _CALL.match(line)
        if not match:
            assert not re.search(r"error|failed|unknown", line, re.I), line
            continue
        name, args = match.group("name"), match.group("args")
        if name == "SET_FEED_RATE":
            feed = float(args)
        elif name == "SET_MOTION_OUTPUT_VALUE":
            marker = float(args.split(",")[1])
        elif name == "SET_MOTION_OUTPUT_BIT" and marker == 0:
            marker = 1.0
        elif name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED"):
            values = [float(v) for v in args.split(",")[:3]]
            kind = "rapid" if name == "STRAIGHT_TRAVERSE" else "feed"
            moves.append(Canon(kind, (values[0], values[1], values[2]), feed, marker))
    return moves


def check_against_schedule(moves: list[Canon], schedule: Schedule, markers: bool) -> None:
    axes = {a.name: a for a in schedule.axes}
    previous = (0.0, 0.0, 0.0)
    windows = {name: list(a.windows) for name, a in axes.items()}
    found = dict.fromkeys(axes, 0)
    for move in moves:
        moved = [AXES[i] for i in range(3) if abs(move.position[i] - previous[i]) > 1e-9]
        assert len(moved) <= 1, f"several axes move at once: {move}"
        for i, name in enumerate(AXES):
            low, high = axes[name].travel_mm
            assert low <= move.position[i] <= high, f"{name} {move.position[i]} outside limits"
        if moved and move.kind == "feed":
            name = moved[0]
            i = AXES.index(name)
            assert move.feed <= axes[name].max_velocity_mm_min
            pending = windows[name]
            if pending:
                w = pending[0]
                is_window = (
                    abs(previous[i] - w.window_start_mm) < 5e-4
                    and abs(move.position[i] - w.window_end_mm) < 5e-4
                    and abs(move.feed - abs(w.velocity_mm_min)) < 5e-4
                )
                if is_window:
                    pending.pop(0)
                    found[name] += 1
                if markers:
                    assert move.marker == (w.id if is_window else 0), (move, w)
        previous = move.position
    for name, axis in axes.items():
        assert found[name] == len(axis.windows)


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


def test_fanuc_output_runs_in_rs274_fanuc_style(
    make_config: Callable[..., MachineConfig], tmp_path: Path
) -> None:
    """LinuxCNC reads FANUC-style O-number programs with M98/M99 from one file."""
    result = generate_programs(make_config("fanuc"), generated=FIXED_TIME)
    result.write(tmp_path)
    combined = ["%"]
    for name in sorted(result.files):  # O1000 (main) first, then its subprograms
        combined += [line for line in result.files[name].splitlines() if line != "%"]
    combined.append("%")
    (tmp_path / "all.ngc").write_text("\n".join(combined) + "\n")
    moves = run_rs274(tmp_path, "all.ngc")
    check_against_schedule(moves, result.schedule, markers=False)
    # the combined file is FANUC too: ncmeasure's reader splits it by O-numbers
    single = tmp_path / "single"
    single.mkdir()
    (single / "O1000.nc").write_text("\n".join(combined) + "\n")
    assert_reader_agrees(moves, single, result, "O1000.nc")
