"""ncmeasure's own exchange formats: a recording as CSV and as MDF4, and back, bit-exact."""

from __future__ import annotations

import datetime as dt
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import DependencyError, RecordingError
from ncmeasure.recording import Recording, RecordingWriter
from ncmeasure.samples import Channel, LinkEvent, SampleBlock
from ncmeasure.traces import csv as csv_module
from ncmeasure.traces.csv import export_csv, import_csv
from ncmeasure.traces.mdf4 import export_mdf4, import_mdf4
from tests.conftest import optional
from tests.test_recording import ALL_SIGNALS, LINK, FullDisk, same_bits, write_frames

Make = Callable[..., MachineConfig]

# --- CSV -------------------------------------------------------------------------------------

AWKWARD = [
    0.1,
    1e-300,
    -0.0,
    0.0,
    5e-324,  # the smallest subnormal
    -2.2250738585072014e-308,
    1 / 3,
    123.45678912345679,
    -99.99999999999999,  # inside every channel's range, also the example machine's
    np.nan,
]
"""Floats that must survive the CSV round trip bit for bit (every one a possible sample)."""

IMPOSSIBLE = [1.7976931348623157e308, -1e22, 2**53 + 1.0, np.inf, -np.inf, 1e16, -999999.0]
"""Values no drive reports: an import leaves them out (NaN) and counts them."""


def awkward_recording(
    directory: Path, rows: int = 500, extremes: list[float] | None = None
) -> Recording:
    rng = np.random.default_rng(7)
    channels = ALL_SIGNALS
    time_s = np.cumsum(rng.uniform(0.0009, 0.0011, rows)) + 1e-7
    values = rng.standard_normal((rows, len(channels))) * 10.0 ** rng.integers(-300, 2, (rows, 1))
    values[: len(AWKWARD), 0] = AWKWARD
    values[: len(AWKWARD), -1] = AWKWARD[::-1]
    if extremes:
        values[len(AWKWARD) : len(AWKWARD) + len(extremes), 1] = extremes
    with RecordingWriter.create(directory, channels, nominal_period_s=0.001) as writer:
        writer.append(SampleBlock(time_s[:100], values[:100]))
        writer.append(SampleBlock(time_s[100:], values[100:]))
    return Recording.open(directory)


def test_export_never_writes_through_a_planted_temporary_file(tmp_path: Path) -> None:
    """A symlink at the old temporary name out.csv.tmp does not redirect the export."""
    write_frames(tmp_path / "r", frames=2, rows_per_frame=5)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me", encoding="utf-8")
    (tmp_path / "out.csv.tmp").symlink_to(victim)
    export_csv(tmp_path / "r", tmp_path / "out.csv")
    assert victim.read_text(encoding="utf-8") == "keep me"
    assert (tmp_path / "out.csv.tmp").is_symlink()
    assert len((tmp_path / "out.csv").read_text(encoding="utf-8").splitlines()) == 11
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["out.csv", "out.csv.tmp", "r", "victim.txt"]


def test_csv_import_leaves_out_what_no_drive_reports(tmp_path: Path) -> None:
    original = awkward_recording(tmp_path / "original", extremes=IMPOSSIBLE)
    copy = import_csv(export_csv(original, tmp_path / "out.csv"), tmp_path / "copy")
    rows = slice(len(AWKWARD), len(AWKWARD) + len(IMPOSSIBLE))
    assert np.isnan(copy.values[rows, 1]).all()
    untouched = np.ones(len(copy), dtype=bool)
    untouched[rows] = False
    assert same_bits(copy.values[untouched], original.values[untouched])
    name = ALL_SIGNALS[1].name
    assert copy.meta.link["implausible"] == {name: len(IMPOSSIBLE)}
    (line,) = copy.meta.link["report"]
    assert line.startswith(f"{name}: {len(IMPOSSIBLE)} value(s) left out as not physically")


def test_csv_round_trip_is_bit_exact(tmp_path: Path, make_config: Make) -> None:
    original = awkward_recording(tmp_path / "original")
    csv_path = export_csv(original, tmp_path / "out.csv")
    lines = csv_path.read_text(encoding="utf-8").splitlines()
    assert lines[0] == "time_s," + ",".join(c.name for c in ALL_SIGNALS)
    assert "X_velocity_cmd_mm_min" in lines[0] and "Z_marker" in lines[0]
    first_column = [line.split(",")[1] for line in lines[1 : 1 + len(AWKWARD)]]
    assert first_column[:4] == ["0.1", "1e-300", "-0.0", "0.0"]
    assert len(lines) == 1 + len(original)

    config = make_config()
    copy = import_csv(csv_path, tmp_path / "copy", machine=config)
    assert same_bits(copy.time_s, original.time_s)
    assert same_bits(copy.values, original.values)
    assert copy.channels == original.channels
    assert [c.unit for c in copy.channels][:5] == ["A", "mm/min", "mm", "mm/min", "1"]
    assert copy.meta.source == "import:csv"
    assert copy.meta.machine == config.machine.name
    assert [a.name for a in copy.meta.axes] == ["X", "Y", "Z"]
    assert copy.meta.nominal_period_s == float(np.median(np.diff(original.time_s)))
    assert copy.meta.status == "complete"
    assert copy.problems == []
    again = export_csv(copy, tmp_path / "again.csv")  # and the text is stable
    assert again.read_bytes() == csv_path.read_bytes()


def test_csv_import_in_chunks_with_a_given_period(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(csv_module, "_BLOCK_CHARS", 500)
    original = awkward_recording(tmp_path / "original", rows=100)
    csv_path = export_csv(tmp_path / "original", tmp_path / "out.csv")  # a directory works too
    copy = import_csv(csv_path, tmp_path / "copy", nominal_period_s=0.001)
    assert same_bits(copy.values, original.values)
    assert copy.meta.nominal_period_s == 0.001


def test_csv_with_crlf_bom_and_blank_lines(tmp_path: Path) -> None:
    path = tmp_path / "excel.csv"
    path.write_bytes(
        b"\xef\xbb\xbftime_s,X_current_a,X_position_mm\r\n0,0.5,1\r\n\r\n0.002,-0.25,2\r\n"
    )
    rec = import_csv(path, tmp_path / "r")
    assert same_bits(rec.time_s, np.array([0.0, 0.002]))
    assert same_bits(rec.values, np.array([[0.5, 1.0], [-0.25, 2.0]]))
    assert rec.channels == (Channel("X", "current_a", "A"), Channel("X", "position_mm", "mm"))
    assert rec.meta.nominal_period_s == 0.002


@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        ("", 1, "empty"),
        ("t,X_current_a\n0,1\n", 1, "first column must be time_s"),
        ("time_s\n0\n", 1, "no channel columns"),
        ("time_s,X_torque_nm\n0,1\n", 1, "column 2 'X_torque_nm' is not <AXIS>_<signal>"),
        ("time_s,x_current_a\n0,1\n", 1, "'x_current_a' is not"),
        ("time_s,X_current_a,X_current_a\n", 1, "appears twice"),
        ("time_s,X_current_a\n0,1\n0.001,2\n0.002,abc\n", 4, "column X_current_a: 'abc' is not"),
        ("time_s,X_current_a\n0,1\n0.001,\n", 3, "column X_current_a: '' is not a number"),
        ("time_s,X_current_a\n0,1\n0.001,2,3\n", 3, "3 cells, expected 2"),
        ("time_s,X_current_a\n0,1\n0.001\n", 3, "1 cells, expected 2"),
        (
            "time_s,X_current_a\n0,1\n0.002,2\n\n0.001,3\n",
            5,
            "time_s 0.001 is not later than the row before (0.002)",
        ),
        ("time_s,X_current_a\n0,1\nnan,2\n", 3, "time_s nan is not a finite number"),
    ],
)
def test_csv_import_errors_name_file_and_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, text: str, where: int, message: str
) -> None:
    monkeypatch.setattr(csv_module, "_BLOCK_CHARS", 8)  # errors across blocks too
    path = tmp_path / "bad.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(RecordingError) as info:
        import_csv(path, tmp_path / "r", nominal_period_s=0.001)
    assert str(info.value).startswith(f"{path}:{where}")
    assert message in str(info.value)
    assert not (tmp_path / "r").exists()  # a failed import leaves nothing behind


def test_csv_import_needs_two_rows_or_a_period(tmp_path: Path) -> None:
    path = tmp_path / "one.csv"
    path.write_text("time_s,X_current_a\n0.5,1\n", encoding="utf-8")
    with pytest.raises(RecordingError, match="pass nominal_period_s"):
        import_csv(path, tmp_path / "r")
    rec = import_csv(path, tmp_path / "r", nominal_period_s=0.004)
    assert len(rec) == 1 and rec.meta.nominal_period_s == 0.004
    with pytest.raises(RecordingError, match="no such file"):
        import_csv(tmp_path / "missing.csv", tmp_path / "r2")
    (tmp_path / "binary.csv").write_bytes(b"time_s,X_current_a\n\xff\xfe\n")
    with pytest.raises(RecordingError, match="not a text file"):
        import_csv(tmp_path / "binary.csv", tmp_path / "r3")


def test_a_failed_import_keeps_what_was_in_the_directory(tmp_path: Path) -> None:
    write_frames(tmp_path / "existing", frames=1, rows_per_frame=3)
    path = tmp_path / "in.csv"
    path.write_text("time_s,X_current_a\n0,1\n0.001,2\n", encoding="utf-8")
    with pytest.raises(RecordingError, match="not empty"):
        import_csv(path, tmp_path / "existing")
    assert len(Recording.open(tmp_path / "existing")) == 3


# --- MDF4 ------------------------------------------------------------------------------------


def test_an_import_the_disk_refuses_says_so_and_promises_nothing_of_its_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The disk fills while the import closes its recording: the message names the
    recording and the disk, and says the import is not kept. It does not say the samples
    on disk are readable, nor that a later recording moves them aside: the failed import
    removes them."""
    original = awkward_recording(tmp_path / "original")
    csv_path = export_csv(original, tmp_path / "out.csv")

    disk = FullDisk(monkeypatch)
    real_close = RecordingWriter.close

    def close(self: RecordingWriter, *args: Any, **kwargs: Any) -> None:
        disk.fill()  # while the import closes its recording
        real_close(self, *args, **kwargs)

    monkeypatch.setattr(RecordingWriter, "close", close)
    with pytest.raises(RecordingError) as caught:
        import_csv(csv_path, tmp_path / "copy")
    message = str(caught.value)
    assert message.startswith(f"{tmp_path / 'copy'}: disk full (No space left on device)")
    assert "the import is not kept" in message
    assert "readable" not in message and "aside" not in message
    assert not (tmp_path / "copy").exists()


def test_mdf4_keeps_the_serial_and_an_unknown_start(tmp_path: Path, make_config: Make) -> None:
    """A recording whose time is unknown (an import without a date) stays unknown through
    MDF4: the file header's time is not taken for it."""
    optional("asammdf")
    with RecordingWriter.create(
        tmp_path / "original", ALL_SIGNALS[:2], nominal_period_s=0.001, machine=make_config(),
        serial="M17", start_utc=None,
    ) as writer:  # fmt: skip
        writer.append(SampleBlock(np.arange(10) * 0.001, np.ones((10, 2))))
    path = export_mdf4(Recording.open(tmp_path / "original"), tmp_path / "out.mf4")
    copy = import_mdf4(path, tmp_path / "copy")
    assert copy.meta.start_utc is None and copy.meta.serial == "M17"
    when = dt.datetime(2024, 3, 5, 14, 22, tzinfo=dt.UTC)
    dated = import_mdf4(path, tmp_path / "dated", measured_at=when)
    assert dated.meta.start_utc == "2024-03-05T14:22:00.000+00:00"


def test_mdf4_round_trip(tmp_path: Path, make_config: Make) -> None:
    asammdf = optional("asammdf")
    config = make_config()
    directory = tmp_path / "original"
    rng = np.random.default_rng(3)
    events = [LinkEvent(0.2, "reconnect", "bus back", details={"tries": 2})]
    with RecordingWriter.create(
        directory, ALL_SIGNALS, nominal_period_s=0.001, machine=config, link=LINK,
        notes="mdf", source="canopen", faster_than_real_time=True, time_scale=4.0,
    ) as writer:  # fmt: skip
        time_s = np.arange(2000) * 0.001
        writer.append(SampleBlock(time_s, rng.standard_normal((2000, len(ALL_SIGNALS)))))
        writer.add_event(events[0])
    original = Recording.open(directory)

    path = export_mdf4(original, tmp_path / "out.mf4")
    with asammdf.MDF(path) as mdf:
        names = {c.name: c.unit for g in mdf.groups for c in g.channels}
        stored = mdf.get("Y_velocity_cmd_mm_min")
    for channel in ALL_SIGNALS:
        assert names[channel.name] == channel.unit
    assert np.array_equal(stored.samples, original.column("Y_velocity_cmd_mm_min"))

    copy = import_mdf4(path, tmp_path / "copy")
    assert np.array_equal(copy.time_s, original.time_s)
    assert np.array_equal(copy.values, original.values)
    assert copy.channels == original.channels
    assert copy.events == events
    assert copy.meta.source == "import:mdf4"
    assert copy.meta.machine == original.meta.machine
    assert copy.meta.axes == original.meta.axes
    assert copy.meta.link == LINK
    assert copy.meta.nominal_period_s == 0.001
    assert copy.meta.faster_than_real_time is True and copy.meta.time_scale == 4.0
    assert copy.meta.start_utc == original.meta.start_utc
    assert copy.problems == []


def test_mdf4_import_of_a_foreign_file(tmp_path: Path) -> None:
    asammdf = optional("asammdf")
    time_s = np.arange(100) * 0.01
    path = tmp_path / "scope.mf4"
    mdf = asammdf.MDF(version="4.10")
    mdf.append(
        [
            asammdf.Signal(np.sin(time_s), time_s, name="X_current_a", unit="A"),
            asammdf.Signal(np.cos(time_s), time_s, name="X_position_mm", unit=""),
        ],
        common_timebase=True,
    )
    mdf.save(path, overwrite=True)
    mdf.close()
    rec = import_mdf4(path, tmp_path / "r")
    assert np.array_equal(rec.column("X_position_mm"), np.cos(time_s))
    assert rec.meta.nominal_period_s == pytest.approx(0.01)
    assert rec.meta.machine is None

    bad = tmp_path / "bad.mf4"
    mdf = asammdf.MDF(version="4.10")
    mdf.append([asammdf.Signal(time_s, time_s, name="Engine_speed", unit="rpm")])
    mdf.save(bad, overwrite=True)
    mdf.close()
    with pytest.raises(RecordingError, match=r"'Engine_speed' .* is not <AXIS>_<signal>"):
        import_mdf4(bad, tmp_path / "r2")
    assert not (tmp_path / "r2").exists()
    wrong_unit = tmp_path / "unit.mf4"
    mdf = asammdf.MDF(version="4.10")
    mdf.append([asammdf.Signal(time_s, time_s, name="X_current_a", unit="mA")])
    mdf.save(wrong_unit, overwrite=True)
    mdf.close()
    with pytest.raises(RecordingError, match="in 'mA'"):
        import_mdf4(wrong_unit, tmp_path / "r3")
    (tmp_path / "text.mf4").write_text("not mdf", encoding="utf-8")
    with pytest.raises(RecordingError, match="not a readable MDF file"):
        import_mdf4(tmp_path / "text.mf4", tmp_path / "r4")


def test_mdf4_without_asammdf_names_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write_frames(tmp_path / "r", frames=1, rows_per_frame=3)
    monkeypatch.setitem(sys.modules, "asammdf", None)  # makes `import asammdf` fail
    with pytest.raises(DependencyError, match=r"pip install 'ncmeasure\[mdf\]'"):
        export_mdf4(tmp_path / "r", tmp_path / "out.mf4")
    with pytest.raises(DependencyError, match="ncmeasure\\[mdf\\]"):
        import_mdf4(tmp_path / "out.mf4", tmp_path / "copy")
    assert not (tmp_path / "out.mf4").exists()


def test_mdf4_export_is_written_whole_under_the_name_asked_for(tmp_path: Path) -> None:
    """asammdf writes .mf4 files: the export still lands exactly at the path given, via a
    temporary file, and a symlink beside it is never followed."""
    optional("asammdf")
    write_frames(tmp_path / "r", frames=1, rows_per_frame=5)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (tmp_path / "out.mdf.tmp").symlink_to(victim)
    target = export_mdf4(tmp_path / "r", tmp_path / "out.mdf")
    assert target == tmp_path / "out.mdf" and target.is_file()
    assert victim.read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "out.mdf",
        "out.mdf.tmp",
        "r",
        "victim.txt",
    ]
    copy = import_mdf4(target, tmp_path / "copy")
    assert len(copy) == 5


# --- export chunk by chunk -------------------------------------------------------------------


def _never_whole(monkeypatch: pytest.MonkeyPatch) -> None:
    """Reading a whole recording into memory fails: an export from a directory must not."""

    def refuse(*args: object, **kwargs: object) -> Recording:
        raise AssertionError("the whole recording was read into memory")

    monkeypatch.setattr(Recording, "open", classmethod(refuse))


def test_export_from_a_directory_reads_chunk_by_chunk_and_writes_the_same_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Several chunks (20,500 rows read at a time for CSV, 8,192 for MDF4): the same bytes
    as from memory, formatted in pieces of at most 1,000 rows (the last of a chunk shorter)."""
    monkeypatch.setattr(csv_module, "_CSV_CHUNK_ROWS", 20_500)
    original = awkward_recording(tmp_path / "r", rows=45_000)
    formatted: list[int] = []
    format_rows = csv_module.csv_rows

    def csv_rows(rows: np.ndarray[Any, np.dtype[np.float64]]) -> bytes:
        formatted.append(len(rows))
        return format_rows(rows)

    with monkeypatch.context() as patched:
        patched.setattr(csv_module, "csv_rows", csv_rows)
        from_memory = export_csv(original, tmp_path / "memory.csv").read_bytes()
    assert sum(formatted) == 45_000
    assert max(formatted) == csv_module._FORMAT_ROWS == 1_000
    assert 500 in formatted  # the last piece of a chunk of 20,500 rows
    # the same bytes as the rows formatted at once
    rows = np.column_stack([original.time_s, original.values])
    assert from_memory.split(b"\n", 1)[1] == csv_module.csv_rows(rows)
    mdf_ok = True
    try:
        export_mdf4(original, tmp_path / "memory.mf4")
    except DependencyError:
        mdf_ok = False
    _never_whole(monkeypatch)
    assert export_csv(tmp_path / "r", tmp_path / "chunks.csv").read_bytes() == from_memory
    if mdf_ok:
        export_mdf4(tmp_path / "r", tmp_path / "chunks.mf4")
        monkeypatch.undo()
        copy = import_mdf4(tmp_path / "chunks.mf4", tmp_path / "copy")
        assert same_bits(copy.time_s, original.time_s)
        assert same_bits(copy.values, original.values)
        assert copy.channel_names == original.channel_names


def test_export_of_a_damaged_recording_says_so_and_keeps_the_good_rows(tmp_path: Path) -> None:
    from ncmeasure.recording import RecordingHead

    write_frames(tmp_path / "r", frames=3, rows_per_frame=5)
    samples = tmp_path / "r" / "samples.bin"
    samples.write_bytes(samples.read_bytes()[:-3])  # the last frame torn
    head = RecordingHead.open(tmp_path / "r")
    export_csv(head, tmp_path / "out.csv")
    assert head.rows == 10
    assert any("torn tail" in problem for problem in head.problems), head.problems
    assert len((tmp_path / "out.csv").read_text(encoding="utf-8").splitlines()) == 11
