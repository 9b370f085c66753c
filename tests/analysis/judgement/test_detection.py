"""Detection and false alarms on the virtual machine, against a reference with other noise.

Every measurement is the demo machine's programs on the virtual machine (each axis
with the same assembly variation), analysed as ``ncmeasure analyze`` would, and
compared with a reference measured with another seed, as a machine maker compares a
machine at the customer with its delivery state. docs/analysis-models.md,
*Detection limits*, gives the sizes each fault kind is found from.
"""

from __future__ import annotations

import pytest

from ncmeasure.analysis.judgement.compare import compare_results
from ncmeasure.analysis.judgement.summary import axis_comparison, axis_headline
from ncmeasure.demo import DemoBench
from ncmeasure.formats.comparison import Comparison
from ncmeasure.formats.results import Results
from ncmeasure.sim.axis import Variation
from ncmeasure.sim.realism import Realism


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> DemoBench:
    return DemoBench.create(tmp_path_factory.mktemp("detection"))


@pytest.fixture(scope="module")
def reference(bench: DemoBench) -> Results:
    return bench.measure(seed=1)


def _verdicts(later: Results, comparison: Comparison) -> dict[str, str]:
    """The printed verdict of every axis: its own, combined with the comparison."""
    return {
        name: axis_headline(axis, axis_comparison(comparison, name)).verdict.level
        for name, axis in later.axes.items()
    }


def test_a_loose_bearing_raised_50um_is_named_on_every_axis(
    bench: DemoBench, reference: Results
) -> None:
    """50 µm at the loose bearing changes friction along the travel by 2–3 % (far below any
    limit on the level): the change's own pattern names the bearing, and the axis is 'check'."""
    later = bench.measure(seed=2, variation=Variation(loose_bearing_shift_um=50.0))
    comparison = compare_results(reference, [later])
    changes = {c.axis: c for c in comparison.changes}
    assert set(changes) == set(later.axes) == {"X", "Z"}
    for name, change in changes.items():
        assert change.signature == "rising_to_loose_bearing", (name, change)
        assert change.causes[0].cause == "loose_bearing", (name, change.causes)
        assert abs(change.mean_change_percent) < 5  # invisible to the level's limits
    (run,) = comparison.runs
    assert run.axis_status == {"X": "warning", "Z": "warning"}
    assert any("likely a shifted or tilted loose bearing" in r for r in run.reasons)
    assert _verdicts(later, comparison) == {"X": "check", "Z": "check"}


def test_a_healthy_re_measurement_names_no_cause(bench: DemoBench, reference: Results) -> None:
    later = bench.measure(seed=3)
    comparison = compare_results(reference, [later])
    for change in comparison.changes:
        assert change.signature == "flat"
        assert change.causes[0].cause == "none", change.causes
    assert comparison.runs[0].status == "ok"
    assert _verdicts(later, comparison) == {"X": "ok", "Z": "ok"}


def test_a_shifted_nut_on_the_vertical_axis_is_no_preload_change(
    bench: DemoBench, reference: Results
) -> None:
    """A nut shifted by 100 µm raises friction next to both bearings, by 2–4 %: on the vertical
    axis, where gravity is taken out as the offset of both directions, that used to read as
    a flat change, i.e. preload."""
    later = bench.measure(seed=4, variation=Variation(nut_shift_um=100.0))
    comparison = compare_results(reference, [later])
    for change in comparison.changes:
        assert change.signature == "high_at_both_ends", change
        assert change.causes[0].cause == "screw_nut", change.causes


def test_no_false_alarm_in_20_healthy_runs_with_a_realistic_machine(bench: DemoBench) -> None:
    """Five machines with their own healthy fingerprint along the travel (assembly within
    tolerance, the nut's and carriages' preload varying along the screw), each measured
    for reference and then four times more, with drift of level and profile between the
    runs and the drives' real noise: no comparison raises anything. Several of these axes
    show a pattern along the travel of their own ('check' from the single run): against
    the reference it is their fingerprint, unchanged."""
    lifted = 0
    for machine in range(5):
        realistic = {"realism": Realism(), "machine_seed": machine}
        reference = bench.measure(seed=1000 + 100 * machine, **realistic)
        for run in range(4):
            later = bench.measure(seed=1001 + 100 * machine + run, **realistic)
            comparison = compare_results(reference, [later])
            where = f"machine {machine}, run {run}"
            assert comparison.runs[0].status == "ok", (where, comparison.runs[0].reasons)
            assert _verdicts(later, comparison) == {"X": "ok", "Z": "ok"}, where
            for change in comparison.changes:
                assert change.signature == "flat", (where, change.axis, change.spread_percent)
                assert change.causes[0].cause in ("none", "preload_or_carriage"), where
            lifted += sum(axis.verdict.level != "ok" for axis in later.axes.values())
    assert lifted > 0  # the fingerprint alone would have raised a 'check'
