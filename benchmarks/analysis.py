"""How fast ncmeasure builds the friction table, against a plain pandas groupby.

Simulates a measurement of about one hour: three axes measured one after the
other (50 geometric steps 10..15 000 mm/min, 5 positions, both directions,
2 repetitions: 1000 windows per axis), sampled at 1 kHz (about 3.5 M rows,
16 float64 columns: time and five signals per axis), and writes it as a real
recording with :class:`~ncmeasure.recording.RecordingWriter` into a
temporary directory, then reads it back. The windows are found once (marker
and schedule; the time is printed). Then, in the same run, the table
(median, mean, standard deviation and count of the current per axis,
position, direction and step, over every sample of the windows) is built
from the same windows:

* ncmeasure: :func:`~ncmeasure.analysis.friction.friction_table`, one call per
  axis (which also computes the batch standard errors: more work than the
  baselines do);
* pandas: one DataFrame per window (current and its labels), ``pd.concat``,
  and ``groupby([axis, position, direction, step]).agg(median, mean, std, count)``;
* pandas again, with the per-sample label columns built by ``np.repeat``
  (as ncmeasure builds them) so that only the groupby is pandas': the floor
  for any pandas version of the table.

Both are timed from the windows to the finished table (best of several
runs) and reported as recording rows per second. Last, the two tables are
compared cell by cell and the largest difference printed.

Run: python benchmarks/analysis.py [--repeats N] [--repetitions N]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np
import pandas as pd  # type: ignore[import-untyped]

from ncmeasure.analysis.friction import FrictionTable, friction_table
from ncmeasure.analysis.segment import Segmentation, SegmentSettings, windows_of
from ncmeasure.recording import Recording
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording

T = TypeVar("T")
RATE_HZ = 1000
POSITIONS = (50.0, 212.5, 375.0, 537.5, 700.0)
SETTINGS = SegmentSettings()


def _best(run: Callable[[], T], repeats: int) -> tuple[float, T]:
    """The shortest of ``repeats`` runs, in seconds, and the last result."""
    best = float("inf")
    result: T
    for _ in range(repeats):
        start = time.perf_counter()
        result = run()
        best = min(best, time.perf_counter() - start)
    return best, result


def _axes(repetitions: int) -> list[SyntheticAxis]:
    steps = geometric_velocities(10.0, 15000.0, 50)
    common = {
        "positions_mm": POSITIONS,
        "velocities_mm_min": steps,
        "repetitions": repetitions,
        "dwell_s": 0.2,
    }
    return [
        SyntheticAxis(name="X", coulomb=(2.0, 2.1, 2.2, 2.3, 2.4), **common),  # type: ignore[arg-type]
        SyntheticAxis(name="Y", coulomb=1.5, **common),  # type: ignore[arg-type]
        SyntheticAxis(name="Z", coulomb=2.5, offset=3.0, vertical=True, **common),  # type: ignore[arg-type]
    ]


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
            }
        )
        for t in tables
    ]
    return pd.concat(parts).set_index(["axis", "position", "direction", "step"]).sort_index()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="timed runs of each table")
    parser.add_argument(
        "--repetitions", type=int, default=2, help="program repetitions per axis (2: ~1 h)"
    )
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="ncmeasure-bench-") as tmp:
        start = time.perf_counter()
        recording, schedule = synthetic_recording(
            Path(tmp) / "recording", _axes(args.repetitions), sample_period_s=1.0 / RATE_HZ
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

        ours_s, ours = _best(lambda: ncmeasure_tables(recording, segmentations), args.repeats)
        plain_s, plain = _best(lambda: pandas_table(recording, segmentations), args.repeats)
        floor_s, floor = _best(
            lambda: pandas_table_prebuilt(recording, segmentations), args.repeats
        )

    print()
    print(f"{'friction table (windows -> table)':44} {'time':>9} {'rows/s':>13}")
    for name, seconds in (
        ("ncmeasure (numpy)", ours_s),
        ("pandas groupby, a frame per window", plain_s),
        ("pandas groupby, labels built with numpy", floor_s),
    ):
        print(f"{name:44} {seconds * 1000:7.1f} ms {rows / seconds:13,.0f}")
    print(f"ncmeasure vs plain pandas: {plain_s / ours_s:.1f} x faster; "
          f"vs pandas on prebuilt labels: {floor_s / ours_s:.1f} x")  # fmt: skip

    mine = _as_frame(ours)
    for label, theirs in (("plain pandas", plain), ("prebuilt pandas", floor)):
        theirs = theirs.set_axis(theirs.index.set_levels(  # categorical axis level -> str
            theirs.index.levels[0].astype(str), level=0))  # fmt: skip
        joined = mine.join(theirs.add_suffix("_pandas"), how="outer")
        differences = ", ".join(
            f"{column} {(joined[column] - joined[f'{column}_pandas']).abs().max():.3g}"
            for column in ("median", "mean", "std", "count")
        )
        print(
            f"vs {label}: rows {len(mine)} / {len(theirs)} / joined {len(joined)}; "
            f"max |difference|: {differences}"
        )


if __name__ == "__main__":
    main()
