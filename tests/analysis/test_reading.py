"""The hole counter of a recording read in passes: the window finder's rule of a hole."""

from __future__ import annotations

import datetime as dt
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.reading import recording_gaps
from ncmeasure.recording import Recording
from ncmeasure.traces import import_traces
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
