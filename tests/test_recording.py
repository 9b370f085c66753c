"""The recording format: write, read back, survive crashes and damage."""

from __future__ import annotations

import contextlib
import datetime as dt
import errno
import json
import math
import os
import signal
import struct
import subprocess
import sys
import textwrap
import threading
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

import ncmeasure
from ncmeasure.config import MachineConfig
from ncmeasure.errors import LinkError, RecordingError
from ncmeasure.recording import (
    EVENTS_FILE,
    FRAME_HEADER,
    FRAME_MAGIC,
    META_FILE,
    SAMPLES_FILE,
    Recording,
    RecordingWriter,
    axis_metadata,
    channel_from_name,
    iter_chunks,
    read_recording,
)
from ncmeasure.recording import reader as recording_reader
from ncmeasure.recording import writer as recording_writer
from ncmeasure.samples import SIGNAL_UNITS, Channel, LinkEvent, SampleBlock, channels_for

Make = Callable[..., MachineConfig]

XY = channels_for(["X", "Y"])  # current, velocity, position of X and Y: 6 channels
ALL_SIGNALS = channels_for(["X", "Y", "Z"], tuple(SIGNAL_UNITS))  # 15 channels
LINK = {
    "link": {"type": "canopen", "interface": "virtual", "channel": "0", "bitrate": 1_000_000},
    "axes": {"X": {"node_id": 1}, "Y": {"node_id": 2}},
}


def rows_for(
    first: int, count: int, channels: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Row ``k`` has time k ms and values k·(c+1)/7 + c: exact, and different per column."""
    k = np.arange(first, first + count, dtype=np.float64)
    time_s = k * 0.001
    values = k[:, None] * (np.arange(channels) + 1) / 7 + np.arange(channels)
    return time_s, values


def block(first: int, count: int, channels: int = len(XY)) -> SampleBlock:
    return SampleBlock(*rows_for(first, count, channels))


def write_frames(directory: Path, frames: int, rows_per_frame: int) -> None:
    """A closed recording of ``frames`` frames, each written by an explicit flush."""
    with RecordingWriter.create(directory, XY, nominal_period_s=0.001) as writer:
        for index in range(frames):
            writer.append(block(index * rows_per_frame, rows_per_frame))
            writer.flush()


def frame_offsets(path: Path, columns: int) -> list[int]:
    """Byte offset of every frame header in a samples file."""
    data = path.read_bytes()
    offsets, offset = [], 0
    while offset < len(data):
        offsets.append(offset)
        _, count, _, _ = FRAME_HEADER.unpack_from(data, offset)
        offset += FRAME_HEADER.size + count * columns * 8
    return offsets


def same_bits(a: NDArray[np.float64], b: NDArray[np.float64]) -> bool:
    """Equal bit for bit (tells -0.0 from 0.0, and NaN equals itself)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


# --- writing and reading -----------------------------------------------------------------


def test_write_close_read_back(tmp_path: Path, make_config: Make) -> None:
    config = make_config()
    directory = tmp_path / "runs" / "first"  # parents are created
    events = [
        LinkEvent(0.0125, "gap", "3 SYNC cycles without PDO", axis="X", lost_samples=3),
        LinkEvent(0.05, "fault", "drive fault 0x7500", axis="Y", details={"code": 0x7500}),
    ]
    writer = RecordingWriter.create(
        directory,
        XY,
        nominal_period_s=0.001,
        machine=config,
        link=LINK,
        config_hash="0123456789abcdef",
        notes="before lubrication",
        source="canopen",
    )
    sizes = [1, 7, 250, 42]
    first = 0
    for count in sizes:
        writer.append(block(first, count))
        first += count
    writer.append(SampleBlock(np.empty(0), np.empty((0, len(XY)))))  # empty blocks are fine
    for event in events:
        writer.add_event(event)
    writer.close(notes="after lubrication")
    writer.close()  # idempotent
    assert writer.rows_written == writer.rows_appended == sum(sizes)

    rec = Recording.open(directory)
    time_s, values = rows_for(0, sum(sizes), len(XY))
    assert same_bits(rec.time_s, time_s)
    assert same_bits(rec.values, values)
    assert len(rec) == sum(sizes)
    assert rec.channels == XY
    assert rec.axes == ("X", "Y")
    assert same_bits(rec.column("Y_velocity_mm_min"), values[:, 4])
    assert same_bits(rec.axis_signal("X", "position_mm"), values[:, 2])
    assert same_bits(rec.column("time_s"), time_s)
    assert rec.events == events
    assert rec.problems == []

    meta = rec.meta
    assert meta.format == "ncmeasure-recording"
    assert meta.format_version == 1
    assert meta.ncmeasure_version == ncmeasure.__version__
    assert meta.machine == config.machine.name
    assert meta.axes == [axis_metadata(config.axis("X")), axis_metadata(config.axis("Y"))]
    assert meta.axes[0].torque_constant_nm_per_a == config.axis("X").torque_constant_nm_per_a
    assert meta.link == LINK
    assert [(c.name, c.axis, c.signal, c.unit) for c in meta.channels] == [
        (c.name, c.axis, c.signal, c.unit) for c in XY
    ]
    assert meta.nominal_period_s == 0.001
    assert meta.config_hash == "0123456789abcdef"
    assert meta.notes == "after lubrication"
    assert meta.source == "canopen"
    assert meta.faster_than_real_time is False
    assert meta.time_scale == 1.0
    assert meta.status == "incomplete"  # closed as complete, but a gap event lost 3 samples
    assert (meta.gaps, meta.lost_samples) == (1, 3)
    assert meta.samples == sum(sizes)
    assert meta.end_utc is not None
    start = dt.datetime.fromisoformat(meta.start_utc)
    assert start.tzinfo is not None
    assert start <= dt.datetime.fromisoformat(meta.end_utc)
    assert read_recording(directory).meta == meta
    # meta.json is plain JSON with the documented fields
    on_disk = json.loads((directory / META_FILE).read_text(encoding="utf-8"))
    assert on_disk["status"] == "incomplete"
    assert on_disk["channels"][0] == {"name": "X_current_a", "axis": "X", "signal": "current_a",
                                      "unit": "A"}  # fmt: skip


def test_meta_json_says_recording_until_closed(tmp_path: Path) -> None:
    writer = RecordingWriter.create(tmp_path / "r", XY, nominal_period_s=0.002)
    meta = json.loads((tmp_path / "r" / META_FILE).read_text(encoding="utf-8"))
    assert meta["status"] == "recording"
    assert meta["samples"] is None and meta["end_utc"] is None
    writer.close("interrupted")
    meta = json.loads((tmp_path / "r" / META_FILE).read_text(encoding="utf-8"))
    assert meta["status"] == "interrupted"
    assert meta["samples"] == 0
    assert not (tmp_path / "r" / (META_FILE + ".tmp")).exists()


@pytest.mark.parametrize(
    ("error", "status"),
    [
        (None, "complete"),
        (LinkError("bus off"), "link_lost"),
        (KeyboardInterrupt(), "interrupted"),
        (RuntimeError("bug"), "failed"),
    ],
)
def test_context_manager_sets_the_status(
    tmp_path: Path, error: BaseException | None, status: str
) -> None:
    directory = tmp_path / "r"
    expect = pytest.raises(type(error)) if error else contextlib.nullcontext()
    with expect, RecordingWriter.create(directory, XY, nominal_period_s=0.001) as writer:
        writer.append(block(0, 10))
        if error:
            raise error
    rec = Recording.open(directory)
    assert rec.meta.status == status
    assert len(rec) == 10  # rows appended before the error are kept
    assert writer.closed


def test_rows_are_flushed_without_an_explicit_flush(tmp_path: Path) -> None:
    directory = tmp_path / "live"
    writer = RecordingWriter.create(directory, XY, nominal_period_s=0.001)
    try:
        writer.append(block(0, 300))
        writer.add_event(LinkEvent(0.1, "info", "started"))
        deadline = time.monotonic() + 60  # the flush thread writes them; a guard, not a timing
        while writer.rows_written < 300 and time.monotonic() < deadline:
            time.sleep(0.01)
        live = Recording.open(directory)  # a second handle, while the writer is open
        assert len(live) == 300
        assert same_bits(live.values, rows_for(0, 300, len(XY))[1])
        assert [e.message for e in live.events] == ["started"]
        assert live.meta.status == "recording"
        assert any("still being recorded" in p for p in live.problems)
        assert writer.rows_written == 300
    finally:
        writer.close()
    assert Recording.open(directory).problems == []


def test_large_flushes_are_split_into_frames(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recording_writer, "MAX_FRAME_ROWS", 64)
    with RecordingWriter.create(tmp_path / "r", XY, nominal_period_s=0.001) as writer:
        writer.append(block(0, 1000))
    columns = 1 + len(XY)
    assert len(frame_offsets(tmp_path / "r" / SAMPLES_FILE, columns)) == 16  # 15 × 64 + 40
    rec = Recording.open(tmp_path / "r")
    assert same_bits(rec.values, rows_for(0, 1000, len(XY))[1])
    assert rec.problems == []


def test_a_writer_fed_faster_than_real_time_writes_bounded_frames(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A replay or an import appends rows far faster than the flush thread's interval:
    the rows waiting in memory (and lost by a crash) stay bounded by FLUSH_ROWS, and so
    do the frames, whatever the pace."""
    monkeypatch.setattr(recording_writer, "FLUSH_ROWS", 2500)
    directory = tmp_path / "r"
    writer = RecordingWriter.create(directory, XY, nominal_period_s=0.001, flush_interval_s=0.5)
    for index in range(10):
        writer.append(block(index * 1000, 1000))
    assert writer.rows_written >= 9000  # on disk before any flush of the thread is due
    writer.close()
    columns = 1 + len(XY)
    data = (directory / SAMPLES_FILE).read_bytes()
    sizes = [
        FRAME_HEADER.unpack_from(data, o)[1]
        for o in frame_offsets(directory / SAMPLES_FILE, columns)
    ]
    assert sum(sizes) == 10_000
    assert max(sizes) <= 3000  # under FLUSH_ROWS when the last block came, plus that block
    assert same_bits(Recording.open(directory).values, rows_for(0, 10_000, len(XY))[1])


def test_a_flush_that_fails_inside_append_is_raised_by_the_next_call_and_keeps_the_rows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recording_writer, "FLUSH_ROWS", 100)
    directory = tmp_path / "r"
    writer = RecordingWriter.create(directory, XY, nominal_period_s=0.001, flush_interval_s=0.5)
    disk = FullDisk(monkeypatch)
    disk.fill()
    writer.append(block(0, 150))  # its flush fails: the rows stay buffered, append returns
    with pytest.raises(RecordingError, match="No space left on device"):
        writer.append(block(150, 10))
    disk.free()
    writer.flush()  # the retry writes what was buffered
    writer.append(block(150, 10))
    writer.close()
    assert same_bits(Recording.open(directory).values, rows_for(0, 160, len(XY))[1])


def test_an_interrupt_in_the_middle_of_a_frame_leaves_no_partial_frame(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A Ctrl-C (KeyboardInterrupt) while append writes a frame on the caller's thread: the
    partial frame is cut away and the rows stay buffered, so closing the recording as
    interrupted writes them after the last whole frame and every row reads back."""
    monkeypatch.setattr(recording_writer, "FLUSH_ROWS", 1000)
    real_write_all = recording_writer._write_all
    payloads = [0]

    def write_all(file: Any, data: Any) -> None:
        # The second frame append writes (not the flush thread's): half of it, then Ctrl-C.
        if threading.current_thread() is threading.main_thread() and len(data) > 16:
            payloads[0] += 1
            if payloads[0] == 2:
                view = memoryview(data).cast("B")
                file.write(view[: len(view) // 2])
                raise KeyboardInterrupt
        real_write_all(file, data)

    monkeypatch.setattr(recording_writer, "_write_all", write_all)
    directory = tmp_path / "r"
    appended = 0
    with (
        pytest.raises(KeyboardInterrupt),
        RecordingWriter.create(
            directory, XY, nominal_period_s=0.001, flush_interval_s=0.5
        ) as writer,
    ):
        for index in range(100):
            appended += 500  # the block of the interrupted append was buffered
            writer.append(block(index * 500, 500))
    rec = Recording.open(directory)
    assert rec.problems == []
    assert rec.meta.status == "interrupted"
    assert rec.meta.samples == len(rec) == appended
    assert same_bits(rec.values, rows_for(0, appended, len(XY))[1])


def test_appends_and_events_from_several_threads(tmp_path: Path) -> None:
    directory = tmp_path / "r"
    with RecordingWriter.create(directory, XY, nominal_period_s=0.001) as writer:

        def add_events(name: str) -> None:
            for number in range(200):
                writer.add_event(LinkEvent(float(number), "info", f"{name}{number}"))

        threads = [threading.Thread(target=add_events, args=(n,)) for n in "abcd"]
        for thread in threads:
            thread.start()
        for first in range(0, 5000, 50):
            writer.append(block(first, 50))
            if first % 1000 == 0:
                writer.flush()
        for thread in threads:
            thread.join()
    rec = Recording.open(directory)
    assert same_bits(rec.values, rows_for(0, 5000, len(XY))[1])
    assert sorted(e.message for e in rec.events) == sorted(
        f"{n}{i}" for n in "abcd" for i in range(200)
    )


# --- crash safety -------------------------------------------------------------------------

RECORDER = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from ncmeasure.samples import Channel, SampleBlock
    from ncmeasure.recording import RecordingWriter

    channels = [Channel("X", "current_a", "A"), Channel("X", "position_mm", "mm")]
    writer = RecordingWriter.create(sys.argv[1], channels, nominal_period_s=0.001)
    print("ready", flush=True)
    k = 0
    due = time.monotonic()
    while True:  # 1 kHz in blocks of 10 rows, until killed
        index = np.arange(k, k + 10)
        values = np.column_stack([index * 0.5 - 3.0, np.sqrt(index)])
        writer.append(SampleBlock(index * 0.001, values))
        k += 10
        print(k, writer.rows_written, flush=True)  # appended, and on disk (fsynced)
        due += 0.01
        time.sleep(max(0.0, due - time.monotonic()))
    """
)


@pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL is POSIX")
def test_rows_on_disk_survive_kill_9(tmp_path: Path) -> None:
    """What the flush thread wrote (every 0.5 s, fsynced) survives ``kill -9``, exactly.

    The recorder reports what it appended and what is on disk; the test kills it once
    1500 rows are on disk, whenever that is on a busy computer.
    """
    script = tmp_path / "recorder.py"
    script.write_text(RECORDER, encoding="utf-8")
    directory = tmp_path / "killed"
    process = subprocess.Popen(
        [sys.executable, str(script), str(directory)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stdout is not None
    on_disk = appended = 0
    try:
        deadline = time.monotonic() + 120  # a guard against a hang
        for line in process.stdout:
            if line.strip() == "ready":
                continue
            appended, on_disk = (int(word) for word in line.split())
            if on_disk >= 1500 or time.monotonic() > deadline:
                break
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=10)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=10)
    assert process.returncode == -signal.SIGKILL
    assert on_disk >= 1500, process.stderr.read() if process.stderr else ""
    rec = Recording.open(directory)
    assert on_disk <= len(rec) <= appended + 10  # what was on disk, perhaps a frame more
    index = np.arange(len(rec))
    assert same_bits(rec.time_s, index * 0.001)
    assert same_bits(rec.values[:, 0], index * 0.5 - 3.0)
    assert same_bits(rec.values[:, 1], np.sqrt(index))
    assert rec.meta.status == "recording"
    assert any(
        p.startswith("not closed cleanly (status 'recording')") and f"{len(rec)} samples" in p
        for p in rec.problems
    )


def test_every_cut_reads_as_whole_frames(tmp_path: Path) -> None:
    """Cut the file at every byte: the reader returns the whole frames before the cut, only."""
    directory = tmp_path / "r"
    write_frames(directory, frames=3, rows_per_frame=4)
    path = directory / SAMPLES_FILE
    full = path.read_bytes()
    columns = 1 + len(XY)
    offsets = [*frame_offsets(path, columns), len(full)]
    _, values = rows_for(0, 12, len(XY))
    for cut in range(len(full) + 1):
        path.write_bytes(full[:cut])
        rec = Recording.open(directory)
        whole = sum(1 for end in offsets[1:] if end <= cut)
        assert same_bits(rec.values, values[: 4 * whole]), cut
        torn = cut not in offsets
        assert any(p.startswith("torn tail") for p in rec.problems) == torn, cut


@pytest.mark.parametrize("garbage", [b"", b"\x00" * 3, b"NCMF" + b"\xff" * 40, os.urandom(5000)])
def test_torn_tail_with_garbage_is_ignored(tmp_path: Path, garbage: bytes) -> None:
    directory = tmp_path / "r"
    write_frames(directory, frames=5, rows_per_frame=20)
    path = directory / SAMPLES_FILE
    offsets = frame_offsets(path, 1 + len(XY))
    data = path.read_bytes()
    path.write_bytes(data[: offsets[4] + FRAME_HEADER.size + 100] + garbage)  # cut in frame 4
    rec = Recording.open(directory)
    assert same_bits(rec.values, rows_for(0, 80, len(XY))[1])
    assert same_bits(rec.time_s, rows_for(0, 80, len(XY))[0])
    assert any("frame 4" in p or "after frame 3" in p for p in rec.problems)
    assert any("meta.json says 100 samples" in p for p in rec.problems)


@pytest.mark.parametrize(
    ("garbage", "problem"),
    [
        (b"\x13" * 12, "torn tail: 12 bytes after frame 1 ignored (incomplete frame)"),
        (b"\x13" * 40, "torn tail: 40 bytes after frame 1 ignored (no frame header at byte 1152)"),
    ],
)
def test_garbage_after_a_clean_file_is_reported(
    tmp_path: Path, garbage: bytes, problem: str
) -> None:
    directory = tmp_path / "r"
    write_frames(directory, frames=2, rows_per_frame=10)
    assert (directory / SAMPLES_FILE).stat().st_size == 2 * (16 + 10 * 7 * 8)
    with (directory / SAMPLES_FILE).open("ab") as file:
        file.write(garbage)
    rec = Recording.open(directory)
    assert same_bits(rec.values, rows_for(0, 20, len(XY))[1])
    assert rec.problems == [problem]


def test_a_huge_sparse_zero_tail_is_a_torn_tail_read_in_bounded_memory(tmp_path: Path) -> None:
    """A 50 GiB hole after the frames (a file system's zeros after a crash, or a stray
    truncate) reads as the intact rows plus a torn-tail report, allocating only them."""
    import tracemalloc

    directory = tmp_path / "r"
    write_frames(directory, frames=3, rows_per_frame=10)
    path = directory / SAMPLES_FILE
    end = path.stat().st_size
    with path.open("r+b") as file:
        file.truncate(50 * 2**30)  # sparse: no block of the hole is allocated
    tracemalloc.start()
    try:
        rec = Recording.open(directory)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20, peak  # numpy reports its buffers to tracemalloc
    assert same_bits(rec.values, rows_for(0, 30, len(XY))[1])
    assert same_bits(rec.time_s, rows_for(0, 30, len(XY))[0])
    tail = 50 * 2**30 - end
    assert f"torn tail: {tail} bytes after frame 2 ignored (zero bytes at byte {end}" in (
        " ".join(rec.problems)
    )


def test_a_corrupt_frame_stops_the_read_at_the_frame_before(tmp_path: Path) -> None:
    directory = tmp_path / "r"
    write_frames(directory, frames=5, rows_per_frame=20)
    path = directory / SAMPLES_FILE
    offsets = frame_offsets(path, 1 + len(XY))
    data = bytearray(path.read_bytes())
    data[offsets[2] + FRAME_HEADER.size + 333] ^= 0x01  # one bit of one value of frame 2
    path.write_bytes(bytes(data))
    rec = Recording.open(directory)
    assert same_bits(rec.values, rows_for(0, 40, len(XY))[1])
    assert any(p.startswith("frame 2 fails its checksum") for p in rec.problems)


@pytest.mark.parametrize("read_rows", [1 << 16, 7])
def test_every_channel_is_one_contiguous_run_of_memory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, read_rows: int
) -> None:
    """The analysis reads a recording channel by channel: in rows of every channel, each
    sample of a channel would sit in a cache line of its own. Frames larger than one
    read (7 rows here) are read in pieces, each piece into its columns."""
    monkeypatch.setattr(recording_reader, "_READ_ROWS", read_rows)
    directory = tmp_path / "r"
    write_frames(directory, frames=3, rows_per_frame=20)
    rec = Recording.open(directory)
    time_s, values = rows_for(0, 60, len(XY))
    assert same_bits(rec.time_s, time_s)
    assert same_bits(rec.values, values)
    for name in ("time_s", *rec.channel_names):
        column = rec.column(name)
        assert column.flags.c_contiguous, name
        assert column.base is not None  # a view, not a copy per call
    assert rec.problems == []


def test_a_corrupt_piece_of_a_frame_read_in_pieces_stops_the_read_at_the_frame_before(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recording_reader, "_READ_ROWS", 7)
    directory = tmp_path / "r"
    write_frames(directory, frames=4, rows_per_frame=20)
    path = directory / SAMPLES_FILE
    offsets = frame_offsets(path, 1 + len(XY))
    data = bytearray(path.read_bytes())
    row_bytes = 8 * (1 + len(XY))
    data[offsets[2] + FRAME_HEADER.size + 15 * row_bytes + 3] ^= 0x10  # its third piece
    path.write_bytes(bytes(data))
    rec = Recording.open(directory)
    assert same_bits(rec.values, rows_for(0, 40, len(XY))[1])
    assert same_bits(rec.time_s, rows_for(0, 40, len(XY))[0])
    assert any(p.startswith("frame 2 fails its checksum") for p in rec.problems)


def test_a_frame_out_of_sequence_is_not_read(tmp_path: Path) -> None:
    directory = tmp_path / "r"
    write_frames(directory, frames=3, rows_per_frame=5)
    path = directory / SAMPLES_FILE
    offsets = frame_offsets(path, 1 + len(XY))
    data = bytearray(path.read_bytes())
    # A whole, valid frame that claims to be frame 7: e.g. a block written twice.
    payload = bytes(data[offsets[1] + FRAME_HEADER.size : offsets[2]])
    header = FRAME_HEADER.pack(FRAME_MAGIC, 5, zlib.crc32(payload), 7)
    data[offsets[1] : offsets[1] + FRAME_HEADER.size] = header
    path.write_bytes(bytes(data))
    rec = Recording.open(directory)
    assert len(rec) == 5
    assert any("sequence number 7" in p for p in rec.problems)


def test_a_torn_last_event_line_is_ignored(tmp_path: Path) -> None:
    directory = tmp_path / "r"
    with RecordingWriter.create(directory, XY, nominal_period_s=0.001) as writer:
        writer.append(block(0, 10))
        writer.add_event(LinkEvent(0.001, "reboot", "drive 2 rebooted", axis="Y"))
    with (directory / EVENTS_FILE).open("ab") as file:
        file.write(b'{"time_s": 0.009, "kind": "ga')
    rec = Recording.open(directory)
    assert [e.message for e in rec.events] == ["drive 2 rebooted"]
    assert any("torn last line" in p for p in rec.problems)
    assert len(rec) == 10


def test_problems_are_logged_as_warnings(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    directory = tmp_path / "r"
    write_frames(directory, frames=1, rows_per_frame=3)
    with (directory / SAMPLES_FILE).open("ab") as file:
        file.write(b"NC")
    with caplog.at_level("WARNING", logger="ncmeasure.recording"):
        rec = Recording.open(directory)
    assert rec.problems
    assert [r.getMessage() for r in caplog.records] == [
        f"recording {directory}: {p}" for p in rec.problems
    ]


# --- a full disk ---------------------------------------------------------------------------


class FullDisk:
    """``os.fsync`` fails with ENOSPC once the disk is "full", as a full disk makes it fail.

    The disk fills by hand (:meth:`fill`) or after ``samples_syncs`` syncs of
    a ``samples.bin`` (Linux: the file's name from /proc); everything synced
    after that fails, meta.json included.
    """

    def __init__(self, monkeypatch: pytest.MonkeyPatch, samples_syncs: int | None = None) -> None:
        self.full = False
        self.samples_syncs = samples_syncs
        real = os.fsync

        def fsync(fd: int) -> None:
            if self.samples_syncs is not None and not self.full:
                with contextlib.suppress(OSError):
                    if Path(f"/proc/self/fd/{fd}").readlink().name == SAMPLES_FILE:
                        self.samples_syncs -= 1
                        self.full = self.samples_syncs < 0
            if self.full:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            real(fd)

        monkeypatch.setattr(os, "fsync", fsync)

    def fill(self) -> None:
        self.full = True

    def free(self) -> None:
        self.full, self.samples_syncs = False, None


def test_a_full_disk_keeps_what_was_written_and_a_retry_moves_it_aside(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    disk = FullDisk(monkeypatch)
    directory = tmp_path / "run"
    writer = RecordingWriter.create(directory, XY, nominal_period_s=0.001)
    writer.append(block(0, 10))
    writer.flush()
    disk.fill()
    writer.append(block(10, 10))
    with pytest.raises(RecordingError, match=r"run: disk full \(No space left on device\)"):
        writer.flush()
    with pytest.raises(RecordingError, match="disk full") as caught:
        writer.close()
    message = caught.value.message
    assert str(directory) in message and "10 samples" in message and "readable" in message
    assert "meta.json" in message  # still says 'recording': the disk had no room for it
    # no temporary file is left behind; the 10 samples on disk read back
    assert sorted(p.name for p in directory.iterdir()) == [EVENTS_FILE, META_FILE, SAMPLES_FILE]
    rec = Recording.open(directory)
    assert same_bits(rec.values, rows_for(0, 10, len(XY))[1])
    assert rec.meta.status == "recording"

    # with room again, a retry into the same directory moves the failed attempt aside
    disk.free()
    with RecordingWriter.create(directory, XY, nominal_period_s=0.001) as retry:
        retry.append(block(0, 3))
    assert retry.moved_aside == tmp_path / "run.failed-1"
    assert len(Recording.open(tmp_path / "run.failed-1")) == 10
    assert len(Recording.open(directory)) == 3
    # a finished recording is never replaced or moved
    with pytest.raises(
        RecordingError, match=r"not empty: .*finished recording \(status complete\)"
    ):
        RecordingWriter.create(directory, XY, nominal_period_s=0.001)
    assert len(Recording.open(directory)) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "run.failed-1"]


def test_a_disk_that_is_full_from_the_start_leaves_nothing_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    disk = FullDisk(monkeypatch)
    disk.fill()
    (tmp_path / "empty").mkdir()
    for directory in (tmp_path / "new", tmp_path / "empty"):
        with pytest.raises(RecordingError, match=f"{directory.name}: disk full") as caught:
            RecordingWriter.create(directory, XY, nominal_period_s=0.001)
        assert "meta.json" in caught.value.message
    assert not (tmp_path / "new").exists()
    assert list((tmp_path / "empty").iterdir()) == []
    disk.free()
    RecordingWriter.create(tmp_path / "new", XY, nominal_period_s=0.001).close()
    assert Recording.open(tmp_path / "new").meta.status == "complete"


def test_which_earlier_attempts_a_new_recording_moves_aside(tmp_path: Path) -> None:
    # failed, or stopped without closing (status 'recording', no writer): moved aside
    failed = RecordingWriter.create(tmp_path / "a", XY, nominal_period_s=0.001)
    failed.append(block(0, 4))
    failed.close("failed")
    write_frames(tmp_path / "b", frames=1, rows_per_frame=4)
    meta = json.loads((tmp_path / "b" / META_FILE).read_text(encoding="utf-8"))
    (tmp_path / "b" / META_FILE).write_text(json.dumps({**meta, "status": "recording"}))
    for name in ("a", "b"):
        RecordingWriter.create(tmp_path / name, XY, nominal_period_s=0.001).close()
        assert len(Recording.open(tmp_path / f"{name}.failed-1")) == 4
    # a second failed attempt goes beside the first
    meta = json.loads((tmp_path / "a" / META_FILE).read_text(encoding="utf-8"))
    (tmp_path / "a" / META_FILE).write_text(json.dumps({**meta, "status": "failed"}))
    assert RecordingWriter.create(tmp_path / "a", XY, nominal_period_s=0.001).moved_aside == (
        tmp_path / "a.failed-2"
    )
    # a recording still being written is left alone
    live = RecordingWriter.create(tmp_path / "c", XY, nominal_period_s=0.001)
    try:
        with pytest.raises(RecordingError, match=r"not empty: .*still being recorded"):
            RecordingWriter.create(tmp_path / "c", XY, nominal_period_s=0.001)
    finally:
        live.close()
    # finished ones, whatever their end, and folders that hold no recording are refused
    for status in ("incomplete", "interrupted", "link_lost"):
        with RecordingWriter.create(tmp_path / status, XY, nominal_period_s=0.001) as writer:
            writer.append(block(0, 2))
        writer_meta = json.loads((tmp_path / status / META_FILE).read_text(encoding="utf-8"))
        (tmp_path / status / META_FILE).write_text(json.dumps({**writer_meta, "status": status}))
        with pytest.raises(RecordingError, match=f"finished recording \\(status {status}\\)"):
            RecordingWriter.create(tmp_path / status, XY, nominal_period_s=0.001)
    assert not (tmp_path / "c.failed-1").exists()
    moved = sorted(p.name for p in tmp_path.iterdir() if ".failed-" in p.name)
    assert moved == ["a.failed-1", "a.failed-2", "b.failed-1"]


RECORDER_WITH_A_SIZE_LIMIT = textwrap.dedent(
    """
    import resource, signal, sys
    import numpy as np
    from ncmeasure.errors import RecordingError
    from ncmeasure.recording import RecordingWriter
    from ncmeasure.samples import SampleBlock, channels_for

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))
    writer = RecordingWriter.create(sys.argv[1], channels_for(["X"]), nominal_period_s=0.001)
    try:
        for k in range(100):
            time_s = (np.arange(100) + 100 * k) * 0.001
            writer.append(SampleBlock(time_s, np.ones((100, 3))))
            writer.flush()
    except RecordingError as exc:
        print("append:", exc.message)
    try:
        writer.close()
    except RecordingError as exc:
        print("close:", exc.message)
    """
)


def test_a_file_size_limit_of_the_system_stops_the_recording_cleanly(tmp_path: Path) -> None:
    """A real write that fails half way (RLIMIT_FSIZE: EFBIG) is cut back to whole frames."""
    script = tmp_path / "recorder.py"
    script.write_text(RECORDER_WITH_A_SIZE_LIMIT, encoding="utf-8")
    directory = tmp_path / "limited"
    done = subprocess.run(
        [sys.executable, str(script), str(directory)],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert "append: " in done.stdout and "file size limit" in done.stdout, done.stdout
    assert f"close: {directory}: file size limit" in done.stdout, done.stdout
    rec = Recording.open(directory)
    assert rec.meta.status == "failed"  # meta.json is small enough to be written
    assert 0 < len(rec) < 10_000 and len(rec) % 100 == 0
    assert rec.meta.samples == len(rec)
    assert rec.problems == []
    assert sorted(p.name for p in directory.iterdir()) == [EVENTS_FILE, META_FILE, SAMPLES_FILE]


# --- bad input -----------------------------------------------------------------------------


def test_append_checks_columns_and_time(tmp_path: Path) -> None:
    with RecordingWriter.create(tmp_path / "r", XY, nominal_period_s=0.001) as writer:
        with pytest.raises(RecordingError, match=r"5 value columns .* 6 channels"):
            writer.append(block(0, 3, channels=5))
        writer.append(block(10, 3))
        with pytest.raises(RecordingError, match="goes backwards"):
            writer.append(block(12, 3))  # starts at the last row's time
        with pytest.raises(RecordingError, match="does not increase inside the block"):
            writer.append(SampleBlock(np.array([1.0, 1.0]), np.zeros((2, len(XY)))))
        with pytest.raises(RecordingError, match="nan"):
            writer.append(SampleBlock(np.array([2.0, np.nan]), np.zeros((2, len(XY)))))
        writer.append(block(13, 2))
    rec = Recording.open(tmp_path / "r")
    assert same_bits(rec.time_s, rows_for(10, 5, len(XY))[0])  # only the valid blocks
    with pytest.raises(RecordingError, match="closed"):
        writer.append(block(20, 1))


def test_create_refuses_a_directory_that_is_not_empty(tmp_path: Path) -> None:
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "notes.txt").write_text("keep me", encoding="utf-8")
    with pytest.raises(RecordingError, match="used: directory is not empty"):
        RecordingWriter.create(tmp_path / "used", XY, nominal_period_s=0.001)
    assert (tmp_path / "used" / "notes.txt").read_text(encoding="utf-8") == "keep me"
    (tmp_path / "file").write_text("", encoding="utf-8")
    with pytest.raises(RecordingError, match="not a directory"):
        RecordingWriter.create(tmp_path / "file", XY, nominal_period_s=0.001)
    (tmp_path / "empty").mkdir()
    RecordingWriter.create(tmp_path / "empty", XY, nominal_period_s=0.001).close()
    assert Recording.open(tmp_path / "empty").meta.status == "complete"


def test_meta_json_is_never_written_through_a_planted_temporary_file(tmp_path: Path) -> None:
    """A symlink or file at the old predictable name meta.json.tmp is neither followed
    nor replaced: meta.json goes through a new temporary file of its own."""
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me", encoding="utf-8")
    directory = tmp_path / "r"
    writer = RecordingWriter.create(directory, XY, nominal_period_s=0.001)
    writer.append(block(0, 5))
    (directory / "meta.json.tmp").symlink_to(victim)
    (directory / ".meta.json.tmp").write_text("someone else's", encoding="utf-8")
    writer.close()
    assert victim.read_text(encoding="utf-8") == "keep me"
    assert (directory / ".meta.json.tmp").read_text(encoding="utf-8") == "someone else's"
    assert (directory / "meta.json.tmp").is_symlink()
    assert Recording.open(directory).meta.status == "complete"
    assert sorted(p.name for p in directory.iterdir()) == sorted(
        [EVENTS_FILE, META_FILE, SAMPLES_FILE, "meta.json.tmp", ".meta.json.tmp"]
    )


def test_create_checks_its_arguments(tmp_path: Path, make_config: Make) -> None:
    with pytest.raises(ValueError, match="flush_interval_s"):
        RecordingWriter.create(tmp_path / "a", XY, nominal_period_s=0.001, flush_interval_s=1.0)
    with pytest.raises(ValueError, match="nominal_period_s"):
        RecordingWriter.create(tmp_path / "b", XY, nominal_period_s=0.0)
    with pytest.raises(RecordingError, match="axis W is not an axis of machine"):
        RecordingWriter.create(
            tmp_path / "c", channels_for(["W"]), nominal_period_s=0.001, machine=make_config()
        )
    with pytest.raises(RecordingError, match="channels appear twice: X_current_a"):
        RecordingWriter.create(tmp_path / "d", [XY[0], XY[0]], nominal_period_s=0.001)
    assert not any((tmp_path / name).exists() for name in "abcd")


def test_close_refuses_bad_metadata_updates(tmp_path: Path) -> None:
    writer = RecordingWriter.create(tmp_path / "r", XY, nominal_period_s=0.001)
    writer.append(block(0, 5))
    with pytest.raises(RecordingError, match="cannot change samples"):
        writer.close(samples=99)
    with pytest.raises(RecordingError, match="nominal_period_s"):
        writer.close(nominal_period_s=-1.0)
    with pytest.raises(RecordingError, match="colour"):
        writer.close(colour="red")
    with pytest.raises(RecordingError, match="status 'recording'"):
        writer.close("recording")
    assert not writer.closed  # still usable after a refused close
    writer.append(block(5, 5))
    writer.close("complete", nominal_period_s=0.002)
    assert Recording.open(tmp_path / "r").meta.nominal_period_s == 0.002
    assert len(Recording.open(tmp_path / "r")) == 10


def _write_meta(directory: Path, text: str) -> Path:
    directory.mkdir()
    (directory / META_FILE).write_text(text, encoding="utf-8")
    (directory / SAMPLES_FILE).write_bytes(b"")
    return directory


def _valid_meta() -> dict[str, object]:
    return {
        "format": "ncmeasure-recording",
        "format_version": 1,
        "channels": [{"name": "X_current_a", "axis": "X", "signal": "current_a", "unit": "A"}],
        "nominal_period_s": 0.001,
        "start_utc": "2026-01-15T08:30:00.000+00:00",
    }


@pytest.mark.parametrize(
    ("meta", "message"),
    [
        (None, "not a recording \\(meta.json is missing\\)"),
        ("{not json", "meta.json: invalid JSON"),
        ('{"format": "something-else"}', "not an ncmeasure recording"),
        ('["ncmeasure-recording"]', "not an ncmeasure recording"),
        ({**_valid_meta(), "format_version": 2}, "format_version 2 is newer"),
        ({k: v for k, v in _valid_meta().items() if k != "start_utc"}, "start_utc"),
        ({**_valid_meta(), "colour": "red"}, "colour: unknown key"),
        ({**_valid_meta(), "status": "done"}, "status"),
    ],
)
def test_reading_something_that_is_not_a_recording(
    tmp_path: Path, meta: object, message: str
) -> None:
    directory = tmp_path / "r"
    if meta is None:
        directory.mkdir()
        (directory / "data.csv").write_text("1,2\n", encoding="utf-8")
    else:
        _write_meta(directory, meta if isinstance(meta, str) else json.dumps(meta))
    with pytest.raises(RecordingError, match=message) as info:
        Recording.open(directory)
    assert str(directory) in str(info.value)


def test_a_recording_without_time_scale_is_real_time(tmp_path: Path) -> None:
    """Recordings written before ``time_scale`` existed read as real time."""
    directory = _write_meta(tmp_path / "r", json.dumps({**_valid_meta(), "status": "complete"}))
    meta = Recording.open(directory).meta
    assert meta.time_scale == 1.0 and meta.faster_than_real_time is False


def test_time_scale_of_a_faster_than_real_time_run(tmp_path: Path) -> None:
    with RecordingWriter.create(
        tmp_path / "r", XY, nominal_period_s=0.004, faster_than_real_time=True, time_scale=4.0
    ):
        pass
    on_disk = json.loads((tmp_path / "r" / META_FILE).read_text(encoding="utf-8"))
    assert on_disk["time_scale"] == 4.0 and on_disk["faster_than_real_time"] is True
    assert read_recording(tmp_path / "r").meta.time_scale == 4.0
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="time_scale"):
            RecordingWriter.create(tmp_path / "bad", XY, nominal_period_s=0.004, time_scale=bad)
    directory = _write_meta(tmp_path / "neg", json.dumps({**_valid_meta(), "time_scale": -2}))
    with pytest.raises(RecordingError, match="time_scale"):
        Recording.open(directory)


def test_reading_a_missing_directory_or_a_file(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="no such recording directory"):
        Recording.open(tmp_path / "nowhere")
    (tmp_path / "file").write_text("x", encoding="utf-8")
    with pytest.raises(RecordingError, match="a recording is a directory"):
        Recording.open(tmp_path / "file")
    directory = _write_meta(tmp_path / "r", json.dumps(_valid_meta()))
    (directory / SAMPLES_FILE).unlink()
    with pytest.raises(RecordingError, match=r"samples.bin is missing"):
        Recording.open(directory)


def test_a_minimal_recording_written_by_hand_reads(tmp_path: Path) -> None:
    """The format is open: meta.json plus frames packed with struct are a recording."""
    directory = _write_meta(tmp_path / "r", json.dumps({**_valid_meta(), "status": "complete"}))
    rows = np.array([[0.0, 1.5], [0.001, -2.25]], dtype="<f8")
    payload = rows.tobytes()
    header = struct.pack("<4sIII", b"NCMF", 2, zlib.crc32(payload), 0)
    (directory / SAMPLES_FILE).write_bytes(header + payload)
    rec = Recording.open(directory)
    assert same_bits(rec.column("X_current_a"), np.array([1.5, -2.25]))
    assert rec.events == []
    assert rec.problems == ["events.jsonl is missing: no events"]


def test_unknown_channel(tmp_path: Path) -> None:
    write_frames(tmp_path / "r", frames=1, rows_per_frame=2)
    rec = Recording.open(tmp_path / "r")
    with pytest.raises(RecordingError, match=r"no channel 'Z_current_a'.*X_current_a"):
        rec.axis_signal("Z", "current_a")


def test_channel_names() -> None:
    assert channel_from_name("Z1_velocity_cmd_mm_min") == Channel(
        "Z1", "velocity_cmd_mm_min", "mm/min"
    )
    assert channel_from_name("X_velocity_mm_min") == Channel("X", "velocity_mm_min", "mm/min")
    assert channel_from_name("X_marker") == Channel("X", "marker", "1")
    assert channel_from_name("_current_a") is None
    assert channel_from_name("X_current") is None
    assert channel_from_name("X Y_current_a") is None


def test_the_numpy_only_reader_of_the_docs(tmp_path: Path) -> None:
    """docs/recording-format.md shows how to read a recording without ncmeasure: it works."""
    docs = Path(__file__).parents[1] / "docs" / "recording-format.md"
    text = docs.read_text(encoding="utf-8")
    section = text.split("## Reading a recording without ncmeasure", 1)[1]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    directory = tmp_path / "run"
    write_frames(directory, frames=3, rows_per_frame=7)
    with RecordingWriter.create(tmp_path / "other", XY, nominal_period_s=0.001) as writer:
        writer.add_event(LinkEvent(0.0, "info", "hello"))
    (directory / EVENTS_FILE).write_bytes((tmp_path / "other" / EVENTS_FILE).read_bytes())
    with (directory / SAMPLES_FILE).open("ab") as file:
        file.write(b"NCMF\x05")  # a torn tail
    namespace: dict[str, object] = {}
    exec(code.replace('"run-2026-01-15"', repr(str(directory))), namespace)
    time_s, values = rows_for(0, 21, len(XY))
    assert same_bits(namespace["time_s"], time_s)  # type: ignore[arg-type]
    assert same_bits(namespace["values"], values)  # type: ignore[arg-type]
    assert same_bits(namespace["current_x"], values[:, 0])  # type: ignore[arg-type]
    assert namespace["events"] == [
        {"time_s": 0.0, "kind": "info", "message": "hello", "axis": None, "lost_samples": 0,
         "details": {}}
    ]  # fmt: skip


@pytest.mark.parametrize("rows", [1, 7, 250, 10_000])
def test_chunks_hold_the_rows_of_the_whole_read_also_before_a_damaged_frame(
    tmp_path: Path, rows: int
) -> None:
    """Chunks of any size (smaller and larger than a frame) give the rows, in order, that
    Recording.open gives; a frame failing its checksum ends both at the same row."""
    channels = channels_for(("X", "Y"), ("current_a", "velocity_mm_min"))
    directory = tmp_path / "run"
    with RecordingWriter.create(directory, channels, nominal_period_s=0.001) as writer:
        for first in range(0, 2000, 300):
            time_s = np.arange(first, first + 300) * 0.001
            values = np.random.default_rng(first).normal(size=(300, len(channels)))
            writer.append(SampleBlock(time_s, values))
            writer.flush()
    whole = Recording.open(directory)
    wanted = ("Y_velocity_mm_min", "X_current_a")
    chunks = list(iter_chunks(directory, rows, wanted))
    assert [c.first for c in chunks] == list(range(0, len(whole), rows))
    assert all(len(c.time_s) == rows for c in chunks[:-1])
    assert np.array_equal(np.concatenate([c.time_s for c in chunks]), whole.time_s)
    expected = np.column_stack([whole.column(name) for name in wanted])
    assert np.array_equal(np.concatenate([c.values for c in chunks]), expected)

    samples = directory / SAMPLES_FILE
    data = bytearray(samples.read_bytes())
    data[-100] ^= 0xFF  # a bit flip in the last frame's payload
    samples.write_bytes(bytes(data))
    damaged = Recording.open(directory)
    problems: list[str] = []
    rest = list(iter_chunks(directory, rows, wanted, problems))
    assert np.array_equal(np.concatenate([c.time_s for c in rest]), damaged.time_s)
    assert problems == [p for p in damaged.problems if "checksum" in p]


@pytest.mark.parametrize("rows", [64, 250, 10_000])
def test_chunks_from_a_row_on_begin_with_its_frame_and_read_none_before(
    tmp_path: Path, rows: int
) -> None:
    """first_row: the frames before the one holding it are neither read nor checked; the
    rows from that frame on are the whole read's, at their place in the recording."""
    channels = channels_for(("X", "Y"), ("current_a", "velocity_mm_min"))
    directory = tmp_path / "run"
    with RecordingWriter.create(directory, channels, nominal_period_s=0.001) as writer:
        for first in range(0, 2000, 300):  # frames of 300 rows (the last of 200)
            time_s = np.arange(first, first + 300) * 0.001
            values = np.random.default_rng(first).normal(size=(300, len(channels)))
            writer.append(SampleBlock(time_s, values))
            writer.flush()
    whole = Recording.open(directory)
    wanted = ("Y_velocity_mm_min", "X_current_a")
    samples = directory / SAMPLES_FILE
    data = bytearray(samples.read_bytes())
    data[frame_offsets(samples, 1 + len(channels))[1] + FRAME_HEADER.size] ^= 0xFF  # frame 1
    samples.write_bytes(bytes(data))
    for first_row, frame_start in [(0, None), (599, None), (600, 600), (1000, 900), (1999, 1800)]:
        problems: list[str] = []
        chunks = list(iter_chunks(directory, rows, wanted, problems, first_row=first_row))
        if frame_start is None:  # frame 1 is read: its damage ends the rows there
            assert problems and problems[0].startswith("frame 1 fails its checksum")
            continue
        assert not problems
        assert chunks[0].first == frame_start
        assert [c.first for c in chunks] == list(range(frame_start, len(whole), rows))
        assert np.array_equal(
            np.concatenate([c.time_s for c in chunks]), whole.time_s[frame_start:]
        )
        expected = np.column_stack([whole.column(name) for name in wanted])[frame_start:]
        assert np.array_equal(np.concatenate([c.values for c in chunks]), expected)


def _three_frames(directory: Path, quantities: tuple[str, ...]) -> Path:
    """A recording of axis X with these quantities: three frames of 1,000 rows at 1 kHz,
    every value of a frame its first row's index."""
    channels = channels_for(("X",), quantities)
    with RecordingWriter.create(directory, channels, nominal_period_s=0.001) as writer:
        for first in range(0, 3000, 1000):
            time_s = np.arange(first, first + 1000) * 0.001
            writer.append(SampleBlock(time_s, np.full((1000, len(quantities)), float(first))))
            writer.flush()
    return directory


def test_frames_larger_than_a_chunk_are_checked_once_for_many_reads(tmp_path: Path) -> None:
    """A frame larger than a chunk is read in chunks, never whole; a damaged one gives no
    row at all, wherever its damage; the frames checked once are not checked again."""
    directory = _three_frames(tmp_path / "run", ("current_a",))
    samples = directory / SAMPLES_FILE
    offsets = frame_offsets(samples, 2)
    verified: set[int] = set()
    for _ in range(2):
        chunks = list(iter_chunks(directory, 64, verified=verified))
        assert np.array_equal(
            np.concatenate([c.time_s for c in chunks]), Recording.open(directory).time_s
        )
    assert verified == set(offsets)
    data = bytearray(samples.read_bytes())
    data[offsets[1] + FRAME_HEADER.size + 8] ^= 0x01  # the first row of frame 1
    samples.write_bytes(bytes(data))
    problems: list[str] = []
    rows = np.concatenate([c.time_s for c in iter_chunks(directory, 64, problems=problems)])
    assert len(rows) == 1000
    assert problems and problems[0].startswith("frame 1 fails its checksum")


def test_a_reading_reads_every_frame_once_and_gives_no_row_of_a_damaged_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Frames larger than a chunk: the first reading checks each frame on the bytes it
    gives (one read of every payload byte, not a check and a second read); a later
    reading skips the checks of the frames checked; a damaged frame still gives no row,
    the rows before it all."""
    directory = _three_frames(tmp_path / "run", ("current_a", "velocity_mm_min"))
    payload = 3000 * 8 * 3 + 3 * FRAME_HEADER.size  # the headers are read too
    read = [0]
    exactly = recording_reader._read_exactly

    def counted(file: Any, target: memoryview) -> int:
        got = exactly(file, target)
        read[0] += got
        return got

    monkeypatch.setattr(recording_reader, "_read_exactly", counted)
    whole = Recording.open(directory)
    read[0] = 0
    verified: set[int] = set()
    chunks = list(iter_chunks(directory, 64, ("X_velocity_mm_min",), verified=verified))
    assert read[0] == payload
    assert np.array_equal(np.concatenate([c.time_s for c in chunks]), whole.time_s)
    assert np.array_equal(np.concatenate([c.values[:, 0] for c in chunks]), whole.values[:, 1])
    samples = directory / SAMPLES_FILE
    offsets = frame_offsets(samples, 3)
    assert verified == set(offsets)

    data = bytearray(samples.read_bytes())
    data[offsets[2] - 8] ^= 0x01  # the last row of frame 1
    samples.write_bytes(bytes(data))
    for rows in (64, 700, 5000):
        problems: list[str] = []
        given = list(iter_chunks(directory, rows, problems=problems))
        assert np.array_equal(np.concatenate([c.time_s for c in given]), whole.time_s[:1000])
        assert [c.first for c in given] == list(range(0, 1000, rows))
        assert problems and problems[0].startswith("frame 1 fails its checksum")
