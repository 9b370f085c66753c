"""The hole counter of a recording read in passes: a step against the regular period around it."""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Generator
from dataclasses import replace
from pathlib import Path
from typing import cast

import numpy as np
import pytest

from ncmeasure.analysis import reading
from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.reading import recording_gaps
from ncmeasure.analysis.windows.chunked import ChunkedFinder
from ncmeasure.analysis.windows.find import recording_chunks
from ncmeasure.analysis.windows.scan import Rows, axes_statistics
from ncmeasure.analysis.windows.settings import SegmentSettings
from ncmeasure.analysis.windows.signals import HoleCounter
from ncmeasure.analysis.windows.streaming import run_task
from ncmeasure.analysis.windows.sweep import Sparse
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RecordingHead, RecordingWriter
from ncmeasure.recording.reader import READ_COUNT
from ncmeasure.samples import Channel, SampleBlock
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording
from ncmeasure.traces import import_traces
from tests.analysis.test_oracle import _damaged
from tests.traces.test_files import write_epos, write_map


def two_periods(tmp_path: Path) -> Path:
    """An import of EPOS exports a minute apart: two at 10 ms per sample, then one at 40 ms.

    The recording's sample period is the median step, 10 ms.
    """
    folder = tmp_path / "captures"
    folder.mkdir()
    start = dt.datetime(2024, 3, 5, 14, 0, 0)
    for k, (speed, period_ms) in enumerate(((100, 10.0), (-100, 10.0), (100, 40.0))):
        when = start + dt.timedelta(minutes=k)
        write_epos(folder / f"c{k}.txt", speed, start=when, period_ms=period_ms, seed=k)
    import_traces([folder], tmp_path / "rec", columns=write_map(tmp_path / "epos.toml"))
    return tmp_path / "rec"


def test_a_file_sampled_more_slowly_loses_no_samples(tmp_path: Path) -> None:
    rec = Recording.open(two_periods(tmp_path))
    assert len(rec) == 1500
    assert rec.meta.nominal_period_s == pytest.approx(0.01)
    # The plain 1.5-period rule took every step of the 40 ms file for a hole of 3 lost samples:
    # 499 holes, 1497 samples lost.
    assert recording_gaps(rec) == (0, 0, 0)
    # The analysis reads it in passes, chunk by chunk: the same count.
    results = analyze(tmp_path / "rec")
    assert (results.recording.gaps, results.recording.gap_samples) == (0, 0)
    assert not any("lost" in w for w in results.axes["X"].warnings)


def test_a_hole_in_the_slower_file_counts_its_own_samples(tmp_path: Path) -> None:
    rec = Recording.open(two_periods(tmp_path))
    slow = np.flatnonzero(rec.time_s >= 120.0)
    keep = np.ones(len(rec), dtype=bool)
    keep[slow[100:104]] = False  # 4 samples of 40 ms lost: one hole of 200 ms
    cut = replace(rec, time_s=rec.time_s[keep], values=rec.values[keep])
    assert recording_gaps(cut) == (1, 4, 0)


def outage_times(*times_s: float, period_s: float = 0.004, end_s: float = 3.0) -> np.ndarray:
    """Times at ``period_s`` up to ``times_s[0]``, then ``times_s``, then on at the period."""
    before = np.arange(0.0, times_s[0] - period_s / 2, period_s)
    after = times_s[-1] + period_s * np.arange(1, round((end_s - times_s[-1]) / period_s) + 1)
    return np.concatenate((before, times_s, after))


def outage(directory: Path, *times_s: float) -> Recording:
    """A recording of one channel at 4 ms per sample with ``times_s`` in it (outage_times)."""
    time_s = outage_times(*times_s)
    channels = [Channel("X", "velocity_mm_min", "mm/min")]
    with RecordingWriter.create(directory, channels, nominal_period_s=0.004) as writer:
        writer.append(SampleBlock(time_s, np.zeros((len(time_s), 1))))
    return Recording.open(directory)


@pytest.mark.parametrize(
    ("times_s", "found"),
    [
        # an outage broken by one sample: two holes, about 99 samples lost in all (the
        # step before a step took the second for none, or divided it by the first)
        ((0.996, 1.2, 1.4), (2, 50 + 49)),
        ((0.996, 1.1, 1.4), (2, 25 + 74)),
        # broken by two samples, and by two next to each other
        ((0.996, 1.2, 1.4, 1.6), (3, 50 + 49 + 49)),
        ((0.996, 1.2, 1.204, 1.4), (2, 50 + 48)),
        # one hole
        ((0.996, 1.2), (1, 50)),
    ],
)
def test_an_outage_broken_by_a_few_samples_counts_every_sample_lost(
    tmp_path: Path, times_s: tuple[float, ...], found: tuple[int, int]
) -> None:
    rec = outage(tmp_path / "rec", *times_s)
    assert recording_gaps(rec)[:2] == found


@pytest.mark.parametrize("rows", [1, 2, 3, 7, 100])
def test_the_holes_counted_chunk_by_chunk_are_those_of_the_whole(rows: int) -> None:
    time_s = outage_times(0.996, 1.2, 1.4, 1.6, end_s=1.64)
    time_s = np.concatenate((time_s, 1.64 + 0.04 * np.arange(1, 20)))  # slower at the end
    counter = HoleCounter(0.004, np.empty(0))
    for first in range(0, len(time_s), rows):
        counter.feed(time_s[first : first + rows])
    whole = HoleCounter(0.004, np.empty(0))
    whole.feed(time_s)
    assert counter.finish() == whole.finish() == (3, 50 + 49 + 49)


@pytest.mark.parametrize("rows", [64, 1 << 16])
def test_an_outage_read_in_passes_counts_as_in_memory(tmp_path: Path, rows: int) -> None:
    # In the first 10 ms file: 0.2 s lost, one sample, 0.2 s lost; a 40 ms file follows.
    rec = Recording.open(two_periods(tmp_path))
    keep = np.ones(len(rec), dtype=bool)
    keep[200:219] = keep[220:239] = False
    cut = replace(rec, time_s=rec.time_s[keep], values=rec.values[keep])
    assert recording_gaps(cut) == (2, 38, 0)
    channels = [c.to_channel() for c in rec.meta.channels]
    period = rec.meta.nominal_period_s
    with RecordingWriter.create(tmp_path / "cut", channels, nominal_period_s=period) as writer:
        writer.append(SampleBlock(cut.time_s, cut.values))
        for event in rec.events:
            writer.add_event(event)
    results = analyze(tmp_path / "cut", rows=rows)
    assert (results.recording.gaps, results.recording.gap_samples) == (2, 38)


def _results(head: RecordingHead, schedule: Schedule | None) -> dict[str, object]:
    """results.json of the analysis of ``head`` in chunks of 1000 rows, without its time."""
    data = json.loads(analyze(head, schedule=schedule, rows=1000).model_dump_json())
    data.pop("created_utc")
    return data


def _results_and_readings(
    directory: Path, schedule: Schedule | None
) -> tuple[dict[str, object], int]:
    """:func:`_results` of the recording in ``directory``, and the readings it took."""
    readings = READ_COUNT.readings
    found = _results(RecordingHead.open(directory), schedule)
    return found, READ_COUNT.readings - readings


@pytest.mark.parametrize("damaged", [False, True], ids=["whole", "damaged"])
def test_a_recording_that_fits_is_read_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damaged: bool
) -> None:
    velocities = geometric_velocities(10.0, 15000.0, 6)
    axes = [
        SyntheticAxis(name="X", velocities_mm_min=velocities),
        SyntheticAxis(name="Y", velocities_mm_min=velocities, velocity_quantum_mm_min=8.5),
    ]
    recording, schedule = synthetic_recording(tmp_path / "rec", axes)
    directory = (
        _damaged(recording, tmp_path / "damaged").directory if damaged else recording.directory
    )
    rows, readings = READ_COUNT.rows, READ_COUNT.readings
    head = RecordingHead.open(directory)
    once = _results(head, schedule)
    assert READ_COUNT.readings - readings == 1
    assert READ_COUNT.rows - rows == head.rows
    assert (head.problems != []) == damaged
    # Beyond the budget, every pass reads the file again: the same results.
    monkeypatch.setattr(reading, "HOLD_BYTES", 0)
    rows, readings = READ_COUNT.rows, READ_COUNT.readings
    again = _results(RecordingHead.open(directory), schedule)
    assert READ_COUNT.readings - readings > 5
    assert READ_COUNT.rows - rows > 5 * (head.rows or 0)
    assert again == once


@pytest.mark.parametrize("marker", [True, False], ids=["marker", "command"])
def test_a_recording_read_per_pass_gathers_every_axis_slices_on_one_reading(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, marker: bool
) -> None:
    velocities = geometric_velocities(10.0, 15000.0, 6)
    axes = [
        SyntheticAxis(name="X", velocities_mm_min=velocities),
        SyntheticAxis(name="Y", velocities_mm_min=velocities),
        SyntheticAxis(name="Z", velocities_mm_min=velocities),
    ]
    recording, schedule = synthetic_recording(tmp_path / "rec", axes, with_marker=marker)
    monkeypatch.setattr(reading, "HOLD_BYTES", 0)  # read per pass, as a long recording

    ahead, shared = _results_and_readings(recording.directory, schedule)
    monkeypatch.setattr(reading, "GATHER_AHEAD_BYTES", 0)  # one axis' slices at a time
    alone, each = _results_and_readings(recording.directory, schedule)
    assert ahead == alone
    assert shared == each - 2  # one reading for three axes' slices, not three


def _no_early_sweep(*args: object, **kwargs: object) -> Generator[None, None, None]:
    """An early sweep that gives up at once: each finder sweeps on a reading of its own."""
    return
    yield


@pytest.mark.parametrize("marker", [True, False], ids=["marker", "command"])
def test_the_sweep_rides_the_statistics_readings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, marker: bool
) -> None:
    velocities = geometric_velocities(10.0, 15000.0, 6)
    axes = [
        SyntheticAxis(name="X", velocities_mm_min=velocities),
        SyntheticAxis(name="Y", velocities_mm_min=velocities, velocity_quantum_mm_min=8.5),
    ]
    recording, schedule = synthetic_recording(tmp_path / "rec", axes, with_marker=marker)
    monkeypatch.setattr(reading, "HOLD_BYTES", 0)  # read per pass, as a long recording

    riding, fewer = _results_and_readings(recording.directory, schedule)
    monkeypatch.setattr(reading, "early_sweep_task", _no_early_sweep)
    alone, more = _results_and_readings(recording.directory, schedule)
    assert riding == alone
    assert fewer == more - 1  # the marker runs, command stretches and holes: no reading


@pytest.mark.parametrize("marker", [True, False], ids=["marker", "command"])
def test_slice_bytes_is_about_the_slices_kept(tmp_path: Path, marker: bool) -> None:
    velocities = geometric_velocities(10.0, 15000.0, 6)
    axes = [SyntheticAxis(name="X", velocities_mm_min=velocities)]
    recording, schedule = synthetic_recording(tmp_path / "rec", axes, with_marker=marker)
    column = {name: k for k, name in enumerate(recording.channel_names)}
    source = Rows(recording_chunks(recording), column, max(len(recording), 1))
    statistics = axes_statistics(source, ("X",))["X"]
    finder = ChunkedFinder("X", statistics, source, schedule, SegmentSettings())
    run_task(source.read, finder.sweep_task())
    stretches = finder.first_stretches()
    assert stretches
    finder.gather_ahead(stretches)(next(source.read()))
    finder._gather(stretches)
    kept = {id(a): a for a in (finder.t, finder.v, finder.x, finder.v_detect, finder.command)}
    kept[id(finder.current)] = finder.current
    held = sum(8 * cast("Sparse", a).samples for a in kept.values() if a is not None)
    estimate = finder.slice_bytes(stretches)
    assert held <= estimate <= 1.05 * held
