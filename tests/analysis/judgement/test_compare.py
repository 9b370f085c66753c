"""Comparison of results: deviation, limits and status, fleet outliers, mismatches, causes."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from ncmeasure.analysis.judgement.compare import ComparisonError, compare_results
from ncmeasure.analysis.judgement.fleet import modified_z_against, modified_z_leave_one_out
from ncmeasure.formats.comparison import AxisChange, Comparison, Limits
from ncmeasure.formats.results import (
    AxisResult,
    DirectionResult,
    LinearFit,
    Point,
    PositionResult,
    RecordingInfo,
    Results,
    Verdict,
)

SPEEDS = np.geomspace(10.0, 15000.0, 20)
POSITIONS = [50.0, 375.0, 700.0]


def curve(v: float) -> float:
    return 1.5 + 0.7 * math.exp(-v / 60.0) + 2e-4 * v


Factor = Callable[[str, int, str, float], float]  # axis, position index, direction, speed

LINE_FROM_MM_MIN = 300.0
"""The fixture's lines start here: above the Stribeck region of ``curve`` (e^-5 of it left)."""


def line(points: list[Point]) -> LinearFit:
    """The line through the points above the Stribeck region, as the analysis fits it: its
    Coulomb friction is the curve's 1.5 times the points' factor."""
    above = [p for p in points if abs(p.velocity_mm_min) >= LINE_FROM_MM_MIN]
    speeds = np.array([abs(p.velocity_mm_min) for p in above])
    friction = np.array([abs(p.median) for p in above])
    viscous, coulomb = np.polyfit(speeds, friction, 1)
    return LinearFit(
        coulomb=float(coulomb),
        viscous_per_mm_min=float(viscous),
        coulomb_stderr=None,
        viscous_stderr=None,
        chi2_reduced=1.0,
        accepted=True,
        n_points=len(above),
        velocity_range_mm_min=(float(speeds.min()), float(speeds.max())),
        points_below_range=len(points) - len(above),
    )


def results(
    machine: str | None = "HMX-400 #17",
    factor: Factor | float = 1.0,
    *,
    axes: tuple[str, ...] = ("X", "Y"),
    positions: list[float] = POSITIONS,
    speeds: np.ndarray = SPEEDS,
    noise: float = 0.0,
    seed: int = 0,
    quantity: Literal["torque_nm", "current_a"] = "torque_nm",
    created: str = "2026-01-15T08:30:00+00:00",
    travel_mm: tuple[float, float] | None = None,
    fixed_bearing_end: Literal["min", "max"] | None = None,
    lines: bool = True,
) -> Results:
    """Results of a machine whose friction is the healthy curve times ``factor``; with
    ``lines``, each direction holds the line fitted to its points."""
    rng = np.random.default_rng(seed)

    def scale(axis: str, i: int, direction: str, v: float) -> float:
        return factor(axis, i, direction, v) if callable(factor) else float(factor)

    def direction(axis: str, i: int, name: str, sign: int) -> DirectionResult:
        pts = []
        for v in speeds:
            t = curve(float(v)) * scale(axis, i, name, float(v)) * (1 + rng.normal(0, noise))
            pts.append(
                Point(
                    velocity_mm_min=sign * float(v), median=sign * t, mean=sign * t, std=0.05, n=100
                )
            )
        return DirectionResult(points=pts, fit=line(pts) if lines else None)

    axis_results = {
        axis: AxisResult(
            verdict=Verdict(level="ok", reason="made by the test", action="none"),
            quantity=quantity,
            unit="Nm" if quantity == "torque_nm" else "A",
            torque_constant_nm_per_a=2.1 if quantity == "torque_nm" else None,
            travel_mm=travel_mm,
            fixed_bearing_end=fixed_bearing_end,
            window_source="marker",
            windows=len(positions) * 2 * len(speeds),
            samples_used=100 * len(positions) * 2 * len(speeds),
            positions=[
                PositionResult(
                    position_mm=p,
                    position_index=i,
                    directions={
                        "positive": direction(axis, i, "positive", 1),
                        "negative": direction(axis, i, "negative", -1),
                    },
                )
                for i, p in enumerate(positions)
            ],
        )
        for axis in axes
    }
    return Results(
        created_utc=created,
        recording=RecordingInfo(
            directory=f"/data/{machine}",
            machine=machine,
            start_utc=created,
            config_hash="abc",
            source="recording",
        ),
        settings={},
        axes=axis_results,
    )


# --------------------------------------------------------------------------- lifetime


@pytest.mark.parametrize(
    ("factor", "status"),
    [
        (1.05, "ok"),
        (0.85, "warning"),
        (1.15, "warning"),
        (0.7, "critical"),
        (1.3, "critical"),
        (0.5, "critical"),
    ],
)
def test_lifetime_deviation_limits_and_status(factor: float, status: str) -> None:
    base = results(created="2026-01-15T08:30:00+00:00")
    later = results(factor=factor, created="2028-01-15T08:30:00+00:00")
    comparison = compare_results(base, [later])
    assert comparison.mode == "lifetime"
    assert len(comparison.deviations) == 2 * 3 * 2 * SPEEDS.size
    for d in comparison.deviations:
        assert d.deviation_percent == pytest.approx((factor - 1) * 100)
        assert d.base > 0 and d.value > 0  # magnitudes, also in the negative direction
    (run,) = comparison.runs
    assert run.status == status
    assert run.max_abs_deviation_percent == pytest.approx(abs(factor - 1) * 100)
    assert comparison.status == status
    assert comparison.problems == []
    # Same machine name: the labels are made unique by the creation time.
    assert comparison.base != comparison.others[0]


def test_global_decrease_is_called_preload_loss() -> None:
    comparison = compare_results(results(), [results(factor=0.62)], labels=["delivery", "year 3"])
    assert comparison.base == "delivery" and comparison.others == ["year 3"]
    text = " ".join(comparison.findings)
    assert "-38.0 %" in text
    assert "preload" in text
    assert comparison.runs[0].status == "critical"  # beyond 25 %


def test_local_change_is_reported_as_local() -> None:
    def stuck_cover(axis: str, i: int, direction: str, v: float) -> float:
        return 1.4 if (axis, i) == ("X", 2) else 1.0

    comparison = compare_results(results(), [results(factor=stuck_cover)])
    # Coulomb friction of axis X +13.3 % (a warning), and a local change of 40 % at one
    # position: the change's own pattern names a cause, beyond the fault spread
    assert comparison.runs[0].status == "critical"
    assert comparison.runs[0].axis_status == {"X": "critical", "Y": "ok"}
    assert any(
        r.startswith("axis X: since the baseline, friction changed along the travel by")
        and r.endswith("(critical)")
        for r in comparison.runs[0].reasons
    )
    assert "axis X position 3 (700 mm)" in (comparison.runs[0].worst or "")
    assert any("local cause" in line for line in comparison.findings)
    groups = {(g.axis, g.position_index, g.direction): g for g in comparison.groups}
    assert groups["X", 2, "negative"].median_deviation_percent == pytest.approx(40.0)
    assert groups["X", 1, "negative"].status == "ok"


def test_without_friction_lines_the_change_is_a_warning_not_ok() -> None:
    base = results(created="2026-01-15T08:30:00+00:00")
    for later, which in (
        (results(factor=0.7, lines=False, created="2028-01-15T08:30:00+00:00"), "the latest"),
        (results(factor=1.0, lines=False, created="2028-01-15T08:30:00+00:00"), "the latest"),
    ):
        comparison = compare_results(base, [later])
        (run,) = comparison.runs
        assert run.status == "warning"
        assert run.axis_status == {"X": "warning", "Y": "warning"}
        assert run.reasons[0] == (
            f"axis X: no friction line in {which} measurement: the change since the baseline "
            "cannot be judged"
        )
    unfitted = results(lines=False)
    comparison = compare_results(unfitted, [results(factor=1.02, created="2028-01-15T08:30:00Z")])
    assert comparison.runs[0].status == "warning"
    assert "no friction line in the baseline measurement" in comparison.runs[0].reasons[0]


def test_limits_use_the_median_over_velocities_not_single_points() -> None:
    def one_bad_step(axis: str, i: int, direction: str, v: float) -> float:
        return 2.0 if v == SPEEDS[3] else 1.0  # +100 % at one velocity only

    comparison = compare_results(results(), [results(factor=one_bad_step)])
    assert comparison.runs[0].status == "ok"
    assert max(g.max_abs_point_deviation_percent for g in comparison.groups) == pytest.approx(100)
    assert comparison.status == "ok"


def test_labels_for_the_others_only_or_for_all() -> None:
    base, later = results("M1"), results("M1", 0.9, created="2027-01-01T00:00:00+00:00")
    only_others = compare_results(base, [later], labels=["2027"])
    assert only_others.base == "M1 @ 2026-01-15T08:30:00+00:00"
    assert only_others.others == ["2027"]
    assert {d.label for d in only_others.deviations} == {"2027"}
    both = compare_results(base, [later], labels=["2026", "2027"])
    assert (both.base, both.others) == ("2026", ["2027"])


def test_a_label_that_is_the_base_default_does_not_clash() -> None:
    comparison = compare_results(results("A"), [results("B")], labels=["A"])
    assert (comparison.base, comparison.others) == ("A (base)", ["A"])


def test_custom_limits() -> None:
    limits = Limits(warning_percent=10, critical_percent=15)
    comparison = compare_results(results(), [results(factor=1.12)], limits=limits)
    assert comparison.runs[0].status == "warning"
    comparison = compare_results(results(), [results(factor=1.2)], limits=limits)
    assert comparison.status == "critical"
    with pytest.raises(ValidationError, match="critical_percent"):
        Limits(warning_percent=30, critical_percent=20)
    with pytest.raises(ValidationError):
        Limits(outlier_z=0)


# --------------------------------------------------------------------------- fleet


def test_fleet_outlier_among_six_machines() -> None:
    levels = [1.0, 1.04, 0.97, 1.02, 0.99, 1.6]  # machine 6: a constrained assembly
    runs = [
        results(f"HMX-400 #{i + 1}", level, noise=0.01, seed=i) for i, level in enumerate(levels)
    ]
    comparison = compare_results(runs[0], runs[1:])
    assert comparison.mode == "fleet"
    assert comparison.others == [f"HMX-400 #{i}" for i in range(2, 7)]
    assert [f.axis for f in comparison.fleet] == ["X", "Y"]
    for stats in comparison.fleet:
        assert stats.outliers == ["HMX-400 #6"]
        assert stats.common_points == 3 * 2 * SPEEDS.size
        assert len(stats.mean_friction) == 6
        assert stats.modified_z[5] > 3.5
        assert max(abs(z) for z in stats.modified_z[:5]) < 3.5
        expected = (max(stats.mean_friction) - min(stats.mean_friction)) / np.mean(
            stats.mean_friction
        )
        assert stats.spread_percent == pytest.approx(100 * expected)
        assert stats.spread_percent == pytest.approx(100 * 0.63 / np.mean(levels), rel=0.05)
        assert stats.std == pytest.approx(np.std(stats.mean_friction, ddof=1))
    assert any("outlier: 'HMX-400 #6'" in line for line in comparison.findings)
    statuses = {r.label: r.status for r in comparison.runs}
    assert statuses["HMX-400 #6"] == "critical"
    assert comparison.status == "critical"


def test_fleet_without_outlier() -> None:
    runs = [results(f"M{i}", 1 + 0.015 * i, noise=0.01, seed=i) for i in range(6)]
    comparison = compare_results(runs[0], runs[1:])
    assert all(stats.outliers == [] for stats in comparison.fleet)
    assert comparison.status == "ok"


def test_two_different_machines_are_a_fleet_without_outliers() -> None:
    comparison = compare_results(results("A"), [results("B", 1.1)])
    assert comparison.mode == "fleet"
    assert comparison.fleet[0].outliers == []
    assert any("at least 3 runs" in line for line in comparison.findings)


# --------------------------------------------------------------------------- mismatches


def test_mismatched_velocities_are_reported_and_skipped() -> None:
    other_speeds = SPEEDS.copy()
    other_speeds[4] *= 1.01  # 1 % off: no match
    other_speeds[5] *= 1.004  # 0.4 % off: matches
    other = results(factor=0.9, speeds=np.delete(other_speeds, [0]))  # lowest step missing
    comparison = compare_results(results(), [other])
    per_direction = SPEEDS.size - 2
    assert len(comparison.deviations) == 2 * 3 * 2 * per_direction
    assert len(comparison.problems) == 2 * 3 * 2 * 2  # missing + extra per direction
    first = comparison.problems[0]
    assert "2 of 20 base velocities have no match within 0.5 %" in first
    assert f"{SPEEDS[0]:g}" in first
    assert any("not every point was compared" in line for line in comparison.findings)
    assert comparison.runs[0].max_abs_deviation_percent == pytest.approx(10.0)


def test_different_position_counts_are_matched_by_position() -> None:
    other = results(factor=0.9, positions=[50.0, 212.5, 375.0, 537.5, 700.0])
    comparison = compare_results(results(), [other])
    assert {d.position_index for d in comparison.deviations} == {0, 1, 2}
    assert {d.position_mm for d in comparison.deviations} == set(POSITIONS)
    assert any(
        "has 5 positions, the base 3; matched 3 by position" in p for p in comparison.problems
    )


def test_shifted_positions_are_compared_by_index_with_a_note() -> None:
    other = results(factor=0.9, positions=[60.0, 375.0, 690.0])
    comparison = compare_results(results(), [other])
    assert len(comparison.deviations) == 2 * 3 * 2 * SPEEDS.size
    assert any("position 1 is at 60 mm, the base's at 50 mm" in p for p in comparison.problems)


def test_missing_axis_and_other_quantity() -> None:
    other = results(factor=0.9, axes=("X",))
    comparison = compare_results(results(), [other])
    assert any("axis Y of the base is missing" in p for p in comparison.problems)
    current = results(axes=("X", "Y"), quantity="current_a")
    with pytest.raises(ComparisonError, match="no point"):
        compare_results(results(), [current])


def test_nothing_to_compare_is_bad_input() -> None:
    with pytest.raises(ComparisonError, match="at least one"):
        compare_results(results(), [])
    with pytest.raises(ComparisonError, match="1 labels for 3 results"):
        compare_results(results("A"), [results("B"), results("C")], labels=["B"])
    with pytest.raises(ComparisonError, match="unique"):
        compare_results(results("A"), [results("B")], labels=["A", "A"])
    other = results(speeds=SPEEDS * 1.5)
    with pytest.raises(ComparisonError) as info:
        compare_results(results(), [other])
    assert "within 0.5 %" in str(info.value)
    assert "no match" in str(info.value)  # the problem lines come with it
    assert isinstance(info.value, ValueError)


def test_comparison_json_round_trip() -> None:
    comparison = compare_results(results("A"), [results("B", 0.8), results("C", 1.1)])
    again = Comparison.model_validate_json(comparison.model_dump_json())
    assert again == comparison
    assert again.format == "ncmeasure-comparison" and again.format_version == 1
    with pytest.raises(ValidationError):
        Comparison.model_validate({**comparison.model_dump(), "unexpected": 1})


# --------------------------------------------------------------------------- cause of the change

FIVE = [50.0, 212.5, 375.0, 537.5, 700.0]
TRAVEL = (0.0, 750.0)


def change_of(
    factor: Factor | float,
    *,
    base_factor: Factor | float = 1.0,
    fixed_bearing_end: Literal["min", "max"] = "min",
    limits: Limits | None = None,
) -> tuple[Comparison, AxisChange]:
    """Base and later run on 5 positions with 1 % noise; the change of axis X."""

    def run(f: Factor | float, seed: int, created: str) -> Results:
        return results(
            factor=f,
            noise=0.01,
            seed=seed,
            created=created,
            positions=FIVE,
            travel_mm=TRAVEL,
            fixed_bearing_end=fixed_bearing_end,
        )

    base = run(base_factor, 1, "2026-01-15T08:30:00+00:00")
    later = run(factor, 2, "2028-01-15T08:30:00+00:00")
    comparison = compare_results(base, [later], labels=["delivery", "year 3"], limits=limits)
    assert [(c.label, c.axis) for c in comparison.changes] == [("year 3", "X"), ("year 3", "Y")]
    return comparison, comparison.changes[0]


def along(values: list[float]) -> Factor:
    return lambda axis, i, direction, v: values[i]


def test_global_increase_points_at_preload_or_carriage() -> None:
    comparison, change = change_of(1.2)
    assert change.signature == "flat"
    assert change.mean_change_percent == pytest.approx(20.0, abs=1.0)
    assert change.points == 2 * 5 * SPEEDS.size
    assert change.positions_mm == FIVE
    assert change.change_percent == pytest.approx([20.0] * 5, abs=1.5)
    assert [c.cause for c in change.causes] == ["preload_or_carriage", "cover_or_seal"]
    assert 0.5 < change.causes[0].score < 0.9  # between the warning and the critical limit
    assert "+20" in change.causes[0].evidence and "global offset" in change.causes[0].evidence
    assert any(
        "axis X" in line and "likely cause" in line and "preload_or_carriage" in line
        for line in comparison.findings
    )
    assert change.notes == []


def test_global_decrease_is_preload_loss_and_scores_grow_with_size() -> None:
    comparison, change = change_of(0.62)
    lead = change.causes[0]
    assert (lead.cause, change.signature) == ("preload_or_carriage", "flat")
    assert "preload loss" in lead.evidence and "60 %" in lead.evidence
    assert any("preload loss" in line and "axis X" in line for line in comparison.findings)
    smaller = change_of(0.75)[1].causes[0]
    assert smaller.cause == "preload_or_carriage"
    assert smaller.score < lead.score
    assert change_of(0.5)[1].causes[0].score == pytest.approx(0.9)  # beyond critical: capped


def test_rise_towards_the_loose_bearing_against_the_base() -> None:
    rise = along([1 + 0.3 * (p - FIVE[0]) / (FIVE[-1] - FIVE[0]) for p in FIVE])
    comparison, change = change_of(rise)
    assert change.signature == "rising_to_loose_bearing"
    assert change.causes[0].cause == "loose_bearing"
    assert change.causes[0].evidence.startswith("The change against 'delivery'")
    assert change.change_percent[-1] - change.change_percent[0] == pytest.approx(30.0, abs=2.0)
    assert any("loose_bearing" in line for line in comparison.findings)
    # The fixed bearing at the other end: the same rise now runs towards the fixed bearing.
    _, mirrored = change_of(rise, fixed_bearing_end="max")
    assert mirrored.causes[0].cause == "fixed_bearing"


def test_nut_pattern_step_and_small_change() -> None:
    assert change_of(along([1.25, 1.08, 1.0, 1.08, 1.25]))[1].causes[0].cause == "screw_nut"
    step = change_of(along([1.0, 1.0, 1.25, 1.25, 1.25]))[1]
    assert (step.signature, step.causes[0].cause) == ("step", "cover_or_seal")
    small = change_of(1.01)[1]
    assert (small.signature, small.causes[0].cause) == ("flat", "none")
    assert small.causes[0].score > 0.8
    # The same +10 % is a global offset once the warning limit is lower.
    strict = change_of(1.1, limits=Limits(warning_percent=5, critical_percent=15))[1]
    assert strict.causes[0].cause == "preload_or_carriage"


def test_the_machines_own_position_dependency_cancels() -> None:
    own = along([1.0, 1.075, 1.15, 1.225, 1.3])  # 30 % rise in both runs
    comparison, change = change_of(own, base_factor=own)
    assert (change.signature, change.causes[0].cause) == ("flat", "none")
    assert abs(change.mean_change_percent) < 2.0
    assert comparison.runs[0].status == "ok"


def test_a_local_pattern_on_a_moved_level_names_both() -> None:
    _, change = change_of(along([1.3 * f for f in (1.25, 1.08, 1.0, 1.08, 1.25)]))
    assert [c.cause for c in change.causes[:2]] == ["screw_nut", "preload_or_carriage"]
    assert change.causes[1].score <= change.causes[0].score


def test_unknown_bearing_end_and_few_positions_are_noted() -> None:
    comparison = compare_results(results(), [results(factor=1.3)])  # no travel, no bearing end
    change = comparison.changes[0]
    assert change.causes[0].cause == "preload_or_carriage"
    assert any("fixed-bearing end unknown" in n for n in change.notes)
    assert any("travel unknown" in n for n in change.notes)
    two = [50.0, 700.0]
    comparison = compare_results(results(positions=two), [results(factor=1.3, positions=two)])
    change = comparison.changes[0]
    assert change.signature == "insufficient_data"
    assert [c.cause for c in change.causes] == ["preload_or_carriage", "none"]
    assert "fewer than 3 positions" in change.causes[0].evidence


def test_changes_in_a_fleet_are_per_run() -> None:
    comparison = compare_results(results("A"), [results("B", 1.3), results("C", 1.02)])
    leads = {(c.label, c.axis): c.causes[0].cause for c in comparison.changes}
    assert leads == {
        ("B", "X"): "preload_or_carriage",
        ("B", "Y"): "preload_or_carriage",
        ("C", "X"): "none",
        ("C", "Y"): "none",
    }


def test_changes_round_trip_and_old_files_load() -> None:
    comparison, _ = change_of(along([1.0, 1.0, 1.25, 1.25, 1.25]))
    again = Comparison.model_validate_json(comparison.model_dump_json())
    assert again == comparison
    assert again.changes[0].causes[0].cause == "cover_or_seal"
    old = comparison.model_dump(mode="json")
    del old["changes"]
    loaded = Comparison.model_validate(old)
    assert loaded.changes == []
    assert loaded.findings == comparison.findings


# --- the fleet at once: leave-one-out modified z ----------------------------------------

_fleet_values = st.lists(
    st.one_of(
        st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False),
        st.sampled_from([0.0, 1.0, 1.5, 2.0]),  # ties: MAD 0, mean-AD fallback, no scatter
    ),
    min_size=2,
    max_size=14,
)


@settings(max_examples=400, deadline=None)
@given(_fleet_values)
def test_leave_one_out_z_is_each_value_against_the_others(values: list[float]) -> None:
    z, medians = modified_z_leave_one_out(values)
    for i, value in enumerate(values):
        others = values[:i] + values[i + 1 :]
        assert medians[i] == pytest.approx(float(np.median(others)), rel=1e-12, abs=1e-12)
        assert z[i] == pytest.approx(modified_z_against(value, others), rel=1e-9, abs=1e-9)


def test_leave_one_out_z_names_the_outlier_of_a_fleet() -> None:
    values = [1.0, 1.02, 0.98, 1.01, 0.99, 1.6]
    z, medians = modified_z_leave_one_out(values)
    assert np.argmax(np.abs(z)) == 5 and z[5] > 3.5
    assert medians[5] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="at least two"):
        modified_z_leave_one_out([1.0])


@pytest.mark.parametrize(
    ("ends", "middle", "lead"),
    [
        # the whole level moved far more than its shape varies: a preload change that
        # follows the part's own friction along the screw
        (1.166, 1.116, "preload_or_carriage"),
        # more at the ends than a preload change explains: the nut, the level second
        (1.33, 1.21, "screw_nut"),
    ],
)
def test_a_level_change_with_a_shape_is_led_by_what_dominates(
    ends: float, middle: float, lead: str
) -> None:
    def shaped(axis: str, i: int, direction: str, v: float) -> float:
        return middle if i == 1 else ends

    comparison = compare_results(results(), [results(factor=shaped)])
    for change in comparison.changes:
        assert change.signature == "high_at_both_ends"
        ranked = [c.cause for c in change.causes]
        assert ranked[0] == lead, ranked
        assert {"preload_or_carriage", "screw_nut"} <= set(ranked[:2])
        assert [c.score for c in change.causes] == sorted(
            (c.score for c in change.causes), reverse=True
        )
