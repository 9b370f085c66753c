"""``ncmeasure demo`` end to end, through both real links: the virtual machine runs the
generated program, simulated drives serve it, the link records it, the analysis must
find the friction the model put in and name the assembly fault that was injected.

Tolerances (also in docs/virtual-machine.md): per axis, the median relative error of the
measured friction against the model's is within ±1.5 % (a bias), every single point
(position, direction, velocity step) within 10 %; the injected cause ranks first,
in the single-run diagnosis for the local faults and in the comparison with the
correctly assembled machine for all of them (a preload shows only there).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.demo import DEFAULT_SPEED, DemoResult, run_demo
from ncmeasure.recording import read_recording
from ncmeasure.sim.axis import EXAMPLE_VARIATIONS

BIAS_PERCENT = 1.5
POINT_PERCENT = 10.0
LINKS = ("canopen", "modbus")
LOCAL = ("loose_bearing", "fixed_bearing", "screw_nut", "guide_rail", "cover_or_seal")

runner = CliRunner()


def assert_recovers_the_simulated_friction(result: DemoResult) -> None:
    measured = result.measured
    assert measured.acquisition is not None and measured.acquisition.status == "complete"
    expected_rows = measured.machine_time_s / 0.004
    if result.link == "modbus":
        expected_rows /= 2  # polled at 125 Hz
    assert measured.acquisition.rows >= 0.95 * expected_rows
    assert set(measured.accuracy) == {"X", "Z"}
    planned = 5 * 8 * 2  # positions, velocity steps, directions
    for name, axis in measured.results.axes.items():
        assert axis.windows >= 0.95 * planned, f"axis {name}: {axis.windows} of {planned} windows"
        found = measured.accuracy[name]
        assert found.points >= 0.95 * planned
        assert abs(found.median_error_percent) <= BIAS_PERCENT, found
        assert found.max_error_percent <= POINT_PERCENT, found
    meta = read_recording(measured.recording).meta
    assert meta.faster_than_real_time and meta.time_scale == result.speed
    assert measured.wall_time_s < measured.machine_time_s  # it did run faster


@pytest.fixture(scope="module")
def nominals(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], DemoResult]:
    """The demo without variation, once per link: the reference of the variation tests."""
    done: dict[str, DemoResult] = {}

    def nominal(link: str) -> DemoResult:
        if link not in done:
            folder = tmp_path_factory.mktemp(f"demo-{link}") / "nominal"
            done[link] = run_demo(folder, link=link)
        return done[link]

    return nominal


@pytest.mark.parametrize("link", LINKS)
def test_demo_without_variation(nominals: Callable[[str], DemoResult], link: str) -> None:
    nominal = nominals(link)
    assert_recovers_the_simulated_friction(nominal)
    assert nominal.speed == DEFAULT_SPEED[nominal.link]
    assert len(nominal.runs) == 1 and nominal.comparison is None
    results = nominal.measured.results
    assert results.skipped == {}
    for axis in results.axes.values():
        dependency = axis.position_dependency
        assert dependency is not None
        assert dependency.signature == "flat" and dependency.causes[0].cause == "none"
        # The healthy machine looks healthy: no alarm, and every curve says which model
        # describes it (the Stribeck hump is friction, not a fault).
        assert axis.verdict.level == "ok", axis.verdict
        for position in axis.positions:
            for direction in position.directions.values():
                assert direction is not None and direction.model_reason
                fit = direction.fit
                assert fit is not None and fit.coulomb is not None and fit.coulomb > 0
    assert nominal.measured.results.axes["Z"].offset is not None
    # gravity on the vertical axis: 500 kg, 20 mm lead
    assert nominal.measured.results.axes["Z"].offset.value == pytest.approx(15.6, rel=0.02)
    folder = nominal.directory
    for name in ("machine.toml", "programs/schedule.json", "results.json", "truth.json"):
        assert (folder / name).is_file(), name
    assert nominal.report is not None and nominal.report.is_file()
    html = nominal.report.read_text(encoding="utf-8")
    assert "virtual machine" in html and "Stribeck" in html
    truth = json.loads((folder / "truth.json").read_text(encoding="utf-8"))
    assert truth["axes"]["X"]["variation"] == {}


@pytest.mark.parametrize("link", LINKS)
@pytest.mark.parametrize("cause", list(EXAMPLE_VARIATIONS))
def test_demo_with_each_variation(
    nominals: Callable[[str], DemoResult], link: str, cause: str, tmp_path: Path
) -> None:
    nominal = nominals(link)
    variation = EXAMPLE_VARIATIONS[cause]
    result = run_demo(
        tmp_path / "varied",
        link=nominal.link,
        variation=variation,
        reference=nominal.directory,
        report=False,
    )
    assert_recovers_the_simulated_friction(result)
    assert [run.label for run in result.runs] == ["reference", "machine with the variation"]
    assert result.comparison is not None
    changes = {c.axis: c for c in result.comparison.changes}
    assert set(changes) == {"X", "Z"}
    for name, axis in result.measured.results.axes.items():
        ranked = [c.cause for c in changes[name].causes]
        assert ranked[0] == cause, f"axis {name}, change: {ranked}"
        dependency = axis.position_dependency
        assert dependency is not None
        single = [c.cause for c in dependency.causes]
        if cause in LOCAL:
            assert single[0] == cause, f"axis {name}, single run: {single}"
            assert axis.verdict.level in ("check", "fault"), axis.verdict
        else:  # a global offset: invisible in one run
            assert dependency.signature == "flat"
            assert changes[name].mean_change_percent > 5.0
    truth = json.loads((result.directory / "truth.json").read_text(encoding="utf-8"))
    assert truth["axes"]["X"]["variation"] == {k: v for k, v in vars(variation).items() if v}


def test_demo_command(nominals: Callable[[str], DemoResult], tmp_path: Path) -> None:
    nominal = nominals("canopen")
    out = tmp_path / "cli"
    result = runner.invoke(
        app,
        [
            "demo",
            str(out),
            "--variation",
            "loose_bearing_shift_um=500",
            "--reference",
            str(nominal.directory),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "Open" in result.output and str(out / "report.html") in result.output
    # the verdict per axis first, then the likely cause of the change against the reference
    for axis in ("X", "Z"):
        assert f"axis {axis}: fault · Coulomb friction " in result.output
    assert "likely a shifted or tilted loose bearing" in result.output
    assert "Likely cause of the change: Loose bearing shifted or tilted" in result.output
    assert (out / "comparison.json").is_file() and (out / "report.html").is_file()
    # a second run into the same folder needs --force; nothing is replaced without it
    again = runner.invoke(app, ["demo", str(out)])
    assert again.exit_code == 2
    assert "pass --force" in again.output and "Traceback" not in again.output
    assert (out / "comparison.json").is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--variation", "loose_bearing=5"], "loose_bearing: unknown variation key"),
        (["--variation", "nut_shift_um=abc"], "nut_shift_um: 'abc' is not a number"),
        (["--link", "ethercat"], "the demo records through canopen or modbus"),
        (["--speed", "0"], "speed 0: must be above 0"),
        (["--controller", "nonesuch"], "nonesuch"),
    ],
)
def test_demo_bad_input(tmp_path: Path, args: list[str], message: str) -> None:
    result = runner.invoke(app, ["demo", str(tmp_path / "out"), *args])
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output


def test_demo_refuses_a_folder_that_is_not_its_own(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine\n", encoding="utf-8")
    result = runner.invoke(app, ["demo", str(tmp_path)])
    assert result.exit_code == 2
    assert "exists and is not empty" in result.output
    assert (tmp_path / "notes.txt").read_text(encoding="utf-8") == "mine\n"
