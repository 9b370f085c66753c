"""How long the nonlinear fits and the HTML report take, against the analysis in the same run.

Simulates the measurement of ``benchmarks/analysis.py``: three axes measured
one after the other, 5 positions, 50 geometric velocity steps
10..15 000 mm/min, both directions, sampled at 1 kHz (``--rate``), written as
a real recording and read back. Two rows, each timed in interleaved rounds
(A B A B ...), reported as median and range:

* **nonlinear fits**: :func:`~ncmeasure.analysis.friction.stribeck.fit_nonlinear`, the
  Stribeck and the extended model, for every axis, position and direction
  (3 × 5 × 2 × 2 = 60 fits), on exactly the points the analysis fits (the
  friction magnitudes with the offset taken out and their σ, as
  :func:`~ncmeasure.analysis.friction.fit.fit_direction` prepares them), in CPU
  time. Baselines: ``scipy.optimize.curve_fit`` of both models from one plain
  start per series (:func:`plain_fits`: what an engineer writes without
  ncmeasure, with less work: no grid of starts, no checks), and the whole
  analysis of the same recording (``analyze``, which includes these fits), so
  the share of the fits is printed next to the goal (≤ 1 s CPU).
* **report**: what ``ncmeasure analyze RUN --schedule S --report R`` does,
  against the same command without ``--report``: the recording read chunk by
  chunk and analysed, results.json written (A), and the same plus
  :func:`~ncmeasure.report.write_report` (B), as the command does it: the
  raw-data figures' data gathered on the analysis' readings of the recording
  (:class:`~ncmeasure.report.traces.RawTraces`, the last axis' on one more
  reading of its span), then handed to the report with the windows the
  analysis used. Goal: B/A ≤ 1.3 in CPU time; the CPU time of ``write_report`` alone
  is printed as well (steadier than B − A). Wall and CPU time of the process are
  printed: on a shared machine CPU time is the steadier figure (nothing here
  runs in parallel).

``--short`` runs tiny data (3 positions, 8 steps, 250 Hz) once: it checks that
everything runs (``.ci/run``) and prints figures that mean nothing.

Run: python benchmarks/fit_report.py [--rounds N] [--rate HZ] [--repetitions N] [--short]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

# As the ncmeasure command runs (ncmeasure.__main__): OpenBLAS with one thread.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from measurement import measurement_axes

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.friction.fit import point_sigma
from ncmeasure.analysis.friction.stribeck import fit_nonlinear
from ncmeasure.formats.results import Results, write_results
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import RecordingHead
from ncmeasure.report import write_report
from ncmeasure.report.traces import RawTraces
from ncmeasure.sim.synthetic import synthetic_recording

FIT_GOAL_S = 1.0
REPORT_GOAL_RATIO = 1.3
Series = tuple[np.ndarray, np.ndarray, np.ndarray | None]


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


def _stribeck(v: np.ndarray, tc: float, ts: float, vs: float, delta: float, b: float) -> np.ndarray:
    return tc + (ts - tc) * np.exp(-((v / vs) ** delta)) + b * v


def _extended(
    v: np.ndarray, tc: float, ts: float, vs: float, delta: float, b: float, fw: float, k: float
) -> np.ndarray:
    return _stribeck(v, tc, ts, vs, delta, b) + fw * (v / 1000.0) ** k


def plain_fits(series: Sequence[Series]) -> int:
    """The baseline: both models by ``scipy.optimize.curve_fit`` from one plain start each.

    What an engineer writes without ncmeasure: the model as a function, σ as
    weights, bounds (δ 0.3..3, k 0.3..2, v_S within the measured speeds, the
    friction terms non-negative), the start from the data (T_C the least
    value, T_S the value at the slowest speed, v_S the geometric middle speed,
    δ 1, b and f_w 0, k 1). No grid of starts and no check of the fit: less
    work than ncmeasure does. Returns the fits that converged.
    """
    from scipy.optimize import curve_fit

    made = 0
    for speed, magnitude, sigma in series:
        low, high = float(speed.min()), float(speed.max())
        start = [float(magnitude.min()), float(magnitude[0]), math.sqrt(low * high), 1.0, 0.0]
        lower = [0.0, 0.0, 0.1 * low, 0.3, 0.0]
        upper = [np.inf, np.inf, high, 3.0, np.inf]
        for model, extra in (
            (_stribeck, ([], [], [])),
            (_extended, ([0.0, 1.0], [0.0, 0.3], [np.inf, 2.0])),
        ):
            try:
                curve_fit(
                    model, speed, magnitude, p0=start + extra[0], sigma=sigma,
                    bounds=(lower + extra[1], upper + extra[2]), maxfev=2000,
                )  # fmt: skip
                made += 1
            except (RuntimeError, ValueError):
                pass
    return made


def all_fits(series: Sequence[Series]) -> int:
    """Both nonlinear models on every series; the number of fits that returned a result."""
    made = 0
    for speed, magnitude, sigma in series:
        for model in ("stribeck", "extended"):
            made += fit_nonlinear(speed, magnitude, sigma, model=model) is not None  # type: ignore[arg-type]
    return made


def analysis(run: Path, schedule: Schedule, out: Path) -> Results:
    """What ``ncmeasure analyze`` does without ``--report``: read, analyse, write results.json."""
    results = analyze(RecordingHead.open(run), schedule=schedule)
    write_results(results, out / "results.json")
    return results


def analysis_and_report(
    run: Path, schedule: Schedule, out: Path, report_cpu: list[float] | None = None
) -> Results:
    """The same, then the HTML report as ``--report`` writes it: the analysis' windows and the
    raw-data figures' data gathered on the analysis' readings handed over. The CPU time of
    ``write_report`` alone is appended to ``report_cpu``."""
    recording = RecordingHead.open(run)
    windows: dict[str, list[tuple[float, float]]] = {}
    traces = RawTraces(recording)
    results = analyze(recording, schedule=schedule, window_times=windows, on_windows=traces.watch)
    write_results(results, out / "results.json")
    cpu = time.process_time()
    write_report(
        results, out / "report.html", recording=recording, windows=windows, traces=traces.found
    )
    if report_cpu is not None:
        report_cpu.append(time.process_time() - cpu)
    return results


Timing = tuple[float, float]  # wall and CPU seconds of one run


def interleaved(*runs: Callable[[], object], rounds: int) -> list[list[Timing]]:
    """(wall, CPU) seconds of ``rounds`` runs of each, alternating A B A B ... (A B C ...)."""
    times: list[list[Timing]] = [[] for _ in runs]
    for _ in range(rounds):
        for run, kept in zip(runs, times, strict=True):
            wall, cpu = time.perf_counter(), time.process_time()
            run()
            kept.append((time.perf_counter() - wall, time.process_time() - cpu))
    return times


def _line(name: str, times: Sequence[Timing]) -> str:
    walls = [wall for wall, _ in times]
    return (
        f"  {name:52} median {statistics.median(walls):7.3f} s "
        f"(range {min(walls):.3f}-{max(walls):.3f} s, {len(walls)} runs), "
        f"CPU {statistics.median(cpu for _, cpu in times):.3f} s"
    )


def _ratio(name: str, times: Sequence[Timing], base: Sequence[Timing]) -> str:
    def median(kept: Sequence[Timing], which: int) -> float:
        return statistics.median(t[which] for t in kept)

    wall, cpu = median(times, 0) / median(base, 0), median(times, 1) / median(base, 1)
    verdict = "met" if cpu <= REPORT_GOAL_RATIO else "NOT met"
    return (
        f"  {name}: CPU ratio {cpu:.2f}, wall {wall:.2f} (the report adds "
        f"~{median(times, 1) - median(base, 1):.2f} s CPU); goal <= {REPORT_GOAL_RATIO:g} "
        f"(CPU): {verdict}"
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
            run, measurement_axes(steps, repetitions, positions), sample_period_s=1.0 / rate
        )
        print(
            f"recording: 3 axes x {len(positions)} positions x {steps} steps x 2 directions, "
            f"{len(recording):,} rows, {recording.time_s[-1] / 60:.1f} min at {rate:g} Hz "
            f"(simulated in {time.perf_counter() - start:.1f} s)"
        )
        results = analysis(run, schedule, out)
        series = fit_inputs(results)

        print(f"\nnonlinear fits: {2 * len(series)} fits (Stribeck + extended per series)")
        converged = plain_fits(series)
        fits_t, plain_t, whole_t = interleaved(
            lambda: all_fits(series),
            lambda: plain_fits(series),
            lambda: analysis(run, schedule, out),
            rounds=rounds,
        )
        print(_line("fit_nonlinear, all axes, positions, directions", fits_t))
        print(_line(f"baseline: plain curve_fit, one start ({converged} converged)", plain_t))
        print(_line("the whole analysis (includes these fits)", whole_t))
        fits = statistics.median(cpu for _, cpu in fits_t)
        plain = statistics.median(cpu for _, cpu in plain_t)
        whole = statistics.median(cpu for _, cpu in whole_t)
        print(
            f"  fits {fits:.3f} s CPU = {fits / whole:.0%} of the analysis, "
            f"{fits / plain:.2f} x the plain curve_fit; goal <= {FIT_GOAL_S:g} s CPU: "
            f"{'met' if fits <= FIT_GOAL_S else 'NOT met'}"
        )

        print("\nreport: ncmeasure analyze with and without --report, same recording")
        report_cpu: list[float] = []
        plain_t, report_t = interleaved(
            lambda: analysis(run, schedule, out),
            lambda: analysis_and_report(run, schedule, out, report_cpu),
            rounds=rounds,
        )
        print(_line("A baseline: analyze (read, analyse, results.json)", plain_t))
        print(_line("B analyze --report", report_t))
        print(
            f"  of B, write_report alone: median CPU {statistics.median(report_cpu):.3f} s "
            f"(range {min(report_cpu):.3f}-{max(report_cpu):.3f} s); the page "
            f"{(out / 'report.html').stat().st_size / 1e3:,.0f} kB, its figures' files "
            f"{sum(f.stat().st_size for f in (out / 'report_plots').iterdir()) / 1e3:,.0f} kB"
        )
        print(_ratio("B/A", report_t, plain_t))
        if args.short:
            print("(--short: tiny data, one round: the figures mean nothing)")


if __name__ == "__main__":
    main()
