"""LinuxCNC's standalone interpreter rs274 (package linuxcnc-uspace), as the tests use it.

``run_rs274`` runs a program and returns the canonical moves it emits;
``check_against_schedule`` holds them against the soft limits, the feeds and
the windows of schedule.json.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from ncmeasure.formats.schedule import Schedule

RS274 = shutil.which("rs274")
AXES = ("X", "Y", "Z", "A", "B", "C")
"""The axes rs274 prints, in its order (it knows no U, V, W without a configuration)."""
_CALL = re.compile(r"^\s*\d+ N\S* (?P<name>[A-Z0-9_]+)\((?P<args>.*)\)\s*$")


@dataclass(frozen=True)
class Canon:
    kind: str  # "rapid" | "feed"
    position: tuple[float, ...]
    """In program coordinates, as rs274 prints a canonical move."""
    feed: float
    marker: float
    machine: tuple[float, ...] = ()
    """In machine coordinates: the position plus the active G5x and G92 offsets."""


def _offsets(args: str, skip: int) -> tuple[float, ...]:
    return tuple(float(v) for v in args.split(",")[skip : skip + len(AXES)])


def run_rs274(folder: Path, main: str, parameters: str = "") -> list[Canon]:
    """The canonical moves of ``main``; ``parameters``: a parameter (.var) file's text,
    e.g. offsets the operator left active (rs274 reads its lengths in inches)."""
    assert RS274 is not None
    home = folder / "home"
    home.mkdir(exist_ok=True)
    options = []
    if parameters:
        (folder / "rs274.var").write_text(parameters, encoding="utf-8")
        options = ["-v", "rs274.var"]
    done = subprocess.run(
        [RS274, *options, "-g", main],
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
    g5x = g92 = (0.0,) * len(AXES)
    for line in output.splitlines():
        match = _CALL.match(line)
        if not match:
            assert not re.search(r"error|failed|unknown", line, re.I), line
            continue
        name, args = match.group("name"), match.group("args")
        if name == "SET_G5X_OFFSET":
            g5x = _offsets(args, 1)  # the first argument is the coordinate system's number
        elif name == "SET_G92_OFFSET":
            g92 = _offsets(args, 0)
        elif name == "SET_FEED_RATE":
            feed = float(args)
        elif name == "SET_MOTION_OUTPUT_VALUE":
            marker = float(args.split(",")[1])
        elif name == "SET_MOTION_OUTPUT_BIT" and marker == 0:
            marker = 1.0
        elif name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED"):
            values = tuple(float(v) for v in args.split(",")[: len(AXES)])
            kind = "rapid" if name == "STRAIGHT_TRAVERSE" else "feed"
            machine = tuple(v + a + b for v, a, b in zip(values, g5x, g92, strict=True))
            moves.append(Canon(kind, values, feed, marker, machine))
    return moves


def check_against_schedule(moves: list[Canon], schedule: Schedule, markers: bool) -> None:
    axes = {a.name: a for a in schedule.axes}
    previous: tuple[float, ...] = (0.0,) * len(AXES)
    feeds: dict[str, list[tuple[float, float, Canon]]] = {name: [] for name in axes}
    started: set[str] = set()  # rs274 starts every axis at 0: limits hold from its first move
    for move in moves:
        moved = [AXES[i] for i in range(len(AXES)) if abs(move.position[i] - previous[i]) > 1e-9]
        assert len(moved) <= 1, f"several axes move at once: {move}"
        started.update(moved)
        for i, name in enumerate(AXES):
            if name not in axes:
                assert move.position[i] == 0.0, f"{name} moves, which the schedule lacks"
                continue
            if name not in started:
                continue
            low, high = axes[name].travel_mm
            assert low <= move.position[i] <= high, f"{name} {move.position[i]} outside limits"
        if moved and move.kind == "feed":
            name = moved[0]
            i = AXES.index(name)
            assert move.feed <= axes[name].max_velocity_mm_min
            feeds[name].append((previous[i], move.position[i], move))
        previous = move.position
    for name, axis in axes.items():
        # each window with its run: run-up, window, run-out in a row (a run-out may look
        # like the next window)
        marked: dict[int, float] = {}
        index = 0
        for w in axis.windows:
            points = (w.start_mm, w.window_start_mm, w.window_end_mm, w.stop_mm)
            speed = abs(w.velocity_mm_min)
            while index + 3 <= len(feeds[name]) and not all(
                abs(feeds[name][index + k][0] - points[k]) < 5e-4
                and abs(feeds[name][index + k][1] - points[k + 1]) < 5e-4
                and abs(feeds[name][index + k][2].feed - speed) < 5e-4
                for k in range(3)
            ):
                index += 1
            assert index + 3 <= len(feeds[name]), f"window {w.id} of {name} is not driven"
            marked[index + 1] = w.id
            index += 3
        if markers:
            for number, (_, _, move) in enumerate(feeds[name]):
                assert move.marker == marked.get(number, 0.0), (name, number, move)


def fanuc_as_one_file(
    folder: Path, program_files: list[str], name: str = "all.ngc", sync_m: int = 0
) -> str:
    """FANUC programs (one O-number per file) joined into one file, as rs274 reads them.

    LinuxCNC reads a dwell only as G4 P<seconds>; FANUC's G04 X<seconds> is the same
    dwell and is rewritten so (FANUC's own P would be milliseconds). The prolog's
    offset verification (``IF[...]THEN``, custom macro B) is unknown to LinuxCNC and
    moves nothing: it is left out (see :func:`fanuc_lines`). The marker's
    non-buffered M code ``sync_m`` is a PLC function of the machine, unknown to
    LinuxCNC, and moves nothing: its blocks are left out.
    """
    combined = ["%"]
    for file in program_files:  # the main program first, then its subprograms
        text = (folder / file).read_text(encoding="utf-8")
        text = re.sub(r"^G04 X", "G4 P", text, flags=re.M)
        if sync_m:
            text = re.sub(rf"^M{sync_m}\n", "", text, flags=re.M)
        combined += fanuc_lines(text)
    combined.append("%")
    (folder / name).write_text("\n".join(combined) + "\n", encoding="utf-8")
    return name


def fanuc_lines(text: str) -> list[str]:
    """A FANUC program's lines as rs274 reads them: without its tape marks and without
    the offset verification (macro B ``IF[...]THEN #3000=1(...)``, which rs274 does not
    know and which moves nothing)."""
    return [line for line in text.splitlines() if line != "%" and not line.startswith("IF[")]
