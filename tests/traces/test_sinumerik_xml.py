"""Sinumerik trace XML: exact values, carry-forward, sentinels, axis mapping, bad files."""

from __future__ import annotations

import datetime as dt
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.recording import RecordingWriter, read_recording
from ncmeasure.traces import import_trace
from ncmeasure.traces.sinumerik_xml import parse_signal_name
from tests.traces.conftest import FIXTURES

XML = FIXTURES / "sinumerik_trace.xml"
NAN = float("nan")


def trace(recs: str, signals: str | None = None) -> str:
    """A small trace XML around ``recs``, in the verified layout."""
    if signals is None:
        signals = (
            '<dataSignal id="f1" name="/Nck/!SD/nckServoDataActCurr64 [u1, 1]" interval="0.002"/>'
            '<dataSignal id="f2" name="/Nck/!SD/nckServoDataActPos1stEnc64 [u1, 1]"'
            ' interval="0.004"/>'
        )
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n<traceSession version="2.0">\n'
        '<traceData dataFrames="1"><dataFrame>\n<frameHeader startTime="x"/>\n'
        f"{signals}\n{recs}\n</dataFrame></traceData></traceSession>\n"
    )


def write(tmp_path: Path, text: str, name: str = "trace.xml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_fixture_parses_to_exact_channels_values_and_times(
    tmp_path: Path, machine: MachineConfig
) -> None:
    result = import_trace(XML, tmp_path / "rec", machine=machine)
    rec = result.recording
    assert rec.channel_names == (
        "X_current_a",
        "X_velocity_mm_min",
        "X_position_mm",
        "Y_current_a",
        "Y_velocity_mm_min",  # derived from Y_position_mm (central differences)
        "Y_position_mm",
    )
    np.testing.assert_array_equal(rec.time_s, [0.0, 0.002, 0.004, 0.006, 0.008])
    expected = np.array(
        [
            # X current: the sentinel of record 3 is NaN; velocity = rpm x 20 mm lead
            [1.5, 2000.0, 10.0, -0.5, -20.0],
            [1.75, 3000.0, 10.0, -0.25, -20.0],  # positions (4 ms) carried forward
            [NAN, 4000.0, 10.125, 0.0, -20.5],
            [2.25, 5000.0, 10.125, 0.25, -20.5],
            [2.5, 6000.0, 10.5, 0.5, -21.0],
        ]
    )
    # NaN == NaN for this assert
    np.testing.assert_array_equal(rec.values[:, [0, 1, 2, 3, 5]], expected)
    np.testing.assert_allclose(
        rec.column("Y_velocity_mm_min"), [0.0, -7500.0, -7500.0, -7500.0, -15000.0]
    )
    assert rec.meta.source == "import:sinumerik-xml"
    assert rec.meta.nominal_period_s == 0.002  # the fastest dataSignal interval
    assert rec.meta.machine == machine.machine.name
    assert rec.meta.start_utc == "2024-05-06T08:15:00.000+00:00"
    assert rec.meta.link["session"] == "FRICTION_X_Y"
    assert rec.meta.link["report"] == result.report
    assert rec.meta.status == "complete"
    assert read_recording(tmp_path / "rec").channel_names == rec.channel_names


def test_report_says_what_was_mapped_converted_and_left_out(
    tmp_path: Path, machine: MachineConfig
) -> None:
    report = import_trace(XML, tmp_path / "rec", machine=machine).report
    text = "\n".join(report)
    assert "controller axis 1 -> X (machine axes in order" in text
    assert "controller axis 2 -> Y (machine axes in order" in text
    assert (
        "X_velocity_mm_min [mm/min]: from /Nck/!SD/nckServoDataActVelMot64 [u1, 1] "
        "(motor rpm x screw lead 20 mm/rev = mm/min" in text
    )
    assert "nckServoDataContDev64 [u1, 1]: not imported (no ncmeasure signal" in text
    assert "/Channel/State/actFeedRate [u1, 1]: not imported" in text
    assert (
        "/Nck/!SD/nckServoDataCmdTorque64 [u1, 2]: not imported (Y_current_a already comes "
        "from /Nck/!SD/nckServoDataActCurr64 [u1, 2])" in text
    )
    invalid = [line for line in report if "invalid sample" in line]
    assert len(invalid) == 1
    assert invalid[0].startswith("X_current_a: 1 invalid sample(s)")
    assert "<rec> #3, time=0.004" in invalid[0]


def test_without_machine_axes_get_default_names_and_rpm_is_not_converted(tmp_path: Path) -> None:
    result = import_trace(XML, tmp_path / "rec")
    assert result.recording.channel_names == (
        "A1_current_a",
        "A1_velocity_mm_min",  # the rpm are not converted: derived from the position
        "A1_position_mm",
        "A2_current_a",
        "A2_velocity_mm_min",
        "A2_position_mm",
    )
    assert any(
        "nckServoDataActVelMot64 [u1, 1]: velocity not converted, not imported" in line
        and "screw_lead_mm" in line
        for line in result.report
    )


def test_axis_names_choose_and_drop_axes(tmp_path: Path, machine: MachineConfig) -> None:
    result = import_trace(XML, tmp_path / "rec", machine=machine, axis_names={"2": "Z"})
    assert result.recording.channel_names == ("Z_current_a", "Z_velocity_mm_min", "Z_position_mm")
    np.testing.assert_array_equal(
        result.recording.column("Z_position_mm"), [-20, -20, -20.5, -20.5, -21]
    )
    assert "controller axis 1: not imported (not in axis_names)" in result.report


def test_torque_becomes_current_when_no_current_is_traced(
    tmp_path: Path, machine: MachineConfig
) -> None:
    signals = (
        '<dataSignal id="f7" name="/Nck/!SD/nckServoDataCmdTorque32 [u1, 3]" interval="0.002"/>'
    )
    recs = '<rec time="0" f7="4.2"/><rec time="0.002" f7="-2.1"/>'
    path = write(tmp_path, trace(recs, signals))
    result = import_trace(path, tmp_path / "rec", machine=machine, axis_names={"3": "Z"})
    np.testing.assert_allclose(result.recording.column("Z_current_a"), [2.0, -1.0], rtol=1e-15)
    assert any("torque Nm / torque constant 2.1 Nm/A = A" in line for line in result.report)


def test_records_before_every_signal_has_a_value_are_dropped_and_reported(tmp_path: Path) -> None:
    recs = (
        '<rec time="0" f1="1"/><rec time="0.002" f1="2"/>'
        '<rec time="0.004" f1="3" f2="7.5"/><rec time="0.006" f1="4"/>'
    )
    result = import_trace(write(tmp_path, trace(recs)), tmp_path / "rec")
    np.testing.assert_array_equal(result.recording.time_s, [0.004, 0.006])
    np.testing.assert_array_equal(result.recording.values[:, [0, 2]], [[3.0, 7.5], [4.0, 7.5]])
    assert "2 leading records dropped: not every channel had a value before t = 0.004 s" in (
        result.report
    )


@pytest.mark.parametrize("marker", ["-9.2188684372274053E+18", "1.7976931348623157E+308", "inf"])
def test_invalid_markers_become_nan_until_the_next_valid_value(tmp_path: Path, marker: str) -> None:
    recs = (
        '<rec time="0" f1="1" f2="5"/>'
        f'<rec time="0.002" f1="{marker}"/>'
        '<rec time="0.004" f2="6"/>'
        '<rec time="0.006" f1="4"/>'
    )
    result = import_trace(write(tmp_path, trace(recs)), tmp_path / "rec")
    np.testing.assert_array_equal(
        result.recording.values[:, [0, 2]], [[1, 5], [NAN, 5], [NAN, 6], [4, 6]]
    )
    assert any(line.startswith("A1_current_a: 1 invalid sample(s)") for line in result.report)


@pytest.mark.parametrize(
    ("name", "variable", "index"),
    [
        ("/Nck/!SD/nckServoDataActCurr64 [u1, 1]", "nckServoDataActCurr64", 1),
        ("/Nck/!SD/nckServoDataActCurr32 [u1; 12]", "nckServoDataActCurr32", 12),
        ("+/Nck/!SD/nckServoDataActVelMot64 [u1  3]", "nckServoDataActVelMot64", 3),
    ],
)
def test_signal_names_in_every_spelling(name: str, variable: str, index: int) -> None:
    parsed = parse_signal_name(name)
    assert parsed is not None
    assert (parsed.variable, parsed.axis_index) == (variable, index)


def test_a_name_without_axis_is_not_a_signal() -> None:
    assert parse_signal_name("/Nck/State/sysTime") is None


# --- malformed files -------------------------------------------------------------------


def assert_nothing_left(directory: Path) -> None:
    assert not directory.exists(), f"a failed import left {list(directory.iterdir())}"


def test_truncated_xml_names_line_and_leaves_nothing(tmp_path: Path) -> None:
    text = XML.read_text(encoding="utf-8")
    cut = text[: text.index('<rec time="0.006"') + 20]
    path = write(tmp_path, cut)
    with pytest.raises(
        RecordingError, match=r"trace\.xml:\d+:\d+: the XML is malformed or cut short"
    ):
        import_trace(path, tmp_path / "rec")
    assert_nothing_left(tmp_path / "rec")


def test_time_that_goes_back_names_the_record(tmp_path: Path) -> None:
    recs = '<rec time="0" f1="1" f2="2"/><rec time="0.002" f1="1"/><rec time="0.001" f1="1"/>'
    with pytest.raises(RecordingError, match=r"<rec> #3, time=0\.001: time 0\.001 s is not later"):
        import_trace(write(tmp_path, trace(recs)), tmp_path / "rec")
    assert_nothing_left(tmp_path / "rec")


def test_decimal_comma_in_a_value_is_an_error(tmp_path: Path) -> None:
    recs = '<rec time="0" f1="1" f2="2"/><rec time="0.002" f1="1,5"/>'
    with pytest.raises(
        RecordingError, match=r"<rec> #2, time=0\.002: f1='1,5' is not a number \(a decimal comma"
    ):
        import_trace(write(tmp_path, trace(recs)), tmp_path / "rec")


def test_record_without_time(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"<rec> #1: no time attribute"):
        import_trace(write(tmp_path, trace('<rec f1="1" f2="2"/>')), tmp_path / "rec")


def test_missing_channels_mean_nothing_to_import(tmp_path: Path) -> None:
    signals = '<dataSignal id="f1" name="/Nck/!SD/nckServoDataContDev64 [u1, 1]"/>'
    with pytest.raises(RecordingError, match="no signal of the trace can be imported") as info:
        import_trace(write(tmp_path, trace('<rec time="0" f1="1"/>', signals)), tmp_path / "rec")
    assert any("nckServoDataContDev64" in p for p in info.value.problems)


def test_a_signal_that_never_has_a_value(tmp_path: Path) -> None:
    recs = '<rec time="0" f1="1"/><rec time="0.002" f1="2"/>'
    with pytest.raises(RecordingError, match=r"A1_position_mm never has a value in 2 records"):
        import_trace(write(tmp_path, trace(recs)), tmp_path / "rec")


def test_no_records(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"no <rec> element"):
        import_trace(write(tmp_path, trace("")), tmp_path / "rec")


def test_other_xml_root(tmp_path: Path) -> None:
    path = write(tmp_path, '<?xml version="1.0"?><ResponseTestCustom/>')
    with pytest.raises(RecordingError, match=r"root element is <ResponseTestCustom>"):
        import_trace(path, tmp_path / "rec", format="sinumerik-xml")


def test_second_data_frame_is_refused(tmp_path: Path) -> None:
    text = trace('<rec time="0" f1="1" f2="2"/>').replace(
        "</dataFrame></traceData>", "</dataFrame><dataFrame/></traceData>"
    )
    with pytest.raises(RecordingError, match="a second <dataFrame>"):
        import_trace(write(tmp_path, text), tmp_path / "rec")
    assert_nothing_left(tmp_path / "rec")


def test_failed_import_keeps_an_existing_empty_directory_empty(tmp_path: Path) -> None:
    target = tmp_path / "rec"
    target.mkdir()
    recs = '<rec time="0" f1="1" f2="2"/><rec time="0.002" f1="1"/><rec time="0.002" f1="1"/>'
    with pytest.raises(RecordingError):
        import_trace(write(tmp_path, trace(recs)), target)
    assert target.is_dir()
    assert list(target.iterdir()) == []


def test_a_start_time_that_is_no_iso_date_leaves_the_time_unknown(
    tmp_path: Path, fixture_text: Callable[[str], str]
) -> None:
    """An unreadable start is kept in link, and the measurement's time is unknown: never
    the time of the import."""
    text = fixture_text("sinumerik_trace.xml").replace(
        "2024-05-06T10:15:00+02:00", "06.05.2024 10:15"
    )
    result = import_trace(write(tmp_path, text), tmp_path / "rec")
    assert result.meta.link["trace_start"] == "06.05.2024 10:15"
    assert result.meta.start_utc is None
    assert any("measurement's time is unknown" in line for line in result.report)


def test_a_start_time_without_zone_is_taken_as_utc(
    tmp_path: Path, fixture_text: Callable[[str], str]
) -> None:
    text = fixture_text("sinumerik_trace.xml").replace(
        "2024-05-06T10:15:00+02:00", "2024-05-06T10:15:00"
    )
    result = import_trace(write(tmp_path, text), tmp_path / "rec")
    assert result.meta.start_utc == "2024-05-06T10:15:00.000+00:00"
    assert (
        "measured at 2024-05-06 10:15:00 UTC (from frameHeader startTime, no time zone: "
        "taken as UTC)" in result.report
    )


def test_measured_at_wins_over_the_start_time(
    tmp_path: Path, fixture_text: Callable[[str], str]
) -> None:
    path = write(tmp_path, fixture_text("sinumerik_trace.xml"))
    when = dt.datetime(2024, 5, 7, 6, 0, tzinfo=dt.UTC)
    result = import_trace(path, tmp_path / "rec", measured_at=when)
    assert result.meta.start_utc == "2024-05-07T06:00:00.000+00:00"
    assert (
        "measured at 2024-05-07 06:00:00 UTC (--measured-at); the data say 2024-05-06 "
        "08:15:00 UTC (frameHeader startTime)" in result.report
    )


def test_failure_after_rows_reached_the_disk_removes_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # more records than one chunk, so rows are on disk when the error comes
    # (a chunk is written once the next one's first row is there: the derived velocity)
    recs = "".join(f'<rec time="{i / 1000!r}" f1="{i}" f2="{i}"/>' for i in range(20_000))
    recs += '<rec time="1.0" f1="1"/>'  # goes back in time
    target = tmp_path / "rec"
    on_disk: list[int] = []
    flush = RecordingWriter.flush

    def spying_flush(writer: RecordingWriter) -> None:
        flush(writer)
        on_disk.append((target / "samples.bin").stat().st_size)

    monkeypatch.setattr(RecordingWriter, "flush", spying_flush)
    with pytest.raises(RecordingError, match=r"<rec> #20001, time=1\.0: time 1\.0 s is not later"):
        import_trace(write(tmp_path, trace(recs)), target)
    assert on_disk and on_disk[0] > 0
    assert_nothing_left(target)


# --- SINUMERIK 840D sl: velocities of the measuring systems, the active system ----------

MOVING = FIXTURES / "sinumerik_840d_moving.xml"
HOLDING = FIXTURES / "sinumerik_840d_holding.xml"
SYSTEM_2 = (
    "position and velocity from measuring system 2 "
    "(the command position nckServoDataCmdPos2ndEnc64 refers to it)"
)


def carried(path: Path, signal_id: str) -> list[float]:
    """The values of ``signal_id`` record by record, a left-out value kept (read independently)."""
    values: list[float] = []
    last = NAN
    for rec in ET.parse(path).getroot().iter("rec"):
        last = float(rec.get(signal_id, last))
        values.append(last)
    return values


def test_840d_moving_axis_position_and_velocity_come_from_measuring_system_2(
    tmp_path: Path, machine: MachineConfig
) -> None:
    """The real header (traceCaptureSetup_V20 then traceCaptureSetup) and the real signal set.

    The fixture's header comment says which of its properties are taken from a
    real trace and which are made up.
    """
    assert "<traceCaptureSetup_V20>" in MOVING.read_text(encoding="utf-8")
    result = import_trace(MOVING, tmp_path / "rec", machine=machine, axis_names={"1": "X"})
    rec = result.recording
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min", "X_position_mm")
    position = rec.column("X_position_mm")
    velocity = rec.column("X_velocity_mm_min")
    # machine coordinates: measuring system 2 (f3, -300 mm), not system 1 (f2, -1100.174 mm)
    np.testing.assert_array_equal(position, carried(MOVING, "f3"))
    assert position[0] == -300.0
    assert position[-1] == pytest.approx(-298.59, abs=1e-9)
    assert np.all(np.abs(np.array(carried(MOVING, "f2")) - position + 800.174) < 0.001)
    # mm/min as written, no conversion: the ActVel2ndEnc64 figures (f6)
    np.testing.assert_array_equal(velocity, carried(MOVING, "f6"))
    np.testing.assert_array_equal(velocity[9:13], [0.0, 30.0, 60.0, 90.0])
    assert velocity[30] == 600.3  # rec time=0.060000 f6="600.300000"
    # ... which is the slope of the imported position in mm/min, as system 1's is of its own
    np.testing.assert_allclose(velocity[1:], np.diff(position) / 0.002 * 60, rtol=0, atol=1e-6)
    slope_1 = np.diff(carried(MOVING, "f2")) / 0.002 * 60
    np.testing.assert_allclose(carried(MOVING, "f5")[1:], slope_1, rtol=0, atol=1e-6)
    assert np.max(np.abs(velocity[1:] - slope_1)) > 1.0  # so the two systems differ
    np.testing.assert_array_equal(rec.column("X_current_a"), carried(MOVING, "f9"))
    assert f"axis X: {SYSTEM_2}" in result.report
    assert rec.meta.link["session"] == "FRICTION_X"
    assert rec.meta.link["trace_version"] == "01.00.03.02"
    assert rec.meta.start_utc == "2025-03-14T09:26:53.589+00:00"
    assert rec.meta.nominal_period_s == 0.002


def test_840d_signals_that_are_not_imported_say_why(tmp_path: Path, machine: MachineConfig) -> None:
    report = import_trace(MOVING, tmp_path / "rec", machine=machine).report
    reasons = {
        line.split(" [u1, 1]: ")[0].rsplit("/", 1)[1]: line.split(": not imported ", 1)[1]
        for line in report
        if ": not imported " in line
    }
    assert reasons["nckServoDataCmdVelCtrlIn64"].startswith(
        "(velocity setpoint at the speed controller input: unit not verified"
    )
    assert reasons["nckServoDataDrvLoad64"] == (
        "(drive load in % of the torque limit: ncmeasure has no such signal)"
    )
    assert reasons["nckServoDataCtrlDev64"] == (
        "(control deviation in mm: ncmeasure has no such signal)"
    )
    assert "ncmeasure records no command position" in reasons["nckServoDataCmdPos2ndEnc64"]
    assert reasons["nckServoDataActPos1stEnc64"] == (
        "(X_position_mm already comes from /Nck/!SD/nckServoDataActPos2ndEnc64 [u1, 1])"
    )
    assert reasons["nckServoDataActVel1stEnc64"] == (
        "(X_velocity_mm_min already comes from /Nck/!SD/nckServoDataActVel2ndEnc64 [u1, 1])"
    )
    assert reasons["nckServoDataCmdTorque64"] == (
        "(X_current_a already comes from /Nck/!SD/nckServoDataActCurr64 [u1, 1])"
    )


def test_840d_holding_axis_imports_position_velocity_and_current(tmp_path: Path) -> None:
    """An axis that holds: measuring system 2 creeps by less than one velocity count.

    Only traceCaptureSetup_V20 holds the session settings. The import must
    succeed; that the axis did not move is for the analysis to say.
    """
    text = HOLDING.read_text(encoding="utf-8")
    assert "<traceCaptureSetup_V20>" in text and "<traceCaptureSetup>" not in text
    result = import_trace(HOLDING, tmp_path / "rec")
    rec = result.recording
    assert rec.channel_names == ("A1_current_a", "A1_velocity_mm_min", "A1_position_mm")
    assert len(rec.time_s) == 200
    position = rec.column("A1_position_mm")
    velocity = rec.column("A1_velocity_mm_min")
    np.testing.assert_array_equal(position, carried(HOLDING, "f3"))
    assert position[0] == -300.0
    assert 0.2e-3 < position.max() - position.min() < 0.4e-3  # a few tenths of a um
    assert set(np.unique(velocity)) == {-0.292969, 0.0, 0.292969}  # 0 or one count
    # positions are rounded to 1e-6 mm: their slope matches to within 1e-6 / 0.002 x 60
    slope = np.diff(position) / 0.002 * 60
    assert np.max(np.abs(velocity[1:] - slope)) <= 0.03 + 1e-9
    np.testing.assert_array_equal(rec.column("A1_current_a"), carried(HOLDING, "f9"))
    assert f"axis A1: {SYSTEM_2}" in result.report
    assert rec.meta.link["session"] == "HOLD_X"


def servo(variable: str, sid: str, axis: int = 1) -> str:
    return f'<dataSignal id="{sid}" name="/Nck/!SD/{variable} [u1, {axis}]" interval="0.002"/>'


def systems_trace(tmp_path: Path, variables: list[str], values: list[list[float]]) -> Path:
    """A trace with the servo ``variables`` of axis 1 and one record per row of ``values``."""
    signals = "".join(servo(v, f"f{i + 1}") for i, v in enumerate(variables))
    recs = "".join(
        f'<rec time="{k * 0.002!r}" '
        + " ".join(f'f{i + 1}="{x!r}"' for i, x in enumerate(row))
        + "/>"
        for k, row in enumerate(values)
    )
    return write(tmp_path, trace(recs, signals))


BOTH_SYSTEMS = [
    "nckServoDataActCurr64",
    "nckServoDataActPos1stEnc64",
    "nckServoDataActPos2ndEnc64",
    "nckServoDataActVel1stEnc64",
    "nckServoDataActVel2ndEnc64",
]
BOTH_ROWS = [[1.0, -1100.0, -300.0, 0.0, 0.0], [1.5, -1099.99, -299.98, 300.0, 600.0]]


@pytest.mark.parametrize(
    ("command", "system"),
    [("nckServoDataCmdPos2ndEnc64", 2), ("nckServoDataCmdPos1stEnc32", 1)],
)
def test_the_command_position_names_the_measuring_system(
    tmp_path: Path, command: str, system: int
) -> None:
    path = systems_trace(tmp_path, [command, *BOTH_SYSTEMS], [[-300.0, *row] for row in BOTH_ROWS])
    result = import_trace(path, tmp_path / "rec")
    rec = result.recording
    assert rec.channel_names == ("A1_current_a", "A1_velocity_mm_min", "A1_position_mm")
    index = {1: (1, 3), 2: (2, 4)}[system]
    np.testing.assert_array_equal(rec.column("A1_position_mm"), [r[index[0]] for r in BOTH_ROWS])
    np.testing.assert_array_equal(
        rec.column("A1_velocity_mm_min"), [r[index[1]] for r in BOTH_ROWS]
    )
    assert (
        f"axis A1: position and velocity from measuring system {system} "
        f"(the command position {command} refers to it)"
    ) in result.report


def test_without_a_command_position_measuring_system_1_is_taken_and_the_report_says_so(
    tmp_path: Path,
) -> None:
    result = import_trace(systems_trace(tmp_path, BOTH_SYSTEMS, BOTH_ROWS), tmp_path / "rec")
    np.testing.assert_array_equal(result.recording.column("A1_position_mm"), [-1100.0, -1099.99])
    np.testing.assert_array_equal(result.recording.column("A1_velocity_mm_min"), [0.0, 300.0])
    assert (
        "axis A1: position and velocity from measuring system 1 (no command position "
        "(nckServoDataCmdPos1stEnc/2ndEnc) in the trace tells which measuring system the "
        "axis is controlled on; measuring system 1 by default)"
    ) in result.report


def test_position_and_velocity_are_never_taken_from_two_measuring_systems(
    tmp_path: Path,
) -> None:
    variables = [
        "nckServoDataCmdPos2ndEnc64",
        "nckServoDataActCurr64",
        "nckServoDataActPos2ndEnc64",
        "nckServoDataActVel1stEnc64",  # the velocity of the other system only
    ]
    path = systems_trace(
        tmp_path, variables, [[-300.0, 1.0, -300.0, 0.0], [-300.0, 1.0, -300.0, 3.0]]
    )
    result = import_trace(path, tmp_path / "rec")
    assert result.recording.channel_names == (
        "A1_current_a",
        "A1_velocity_mm_min",  # derived from the position of measuring system 2
        "A1_position_mm",
    )
    assert (
        "/Nck/!SD/nckServoDataActVel1stEnc64 [u1, 1]: not imported (axis A1 takes its values "
        "from measuring system 2; this is measuring system 1, and the two are not mixed)"
    ) in result.report
    assert (
        "axis A1: position from measuring system 2 (the command position "
        "nckServoDataCmdPos2ndEnc64 refers to it); the trace has no velocity of measuring "
        "system 2, and that of another measuring system is not mixed in"
    ) in result.report


def test_measuring_system_1_when_the_commanded_one_is_not_traced_is_a_warning(
    tmp_path: Path,
) -> None:
    variables = [
        "nckServoDataCmdPos2ndEnc64",
        "nckServoDataActCurr32",
        "nckServoDataActPos1stEnc32",
        "nckServoDataActVel1stEnc32",
    ]
    rows = [[-300.0, 1.0, -1100.0, 0.0], [-300.0, 1.0, -1100.0, 0.0]]
    result = import_trace(systems_trace(tmp_path, variables, rows), tmp_path / "rec")
    np.testing.assert_array_equal(result.recording.column("A1_position_mm"), [-1100.0, -1100.0])
    assert (
        "axis A1: position and velocity from measuring system 1 (the command position "
        "nckServoDataCmdPos2ndEnc64 refers to measuring system 2, of which the trace has no "
        "position or velocity; the positions may be offset from machine coordinates)"
    ) in result.report


def test_velocity_of_a_measuring_system_wins_over_the_motor_speed(
    tmp_path: Path, machine: MachineConfig
) -> None:
    variables = [
        "nckServoDataActCurr64",
        "nckServoDataActVelMot64",
        "nckServoDataActPos2ndEnc64",
        "nckServoDataActVel2ndEnc32",
    ]
    rows = [[1.0, 30.0, -300.0, 0.0], [1.0, 31.0, -299.99, 600.0]]
    path = systems_trace(tmp_path, variables, rows)
    result = import_trace(path, tmp_path / "rec", machine=machine, axis_names={"1": "X"})
    np.testing.assert_array_equal(result.recording.column("X_velocity_mm_min"), [0.0, 600.0])
    assert (
        "/Nck/!SD/nckServoDataActVelMot64 [u1, 1]: not imported (X_velocity_mm_min already "
        "comes from /Nck/!SD/nckServoDataActVel2ndEnc32 [u1, 1])"
    ) in result.report
    assert (
        "X_velocity_mm_min [mm/min]: from /Nck/!SD/nckServoDataActVel2ndEnc32 [u1, 1] "
        "(mm/min of measuring system 2, no conversion)"
    ) in result.report
    assert any(
        line.startswith("axis X: position and velocity from measuring system 2 (no ")
        for line in result.report
    )


def test_axes_choose_their_measuring_systems_independently(tmp_path: Path) -> None:
    signals = "".join(
        [
            servo("nckServoDataCmdPos2ndEnc64", "f1", axis=1),
            servo("nckServoDataActPos1stEnc64", "f2", axis=1),
            servo("nckServoDataActPos2ndEnc64", "f3", axis=1),
            servo("nckServoDataActPos1stEnc64", "f4", axis=2),
            servo("nckServoDataActPos2ndEnc64", "f5", axis=2),
        ]
    )
    recs = '<rec time="0" f1="-300" f2="-1100" f3="-300" f4="50" f5="-750"/>'
    result = import_trace(write(tmp_path, trace(recs, signals)), tmp_path / "rec")
    assert result.recording.channel_names == (
        "A1_velocity_mm_min",
        "A1_position_mm",
        "A2_velocity_mm_min",
        "A2_position_mm",
    )
    np.testing.assert_array_equal(result.recording.values[:, [1, 3]], [[-300.0, 50.0]])


def test_session_settings_outside_the_capture_setup_are_not_the_session(tmp_path: Path) -> None:
    text = trace('<rec time="0" f1="1" f2="2"/>').replace(
        '<traceData dataFrames="1">',
        '<traceDisplaySetup_V20><sessionSettings sessionName="WRONG"/></traceDisplaySetup_V20>'
        '<traceCaptureSetup_V20><sessionSettings sessionName="RIGHT"/></traceCaptureSetup_V20>'
        '<traceCaptureSetup><sessionSettings sessionName="LATER"/></traceCaptureSetup>'
        '<traceData dataFrames="1">',
    )
    rec = import_trace(write(tmp_path, text), tmp_path / "rec").recording
    assert rec.meta.link["session"] == "RIGHT"
