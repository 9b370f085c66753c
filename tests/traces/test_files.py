"""The files people have: EPOS Studio exports (a preamble, an empty time header, a units row,
one file per speed and direction), several files into one recording, MATLAB files, and a
position without a velocity channel."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray
from typer.testing import CliRunner

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.reading import recording_gaps
from ncmeasure.cli import app
from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.recording import Recording, read_recording
from ncmeasure.traces import import_columns, import_trace, import_traces
from ncmeasure.traces.csv import export_csv
from ncmeasure.traces.derive import derive_velocity
from ncmeasure.traces.merge import CHUNK_ROWS
from tests.conftest import optional

runner = CliRunner()

#: A maxon EPOS2 on a 20 mm lead: velocity actual value averaged in motor rpm (x 20 mm/rev
#: into mm/min), current actual value averaged in mA; time in ms from the units row.
EPOS_MAP = """\
time = { column = 1 }
[channels]
X_velocity_mm_min = { column = "Velocity Actual Value Averaged", scale = 20 }
X_current_a = { column = "Current Actual Value Averaged" }
"""
EPOS_HEADER = ";Velocity Actual Value Averaged;Current Actual Value Averaged"
#: Friction of the synthetic axis, in motor current: Coulomb 0.8 A, viscous 0.1 mA per rpm.
COULOMB_MA, VISCOUS_MA_RPM = 800.0, 0.1


def epos_preamble(start: dt.datetime | None, period_ms: float, lines: int = 12) -> list[str]:
    """EPOS Studio's data recorder preamble: device, date, sampling period, channels."""
    rows = [
        "EPOS Studio Data Recorder Export",
        "Device Name;EPOS2 70/10",
        "Node Id;1",
        "Serial Number;0x6420012345",
        f"Date;{start:%Y-%m-%d %H:%M:%S}" if start else "Date;(not stored)",
        f"Sampling Period;{period_ms:g};ms",
        "Number of Samples;500",
        "Trigger Mode;Single",
        "Trigger Variable;Velocity Actual Value Averaged",
        "Channels;2",
        "Channel 1;Velocity Actual Value Averaged;rpm",
        "Channel 2;Current Actual Value Averaged;mA",
    ]
    return rows[:lines]


def epos_capture(
    speed_rpm: int, period_ms: float, seed: int, samples: int = 500
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A capture of one constant-speed move: standstill, ramp, steady, ramp, standstill;
    velocity in whole counts (1 rpm) with a count of noise, current in mA."""
    rng = np.random.default_rng(seed)
    t_ms = np.arange(samples) * period_ms
    ramp = 30
    profile = np.zeros(samples)
    profile[20 : 20 + ramp] = np.linspace(0, 1, ramp)
    profile[20 + ramp : samples - 20 - ramp] = 1
    profile[samples - 20 - ramp : samples - 20] = np.linspace(1, 0, ramp)
    v_rpm = np.round(speed_rpm * profile + rng.normal(0, 0.5, samples) * (profile > 0))
    moving = np.abs(v_rpm) > 0
    i_ma = np.where(
        moving, np.sign(v_rpm) * (COULOMB_MA + VISCOUS_MA_RPM * np.abs(v_rpm)), 0.0
    ) + rng.normal(0, 4, samples)
    return t_ms, v_rpm, np.round(i_ma, 1)


def write_epos(
    path: Path,
    speed_rpm: int,
    *,
    start: dt.datetime | None = None,
    period_ms: float = 10.0,
    seed: int = 0,
    preamble_lines: int = 12,
    current_unit: str = "mA",
) -> Path:
    t_ms, v_rpm, i_ma = epos_capture(speed_rpm, period_ms, seed)
    current = i_ma if current_unit == "mA" else i_ma / 17700.0 * 100  # % of 17.7 A
    rows = [*epos_preamble(start, period_ms, preamble_lines), EPOS_HEADER]
    rows.append(f"ms;rpm;{current_unit}")
    rows += [
        f"{t:g};{v:g};{c:.4g}".replace(".", ",")
        for t, v, c in zip(t_ms, v_rpm, current, strict=True)
    ]
    path.write_text("\r\n".join(rows) + "\r\n", encoding="cp1252")
    return path


def write_map(path: Path, text: str = EPOS_MAP) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


SPEEDS_RPM = (25, 50, 100, 200, 400)


def epos_folder(folder: Path, *, dated: bool = True) -> list[Path]:
    """One export per speed and direction, as EPOS Studio writes them, a minute apart."""
    folder.mkdir()
    start = dt.datetime(2024, 3, 5, 14, 0, 0)
    files = []
    for k, speed in enumerate(s * d for s in SPEEDS_RPM for d in (1, -1)):
        name = f"v{abs(speed)}_{'pos' if speed > 0 else 'neg'}.txt"
        when = start + dt.timedelta(minutes=k) if dated else None
        files.append(write_epos(folder / name, speed, start=when, seed=k))
    return files


# --- one EPOS export: preamble, empty time header, units row ---------------------------


def test_epos_export_reads_without_skip_lines(tmp_path: Path) -> None:
    data = write_epos(tmp_path / "v100_pos.txt", 100, start=dt.datetime(2024, 3, 5, 14, 22, 10))
    result = import_columns(data, tmp_path / "rec", write_map(tmp_path / "epos.toml"))
    rec = result.recording
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min")
    # the header is line 13, the units row line 14, the first sample line 15
    assert any(line.startswith("header at line 13") for line in result.report)
    assert any(line.startswith("units row at line 14") for line in result.report)
    assert "time_s [s]: x 0.001 from the units row's 'ms'" in result.report
    assert "X_current_a [A]: x 0.001 from the units row's 'mA'" in result.report
    t_ms, v_rpm, i_ma = epos_capture(100, 10.0, 0)
    np.testing.assert_allclose(rec.time_s, t_ms / 1000)
    np.testing.assert_allclose(rec.axis_signal("X", "velocity_mm_min"), v_rpm * 20)
    np.testing.assert_allclose(rec.axis_signal("X", "current_a"), i_ma / 1000)
    assert rec.meta.start_utc is not None and rec.meta.start_utc.startswith("2024-03-05T14:22:10")


@pytest.mark.parametrize("preamble", [10, 12])
def test_units_row_is_never_data(tmp_path: Path, preamble: int) -> None:
    data = write_epos(tmp_path / "x.txt", -50, preamble_lines=preamble)
    rec = import_columns(data, tmp_path / "rec", write_map(tmp_path / "m.toml")).recording
    assert len(rec) == 500


def test_percent_column_needs_a_scale(tmp_path: Path) -> None:
    data = write_epos(tmp_path / "x.txt", 100, current_unit="%")
    with pytest.raises(RecordingError) as info:
        import_columns(data, tmp_path / "rec", write_map(tmp_path / "m.toml"))
    assert info.value.message == (
        f"{data}:14: X_current_a [A]: the units row says '%', which the column map cannot "
        "convert; give channels.X_current_a.scale (the factor from '%' into the channel's unit)"
    )
    assert not (tmp_path / "rec").exists()
    # with the factor (% of the 17.7 A rated current) it reads
    mapping = write_map(
        tmp_path / "p.toml",
        EPOS_MAP.replace(
            'column = "Current Actual Value Averaged" }',
            'column = "Current Actual Value Averaged", scale = 0.177 }',
        ),
    )
    result = import_columns(data, tmp_path / "rec", mapping)
    _, _, i_ma = epos_capture(100, 10.0, 0)
    np.testing.assert_allclose(
        result.recording.axis_signal("X", "current_a"), i_ma / 1000, rtol=1e-3, atol=2e-3
    )
    assert any("'%'" in line and "units row" in line for line in result.report)


def test_units_row_checks_a_scale_the_map_gives(tmp_path: Path) -> None:
    data = write_epos(tmp_path / "x.txt", 100)
    mapping = write_map(
        tmp_path / "m.toml",
        EPOS_MAP.replace("time = { column = 1 }", "time = { column = 1, scale = 1 }"),
    )
    result = import_columns(data, tmp_path / "rec", mapping)
    assert (
        "time_s [s]: the units row says 'ms' (x 0.001), the column map's time.scale = 1 is used"
        in result.report
    )


def test_column_by_position_and_by_name(tmp_path: Path) -> None:
    data = write_epos(tmp_path / "x.txt", 100)
    mapping = write_map(
        tmp_path / "m.toml",
        "time = { column = 1 }\n[channels]\n"
        "X_velocity_mm_min = { column = 2, scale = 20 }\n"
        'X_current_a = { column = "Current Actual Value Averaged" }\n',
    )
    result = import_columns(data, tmp_path / "rec", mapping)
    assert (
        "X_velocity_mm_min [mm/min]: from column 2 ('Velocity Actual Value Averaged') (x 20)"
        in result.report
    )
    beyond = write_map(tmp_path / "b.toml", EPOS_MAP.replace("column = 1", "column = 4"))
    with pytest.raises(RecordingError, match=r"x.txt:13: column 4 of .*b.toml is beyond"):
        import_columns(data, tmp_path / "rec2", beyond)


def test_position_zero_is_not_a_column(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"time.column"):
        import_columns(
            write_epos(tmp_path / "x.txt", 100),
            tmp_path / "rec",
            write_map(tmp_path / "m.toml", EPOS_MAP.replace("column = 1", "column = 0")),
        )


def test_header_not_found_names_the_closest_line(tmp_path: Path) -> None:
    data = write_epos(tmp_path / "x.txt", 100)
    mapping = write_map(tmp_path / "m.toml", EPOS_MAP.replace('Averaged" }', 'Avg" }'))
    with pytest.raises(RecordingError) as info:
        import_columns(data, tmp_path / "rec", mapping)
    assert info.value.message == (
        f"{data}:13: column(s) named in {mapping} not in the header: 'Current Actual Value Avg'"
    )


# --- several files into one recording ----------------------------------------------------


def test_one_file_per_speed_and_direction_is_one_recording(
    tmp_path: Path, machine: MachineConfig
) -> None:
    files = epos_folder(tmp_path / "captures")
    result = import_traces(
        [tmp_path / "captures"],
        tmp_path / "rec",
        columns=write_map(tmp_path / "epos.toml"),
        machine=machine,
    )
    rec = Recording.open(tmp_path / "rec")
    assert len(rec) == 500 * len(files)
    assert (
        result.report[0]
        == "10 files, one segment each, each at its own start time (from the files' dates), "
        "in the order measured"
    )
    for k, file in enumerate(files):  # natural order: v25 before v100
        assert any(
            line.startswith(f"{file.name}: 500 samples at 10 ms, t = {60 * k:.6g}")
            for line in result.report
        )
    assert rec.meta.start_utc is not None and rec.meta.start_utc.startswith("2024-03-05T14:00:00")
    segments = [e for e in rec.events if e.kind == "info" and "segment" in e.details]
    assert [e.details["segment"] for e in segments] == [f.name for f in files]
    assert [e.time_s for e in segments] == [60.0 * k for k in range(len(files))]
    # the step into a file's segment is no lost sample
    assert recording_gaps(rec) == (0, 0, 0)
    # one analysable recording: a friction value at every speed and direction
    results = analyze(tmp_path / "rec", machine=machine)
    assert not any("lost" in w for w in results.axes["X"].warnings), results.axes["X"].warnings
    x = results.axes["X"]
    found = {
        round(point.velocity_mm_min)
        for position in x.positions
        for side in position.directions.values()
        if side is not None
        for point in side.points
    }
    assert found >= {s * 20 * d for s in SPEEDS_RPM for d in (1, -1)}, found


def test_files_without_dates_follow_each_other_with_a_gap(tmp_path: Path) -> None:
    epos_folder(tmp_path / "captures", dated=False)
    result = import_traces(
        [str(tmp_path / "captures" / "v*_pos.txt"), tmp_path / "captures" / "v25_neg.txt"],
        tmp_path / "rec",
        columns=write_map(tmp_path / "epos.toml"),
    )
    rec = Recording.open(tmp_path / "rec")
    assert result.report[0].startswith("6 files, one segment each, one after another with 1 s")
    starts = [e.time_s for e in rec.events if e.kind == "info"]
    assert starts[1] == pytest.approx(4.99 + 1.0)
    assert np.diff(rec.time_s).max() == pytest.approx(1.0)
    assert rec.meta.start_utc is None


def test_a_bad_file_names_itself_and_leaves_nothing(tmp_path: Path) -> None:
    files = epos_folder(tmp_path / "captures")
    lines = files[3].read_bytes().decode("cp1252").split("\r\n")
    lines[20] = "x;1;2"
    files[3].write_text("\r\n".join(lines), encoding="cp1252")
    with pytest.raises(RecordingError, match=rf"{files[3].name}:21: .*'x' is not a number"):
        import_traces(
            [tmp_path / "captures"], tmp_path / "rec", columns=write_map(tmp_path / "m.toml")
        )
    assert not (tmp_path / "rec").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_command_line_takes_a_folder_and_a_pattern(tmp_path: Path) -> None:
    epos_folder(tmp_path / "captures")
    mapping = write_map(tmp_path / "epos.toml")
    result = runner.invoke(
        app,
        [
            "import",
            str(tmp_path / "captures"),
            "--columns",
            str(mapping),
            "-o",
            str(tmp_path / "a"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "wrote" in result.stdout and "(5000 samples, 2 channels)" in result.stdout
    assert "v400_neg.txt: 500 samples" in result.stderr
    result = runner.invoke(
        app,
        [
            "import",
            str(tmp_path / "captures" / "*_neg.txt"),
            "--columns",
            str(mapping),
            "-o",
            str(tmp_path / "b"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "(2500 samples, 2 channels)" in result.stdout
    result = runner.invoke(
        app,
        [
            "import",
            str(tmp_path / "none*.txt"),
            "--columns",
            str(mapping),
            "-o",
            str(tmp_path / "c"),
        ],
    )
    assert result.exit_code == 2
    assert "the pattern matches no file" in result.stderr


def test_export_import_round_trip_still_exact(tmp_path: Path) -> None:
    write_epos(tmp_path / "x.txt", 100)
    rec = import_columns(
        tmp_path / "x.txt", tmp_path / "rec", write_map(tmp_path / "m.toml")
    ).recording
    export_csv(rec, tmp_path / "rec.csv")
    again = import_traces([tmp_path / "rec.csv"], tmp_path / "again").recording
    np.testing.assert_array_equal(again.time_s, rec.time_s)
    np.testing.assert_array_equal(again.values, rec.values)
    # several exports of ncmeasure join as well
    export_csv(rec, tmp_path / "rec2.csv")
    joined = import_traces(
        [tmp_path / "rec.csv", tmp_path / "rec2.csv"], tmp_path / "joined"
    ).recording
    assert len(joined) == 2 * len(rec)


# --- a position without a velocity channel -----------------------------------------------


def test_velocity_is_derived_from_the_position(tmp_path: Path) -> None:
    t = np.arange(0, 4, 0.01)
    x = 100 + 50 * np.sin(t)  # mm; velocity 50 cos(t) mm/s
    rows = ["t;pos;cur"] + [f"{a:.6f};{b:.9f};1.5" for a, b in zip(t, x, strict=True)]
    (tmp_path / "p.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    mapping = write_map(
        tmp_path / "m.toml",
        'time = { column = "t" }\n[channels]\nX_position_mm = { column = "pos" }\n'
        'X_current_a = { column = "cur" }\n',
    )
    result = import_trace(tmp_path / "p.csv", tmp_path / "rec", columns=mapping)
    assert (
        "X_velocity_mm_min [mm/min]: derived from X_position_mm (central differences on the "
        "sample times); the file has no velocity channel"
    ) in result.report
    rec = Recording.open(tmp_path / "rec")
    assert rec.channel_names == ("X_current_a", "X_velocity_mm_min", "X_position_mm")
    v = rec.axis_signal("X", "velocity_mm_min")
    np.testing.assert_allclose(v[1:-1], 50 * np.cos(t[1:-1]) * 60, rtol=0, atol=0.1)
    assert rec.meta.source == "import:columns"


def test_derived_velocity_matches_across_chunks(tmp_path: Path) -> None:
    t = np.cumsum(np.random.default_rng(1).uniform(0.005, 0.015, 3 * CHUNK_ROWS + 17))
    x = np.cumsum(np.random.default_rng(2).normal(0, 0.01, len(t)))
    (tmp_path / "p.csv").write_text(
        "t,x\n" + "".join(f"{a!r},{b!r}\n" for a, b in zip(t.tolist(), x.tolist(), strict=True)),
        encoding="utf-8",
    )
    mapping = write_map(
        tmp_path / "m.toml",
        'time = { column = "t" }\n[channels]\nX_position_mm = { column = "x" }\n',
    )
    rec = import_traces([tmp_path / "p.csv"], tmp_path / "rec", columns=mapping).recording
    np.testing.assert_allclose(
        rec.axis_signal("X", "velocity_mm_min"), derive_velocity(t, x), rtol=1e-12
    )


def test_derive_velocity_central_differences() -> None:
    t = np.array([0.0, 0.1, 0.3, 0.4])
    x = np.array([0.0, 1.0, 2.0, 4.0])
    np.testing.assert_allclose(derive_velocity(t, x), [600.0, 2 / 0.3 * 60, 3 / 0.3 * 60, 1200.0])
    assert np.isnan(derive_velocity(np.array([1.0]), np.array([2.0]))).all()


# --- MATLAB files ------------------------------------------------------------------------

MAT_MAP = """\
time = { column = "data.time", scale = 0.001 }
[channels]
X_velocity_mm_min = { column = "data.velocity", scale = 20 }
X_current_a = { column = "data.current", scale = 0.001 }
"""


def mat_vectors() -> dict[str, NDArray[np.float64]]:
    t_ms, v_rpm, i_ma = epos_capture(200, 6.4, 3)
    return {"time": t_ms, "velocity": v_rpm, "current": i_ma}


def check_mat(rec: Recording) -> None:
    vectors = mat_vectors()
    np.testing.assert_allclose(rec.time_s, vectors["time"] / 1000)
    np.testing.assert_allclose(rec.axis_signal("X", "velocity_mm_min"), vectors["velocity"] * 20)
    np.testing.assert_allclose(rec.axis_signal("X", "current_a"), vectors["current"] / 1000)


def test_matlab_v5(tmp_path: Path) -> None:
    from scipy.io import savemat

    vectors = mat_vectors()
    # MATLAB stores vectors as 1xN or Nx1 matrices: both read
    data = {
        "time": vectors["time"][:, None],
        "velocity": vectors["velocity"],
        "current": vectors["current"],
    }
    savemat(tmp_path / "run.mat", {"data": data, "note": "rig 2"})
    result = import_trace(
        tmp_path / "run.mat", tmp_path / "rec", columns=write_map(tmp_path / "m.toml", MAT_MAP)
    )
    check_mat(result.recording)
    assert "run.mat: MATLAB 5 file" in result.report
    assert "1 variable(s) not in the column map, not imported: 'note'" in result.report
    assert "X_current_a [A]: from variable 'data.current' (x 0.001)" in result.report
    # top-level vectors, a period instead of a time variable
    savemat(tmp_path / "flat.mat", {"v": vectors["velocity"], "i": vectors["current"]})
    flat = write_map(
        tmp_path / "flat.toml",
        'period_s = 0.0064\n[channels]\nX_velocity_mm_min = { column = "v", scale = 20 }\n'
        'X_current_a = { column = "i", scale = 0.001 }\n',
    )
    check_mat(import_columns(tmp_path / "flat.mat", tmp_path / "rec2", flat).recording)


def test_matlab_v73(tmp_path: Path) -> None:
    h5py = optional("h5py")
    vectors = mat_vectors()
    path = tmp_path / "run73.mat"
    with h5py.File(path, "w", userblock_size=512) as file:
        group = file.create_group("data")
        for name, values in vectors.items():
            group.create_dataset(name, data=values[None, :])  # MATLAB writes 1xN transposed
        file.create_dataset("fs", data=np.array([[156.25]]))
    with path.open("r+b") as file:
        file.write(
            b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Tue Mar  5 14:22:10 2024 "
            b"HDF5 schema 1.00 ."
        )
    result = import_trace(path, tmp_path / "rec", columns=write_map(tmp_path / "m.toml", MAT_MAP))
    check_mat(result.recording)
    assert "run73.mat: MATLAB 7.3 (HDF5) file" in result.report
    assert "1 variable(s) not in the column map, not imported: 'fs'" in result.report


def test_matlab_problems(tmp_path: Path) -> None:
    from scipy.io import savemat

    vectors = mat_vectors()
    savemat(
        tmp_path / "run.mat",
        {
            "data": {
                "time": vectors["time"],
                "velocity": vectors["velocity"][:-1],
                "current": vectors["current"],
            }
        },
    )
    mapping = write_map(tmp_path / "m.toml", MAT_MAP)
    with pytest.raises(
        RecordingError,
        match=r"the variables differ in length "
        r"\(.data.time.: 500, .data.current.: 500, .data.velocity.: 499\)",
    ):
        import_trace(tmp_path / "run.mat", tmp_path / "rec", columns=mapping)
    savemat(tmp_path / "other.mat", {"data": {"t": vectors["time"]}})
    with pytest.raises(RecordingError) as info:
        import_trace(tmp_path / "other.mat", tmp_path / "rec", columns=mapping)
    assert info.value.message == f"{tmp_path / 'other.mat'}: no variable 'data.time' (no 'time')"
    assert info.value.problems == ("the file has: data.t",)
    with pytest.raises(RecordingError, match="a MATLAB file: name its variables in a column map"):
        import_trace(tmp_path / "other.mat", tmp_path / "rec")
    positional = write_map(tmp_path / "p.toml", MAT_MAP.replace('"data.time"', "1"))
    with pytest.raises(ConfigError, match="not by position: time_s: column = 1"):
        import_trace(tmp_path / "other.mat", tmp_path / "rec", columns=positional)
    assert not (tmp_path / "rec").exists()


def test_matlab_v73_without_h5py_says_what_to_install(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    path = tmp_path / "run73.mat"
    path.write_bytes(b"MATLAB 7.3 MAT-file".ljust(512, b" ") + b"\x89HDF\r\n\x1a\n" + b"\0" * 64)
    monkeypatch.setitem(sys.modules, "h5py", None)  # import h5py raises ImportError
    with pytest.raises(RecordingError, match=r"needs h5py: pip install 'ncmeasure\[matlab\]'"):
        import_trace(path, tmp_path / "rec", columns=write_map(tmp_path / "m.toml", MAT_MAP))


def test_read_recording_of_a_join_is_complete(tmp_path: Path) -> None:
    epos_folder(tmp_path / "c")
    import_traces([tmp_path / "c"], tmp_path / "rec", columns=write_map(tmp_path / "m.toml"))
    rec = read_recording(tmp_path / "rec")
    assert rec.meta.status == "complete"
    assert not math.isnan(rec.meta.nominal_period_s)


# --- Parquet -----------------------------------------------------------------------------

PARQUET_MAP = """\
time = { column = "t" }
[channels]
X_velocity_mm_min = { column = "v", scale = 60 }
X_current_a = { column = 3 }
"""


def test_parquet_in_batches(tmp_path: Path) -> None:
    pa = optional("pyarrow")
    pq = optional("pyarrow.parquet")
    n = 2 * CHUNK_ROWS + 5
    t = np.arange(n) * 0.004
    v = np.sin(t)
    i = np.cos(t)
    table = pa.table({"t": t, "v": v, "i": i, "status": ["RUN"] * n})
    pq.write_table(table, tmp_path / "run.parquet", row_group_size=5000)
    result = import_trace(
        tmp_path / "run.parquet",
        tmp_path / "rec",
        columns=write_map(tmp_path / "m.toml", PARQUET_MAP),
    )
    rec = result.recording
    np.testing.assert_array_equal(rec.time_s, t)
    np.testing.assert_array_equal(rec.axis_signal("X", "velocity_mm_min"), v * 60)
    np.testing.assert_array_equal(rec.axis_signal("X", "current_a"), i)
    assert f"run.parquet: Parquet file, {n} rows, 4 column(s)" in result.report
    assert "1 column(s) not in the column map, not imported: 'status'" in result.report


def test_parquet_timestamps_give_times_and_the_start(tmp_path: Path) -> None:
    pa = optional("pyarrow")
    pq = optional("pyarrow.parquet")
    start = np.datetime64("2024-03-05T14:22:10", "ns")
    stamps = start + np.arange(4) * np.timedelta64(2, "ms")
    table = pa.table(
        {"t": pa.array(stamps, pa.timestamp("ns")), "v": [1.0, 2, 3, 4], "i": [0.5] * 4}
    )
    pq.write_table(table, tmp_path / "run.parquet")
    result = import_trace(
        tmp_path / "run.parquet",
        tmp_path / "rec",
        columns=write_map(tmp_path / "m.toml", PARQUET_MAP),
    )
    np.testing.assert_allclose(result.recording.time_s, [0, 0.002, 0.004, 0.006])
    assert result.meta.start_utc is not None
    assert result.meta.start_utc.startswith("2024-03-05T14:22:10")


def test_parquet_problems(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    pa = optional("pyarrow")
    pq = optional("pyarrow.parquet")
    pq.write_table(pa.table({"t": [0.0, 1.0], "v": ["a", "b"], "i": [1.0, 2.0]}), tmp_path / "x.pq")
    mapping = write_map(tmp_path / "m.toml", PARQUET_MAP)
    with pytest.raises(RecordingError, match=r"x.pq: column 'v' holds string, not numbers"):
        import_trace(tmp_path / "x.pq", tmp_path / "rec", columns=mapping)
    other = write_map(tmp_path / "o.toml", PARQUET_MAP.replace('"v"', '"speed"'))
    with pytest.raises(RecordingError, match=r"x.pq: no column 'speed'"):
        import_trace(tmp_path / "x.pq", tmp_path / "rec", columns=other)
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    with pytest.raises(RecordingError, match=r"needs pyarrow: pip install 'ncmeasure\[parquet\]'"):
        import_trace(tmp_path / "x.pq", tmp_path / "rec", columns=mapping)
    assert not (tmp_path / "rec").exists()
