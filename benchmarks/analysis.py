"""How fast ncmeasure builds the friction table, against a plain pandas groupby.

Simulates a measurement of about one hour: three axes measured one after the
other (50 geometric steps 10..15 000 mm/min, 5 positions, both directions,
2 repetitions: 1000 windows per axis), sampled at 1 kHz (about 3.5 M rows,
16 float64 columns: time and five signals per axis), and writes it as a real
recording with :class:`~ncmeasure.recording.RecordingWriter` into a
temporary directory, then reads it back (:meth:`Recording.open
<ncmeasure.recording.Recording.open>`: every channel one contiguous column,
the layout every side below gathers from). The windows are found once (marker
and schedule; the time is printed). Then, in the same run, the table
(median, mean, standard deviation and count of the current per axis,
position, direction and step, over every sample of the windows) is built
from the same windows:

* ncmeasure: :func:`~ncmeasure.analysis.friction.table.friction_table`, one call per
  axis (which also computes the batch standard errors: more work than the
  baselines do);
* pandas: one DataFrame per window (current and its labels), ``pd.concat``,
  and ``groupby([axis, position, direction, step]).agg(median, mean, std, count)``;
* pandas again, with the per-sample label columns built by ``np.repeat``
  (as ncmeasure builds them) so that only the groupby is pandas': the floor
  for any pandas version of the table without its standard error;
* pandas doing the same work as ncmeasure: the labels built with numpy as
  above (plus the window and batch of every sample), and pandas groupbys for
  the table, the batch and window medians and their scatter, which give the
  standard error (:func:`pandas_table_same_work`).

All three start from the same windows and the same in-memory recording and
end with the finished table: each gathers the current of the window samples
itself. They run in interleaved rounds (ncmeasure, pandas, pandas prebuilt,
ncmeasure, ...), so a busy computer slows all alike; the median and the range
over the rounds are printed, in window samples per second (the samples the
step processes, not recording rows), with the ratios and the goals
(issue "performance": >= 40 M window samples/s, >= 5 x pandas). The ratio
goal is taken against pandas doing the same work (the benchmarks compare the
same work on both sides); the ratio against the table without the standard
error is printed beside it. Last, the tables are compared cell by cell
(the standard error too, against the same-work version) and the largest
difference printed.

Run: python benchmarks/analysis.py [--rounds N] [--repetitions N] [--short]
(``--short``: one repetition of a 10-step program, a few minutes of
recording, 2 rounds: checks that it runs, the figures mean nothing.)
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np
import pandas as pd  # type: ignore[import-untyped]
from analysis_memory import _write as write_copies
from baseline_script import axis_table, friction_tables
from measurement import measurement_axes

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.friction.table import FrictionTable, friction_table
from ncmeasure.analysis.windows.find import windows_of
from ncmeasure.analysis.windows.model import Segmentation, VelocityWindow
from ncmeasure.analysis.windows.settings import SegmentSettings
from ncmeasure.formats.schedule import load_schedule
from ncmeasure.recording import Recording, RecordingHead
from ncmeasure.recording.reader import READ_COUNT
from ncmeasure.sim.synthetic import synthetic_recording

T = TypeVar("T")
RATE_HZ = 1000
SETTINGS = SegmentSettings()


GOAL_SAMPLES_PER_S = 40e6
GOAL_VS_PANDAS = 5.0
GOAL_VS_SCRIPT = 2.0  # ncmeasure analyze at most this many times the plain script's CPU
GOAL_REAL_TIME = 1000.0  # without a marker: recorded seconds per second of CPU
BENCHMARKS = Path(__file__).resolve().parent


def _interleaved(
    runs: dict[str, Callable[[], T]], rounds: int
) -> tuple[dict[str, list[float]], dict[str, T]]:
    """Every run once per round, in turn; the seconds of each round and the last results."""
    seconds: dict[str, list[float]] = {name: [] for name in runs}
    results: dict[str, T] = {}
    for _ in range(rounds):
        for name, run in runs.items():
            start = time.perf_counter()
            results[name] = run()
            seconds[name].append(time.perf_counter() - start)
    return seconds, results


def ncmeasure_tables(
    recording: Recording, segmentations: dict[str, Segmentation]
) -> list[FrictionTable]:
    return [
        friction_table(
            axis,
            recording.axis_signal(axis, "current_a"),
            seg.windows,
        )
        for axis, seg in segmentations.items()
    ]


def pandas_table(recording: Recording, segmentations: dict[str, Segmentation]) -> pd.DataFrame:
    frames = []
    for axis, seg in segmentations.items():
        current = recording.axis_signal(axis, "current_a")
        for w in seg.windows:
            frames.append(
                pd.DataFrame(
                    {
                        "axis": axis,
                        "position": w.position_index,
                        "direction": w.direction,
                        "step": w.step,
                        "current": current[w.start : w.stop],
                    }
                )
            )
    samples = pd.concat(frames, ignore_index=True)
    kept = samples[np.isfinite(samples["current"])]
    return (
        kept.groupby(["axis", "position", "direction", "step"])["current"]
        .agg(["median", "mean", "std", "count"])
        .sort_index()
    )


def pandas_table_prebuilt(
    recording: Recording, segmentations: dict[str, Segmentation]
) -> pd.DataFrame:
    names = list(segmentations)
    columns: dict[str, list[np.ndarray]] = {
        k: [] for k in ("axis", "position", "direction", "step", "current")
    }
    for number, (axis, seg) in enumerate(segmentations.items()):
        current = recording.axis_signal(axis, "current_a")
        starts = np.array([w.start for w in seg.windows])
        lengths = np.array([w.samples for w in seg.windows])
        offsets = np.cumsum(lengths) - lengths
        index = np.arange(lengths.sum()) + np.repeat(starts - offsets, lengths)
        for name, values in (
            ("position", [w.position_index for w in seg.windows]),
            ("direction", [w.direction for w in seg.windows]),
            ("step", [w.step for w in seg.windows]),
        ):
            columns[name].append(np.repeat(np.asarray(values), lengths))
        columns["axis"].append(np.full(len(index), number))
        columns["current"].append(current[index])
    data = {k: np.concatenate(v) for k, v in columns.items()}
    samples = pd.DataFrame(
        {**data, "axis": pd.Categorical.from_codes(data["axis"], categories=names)}
    )
    kept = samples[np.isfinite(samples["current"])]
    return (
        kept.groupby(["axis", "position", "direction", "step"], observed=True)["current"]
        .agg(["median", "mean", "std", "count"])
        .sort_index()
    )


def same_work_samples(
    recording: Recording, segmentations: dict[str, Segmentation]
) -> dict[str, np.ndarray]:
    """Every window sample with integer labels: axis number, position, direction, step,
    window and batch (as :func:`pandas_table_same_work` describes them), and its current."""
    parts: dict[str, list[np.ndarray]] = {
        k: [] for k in ("axis", "position", "direction", "step", "window", "batch", "current")
    }
    window_count = batch_count = 0
    for number, (axis, seg) in enumerate(segmentations.items()):
        current = recording.axis_signal(axis, "current_a")
        windows = sorted(
            seg.windows, key=lambda w: (w.position_index, w.direction, w.step, w.start)
        )
        starts = np.array([w.start for w in windows])
        lengths = np.array([w.samples for w in windows])
        offsets = np.cumsum(lengths) - lengths
        index = np.arange(lengths.sum()) + np.repeat(starts - offsets, lengths)
        for name, values in (
            ("position", [w.position_index for w in windows]),
            ("direction", [w.direction for w in windows]),
            ("step", [w.step for w in windows]),
        ):
            parts[name].append(np.repeat(np.asarray(values), lengths))
        parts["axis"].append(np.full(len(index), number))
        parts["window"].append(np.repeat(np.arange(len(windows)) + window_count, lengths))
        # Batch edges: k * ((stop - start) / count) + start, rounded, per window.
        count = np.maximum(1, np.minimum(5, lengths // 5))
        owner = np.repeat(np.arange(len(windows)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + 1
        edges = np.round(k * (lengths / count)[owner] + offsets[owner]).astype(np.intp)
        edges[k == count[owner]] = (offsets + lengths)[owner][k == count[owner]]
        batch = np.zeros(len(index), dtype=np.intp)
        np.add.at(batch, edges[edges < len(index)], 1)
        parts["batch"].append(np.cumsum(batch) + batch_count)
        window_count += len(windows)
        batch_count += int(count.sum())
        parts["current"].append(current[index])
    return {k: np.concatenate(v) for k, v in parts.items()}


def pandas_table_same_work(
    recording: Recording, segmentations: dict[str, Segmentation]
) -> pd.DataFrame:
    """The whole table ncmeasure builds, standard error included, with pandas groupbys.

    Labels per sample built with numpy (group, window, batch: each window cut into
    up to 5 batches of at least 5 samples, edges rounded as
    ``np.linspace(start, stop, batches + 1)`` over the samples in table order);
    pandas does every grouping: the median, mean, std and count per group, the
    median per batch and per window, and their scatter over the root of their
    count. The standard error is ncmeasure's: the larger of the batch medians'
    scatter and √(π/2)·std/√n, and of the window medians' scatter where a group
    has more than one window.
    """
    data = same_work_samples(recording, segmentations)
    keys = ["axis", "position", "direction", "step"]
    samples = pd.DataFrame(
        {**data, "axis": pd.Categorical.from_codes(data["axis"], categories=list(segmentations))}
    )
    table = samples.groupby(keys, observed=True)["current"].agg(["median", "mean", "std", "count"])
    scatter = []
    for unit in ("batch", "window"):
        medians = samples.groupby(unit, sort=False).agg(
            {"current": "median", **dict.fromkeys(keys, "first")}
        )
        spread = medians.groupby(keys, observed=True)["current"].agg(["std", "count"])
        scatter.append(spread["std"] / np.sqrt(spread["count"]))
    independent = np.sqrt(np.pi / 2) * table["std"] / np.sqrt(table["count"])
    stderr = np.fmax(scatter[0].reindex(table.index), independent)
    table["stderr"] = np.fmax(scatter[1].reindex(table.index), stderr)
    return table.sort_index()


def polars_table_same_work(
    recording: Recording, segmentations: dict[str, Segmentation]
) -> pd.DataFrame:
    """The same table with polars (integer keys): group_by for the cells, batches and windows."""
    import polars as pl

    keys = ["axis", "position", "direction", "step"]
    samples = pl.DataFrame(same_work_samples(recording, segmentations))
    current = pl.col("current")
    table = samples.group_by(keys).agg(
        current.median().alias("median"),
        current.mean().alias("mean"),
        current.std().alias("std"),
        pl.len().alias("count"),
    )
    for unit in ("batch", "window"):
        medians = samples.group_by(unit).agg(current.median(), *(pl.col(k).first() for k in keys))
        spread = medians.group_by(keys).agg(
            (current.std() / pl.len().cast(pl.Float64).sqrt()).alias(f"scatter_{unit}"),
            pl.len().alias(f"count_{unit}"),
        )
        table = table.join(spread, on=keys, how="left")
    independent = math.sqrt(math.pi / 2) * pl.col("std") / pl.col("count").cast(pl.Float64).sqrt()
    several = pl.when(pl.col("count_window") > 1).then(pl.col("scatter_window"))
    table = table.with_columns(
        pl.max_horizontal(pl.col("scatter_batch"), independent, several).alias("stderr")
    ).sort(keys)
    names = list(segmentations)
    return (
        table.select(*keys, "median", "mean", "std", "count", "stderr")
        .to_pandas()
        .assign(axis=lambda f: [names[a] for a in f["axis"]])
        .set_index(keys)
    )


def duckdb_table_same_work(
    recording: Recording, segmentations: dict[str, Segmentation]
) -> pd.DataFrame:
    """The same table in SQL with duckdb (integer keys), on the same numpy arrays."""
    import duckdb

    samples = pd.DataFrame(same_work_samples(recording, segmentations))  # noqa: F841 (in SQL)
    table = duckdb.sql(
        """
        WITH cells AS (SELECT axis, position, direction, step, median(current) AS median,
                avg(current) AS mean, stddev_samp(current) AS std, count(*) AS count
            FROM samples GROUP BY ALL),
        batches AS (SELECT axis, position, direction, step, batch, median(current) AS m
            FROM samples GROUP BY ALL),
        windows AS (SELECT axis, position, direction, step, "window", median(current) AS m
            FROM samples GROUP BY ALL),
        batch_scatter AS (SELECT axis, position, direction, step,
                stddev_samp(m) / sqrt(count(*)) AS s FROM batches GROUP BY ALL),
        window_scatter AS (SELECT axis, position, direction, step,
                stddev_samp(m) / sqrt(count(*)) AS s, count(*) AS n FROM windows GROUP BY ALL)
        SELECT c.*, greatest(b.s, sqrt(pi() / 2) * c.std / sqrt(c.count),
                CASE WHEN w.n > 1 THEN w.s END) AS stderr
        FROM cells c JOIN batch_scatter b USING (axis, position, direction, step)
            JOIN window_scatter w USING (axis, position, direction, step)
        ORDER BY axis, position, direction, step
        """
    ).df()
    names = list(segmentations)
    table["axis"] = [names[a] for a in table["axis"]]
    return table.set_index(["axis", "position", "direction", "step"])


def _optional_baselines() -> dict[str, str]:
    """polars and duckdb where installed (the dev extra): name -> label."""
    found = {}
    for module, name, label in (
        ("polars", "polars", "polars, same work (+ standard error)"),
        ("duckdb", "duckdb", "duckdb SQL, same work (+ standard error)"),
    ):
        try:
            __import__(module)
        except ImportError:
            print(f"({module} not installed: its baseline is left out; pip install {module})")
            continue
        found[name] = label
    return found


def _as_frame(tables: Sequence[FrictionTable]) -> pd.DataFrame:
    parts = [
        pd.DataFrame(
            {
                "axis": t.axis,
                "position": t.position_index,
                "direction": t.direction,
                "step": t.step,
                "median": t.median,
                "mean": t.mean,
                "std": t.std,
                "count": t.n,
                "stderr": t.stderr,
            }
        )
        for t in tables
    ]
    return pd.concat(parts).set_index(["axis", "position", "direction", "step"]).sort_index()


def numpy_tables(
    recording: Recording, segmentations: dict[str, Segmentation]
) -> dict[str, dict[str, np.ndarray]]:
    """The plain numpy script's table (``baseline_script.axis_table``) on the same windows."""
    tables = {}
    for axis, seg in segmentations.items():
        windows = seg.windows
        tables[axis] = axis_table(
            recording.axis_signal(axis, "current_a"),
            np.array([w.start for w in windows]),
            np.array([w.stop for w in windows]),
            np.array([(w.position_index, w.direction, w.step) for w in windows]),
        )
    return tables


def _numpy_frame(tables: dict[str, dict[str, np.ndarray]]) -> pd.DataFrame:
    keys = ("position_index", "direction", "step", "median", "mean", "std", "n", "stderr")
    parts = [
        pd.DataFrame({"axis": axis, **{k: t[k] for k in keys}}).rename(
            columns={"position_index": "position", "n": "count"}
        )
        for axis, t in tables.items()
    ]
    return pd.concat(parts).set_index(["axis", "position", "direction", "step"]).sort_index()


def _differences(mine: pd.DataFrame, theirs: pd.DataFrame) -> str:
    joined = mine.join(theirs.add_suffix("_other"), how="outer")
    found = ", ".join(
        f"{column} {(joined[column] - joined[f'{column}_other']).abs().max():.3g}"
        for column in ("median", "mean", "std", "count", "stderr")
        if f"{column}_other" in joined
    )
    return f"rows {len(mine)} / {len(theirs)} / joined {len(joined)}; max |difference|: {found}"


def child_cpu(command: list[str]) -> float:
    """CPU seconds (user + system) of ``command`` run in a fresh process; it must succeed."""
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    assert child.stderr is not None
    error = child.stderr.read()
    _, status, usage = os.wait4(child.pid, 0)
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"{' '.join(command)} failed:\n{error.decode(errors='replace')}")
    return usage.ru_utime + usage.ru_stime


def _analyze_command(run: Path, schedule: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "ncmeasure", "analyze", str(run), "--schedule", str(schedule),
            "-o", str(out), "-q"]  # fmt: skip


def rows_read(run: Path, schedule: Path) -> tuple[int, int, int, float]:
    """Rows and readings of samples.bin of one analysis (in this process), its rows, its CPU."""
    rows, readings = READ_COUNT.rows, READ_COUNT.readings
    head = RecordingHead.open(run)
    cpu = time.process_time()
    analyze(head, schedule=load_schedule(schedule))
    cpu = time.process_time() - cpu
    return READ_COUNT.rows - rows, READ_COUNT.readings - readings, head.rows or 0, cpu


def check_script(run: Path, schedule: Path) -> str:
    """The script's tables against ncmeasure's friction_table on the script's own windows."""
    recording = Recording.open(run)
    theirs = friction_tables(run, schedule)
    mine = []
    for axis, table in theirs.items():
        windows = [
            VelocityWindow(axis, int(a), int(b), 1.0, 1.0, int(d), 0.0, int(p), int(s), "marker")  # type: ignore[arg-type]
            for a, b, (p, d, s) in zip(
                table["starts"], table["stops"], table["labels"].tolist(), strict=True
            )
        ]  # fmt: skip
        mine.append(friction_table(axis, recording.axis_signal(axis, "current_a"), windows))
    del recording
    return _differences(_as_frame(mine), _numpy_frame(theirs))


def whole_analysis(run: Path, schedule: Path, hours: float, rounds: int, marker: bool) -> None:
    """ncmeasure analyze of a recording against the plain script (with a marker), as CPU."""
    out = run.with_name(run.name + ".results.json")
    read, readings, rows, cpu = rows_read(run, schedule)
    print(
        f"  rows read: {read:,} in {readings} reading(s) of a {rows:,}-row recording "
        f"({read / max(rows, 1):.2f} x; analyze in this process: {cpu:.2f} s CPU)"
    )
    commands = {"ncmeasure": _analyze_command(run, schedule, out)}
    if marker:
        script = [sys.executable, str(BENCHMARKS / "baseline_script.py"), str(run), str(schedule)]
        commands["script"] = script
    cpu_s: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(rounds):
        for name, command in commands.items():
            cpu_s[name].append(child_cpu(command))
    median = {name: statistics.median(times) for name, times in cpu_s.items()}
    for name, label in (
        ("ncmeasure", "ncmeasure analyze (fresh process)"),
        ("script", "plain numpy script (fresh process)"),
    ):
        if name in cpu_s:
            low, high = min(cpu_s[name]), max(cpu_s[name])
            print(
                f"  {label:40} CPU {median[name]:6.2f} s ({low:.2f} .. {high:.2f}, {rounds} runs)"
            )
    factor = hours * 3600 / median["ncmeasure"]
    if marker:
        ratio = median["ncmeasure"] / median["script"]
        print(
            f"  ncmeasure / script CPU: {ratio:.2f} x (goal <= {GOAL_VS_SCRIPT:g} x: "
            f"{'met' if ratio <= GOAL_VS_SCRIPT else 'NOT met'}); {factor:,.0f} x real time"
        )
    else:
        print(
            f"  {factor:,.0f} x real time (goal >= {GOAL_REAL_TIME:,.0f} x: "
            f"{'met' if factor >= GOAL_REAL_TIME else 'NOT met'})"
        )


def analyses(hours: list[int], rounds: int, cache: Path, short: bool) -> None:
    """The whole analysis of 1 h and 4 h recordings, with and without a marker."""
    steps, repetitions = (10, 1) if short else (50, 2)
    cache.mkdir(parents=True, exist_ok=True)
    for copies in hours:
        for marker in (True, False):
            tag = f"{'short' if short else ''}{copies}h-{'marker' if marker else 'command'}"
            run = cache / f"analysis-{tag}"
            start = time.perf_counter()
            schedule = write_copies(run, copies, steps, repetitions, with_marker=marker)
            length = RecordingHead.open(run).meta.samples or 0
            print(
                f"\n{length / RATE_HZ / 3600:.2f} h, {length:,} rows, "
                f"{'with a marker' if marker else 'without a marker (windows by the command)'} "
                f"(written or found in {time.perf_counter() - start:.0f} s)"
            )
            whole_analysis(run, schedule, length / RATE_HZ / 3600, rounds, marker)
            if marker:
                print(
                    f"  script's table vs ncmeasure's friction_table: {check_script(run, schedule)}"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9, help="interleaved timed rounds")
    parser.add_argument(
        "--repetitions", type=int, default=2, help="program repetitions per axis (2: ~1 h)"
    )
    parser.add_argument("--short", action="store_true", help="a few minutes, 2 rounds")
    parser.add_argument(
        "--hours", type=int, nargs="*", default=[1, 4], help="whole analyses of these lengths"
    )
    parser.add_argument(
        "--analysis-rounds", type=int, default=3, help="interleaved runs of each whole analysis"
    )
    parser.add_argument(
        "--cache", type=Path, default=Path("/tmp/ncmeasure-bench-analysis"),
        help="where the recordings of the whole analyses are kept and reused",
    )  # fmt: skip
    args = parser.parse_args()
    steps_count, rounds = (10, 2) if args.short else (50, args.rounds)
    repetitions = 1 if args.short else args.repetitions

    with tempfile.TemporaryDirectory(prefix="ncmeasure-bench-") as tmp:
        start = time.perf_counter()
        recording, schedule = synthetic_recording(
            Path(tmp) / "recording",
            measurement_axes(steps_count, repetitions),
            sample_period_s=1.0 / RATE_HZ,
        )
        rows = len(recording)
        print(
            f"recording: {rows:,} rows x {len(recording.channels)} channels, "
            f"{recording.time_s[-1] / 3600:.2f} h at {RATE_HZ} Hz "
            f"(simulated, written and read in {time.perf_counter() - start:.1f} s)"
        )

        start = time.perf_counter()
        segmentations = {
            axis: windows_of(recording, axis, schedule=schedule, settings=SETTINGS)
            for axis in recording.axes
        }
        windows = sum(len(s.windows) for s in segmentations.values())
        samples = sum(w.samples for s in segmentations.values() for w in s.windows)
        print(
            f"windows:   {windows} windows, {samples:,} window samples "
            f"(found in {time.perf_counter() - start:.2f} s, not part of the timing below)"
        )

        optional = _optional_baselines()
        seconds, results = _interleaved(
            {
                "ncmeasure": lambda: ncmeasure_tables(recording, segmentations),
                "pandas": lambda: pandas_table(recording, segmentations),
                "prebuilt": lambda: pandas_table_prebuilt(recording, segmentations),
                "same": lambda: pandas_table_same_work(recording, segmentations),
                "numpy": lambda: numpy_tables(recording, segmentations),
                **{
                    name: functools.partial(function, recording, segmentations)
                    for name, function in (
                        ("polars", polars_table_same_work),
                        ("duckdb", duckdb_table_same_work),
                    )
                    if name in optional
                },
            },
            rounds,
        )

    median = {name: float(np.median(s)) for name, s in seconds.items()}
    print()
    print(f"friction table (windows -> table), {rounds} interleaved rounds")
    print(f"{'':44} {'median':>9} {'range':>19} {'window samples/s':>17}")
    for name, label in (
        ("ncmeasure", "ncmeasure (numpy)"),
        ("pandas", "pandas groupby, a frame per window"),
        ("prebuilt", "pandas groupby, labels built with numpy"),
        ("same", "pandas, same work (+ standard error)"),
        ("numpy", "numpy script's table, same work"),
        *optional.items(),
    ):
        low, high = min(seconds[name]), max(seconds[name])
        print(
            f"{label:44} {median[name] * 1000:6.1f} ms {low * 1000:7.1f} .. {high * 1000:6.1f} ms "
            f"{samples / median[name]:17,.0f}"
        )
    rate = samples / median["ncmeasure"]
    versus = median["same"] / median["ncmeasure"]
    print(
        f"ncmeasure: {rate / 1e6:.1f} M window samples/s "
        f"(goal >= {GOAL_SAMPLES_PER_S / 1e6:.0f} M: "
        f"{'met' if rate >= GOAL_SAMPLES_PER_S else 'NOT met'}); "
        f"{median['pandas'] / median['ncmeasure']:.1f} x plain pandas; "
        f"{median['prebuilt'] / median['ncmeasure']:.1f} x pandas on prebuilt labels without "
        f"the standard error; {versus:.1f} x pandas doing the same work "
        f"(goal >= {GOAL_VS_PANDAS:g} x: {'met' if versus >= GOAL_VS_PANDAS else 'NOT met'})"
    )

    best = min(("same", "numpy", *optional), key=lambda name: median[name])
    print(
        f"against the best baseline doing the same work ({best}): "
        f"{median[best] / median['ncmeasure']:.2f} x"
    )
    ours = results["ncmeasure"]
    mine = _as_frame(ours)  # type: ignore[arg-type]
    print(f"vs numpy script's table: {_differences(mine, _numpy_frame(results['numpy']))}")  # type: ignore[arg-type]
    for label, key in (
        ("plain pandas", "pandas"),
        ("prebuilt pandas", "prebuilt"),
        ("pandas, same work", "same"),
        *((name, name) for name in optional),
    ):
        theirs = results[key]
        theirs = theirs.set_axis(theirs.index.set_levels(  # categorical axis level -> str
            theirs.index.levels[0].astype(str), level=0))  # fmt: skip
        joined = mine.join(theirs.add_suffix("_pandas"), how="outer")
        differences = ", ".join(
            f"{column} {(joined[column] - joined[f'{column}_pandas']).abs().max():.3g}"
            for column in ("median", "mean", "std", "count", "stderr")
            if f"{column}_pandas" in joined
        )
        print(
            f"vs {label}: rows {len(mine)} / {len(theirs)} / joined {len(joined)}; "
            f"max |difference|: {differences}"
        )

    print("\nthe whole analysis: ncmeasure analyze against the plain numpy script, CPU")
    if args.short:
        with tempfile.TemporaryDirectory(prefix="ncmeasure-bench-") as tmp:
            analyses([1], 1, Path(tmp), short=True)
        print("(--short: a few minutes of recording, one run: the figures mean nothing)")
    else:
        analyses(sorted(set(args.hours)), args.analysis_rounds, args.cache, short=False)


if __name__ == "__main__":
    main()
