"""The vertical axis first, and up: it parks at its safe end before anything else moves,
is measured last, and no other axis traverses while it is away from its park."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import ConfigError, ProgramCheckError
from ncmeasure.formats.schedule import SCHEDULE_FILE, load_schedule
from ncmeasure.program import check_programs, generate_programs
from ncmeasure.program.check import read_generated
from ncmeasure.sim.machine import VirtualMachine
from tests.conftest import DIALECTS, FIXED_TIME, small_data

Make = Callable[..., MachineConfig]


def _data(controller: str = "linuxcnc") -> dict[str, Any]:
    data = small_data(controller)
    names = [axis["name"] for axis in data["axes"]]
    assert "Z" in names and next(a for a in data["axes"] if a["name"] == "Z")["vertical"]
    return data


def _z(data: dict[str, Any]) -> dict[str, Any]:
    return next(axis for axis in data["axes"] if axis["name"] == "Z")


def test_a_vertical_axis_parked_low_is_refused_with_the_numbers() -> None:
    data = _data()
    z = _z(data)
    z["travel_mm"] = [-900.0, 5.0]
    z["park_mm"] = -850.0
    with pytest.raises(ConfigError) as caught:
        parse_machine(data)
    problem = "\n".join(caught.value.problems)
    assert "axes[2].park_mm: -850 mm is not at the safe end of vertical axis Z" in problem
    assert "[-221.25, 5] mm" in problem  # the upper quarter of -900...5
    z["park_mm"] = -80.0
    assert parse_machine(data).axis("Z").park_mm == -80.0


def test_the_safe_end_can_be_the_lower_one_and_any_axis_can_retract_first() -> None:
    data = _data()
    z = _z(data)
    z["travel_mm"] = [0.0, 500.0]
    z["park_mm"] = 10.0
    with pytest.raises(ConfigError, match=r"upper quarter of its travel \[375, 500\]"):
        parse_machine(data)
    z["safe_end"] = "min"
    assert parse_machine(data).axis("Z").safe_side == "min"
    y = data["axes"][1]
    y["retract_first"] = True
    y["park_mm"] = 100.0
    with pytest.raises(ConfigError, match=r"retract_first axis Y"):
        parse_machine(data)
    y["park_mm"] = y["travel_mm"][1]
    config = parse_machine(data)
    assert [a.name for a in config.park_sequence()][:2] == ["Y", "Z"]
    assert [a.name for a in config.measure_sequence()][-2:] == ["Y", "Z"]
    data["axes"][0]["safe_end"] = "max"
    with pytest.raises(ConfigError, match=r"axes\[0\].safe_end: only a vertical"):
        parse_machine(data)


def test_a_park_or_measure_order_that_moves_the_vertical_axis_late_or_early_is_refused() -> None:
    data = _data()
    data["machine"]["park_order"] = ["X", "Z", "Y"]
    with pytest.raises(ConfigError, match=r"park_order: X would move before Z"):
        parse_machine(data)
    data["machine"]["park_order"] = ["Z", "Y", "X"]
    data["machine"]["measure_order"] = ["Z", "X", "Y"]
    with pytest.raises(ConfigError, match=r"measure_order: Z would leave its park before"):
        parse_machine(data)
    data["machine"]["measure_order"] = ["Y", "X", "Z"]
    config = parse_machine(data)
    assert [a.name for a in config.park_sequence()] == ["Z", "Y", "X"]


def _main_axis_lines(folder: Path) -> list[str]:
    """The axis letters of the main program's motion blocks, in order, from its text."""
    schedule = load_schedule(folder / SCHEDULE_FILE)
    text = (folder / schedule.main_program).read_text(encoding="utf-8")
    letters = []
    for line in text.splitlines():
        line = re.sub(r"\(.*?\)|;.*$|\"[^\"]*\"", "", line)
        found = re.search(r"(?<![A-Z#])([XYZ])\s*=?\s*[-+]?\d", line)
        if found:
            letters.append(found.group(1))
    return letters


@pytest.mark.parametrize("dialect", DIALECTS)
def test_the_main_program_retracts_the_vertical_axis_first(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    config = make_config(dialect, small=True)
    generate_programs(config, generated=FIXED_TIME).write(tmp_path)
    assert _main_axis_lines(tmp_path)[0] == "Z"
    _, _, trace = read_generated(tmp_path)
    first = trace.motions[0]
    assert first.target == {"Z": config.axis("Z").park_mm} and first.calls == 0
    # measured last: the last subprogram's (or inline block's) moves are Z's
    assert set(trace.motions[-1].target) == {"Z"}


def test_check_refuses_a_program_that_traverses_with_the_vertical_axis_down(
    make_config: Make, tmp_path: Path
) -> None:
    generate_programs(make_config("linuxcnc", small=True), generated=FIXED_TIME).write(tmp_path)
    main = tmp_path / "friction.ngc"
    text = main.read_text(encoding="utf-8")
    z = re.search(r"^G53 G0 Z.*\n", text, flags=re.M)
    assert z
    text = text.replace(z.group(0), "")
    text = text.replace("(axis X:", z.group(0) + "(axis X:", 1)  # Z parked after X and Y
    main.write_text(text, encoding="utf-8")
    with pytest.raises(ProgramCheckError, match=r"X moves while a vertical .*\(Z not yet parked\)"):
        check_programs(tmp_path)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_on_the_virtual_machine_nothing_moves_before_the_vertical_axis_is_up(
    dialect: str, make_config: Make, tmp_path: Path
) -> None:
    config = make_config(dialect, small=True)
    generate_programs(config, generated=FIXED_TIME).write(tmp_path)
    z_park = config.axis("Z").park_mm
    low = config.axis("Z").travel_mm[0] + 10.0
    start = {"X": config.axis("X").travel_mm[0] + 20.0, "Y": 50.0, "Z": low}
    run = VirtualMachine.from_programs(config, tmp_path, start_mm=start, seed=1).run()
    # the commanded path: what the program tells the machine (the actual lags it a little)
    position = dict(zip(run.axes, run.position_cmd_mm, strict=True))
    z = position["Z"]
    up = np.abs(z - z_park) < 0.01
    assert z[0] == pytest.approx(low) and up.any()
    for name in ("X", "Y"):
        others = position[name]
        moving = np.abs(np.diff(others)) > 1e-9
        # X and Y stand still until Z is up, and move only while Z is at its park
        assert not moving[: int(np.argmax(up))].any()
        assert up[1:][moving].all()
        assert moving.any()


def test_no_retracting_axis_moves_while_another_is_away_from_its_park(tmp_path: Path) -> None:
    """Two retracting axes (a vertical Z, a quill W): they park one after the other, and
    neither moves while the other is away from its park."""
    data = _data()
    data["axes"].append(
        {
            **_z(data),
            "name": "W",
            "vertical": False,
            "retract_first": True,
            "travel_mm": [-300.0, 0.0],
            "park_mm": -5.0,
        }
    )
    data["machine"]["measure_order"] = ["X", "Y", "Z", "W"]
    generate_programs(parse_machine(data), generated=FIXED_TIME).write(tmp_path)
    assert check_programs(tmp_path).ok
    text = (tmp_path / "friction_z.ngc").read_text(encoding="utf-8")
    last = text.rstrip().split("\n")
    back = max(i for i, line in enumerate(last) if line.startswith("G53 G0 Z"))
    del last[back]  # Z stays down at the end of its measurement; W is measured next
    (tmp_path / "friction_z.ngc").write_text("\n".join(last) + "\n", encoding="utf-8")
    with pytest.raises(ProgramCheckError, match=r"W moves while a vertical .*\(Z at "):
        check_programs(tmp_path)
