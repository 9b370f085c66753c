"""Sinumerik trace CSV: the three spellings of the axis index, decimal comma, bad rows."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.traces import import_trace

from .conftest import FIXTURES

NAN = float("nan")
CHANNELS = ("X_current_a", "X_velocity_mm_min", "X_position_mm", "Y_current_a")
TIMES = [0.0, 0.002, 0.004, 0.006, 0.008]
VALUES = [
    [1.5, 2000.0, 10.0, -0.5],
    [1.75, 3000.0, 10.0, -0.25],  # empty position cell: the last position holds
    [NAN, 4000.0, 10.125, 0.0],  # invalid-value marker
    [2.25, 5000.0, 10.125, 0.25],
    [2.5, 6000.0, 10.5, 0.5],
]


@pytest.mark.parametrize(
    "name", ["sinumerik_semicolon.csv", "sinumerik_comma.csv", "sinumerik_spaces.csv"]
)
def test_every_spelling_gives_the_same_recording(
    tmp_path: Path, machine: MachineConfig, name: str
) -> None:
    result = import_trace(FIXTURES / name, tmp_path / "rec", machine=machine)
    rec = result.recording
    assert rec.channel_names == CHANNELS
    np.testing.assert_array_equal(rec.time_s, TIMES)
    np.testing.assert_array_equal(rec.values, VALUES)
    assert rec.meta.source == "import:sinumerik-csv"
    assert rec.meta.nominal_period_s == pytest.approx(0.002, abs=1e-15)
    assert any(line.startswith("X_current_a: 1 invalid sample(s)") for line in result.report)
    assert any("nckServoDataContDev64" in line and "not imported" in line for line in result.report)


def test_decimal_comma_is_detected_and_reported(tmp_path: Path, machine: MachineConfig) -> None:
    report = import_trace(
        FIXTURES / "sinumerik_semicolon.csv", tmp_path / "r", machine=machine
    ).report
    assert "numbers use a decimal comma" in report


def test_lines_before_the_header_are_skipped_and_reported(
    tmp_path: Path, machine: MachineConfig
) -> None:
    report = import_trace(FIXTURES / "sinumerik_spaces.csv", tmp_path / "r", machine=machine).report
    assert "2 line(s) before the header row (line 3) skipped" in report


def test_quoted_names_with_a_comma_in_a_comma_separated_file(tmp_path: Path) -> None:
    path = tmp_path / "quoted.csv"
    path.write_text(
        'time,"/Nck/!SD/nckServoDataActCurr64 [u1, 1]",'
        '"/Nck/!SD/nckServoDataActPos1stEnc64 [u1, 1]"\n'
        "0,1.5,10\n0.001,1.5,\n0.002,2,10.5\n",
        encoding="utf-8",
    )
    rec = import_trace(path, tmp_path / "rec", axis_names={"1": "X"}).recording
    assert rec.channel_names == ("X_current_a", "X_position_mm")
    np.testing.assert_array_equal(rec.values, [[1.5, 10], [1.5, 10], [2, 10.5]])


def test_time_in_milliseconds_is_converted(tmp_path: Path) -> None:
    path = tmp_path / "ms.csv"
    path.write_text(
        "time [ms];/Nck/!SD/nckServoDataActCurr64 [u1; 1]\n0;1\n2;2\n4;3\n", encoding="utf-8"
    )
    result = import_trace(path, tmp_path / "rec")
    np.testing.assert_array_equal(result.recording.time_s, [0.0, 0.002, 0.004])
    assert any("converted to seconds" in line for line in result.report)


def rewrite(
    tmp_path: Path, fixture_text: Callable[[str], str], name: str, old: str, new: str
) -> Path:
    text = fixture_text(name)
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


def test_decimal_comma_in_a_comma_separated_file(
    tmp_path: Path, fixture_text: Callable[[str], str]
) -> None:
    path = rewrite(tmp_path, fixture_text, "sinumerik_comma.csv", "0.006,2.25,", "0.006,2,25,")
    with pytest.raises(
        RecordingError,
        match=r"sinumerik_comma\.csv:5: 7 cells, the header \(line 1\) has 6 \(a decimal comma",
    ):
        import_trace(path, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_decimal_point_in_a_decimal_comma_file(
    tmp_path: Path, fixture_text: Callable[[str], str]
) -> None:
    path = rewrite(tmp_path, fixture_text, "sinumerik_semicolon.csv", "0,006;2,25;", "0,006;2.25;")
    with pytest.raises(RecordingError, match=r"semicolon\.csv:5: column .*'2\.25' .*decimal point"):
        import_trace(path, tmp_path / "rec")


def test_garbage_row(tmp_path: Path, fixture_text: Callable[[str], str]) -> None:
    path = rewrite(tmp_path, fixture_text, "sinumerik_comma.csv", "0.004,", "garbage,")
    with pytest.raises(
        RecordingError, match=r"sinumerik_comma\.csv:4: time 'garbage' is not a number"
    ):
        import_trace(path, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_non_monotonic_time(tmp_path: Path, fixture_text: Callable[[str], str]) -> None:
    path = rewrite(tmp_path, fixture_text, "sinumerik_comma.csv", "0.006,", "0.001,")
    with pytest.raises(RecordingError, match=r"sinumerik_comma\.csv:5: time 0\.001 s is not later"):
        import_trace(path, tmp_path / "rec")


def test_no_header_row(tmp_path: Path) -> None:
    path = tmp_path / "plain.csv"
    path.write_text("a,b\n1,2\n", encoding="utf-8")
    with pytest.raises(RecordingError, match="no header row in the first 2 lines"):
        import_trace(path, tmp_path / "rec", format="sinumerik-csv")


def test_header_without_data(tmp_path: Path) -> None:
    path = tmp_path / "empty.csv"
    path.write_text("time,/Nck/!SD/nckServoDataActCurr64 [u1; 1]\n\n", encoding="utf-8")
    with pytest.raises(RecordingError, match=r"no data rows after the header \(line 1\)"):
        import_trace(path, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_a_column_that_stays_empty(tmp_path: Path) -> None:
    path = tmp_path / "half.csv"
    path.write_text(
        "time,/Nck/!SD/nckServoDataActCurr64 [u1; 1],/Nck/!SD/nckServoDataActPos1stEnc64 [u1; 1]\n"
        "0,1,\n0.001,2,\n",
        encoding="utf-8",
    )
    with pytest.raises(RecordingError, match=r"A1_position_mm never has a value in 2 rows"):
        import_trace(path, tmp_path / "rec")


def test_a_quote_that_is_never_closed(tmp_path: Path) -> None:
    # the csv module joins every following line into one cell until its field limit
    path = tmp_path / "quote.csv"
    rows = "".join(f"0.{k:06d},1\n" for k in range(1, 20_000))
    path.write_text(f'time,/Nck/!SD/nckServoDataActCurr64 [u1; 1]\n0,"1\n{rows}', encoding="utf-8")
    with pytest.raises(RecordingError, match=r"quote\.csv: cannot be split into cells \(field"):
        import_trace(path, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()
