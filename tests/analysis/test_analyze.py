"""analyze() end to end: synthetic recordings with known friction analysed back to it.

Stated tolerances (docs/analysis.md, "Accuracy"), for the default synthetic
axis (noise 0.05 Nm, cogging ripple 0.02 Nm, 0.2 % current spikes of 3 Nm,
servo overshoot after every ramp, 16 geometric steps 10..15 000 mm/min,
3 positions, both directions, 0.4 s windows at 4 ms):

=====================================  =====================================
every point's median                   within the cogging amplitude + 5
                                       standard errors (√(π/2)·std/√n) of
                                       the true friction + offset
Coulomb T_C per position               1 % (mean of both directions' fits)
viscous coefficient b                  3 %
Stribeck hump T_S − T_C                25 %
Stribeck velocity v_S                  25 %
Stribeck exponent δ                    ± 0.3
offset (gravity / bias)                ± 0.01 Nm
=====================================  =====================================

The observed errors over seeds 0..3 and all six ways of finding and
labelling windows were a third of these or less (T_C 0.3 %, b 0.8 %, hump
9 %, v_S 9 %, δ 0.12, offset 0.001 Nm).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from pydantic import ValidationError

from ncmeasure.analysis.analyze import AnalysisSettings, analyze
from ncmeasure.errors import ConfigError, OutputError, RecordingError
from ncmeasure.formats.results import (
    RESULTS_FORMAT_VERSION,
    AxisResult,
    Results,
    load_results,
    write_results,
)
from ncmeasure.formats.schedule import Schedule
from ncmeasure.recording import Recording, RecordingWriter
from ncmeasure.samples import SIGNAL_UNITS, Channel, SampleBlock
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.synthetic import (
    SyntheticAxis,
    geometric_velocities,
    machine_config,
    simulate,
    synthetic_recording,
)

COULOMB_REL = 0.01
VISCOUS_REL = 0.03
HUMP_REL = 0.25
STRIBECK_VELOCITY_REL = 0.25
DELTA_ABS = 0.3
OFFSET_ABS = 0.01
POINT_STANDARD_ERRORS = 5.0

KNOWN = SyntheticAxis(
    coulomb=(2.0, 2.2, 2.6),
    viscous_per_mm_min=2e-4,
    stribeck=0.8,
    stribeck_velocity_mm_min=60.0,
    offset=0.5,
    velocities_mm_min=geometric_velocities(10.0, 15000.0, 16),
)
P5 = (50.0, 212.5, 375.0, 537.5, 700.0)
WAYS: dict[str, dict[str, Any]] = {
    "marker": {},
    "command": {"with_marker": False},
    "plateau": {"with_marker": False, "with_command": False},
}


def _record(
    directory: Path, axes: list[SyntheticAxis], way: str = "marker", **options: Any
) -> tuple[Recording, Schedule | None]:
    return synthetic_recording(directory, axes, **WAYS[way], **options)


# --- parameters back -------------------------------------------------------------------


@pytest.fixture(scope="module")
def known_results(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, bool], AxisResult]:
    results = {}
    for way in WAYS:
        for with_schedule in (True, False):
            directory = tmp_path_factory.mktemp(f"{way}-{with_schedule}")
            recording, schedule = _record(directory / "rec", [KNOWN], way, seed=5)
            result = analyze(recording, schedule=schedule if with_schedule else None)
            results[(way, with_schedule)] = result.axes["X"]
    return results


CASES = [(way, s) for way in WAYS for s in (True, False)]
IDS = [f"{way}-{'schedule' if s else 'clusters'}" for way, s in CASES]


@pytest.mark.parametrize(("way", "with_schedule"), CASES, ids=IDS)
def test_windows_found_and_labelled(
    known_results: dict[tuple[str, bool], AxisResult], way: str, with_schedule: bool
) -> None:
    axis = known_results[(way, with_schedule)]
    assert axis.window_source == way
    assert axis.windows == len(KNOWN.velocities_mm_min) * 3 * 2
    assert axis.quantity == "torque_nm"
    assert axis.unit == "Nm"
    assert axis.torque_constant_nm_per_a == 2.1
    assert [p.position_mm for p in axis.positions] == pytest.approx(KNOWN.positions_mm, abs=2.0)
    first = {
        "marker": None,
        "command": "no marker: windows from the commanded velocity",
        "plateau": "no marker and no commanded velocity: windows from constant-velocity "
        "plateaus of the actual velocity",
    }[way]
    if first is None:
        assert axis.warnings == []
    else:
        assert axis.warnings[0] == first
        assert any("rapid traverse" in w for w in axis.warnings)


@pytest.mark.parametrize(("way", "with_schedule"), CASES, ids=IDS)
def test_every_point_is_the_known_friction(
    known_results: dict[tuple[str, bool], AxisResult], way: str, with_schedule: bool
) -> None:
    axis = known_results[(way, with_schedule)]
    for position in axis.positions:
        keys: tuple[tuple[int, Literal["positive", "negative"]], ...] = (
            (1, "positive"),
            (-1, "negative"),
        )
        for sign, key in keys:
            direction = position.directions[key]
            assert direction is not None
            assert len(direction.points) == len(KNOWN.velocities_mm_min)
            for point, speed in zip(direction.points, KNOWN.velocities_mm_min, strict=True):
                assert point.velocity_mm_min == pytest.approx(sign * speed, rel=0.01)
                expected = KNOWN.expected(sign * speed, position.position_index)
                bound = KNOWN.cogging_amplitude + POINT_STANDARD_ERRORS * math.sqrt(
                    math.pi / 2
                ) * point.std / math.sqrt(point.n)
                assert abs(point.median - expected) <= bound, (point, expected)


@pytest.mark.parametrize(("way", "with_schedule"), CASES, ids=IDS)
def test_fits_give_back_the_known_parameters(
    known_results: dict[tuple[str, bool], AxisResult], way: str, with_schedule: bool
) -> None:
    axis = known_results[(way, with_schedule)]
    assert axis.offset is not None
    assert axis.offset.value == pytest.approx(KNOWN.offset, abs=OFFSET_ABS)
    for position in axis.positions:
        index = position.position_index
        positive, negative = position.directions["positive"], position.directions["negative"]
        assert positive is not None and negative is not None
        assert positive.fit is not None and negative.fit is not None
        # The points carry T₊ = F + o and T₋ = −F + o; the fits see friction, the offset
        # taken out first: both directions give F.
        for direction in (positive, negative):
            assert direction.offset_removed == pytest.approx(KNOWN.offset, abs=OFFSET_ABS)
            assert direction.fit is not None and direction.fit.coulomb is not None
            assert direction.fit.coulomb == pytest.approx(
                KNOWN.parameter("coulomb", index), rel=COULOMB_REL
            )
        for direction in (positive, negative):
            assert direction.fit is not None and direction.stribeck is not None
            assert direction.fit.accepted
            assert direction.fit.viscous_per_mm_min == pytest.approx(2e-4, rel=VISCOUS_REL)
            # The Stribeck model describes the whole curve; the line holds above its hump.
            assert direction.model == "stribeck", direction.model_reason
            assert direction.fit.points_below_range > 0
            parameters = direction.stribeck.parameters
            assert parameters is not None
            assert parameters["T_S"] - parameters["T_C"] == pytest.approx(0.8, rel=HUMP_REL)
            assert parameters["v_S"] == pytest.approx(60.0, rel=STRIBECK_VELOCITY_REL)
            assert parameters["delta"] == pytest.approx(1.0, abs=DELTA_ABS)
            assert direction.stribeck.identifiable


def test_rising_coulomb_reads_as_rising_to_the_loose_bearing(
    known_results: dict[tuple[str, bool], AxisResult],
) -> None:
    dependency = known_results[("marker", True)].position_dependency
    assert dependency is not None
    assert dependency.signature == "rising_to_loose_bearing"
    assert dependency.causes[0].cause == "loose_bearing"


# --- position dependency: every signature --------------------------------------------

SIGNATURES = {
    "flat": ((2.0, 2.0, 2.0, 2.0, 2.0), "min", "none"),
    "rising_to_loose_bearing": ((2.0, 2.15, 2.3, 2.45, 2.6), "min", "loose_bearing"),
    "rising_to_fixed_bearing": ((2.0, 2.15, 2.3, 2.45, 2.6), "max", "fixed_bearing"),
    "high_at_both_ends": ((2.6, 2.2, 2.0, 2.2, 2.6), "min", "screw_nut"),
    "step": ((2.0, 2.0, 2.0, 2.5, 2.5), "min", "cover_or_seal"),
}


@pytest.mark.parametrize("way", ["marker", "plateau"])
@pytest.mark.parametrize("signature", list(SIGNATURES))
def test_each_signature_is_recognised(tmp_path: Path, signature: str, way: str) -> None:
    coulomb, fixed_end, cause = SIGNATURES[signature]
    spec = SyntheticAxis(
        positions_mm=P5,
        coulomb=coulomb,
        mechanics=rig_mechanics(fixed_bearing_end=fixed_end),
        velocities_mm_min=geometric_velocities(10.0, 15000.0, 8),
    )
    recording, schedule = _record(tmp_path / "rec", [spec], way, schedule=way == "marker")
    axis = analyze(recording, schedule=schedule).axes["X"]
    assert len(axis.positions) == 5
    dependency = axis.position_dependency
    assert dependency is not None
    assert dependency.signature == signature
    assert dependency.causes[0].cause == cause


# --- offset, units, machine file -------------------------------------------------------


def test_vertical_axis_gravity_is_separated(tmp_path: Path) -> None:
    z = SyntheticAxis(
        name="Z",
        mechanics=rig_mechanics(travel_mm=(-500.0, 0.0), fixed_bearing_end="max", vertical=True),
        positions_mm=(-450.0, -250.0, -50.0),
        offset=3.0,  # gravity: larger than the friction, so T₋ is positive too
        velocities_mm_min=geometric_velocities(10.0, 12000.0, 10),
    )
    recording, schedule = _record(tmp_path / "rec", [z], seed=2)
    axis = analyze(recording, schedule=schedule).axes["Z"]
    assert axis.offset is not None
    assert axis.offset.value == pytest.approx(3.0, abs=OFFSET_ABS)
    assert "gravity" in axis.offset.explanation
    for position in axis.positions:
        negative = position.directions["negative"]
        assert negative is not None
        # Below 1 m/min gravity (3 Nm) outweighs friction (at most 2.8 Nm): T₋ > 0.
        slow = [p for p in negative.points if abs(p.velocity_mm_min) <= 1000.0]
        assert slow
        assert all(p.median > 0 for p in slow)
    dependency = axis.position_dependency
    assert dependency is not None
    assert dependency.signature == "flat"  # the half difference is free of gravity


def test_vertical_axis_in_one_direction_warns(tmp_path: Path) -> None:
    z = SyntheticAxis(
        name="Z",
        mechanics=rig_mechanics(vertical=True),
        offset=3.0,
        both_directions=False,
        velocities_mm_min=geometric_velocities(10.0, 12000.0, 8),
    )
    recording, schedule = _record(tmp_path / "rec", [z])
    axis = analyze(recording, schedule=schedule).axes["Z"]
    assert axis.offset is None
    assert any("gravity is not separated" in w for w in axis.warnings)
    assert all(p.directions["negative"] is None for p in axis.positions)


def test_current_only_axis_stays_in_amperes(tmp_path: Path) -> None:
    spec = SyntheticAxis(
        unit="A",
        mechanics=rig_mechanics(torque_constant_nm_per_a=None),
        coulomb=3.0,
        noise=0.03,
        velocities_mm_min=geometric_velocities(10.0, 15000.0, 10),
    )
    recording, schedule = _record(tmp_path / "rec", [spec], axis_metadata=False)
    axis = analyze(recording, schedule=schedule).axes["X"]
    assert axis.quantity == "current_a"
    assert axis.unit == "A"
    assert axis.torque_constant_nm_per_a is None
    assert any("no torque constant" in w for w in axis.warnings)
    fits = [d.fit for p in axis.positions for d in p.directions.values() if d and d.fit]
    assert np.mean([f.coulomb for f in fits]) == pytest.approx(3.0, rel=COULOMB_REL)


def test_machine_file_supplies_what_the_recording_lacks(tmp_path: Path) -> None:
    spec = SyntheticAxis(velocities_mm_min=geometric_velocities(10.0, 15000.0, 8))
    recording, _ = _record(tmp_path / "rec", [spec], axis_metadata=False)
    assert recording.meta.axes == []
    bare = analyze(recording).axes["X"]
    machine = machine_config([spec])
    full = analyze(recording, machine=machine).axes["X"]
    assert bare.quantity == "current_a"
    assert full.quantity == "torque_nm"
    assert full.torque_constant_nm_per_a == 2.1
    assert not any("torque constant" in w or "bearing end unknown" in w for w in full.warnings)
    assert any("fixed-bearing end unknown" in w for w in bare.warnings)
    a = bare.positions[1].directions["positive"]
    nm = full.positions[1].directions["positive"]
    assert a is not None and nm is not None
    assert [p.median for p in nm.points] == pytest.approx([2.1 * p.median for p in a.points])


def test_the_recording_wins_over_the_machine_file_and_says_so(tmp_path: Path) -> None:
    spec = SyntheticAxis(velocities_mm_min=geometric_velocities(10.0, 15000.0, 8))
    recording, _ = _record(tmp_path / "rec", [spec])
    other = machine_config([SyntheticAxis(mechanics=rig_mechanics(torque_constant_nm_per_a=2.5))])
    axis = analyze(recording, machine=other).axes["X"]
    assert axis.torque_constant_nm_per_a == 2.1
    assert any(
        "torque_constant_nm_per_a is 2.1 in the recording but 2.5 in the machine file" in w
        for w in axis.warnings
    )


def test_three_axes_in_one_recording(tmp_path: Path) -> None:
    # 12 steps: enough points above the Stribeck region for the linear fit to use only them.
    steps = geometric_velocities(10.0, 12000.0, 12)
    axes = [
        SyntheticAxis(name="X", coulomb=2.0, velocities_mm_min=steps),
        SyntheticAxis(name="Y", mechanics=rig_mechanics(travel_mm=(0.0, 600.0)),
                      positions_mm=(50.0, 300.0, 550.0), coulomb=1.5, velocities_mm_min=steps),
        SyntheticAxis(name="Z", mechanics=rig_mechanics(travel_mm=(-500.0, 0.0), vertical=True,
                                                        fixed_bearing_end="max"),
                      positions_mm=(-450.0, -250.0, -50.0), offset=3.0, coulomb=2.5,
                      velocities_mm_min=steps),
    ]  # fmt: skip
    for way in ("marker", "command"):
        recording, schedule = _record(tmp_path / way, axes, way)
        results = analyze(recording, schedule=schedule)
        assert list(results.axes) == ["X", "Y", "Z"]
        for spec in axes:
            axis = results.axes[spec.name]
            assert axis.windows == len(steps) * 3 * 2
            assert axis.offset is not None
            assert axis.offset.value == pytest.approx(spec.offset, abs=OFFSET_ABS)
            fits = [d.fit for p in axis.positions for d in p.directions.values() if d and d.fit]
            mean = np.mean([f.coulomb for f in fits])
            assert mean == pytest.approx(spec.parameter("coulomb", 0), rel=COULOMB_REL)


# --- bad input -------------------------------------------------------------------------


def _write(directory: Path, columns: dict[str, np.ndarray], period_s: float = 0.004) -> Recording:
    channels = []
    for name in columns:
        axis, signal = name.split("_", 1)
        channels.append(Channel(axis, signal, SIGNAL_UNITS[signal]))
    values = np.column_stack(list(columns.values()))
    time_s = np.arange(len(values), dtype=np.float64) * period_s
    with RecordingWriter.create(directory, channels, nominal_period_s=period_s) as writer:
        writer.append(SampleBlock(time_s, values))
    return Recording.open(directory)


@pytest.fixture(scope="module")
def moving() -> dict[str, np.ndarray]:
    data = simulate([SyntheticAxis(velocities_mm_min=(100.0, 1000.0))])
    names = [c.name for c in data.channels]
    return {name: data.values[:, i] for i, name in enumerate(names)}


def test_an_axis_without_current_is_refused(tmp_path: Path, moving: dict[str, Any]) -> None:
    recording = _write(
        tmp_path / "rec",
        {k: v for k, v in moving.items() if k in ("X_velocity_mm_min", "X_position_mm")},
    )
    with pytest.raises(RecordingError, match="axis X cannot be analysed without X_current_a"):
        analyze(recording)


def test_an_axis_without_velocity_is_refused(tmp_path: Path, moving: dict[str, Any]) -> None:
    recording = _write(
        tmp_path / "rec", {k: v for k, v in moving.items() if k in ("X_current_a", "X_marker")}
    )
    with pytest.raises(RecordingError, match="without X_velocity_mm_min"):
        analyze(recording)


def test_no_window_says_what_was_tried(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    recording = _write(
        tmp_path / "rec",
        {
            "X_current_a": rng.normal(0.0, 0.1, 3000),
            "X_velocity_mm_min": rng.normal(0.0, 0.2, 3000),
            "X_position_mm": np.full(3000, 100.0),
            "X_velocity_cmd_mm_min": np.zeros(3000),
        },
    )
    with pytest.raises(RecordingError) as caught:
        analyze(recording)
    text = str(caught.value)
    assert str(recording.directory) in text
    assert "no window of constant velocity found" in text
    assert "marker: not recorded" in text
    assert "commanded velocity: no constant stretch" in text
    assert "plateaus: no stretch" in text


def test_schedule_of_another_program_is_flagged(tmp_path: Path) -> None:
    spec = SyntheticAxis(velocities_mm_min=geometric_velocities(10.0, 15000.0, 6))
    recording, schedule = _record(tmp_path / "rec", [spec])
    assert schedule is not None
    other = schedule.model_copy(update={"config_hash": "0123456789abcdef"})
    axis = analyze(recording, schedule=other).axes["X"]
    assert any("the schedule belongs to another program" in w for w in axis.warnings)


def test_settings_are_validated_and_recorded(tmp_path: Path) -> None:
    with pytest.raises(ValidationError):
        AnalysisSettings(velocity_tolerance=0.0)
    with pytest.raises(ValidationError):
        AnalysisSettings(unknown_setting=1.0)  # type: ignore[call-arg]
    spec = SyntheticAxis(velocities_mm_min=geometric_velocities(10.0, 15000.0, 6))
    recording, schedule = _record(tmp_path / "rec", [spec])
    settings = AnalysisSettings(settle_s=0.05, window_method="command")
    results = analyze(recording, schedule=schedule, settings=settings)
    assert results.settings["settle_s"] == 0.05
    assert results.settings["window_method"] == "command"
    assert results.axes["X"].window_source == "command"


def test_settling_time_removes_the_acceleration_transient(tmp_path: Path) -> None:
    # Strong inertia, no spikes: the mean shows what the transient does.
    spec = SyntheticAxis(
        inertia_per_m_s2=10.0,
        outlier_fraction=0.0,
        velocities_mm_min=geometric_velocities(10.0, 15000.0, 8),
    )
    recording, schedule = _record(tmp_path / "rec", [spec], "command")

    def worst_mean_error(settle_s: float) -> float:
        settings = AnalysisSettings(settle_s=settle_s)
        axis = analyze(recording, schedule=schedule, settings=settings).axes["X"]
        errors = []
        for position in axis.positions:
            for direction in position.directions.values():
                assert direction is not None
                for point in direction.points:
                    expected = spec.expected(point.velocity_mm_min, position.position_index)
                    errors.append(abs(point.mean - expected))
        return max(errors)

    assert worst_mean_error(0.1) < 0.03
    assert worst_mean_error(0.0) > 0.1


def test_progress_is_reported_to_the_end(tmp_path: Path) -> None:
    spec = SyntheticAxis(velocities_mm_min=geometric_velocities(10.0, 15000.0, 6))
    recording, schedule = _record(tmp_path / "rec", [spec])
    seen: list[tuple[str, float]] = []
    analyze(recording, schedule=schedule, progress=lambda s, f: seen.append((s, f)))
    assert seen[0] == ("axis X: windows", 0.0)
    assert seen[-1] == ("done", 1.0)
    fractions = [f for _, f in seen]
    assert fractions == sorted(fractions)
    stages = [s for s, _ in seen]
    assert "axis X: friction table" in stages
    assert "axis X: fits at 375 mm" in stages
    assert "axis X: position dependency" in stages


# --- results.json ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_results(tmp_path_factory: pytest.TempPathFactory) -> Results:
    spec = SyntheticAxis(velocities_mm_min=geometric_velocities(10.0, 15000.0, 6))
    directory = tmp_path_factory.mktemp("small")
    recording, schedule = _record(directory / "rec", [spec])
    return analyze(recording, schedule=schedule)


def test_results_round_trip(tmp_path: Path, small_results: Results) -> None:
    path = write_results(small_results, tmp_path / "out" / "run.results.json")
    assert load_results(path) == small_results
    assert [p.name for p in path.parent.iterdir()] == ["run.results.json"]
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["format"] == "ncmeasure-results"
    assert data["format_version"] == RESULTS_FORMAT_VERSION
    assert data["recording"]["source"] == "synthetic"


def test_writing_replaces_an_old_file_whole(tmp_path: Path, small_results: Results) -> None:
    path = tmp_path / "r.json"
    path.write_text("old", encoding="utf-8")
    write_results(small_results, path)
    assert load_results(path) == small_results


def test_writing_never_follows_a_planted_temporary_file(
    tmp_path: Path, small_results: Results
) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me", encoding="utf-8")
    (tmp_path / ".r.json.tmp").symlink_to(victim)
    write_results(small_results, tmp_path / "r.json")
    assert victim.read_text(encoding="utf-8") == "keep me"
    assert (tmp_path / ".r.json.tmp").is_symlink()
    assert load_results(tmp_path / "r.json") == small_results


def test_writing_where_a_file_blocks_the_directory(tmp_path: Path, small_results: Results) -> None:
    (tmp_path / "blocker").write_text("", encoding="utf-8")
    with pytest.raises(OutputError, match="cannot be written"):
        write_results(small_results, tmp_path / "blocker" / "r.json")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("not json", "x.json: invalid JSON"),
        ('{"format": "ncmeasure-schedule"}', "not an ncmeasure results file"),
        ("[1, 2]", "not an ncmeasure results file"),
        ('{"format": "ncmeasure-results", "format_version": 99}', "update ncmeasure"),
        ('{"format": "ncmeasure-results", "format_version": 1}', "analyse the recording again"),
        ('{"format": "ncmeasure-results", "format_version": 2}', "not a valid results file"),
    ],
)
def test_loading_something_else_is_refused(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "x.json"
    path.write_text(content, encoding="utf-8")
    with pytest.raises(ConfigError, match=message):
        load_results(path)


def test_loading_a_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such results file"):
        load_results(tmp_path / "nothing.json")
