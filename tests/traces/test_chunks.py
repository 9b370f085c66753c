"""Streaming imports: chunk boundaries change nothing, a late bad row names its place.

Every importer reads its file in chunks (rows, bytes, merge batches); here the
chunks are made a few rows or bytes long, so rows, XML elements and merge
batches are split everywhere, and the recording must come out bit for bit as
with the default chunks.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.errors import RecordingError
from ncmeasure.recording import Recording
from ncmeasure.recording import sink as sink_module
from ncmeasure.recording.sink import StepMedian
from ncmeasure.traces import import_trace, sinumerik_xml
from ncmeasure.traces import merge as merging
from ncmeasure.traces import text as trace_text
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.merge import Series, SeriesMerge, merge_series

FIXTURES = Path(__file__).parent / "fixtures"
TRACES = [
    "twincat_per_channel.csv",
    "twincat_shared.csv",
    "tncscope.sco",
    "sinumerik_comma.csv",
    "sinumerik_semicolon.csv",
    "sinumerik_spaces.csv",
    "sinumerik_trace.xml",
    "sinumerik_840d_moving.xml",
    "sinumerik_840d_holding.xml",
    "recording_export.csv",
]


def _tiny_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(merging, "CHUNK_ROWS", 2)
    monkeypatch.setattr(merging, "MERGE_ROWS", 2)
    monkeypatch.setattr(merging, "SPILL_ROWS", 1)
    monkeypatch.setattr(trace_text, "_READ_BYTES", 7)
    monkeypatch.setattr(sinumerik_xml, "_READ_BYTES", 5)


def _summary(rec: Recording) -> dict[str, Any]:
    meta = rec.meta.model_dump()
    for key in ("start_utc", "end_utc", "ncmeasure_version"):
        meta.pop(key, None)
    return {"samples": rec.time_s.tobytes() + rec.values.tobytes(), "meta": meta}


@pytest.mark.parametrize("name", TRACES)
def test_tiny_chunks_give_the_same_recording(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    axis_names = {"1": "X", "2": "Y"} if name.startswith("sinumerik") else None
    normal = import_trace(FIXTURES / name, tmp_path / "normal", axis_names=axis_names)
    _tiny_chunks(monkeypatch)
    tiny = import_trace(FIXTURES / name, tmp_path / "tiny", axis_names=axis_names)
    assert tiny.report == normal.report
    assert _summary(tiny.recording) == _summary(normal.recording)
    assert tiny.meta.samples == len(normal.recording) > 0


def _multirate_twincat(rows: int, bad_row: int | None = None, position_rows: int = 0) -> str:
    """X_current_a at 1 ms, X.ActPos at 2 ms ending after half the rows, tab, decimal comma."""
    lines = [
        "Name\tmany",
        "",
        "Name\tX_current_a\tName\tX.ActPos",
        "SampleTime[ms]\t1\tSampleTime[ms]\t2",
        "Unit\tA (Ampere)\tUnit\tmm (Millimeter)",
        "",
    ]
    for k in range(rows):
        ended = k >= (position_rows or rows // 2)
        position = " \t " if ended else f"{2 * k}\t{k / 8:.3f}".replace(".", ",")
        current = f"{(k % 7) / 4:.2f}".replace(".", ",")
        lines.append(f"{k}\t{current}\t{position}")
    if bad_row is not None:
        lines[6 + bad_row] = lines[6 + bad_row].replace("\t", "\tx", 1)
    return "\n".join(lines) + "\n"


def test_a_channel_far_ahead_waits_on_disk_and_merges_exactly(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "multirate.csv"
    path.write_text(_multirate_twincat(501), encoding="utf-8")
    normal = import_trace(path, tmp_path / "normal")
    monkeypatch.setattr(merging, "CHUNK_ROWS", 3)
    monkeypatch.setattr(merging, "MERGE_ROWS", 4)
    monkeypatch.setattr(merging, "SPILL_ROWS", 5)
    tiny = import_trace(path, tmp_path / "tiny")
    assert tiny.report == normal.report
    assert _summary(tiny.recording) == _summary(normal.recording)
    rec = normal.recording
    # union of 0..500 ms and 0..498 ms, cut at the position's end (498 ms)
    np.testing.assert_array_equal(rec.time_s, np.arange(499) / 1000)
    k = np.arange(499)
    np.testing.assert_array_equal(rec.column("X_position_mm"), np.round((k // 2) / 8, 3))
    assert "2 trailing row(s) dropped: a channel ends at t = 0.498 s" in normal.report


class _ListSink:
    """Collects what a merge writes."""

    def __init__(self) -> None:
        self.written: list[tuple[np.ndarray, np.ndarray]] = []

    def append(self, time_s: np.ndarray, values: np.ndarray) -> None:
        self.written.append((time_s.copy(), values.copy()))


def test_a_channel_still_waiting_on_disk_at_the_end_is_read_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "ahead.csv"
    path.write_text(_multirate_twincat(300, position_rows=300), encoding="utf-8")
    normal = import_trace(path, tmp_path / "normal")
    monkeypatch.setattr(merging, "CHUNK_ROWS", 50)
    monkeypatch.setattr(merging, "MERGE_ROWS", 4)
    monkeypatch.setattr(merging, "SPILL_ROWS", 5)
    tiny = import_trace(path, tmp_path / "tiny")
    assert tiny.report == normal.report
    assert _summary(tiny.recording) == _summary(normal.recording)
    assert "150 trailing row(s) dropped: a channel ends at t = 0.299 s" in normal.report


def test_series_merge_equals_merge_series_on_random_timelines(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    source = tmp_path / "t.csv"
    source.write_text("x")
    for _ in range(40):
        series = []
        for c in range(int(rng.integers(1, 4))):
            n = int(rng.integers(1, 60))
            times = np.cumsum(rng.choice([0.001, 0.002, 0.003], n)) + rng.choice([0, 0.001, 0.004])
            raw = rng.normal(size=n)
            raw[rng.random(n) < 0.1] = 9.3e18  # invalid marker
            series.append(Series(f"X{c}_current_a", np.round(times, 6), raw, 0.5))
        whole = ImportJob(
            source, tmp_path / "a", "csv", machine=None, axis_names=None, progress=None
        )
        expected_t, expected_v = merge_series(series, whole)
        sink = _ListSink()

        job = ImportJob(source, tmp_path / "b", "csv", machine=None, axis_names=None, progress=None)
        merge = SeriesMerge(
            sink,  # type: ignore[arg-type]
            [s.name for s in series],
            [s.factor for s in series],
            batch_rows=int(rng.integers(1, 5)),
            spill_rows=int(rng.integers(1, 5)),
        )
        portions = [np.array_split(np.arange(len(s.time_s)), 5) for s in series]
        for step in range(5):  # the channels' portions interleaved, as rows of a file
            for column, s in enumerate(series):
                part = portions[column][step]
                merge.add(column, s.time_s[part], s.values[part])
            merge.flush()
        merge.finish(job)
        got_t = np.concatenate([t for t, _ in sink.written]) if sink.written else np.empty(0)
        got_v = (
            np.concatenate([v for _, v in sink.written])
            if sink.written
            else np.empty((0, len(series)))
        )
        assert got_t.tobytes() == expected_t.tobytes()
        assert got_v.tobytes() == expected_v.tobytes()
        assert job.report == whole.report


def test_carry_forward_in_blocks_equals_record_by_record(tmp_path: Path) -> None:
    """Sparse records (channels missing at the start, in runs, in whole blocks), invalid
    markers and factors: blocks of any size give the rows and counts of one record at a time."""
    rng = np.random.default_rng(29)
    for _ in range(60):
        count, width = int(rng.integers(1, 80)), int(rng.integers(1, 5))
        times = np.cumsum(rng.choice([0.001, 0.002], count))
        raw = rng.normal(size=(count, width))
        raw[rng.random((count, width)) < rng.random(width) * 0.9] = np.nan  # no new sample
        raw[: int(rng.integers(0, count + 1)), int(rng.integers(0, width))] = np.nan
        raw[rng.random((count, width)) < 0.05] = 9.3e18  # the invalid marker
        factors = rng.choice([1.0, 0.5, 60.0], width).tolist()
        names = [f"X{c}_current_a" for c in range(width)]
        one, blocks = _ListSink(), _ListSink()
        by_record = merging.CarryForward(one, names, factors, chunk_rows=7)  # type: ignore[arg-type]
        by_block = merging.CarryForward(blocks, names, factors, chunk_rows=7)  # type: ignore[arg-type]
        for row in range(count):
            for column in np.flatnonzero(~np.isnan(raw[row])).tolist():
                by_record.set(column, float(raw[row, column]), lambda row=row: f"line {row}")
            by_record.commit(float(times[row]), lambda: "")
        cuts = np.sort(rng.integers(0, count + 1, int(rng.integers(0, 6))))
        for part in np.split(np.arange(count), cuts):
            first = int(part[0]) if len(part) else 0
            by_block.commit_block(
                times[part], raw[part], lambda index, first=first: f"line {first + index}"
            )
        by_record.flush()
        by_block.flush()
        for carry in ("records", "dropped_leading", "first_complete_s", "invalid"):
            assert getattr(by_block, carry) == getattr(by_record, carry), carry
        assert by_block.first_invalid == by_record.first_invalid
        assert by_block.missing() == by_record.missing()
        for (t_a, v_a), (t_b, v_b) in zip(blocks.written, one.written, strict=True):
            assert t_a.tobytes() == t_b.tobytes()
            assert v_a.tobytes() == v_b.tobytes()


@pytest.mark.parametrize("distinct", [4096, 8])
def test_step_median_is_numpy_median_bit_for_bit(
    distinct: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Counted in memory (few distinct steps) or selected from the file (more: from the
    first block on, or from a later one), the median is numpy's."""
    monkeypatch.setattr(sink_module, "_DISTINCT_STEPS", distinct)
    rng = np.random.default_rng(3)
    in_file = 0
    for n in (2, 3, 4, 11, 1000):
        for times in (
            np.cumsum(rng.random(n) * 1e-3),
            np.arange(n) / 1000,
            np.cumsum(rng.choice([0.001, 0.002, 1e-9, 5.0], n)),
            np.concatenate([np.arange(n) * 0.5, n * 0.5 + np.cumsum(rng.random(n))]),
        ):
            steps = StepMedian()
            for number, part in enumerate(np.array_split(times, 4)):
                steps.add(part)
                if number == 0 and len(times) == 2000:  # one step so far: counted
                    assert steps._counts is not None
            in_file += steps._counts is None
            assert steps.median() == float(np.median(np.diff(times)))
            steps.close()
    assert (in_file == 0) == (distinct == 4096)


def _sinumerik_xml(records: int, bad: int) -> str:
    head = (
        '<?xml version="1.0"?>\n<traceSession version="2.0">\n'
        '<traceCaptureSetup><sessionSettings sessionName="S"/></traceCaptureSetup>\n'
        '<traceData dataFrames="1"><dataFrame>\n<frameHeader startTime="x"/>\n'
        '<dataSignal id="f1" name="/Nck/!SD/nckServoDataActCurr64 [u1, 1]" interval="0.001"/>\n'
    )
    recs = []
    for i in range(records):
        value = "1,5" if i == bad else f"{i / 4}"
        recs.append(f'<rec time="{i / 1000}" f1="{value}"/>\n<other n="{i}"><x/></other>\n')
    return head + "".join(recs) + "</dataFrame></traceData></traceSession>\n"


def _sinumerik_csv(rows: int, bad: int) -> str:
    lines = ["time,/Nck/!SD/nckServoDataActCurr64 [u1; 1]"]
    lines += [f"{k / 1000},{'1;5' if k == bad else k / 4}" for k in range(rows)]
    return "\n".join(lines) + "\n"


def _tncscope(rows: int, bad: int) -> str:
    lines = ["%[CURVE 1]", "%CHANNELTYPE=i ist", "%AXISTYPE=X", "%DIMENSION=A"]
    lines += [f"%COUNT={rows}", "%CYCLETIME=3000", "%", "%[DATA]"]
    lines += [f"{3000 * k};{'x' if k == bad else k / 4};" for k in range(rows)]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("late.csv", _multirate_twincat(60, bad_row=41), ":48: channel X_current_a: not a number"),
        ("late.sco", _tncscope(60, bad=41), ":50: curve 1 (i ist X): 'x' is not a number"),
        ("late_sinumerik.csv", _sinumerik_csv(60, bad=41), ":43: "),
        (
            "late.xml",
            _sinumerik_xml(60, bad=41),
            ": <rec> #42, time=0.041: f1='1,5' is not a number",
        ),
    ],
)
def test_a_bad_row_after_several_chunks_names_its_place_and_leaves_nothing(
    name: str, text: str, message: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    _tiny_chunks(monkeypatch)
    target = tmp_path / "rec"
    with pytest.raises(RecordingError) as caught:
        import_trace(
            path,
            target,
            axis_names={"1": "X"} if "sinumerik" in name or name.endswith(".xml") else None,
        )
    assert f"{path}{message}" in str(caught.value)
    assert not target.exists()
    result = CliRunner().invoke(app, ["import", str(path), "-o", str(target), "-q"])
    assert result.exit_code != 0
    assert message.split(": ", 1)[-1] in result.output
    assert "Traceback" not in result.output
    assert not target.exists()
