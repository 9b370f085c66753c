"""Recordings with holes in their time axis: windows never span one, positions never cross one.

A hole is a time step longer than 1.5 sample periods: a link outage of a live
recording, or the step between two files of an import of several (each file a
segment). The axis may have moved any distance in it, at any speed.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.windows.find import array_rows, axis_windows, find_windows
from ncmeasure.analysis.windows.model import Segmentation
from ncmeasure.analysis.windows.settings import SegmentSettings
from ncmeasure.analysis.windows.signals import hole_rows
from ncmeasure.config import MachineConfig
from ncmeasure.traces import import_traces
from tests.analysis import oracle
from tests.traces.test_files import SPEEDS_RPM, epos_folder, write_map

FloatArray = NDArray[np.float64]


@pytest.fixture
def machine(make_config: Callable[..., MachineConfig]) -> MachineConfig:
    return make_config()


DT = 0.01
SPEED = 600.0
HOLE_S = 7.0


def _captures(seed: int, ramps: tuple[bool, bool] = (True, False)) -> tuple[FloatArray, FloatArray]:
    """One capture of a move at ``SPEED``: 6 s, a ramp at its start and/or its end only."""
    rng = np.random.default_rng(seed)
    n = 600
    profile = np.ones(n)
    ramp = np.linspace(0.0, 1.0, 40)
    if ramps[0]:
        profile[:60] = 0.0
        profile[60:100] = ramp
    if ramps[1]:
        profile[-60:] = 0.0
        profile[-100:-60] = ramp[::-1]
    # a drive's averaged velocity: correlated noise of about 1 %
    noise = np.zeros(n)
    for k in range(1, n):
        noise[k] = 0.8 * noise[k - 1] + rng.normal(0.0, 0.6 * 0.01 * SPEED)
    return np.arange(n) * DT, SPEED * profile + noise * (profile > 0)


def _two_segments() -> tuple[FloatArray, FloatArray]:
    """A steady move cut by a hole of ``HOLE_S``: the same speed and direction either side."""
    t1, v1 = _captures(1, (True, False))
    t2, v2 = _captures(2, (False, True))
    return np.concatenate((t1, t2 + t1[-1] + HOLE_S)), np.concatenate((v1, v2))


def _spans_no_hole(time_s: FloatArray, found: Segmentation) -> None:
    for window in found.windows:
        steps = np.diff(time_s[window.start : window.stop])
        assert steps.max() < 1.5 * DT, (window.start, window.stop)


@pytest.mark.parametrize("way", ["plateau", "command"])
def test_no_window_spans_a_hole(way: str) -> None:
    time_s, velocity = _two_segments()
    given = {"command_mm_min": np.full(len(time_s), SPEED)} if way == "command" else {}
    settings = SegmentSettings(window_method=way)  # type: ignore[arg-type]
    found = find_windows("X", time_s, velocity, settings=settings, **given)
    _spans_no_hole(time_s, found)
    # one window either side of the hole, each of most of its segment's steady part
    hole = len(time_s) // 2
    assert [w.start < hole for w in found.windows] == [True, False]
    assert all(w.samples > 300 for w in found.windows)
    # the same windows on the whole arrays, and in chunks smaller than a plateau
    expected = oracle.find_windows("X", time_s, velocity, settings=settings, **given)
    assert found == expected
    columns = {"X_velocity_mm_min": velocity} | (
        {"X_velocity_cmd_mm_min": given["command_mm_min"]} if given else {}
    )
    assert axis_windows("X", array_rows(time_s, columns, rows=37), None, settings) == expected


def test_fragments_are_not_joined_across_a_hole() -> None:
    """Two short plateaus next to a hole, close in samples, stay two windows."""
    t1, v1 = _captures(3, (True, False))
    t2, v2 = _captures(4, (False, True))
    # only the last and first 2.5 s of motion next to the hole
    v1[:350] = 0.0
    v2[250:] = 0.0
    time_s = np.concatenate((t1, t2 + t1[-1] + HOLE_S))
    velocity = np.concatenate((v1, v2))
    settings = SegmentSettings(window_method="plateau")
    found = find_windows("X", time_s, velocity, settings=settings)
    _spans_no_hole(time_s, found)
    assert len(found.windows) == 2
    assert found == oracle.find_windows("X", time_s, velocity, settings=settings)


def test_positions_integrated_per_segment() -> None:
    """Without a position channel, the velocity is not integrated across a hole."""
    time_s, velocity = _two_segments()
    found = find_windows("X", time_s, velocity)
    first, second = found.windows
    # the second capture's position counts from its own start: the move of the first
    # (about 50 mm) does not carry over the hole
    assert 0.0 < second.position_mm < 0.5 * SPEED / 60.0 * 6.0
    assert first.position_mm > second.position_mm
    # positions on either side of a hole are not comparable: one position, said so
    assert len(found.positions) == 1
    assert {w.position_index for w in found.windows} == {0}
    assert any("hole" in w and "one position" in w for w in found.warnings), found.warnings
    assert found == oracle.find_windows("X", time_s, velocity)


def test_a_hole_within_one_window_is_kept_with_a_position() -> None:
    """With a position channel the positions stay measured: no pooling, only the split."""
    time_s, velocity = _two_segments()
    position = np.cumsum(velocity) * DT / 60.0
    found = find_windows("X", time_s, velocity, position_mm=position)
    _spans_no_hole(time_s, found)
    assert len(found.windows) == 2
    assert not any("one position" in w for w in found.warnings)
    assert found == oracle.find_windows("X", time_s, velocity, position_mm=position)


def test_holes_in_chunks_and_slower_segments() -> None:
    """A hole is a step over 1.5 periods and the step before: a segment sampled more slowly
    is no run of holes; the rows of any chunking give the same holes."""
    rng = np.random.default_rng(5)
    fast = np.arange(200) * DT
    slow = fast[-1] + 2.0 + np.arange(100) * 2.5 * DT  # a file at 25 ms after one at 10 ms
    outage = slow[-1] + 4 * DT + np.arange(100) * 2.5 * DT  # 3 samples lost
    time_s = np.concatenate((fast, slow, outage)) + rng.uniform(0, 1e-4, 400)
    whole = hole_rows(time_s, DT)
    assert whole.tolist() == [200, 300]
    for size in (1, 2, 3, 37, 199, 200, 201):
        found: list[int] = []
        before: list[float] = []
        for lo in range(0, len(time_s), size):
            part = time_s[lo : lo + size]
            found += (hole_rows(part, DT, before) + lo).tolist()
            before = [*before, *part[-2:].tolist()][-2:]
        assert found == whole.tolist(), size


def test_windows_in_segments_of_two_sample_periods() -> None:
    """Captures at 10, 10 and 25 ms in one recording: a window in each, none across."""
    t1, v1 = _captures(6, (True, True))
    t2, v2 = _captures(7, (True, True))
    t3, v3 = _captures(8, (True, True))
    second = t1[-1] + 2.0 + t2
    time_s = np.concatenate((t1, second, second[-1] + 2.0 + 2.5 * t3))
    velocity = np.concatenate((v1, v2, -v3))
    found = find_windows("X", time_s, velocity)
    assert [w.start // len(t1) for w in found.windows] == [0, 1, 2]
    for window in found.windows:
        steps = np.diff(time_s[window.start : window.stop])
        assert steps.max() < 1.5 * steps.min()
    assert found == oracle.find_windows("X", time_s, velocity)


def test_captures_of_an_import_without_position(tmp_path: Path, machine: MachineConfig) -> None:
    """One EPOS export per speed and direction, no position: every capture is measured, and
    the positions are not made up across the files."""
    epos_folder(tmp_path / "captures")
    import_traces(
        [tmp_path / "captures"],
        tmp_path / "rec",
        columns=write_map(tmp_path / "epos.toml"),
        machine=machine,
    )
    results = analyze(tmp_path / "rec", machine=machine)
    x = results.axes["X"]
    assert len(x.positions) == 1, [p.position_mm for p in x.positions]
    assert any("hole" in w and "one position" in w for w in x.warnings), x.warnings
    found = {
        round(point.velocity_mm_min)
        for position in x.positions
        for side in position.directions.values()
        if side is not None
        for point in side.points
    }
    assert found >= {s * 20 * d for s in SPEEDS_RPM for d in (1, -1)}, found
