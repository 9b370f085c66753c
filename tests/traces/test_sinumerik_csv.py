"""Sinumerik trace CSV: the three spellings of the axis index, decimal comma, bad rows."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.traces import import_trace
from tests.traces.conftest import FIXTURES

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
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min", "X_position_mm")
    np.testing.assert_array_equal(rec.values[:, [0, 2]], [[1.5, 10], [1.5, 10], [2, 10.5]])


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


def test_840d_signals_take_position_and_velocity_from_the_commanded_measuring_system(
    tmp_path: Path, machine: MachineConfig
) -> None:
    """The CSV export shares the XML's signal table and choice of the measuring system."""
    names = [
        "nckServoDataCmdPos2ndEnc64",
        "nckServoDataActPos1stEnc64",
        "nckServoDataActPos2ndEnc64",
        "nckServoDataCmdVelCtrlIn64",
        "nckServoDataActVel1stEnc64",
        "nckServoDataActVel2ndEnc64",
        "nckServoDataActCurr64",
        "nckServoDataCmdTorque64",
    ]
    header = ",".join(["time"] + [f"+/Nck/!SD/{n} [u1; 1]" for n in names])
    rows = [
        "0,-300.0,-1100.174,-300.0,0.0,0.0,0.0,0.25,0.45",
        "0.002,-299.999,-1100.173,-300.0,30.0,30.0,0.0,2.5,4.5",
        "0.004,-299.997,-1100.171,-299.999,60.0,60.0,30.0,2.625,4.7",
        "0.006,-299.994,-1100.168,-299.997,90.0,90.0,60.0,,",  # empty: the last value holds
    ]
    path = tmp_path / "x_840d.csv"
    path.write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    result = import_trace(path, tmp_path / "rec", machine=machine, axis_names={"1": "X"})
    rec = result.recording
    assert rec.meta.source == "import:sinumerik-csv"
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min", "X_position_mm")
    np.testing.assert_array_equal(rec.column("X_position_mm"), [-300.0, -300.0, -299.999, -299.997])
    np.testing.assert_array_equal(rec.column("X_velocity_mm_min"), [0.0, 0.0, 30.0, 60.0])
    np.testing.assert_array_equal(rec.column("X_current_a"), [0.25, 2.5, 2.625, 2.625])
    assert (
        "axis X: position and velocity from measuring system 2 "
        "(the command position nckServoDataCmdPos2ndEnc64 refers to it)"
    ) in result.report
    assert any(
        line.startswith("/Nck/!SD/nckServoDataCmdVelCtrlIn64 [u1; 1]: not imported (")
        and "unit not verified" in line
        for line in result.report
    )
    assert (
        "/Nck/!SD/nckServoDataActPos1stEnc64 [u1; 1]: not imported (X_position_mm already "
        "comes from /Nck/!SD/nckServoDataActPos2ndEnc64 [u1; 1])"
    ) in result.report


def test_a_quote_that_is_never_closed(tmp_path: Path) -> None:
    # the csv module joins every following line into one cell until its field limit
    path = tmp_path / "quote.csv"
    rows = "".join(f"0.{k:06d},1\n" for k in range(1, 20_000))
    path.write_text(f'time,/Nck/!SD/nckServoDataActCurr64 [u1; 1]\n0,"1\n{rows}', encoding="utf-8")
    with pytest.raises(RecordingError, match=r"quote\.csv: cannot be split into cells \(field"):
        import_trace(path, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()
