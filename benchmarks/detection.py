"""Detection limits: from which size each assembly fault is named, alone and against a reference.

The demo machine (axes X and vertical Z, 5 positions, 8 velocity steps per
direction) runs its LinuxCNC programs on the virtual machine
(:class:`ncmeasure.demo.DemoBench`), each axis with one assembly fault
of a given size, and is analysed as ``ncmeasure analyze`` would. For every
fault kind and size and ``--seeds`` noise seeds this prints:

* **single run**: in how many runs every axis' own verdict is ``check`` or
  ``fault`` *and* names the fault's cause first (a preload change never can: it
  is flat along the travel);
* **against a reference** (a healthy measurement with another seed, as the
  delivery state): in how many runs every axis' change names the fault's cause
  first and the axis' status is at least a warning;
* the size of the change in % of friction: the spread of the change along the
  travel (local faults) or its mean (preload), the mean over the runs.

Then, per fault kind, the smallest size found in every run: the detection
limit, in µm (or relative preload, or relative step) and in % friction change.
The µm rest on the axis model's support stiffness (2.2 N/µm, calibrated to the
test rig's shapes and sizes, not measured; docs/axis-model.md).

``--realistic`` turns on the virtual machine's realism
(:class:`ncmeasure.sim.realism.Realism`: a healthy fingerprint along the travel,
drift of level and profile between runs, the drives' real noise). All figures come from
seeded simulations; none is a timing. Run: python benchmarks/detection.py
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path
from typing import Any

from ncmeasure.analysis.judgement.compare import compare_results
from ncmeasure.analysis.judgement.summary import axis_comparison, axis_headline
from ncmeasure.demo import DemoBench
from ncmeasure.formats.results import Results
from ncmeasure.sim.axis import Variation
from ncmeasure.sim.realism import Realism

KINDS: dict[str, tuple[str, str, str, tuple[float, ...]]] = {
    # kind: (variation field, expected cause, unit, sizes)
    "loose bearing shifted": (
        "loose_bearing_shift_um", "loose_bearing", "µm", (10, 20, 30, 50, 100, 200, 500)
    ),
    "fixed bearing shifted": (
        "fixed_bearing_shift_um", "fixed_bearing", "µm", (10, 20, 30, 50, 100, 200, 500)
    ),
    "nut shifted": ("nut_shift_um", "screw_nut", "µm", (20, 50, 100, 200, 300, 500)),
    "guide rail bowed": ("rail_misalignment_um", "guide_rail", "µm", (5, 10, 20, 30, 50, 100)),
    "cover step": ("cover_step", "cover_or_seal", "× friction", (0.02, 0.05, 0.1, 0.2)),
    "nut preload": (
        "nut_preload_change", "preload_or_carriage", "× preload", (0.25, 0.5, 1.0, 1.5)
    ),
}  # fmt: skip
SHORT = {kind: (spec[0], spec[1], spec[2], spec[3][-2:-1]) for kind, spec in KINDS.items()}


def _single(results: Results, cause: str) -> dict[str, bool]:
    """Per axis: its own verdict is check or fault and names ``cause`` first."""
    found = {}
    for name, axis in results.axes.items():
        dependency = axis.position_dependency
        found[name] = (
            axis.verdict.level != "ok"
            and dependency is not None
            and bool(dependency.causes)
            and dependency.causes[0].cause == cause
        )
    return found


def _against(reference: Results, later: Results, cause: str) -> dict[str, tuple[bool, float]]:
    """Per axis: the change names ``cause`` first, the status is not ok, the verdict not ok;
    and the size of the change (its spread along the travel, or its mean for preload)."""
    comparison = compare_results(reference, [later])
    (run,) = comparison.runs
    found = {}
    for change in comparison.changes:
        local = cause != "preload_or_carriage"
        size = change.spread_percent if local else change.mean_change_percent
        verdict = axis_headline(later.axes[change.axis], axis_comparison(comparison, change.axis))
        hit = (
            bool(change.causes)
            and change.causes[0].cause == cause
            and run.axis_status.get(change.axis, "ok") != "ok"
            and verdict.verdict.level != "ok"
        )
        found[change.axis] = (hit, size)
    return found


def _limit(rows: list[tuple[float, int, float]], seeds: int, unit: str) -> str:
    """The smallest size found in every run, with its change in %."""
    for size, hits, change in rows:
        if hits == seeds:
            return f"{size:g} {unit} ({change:+.1f} %)"
    return "not found"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="runs per fault size")
    parser.add_argument("--short", action="store_true", help="one size per kind, one seed")
    parser.add_argument(
        "--realistic",
        action="store_true",
        help="the virtual machine's realism: a healthy fingerprint, drift between runs, the "
        "drives' real noise",
    )
    parser.add_argument(
        "--machine-seed", type=int, default=0, help="the fingerprint's seed (with --realistic)"
    )
    args = parser.parse_args()
    kinds = SHORT if args.short else KINDS
    seeds = 1 if args.short else args.seeds
    options: dict[str, Any] = {}
    if args.realistic:
        options = {"realism": Realism(), "machine_seed": args.machine_seed}
    with tempfile.TemporaryDirectory() as tmp:
        bench = DemoBench.create(Path(tmp))
        reference = bench.measure(seed=1000, **options)
        axes = sorted(reference.axes)
        head = "  ".join(f"{a + ' alone':>8} {a + ' vs ref':>9} {a + ' %':>7}" for a in axes)
        print(f"{'fault':24} {'size':>6}  {head}")
        limits = []
        for kind, (field, cause, unit, sizes) in kinds.items():
            alone: dict[str, list[tuple[float, int, float]]] = {a: [] for a in axes}
            versus: dict[str, list[tuple[float, int, float]]] = {a: [] for a in axes}
            for size in sizes:
                variation = Variation(**{field: float(size)})
                single = dict.fromkeys(axes, 0)
                against = dict.fromkeys(axes, 0)
                changes: dict[str, list[float]] = {a: [] for a in axes}
                for seed in range(seeds):
                    later = bench.measure(seed=seed + 1, variation=variation, **options)
                    for a, hit in _single(later, cause).items():
                        single[a] += hit
                    for a, (hit, change) in _against(reference, later, cause).items():
                        against[a] += hit
                        changes[a].append(change)
                cells = []
                for a in axes:
                    mean = statistics.fmean(changes[a]) if changes[a] else float("nan")
                    alone[a].append((size, single[a], mean))
                    versus[a].append((size, against[a], mean))
                    cells.append(
                        f"{single[a]:>4}/{seeds:<3} {against[a]:>5}/{seeds:<3} {mean:+7.2f}"
                    )
                print(f"{kind:24} {size:>6g}  " + "  ".join(cells))
            limits.append((kind, unit, alone, versus))
        print("\ndetection limit (the smallest size found in every run; its change in %):")
        for kind, unit, alone, versus in limits:
            for a in axes:
                print(
                    f"  {kind:24} axis {a}: single run {_limit(alone[a], seeds, unit):24} "
                    f"against a reference {_limit(versus[a], seeds, unit)}"
                )


if __name__ == "__main__":
    main()
