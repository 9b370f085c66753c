"""Sinumerik trace XML: exact values, carry-forward, sentinels, axis mapping, bad files."""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.recording import RecordingWriter, read_recording
from ncmeasure.traces import import_trace
from ncmeasure.traces.sinumerik_xml import parse_signal_name

from .conftest import FIXTURES

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
    np.testing.assert_array_equal(rec.values, expected)  # NaN == NaN for this assert
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
        "A1_position_mm",
        "A2_current_a",
        "A2_position_mm",
    )
    assert any(
        "nckServoDataActVelMot64 [u1, 1]: velocity not converted, not imported" in line
        and "screw_lead_mm" in line
        for line in result.report
    )


def test_axis_names_choose_and_drop_axes(tmp_path: Path, machine: MachineConfig) -> None:
    result = import_trace(XML, tmp_path / "rec", machine=machine, axis_names={"2": "Z"})
    assert result.recording.channel_names == ("Z_current_a", "Z_position_mm")
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
    np.testing.assert_array_equal(result.recording.values, [[3.0, 7.5], [4.0, 7.5]])
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
    np.testing.assert_array_equal(result.recording.values, [[1, 5], [NAN, 5], [NAN, 6], [4, 6]])
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


def test_start_time_without_zone_is_kept_in_link_only(
    tmp_path: Path, fixture_text: Callable[[str], str]
) -> None:
    text = fixture_text("sinumerik_trace.xml").replace(
        "2024-05-06T10:15:00+02:00", "06.05.2024 10:15"
    )
    before = dt.datetime.now(dt.UTC)
    rec = import_trace(write(tmp_path, text), tmp_path / "rec").recording
    assert rec.meta.link["trace_start"] == "06.05.2024 10:15"
    assert dt.datetime.fromisoformat(rec.meta.start_utc) >= before.replace(microsecond=0)


def test_failure_after_rows_reached_the_disk_removes_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # more records than one chunk, so rows are on disk when the error comes
    recs = "".join(f'<rec time="{i / 1000!r}" f1="{i}" f2="{i}"/>' for i in range(10_000))
    recs += '<rec time="1.0" f1="1"/>'  # goes back in time
    target = tmp_path / "rec"
    on_disk: list[int] = []
    flush = RecordingWriter.flush

    def spying_flush(writer: RecordingWriter) -> None:
        flush(writer)
        on_disk.append((target / "samples.bin").stat().st_size)

    monkeypatch.setattr(RecordingWriter, "flush", spying_flush)
    with pytest.raises(RecordingError, match=r"<rec> #10001, time=1\.0: time 1\.0 s is not later"):
        import_trace(write(tmp_path, trace(recs)), target)
    assert on_disk and on_disk[0] > 0
    assert_nothing_left(target)
