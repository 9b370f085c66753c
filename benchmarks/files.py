"""CPU time and peak memory of the CSV export and import and the trace importers, against polars.

Each task runs twice in a fresh interpreter, once as ncmeasure does it and once as
a competent engineer would write it with polars today (the baseline: the same work,
the same values out), and prints the CPU time of each (``time.process_time``: all
threads of the process, so a parallel polars pays for both cores), the peak resident
memory (``ru_maxrss``) and the ratio ncmeasure / polars (goal: at most 1.5). After
each pair the two outputs are compared value for value (bit for bit, NaN for NaN):
"same" or the first difference.

The tasks, on generated inputs (the recording: ``--rows`` rows of time and 13
channels, three axes at 1 kHz and a marker, values with all their digits as a
drive delivers them; the trace files: the layouts of ``benchmarks/import_memory.py``,
``--size-mb`` each):

* export: ``ncmeasure export`` of the recording to CSV / the recording read with
  numpy, a polars frame written with ``write_csv`` (shortest round-trip floats);
* import: the CSV back into a recording / ``polars.read_csv`` and the recording writer;
* sinumerik-csv: a SINUMERIK trace CSV (positions in every other row) /
  ``read_csv``, forward fill, rows before every signal has a value dropped, the writer;
* twincat-csv: a TwinCAT Scope CSV (decimal comma, a time column per channel, one
  channel at 2 ms that ends half-way) / ``read_csv`` with ``decimal_comma``, the
  channels merged on the union of their times with numpy (each holds its last
  value), the writer;
* tncscope: a TNCscope export (a curve at twice the cycle) / ``read_csv``, times
  from COUNT and CYCLETIME, the same merge, the writer.

The imports of the commands (numpy, polars, ncmeasure) are paid by both sides and
are part of the figures; they are small beside the work at the default sizes.

Run:  python benchmarks/files.py [--rows 3600000] [--size-mb 200] [--tasks ...]
      python benchmarks/files.py --short     (small inputs: only checks that nothing crashes)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Final

from import_memory import write_sinumerik_csv, write_tncscope, write_twincat

GOAL: Final = 1.5
MB: Final = 1_000_000

#: The child: runs one side of one task, prints its CPU time and peak memory as JSON.
_CHILD: Final = r'''
import json, resource, sys, time
side, task, source, target = sys.argv[1:5]
start = time.process_time()
import numpy as np
from pathlib import Path

CHUNK = 100_000


def write(target, names, time_s, values, period_s):
    from ncmeasure.recording import RecordingWriter
    from ncmeasure.recording.format import channel_from_name
    from ncmeasure.samples import SampleBlock

    channels = [channel_from_name(n) for n in names]
    with RecordingWriter.create(
        target, channels, nominal_period_s=period_s, source="polars",
        faster_than_real_time=True,
    ) as writer:
        for first in range(0, len(time_s), CHUNK):
            rows = slice(first, first + CHUNK)
            writer.append(SampleBlock(
                np.ascontiguousarray(time_s[rows]), np.ascontiguousarray(values[rows])
            ))


def merge(series):
    """Rows on the union of the channels' times, each holding its last value."""
    start = max(t[0] for t, _ in series)
    end = min(t[-1] for t, _ in series)
    times = np.unique(np.concatenate([t for t, _ in series]))
    times = times[(times >= start) & (times <= end)]
    values = np.empty((len(times), len(series)))
    for column, (t, v) in enumerate(series):
        values[:, column] = v[np.searchsorted(t, times, side="right") - 1]
    return times, values


if side == "ncmeasure":
    if task == "export":
        from ncmeasure.traces.csv import export_csv
        export_csv(source, target)
    else:
        from ncmeasure.traces import import_traces
        fmt = "csv" if task == "import" else task
        import_traces([Path(source)], Path(target), format=fmt)
else:
    import polars as pl
    if task == "export":
        from ncmeasure.recording import read_recording
        rec = read_recording(source)
        frame = pl.DataFrame(
            {"time_s": rec.time_s, **{n: rec.values[:, i] for i, n in enumerate(rec.channel_names)}}
        )
        frame.write_csv(target)
    elif task == "import":
        frame = pl.read_csv(source, infer_schema=False).cast(pl.Float64)
        data = frame.to_numpy()
        time_s = data[:, 0]
        write(target, frame.columns[1:], time_s, data[:, 1:], float(np.median(np.diff(time_s))))
    elif task == "sinumerik-csv":
        frame = pl.read_csv(source, infer_schema=False).cast(pl.Float64)
        # the channels as ncmeasure names them: current, velocity, position per axis
        order = [1, 3, 2, 4, 6, 5]
        frame = frame.select(frame.columns[0], *[frame.columns[i] for i in order])
        frame = frame.fill_null(strategy="forward").drop_nulls()
        data = frame.to_numpy()
        signals = ("current_a", "velocity_mm_min", "position_mm")
        names = [f"A{a}_{s}" for a in (1, 2) for s in signals]
        time_s = data[:, 0]
        write(target, names, time_s, data[:, 1:], float(np.median(np.diff(time_s))))
    elif task == "twincat-csv":
        with open(source, encoding="utf-8") as file:
            skip = next(i for i, line in enumerate(file) if not line.strip() and i > 8) + 1
        frame = pl.read_csv(
            source, separator="\t", has_header=False, skip_rows=skip, decimal_comma=True,
            null_values=[" "], schema={f"c{i}": pl.Float64 for i in range(8)},
        )
        data = [frame[f"c{i}"].drop_nulls().to_numpy() for i in range(8)]
        # X_current_a, X.ActVelo (mm/s), X.ActPos, Y_current_a; times in ms
        series = [(data[0] / 1000, data[1]), (data[2] / 1000, data[3] * 60.0),
                  (data[4] / 1000, data[5]), (data[6] / 1000, data[7])]
        time_s, values = merge(series)
        names = ["X_current_a", "X_velocity_mm_min", "X_position_mm", "Y_current_a"]
        write(target, names, time_s, values, 0.001)
    elif task == "tncscope":
        with open(source, encoding="utf-8") as file:
            skip = next(i for i, line in enumerate(file) if line.strip() == "%[DATA]") + 1
        frame = pl.read_csv(
            source, separator=";", has_header=False, skip_rows=skip,
            schema={f"c{i}": pl.Float64 for i in range(6)},
        )
        rows = len(frame)
        # v act. (mm/min), s actual (mm), i ist (A) at 3000 us; I nominal: COUNT rows // 2
        cycles = (3000, 3000, 3000, 6000)
        counts = (rows, rows, rows, rows // 2)
        series = [
            (np.arange(count) * cycle / 1e6, frame[f"c{k + 1}"].to_numpy()[:count])
            for k, (count, cycle) in enumerate(zip(counts, cycles))
        ]
        # ncmeasure's channels: the velocity, position and the current it ranks first
        time_s, values = merge(series[:3])
        write(target, ["X_velocity_mm_min", "X_position_mm", "X_current_a"], time_s, values, 0.003)
cpu = time.process_time() - start
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"cpu_s": cpu, "peak_bytes": peak}))
'''

TASKS: Final = ("export", "import", "sinumerik-csv", "twincat-csv", "tncscope")


def write_recording(directory: Path, rows: int) -> None:
    """Three axes at 1 kHz (position, velocity, commanded velocity, current) and a marker."""
    import numpy as np

    from ncmeasure.recording import RecordingWriter
    from ncmeasure.recording.format import channel_from_name
    from ncmeasure.samples import SampleBlock

    signals = ("position_mm", "velocity_mm_min", "velocity_cmd_mm_min", "current_a")
    names = [f"{axis}_{signal}" for axis in "XYZ" for signal in signals] + ["X_marker"]
    channels = [channel_from_name(name) for name in names]
    assert all(channels)
    rng = np.random.default_rng(29)
    with RecordingWriter.create(
        directory,
        [c for c in channels if c is not None],
        nominal_period_s=1e-3,
        source="synthetic",
        notes="benchmarks/files.py",
        faster_than_real_time=True,
    ) as writer:
        for first in range(0, rows, 100_000):
            count = min(100_000, rows - first)
            time_s = np.arange(first + 1, first + count + 1) / 1000.0
            phase = time_s[:, None] * np.arange(1, 14) * 0.01
            values = 150.0 * np.sin(phase) + rng.normal(0.0, 0.01, (count, 13))
            values[:, 3::4] = 3.0 * np.sin(phase[:, 3::4]) + rng.normal(0.0, 0.02, (count, 3))
            values[:, -1] = np.floor(time_s / 10) % 2
            writer.append(SampleBlock(time_s, values))


def _run(side: str, task: str, source: Path, target: Path) -> dict[str, float]:
    if target.is_dir():
        shutil.rmtree(target)
    target.unlink(missing_ok=True)
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, side, task, str(source), str(target)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode:
        sys.exit(f"{task} ({side}) failed (exit {done.returncode}):\n{done.stdout}{done.stderr}")
    result: dict[str, float] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def _same(task: str, ours: Path, theirs: Path) -> str:
    """Whether the two outputs hold the same values, bit for bit; else the first difference."""
    import numpy as np

    from ncmeasure.recording import read_recording

    if task == "export":
        import polars as pl

        a = pl.read_csv(ours, infer_schema=False).cast(pl.Float64).to_numpy()
        b = pl.read_csv(theirs, infer_schema=False).cast(pl.Float64).to_numpy()
        names_a = ours.open().readline()
        names_b = theirs.open().readline()
        if names_a != names_b:
            return "different header"
    else:
        ra, rb = read_recording(ours), read_recording(theirs)
        if sorted(ra.channel_names) != sorted(rb.channel_names):
            return f"channels differ: {ra.channel_names} / {rb.channel_names}"
        order = [rb.channel_names.index(n) for n in ra.channel_names]
        a = np.column_stack([ra.time_s, ra.values])
        b = np.column_stack([rb.time_s, rb.values[:, order]])
    if a.shape != b.shape:
        return f"shape {a.shape} / {b.shape}"
    differ = (a.view(np.int64) != b.view(np.int64)) & ~(np.isnan(a) & np.isnan(b))
    if differ.any():
        row, column = (int(i[0]) for i in np.nonzero(differ))
        return f"row {row} column {column}: {a[row, column]!r} / {b[row, column]!r}"
    return "same"


def _compare(task: str, ours: Path, theirs: Path) -> str:
    """:func:`_same` in a child: the peak memory of a child starts at its parent's (Linux
    keeps ``ru_maxrss`` across fork and exec), so this process stays small."""
    done = subprocess.run(
        [sys.executable, __file__, "--compare", task, str(ours), str(theirs)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode:
        sys.exit(f"comparing the outputs of {task} failed:\n{done.stdout}{done.stderr}")
    return done.stdout.strip()


def _make(kind: str, path: Path, size: int) -> None:
    """Write an input in a child, for the same reason as :func:`_compare`."""
    subprocess.run([sys.executable, __file__, "--make", kind, str(path), str(size)], check=True)


def main() -> None:
    if sys.argv[1:2] == ["--compare"]:
        print(_same(sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4])))
        return
    if sys.argv[1:2] == ["--make"]:
        writers = {
            "recording": write_recording,
            "sinumerik-csv": write_sinumerik_csv,
            "twincat-csv": write_twincat,
            "tncscope": write_tncscope,
        }
        writers[sys.argv[2]](Path(sys.argv[3]), int(sys.argv[4]))
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=3_600_000, help="rows of the recording")
    parser.add_argument("--size-mb", type=float, default=200.0, help="size of each trace file")
    parser.add_argument("--tasks", nargs="+", choices=TASKS, default=list(TASKS))
    parser.add_argument("--short", action="store_true", help="small inputs: a crash test")
    parser.add_argument("--work", type=Path, help="keep the inputs here (reused when present)")
    args = parser.parse_args()
    try:
        import polars  # noqa: F401
    except ImportError:
        sys.exit("polars is the baseline: pip install 'ncmeasure[dev]' (or polars)")
    rows = 20_000 if args.short else args.rows
    size_bytes = int((1.0 if args.short else args.size_mb) * MB)
    work = args.work or Path(tempfile.mkdtemp(prefix="ncmeasure-files-"))
    work.mkdir(parents=True, exist_ok=True)
    load = Path("/proc/loadavg").read_text().split()[0] if Path("/proc/loadavg").exists() else "?"
    print(
        f"CSV export/import and trace imports: CPU s and peak MB, ncmeasure vs polars; "
        f"goal ncmeasure <= {GOAL} x polars CPU"
    )
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, load {load} at the start")
    print(
        f"{'task':<14}{'input MB':>9}{'ncmeasure s':>12}{'polars s':>10}{'ratio':>7}"
        f"{'ncm. MB':>9}{'polars MB':>10}  values  goal"
    )
    try:
        recording = work / f"recording-{rows}"
        if not (recording / "meta.json").exists():
            shutil.rmtree(recording, ignore_errors=True)
            _make("recording", recording, rows)
        exported = work / f"export-{rows}.csv"
        inputs = {
            "export": recording,
            "import": exported,
            "sinumerik-csv": work / f"sinumerik-{size_bytes}.csv",
            "twincat-csv": work / f"twincat-{size_bytes}.csv",
            "tncscope": work / f"tncscope-{size_bytes}.sco",
        }
        for task in args.tasks:
            source = inputs[task]
            if task == "import" and not exported.exists():
                _run("ncmeasure", "export", recording, exported)
            if task not in ("export", "import") and not source.exists():
                _make(task, source, size_bytes)
            ending = ".csv" if task == "export" else ""
            ours = work / f"out-ncmeasure-{task}{ending}"
            theirs = work / f"out-polars-{task}{ending}"
            mine = _run("ncmeasure", task, source, ours)
            base = _run("polars", task, source, theirs)
            same = _compare(task, ours, theirs)
            if task == "export" and not exported.exists():
                ours.rename(exported)
            size = (
                sum(f.stat().st_size for f in source.iterdir())
                if source.is_dir()
                else source.stat().st_size
            ) / MB
            ratio = mine["cpu_s"] / max(base["cpu_s"], 1e-9)
            print(
                f"{task:<14}{size:9.1f}{mine['cpu_s']:12.2f}{base['cpu_s']:10.2f}{ratio:7.2f}"
                f"{mine['peak_bytes'] / MB:9.0f}{base['peak_bytes'] / MB:10.0f}  {same}  "
                f"{'met' if ratio <= GOAL else 'NOT met'}",
                flush=True,
            )
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    if args.short:
        print("short mode: a crash test; the figures of small inputs say nothing about the goal")


if __name__ == "__main__":
    main()
