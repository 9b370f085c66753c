"""The importer API: format detection, the generic CSV, axis names, progress, the target."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.traces import FORMATS, TraceImport, detect_format, import_trace
from tests.traces.conftest import FIXTURES

DETECTED = {
    "sinumerik_trace.xml": "sinumerik-xml",
    "sinumerik_semicolon.csv": "sinumerik-csv",
    "sinumerik_comma.csv": "sinumerik-csv",
    "sinumerik_spaces.csv": "sinumerik-csv",
    "twincat_per_channel.csv": "twincat-csv",
    "twincat_shared.csv": "twincat-csv",
    "tncscope.sco": "tncscope",
    "recording_export.csv": "csv",
}


def test_formats() -> None:
    assert FORMATS == (
        "sinumerik-xml",
        "sinumerik-csv",
        "twincat-csv",
        "tncscope",
        "csv",
        "can-log",
    )
    # every text format by its content; a CAN log by its ending (tests/traces/test_canlog.py)
    assert set(DETECTED.values()) == set(FORMATS) - {"can-log"}


@pytest.mark.parametrize(("name", "expected"), sorted(DETECTED.items()))
def test_every_format_is_detected_from_its_content(
    tmp_path: Path, name: str, expected: str
) -> None:
    # under a neutral name: the content decides, not the extension
    path = tmp_path / "trace.dat"
    path.write_bytes((FIXTURES / name).read_bytes())
    assert detect_format(path) == expected


@pytest.mark.parametrize("name", sorted(DETECTED))
def test_every_fixture_imports_with_the_detected_format(
    tmp_path: Path, machine: MachineConfig, name: str
) -> None:
    result = import_trace(FIXTURES / name, tmp_path / "rec", machine=machine)
    assert isinstance(result, TraceImport)
    assert result.recording.meta.source == f"import:{DETECTED[name]}"
    assert len(result.recording) >= 3
    assert np.all(np.diff(result.recording.time_s) > 0)
    assert result.recording.time_s.dtype == np.float64
    assert result.report


@pytest.mark.parametrize("name", sorted(n for n in DETECTED if not n.endswith(".xml")))
@pytest.mark.parametrize("newline", [b"\r\n", b"\r"], ids=["CRLF", "CR"])
def test_text_fixtures_read_the_same_with_any_line_ending(
    tmp_path: Path, machine: MachineConfig, name: str, newline: bytes
) -> None:
    lines = (FIXTURES / name).read_bytes().splitlines()
    assert len(lines) > 3
    path = tmp_path / name
    path.write_bytes(b"".join(line + newline for line in lines))
    expected = import_trace(FIXTURES / name, tmp_path / "lf", machine=machine).recording
    result = import_trace(path, tmp_path / "other", machine=machine).recording
    np.testing.assert_array_equal(result.time_s, expected.time_s)
    np.testing.assert_array_equal(result.values, expected.values)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "the file is empty"),
        (b"\x00\x01\x02binary", "a binary file"),
        (b'<?xml version="1.0"?><svg/>', "without a <traceSession> element"),
        (b"a,b,c\n1,2,3\n", "the trace format is not recognised"),
    ],
)
def test_unknown_content(tmp_path: Path, content: bytes, message: str) -> None:
    path = tmp_path / "x.txt"
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=message):
        detect_format(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="no such file"):
        detect_format(tmp_path / "missing.xml")
    with pytest.raises(RecordingError, match="no such file"):
        import_trace(tmp_path / "missing.xml", tmp_path / "rec")


def test_generic_csv_is_the_recording_importer(tmp_path: Path, machine: MachineConfig) -> None:
    calls: list[tuple[int, int]] = []
    result = import_trace(
        FIXTURES / "recording_export.csv",
        tmp_path / "rec",
        machine=machine,
        progress=lambda a, b: calls.append((a, b)),
    )
    rec = result.recording
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min", "X_position_mm")
    np.testing.assert_array_equal(
        rec.values, [[1.5, 600, 100], [1.75, 1200, 100], [2, 1800, 100.5]]
    )
    assert rec.meta.source == "import:csv"
    assert (
        result.report[0]
        == "X_current_a [A]: from column X_current_a (ncmeasure CSV, no conversion)"
    )
    size = (FIXTURES / "recording_export.csv").stat().st_size
    assert calls == [(size, size)]


def test_axis_names_do_not_apply_to_the_generic_csv(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="axis_names does not apply to the csv format"):
        import_trace(FIXTURES / "recording_export.csv", tmp_path / "rec", axis_names={"X": "Y"})


def test_unknown_format_name(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown trace format 'fanuc'"):
        import_trace(FIXTURES / "tncscope.sco", tmp_path / "rec", format="fanuc")


def test_explicit_format_that_does_not_fit(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="not a TwinCAT Scope export"):
        import_trace(FIXTURES / "tncscope.sco", tmp_path / "rec", format="twincat-csv")
    assert not (tmp_path / "rec").exists()


@pytest.mark.parametrize(
    ("axis_names", "problem"),
    [
        ({"1": "x"}, "'x' is not an axis name"),
        ({"1": "W"}, "W is not an axis of the machine (X, Y, Z)"),
        ({"1": "X", "2": "X"}, "more than one controller axis is mapped to X"),
    ],
)
def test_axis_names_that_do_not_fit(
    tmp_path: Path, machine: MachineConfig, axis_names: dict[str, str], problem: str
) -> None:
    with pytest.raises(ConfigError) as info:
        import_trace(
            FIXTURES / "sinumerik_trace.xml",
            tmp_path / "rec",
            machine=machine,
            axis_names=axis_names,
        )
    assert any(problem in line for line in info.value.problems)
    assert not (tmp_path / "rec").exists()


def test_axis_names_key_not_in_the_trace_is_reported(tmp_path: Path) -> None:
    result = import_trace(
        FIXTURES / "tncscope.sco", tmp_path / "rec", axis_names={"X": "X1", "Y": "Y1"}
    )
    assert result.recording.axes == ("X1",)
    assert "axis_names: controller axis 'Y' does not appear in the trace" in result.report


def test_more_controller_axes_than_machine_axes(tmp_path: Path, machine: MachineConfig) -> None:
    one_axis = machine.model_copy(update={"axes": machine.axes[:1]})
    result = import_trace(FIXTURES / "sinumerik_trace.xml", tmp_path / "rec", machine=one_axis)
    assert result.recording.axes == ("X",)
    assert (
        "controller axis 2: not imported (the machine file has no further axis; pass axis_names)"
        in result.report
    )


def test_target_that_is_not_empty_is_left_alone(tmp_path: Path) -> None:
    target = tmp_path / "rec"
    target.mkdir()
    (target / "notes.txt").write_text("keep me", encoding="utf-8")
    for name in DETECTED:
        with pytest.raises(RecordingError, match="directory is not empty"):
            import_trace(FIXTURES / name, target)
    assert [p.name for p in target.iterdir()] == ["notes.txt"]
    assert (target / "notes.txt").read_text(encoding="utf-8") == "keep me"


@pytest.mark.parametrize(
    "name", ["sinumerik_trace.xml", "twincat_shared.csv", "tncscope.sco", "sinumerik_comma.csv"]
)
def test_progress_ends_at_the_file_size(tmp_path: Path, name: str) -> None:
    calls: list[tuple[int, int]] = []
    import_trace(FIXTURES / name, tmp_path / "rec", progress=lambda a, b: calls.append((a, b)))
    size = (FIXTURES / name).stat().st_size
    assert calls, "progress was never called"
    assert calls[-1] == (size, size)
    assert [a for a, _ in calls] == sorted(a for a, _ in calls)


@pytest.mark.parametrize(
    ("name", "old", "new", "channel"),
    [
        ("recording_export.csv", "0.001,1.75,", "0.001,-999999,", "X_current_a"),
        ("sinumerik_trace.xml", 'f1="1.75"', 'f1="-999999"', "X_current_a"),
        ("sinumerik_trace.xml", 'f1="1.75"', 'f1="99999999"', "X_current_a"),
    ],
)
def test_no_value_codes_are_left_out_of_every_import(
    tmp_path: Path, machine: MachineConfig, name: str, old: str, new: str, channel: str
) -> None:
    """A logger writes −999999 (or another row of nines) where it has no value: never a
    measurement. (9.9E37 and larger codes a Sinumerik trace already marks invalid.)"""
    text = (FIXTURES / name).read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    result = import_trace(path, tmp_path / "rec", machine=machine)
    values = result.recording.column(channel)
    assert np.isnan(values).sum() >= 1
    assert np.nanmin(np.abs(values)) < 1000
    lines = [line for line in result.report if line.startswith(f"{channel}: 1 value(s)")]
    assert len(lines) == 1, result.report
    assert "not physically possible" in lines[0]
    assert result.recording.meta.link["implausible"] == {channel: 1}


def test_a_current_beyond_ten_times_the_rated_current_is_not_real(
    tmp_path: Path, make_config: Callable[..., MachineConfig]
) -> None:
    machine = make_config()
    rated = machine.axes[0].rated_current_a
    assert rated is not None
    text = (FIXTURES / "recording_export.csv").read_text(encoding="utf-8")
    path = tmp_path / "x.csv"
    path.write_text(text.replace("0.001,1.75,", f"0.001,{11 * rated},", 1), encoding="utf-8")
    result = import_trace(path, tmp_path / "rec", machine=machine)
    assert np.isnan(result.recording.column("X_current_a")).sum() == 1
    assert any(f"beyond ±{10 * rated:g}" in line for line in result.report)
