"""Detection limits: from which size each assembly fault is named, alone and against a reference.

The demo machine (axes X and vertical Z, 5 positions, 8 velocity steps per
direction) runs its LinuxCNC programs on the virtual machine
(:class:`ncmeasure.virtual_run.DemoBench`), each axis with one assembly fault
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
from ncmeasure.formats.results import Results
from ncmeasure.sim.axis import Variation
from ncmeasure.sim.realism import Realism
from ncmeasure.virtual_run import DemoBench

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


def _single(results: Results, cause: str) -> bool:
    for axis in results.axes.values():
        dependency = axis.position_dependency
        if axis.verdict.level == "ok" or dependency is None or not dependency.causes:
            return False
        if dependency.causes[0].cause != cause:
            return False
    return True


def _against(reference: Results, later: Results, cause: str) -> tuple[bool, float]:
    comparison = compare_results(reference, [later])
    (run,) = comparison.runs
    found = True
    sizes = []
    for change in comparison.changes:
        local = cause != "preload_or_carriage"
        sizes.append(change.spread_percent if local else change.mean_change_percent)
        if not change.causes or change.causes[0].cause != cause:
            found = False
        if run.axis_status.get(change.axis, "ok") == "ok":
            found = False
        verdict = axis_headline(later.axes[change.axis], axis_comparison(comparison, change.axis))
        if verdict.verdict.level == "ok":
            found = False
    return found, statistics.fmean(sizes) if sizes else float("nan")


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
        print(f"{'fault':24} {'size':>8}  {'single run':>10}  {'vs reference':>12}  change %")
        limits = []
        for kind, (field, cause, unit, sizes) in kinds.items():
            found_single = found_against = None
            for size in sizes:
                variation = Variation(**{field: float(size)})
                single = against = 0
                changes = []
                for seed in range(seeds):
                    later = bench.measure(seed=seed + 1, variation=variation, **options)
                    single += _single(later, cause)
                    hit, change = _against(reference, later, cause)
                    against += hit
                    changes.append(change)
                mean_change = statistics.fmean(changes)
                print(
                    f"{kind:24} {size:>8g}  {single:>5}/{seeds:<4}  {against:>7}/{seeds:<4}  "
                    f"{mean_change:+7.2f}"
                )
                if found_single is None and single == seeds:
                    found_single = size
                if found_against is None and against == seeds:
                    found_against = (size, mean_change)
            limits.append((kind, unit, found_single, found_against))
        print("\ndetection limit (every run found):")
        for kind, unit, single_size, against_size in limits:
            single_text = "not found" if single_size is None else f"{single_size:g} {unit}"
            against_text = (
                "not found"
                if against_size is None
                else f"{against_size[0]:g} {unit} ({against_size[1]:+.1f} %)"
            )
            print(f"  {kind:24} single run: {single_text:16} against a reference: {against_text}")


if __name__ == "__main__":
    main()
