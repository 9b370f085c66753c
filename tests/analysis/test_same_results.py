"""A recording read chunk by chunk gives the same results as the recording in memory.

``analyze(directory)`` (what ``ncmeasure analyze`` runs) reads the samples in
chunks and keeps only the slices around the windows; ``analyze(Recording)``
works on the whole arrays. On every kind of recording the tests hold (the
three ways of finding windows with and without a schedule, whole-run markers,
coarse counts, 100 ms sampling, several axes, dead and still axes, damaged
files, lost rows, "no value" codes, the demo's recordings) the two give the
same results.json, bit for bit, with chunks so small (37 and 1000 rows) that
windows, plateaus and filter spans straddle chunk edges.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.analysis.analyze import analyze
from ncmeasure.errors import RecordingError
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RecordingHead, RecordingWriter
from ncmeasure.samples import SampleBlock
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording
from tests.analysis.real_data import decimate, measure, write
from tests.analysis.test_real_data import COARSE, COUNTS, FOLLOWING, QUANTISED, TWO, VERTICAL

SMALL = SyntheticAxis(velocities_mm_min=geometric_velocities(10.0, 15000.0, 6))
CHUNKS = (37, 1000)


def _outcome(run: Callable[[], Any]) -> Any:
    """results.json without its creation time, or the error's message and lines."""
    try:
        results = run()
    except RecordingError as exc:
        return ("error", exc.message, exc.problems)
    data = json.loads(results.model_dump_json())
    data.pop("created_utc")
    return data


def assert_same(recording: Recording, schedule: Schedule | None = None, **options: Any) -> Any:
    """The same results (and window times) in memory and at every chunk size."""
    times: dict[str, list[tuple[float, float]]] = {}
    whole = _outcome(lambda: analyze(recording, schedule=schedule, window_times=times, **options))
    for rows in CHUNKS:
        found: dict[str, list[tuple[float, float]]] = {}
        chunked = _outcome(
            lambda rows=rows, found=found: analyze(
                recording.directory, schedule=schedule, rows=rows, window_times=found, **options
            )
        )
        assert chunked == whole, rows
        assert found == times, rows
    return whole


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


@pytest.mark.parametrize("way", list(WAYS))
def test_each_way_of_finding_windows(tmp_path: Path, way: str) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", [SMALL], **WAYS[way])
    for plan in (schedule, None):
        found = assert_same(recording, plan)
        assert found["axes"]["X"]["windows"] > 0
    damaged = _damaged(recording, tmp_path / "damaged")
    assert damaged.problems
    for plan in (schedule, None):
        assert_same(damaged, plan)


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
    assert_same(_damaged(recording, tmp_path / "damaged"), schedule)


def test_three_axes_read_together(tmp_path: Path) -> None:
    axes = [
        SyntheticAxis(name="X", velocities_mm_min=SMALL.velocities_mm_min),
        SyntheticAxis(
            name="Y", velocities_mm_min=SMALL.velocities_mm_min, velocity_quantum_mm_min=8.5
        ),
        SyntheticAxis(
            name="Z", velocities_mm_min=SMALL.velocities_mm_min, vertical=True, offset=1.0
        ),
    ]
    recording, schedule = synthetic_recording(tmp_path / "rec", axes)
    assert set(assert_same(recording, schedule)["axes"]) == {"X", "Y", "Z"}
    assert_same(recording, schedule, axes=["Z", "X"])
    assert_same(_damaged(recording, tmp_path / "damaged"), None)


def test_a_100_ms_data_collector(tmp_path: Path) -> None:
    for with_command in (True, False):
        data = decimate(measure([COARSE], with_marker=False, with_command=with_command), 25)
        recording = write(tmp_path / f"rec{with_command}", data, [COARSE])
        assert_same(recording, data.schedule)
        assert_same(recording)


def test_dead_still_and_flat_axes(tmp_path: Path) -> None:
    data = measure(TWO)
    n = len(data.time_s)
    dead = data.set("Z_current_a", np.zeros(n))
    assert "Z" in assert_same(write(tmp_path / "dead", dead, TWO), data.schedule)["skipped"]
    current = data.column("Z_current_a").copy()
    current[np.abs(data.column("Z_velocity_cmd_mm_min")) > 0] = 0.25
    flat = data.set("Z_current_a", current)
    assert_same(write(tmp_path / "flat", flat, TWO), data.schedule)
    still = data.set("Z_position_mm", np.full(n, -250.0)).set("Z_velocity_mm_min", np.zeros(n))
    still = still.set("Z_velocity_cmd_mm_min", np.zeros(n)).set("Z_marker", np.zeros(n))
    assert_same(write(tmp_path / "still", still, TWO), data.schedule)
    both = data.set("X_current_a", np.zeros(n)).set("Z_current_a", np.zeros(n))
    assert assert_same(write(tmp_path / "none", both, TWO))[0] == "error"
    no_position = data.without("X_position_mm", "Z_position_mm")
    assert_same(write(tmp_path / "no-position", no_position, TWO))
    stopped = no_position.set("Z_velocity_mm_min", np.zeros(n)).set("Z_marker", np.zeros(n))
    stopped = stopped.set("Z_velocity_cmd_mm_min", np.zeros(n))
    assert "did not move" in assert_same(write(tmp_path / "stopped", stopped, TWO))["skipped"]["Z"]


def test_real_data_properties(tmp_path: Path) -> None:
    quantised = measure([QUANTISED], with_marker=False, with_command=False)
    velocity = quantised.column("X_velocity_mm_min").copy()
    velocity[np.abs(velocity) < 1.0] = -3.0  # a reading frozen at standstill
    frozen = quantised.set("X_velocity_mm_min", velocity)
    assert_same(write(tmp_path / "frozen", frozen, [QUANTISED]))
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
    assert assert_same(lost, vertical.schedule)["recording"]["gaps"] > 0


def test_a_recording_head_gets_the_problems_of_its_samples(tmp_path: Path) -> None:
    recording, _ = synthetic_recording(tmp_path / "rec", [SMALL])
    damaged = _damaged(recording, tmp_path / "damaged")
    head = RecordingHead.open(damaged.directory)
    analyze(head, rows=1000)
    assert head.problems == damaged.problems
    assert head.rows == len(damaged)


def test_the_demo_recordings(tmp_path: Path) -> None:
    from ncmeasure.demo import run_demo
    from ncmeasure.formats.schedule import load_schedule

    result = run_demo(tmp_path / "demo", report=False)
    recordings = sorted(p.parent for p in (tmp_path / "demo").rglob("meta.json"))
    assert recordings, result
    schedules = sorted((tmp_path / "demo").rglob("schedule.json"))
    for directory in recordings:
        assert_same(Recording.open(directory))
        for path in schedules:
            assert_same(Recording.open(directory), load_schedule(path))


def test_a_missing_current_and_an_empty_recording(tmp_path: Path) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", TWO)
    keep = [i for i, c in enumerate(recording.meta.channels) if c.name != "Z_current_a"]
    channels = [recording.meta.channels[i].to_channel() for i in keep]
    with RecordingWriter.create(tmp_path / "no-current", channels, nominal_period_s=0.004) as w:
        w.append(SampleBlock(recording.time_s, recording.values[:, keep]))
    without = Recording.open(tmp_path / "no-current")
    assert "Z_current_a" in assert_same(without, schedule)["skipped"]["Z"]
    assert assert_same(without, schedule, axes=["Z"])[0] == "error"
    with RecordingWriter.create(tmp_path / "empty", channels, nominal_period_s=0.004):
        pass
    assert assert_same(Recording.open(tmp_path / "empty"))[0] == "error"


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
