"""Heidenhain TNCscope export: curves at different cycle times, units, bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import RecordingError
from ncmeasure.traces import import_trace
from tests.traces.conftest import FIXTURES

SCO = FIXTURES / "tncscope.sco"


def edited(tmp_path: Path, *changes: tuple[str, str], encoding: str = "utf-8") -> Path:
    text = SCO.read_text(encoding="utf-8")
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / "trace.sco"
    path.write_bytes(text.encode(encoding))
    return path


def test_curves_at_different_cycle_times(tmp_path: Path, machine: MachineConfig) -> None:
    result = import_trace(SCO, tmp_path / "rec", machine=machine)
    rec = result.recording
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min", "X_position_mm")
    # sample k of a curve lies at k x CYCLETIME; the 6 ms current holds between its samples,
    # and the rows after its last sample (12 ms) are dropped
    np.testing.assert_array_equal(rec.time_s, np.array([0, 3000, 6000, 9000, 12000]) / 1e6)
    np.testing.assert_array_equal(
        rec.values,
        [
            [1.5, 1200.0, 50.0],
            [1.5, 1250.0, 50.0625],
            [1.75, 1300.0, 50.125],
            [1.75, 1350.0, 50.1875],
            [2.0, 1400.0, 50.25],
        ],
    )
    assert rec.meta.source == "import:tncscope"
    assert rec.meta.nominal_period_s == 0.003
    assert rec.meta.link["global"] == {
        "VERSION": "built for the ncmeasure tests",
        "DATE": "06.05.2024",
    }
    report = result.report
    assert (
        "curve 4 (DSP-Debug X): not imported (no ncmeasure signal for channel type 'DSP-Debug')"
        in report
    )
    assert "X_current_a [A]: from curve 3 (I nominal X) (no unit conversion)" in report
    assert "1 trailing row(s) dropped: a channel ends at t = 0.012 s" in report


def test_decimal_comma(tmp_path: Path) -> None:
    text = SCO.read_text(encoding="utf-8")
    head, data = text.split("%[DATA]\n")
    path = tmp_path / "comma.sco"
    path.write_text(head + "%[DATA]\n" + data.replace(".", ","), encoding="utf-8")
    result = import_trace(path, tmp_path / "rec")
    np.testing.assert_array_equal(
        result.recording.column("X_position_mm"), [50, 50.0625, 50.125, 50.1875, 50.25]
    )
    assert "numbers use a decimal comma" in result.report


def test_micrometres_in_windows_1252(tmp_path: Path) -> None:
    path = edited(
        tmp_path,
        ("%DIMENSION=mm\n", "%DIMENSION=µm\n"),
        ("0;1200;50;", "0;1200;50000;"),
        encoding="cp1252",
    )
    result = import_trace(path, tmp_path / "rec")
    assert result.recording.column("X_position_mm")[0] == 50.0
    assert "X_position_mm [mm]: from curve 2 (s actual X) (µm x 0.001 = mm)" in result.report
    assert "trace.sco is not UTF-8 text; read as Windows-1252" in result.report


def test_torque_and_dsp_debug_current(tmp_path: Path, machine: MachineConfig) -> None:
    path = edited(
        tmp_path,
        (
            "%CHANNELTYPE=I nominal\n%AXISTYPE=X\n%DIMENSION=A",
            "%CHANNELTYPE=M actual\n%AXISTYPE=Y\n%DIMENSION=Nm",
        ),
        ("%DIMENSION=id(222)", "%DIMENSION=id(10)"),
        ("%CHANNELTYPE=DSP-Debug\n%AXISTYPE=X", "%CHANNELTYPE=DSP-Debug\n%AXISTYPE=Z"),
        # currents a drive of the example machine (17.7 A rated) can carry
        *((f";{5000 + k};", f";{5 + k / 1000:.3f};") for k in range(6)),
    )
    rec = import_trace(path, tmp_path / "rec", machine=machine).recording
    assert rec.channel_names == ("X_velocity_mm_min", "X_position_mm", "Y_current_a", "Z_current_a")
    np.testing.assert_allclose(
        rec.column("Y_current_a"),
        [1.5 / 2.1, 1.5 / 2.1, 1.75 / 2.1, 1.75 / 2.1, 2 / 2.1],
        rtol=1e-15,
    )
    np.testing.assert_array_equal(rec.column("Z_current_a"), [5.0, 5.001, 5.002, 5.003, 5.004])


def test_a_dsp_debug_current_beyond_the_drive_is_left_out(
    tmp_path: Path, machine: MachineConfig
) -> None:
    """5000 A on a 17.7 A motor is no current: left out as not physically possible."""
    path = edited(
        tmp_path,
        ("%DIMENSION=id(222)", "%DIMENSION=id(10)"),
        ("%CHANNELTYPE=DSP-Debug\n%AXISTYPE=X", "%CHANNELTYPE=DSP-Debug\n%AXISTYPE=Z"),
    )
    result = import_trace(path, tmp_path / "rec", machine=machine)
    assert np.isnan(result.recording.column("Z_current_a")).all()
    assert any(line.startswith("Z_current_a: ") and "beyond ±177" in line for line in result.report)


def test_missing_dimension_assumes_the_manual_unit(tmp_path: Path) -> None:
    path = edited(tmp_path, ("%DIMENSION=mm/min\n", ""))
    result = import_trace(path, tmp_path / "rec")
    assert (
        "X_velocity_mm_min [mm/min]: from curve 1 (v act. X) (no DIMENSION, mm/min assumed)"
        in result.report
    )


# --- malformed exports -----------------------------------------------------------------


def test_cut_short_before_count(tmp_path: Path) -> None:
    text = SCO.read_text(encoding="utf-8")
    path = tmp_path / "short.sco"
    path.write_text(text[: text.index("12000;")], encoding="utf-8")
    with pytest.raises(
        RecordingError,
        match=r"%\[DATA\] has 4 rows, but curve 1 .*COUNT up to 6\); the file is cut short",
    ):
        import_trace(path, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_no_data_section(tmp_path: Path) -> None:
    text = SCO.read_text(encoding="utf-8")
    path = tmp_path / "nodata.sco"
    path.write_text(text[: text.index("%[DATA]")], encoding="utf-8")
    with pytest.raises(RecordingError, match=r"no %\[DATA\] line"):
        import_trace(path, tmp_path / "rec")


def test_curve_without_cycle_time_names_its_line(tmp_path: Path) -> None:
    path = edited(tmp_path, ("%COUNT=3\n%CYCLETIME=6000\n", "%COUNT=3\n"))
    with pytest.raises(
        RecordingError, match=r"trace\.sco:19: curve 3 \(I nominal X\) has no %CYCLETIME= line"
    ):
        import_trace(path, tmp_path / "rec")


def test_time_column_that_goes_back(tmp_path: Path) -> None:
    path = edited(tmp_path, ("9000;1350", "3000;1350"))
    with pytest.raises(
        RecordingError, match=r"trace\.sco:37: time 3000 is not later than the row before"
    ):
        import_trace(path, tmp_path / "rec")


def test_garbage_row(tmp_path: Path) -> None:
    path = edited(tmp_path, ("6000;1300;50.125;2;5002;", "6000;1300;oops;2;5002;"))
    with pytest.raises(
        RecordingError, match=r"trace\.sco:36: curve 2 \(s actual X\): 'oops' is not a number"
    ):
        import_trace(path, tmp_path / "rec")


def test_row_with_too_few_cells(tmp_path: Path) -> None:
    path = edited(tmp_path, ("6000;1300;50.125;2;5002;", "6000;1300;"))
    with pytest.raises(
        RecordingError, match=r"trace\.sco:36: 2 cells, expected a time and 4 curve\(s\)"
    ):
        import_trace(path, tmp_path / "rec")


def test_text_before_the_data(tmp_path: Path) -> None:
    path = edited(tmp_path, ("%[CURVE 2]", "garbage\n%[CURVE 2]"))
    with pytest.raises(RecordingError, match=r"trace\.sco:12: 'garbage' before %\[DATA\]"):
        import_trace(path, tmp_path / "rec")
