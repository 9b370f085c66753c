"""How long the nonlinear fits and the HTML report take, against the analysis in the same run.

Simulates the measurement of ``benchmarks/analysis.py``: three axes measured
one after the other, 5 positions, 50 geometric velocity steps
10..15 000 mm/min, both directions, sampled at 1 kHz (``--rate``), written as
a real recording and read back. Two rows, each timed in interleaved rounds
(A B A B ...), reported as median and range:

* **nonlinear fits**: :func:`~ncmeasure.analysis.fit.fit_nonlinear`, the
  Stribeck and the extended model, for every axis, position and direction
  (3 × 5 × 2 × 2 = 60 fits), on exactly the points the analysis fits (the
  friction magnitudes with the offset taken out and their σ, as
  :func:`~ncmeasure.analysis.fit.fit_direction` prepares them). Baseline: the
  whole analysis of the same recording (``analyze``, which includes these
  fits), so the share of the fits is printed next to the goal (≤ 1 s).
* **report**: what ``ncmeasure analyze RUN --schedule S --report R`` does,
  against the same command without ``--report``: the recording read, analysed
  and results.json written (A), and the same plus
  :func:`~ncmeasure.report.write_report` (B). Goal: B/A ≤ 1.3.

``--short`` runs tiny data (3 positions, 8 steps, 250 Hz) once: it checks that
everything runs (``.ci/run``) and prints figures that mean nothing.

Run: python benchmarks/fit_report.py [--rounds N] [--rate HZ] [--repetitions N] [--short]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ncmeasure.analysis.analyze import analyze, write_results
from ncmeasure.analysis.fit import fit_nonlinear, point_sigma
from ncmeasure.analysis.results import Results
from ncmeasure.plan import Schedule
from ncmeasure.recording import read_recording
from ncmeasure.report import write_report
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording

FIT_GOAL_S = 1.0
REPORT_GOAL_RATIO = 1.3
Series = tuple[np.ndarray, np.ndarray, np.ndarray | None]


def _axes(positions: Sequence[float], steps: int, repetitions: int) -> list[SyntheticAxis]:
    common = {
        "positions_mm": tuple(positions),
        "velocities_mm_min": geometric_velocities(10.0, 15000.0, steps),
        "repetitions": repetitions,
        "dwell_s": 0.2,
    }
    return [
        SyntheticAxis(name="X", coulomb=(2.0, 2.1, 2.2, 2.3, 2.4)[: len(positions)], **common),  # type: ignore[arg-type]
        SyntheticAxis(name="Y", coulomb=1.5, **common),  # type: ignore[arg-type]
        SyntheticAxis(name="Z", coulomb=2.5, offset=3.0, vertical=True, **common),  # type: ignore[arg-type]
    ]


def fit_inputs(results: Results) -> list[Series]:
    """Speed, friction magnitude and σ of every position and direction, as fit_direction fits."""
    series: list[Series] = []
    for axis in results.axes.values():
        for position in axis.positions:
            for name, direction in position.directions.items():
                if direction is None or not direction.points:
                    continue
                sign = 1 if name == "positive" else -1
                ordered = sorted(direction.points, key=lambda p: abs(p.velocity_mm_min))
                speed = np.abs([p.velocity_mm_min for p in ordered])
                shift = direction.offset_removed or 0.0
                magnitude = sign * (np.array([p.median for p in ordered]) - shift)
                series.append((speed, magnitude, point_sigma(ordered)))
    return series


def all_fits(series: Sequence[Series]) -> int:
    """Both nonlinear models on every series; the number of fits that returned a result."""
    made = 0
    for speed, magnitude, sigma in series:
        for model in ("stribeck", "extended"):
            made += fit_nonlinear(speed, magnitude, sigma, model=model) is not None  # type: ignore[arg-type]
    return made


def analysis(run: Path, schedule: Schedule, out: Path) -> Results:
    """What ``ncmeasure analyze`` does without ``--report``: read, analyse, write results.json."""
    recording = read_recording(run)
    results = analyze(recording, schedule=schedule)
    write_results(results, out / "results.json")
    return results


def analysis_and_report(run: Path, schedule: Schedule, out: Path) -> Results:
    """The same, then the HTML report as ``--report`` writes it."""
    recording = read_recording(run)
    results = analyze(recording, schedule=schedule)
    write_results(results, out / "results.json")
    write_report(results, out / "report.html", recording=recording)
    return results


def interleaved(
    a: Callable[[], object], b: Callable[[], object], rounds: int
) -> tuple[list[float], list[float]]:
    """Seconds of ``rounds`` runs of each, alternating A B A B ..."""
    times_a: list[float] = []
    times_b: list[float] = []
    for _ in range(rounds):
        for run, times in ((a, times_a), (b, times_b)):
            start = time.perf_counter()
            run()
            times.append(time.perf_counter() - start)
    return times_a, times_b


def _line(name: str, times: Sequence[float]) -> str:
    return (
        f"  {name:52} median {statistics.median(times):7.3f} s "
        f"(range {min(times):.3f}-{max(times):.3f} s, {len(times)} runs)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="interleaved rounds per row")
    parser.add_argument("--rate", type=float, default=1000.0, help="sample rate in Hz")
    parser.add_argument(
        "--repetitions", type=int, default=2, help="program repetitions per axis (2: ~1 h)"
    )
    parser.add_argument("--short", action="store_true", help="tiny data, one round (CI)")
    args = parser.parse_args()
    if args.short:
        positions: Sequence[float] = (50.0, 375.0, 700.0)
        steps, rate, repetitions, rounds = 8, 250.0, 1, 1
    else:
        positions = (50.0, 212.5, 375.0, 537.5, 700.0)
        steps, rate, repetitions, rounds = 50, args.rate, args.repetitions, args.rounds

    with tempfile.TemporaryDirectory(prefix="ncmeasure-bench-") as tmp:
        run, out = Path(tmp) / "recording", Path(tmp) / "out"
        out.mkdir()
        start = time.perf_counter()
        recording, schedule = synthetic_recording(
            run, _axes(positions, steps, repetitions), sample_period_s=1.0 / rate
        )
        print(
            f"recording: 3 axes x {len(positions)} positions x {steps} steps x 2 directions, "
            f"{len(recording):,} rows, {recording.time_s[-1] / 60:.1f} min at {rate:g} Hz "
            f"(simulated in {time.perf_counter() - start:.1f} s)"
        )
        results = analysis(run, schedule, out)
        series = fit_inputs(results)

        print(f"\nnonlinear fits: {2 * len(series)} fits (Stribeck + extended per series)")
        fits_s, whole_s = interleaved(
            lambda: all_fits(series), lambda: analysis(run, schedule, out), rounds
        )
        print(_line("fit_nonlinear, all axes, positions, directions", fits_s))
        print(_line("baseline: the whole analysis (includes these fits)", whole_s))
        fits, whole = statistics.median(fits_s), statistics.median(whole_s)
        print(
            f"  fits {fits:.3f} s = {fits / whole:.0%} of the analysis; "
            f"goal <= {FIT_GOAL_S:g} s: {'met' if fits <= FIT_GOAL_S else 'NOT met'}"
        )

        print("\nreport: ncmeasure analyze with and without --report, same recording")
        plain_s, report_s = interleaved(
            lambda: analysis(run, schedule, out),
            lambda: analysis_and_report(run, schedule, out),
            rounds,
        )
        print(_line("baseline: analyze (read, analyse, results.json)", plain_s))
        print(_line("analyze --report", report_s))
        ratio = statistics.median(report_s) / statistics.median(plain_s)
        extra = statistics.median(report_s) - statistics.median(plain_s)
        print(
            f"  ratio {ratio:.2f} (the report adds ~{extra:.2f} s); "
            f"goal <= {REPORT_GOAL_RATIO:g}: {'met' if ratio <= REPORT_GOAL_RATIO else 'NOT met'}"
        )
        if args.short:
            print("(--short: tiny data, one round: the figures mean nothing)")


if __name__ == "__main__":
    main()
