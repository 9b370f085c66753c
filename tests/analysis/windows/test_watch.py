"""Work that needs an axis' windows rides along the analysis' own readings of the recording."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

import ncmeasure.analysis.reading as reading_module
from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.windows.streaming import Task
from ncmeasure.analysis.windows.watch import AxisWindows, NamedChunk, Watch, Watchers
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RecordingHead, RecordingWriter, RowChunk
from ncmeasure.samples import SampleBlock
from ncmeasure.sim.synthetic import (
    SyntheticAxis,
    geometric_velocities,
    machine_config,
    synthetic_recording,
)

AXES = [
    SyntheticAxis(name="X", velocities_mm_min=geometric_velocities(10.0, 15000.0, 5)),
    SyntheticAxis(name="Z", velocities_mm_min=geometric_velocities(10.0, 6000.0, 4)),
]


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory) -> tuple[Recording, Schedule]:
    """The two axes measured one after the other, written in frames of 400 rows."""
    base = tmp_path_factory.mktemp("watch")
    source, schedule = synthetic_recording(base / "source", AXES)
    assert schedule is not None
    channels = [c.to_channel() for c in source.meta.channels]
    with RecordingWriter.create(
        base / "framed",
        channels,
        nominal_period_s=source.meta.nominal_period_s,
        machine=machine_config(AXES),
        config_hash=schedule.config_hash,
        faster_than_real_time=True,
    ) as writer:
        for first in range(0, len(source), 400):
            rows = slice(first, first + 400)
            writer.append(SampleBlock(source.time_s[rows], source.values[rows]))
            writer.flush()
    return Recording.open(base / "framed"), schedule


class Seen:
    """What the tasks were handed: per axis its windows and, per pass, its rows."""

    def __init__(self, passes: int = 1, between: bool = False) -> None:
        self.passes = passes
        self.between = between
        self.found: dict[str, AxisWindows] = {}
        self.rows: dict[str, list[list[NamedChunk]]] = {}

    def watch(self, found: AxisWindows) -> Watch:
        self.found[found.axis] = found
        channels = (f"{found.axis}_velocity_mm_min",)
        stretch = (found.windows[0][0], found.windows[-1][1]) if self.between else None
        return Watch(channels, self._task(found.axis), stretch)

    def _task(self, axis: str) -> Task[NamedChunk, None]:
        self.rows[axis] = []
        for _ in range(self.passes):
            kept: list[NamedChunk] = []
            self.rows[axis].append(kept)
            yield kept.append


def _counting(
    monkeypatch: pytest.MonkeyPatch, hold: bool = False
) -> list[tuple[tuple[str, ...] | None, list[int]]]:
    """Every reading of the analysis: its channels and the first row of each chunk.

    The file is read pass by pass, as a recording longer than ``HOLD_BYTES`` is, or
    (``hold``) once, its chunks held for the passes that follow, as one that fits."""
    monkeypatch.setattr(reading_module, "HOLD_BYTES", 1 << 40 if hold else 0)
    # One axis' slices per reading, as with on_windows (whose tasks ride those readings).
    monkeypatch.setattr(reading_module, "GATHER_AHEAD_BYTES", 0)
    readings: list[tuple[tuple[str, ...] | None, list[int]]] = []
    original = reading_module.iter_chunks

    def counted(*args: object, **kwargs: object) -> Iterator[RowChunk]:
        firsts: list[int] = []
        channels = kwargs.get("channels", args[2] if len(args) > 2 else None)
        readings.append((channels, firsts))  # type: ignore[arg-type]
        for chunk in original(*args, **kwargs):  # type: ignore[arg-type]
            firsts.append(chunk.first)
            yield chunk

    monkeypatch.setattr(reading_module, "iter_chunks", counted)
    return readings


@pytest.mark.parametrize("hold", [False, True])
@pytest.mark.parametrize("passes", [1, 2])
def test_tasks_get_every_row_of_each_pass_on_the_readings_of_the_analysis(
    measured: tuple[Recording, Schedule], monkeypatch: pytest.MonkeyPatch, passes: int, hold: bool
) -> None:
    recording, schedule = measured
    head = RecordingHead.open(recording.directory)
    alone = _counting(monkeypatch, hold)
    analyze(head, schedule=schedule, rows=1000)
    readings = len(alone)
    alone.clear()
    seen = Seen(passes)
    windows: dict[str, list[tuple[float, float]]] = {}
    results = analyze(head, schedule=schedule, rows=1000, window_times=windows,
                      on_windows=seen.watch)  # fmt: skip
    assert list(seen.found) == list(results.axes) == ["X", "Z"]
    for axis, found in seen.found.items():
        assert found.windows == tuple(windows[axis])
        assert (found.rows, found.start_s, found.end_s) == (
            len(recording),
            recording.time_s[0],
            recording.time_s[-1],
        )
        assert len(seen.rows[axis]) == passes
        for chunks in seen.rows[axis]:  # every row, in order, its channel by name
            assert np.array_equal(np.concatenate([c.time_s for c in chunks]), recording.time_s)
            velocity = np.concatenate([c.channel(f"{axis}_velocity_mm_min") for c in chunks])
            assert np.array_equal(velocity, recording.column(f"{axis}_velocity_mm_min"))
    # X's first pass rides along Z's readings; the rest reads once more per pass, only the
    # channels of the tasks still waiting (the last reading Z's alone)
    extra = alone[readings:]
    if hold:  # the file read once, every pass of the tasks over the chunks held
        assert readings == 1 and not extra
        return
    assert len(extra) == passes
    assert extra[-1][0] == ("Z_velocity_mm_min",)
    assert all(set(c or ()) <= {"X_velocity_mm_min", "Z_velocity_mm_min"} for c, _ in extra)


def test_a_task_for_a_stretch_of_time_is_read_only_the_frames_around_it(
    measured: tuple[Recording, Schedule], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The last reading, for tasks that say which stretch they look at, begins with the frame
    before the stretch and ends after it: every row of the stretch, few others."""
    recording, schedule = measured
    head = RecordingHead.open(recording.directory)
    readings = _counting(monkeypatch)
    seen = Seen(between=True)
    analyze(head, schedule=schedule, rows=1000, on_windows=seen.watch)
    firsts = readings[-1][1]
    start, end = seen.found["Z"].windows[0][0], seen.found["Z"].windows[-1][1]
    time_s = recording.time_s
    inside = np.flatnonzero((time_s >= start) & (time_s <= end))
    assert 0 < firsts[0] <= inside[0] and firsts[0] > inside[0] - 1400
    assert firsts[-1] <= inside[-1] < firsts[-1] + 1000 + 400
    times = np.concatenate([c.time_s for c in seen.rows["Z"][0]])
    assert np.isin(time_s[inside], times).all()
    assert len(times) < 0.8 * len(time_s)


def test_a_recording_in_memory_is_handed_over_whole(
    measured: tuple[Recording, Schedule],
) -> None:
    recording, schedule = measured
    seen = Seen()
    windows: dict[str, list[tuple[float, float]]] = {}
    analyze(recording, schedule=schedule, window_times=windows, on_windows=seen.watch)
    for axis in ("X", "Z"):
        assert seen.found[axis].windows == tuple(windows[axis])
        (chunk,) = seen.rows[axis][0]
        assert chunk.first == 0 and np.array_equal(chunk.time_s, recording.time_s)
        assert np.array_equal(
            chunk.channel(f"{axis}_velocity_mm_min"), recording.column(f"{axis}_velocity_mm_min")
        )


def test_a_reading_left_off_midway_starts_its_tasks_afresh() -> None:
    made: list[list[float]] = []

    def make() -> Watch:
        kept: list[float] = []
        made.append(kept)

        def task() -> Task[NamedChunk, None]:
            yield lambda chunk: kept.extend(chunk.time_s.tolist())

        return Watch(("a",), task())

    def chunks() -> Iterator[RowChunk]:
        for first in range(0, 10, 4):
            time_s = np.arange(first, min(first + 4, 10), dtype=np.float64)
            yield RowChunk(first, time_s, time_s[:, None])

    watchers = Watchers({"a": 0})
    watchers.add(make)
    for chunk in watchers.reading(chunks()):
        if chunk.first == 4:
            break  # a reading left off: what the task was fed is dropped, it starts again
    assert len(made) == 2 and watchers.waiting
    assert list(watchers.reading(chunks()))
    assert made[1] == list(range(10)) and not watchers.waiting
    watchers.finish(_never)  # nothing left to read


def test_tasks_on_channels_the_analysis_does_not_read_wait_for_the_last_reading() -> None:
    fed: list[str] = []

    def task(name: str) -> Callable[[], Watch]:
        def passes() -> Task[NamedChunk, None]:
            yield lambda chunk: fed.append(f"{name}:{chunk.channel(name)[0]:g}")

        return lambda: Watch((name,), passes())

    watchers = Watchers({"a": 0})
    watchers.add(task("a"))
    watchers.add(task("b"))
    list(watchers.reading([RowChunk(0, np.zeros(1), np.ones((1, 1)))]))
    assert fed == ["a:1"]

    def read(channels: tuple[str, ...], between: tuple[float, float] | None) -> list[RowChunk]:
        assert channels == ("b",) and between is None
        return [RowChunk(0, np.zeros(1), np.full((1, 1), 2.0))]

    watchers.finish(read)
    assert fed == ["a:1", "b:2"]


def _never(channels: tuple[str, ...], between: tuple[float, float] | None) -> list[RowChunk]:
    raise AssertionError("read although no task waits")
