"""How fast a one-hour recording reads back, against the I/O floor of its raw bytes.

Writes a one-hour, three-axis, 1 kHz recording (five signals per axis:
current, velocity, position, commanded velocity, marker; 16 float64 columns
with time_s, 3.6 M rows, about 460 MB) into a temporary directory with the
real :class:`~ncmeasure.recording.RecordingWriter`, one frame per 250 rows as
its flush thread would write them (4 frames/s). Then it times
:meth:`Recording.open` (frame walk, CRC check of every frame, one array held
column by column)
against ``np.fromfile`` of the same file (raw bytes into memory, no checks:
the floor any reader pays) in the same run, and prints both and their ratio.
Last, the CSV export time of a one-minute slice (60 000 rows).

Both reads run warm (the file is in the page cache after writing); the best of
several runs is printed. Run: python benchmarks/recording_read.py [--minutes N]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

from ncmeasure.recording import SAMPLES_FILE, Recording, RecordingWriter
from ncmeasure.samples import SIGNAL_UNITS, SampleBlock, channels_for
from ncmeasure.traces.csv import export_csv

RATE_HZ = 1000
ROWS_PER_FRAME = 250  # 4 frames/s, as the writer's flush thread writes them at 1 kHz
AXES = ("X", "Y", "Z")
REPEATS = 3
T = TypeVar("T")


def _block(start: int, count: int, columns: int) -> SampleBlock:
    """Rows ``start`` .. ``start + count`` of a plausible axis trace."""
    k = np.arange(start, start + count)
    time_s = k / RATE_HZ
    phase = 2 * np.pi * time_s / 7.0
    per_axis = np.column_stack(
        [
            0.8 * np.sin(phase) + 0.01 * np.cos(37 * phase),  # current_a
            3000.0 * np.cos(phase),  # velocity_mm_min
            50.0 * np.sin(phase),  # position_mm
            3000.0 * np.round(np.cos(phase), 2),  # velocity_cmd_mm_min
            (k // 5000 % 2).astype(np.float64),  # marker
        ]
    )
    values = np.tile(per_axis, (1, columns // per_axis.shape[1]))
    return SampleBlock(time_s, values)


def _best(run: Callable[[], T], repeats: int = REPEATS) -> tuple[float, T]:
    """The shortest of ``repeats`` runs, in seconds, and the last result."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        result = run()
        best = min(best, time.perf_counter() - start)
    return best, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="recording length")
    args = parser.parse_args()
    rows = int(args.minutes * 60 * RATE_HZ)
    channels = channels_for(AXES, tuple(SIGNAL_UNITS))

    with tempfile.TemporaryDirectory(prefix="ncmeasure-bench-") as tmp:
        directory = Path(tmp) / "recording"
        start = time.perf_counter()
        with RecordingWriter.create(
            directory, channels, nominal_period_s=1 / RATE_HZ, source="benchmark",
            flush_interval_s=0.5,
        ) as writer:  # fmt: skip
            for first in range(0, rows, ROWS_PER_FRAME):
                count = min(ROWS_PER_FRAME, rows - first)
                writer.append(_block(first, count, len(channels)))
                writer.flush()
        write_s = time.perf_counter() - start
        path = directory / SAMPLES_FILE
        size_mb = path.stat().st_size / 1e6
        frames = -(-rows // ROWS_PER_FRAME)

        floor_s, _ = _best(lambda: np.fromfile(path, dtype=np.uint8))
        read_s, recording = _best(lambda: Recording.open(directory))

        minute = dataclasses.replace(
            recording,
            time_s=recording.time_s[: 60 * RATE_HZ],
            values=recording.values[: 60 * RATE_HZ],
        )
        csv_path = Path(tmp) / "minute.csv"
        csv_s, _ = _best(lambda: export_csv(minute, csv_path), repeats=1)
        csv_mb = csv_path.stat().st_size / 1e6

    print(
        f"recording: {args.minutes:g} min, {len(AXES)} axes, {RATE_HZ} Hz, "
        f"{len(channels) + 1} columns, {frames} frames"
    )
    print(f"rows={len(recording)} size_mb={size_mb:.1f} write_s={write_s:.2f}")
    print(f"baseline np.fromfile (raw bytes, no checks): {floor_s:.3f} s")
    print(f"Recording.open (frames, CRC32, one array):   {read_s:.3f} s")
    print(f"ratio read/baseline={read_s / floor_s:.2f} read_mb_per_s={size_mb / read_s:.0f}")
    print(f"export_csv one minute: rows={len(minute)} csv_mb={csv_mb:.1f} seconds={csv_s:.2f}")


if __name__ == "__main__":
    main()
