"""Any delimited text file through a column map: layouts, conversions, bad maps, bad files."""

from __future__ import annotations

import json
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.recording import read_recording
from ncmeasure.traces import ColumnMap, import_columns, import_trace, load_column_map
from ncmeasure.traces.merge import CHUNK_ROWS

#: The data collector's export: no time column (100 ms), three significant digits,
#: velocities in mm/s, a timestamp string and a status word that are not numbers.
COLLECTOR_ROWS = [
    "Timestamp,X1_CurrentFeedback,X1_ActualVelocity,X1_ActualPosition,X1_CommandVelocity,Status",
    "2024-03-05 10:00:00.000,1.98E+02,1.50E+00,1.00E+02,1.50E+00,RUN",
    "2024-03-05 10:00:00.100,2.01E+02,1.51E+00,1.00E+02,1.50E+00,RUN",
    '2024-03-05 10:00:00.200,-1.23E+00,-2.50E+01,1.25E+02,-2.50E+01,"RUN, HOLD"',
    "2024-03-05 10:00:00.300,1.00E-03,0.00E+00,1.25E+02,0.00E+00,STOP",
]
COLLECTOR_MAP = """\
period_s = 0.1
[channels]
X_current_a = { column = "X1_CurrentFeedback" }
X_velocity_mm_min = { column = "X1_ActualVelocity", scale = 60 }
X_position_mm = { column = "X1_ActualPosition" }
X_velocity_cmd_mm_min = { column = "X1_CommandVelocity", scale = 60 }
"""
COLLECTOR_VALUES = [
    [198.0, 90.0, 100.0, 90.0],
    [201.0, 1.51 * 60, 100.0, 90.0],
    [-1.23, -1500.0, 125.0, -1500.0],
    [0.001, 0.0, 125.0, 0.0],
]

runner = CliRunner()


def write(path: Path, rows: list[str], newline: str = "\n", encoding: str = "utf-8") -> Path:
    path.write_bytes("".join(row + newline for row in rows).encode(encoding))
    return path


def write_map(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_data_collector_layout(tmp_path: Path, machine: MachineConfig) -> None:
    # A large feed drive: 198 A is a current its 60 A rated motor carries at a peak (the
    # example machine's 17.7 A motor could not: the import would leave it out).
    x = machine.axes[0].model_copy(update={"rated_current_a": 60.0})
    machine = machine.model_copy(update={"axes": [x, *machine.axes[1:]]})
    data = write(tmp_path / "collector.csv", COLLECTOR_ROWS)
    mapping = write_map(tmp_path / "collector.toml", COLLECTOR_MAP)
    result = import_columns(data, tmp_path / "rec", mapping, machine=machine)
    rec = result.recording
    assert rec.channel_names == (
        "X_current_a",
        "X_velocity_mm_min",
        "X_position_mm",
        "X_velocity_cmd_mm_min",
    )
    np.testing.assert_array_equal(rec.values, COLLECTOR_VALUES)
    assert rec.values[0, 0] == 198.0  # 1.98E+02 A
    assert rec.values[0, 1] == 90.0  # 1.5 mm/s x 60
    np.testing.assert_array_equal(rec.time_s, np.arange(4) * 0.1)
    assert rec.meta.nominal_period_s == 0.1
    assert rec.meta.source == "import:columns"
    assert [axis.name for axis in rec.meta.axes] == ["X"]  # --machine: axis data
    assert rec.meta.axes[0].screw_lead_mm == 20.0
    report = result.report
    assert "time_s [s]: no time column; row k is at k x 0.1 s" in report
    assert "X_velocity_mm_min [mm/min]: from column 'X1_ActualVelocity' (x 60)" in report
    assert "X_current_a [A]: from column 'X1_CurrentFeedback' (no conversion)" in report
    assert "2 column(s) not in the column map, not imported: 'Timestamp', 'Status'" in report
    assert "header at line 1: 6 columns separated by comma (detected)" in report
    meta = json.loads((tmp_path / "rec" / "meta.json").read_text(encoding="utf-8"))
    assert meta["link"]["format"] == "columns"
    assert meta["link"]["file"] == "collector.csv"
    assert meta["link"]["mapping"] == "collector.toml"
    assert meta["link"]["column_map"]["channels"]["X_velocity_mm_min"]["scale"] == 60
    assert meta["link"]["report"] == report


def test_import_trace_takes_a_column_map(tmp_path: Path) -> None:
    data = write(tmp_path / "collector.csv", COLLECTOR_ROWS)
    mapping = load_column_map(write_map(tmp_path / "m.toml", COLLECTOR_MAP))
    assert isinstance(mapping, ColumnMap)
    assert mapping.channels["X_velocity_mm_min"].scale == 60
    rec = import_trace(data, tmp_path / "rec", columns=mapping).recording
    np.testing.assert_array_equal(rec.values, COLLECTOR_VALUES)
    assert rec.meta.link["mapping"] is None  # a map given as a model has no file name


def test_semicolon_decimal_comma_time_column_and_preamble(tmp_path: Path) -> None:
    rows = [
        "\ufeffLogger export;v2.1",  # a BOM and two preamble lines
        "Machine;HMX-400",
        'Zeit [ms];Strom;"Geschw; Ist";Lage',
        "0;1,5;2,25;100,125",
        "100;1,75;-3;100,25",
        "200;2;4,5E+01;100,5",
    ]
    data = write(tmp_path / "de.csv", rows, "\r\n")
    mapping = write_map(
        tmp_path / "de.toml",
        """\
skip_lines = 2
time = { column = "Zeit [ms]", scale = 0.001, offset = 5.0 }
[channels]
Y_current_a = { column = "Strom" }
Y_velocity_mm_min = { column = "Geschw; Ist", scale = 60, offset = -1.5 }
""",
    )
    result = import_columns(data, tmp_path / "rec", mapping)
    rec = result.recording
    assert rec.channel_names == ("Y_current_a", "Y_velocity_mm_min")
    np.testing.assert_array_equal(rec.time_s, np.array([0.0, 100.0, 200.0]) * 0.001 + 5.0)
    np.testing.assert_array_equal(
        rec.values, [[1.5, 2.25 * 60 - 1.5], [1.75, -3 * 60 - 1.5], [2.0, 45.0 * 60 - 1.5]]
    )
    assert rec.meta.nominal_period_s == pytest.approx(0.1)
    assert "2 line(s) before the header skipped (skip_lines)" in result.report
    assert "header at line 3: 4 columns separated by semicolon (detected)" in result.report
    assert "time_s [s]: from column 'Zeit [ms]' (x 0.001 + 5)" in result.report
    assert "Y_velocity_mm_min [mm/min]: from column 'Geschw; Ist' (x 60 - 1.5)" in result.report
    assert "1 column(s) not in the column map, not imported: 'Lage'" in result.report
    assert "numbers use a decimal comma (detected)" in result.report


def test_tab_separated(tmp_path: Path) -> None:
    rows = ["t\tZ_position_mm\tcomment", "0.5\t-10.25\tstart here", "1.5\t-10.5\t"]
    data = write(tmp_path / "tab.txt", rows)
    mapping = write_map(
        tmp_path / "tab.toml",
        '[time]\ncolumn = "t"\n[channels]\nZ_position_mm = { column = "Z_position_mm" }\n',
    )
    result = import_columns(data, tmp_path / "rec", mapping)
    np.testing.assert_array_equal(result.recording.time_s, [0.5, 1.5])
    np.testing.assert_array_equal(result.recording.column("Z_position_mm"), [-10.25, -10.5])
    # no velocity channel: derived from the position (mm/s x 60)
    np.testing.assert_array_equal(result.recording.column("Z_velocity_mm_min"), [-15.0, -15.0])
    assert result.recording.meta.nominal_period_s == 1.0
    assert "header at line 1: 3 columns separated by tab (detected)" in result.report


def test_forced_delimiter_and_decimal(tmp_path: Path) -> None:
    # Every value is an integer, so nothing shows the decimal mark: the map says it.
    data = write(tmp_path / "f.csv", ["a;b", "1;2", "3;4"])
    mapping = write_map(
        tmp_path / "f.toml",
        'period_s = 0.5\ndelimiter = ";"\ndecimal = ","\n'
        '[channels]\nX_current_a = { column = "b" }\n',
    )
    result = import_columns(data, tmp_path / "rec", mapping)
    np.testing.assert_array_equal(result.recording.values, [[2.0], [4.0]])
    assert "header at line 1: 2 columns separated by semicolon (from the column map)" in (
        result.report
    )
    assert "numbers use a decimal comma (from the column map)" in result.report


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"], ids=["LF", "CRLF", "CR"])
def test_line_endings(tmp_path: Path, newline: str) -> None:
    data = write(tmp_path / "collector.csv", COLLECTOR_ROWS, newline)
    mapping = write_map(tmp_path / "m.toml", COLLECTOR_MAP)
    rec = import_columns(data, tmp_path / "rec", mapping).recording
    np.testing.assert_array_equal(rec.values, COLLECTOR_VALUES)
    np.testing.assert_array_equal(rec.time_s, np.arange(4) * 0.1)
    # and the line numbers of errors count the same lines
    bad = write(
        tmp_path / "bad.csv",
        [*COLLECTOR_ROWS[:3], COLLECTOR_ROWS[3].replace("1.25E+02", "x")],
        newline,
    )
    with pytest.raises(RecordingError, match=r"bad\.csv:4: column 'X1_ActualPosition': 'x'"):
        import_columns(bad, tmp_path / "rec2", mapping)


def test_empty_cells_become_nan_and_are_counted(tmp_path: Path) -> None:
    rows = [COLLECTOR_ROWS[0]]
    rows += [r.replace(",1.00E+02,", ",,").replace(",1.25E+02,", ", ,") for r in COLLECTOR_ROWS[1:]]
    data = write(tmp_path / "gaps.csv", rows)
    result = import_columns(data, tmp_path / "rec", write_map(tmp_path / "m.toml", COLLECTOR_MAP))
    position = result.recording.column("X_position_mm")
    assert np.isnan(position).all()
    np.testing.assert_array_equal(
        result.recording.column("X_current_a"), [198.0, 201.0, -1.23, 0.001]
    )
    assert (
        "X_position_mm: 4 empty cell(s) in column 'X1_ActualPosition' stored as NaN; "
        f"first at {data}:2" in result.report
    )


def test_rows_go_to_the_recording_in_chunks_with_bounded_memory(tmp_path: Path) -> None:
    rows = 150_000
    path = tmp_path / "large.csv"
    with path.open("w", encoding="utf-8") as file:
        file.write("stamp,I,v\n")
        for k in range(rows):
            file.write(f"2024-03-05T10:00:{k},{(k % 1000) / 8!r},{k / 16!r}\n")
    size = path.stat().st_size
    mapping = write_map(
        tmp_path / "m.toml",
        'period_s = 0.001\n[channels]\nX_current_a = { column = "I" }\n'
        'X_velocity_mm_min = { column = "v", scale = 60 }\n',
    )
    calls: list[tuple[int, int]] = []

    def progress(done: int, total: int) -> None:
        assert total == size
        calls.append((done, tracemalloc.get_traced_memory()[0]))

    tracemalloc.start()
    try:
        result = import_columns(path, tmp_path / "rec", mapping, progress=progress)
    finally:
        tracemalloc.stop()
    during = [memory for done, memory in calls if done < size]
    assert len(during) >= 3  # called while reading, not only at the end
    assert max(during) < 4 << 20  # one chunk of rows, not the file (> 5 MiB)
    assert size > 5 << 20
    assert calls[-1][0] == size
    rec = result.recording
    k = np.arange(rows)
    assert rows > 10 * CHUNK_ROWS
    np.testing.assert_array_equal(rec.time_s, k * 0.001)
    np.testing.assert_array_equal(rec.column("X_current_a"), (k % 1000) / 8)
    np.testing.assert_array_equal(rec.column("X_velocity_mm_min"), k / 16 * 60)


def test_time_that_does_not_increase_names_the_line(tmp_path: Path) -> None:
    # the bad time lies in the second chunk: line numbers carry across chunks
    lines = ["t,I"] + [f"{k},1" for k in range(CHUNK_ROWS + 10)]
    lines[CHUNK_ROWS + 5] = lines[CHUNK_ROWS + 4]
    data = write(tmp_path / "t.csv", lines)
    mapping = write_map(
        tmp_path / "m.toml",
        'time = { column = "t", scale = 0.001 }\n[channels]\nX_current_a = { column = "I" }\n',
    )
    with pytest.raises(RecordingError) as info:
        import_columns(data, tmp_path / "rec", mapping)
    line = CHUNK_ROWS + 6
    assert str(info.value) == (
        f"{data}:{line}: time_s {(CHUNK_ROWS + 3) * 0.001!r} is not later than the row before "
        f"({(CHUNK_ROWS + 3) * 0.001!r}); times must increase strictly"
    )
    assert not (tmp_path / "rec").exists()  # the first chunk was written, then removed


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        (
            [*COLLECTOR_ROWS[:2], COLLECTOR_ROWS[2].replace("2.01E+02", "n/a")],
            r"c\.csv:3: column 'X1_CurrentFeedback': 'n/a' is not a number$",
        ),
        (
            [*COLLECTOR_ROWS[:2], COLLECTOR_ROWS[2].replace("1.51E+00", "1,51E+00")],
            r"c\.csv:3: 7 cells, the header \(line 1\) has 6 \(a decimal comma in a "
            r"comma-separated file\?\)",
        ),
        (
            [*COLLECTOR_ROWS[:2], "2024-03-05 10:00:00.100,2.01E+02"],
            r"c\.csv:3: 2 cell\(s\); column 'X1_ActualVelocity' is cell 3 of 6",
        ),
        (COLLECTOR_ROWS[:1], r"c\.csv: no data rows after the header \(line 1\)"),
        ([], r"c\.csv: the file is empty"),
    ],
    ids=["not-a-number", "decimal-comma", "short-row", "no-rows", "empty"],
)
def test_bad_data_file(tmp_path: Path, rows: list[str], message: str) -> None:
    data = write(tmp_path / "c.csv", rows)
    with pytest.raises(RecordingError, match=message):
        import_columns(data, tmp_path / "rec", write_map(tmp_path / "m.toml", COLLECTOR_MAP))
    assert not (tmp_path / "rec").exists()


def test_a_quote_that_is_never_closed(tmp_path: Path) -> None:
    # the csv module joins every following line into one cell until its field limit
    rows = [*COLLECTOR_ROWS[:2], COLLECTOR_ROWS[2].replace(",RUN", ',"RUN')]
    rows += [COLLECTOR_ROWS[2]] * 4000
    data = write(tmp_path / "c.csv", rows)
    with pytest.raises(RecordingError) as info:
        import_columns(data, tmp_path / "rec", write_map(tmp_path / "m.toml", COLLECTOR_MAP))
    assert str(info.value).startswith(f"{data}:")
    assert "cannot be split into cells (field larger than field limit" in str(info.value)
    assert 'a quote " that is never closed' in str(info.value)
    assert not (tmp_path / "rec").exists()


def test_decimal_mark_written_the_other_way(tmp_path: Path) -> None:
    data = write(tmp_path / "c.csv", ["a;b", "1;2,5", "2;3.5"])
    mapping = write_map(
        tmp_path / "m.toml", 'period_s = 1\n[channels]\nX_current_a = { column = "b" }\n'
    )
    with pytest.raises(
        RecordingError,
        match=r"c\.csv:3: column 'b': '3\.5' is not a number \('3\.5' has a decimal point",
    ):
        import_columns(data, tmp_path / "rec", mapping)


def test_single_row_with_a_time_column(tmp_path: Path) -> None:
    data = write(tmp_path / "c.csv", ["t,I", "0,1"])
    mapping = write_map(
        tmp_path / "m.toml", '[time]\ncolumn = "t"\n[channels]\nX_current_a = { column = "I" }\n'
    )
    with pytest.raises(
        RecordingError, match="a single data row; the sample period needs at least two rows"
    ):
        import_columns(data, tmp_path / "rec", mapping)


def test_missing_column_names_it_and_lists_the_header(tmp_path: Path) -> None:
    data = write(tmp_path / "c.csv", COLLECTOR_ROWS)
    mapping = write_map(tmp_path / "m.toml", COLLECTOR_MAP.replace("X1_ActualPosition", "X1_Pos"))
    with pytest.raises(RecordingError) as info:
        import_columns(data, tmp_path / "rec", mapping)
    assert (
        info.value.message == f"{data}:1: column(s) named in {mapping} not in the header: 'X1_Pos'"
    )
    assert info.value.problems[0] == (
        "the header has: 'Timestamp', 'X1_CurrentFeedback', 'X1_ActualVelocity', "
        "'X1_ActualPosition', 'X1_CommandVelocity', 'Status'"
    )
    assert "no line of the first 5 holds every named column" in info.value.problems[1]
    assert not (tmp_path / "rec").exists()


@pytest.mark.parametrize(
    ("text", "problems"),
    [
        (
            COLLECTOR_MAP.replace("X_position_mm", "X_pos_mm"),
            ["channels.X_pos_mm: X_pos_mm is not an ncmeasure channel name: <AXIS>_<signal>"],
        ),
        (
            COLLECTOR_MAP.replace("period_s = 0.1", 'period_s = 0.1\ntime = { column = "t" }'),
            ["time: give either period_s or time, not both"],
        ),
        (
            COLLECTOR_MAP.replace("period_s = 0.1", ""),
            ["time: the map needs a time base: period_s = <seconds>"],
        ),
        (
            COLLECTOR_MAP.replace("scale = 60 }", "scale = 0 }", 1),
            ["channels.X_velocity_mm_min.scale: must not be 0"],
        ),
        (COLLECTOR_MAP.replace("0.1", "0"), ["period_s: Input should be greater than 0"]),
        (COLLECTOR_MAP.replace("0.1", "inf"), ["period_s: Input should be a finite number"]),
        (
            COLLECTOR_MAP.replace('"X1_CurrentFeedback" }', '"X1_CurrentFeedback", scal = 2 }'),
            ["channels.X_current_a.scal: unknown key"],
        ),
        ("seperator = ';'\n" + COLLECTOR_MAP, ["seperator: unknown key"]),
        (
            COLLECTOR_MAP.replace(
                "period_s = 0.1", 'period_s = 0.1\ndelimiter = ","\ndecimal = ","'
            ),
            ["decimal: a decimal comma does not work with delimiter = ','"],
        ),
        ("period_s = 0.1\n[channels]\n", ["channels: Dictionary should have at least 1 item"]),
    ],
    ids=[
        "unknown-channel",
        "period-and-time",
        "no-time-base",
        "scale-0",
        "period-0",
        "period-inf",
        "unknown-key-in-channel",
        "unknown-key",
        "decimal-comma-with-comma",
        "no-channels",
    ],
)
def test_bad_column_map(tmp_path: Path, text: str, problems: list[str]) -> None:
    path = write_map(tmp_path / "MAP.toml", text)
    with pytest.raises(ConfigError) as info:
        load_column_map(path)
    assert info.value.message == f"{path} is not a valid column map"
    assert len(info.value.problems) == len(problems)
    for line, expected in zip(info.value.problems, problems, strict=True):
        assert line.startswith(f"{path}: {expected}"), line


def test_column_map_file_problems(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"none\.toml: no such file"):
        load_column_map(tmp_path / "none.toml")
    with pytest.raises(ConfigError, match=r"broken\.toml: invalid TOML"):
        load_column_map(write_map(tmp_path / "broken.toml", "period_s = [\n"))


def test_axis_the_machine_does_not_have(tmp_path: Path, machine: MachineConfig) -> None:
    data = write(tmp_path / "c.csv", COLLECTOR_ROWS)
    mapping = write_map(
        tmp_path / "m.toml", COLLECTOR_MAP.replace("X_position_mm", "W_position_mm")
    )
    with pytest.raises(ConfigError) as info:
        import_columns(data, tmp_path / "rec", mapping, machine=machine)
    assert list(info.value.problems) == [
        f"{mapping}: channels.W_position_mm: axis W is not an axis of machine "
        f"{machine.machine.name!r} (X, Y, Z)"
    ]


def test_format_and_axis_names_do_not_combine_with_a_column_map(tmp_path: Path) -> None:
    data = write(tmp_path / "c.csv", COLLECTOR_ROWS)
    mapping = write_map(tmp_path / "m.toml", COLLECTOR_MAP)
    with pytest.raises(ConfigError, match="a column map and format 'csv' exclude each other"):
        import_trace(data, tmp_path / "rec", format="csv", columns=mapping)
    with pytest.raises(ConfigError, match="axis_names does not apply with a column map"):
        import_trace(data, tmp_path / "rec", axis_names={"1": "X"}, columns=mapping)
    with pytest.raises(ConfigError, match="the columns format needs a column map"):
        import_trace(data, tmp_path / "rec", format="columns")


def test_command_line(tmp_path: Path) -> None:
    data = write(tmp_path / "collector.csv", COLLECTOR_ROWS)
    mapping = write_map(tmp_path / "map.toml", COLLECTOR_MAP)
    bad_map = write_map(tmp_path / "bad.toml", COLLECTOR_MAP.replace("scale = 60", "scale = 0"))
    missing = write_map(tmp_path / "missing.toml", COLLECTOR_MAP.replace("X1_Actual", "X2_Actual"))
    out = tmp_path / "run"

    def run(*args: str | Path) -> tuple[int, str]:
        result = runner.invoke(app, [str(a) for a in args])
        return result.exit_code, result.stderr

    for args, message in [
        ((data, "--columns", bad_map), "bad.toml: channels.X_velocity_mm_min.scale: must not be 0"),
        (
            (data, "--columns", missing),
            "not in the header: 'X2_ActualVelocity', 'X2_ActualPosition'",
        ),
        ((data, "--columns", mapping, "--format", "csv"), "exclude each other"),
        ((data, "--columns", mapping, "--axis", "1=X"), "axis_names does not apply"),
        ((tmp_path / "none.csv", "--columns", mapping), "none.csv: no such file"),
    ]:
        code, err = run("import", *args, "-o", out)
        assert code == 2, err
        assert message in err
        assert "Traceback" not in err
        assert not out.exists()

    result = runner.invoke(app, ["import", str(data), "--columns", str(mapping), "-o", str(out)])
    assert result.exit_code == 0, result.stderr
    assert f"wrote {out} (4 samples, 4 channels)" in result.stdout
    assert "X_velocity_mm_min [mm/min]: from column 'X1_ActualVelocity' (x 60)" in result.stderr
    assert "not imported: 'Timestamp', 'Status'" in result.stderr
    rec = read_recording(out)
    np.testing.assert_array_equal(rec.values, COLLECTOR_VALUES)
    assert math.isclose(rec.meta.nominal_period_s, 0.1)
