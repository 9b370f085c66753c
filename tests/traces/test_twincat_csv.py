"""TwinCAT Scope CSV: per-channel and shared timelines, decimal comma, units, bad files."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.traces import import_trace
from tests.traces.conftest import FIXTURES

PER_CHANNEL = FIXTURES / "twincat_per_channel.csv"
SHARED = FIXTURES / "twincat_shared.csv"


def edited(tmp_path: Path, source: Path, *changes: tuple[str, str]) -> Path:
    text = source.read_text(encoding="utf-8")
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / source.name
    path.write_text(text, encoding="utf-8")
    return path


def test_one_timeline_per_channel_with_decimal_comma(
    tmp_path: Path, machine: MachineConfig
) -> None:
    result = import_trace(PER_CHANNEL, tmp_path / "rec", machine=machine)
    rec = result.recording
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min", "X_position_mm")
    np.testing.assert_array_equal(rec.time_s, [0.0, 0.001, 0.002, 0.003, 0.004])
    np.testing.assert_array_equal(
        rec.values,
        [
            [1.5, 600.0, 100.0],  # ActVelo mm/s x 60; ActPos at 2 ms holds its value
            [1.75, 1200.0, 100.0],
            [2.0, 1800.0, 100.5],
            [2.25, 2400.0, 100.5],
            [2.5, 3000.0, 101.0],
        ],
    )
    assert rec.meta.source == "import:twincat-csv"
    assert rec.meta.nominal_period_s == 0.001
    assert rec.meta.start_utc == "2022-05-02T13:56:24.376+00:00"  # FILETIME of the header
    assert rec.meta.link["scope"] == "friction_x"
    report = result.report
    assert (
        "X_velocity_mm_min [mm/min]: from X.ActVelo "
        "(no unit in the export, mm/s assumed; x 60 = mm/min)" in report
    )
    assert "X_current_a [A]: from X_current_a (no unit conversion)" in report
    assert any(line.startswith("X.ActVelo: ScaleFactor 0,5, Offset 0") for line in report)
    assert any(line.startswith("MAIN.bEnable: not imported") for line in report)
    assert "numbers use a decimal comma" in report
    assert any("merged on the union of their times" in line for line in report)


def test_shared_timeline_semicolon_and_eof(tmp_path: Path, machine: MachineConfig) -> None:
    rec = import_trace(SHARED, tmp_path / "rec", machine=machine).recording
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min", "X_position_mm", "Y_current_a")
    np.testing.assert_array_equal(rec.time_s, [0.0, 0.001, 0.002, 0.003, 0.004])
    np.testing.assert_array_equal(rec.column("X_velocity_mm_min"), [15000.0] * 5)  # 0.25 mm/ms
    np.testing.assert_array_equal(
        rec.values[:, [0, 2, 3]],
        [
            [1.5, 100.0, -0.5],
            [1.75, 100.25, -0.5],  # Y at 2 ms carried forward
            [2.0, 100.5, 0.0],
            [2.25, 100.75, 0.0],
            [2.5, 101.0, 0.5],
        ],
    )


def test_comma_separated_export_with_a_header_it_cannot_split(tmp_path: Path) -> None:
    text = SHARED.read_text(encoding="utf-8").replace(";", ",")
    text = text.replace(
        "SampleTime[ms],1,1,SampleTime[ms],2", "SampleTime[ms],1,1,SampleTime[ms],0,5"
    )
    path = tmp_path / "comma.csv"
    path.write_text(text, encoding="utf-8")
    result = import_trace(path, tmp_path / "rec")
    assert result.recording.channel_names == (
        "X_current_a",
        "X_velocity_mm_min",
        "X_position_mm",
        "Y_current_a",
    )
    np.testing.assert_array_equal(
        result.recording.column("X_position_mm"), [100, 100.25, 100.5, 100.75, 101]
    )
    assert any(
        line.startswith("header line SampleTime[ms] (line 10) does not split")
        for line in result.report
    )


def test_units_are_converted(tmp_path: Path) -> None:
    path = edited(
        tmp_path,
        SHARED,
        ("Unit;A (Ampere);mm (Millimeter);", "Unit;mA (Milliampere);µm (Micrometer);"),
    )
    result = import_trace(path, tmp_path / "rec")
    np.testing.assert_allclose(
        result.recording.column("X_current_a"), [1.5e-3, 1.75e-3, 2e-3, 2.25e-3, 2.5e-3], rtol=1e-15
    )
    np.testing.assert_allclose(
        result.recording.column("X_position_mm"), [0.1, 0.10025, 0.1005, 0.10075, 0.101], rtol=1e-15
    )
    assert "X_position_mm [mm]: from X.ActPos (µm x 0.001 = mm)" in result.report


def test_a_unit_that_does_not_fit_is_reported(tmp_path: Path) -> None:
    path = edited(tmp_path, SHARED, ("Unit;A (Ampere);mm", "Unit;V (Voltage);mm"))
    result = import_trace(path, tmp_path / "rec")
    assert "X_current_a" not in result.recording.channel_names
    assert "X_current_a: not imported (unit 'V' cannot be converted to A)" in result.report


def test_full_timestamp(tmp_path: Path) -> None:
    start = 132959733843760000
    rows = [
        f"{start + 10_000 * k};{1.5 + k};{100 + k}"
        + (f";{start + 20_000 * k};{k}" if k < 2 else "")
        for k in range(4)
    ]
    text = SHARED.read_text(encoding="utf-8")
    head = text[: text.index("0;1.5;100")]
    path = tmp_path / "full.csv"
    path.write_text(head + "\n".join(rows) + "\n", encoding="utf-8")
    result = import_trace(path, tmp_path / "rec")
    np.testing.assert_array_equal(result.recording.time_s, [0.0, 0.001, 0.002])
    np.testing.assert_array_equal(result.recording.column("Y_current_a"), [0.0, 0.0, 1.0])
    assert any("FILETIME" in line for line in result.report)


def test_nc_variable_found_through_its_symbol_name(tmp_path: Path) -> None:
    path = edited(tmp_path, SHARED, ("Name;X_current_a;X.ActPos;", "Name;X_current_a;Position;"))
    result = import_trace(path, tmp_path / "rec", axis_names={"X": "X", "MAIN.AxisX": "Z"})
    assert result.recording.channel_names == ("X_current_a", "Z_velocity_mm_min", "Z_position_mm")
    assert "Z_position_mm [mm]: from Position (no unit conversion)" in result.report
    assert "controller axis Y: not imported (not in axis_names)" in result.report


# --- malformed exports -----------------------------------------------------------------


def test_not_a_scope_export(tmp_path: Path) -> None:
    path = tmp_path / "other.csv"
    path.write_text("Title\tsomething\n", encoding="utf-8")
    with pytest.raises(RecordingError, match=r"other\.csv:1: not a TwinCAT Scope export"):
        import_trace(path, tmp_path / "rec", format="twincat-csv")


def test_space_separated_export_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "space.csv"
    path.write_text("Name friction\n", encoding="utf-8")
    with pytest.raises(RecordingError, match="space-separated"):
        import_trace(path, tmp_path / "rec", format="twincat-csv")


def test_time_that_goes_back_names_line_and_channel(tmp_path: Path) -> None:
    path = edited(tmp_path, SHARED, ("3;2.25;100.75", "1;2.25;100.75"))
    with pytest.raises(
        RecordingError, match=r"twincat_shared\.csv:19: channel X_current_a: time 1 is not later"
    ):
        import_trace(path, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_garbage_cell(tmp_path: Path) -> None:
    path = edited(tmp_path, PER_CHANNEL, ("2\t2\t2\t30", "2\tabc\t2\t30"))
    with pytest.raises(
        RecordingError, match=r"per_channel\.csv:25: channel X_current_a: not a number"
    ):
        import_trace(path, tmp_path / "rec")


def test_decimal_point_in_a_decimal_comma_export(tmp_path: Path) -> None:
    path = edited(tmp_path, PER_CHANNEL, ("3\t2,25\t3", "3\t2.25\t3"))
    with pytest.raises(
        RecordingError, match=r"per_channel\.csv:26: .*decimal point; this file uses decimal commas"
    ):
        import_trace(path, tmp_path / "rec")


def test_decimal_comma_in_a_comma_separated_export(tmp_path: Path) -> None:
    text = SHARED.read_text(encoding="utf-8").replace(";", ",")
    path = tmp_path / "comma.csv"
    path.write_text(text.replace("1,1.75,100.25,2,0", "1,1,75,100.25,2,0"), encoding="utf-8")
    with pytest.raises(
        RecordingError,
        match=r"comma\.csv:17: 6 cells, the header \(line 7\) has 5 \(a decimal comma",
    ):
        import_trace(path, tmp_path / "rec")
    path.write_text(text.replace("3,2.25,100.75", "3,2,25,100.75"), encoding="utf-8")
    with pytest.raises(RecordingError, match=r"comma\.csv:19: .* without a time \(a decimal comma"):
        import_trace(path, tmp_path / "rec")


def test_channel_that_resumes_after_it_ended(tmp_path: Path) -> None:
    path = edited(tmp_path, SHARED, ("4;2.5;101", "4;2.5;101;6;1"))
    with pytest.raises(
        RecordingError, match=r"channel Y_current_a has samples again after empty cells"
    ):
        import_trace(path, tmp_path / "rec")


def test_no_channel_can_be_imported(tmp_path: Path) -> None:
    path = edited(
        tmp_path,
        SHARED,
        ("Name;X_current_a;X.ActPos;Name;Y_current_a", "Name;fTemp;bBusy;Name;nCount"),
        ("MAIN.AxisX.NcToPlc.ActPos", "MAIN.bBusy"),
    )
    with pytest.raises(RecordingError, match="no signal of the trace can be imported") as info:
        import_trace(path, tmp_path / "rec")
    assert len(info.value.problems) == 3


def test_header_without_data(tmp_path: Path) -> None:
    text = SHARED.read_text(encoding="utf-8")
    path = tmp_path / "empty.csv"
    path.write_text(text[: text.index("0;1.5;100")], encoding="utf-8")
    with pytest.raises(RecordingError, match="no data rows after the header"):
        import_trace(path, tmp_path / "rec")


def test_export_without_time_columns(tmp_path: Path) -> None:
    text = SHARED.read_text(encoding="utf-8")
    path = tmp_path / "notime.csv"
    path.write_text(text[: text.index("0;1.5;100")] + "1.5;100;-0.5\n", encoding="utf-8")
    with pytest.raises(RecordingError, match="exports without time columns are not supported"):
        import_trace(path, tmp_path / "rec")


def test_windows_1252_export(tmp_path: Path, fixture_text: Callable[[str], str]) -> None:
    text = fixture_text("twincat_shared.csv").replace("mm (Millimeter)", "µm (Mikrometer)")
    path = tmp_path / "cp1252.csv"
    path.write_bytes(text.encode("cp1252"))
    result = import_trace(path, tmp_path / "rec")
    assert "cp1252.csv is not UTF-8 text; read as Windows-1252" in result.report
    np.testing.assert_allclose(result.recording.column("X_position_mm")[0], 0.1, rtol=1e-15)
