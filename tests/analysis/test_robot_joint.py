"""A robot joint's friction test, one file per run: every run found, each direction's friction.

Without the commanded velocity, the slow runs' velocity scatters by 10 to 40 %
of the speed and no stretch of it stays within a few per cent: the runs were
lost (16 and 12 of 40 found at their speed). Each run at one speed is now one
window (:meth:`~ncmeasure.analysis.windows.finder.WindowFinder.steady_runs`),
and each direction's Coulomb friction as measured is reported
(``coulomb_measured``), the offset between the directions left in.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.windows.find import windows_of
from ncmeasure.recording import read_recording
from ncmeasure.traces import import_traces
from tests.analysis.robot_joint import (
    DEG_MIN_PER_RAD_S,
    SHOULDER,
    WRIST,
    Joint,
    column_map,
    write_runs,
)

JOINTS = {joint.name: joint for joint in (SHOULDER, WRIST)}


Runs = dict[str, tuple[Path, list[float]]]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Runs:
    folder = tmp_path_factory.mktemp("robot")
    return {
        name: (folder / name, write_runs(joint, folder / name, seed=k))
        for k, (name, joint) in enumerate(JOINTS.items())
    }


@pytest.fixture(scope="module")
def imported(runs: Runs, tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    """The recording of a joint's runs, with or without the command (imported once)."""
    done: dict[tuple[str, bool, bool], Path] = {}

    def recording(name: str, command: bool, degrees: bool = True) -> Path:
        key = (name, command, degrees)
        if key not in done:
            folder = tmp_path_factory.mktemp(f"{name}-{command}-{degrees}")
            mapping = column_map(folder / "map.toml", command=command, degrees=degrees)
            import_traces([runs[name][0]], folder / "rec", columns=mapping)
            done[key] = folder / "rec"
        return done[key]

    return recording


@pytest.mark.parametrize("name", sorted(JOINTS))
def test_without_the_command_every_run_is_found_at_its_speed(
    runs: Runs, imported: Callable[..., Path], name: str
) -> None:
    _, signed = runs[name]
    seg = windows_of(read_recording(imported(name, False)), "J")
    assert seg.source == "plateau"
    found = [
        any(
            abs(w.velocity_mm_min - v * DEG_MIN_PER_RAD_S) <= 0.03 * abs(v) * DEG_MIN_PER_RAD_S
            for w in seg.windows
        )
        for v in signed
    ]
    assert sum(found) >= 38, [v for v, ok in zip(signed, found, strict=True) if not ok]
    # One window per run, one step per commanded speed: no run broken into fragments.
    assert len(seg.windows) == len(signed)
    assert len(seg.steps) == len(JOINTS[name].speeds_rad_s)


@pytest.mark.parametrize("command", [True, False], ids=["command", "no-command"])
@pytest.mark.parametrize("name", sorted(JOINTS))
def test_each_directions_coulomb_within_5_percent(
    imported: Callable[..., Path], name: str, command: bool
) -> None:
    joint: Joint = JOINTS[name]
    result = analyze(imported(name, command)).axes["J"]
    assert result.offset is not None
    for position in result.positions:
        for key, direction in (("positive", 1), ("negative", -1)):
            found = position.directions[key]
            assert found is not None and found.coulomb_measured is not None
            truth = joint.coulomb_nm(direction)
            assert found.coulomb_measured == pytest.approx(truth, rel=0.05), key
            # The fits take the offset out: both directions then hold the mean friction.
            assert found.fit is not None
            mean = 0.5 * (joint.coulomb_positive_nm + joint.coulomb_negative_nm)
            assert found.fit.coulomb == pytest.approx(mean, rel=0.05)
    assert np.isfinite(result.offset.value)


@pytest.mark.parametrize("name", sorted(JOINTS))
def test_radians_read_as_they_are_still_find_every_run(
    runs: Runs, imported: Callable[..., Path], name: str
) -> None:
    # A map without the degrees' scale: 0.005 to 1 rad/s where mm/min are expected all lay
    # below the standstill floor of 1 mm/min, and nothing was found.
    joint = JOINTS[name]
    _, signed = runs[name]
    path = imported(name, False, False)
    seg = windows_of(read_recording(path), "J")
    found = [any(abs(w.velocity_mm_min - v) <= 0.03 * abs(v) for w in seg.windows) for v in signed]
    assert sum(found) >= 38
    assert any("rad/s or deg/s" in w for w in seg.warnings)
    # Position in rad and velocity in rad/s: the position moves 60 times as far as a
    # velocity "per minute" says, and the readings alone measure the windows.
    assert any("60 times as far" in w for w in seg.warnings)
    result = analyze(path).axes["J"]
    for position in result.positions:
        for key, direction in (("positive", 1), ("negative", -1)):
            found_direction = position.directions[key]
            assert found_direction is not None
            assert found_direction.coulomb_measured == pytest.approx(
                joint.coulomb_nm(direction), rel=0.05
            )
