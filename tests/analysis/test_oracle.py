"""The analysis against its oracle: the same results as the method on whole arrays.

ncmeasure reads a recording one way: in passes of chunks, keeping only the
samples around the windows; a recording in memory is one chunk of its own
arrays, a recording given by its directory is read from its file ``rows`` rows
at a time. ``tests/analysis/oracle.py`` is the same method on the whole arrays.
On the kinds of recording where reading in chunks could go wrong, both give
the same results.json and the same window times, bit for bit: every way of
finding windows (marker, whole-run and flag markers, command, plateaus), with
and without a schedule; gaps of NaN across chunk edges, "no value" codes, lost
rows, a damaged frame; coarse counts found by the position; 100 ms sampling;
several axes read together; dead, flat and still axes; frozen readings, counted
velocities, an axis that does not follow its command; chunks so small (37 rows)
that plateaus, filters and trimming margins reach across several of them. The
demo's recordings, made through the links, are checked in ``tests/test_demo.py``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.windows.find import array_rows, axis_windows, find_windows
from ncmeasure.analysis.windows.settings import SegmentSettings
from ncmeasure.errors import RecordingError
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RecordingHead, RecordingWriter
from ncmeasure.samples import SampleBlock
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.synthetic import (
    SyntheticAxis,
    geometric_velocities,
    simulate,
    synthetic_recording,
)
from tests.analysis import oracle
from tests.analysis.real_data import decimate, measure, write
from tests.analysis.test_real_data import COARSE, COUNTS, FOLLOWING, QUANTISED, TWO, VERTICAL

SMALL = SyntheticAxis(velocities_mm_min=geometric_velocities(10.0, 15000.0, 6))
IN_MEMORY = None
"""``rows`` of :func:`assert_same` for the recording in memory (one chunk)."""


def _outcome(run: Callable[[], Any]) -> Any:
    """results.json without its creation time, or the error's message and lines."""
    try:
        results = run()
    except RecordingError as exc:
        return ("error", exc.message, exc.problems)
    data = json.loads(results.model_dump_json())
    data.pop("created_utc")
    return data


def assert_same(
    recording: Recording,
    schedule: Schedule | None = None,
    *,
    rows: int | None = IN_MEMORY,
    **options: Any,
) -> Any:
    """The analysis gives the oracle's results and window times.

    The recording in memory (``rows`` None), or its file read ``rows`` rows at a time.
    """
    expected_times: dict[str, list[tuple[float, float]]] = {}
    expected = _outcome(
        lambda: oracle.analyze(recording, schedule=schedule, window_times=expected_times, **options)
    )
    times: dict[str, list[tuple[float, float]]] = {}
    source: Recording | Path = recording if rows is None else recording.directory
    chunks = {} if rows is None else {"rows": rows}
    found = _outcome(
        lambda: analyze(source, schedule=schedule, window_times=times, **chunks, **options)
    )
    assert found == expected, rows
    assert times == expected_times, rows
    return expected


def _damaged(source: Recording, directory: Path) -> Recording:
    """Gaps of NaN (some across chunk edges), no-value codes, lost rows, a damaged frame."""
    values = source.values.copy()
    names = list(source.channel_names)
    rng = np.random.default_rng(4)
    for name in names:
        if name.endswith("_marker"):
            continue
        column = names.index(name)
        for start in rng.integers(0, len(values) - 50, size=30).tolist():
            values[start : start + int(rng.integers(1, 40)), column] = np.nan
        values[rng.integers(0, len(values), size=5), column] = -999_999.0
    values[:7, 0] = np.nan  # NaN at both ends
    values[-12:, 0] = np.nan
    time_s = source.time_s.copy()
    time_s[len(time_s) // 3 :] += 0.5  # a hole in the time axis
    channels = [c.to_channel() for c in source.meta.channels]
    with RecordingWriter.create(directory, channels, nominal_period_s=0.004) as writer:
        for begin in range(0, len(time_s), 1000):
            end = begin + 1000
            writer.append(SampleBlock(time_s[begin:end], values[begin:end]))
            writer.flush()
    samples = directory / "samples.bin"
    raw = bytearray(samples.read_bytes())
    raw[-100] ^= 0xFF  # the last frame fails its checksum
    samples.write_bytes(bytes(raw))
    damaged = Recording.open(directory)
    assert 0.85 * len(time_s) < len(damaged) < len(time_s)
    return damaged


WAYS: dict[str, dict[str, Any]] = {
    "marker": {},
    "command": {"with_marker": False},
    "plateau": {"with_marker": False, "with_command": False},
    "run-marker": {"marker_scope": "run"},
    "flag-marker": {"marker_values": "flag"},
}
DAMAGED_ROWS = {"marker": 37, "plateau": 37}
"""Chunks of the damaged recordings: 37 rows, fewer than a plateau, for these ways."""


@pytest.mark.parametrize("way", list(WAYS))
def test_each_way_of_finding_windows(tmp_path: Path, way: str) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", [SMALL], **WAYS[way])
    assert assert_same(recording, schedule)["axes"]["X"]["windows"] > 0
    assert assert_same(recording, None, rows=1000)["axes"]["X"]["windows"] > 0
    damaged = _damaged(recording, tmp_path / "damaged")
    assert damaged.problems
    plan = schedule if "marker" in way else None
    assert_same(damaged, plan, rows=DAMAGED_ROWS.get(way, 1000))


@pytest.mark.parametrize("with_command", [True, False], ids=["command", "plateaus"])
def test_coarse_counts_found_by_the_position(tmp_path: Path, with_command: bool) -> None:
    axis = SyntheticAxis(
        velocities_mm_min=geometric_velocities(10.0, 2000.0, 5),
        velocity_quantum_mm_min=8.5,
        current_quantum=0.01,
    )
    recording, schedule = synthetic_recording(
        tmp_path / "rec", [axis], with_marker=False, with_command=with_command
    )
    found = assert_same(recording, schedule)
    assert any("displacement" in w for w in found["axes"]["X"]["warnings"])
    assert_same(_damaged(recording, tmp_path / "damaged"), schedule, rows=1000)


def test_three_axes_read_together(tmp_path: Path) -> None:
    axes = [
        SyntheticAxis(name="X", velocities_mm_min=SMALL.velocities_mm_min),
        SyntheticAxis(
            name="Y", velocities_mm_min=SMALL.velocities_mm_min, velocity_quantum_mm_min=8.5
        ),
        SyntheticAxis(
            name="Z",
            mechanics=rig_mechanics(vertical=True),
            velocities_mm_min=SMALL.velocities_mm_min,
            offset=1.0,
        ),
    ]
    recording, schedule = synthetic_recording(tmp_path / "rec", axes)
    assert set(assert_same(recording, schedule)["axes"]) == {"X", "Y", "Z"}
    assert_same(recording, schedule, axes=["Z", "X"], rows=1000)
    assert_same(_damaged(recording, tmp_path / "damaged"), None, rows=1000)


def test_a_100_ms_data_collector(tmp_path: Path) -> None:
    for with_command in (True, False):
        data = decimate(measure([COARSE], with_marker=False, with_command=with_command), 25)
        recording = write(tmp_path / f"rec{with_command}", data, [COARSE])
        assert_same(recording, data.schedule, rows=37)
        assert_same(recording)


def test_dead_still_and_flat_axes(tmp_path: Path) -> None:
    data = measure(TWO)
    n = len(data.time_s)
    dead = data.set("Z_current_a", np.zeros(n))
    assert "Z" in assert_same(write(tmp_path / "dead", dead, TWO), data.schedule)["skipped"]
    current = data.column("Z_current_a").copy()
    current[np.abs(data.column("Z_velocity_cmd_mm_min")) > 0] = 0.25
    flat = data.set("Z_current_a", current)
    assert_same(write(tmp_path / "flat", flat, TWO), data.schedule, rows=1000)
    still = data.set("Z_position_mm", np.full(n, -250.0)).set("Z_velocity_mm_min", np.zeros(n))
    still = still.set("Z_velocity_cmd_mm_min", np.zeros(n)).set("Z_marker", np.zeros(n))
    assert_same(write(tmp_path / "still", still, TWO), data.schedule)
    both = data.set("X_current_a", np.zeros(n)).set("Z_current_a", np.zeros(n))
    assert assert_same(write(tmp_path / "none", both, TWO), rows=1000)[0] == "error"
    no_position = data.without("X_position_mm", "Z_position_mm")
    assert_same(write(tmp_path / "no-position", no_position, TWO), rows=1000)
    stopped = no_position.set("Z_velocity_mm_min", np.zeros(n)).set("Z_marker", np.zeros(n))
    stopped = stopped.set("Z_velocity_cmd_mm_min", np.zeros(n))
    assert "did not move" in assert_same(write(tmp_path / "stopped", stopped, TWO))["skipped"]["Z"]


def test_real_data_properties(tmp_path: Path) -> None:
    quantised = measure([QUANTISED], with_marker=False, with_command=False)
    velocity = quantised.column("X_velocity_mm_min").copy()
    velocity[np.abs(velocity) < 1.0] = -3.0  # a reading frozen at standstill
    frozen = quantised.set("X_velocity_mm_min", velocity)
    assert_same(write(tmp_path / "frozen", frozen, [QUANTISED]), rows=1000)
    counts = measure([COUNTS], with_marker=False, with_command=False)
    assert_same(write(tmp_path / "counts", counts, [COUNTS]))
    following = measure([FOLLOWING], with_marker=False)
    assert_same(write(tmp_path / "following", following, [FOLLOWING]), following.schedule)
    vertical = measure([VERTICAL], seed=4)
    keep = np.ones(len(vertical.time_s), dtype=bool)
    rng = np.random.default_rng(2)
    for start in rng.choice(len(keep) - 20, 40, replace=False):
        keep[start : start + int(rng.integers(1, 12))] = False
    lost = write(tmp_path / "lost", vertical.rows(keep), [VERTICAL], period_s=0.004)
    assert assert_same(lost, vertical.schedule, rows=1000)["recording"]["gaps"] > 0


def test_a_missing_current_and_an_empty_recording(tmp_path: Path) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", TWO)
    keep = [i for i, c in enumerate(recording.meta.channels) if c.name != "Z_current_a"]
    channels = [recording.meta.channels[i].to_channel() for i in keep]
    with RecordingWriter.create(tmp_path / "no-current", channels, nominal_period_s=0.004) as w:
        w.append(SampleBlock(recording.time_s, recording.values[:, keep]))
    without = Recording.open(tmp_path / "no-current")
    assert "Z_current_a" in assert_same(without, schedule, rows=1000)["skipped"]["Z"]
    assert assert_same(without, schedule, axes=["Z"])[0] == "error"
    with RecordingWriter.create(tmp_path / "empty", channels, nominal_period_s=0.004):
        pass
    empty = Recording.open(tmp_path / "empty")
    assert assert_same(empty)[0] == "error"
    assert assert_same(empty, rows=1000)[0] == "error"


# --- the windows of given arrays -------------------------------------------------------


@pytest.fixture(scope="module")
def signals() -> tuple[np.ndarray, dict[str, np.ndarray], Schedule]:
    """An axis' arrays with rapids and a warm-up stroke, a few "no value" codes in them."""
    data = simulate([SyntheticAxis()], seed=1)
    names = [c.name for c in data.channels]
    columns = {name: data.values[:, k].copy() for k, name in enumerate(names)}
    columns["X_velocity_mm_min"][[500, 9000]] = -999_999.0  # taken as they are
    assert data.schedule is not None
    return data.time_s, columns, data.schedule


@pytest.mark.parametrize("method", ["marker", "command", "plateau"])
@pytest.mark.parametrize("scheduled", [True, False], ids=["schedule", "clusters"])
def test_the_windows_of_given_arrays(
    signals: tuple[np.ndarray, dict[str, np.ndarray], Schedule], method: str, scheduled: bool
) -> None:
    time_s, columns, schedule = signals
    plan = schedule if scheduled else None
    settings = SegmentSettings(window_method=method)  # type: ignore[arg-type]
    given = {
        "position_mm": columns["X_position_mm"],
        "command_mm_min": columns["X_velocity_cmd_mm_min"],
        "marker": columns["X_marker"],
    }
    velocity = columns["X_velocity_mm_min"]
    expected = oracle.find_windows("X", time_s, velocity, schedule=plan, settings=settings, **given)
    assert (
        find_windows("X", time_s, velocity, schedule=plan, settings=settings, **given) == expected
    )
    # Read in chunks of 1000 rows: the same windows.
    wanted = ("velocity_mm_min", "position_mm", "velocity_cmd_mm_min", "marker")
    source = array_rows(time_s, {f"X_{s}": columns[f"X_{s}"] for s in wanted}, rows=1000)
    assert axis_windows("X", source, plan, settings) == expected


# --- reading a recording's file ----------------------------------------------------------


def test_a_recording_head_gets_the_problems_of_its_samples(tmp_path: Path) -> None:
    recording, _ = synthetic_recording(tmp_path / "rec", [SMALL])
    damaged = _damaged(recording, tmp_path / "damaged")
    head = RecordingHead.open(damaged.directory)
    analyze(head, rows=1000)
    assert head.problems == damaged.problems
    assert head.rows == len(damaged)


def test_progress_while_reading(tmp_path: Path) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", [SMALL])
    seen: list[tuple[str, float]] = []
    analyze(
        recording.directory, schedule=schedule, rows=500, progress=lambda s, f: seen.append((s, f))
    )
    reading = [(s, f) for s, f in seen if s.startswith("reading the recording, pass ")]
    assert reading[0] == ("reading the recording, pass 1", 500 / len(recording))
    assert ("reading the recording, pass 1", 1.0) in reading
    assert all(0.0 < f <= 1.0 for _, f in reading)
    assert "axis X: friction table" in [s for s, _ in seen]
    assert seen[-1] == ("done", 1.0)
