"""The raw-data figure: read chunk by chunk (the same stretch, a bounded overview), as SVG."""

from __future__ import annotations

import dataclasses
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import ncmeasure.report.traces as traces_module
from ncmeasure.analysis.analyze import analyze
from ncmeasure.recording import RecordingHead
from ncmeasure.report import write_report
from ncmeasure.report.raw_svg import OVERVIEW_BINS, WINDOW_FILL, RawTrace, raw_trace, trace_svg
from ncmeasure.report.traces import RawTraces, read_raw_traces
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording

AXES = [
    SyntheticAxis(name="X", velocities_mm_min=geometric_velocities(10.0, 15000.0, 6)),
    SyntheticAxis(name="Z", velocities_mm_min=geometric_velocities(10.0, 6000.0, 4)),
]


@pytest.mark.parametrize("given", [True, False], ids=["windows", "no-windows"])
def test_traces_read_chunk_by_chunk_show_what_the_whole_recording_shows(
    tmp_path: Path, given: bool
) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", AXES)
    windows: dict[str, list[tuple[float, float]]] = {}
    analyze(recording, schedule=schedule, window_times=windows)
    shaded = windows if given else {}
    head = RecordingHead.open(recording.directory)
    traces = read_raw_traces(head, ["X", "Z"], shaded, stretch_s=20.0, rows=777)
    for axis in ("X", "Z"):
        chunked = traces[axis]
        whole = raw_trace(recording, axis, shaded.get(axis, ()), stretch_s=20.0)
        assert isinstance(chunked, RawTrace)
        assert chunked.windows == whole.windows
        assert chunked.span == whole.span
        assert chunked.stretch == whole.stretch
        assert chunked.rows == whole.rows == len(recording)
        for key in ("time_s", "current", "velocity", "command"):
            assert np.array_equal(getattr(chunked, key), getattr(whole, key)), key
        # The overview: at most two points per bin, every extreme of the span kept.
        assert len(chunked.overview_time_s) <= 2 * OVERVIEW_BINS
        assert np.all(np.diff(chunked.overview_time_s) >= 0)
        inside = (recording.time_s >= whole.span[0]) & (recording.time_s <= whole.span[1])
        velocity = recording.column(f"{axis}_velocity_mm_min")[inside]
        assert chunked.overview_velocity.max() == velocity.max()
        assert chunked.overview_velocity.min() == velocity.min()
        ET.fromstring(trace_svg(chunked))  # it draws


def test_a_missing_channel_is_said(tmp_path: Path) -> None:
    recording, _ = synthetic_recording(tmp_path / "rec", AXES[:1])
    traces = read_raw_traces(RecordingHead.open(recording.directory), ["X", "Q"], {})
    assert isinstance(traces["X"], RawTrace)
    assert "no channel 'Q_current_a'" in str(traces["Q"])


def test_the_report_of_a_recording_read_chunk_by_chunk(tmp_path: Path) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", AXES)
    head = RecordingHead.open(recording.directory)
    windows: dict[str, list[tuple[float, float]]] = {}
    results = analyze(head, schedule=schedule, window_times=windows)
    page = write_report(results, tmp_path / "r.html", recording=head, windows=windows)
    text = page.read_text()
    assert (tmp_path / "r_plots" / "01_X_raw.svg").is_file()
    assert (tmp_path / "r_plots" / "02_Z_raw.svg").is_file()
    assert "found again" not in text and "not given" not in text
    unshaded = write_report(results, tmp_path / "u.html", recording=head).read_text()
    assert unshaded.count("the analysis&#39; windows were not given") == 2


def _same(a: RawTrace, b: RawTrace) -> bool:
    return all(
        np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
        for x, y in ((getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(RawTrace))
    )


@pytest.mark.parametrize("rows", [777, 1 << 16])
@pytest.mark.parametrize("whole", [False, True], ids=["chunks", "in-memory"])
def test_traces_gathered_by_the_analysis_are_those_read_on_their_own(
    tmp_path: Path, rows: int, whole: bool
) -> None:
    """On the analysis' readings (the last axis' on one more, of its span) or from a recording
    in memory: the same traces, to the bit, as reading them after the analysis."""
    recording, schedule = synthetic_recording(tmp_path / "rec", AXES)
    head = RecordingHead.open(recording.directory)
    gathered = RawTraces(head, stretch_s=20.0)
    windows: dict[str, list[tuple[float, float]]] = {}
    analyze(recording if whole else head, schedule=schedule, window_times=windows, rows=rows,
            on_windows=gathered.watch)  # fmt: skip
    read = read_raw_traces(head, ["X", "Z"], windows, stretch_s=20.0, rows=rows)
    assert list(gathered.found) == ["X", "Z"]
    for axis in ("X", "Z"):
        alone = read[axis]
        assert isinstance(alone, RawTrace)
        assert _same(gathered.found[axis], alone), axis
        assert len(alone.time_s) and len(alone.overview_time_s)


def test_a_report_with_gathered_traces_reads_no_rows_and_draws_the_same(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", AXES)
    head = RecordingHead.open(recording.directory)
    gathered = RawTraces(head)
    windows: dict[str, list[tuple[float, float]]] = {}
    results = analyze(head, schedule=schedule, window_times=windows, on_windows=gathered.watch)
    read = write_report(results, tmp_path / "read.html", recording=head, windows=windows)

    def unread(*args: object, **kwargs: object) -> None:
        raise AssertionError("the recording was read again")

    monkeypatch.setattr(traces_module, "iter_chunks", unread)
    given = write_report(results, tmp_path / "given.html", recording=head, windows=windows,
                         traces=gathered.found)  # fmt: skip
    for name in ("01_X_raw.svg", "02_Z_raw.svg"):
        assert (tmp_path / "given_plots" / name).read_bytes() == (
            tmp_path / "read_plots" / name
        ).read_bytes()
    assert given.read_text().replace("given_plots", "read_plots") == read.read_text()


SVG = "{http://www.w3.org/2000/svg}"


def _polyline_y(line: ET.Element) -> list[float]:
    return [float(point.split(",")[1]) for point in (line.get("points") or "").split()]


def test_the_figure_shades_the_windows_and_keeps_every_peak(tmp_path: Path) -> None:
    recording, schedule = synthetic_recording(tmp_path / "rec", AXES[:1])
    windows: dict[str, list[tuple[float, float]]] = {}
    analyze(recording, schedule=schedule, window_times=windows)
    trace = raw_trace(recording, "X", windows["X"], stretch_s=20.0)
    text = trace_svg(trace)
    svg = ET.fromstring(text)
    assert ' id="' not in text
    shades = [p for p in svg.iter(f"{SVG}path") if p.get("fill") == WINDOW_FILL]
    assert len(shades) == 3  # the overview, the current, the velocity
    overview_bands = len(re.findall("z", shades[0].get("d", "")))
    assert overview_bands == sum(
        1 for a, b in trace.windows if b >= trace.span[0] and a <= trace.span[1]
    )
    stretch_bands = len(re.findall("z", shades[1].get("d", "")))
    start, end = trace.stretch
    assert stretch_bands == sum(1 for a, b in trace.windows if b >= start and a <= end)
    assert 0 < stretch_bands < overview_bands
    # the stretch's lines: at most two points a bin, and the highest and lowest sample
    # of the stretch where they are (its panel's y scale puts the range within 6 % pads)
    lines = svg.findall(f"{SVG}polyline")
    current = next(line for line in lines if line.get("stroke") == "#1f5fa8")
    ys = _polyline_y(current)
    assert len(ys) <= 2 * 1000
    low, high = min(ys), max(ys)
    panel_h = 150.0
    assert (low - 152.0) == pytest.approx(panel_h * 0.06 / 1.12, abs=0.15)
    assert (152.0 + panel_h - high) == pytest.approx(panel_h * 0.06 / 1.12, abs=0.15)
    texts = "".join(svg.itertext())
    assert "Axis X: raw data" in texts and f"stretch {start:.1f} – {end:.1f} s" in texts
    for entry in ("motor current", "commanded velocity", "actual velocity", "windows used"):
        assert entry in texts
    # where: the panels span 78..944 px; the stretch's bands start at their windows' times,
    # the overview's box at the stretch's
    left, width = 78.0, 960.0 - 78.0 - 16.0
    starts = [float(x) for x in re.findall(r"M([\d.]+) ", shades[1].get("d", ""))]
    inside = sorted(a for a, b in trace.windows if b >= start and a <= end)
    expected = [left + (max(a, start) - start) / (end - start) * width for a in inside]
    assert starts == pytest.approx(expected, abs=0.06)
    box = svg.find(f"{SVG}rect[@fill='none']")
    assert box is not None
    low, high = trace.span
    assert float(box.get("x", "nan")) == pytest.approx(
        left + (start - low) / (high - low) * width, abs=0.06
    )
    assert float(box.get("width", "nan")) == pytest.approx(
        (end - start) / (high - low) * width, abs=0.1
    )


def test_the_figure_is_bounded_whatever_the_windows(tmp_path: Path) -> None:
    """30,000 windows of a 4 h measurement: bands closer than half a pixel are one."""
    recording, _ = synthetic_recording(tmp_path / "rec", AXES[:1])
    trace = raw_trace(recording, "X")
    span = (0.0, 4 * 3600.0)
    starts = np.linspace(span[0], span[1] - 0.3, 30_000)
    many = dataclasses.replace(
        trace, span=span, windows=tuple((float(a), float(a) + 0.2) for a in starts)
    )
    text = trace_svg(many)
    svg = ET.fromstring(text)
    shades = [p for p in svg.iter(f"{SVG}path") if p.get("fill") == WINDOW_FILL]
    assert len(re.findall("z", shades[0].get("d", ""))) <= (960 - 78 - 16) * 2
    assert len(text) < 300_000


def test_a_figure_without_samples_or_a_command_says_so(tmp_path: Path) -> None:
    recording, _ = synthetic_recording(tmp_path / "rec", AXES[:1])
    trace = raw_trace(recording, "X")
    bare = dataclasses.replace(trace, command=None)
    texts = "".join(ET.fromstring(trace_svg(bare)).itertext())
    assert "commanded velocity" not in texts and "actual velocity" in texts
    empty = dataclasses.replace(trace, rows=0)
    assert "the recording holds no samples" in trace_svg(empty)
    # a lost stretch is a gap in the line; a lost sample beside a peak hides no peak
    n = len(trace.current)
    peak = int(np.argmax(trace.current))
    lost = np.zeros(n, dtype=bool)
    lost[n // 2 : n // 2 + n // 10] = True  # a tenth of the stretch: many whole bins
    lost[peak - 1 if peak else peak + 1] = True
    gappy = dataclasses.replace(trace, current=np.where(lost, np.nan, trace.current))
    svg = ET.fromstring(trace_svg(gappy))
    current = [line for line in svg.findall(f"{SVG}polyline") if line.get("stroke") == "#1f5fa8"]
    assert len(current) == 2  # the line breaks where the stretch was lost
    whole = ET.fromstring(trace_svg(trace))
    (line,) = [e for e in whole.findall(f"{SVG}polyline") if e.get("stroke") == "#1f5fa8"]
    assert min(y for c in current for y in _polyline_y(c)) == min(_polyline_y(line))
