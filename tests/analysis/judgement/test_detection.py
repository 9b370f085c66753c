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
from ncmeasure.formats.comparison import Comparison
from ncmeasure.formats.results import Results
from ncmeasure.sim.axis import Variation
from ncmeasure.virtual_run import DemoBench


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
