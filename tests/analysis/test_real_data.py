"""The analysis on data with the properties of real machines' recordings.

Each test builds its fixture from a synthetic measurement with one property
seen on real data (:mod:`tests.analysis.real_data`): 100 ms sampling, a dead
channel, a velocity reading frozen at standstill, a velocity in counts of
8.5 mm/min, a current that reacts to the velocity's fluctuation, a vertical
axis with a window lost, lost rows, "no value" codes. Every test failed on the
analysis before it was made to hold on such data.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ncmeasure.analysis.analyze import analyze
from ncmeasure.errors import RecordingError
from ncmeasure.samples import Channel, LinkEvent
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities
from tests.analysis.real_data import Data, decimate, measure, window_rows, write

# --- 3. coarse sampling ------------------------------------------------------------------

COARSE = SyntheticAxis(
    velocities_mm_min=(200.0, 500.0, 1000.0, 2000.0, 4000.0),
    window_s=0.8,
    stribeck=0.3,
    noise=0.03,
)


@pytest.mark.parametrize("with_command", [True, False], ids=["command", "plateaus"])
def test_a_100_ms_data_collector_is_analysed_and_called_coarse(
    tmp_path: Path, with_command: bool
) -> None:
    """At 100 ms a straight move holds fewer than 10 samples of constant velocity."""
    data = decimate(measure([COARSE], with_marker=False, with_command=with_command), 25)
    recording = write(tmp_path / "rec", data, [COARSE])
    assert recording.meta.nominal_period_s == pytest.approx(0.1)
    axis = analyze(recording).axes["X"]  # a data collector: no schedule
    assert axis.windows == 5 * 3 * 2
    assert axis.coarse
    assert any("coarse data" in w for w in axis.warnings)
    for position in axis.positions:
        for direction in position.directions.values():
            assert direction is not None
            assert len(direction.points) == 5
            for point in direction.points:
                assert point.n < 10
                expected = COARSE.expected(point.velocity_mm_min, position.position_index)
                assert point.median == pytest.approx(expected, rel=0.03)
            # Too coarse for a Stribeck curve: said, not fitted into numbers.
            assert direction.stribeck is None or direction.stribeck.parameters is None
            if direction.stribeck is not None:
                assert "coarse" in (direction.stribeck.reason or "")
            assert direction.model == "linear"
            assert direction.fit is not None and direction.fit.coulomb is not None
            truth = COARSE.parameter("coulomb", position.position_index)
            assert direction.fit.coulomb == pytest.approx(truth, rel=0.05)


# --- 4. one bad axis -----------------------------------------------------------------------

TWO = (
    SyntheticAxis(name="X", velocities_mm_min=geometric_velocities(20.0, 6000.0, 6)),
    SyntheticAxis(name="Z", velocities_mm_min=geometric_velocities(20.0, 6000.0, 6)),
)


def test_a_dead_current_channel_skips_its_axis_and_keeps_the_others(tmp_path: Path) -> None:
    data = measure(TWO)
    data = data.set("Z_current_a", np.zeros(len(data.time_s)))  # 0.0 A in every row
    results = analyze(write(tmp_path / "rec", data, TWO), schedule=data.schedule)
    assert list(results.axes) == ["X"]
    assert "Z_current_a is 0 A in every row" in results.skipped["Z"]
    assert "dead channel" in results.skipped["Z"]
    assert results.axes["X"].windows == 6 * 3 * 2


def test_a_current_flat_while_the_axis_moves_is_dead_too(tmp_path: Path) -> None:
    data = measure(TWO)
    current = data.column("Z_current_a").copy()
    moving = np.abs(data.column("Z_velocity_cmd_mm_min")) > 0
    current[moving] = 0.25  # a stuck reading during the whole measurement of Z
    data = data.set("Z_current_a", current)
    results = analyze(write(tmp_path / "rec", data, TWO), schedule=data.schedule)
    assert "Z" not in results.axes
    assert "in every window" in results.skipped["Z"]


def test_an_axis_without_windows_does_not_lose_the_others(tmp_path: Path) -> None:
    data = measure(TWO)
    still = np.full(len(data.time_s), -250.0)
    data = data.set("Z_position_mm", still)
    data = data.set("Z_velocity_mm_min", np.zeros(len(data.time_s)))
    data = data.set("Z_velocity_cmd_mm_min", np.zeros(len(data.time_s)))
    data = data.set("Z_marker", np.zeros(len(data.time_s)))
    results = analyze(write(tmp_path / "rec", data, TWO), schedule=data.schedule)
    assert list(results.axes) == ["X"]
    assert "did not move" in results.skipped["Z"]


def test_no_axis_at_all_is_an_error_listing_every_axis(tmp_path: Path) -> None:
    data = measure(TWO)
    for name in ("X", "Z"):
        data = data.set(f"{name}_current_a", np.zeros(len(data.time_s)))
    with pytest.raises(RecordingError) as caught:
        analyze(write(tmp_path / "rec", data, TWO))
    text = str(caught.value)
    assert "no axis could be analysed" in text
    assert "axis X: X_current_a is 0 A in every row" in text
    assert "axis Z: Z_current_a is 0 A in every row" in text


# --- 2. an axis holding position -------------------------------------------------------------


def test_an_axis_holding_position_did_not_move(tmp_path: Path) -> None:
    """A real trace of an axis in position control at standstill: the position creeps by
    tenths of a micrometre, the velocity reads 0 or ±1 count, the current is noise."""
    rng = np.random.default_rng(3)
    n = 3000  # 6 s at 2 ms
    time_s = np.arange(n) * 0.002
    count = 0.06  # mm/min per count of the velocity
    position = -412.35 + np.cumsum(rng.normal(0, 2e-5, n))  # creeps by < 1 µm
    velocity = count * rng.choice([-1.0, 0.0, 0.0, 0.0, 1.0], n)
    current = 1.2 + rng.normal(0, 0.05, n)
    data = Data(
        time_s,
        tuple(
            Channel("A1", s, u)
            for s, u in (("current_a", "A"), ("velocity_mm_min", "mm/min"), ("position_mm", "mm"))
        ),
        np.column_stack([current, velocity, position]),
        measure([SyntheticAxis(velocities_mm_min=(100.0,))]).schedule,
    )
    with pytest.raises(RecordingError) as caught:
        analyze(write(tmp_path / "rec", data))
    text = str(caught.value)
    assert "axis A1" in text and "the axis did not move" in text
    assert "missing" not in text and "without" not in text


def test_a_sinumerik_trace_of_an_axis_holding_position_did_not_move(tmp_path: Path) -> None:
    """The 840D sl trace layout (measuring system 2, velocity in counts of 0.29 mm/min):
    an axis in position control creeps by 0.3 µm. Not a missing signal: no motion."""
    from ncmeasure.traces import import_trace

    fixture = Path(__file__).parents[1] / "traces" / "fixtures" / "sinumerik_840d_holding.xml"
    recording = import_trace(fixture, tmp_path / "rec").recording
    assert {c.signal for c in recording.channels} >= {"current_a", "velocity_mm_min"}
    with pytest.raises(RecordingError) as caught:
        analyze(recording)
    text = str(caught.value)
    assert "the axis did not move" in text
    assert "without" not in text and "no velocity" not in text


# --- 5. a velocity reading frozen at standstill -------------------------------------------

QUANTISED = SyntheticAxis(
    velocities_mm_min=(20.0, 60.0, 200.0, 600.0, 2000.0),
    velocity_quantum_mm_min=1.5,
    velocity_noise_mm_min=0.5,
    dwell_s=0.6,
)


def test_a_velocity_frozen_at_standstill_is_no_window(tmp_path: Path) -> None:
    """No command channel; while the axis stands, the velocity reads +1.5 or −3 mm/min
    (one and two counts) and the position does not move."""
    data = measure([QUANTISED], with_marker=False, with_command=False)
    velocity = data.column("X_velocity_mm_min").copy()
    position = data.column("X_position_mm")
    standing = np.abs(np.gradient(position, data.time_s)) * 60 < 0.05
    edges = np.flatnonzero(np.diff(standing.astype(int)) == 1)
    for number, edge in enumerate(edges):
        after = ~standing[edge + 1 :]
        end = edge + 1 + int(np.argmax(after)) if after.any() else len(standing)
        velocity[edge + 1 : end] = 1.5 if number % 2 else -3.0
    data = data.set("X_velocity_mm_min", velocity)
    axis = analyze(write(tmp_path / "rec", data, [QUANTISED])).axes["X"]
    speeds = sorted({round(abs(p.velocity_mm_min)) for pos in axis.positions
                     for d in pos.directions.values() if d for p in d.points})  # fmt: skip
    assert speeds == [20, 60, 200, 600, 2000]
    for position in axis.positions:
        for key, direction in position.directions.items():
            assert direction is not None
            sign = 1 if key == "positive" else -1
            assert all(np.sign(p.velocity_mm_min) == sign for p in direction.points)
            assert all(abs(p.velocity_mm_min) >= 19.0 for p in direction.points)


# --- 6. a velocity in coarse counts, no command ---------------------------------------------

COUNTS = SyntheticAxis(
    velocities_mm_min=(6.0, 12.0, 18.0, 60.0, 200.0, 600.0),
    velocity_quantum_mm_min=8.5,
    velocity_noise_mm_min=1.3,  # 9–22 % at the slow steps
    window_s=1.0,
)


def test_windows_of_a_coarsely_counted_velocity_are_at_the_true_speeds(tmp_path: Path) -> None:
    data = measure([COUNTS], with_marker=False, with_command=False)
    axis = analyze(write(tmp_path / "rec", data, [COUNTS])).axes["X"]
    assert axis.velocity_quantum_mm_min == pytest.approx(8.5, rel=1e-6)
    assert any("displacement" in w for w in axis.warnings)
    for position in axis.positions:
        for direction in position.directions.values():
            assert direction is not None
            speeds = [abs(p.velocity_mm_min) for p in direction.points]
            # One window per step, at the true speed, not at 8.5/17/25.5 mm/min.
            assert speeds == pytest.approx([6.0, 12.0, 18.0, 60.0, 200.0, 600.0], rel=0.03)


# --- 7. a command channel, a noisy counted velocity, a current that reacts to it ---------

FOLLOWING = SyntheticAxis(
    velocities_mm_min=(6.0, 12.0, 18.0, 60.0, 180.0, 600.0, 2000.0),
    velocity_quantum_mm_min=8.5,
    velocity_noise_mm_min=3.0,
    velocity_coupling=0.02,  # Nm the speed controller takes off per mm/min too fast
    noise=0.02,
    cogging_amplitude=0.0,
    window_s=0.6,
)


def test_with_a_command_every_run_counts_and_the_medians_are_unbiased(tmp_path: Path) -> None:
    data = measure([FOLLOWING], with_marker=False)
    recording = write(tmp_path / "rec", data, [FOLLOWING])
    axis = analyze(recording, schedule=data.schedule).axes["X"]
    assert axis.window_source == "command"
    assert axis.windows == 7 * 3 * 2  # the slowest runs too
    for position in axis.positions:
        for direction in position.directions.values():
            assert direction is not None
            assert len(direction.points) == 7
            for point in direction.points:
                expected = FOLLOWING.expected(point.velocity_mm_min, position.position_index)
                assert point.stderr is not None
                assert abs(point.median - expected) <= max(4 * point.stderr, 0.01), (
                    point,
                    expected,
                )


# --- 10. a vertical axis with a cell in one direction only --------------------------------

VERTICAL = SyntheticAxis(
    name="Z",
    mechanics=rig_mechanics(travel_mm=(-500.0, 0.0), fixed_bearing_end="max", vertical=True),
    positions_mm=(-450.0, -350.0, -250.0, -150.0, -50.0),
    offset=15.6,  # gravity, against 1.7 Nm of friction
    coulomb=1.4,
    stribeck=0.3,
    velocities_mm_min=geometric_velocities(20.0, 8000.0, 8),
)


def test_one_lost_window_on_a_vertical_axis_is_no_guide_rail_fault(tmp_path: Path) -> None:
    data = measure([VERTICAL], seed=4)
    middle = [
        w
        for w in data.schedule.axes[0].windows
        if w.position_index == 2 and w.direction == -1 and w.step == 3
    ]
    assert len(middle) == 1
    lost = window_rows(data, "Z", middle[0].id)
    clean = analyze(write(tmp_path / "clean", data, [VERTICAL]), schedule=data.schedule)
    broken = analyze(
        write(tmp_path / "broken", data.rows(~lost), [VERTICAL]), schedule=data.schedule
    )
    for results in (clean, broken):
        axis = results.axes["Z"]
        assert axis.position_dependency is not None
        assert axis.position_dependency.signature == "flat"
        assert axis.position_dependency.spread_percent < 5.0
        assert axis.verdict.level == "ok", axis.verdict
    assert broken.recording.gaps == 1
    assert any("one direction only" in w for w in broken.axes["Z"].warnings)


# --- 11. lost samples --------------------------------------------------------------------------


def test_lost_samples_are_counted_and_said(tmp_path: Path) -> None:
    data = measure([TWO[0]])
    rng = np.random.default_rng(2)
    keep = np.ones(len(data.time_s), dtype=bool)
    for start in rng.choice(len(keep) - 20, 40, replace=False):
        keep[start : start + int(rng.integers(1, 12))] = False
    lost = int(np.count_nonzero(~keep))
    results = analyze(write(tmp_path / "rec", data.rows(keep), [TWO[0]], period_s=0.004))
    info = results.recording
    assert info.gap_samples == lost
    assert 30 <= info.gaps <= 40
    assert info.gap_share == pytest.approx(lost / len(keep))
    assert any(f"{lost} samples lost" in w for w in results.axes["X"].warnings)


def test_skipped_cycles_are_said_apart_as_a_share(tmp_path: Path) -> None:
    """Cycles the link skipped (the host fell behind) are lost samples, and said apart."""
    data = measure([TWO[0]])
    keep = np.ones(len(data.time_s), dtype=bool)
    keep[1000:1100] = False
    gap = LinkEvent(
        float(data.time_s[1000]), "gap", "100 samples dropped: 100 SYNC cycles not sent",
        lost_samples=100, details={"missing_sync": 100, "skipped_cycles": 100},
    )  # fmt: skip
    rows = data.rows(keep)
    results = analyze(write(tmp_path / "rec", rows, [TWO[0]], period_s=0.004, events=[gap]))
    info = results.recording
    assert (info.gap_samples, info.skipped_cycles) == (100, 100)
    share = 100 / len(keep) * 100
    assert any(
        f"100 of them cycles the link skipped because the host fell behind ({share:.2g} % of "
        "the recording): it sampled at " in w
        for w in results.axes["X"].warnings
    ), results.axes["X"].warnings


# --- 12. "no value" codes ------------------------------------------------------------------


def test_no_value_codes_are_left_out_and_counted(tmp_path: Path) -> None:
    axis_spec = TWO[0]
    data = measure([axis_spec], seed=6)
    clean = analyze(write(tmp_path / "clean", data, [axis_spec]), schedule=data.schedule)
    rng = np.random.default_rng(6)
    rows = rng.choice(len(data.time_s), 200, replace=False)
    current = data.column("X_current_a").copy()
    current[rows] = -999999.0
    velocity = data.column("X_velocity_mm_min").copy()
    velocity[rows[:20]] = -999999.0
    data = data.set("X_current_a", current).set("X_velocity_mm_min", velocity)
    dirty = analyze(write(tmp_path / "dirty", data, [axis_spec]), schedule=data.schedule)
    axis = dirty.axes["X"]
    assert axis.implausible_values == {"X_current_a": 200, "X_velocity_mm_min": 20}
    assert any("-999999" in w and "X_current_a: 200 value(s)" in w for w in axis.warnings)
    for found, reference in zip(axis.positions, clean.axes["X"].positions, strict=True):
        for key, direction in found.directions.items():
            other = reference.directions[key]
            assert direction is not None and other is not None
            for point, ref in zip(direction.points, other.points, strict=True):
                assert math.isfinite(point.median)
                assert abs(point.median - ref.median) <= 3 * (ref.stderr or 0.0) + 1e-9


# --- what a review of the rules found on data like this ----------------------------------


def test_an_idle_axis_with_a_frozen_reading_did_not_move(tmp_path: Path) -> None:
    """While X is measured, Z holds: its reading sits at −3 mm/min and drops to 0 now and
    then (many plateaus), its position does not move. No window, and Z did not move."""
    data = measure(TWO)
    rng = np.random.default_rng(5)
    n = len(data.time_s)
    frozen = np.full(n, -3.0)
    for start in rng.choice(n - 300, 12, replace=False):
        frozen[start : start + 200] = 0.0
    data = (
        data.set("Z_velocity_mm_min", frozen)
        .set("Z_position_mm", np.full(n, -250.0))
        .set("Z_velocity_cmd_mm_min", np.zeros(n))
        .set("Z_marker", np.zeros(n))
    )
    results = analyze(write(tmp_path / "rec", data, TWO))  # no schedule: plateaus too
    assert list(results.axes) == ["X"]
    assert "the axis did not move" in results.skipped["Z"]


def test_a_held_axis_reading_exactly_zero_did_not_move(tmp_path: Path) -> None:
    """Velocity 0.0 in every row, the position drifting by a fraction of a micrometre:
    an axis holding position, not a dead velocity channel."""
    data = measure(TWO)
    n = len(data.time_s)
    drift = -250.0 + np.linspace(0.0, 4e-4, n)
    data = (
        data.set("Z_velocity_mm_min", np.zeros(n))
        .set("Z_position_mm", drift)
        .set("Z_velocity_cmd_mm_min", np.zeros(n))
        .set("Z_marker", np.zeros(n))
    )
    results = analyze(write(tmp_path / "rec", data, TWO), schedule=data.schedule)
    assert "the axis did not move" in results.skipped["Z"]
    assert "dead channel" not in results.skipped["Z"]


def test_a_position_in_inches_is_not_taken_for_millimetres(tmp_path: Path) -> None:
    """A counted velocity would be measured by the position, but this position is in
    inches: the readings keep the say, with a warning, and no step is invented."""
    data = measure([COUNTS], with_marker=False, with_command=False)
    data = data.set("X_position_mm", data.column("X_position_mm") / 25.4)
    axis = analyze(write(tmp_path / "rec", data, [COUNTS])).axes["X"]
    assert any("does not move as the velocity says" in w for w in axis.warnings)
    fast = [
        abs(p.velocity_mm_min)
        for pos in axis.positions
        for d in pos.directions.values()
        if d
        for p in d.points
        if abs(p.velocity_mm_min) > 100
    ]
    assert fast and all(min(abs(v - s) for s in (200.0, 600.0)) < 10.0 for v in fast)


def test_a_position_in_another_unit_keeps_its_windows(tmp_path: Path) -> None:
    """Every window's displacement is 1/25.4 of what the velocity says: one factor, a
    unit (inches), not frozen readings. The windows stay, with a warning."""
    spec = TWO[0]
    data = measure([spec], with_marker=False, with_command=False)
    data = data.set("X_position_mm", data.column("X_position_mm") / 25.4)
    axis = analyze(write(tmp_path / "rec", data, [spec])).axes["X"]
    assert any("0.03937 times as far" in w and "another unit" in w for w in axis.warnings)
    assert axis.windows == 6 * 3 * 2


def test_a_position_without_values_does_not_stop_the_analysis(tmp_path: Path) -> None:
    """A logger wrote −999999 for every position sample: left out, the position is then
    unknown, and the windows are clustered on the integrated velocity."""
    data = measure(TWO)
    data = data.set("Z_position_mm", np.full(len(data.time_s), -999999.0))
    results = analyze(write(tmp_path / "rec", data, TWO))  # no schedule
    assert set(results.axes) == {"X", "Z"}
    z = results.axes["Z"]
    assert z.implausible_values["Z_position_mm"] == len(data.time_s)
    assert any("position channel holds a value in fewer than half" in w for w in z.warnings)
    assert len(z.positions) == 3


def test_no_value_codes_left_out_at_the_import_are_counted_in_the_results(
    tmp_path: Path,
) -> None:
    from ncmeasure.traces.csv import export_csv, import_csv

    spec = TWO[0]
    data = measure([spec], seed=6)
    current = data.column("X_current_a").copy()
    current[::500] = -999999.0
    recording = write(tmp_path / "rec", data.set("X_current_a", current), [spec])
    imported = import_csv(export_csv(recording, tmp_path / "x.csv"), tmp_path / "imported")
    expected = len(current[::500])
    assert imported.meta.link["implausible"] == {"X_current_a": expected}
    axis = analyze(imported, schedule=data.schedule).axes["X"]
    assert axis.implausible_values == {"X_current_a": expected}
    assert any("left out at the import" in w for w in axis.warnings)
