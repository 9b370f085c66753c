"""`ncmeasure simulate`: variations of the axis model side by side."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import parse_machine
from ncmeasure.examples import example_machine
from ncmeasure.sim.axis import EXAMPLE_VARIATIONS, Variation
from ncmeasure.sim.explore import plot_study, study
from tests.conftest import example_data

runner = CliRunner()


def test_study_shows_the_shape_of_each_variation(tmp_path: Path) -> None:
    config = parse_machine(example_data())
    x = config.axis("X")  # fixed bearing at the min end
    result = study(
        x,
        config.measurement_for(x),
        ["loose_bearing_shift_um=500", "bearing_preload_change=-0.5", "cover_step=0.2"],
        positions=9,
        velocities=6,
    )
    nominal, loose, preload, cover = result.scenarios
    assert nominal.name == "nominal" and nominal.change_percent == [0.0] * 9
    # a shifted loose bearing: ~nothing at the fixed end, a clear rise towards the loose end
    assert 0 <= loose.change_percent[0] < 0.05 * loose.change_percent[-1]
    assert loose.change_percent[-1] > 20
    assert np.all(np.diff(loose.change_percent) >= -1e-9)
    # less preload: the same drop everywhere
    assert max(preload.change_percent) < 0 and np.ptp(preload.change_percent) < 0.1
    # a sticking cover: a step
    steps = np.diff(cover.change_percent)
    assert steps.max() > 10 and np.sort(steps)[-2] < 1
    assert plot_study(result, tmp_path / "s.png").stat().st_size > 10_000


def test_study_takes_variations_and_names_them_by_their_text() -> None:
    config = parse_machine(example_data())
    x = config.axis("X")
    examples = list(EXAMPLE_VARIATIONS.values())
    result = study(x, config.measurement_for(x), [*examples, Variation()], positions=5)
    names = [s.name for s in result.scenarios]
    assert names == ["nominal", *(v.as_text() for v in examples), "nominal"]
    assert names[1] == "loose_bearing_shift_um=500"
    by_text = study(x, config.measurement_for(x), names[1:-1], positions=5)
    assert by_text.scenarios == result.scenarios[:-1]
    # the bowed rail peaks mid-travel; a preload change is the same everywhere
    rail = result.scenarios[1 + list(EXAMPLE_VARIATIONS).index("guide_rail")]
    assert int(np.argmax(rail.change_percent)) == 2 and rail.change_percent[2] > 10
    preload = result.scenarios[1 + list(EXAMPLE_VARIATIONS).index("preload_or_carriage")]
    assert np.ptp(preload.change_percent) < 1e-6 < preload.change_percent[0]


def test_simulate_command(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    result = runner.invoke(
        app, ["simulate", str(machine), "--variation", "nut_shift_um=500", "--json"]
    )
    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert [s["name"] for s in data["scenarios"]] == ["nominal", "nut_shift_um=500"]
    result = runner.invoke(app, ["simulate", str(machine), "--variation", "nut_shift=5"])
    assert result.exit_code == 2 and "nut_shift" in result.stderr
    assert "Traceback" not in result.stderr
    result = runner.invoke(app, ["simulate", str(machine), "--axis", "Q"])
    assert result.exit_code == 2 and "has axes X, Y, Z" in result.stderr


def test_a_plot_without_matplotlib_names_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """matplotlib is the extra ``plot``: without it, --plot says so before any work."""
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib: ImportError
    png = tmp_path / "s.png"
    result = runner.invoke(app, ["simulate", str(machine), "--plot", str(png)])
    assert result.exit_code != 0
    assert "pip install 'ncmeasure[plot]'" in result.stderr and "--plot" in result.stderr
    assert "Traceback" not in result.stderr and not png.exists()
    assert result.stdout == ""  # no study was printed: the check came first
