"""The friction table of a recording as a plain numpy script would build it: the baseline.

What an engineer who knows numpy writes in an afternoon, without ncmeasure:
read the recording through its documented format (docs/recording-format.md:
``meta.json``, the frames of ``samples.bin`` with their magic, sequence
number and CRC-32), cut every axis' windows from its marker channel (a
stretch of one positive value: the window's id in ``schedule.json``, which
gives its position, direction and velocity step), and build the friction
table per (position, direction, step): median, mean, standard deviation
(ddof 1), count and the standard error as ncmeasure defines it (each window
cut into up to 5 batches of at least 5 samples, edges
``np.linspace(start, stop, batches + 1).round()``; the larger of the batch
medians' scatter over √batches and √(π/2)·std/√n, and of the window
medians' scatter over √windows where a cell has several windows).

It imports numpy and the standard library only. ``benchmarks/analysis.py``
runs it as a program (its CPU time is the baseline of ``ncmeasure
analyze``) and calls :func:`friction_tables` to check its table against
ncmeasure's.

Run: python benchmarks/baseline_script.py RECORDING SCHEDULE [--out table.npz]
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import time
import zlib
from pathlib import Path

import numpy as np

HEADER = struct.Struct("<4sIII")
BATCHES_PER_WINDOW = 5
MIN_BATCH_SAMPLES = 5


def read_columns(directory: Path, names: list[str]) -> dict[str, np.ndarray]:
    """The columns ``names`` of a recording (``time_s`` or channel names), intact frames only."""
    meta = json.loads((directory / "meta.json").read_text(encoding="utf-8"))
    channels = ["time_s", *(c["name"] for c in meta["channels"])]
    width = len(channels)
    data = (directory / "samples.bin").read_bytes()
    frames: list[tuple[int, int]] = []  # (payload offset, rows)
    offset = sequence = 0
    while offset + HEADER.size <= len(data):
        magic, n, crc, seq = HEADER.unpack_from(data, offset)
        size = 8 * n * width
        end = offset + HEADER.size + size
        if magic != b"NCMF" or seq != sequence or end > len(data):
            break  # torn tail
        if zlib.crc32(memoryview(data)[offset + HEADER.size : end]) != crc:
            break  # damaged frame: it and the rest are not read
        frames.append((offset + HEADER.size, n))
        offset, sequence = end, sequence + 1
    total = sum(n for _, n in frames)
    columns = {name: np.empty(total) for name in names}
    at = 0
    for start, n in frames:
        rows = np.frombuffer(data, dtype="<f8", count=n * width, offset=start).reshape(n, width)
        for name, column in columns.items():
            column[at : at + n] = rows[:, channels.index(name)]
        at += n
    return columns


def marker_windows(marker: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start, stop and value of every stretch of one positive marker value."""
    changes = np.flatnonzero(marker[1:] != marker[:-1]) + 1
    starts = np.concatenate(([0], changes))
    stops = np.concatenate((changes, [len(marker)]))
    values = marker[starts]
    kept = values > 0
    return starts[kept], stops[kept], values[kept].astype(np.int64)


def segment_medians(values: np.ndarray, segment: np.ndarray, count: int) -> np.ndarray:
    """The median of the values of every segment 0 .. count - 1 (segments contiguous)."""
    ordered = values[np.lexsort((values, segment))]
    sizes = np.bincount(segment, minlength=count)
    first = np.cumsum(sizes) - sizes
    low = ordered[first + (sizes - 1) // 2]
    high = ordered[first + sizes // 2]
    return (low + high) / 2


def scatter(medians: np.ndarray, cell: np.ndarray, cells: int) -> np.ndarray:
    """Standard deviation (ddof 1) of the medians of each cell over the root of their count."""
    n = np.bincount(cell, minlength=cells)
    mean = np.bincount(cell, weights=medians, minlength=cells) / n
    squares = np.bincount(cell, weights=(medians - mean[cell]) ** 2, minlength=cells)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(squares / (n - 1)) / np.sqrt(n)


def axis_table(
    current: np.ndarray, starts: np.ndarray, stops: np.ndarray, labels: np.ndarray
) -> dict[str, np.ndarray]:
    """The friction table of one axis from its windows and their (position, direction, step)."""
    order = np.lexsort((starts, labels[:, 2], labels[:, 1], labels[:, 0]))
    starts, stops, labels = starts[order], stops[order], labels[order]
    lengths = stops - starts
    offsets = np.cumsum(lengths) - lengths
    total = int(lengths.sum())
    index = np.arange(total) + np.repeat(starts - offsets, lengths)
    values = current[index]
    # Cells: runs of equal labels among the sorted windows.
    new_cell = np.r_[True, np.any(labels[1:] != labels[:-1], axis=1)]
    window_cell = np.cumsum(new_cell) - 1
    cells = int(window_cell[-1]) + 1 if len(window_cell) else 0
    window = np.repeat(np.arange(len(starts)), lengths)
    # Batches: up to 5 per window, edges linspace(start, stop, count + 1).round().
    count = np.maximum(1, np.minimum(BATCHES_PER_WINDOW, lengths // MIN_BATCH_SAMPLES))
    owner = np.repeat(np.arange(len(starts)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + 1
    edges = np.round(k * (lengths / count)[owner] + offsets[owner]).astype(np.intp)
    last = k == count[owner]
    edges[last] = (offsets + lengths)[owner][last]
    batch = np.zeros(total + 1, dtype=np.intp)
    np.add.at(batch, edges, 1)
    batch = np.cumsum(batch[:total])
    finite = np.isfinite(values)
    if not finite.all():
        values, window, batch = values[finite], window[finite], batch[finite]
    cell = window_cell[window]
    n = np.bincount(cell, minlength=cells)
    mean = np.bincount(cell, weights=values, minlength=cells) / n
    with np.errstate(invalid="ignore", divide="ignore"):
        std = np.sqrt(
            np.bincount(cell, weights=(values - mean[cell]) ** 2, minlength=cells) / (n - 1)
        )
    median = segment_medians(values, cell, cells)
    batches = int(count.sum())
    batch_median = segment_medians(values, batch, batches)
    batch_cell = window_cell[owner]
    stderr = np.fmax(
        scatter(batch_median, batch_cell, cells), math.sqrt(math.pi / 2) * std / np.sqrt(n)
    )
    window_median = segment_medians(values, window, len(starts))
    several = np.bincount(window_cell, minlength=cells) > 1
    stderr = np.where(several, np.fmax(scatter(window_median, window_cell, cells), stderr), stderr)
    first = np.flatnonzero(new_cell)
    return {
        "position_index": labels[first, 0],
        "direction": labels[first, 1],
        "step": labels[first, 2],
        "median": median,
        "mean": mean,
        "std": std,
        "n": n,
        "stderr": stderr,
        "starts": starts,  # the windows, in table order, and their labels
        "stops": stops,
        "labels": labels,
    }


def friction_tables(recording: Path, schedule: Path) -> dict[str, dict[str, np.ndarray]]:
    """The friction table of every axis of the schedule whose marker was recorded."""
    plan = json.loads(schedule.read_text(encoding="utf-8"))
    meta = json.loads((recording / "meta.json").read_text(encoding="utf-8"))
    recorded = {c["name"] for c in meta["channels"]}
    axes = [a for a in plan["axes"] if f"{a['name']}_marker" in recorded]
    names = [f"{a['name']}_{s}" for a in axes for s in ("current_a", "marker")]
    columns = read_columns(recording, names)
    tables = {}
    for axis in axes:
        name = axis["name"]
        labels_by_id = {
            w["id"]: (w["position_index"], w["direction"], w["step"]) for w in axis["windows"]
        }
        starts, stops, ids = marker_windows(columns[f"{name}_marker"])
        known = np.array([i in labels_by_id for i in ids.tolist()], dtype=bool)
        starts, stops = starts[known], stops[known]
        labels = np.array([labels_by_id[i] for i in ids[known].tolist()], dtype=np.int64)
        tables[name] = axis_table(columns[f"{name}_current_a"], starts, stops, labels)
    return tables


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("schedule", type=Path)
    parser.add_argument("--out", type=Path, help="write the tables to this .npz")
    args = parser.parse_args()
    start = time.process_time()
    tables = friction_tables(args.recording, args.schedule)
    cells = sum(len(t["median"]) for t in tables.values())
    print(f"{cells} cells, {len(tables)} axes, {time.process_time() - start:.3f} s CPU")
    if args.out is not None:
        np.savez(args.out, **{f"{a}/{k}": v for a, t in tables.items() for k, v in t.items()})


if __name__ == "__main__":
    main()
