"""Finding and labelling constant-velocity windows: marker, command, plateaus; schedule, clusters.

The recordings come from :mod:`ncmeasure.sim.synthetic`: 12 geometric steps
from 10 to 15 000 mm/min at 50 / 375 / 700 mm, both directions (72 windows),
one warm-up stroke, rapids at 30 000 mm/min between the runs, a servo that
lags and overshoots after every ramp.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.ndimage import median_filter

from ncmeasure.analysis.windows.find import find_windows
from ncmeasure.analysis.windows.model import Segmentation, VelocityWindow
from ncmeasure.analysis.windows.settings import SegmentSettings
from ncmeasure.analysis.windows.signals import cluster_gaps
from ncmeasure.errors import RecordingError
from ncmeasure.formats.schedule import Schedule
from ncmeasure.sim.synthetic import SyntheticAxis, SyntheticData, simulate

SPEC = SyntheticAxis()
PLANNED = len(SPEC.velocities_mm_min) * len(SPEC.positions_mm) * 2


@dataclass(frozen=True)
class Signals:
    time_s: NDArray[np.float64]
    velocity: NDArray[np.float64]
    position: NDArray[np.float64]
    command: NDArray[np.float64]
    marker: NDArray[np.float64]
    schedule: Schedule


def _signals(data: SyntheticData, axis: str = "X") -> Signals:
    names = [c.name for c in data.channels]

    def column(signal: str) -> NDArray[np.float64]:
        return data.values[:, names.index(f"{axis}_{signal}")]

    return Signals(
        data.time_s,
        column("velocity_mm_min"),
        column("position_mm"),
        column("velocity_cmd_mm_min"),
        column("marker"),
        data.schedule,
    )


@pytest.fixture(scope="module")
def signals() -> Signals:
    return _signals(simulate([SPEC], seed=1))


def _find(
    s: Signals,
    method: str,
    *,
    schedule: bool = True,
    settings: SegmentSettings | None = None,
    **overrides: Any,
) -> Segmentation:
    channels: dict[str, Any] = {"position_mm": s.position}
    if method == "marker":
        channels.update(marker=s.marker, command_mm_min=s.command)
    elif method == "command":
        channels.update(command_mm_min=s.command)
    channels.update(overrides)
    return find_windows(
        "X",
        s.time_s,
        s.velocity,
        schedule=s.schedule if schedule else None,
        settings=settings,
        **channels,
    )


def _labels(windows: list[VelocityWindow]) -> list[tuple[int, int, int]]:
    return [(w.step, w.position_index, w.direction) for w in windows]


# --- clustering ------------------------------------------------------------------------


def test_cluster_gaps_splits_where_neighbours_are_far_apart() -> None:
    values = [5.2, 1.0, 9.0, 1.1, 5.0]
    assert cluster_gaps(values, 1.0).tolist() == [1, 0, 2, 0, 1]


def test_cluster_gaps_takes_one_gap_per_value() -> None:
    # The gap below 12 is 2 (allowed: 3), the one below 20 is 8 (allowed: 5).
    assert cluster_gaps([10.0, 12.0, 20.0], np.array([1.0, 3.0, 5.0])).tolist() == [0, 0, 1]


def test_cluster_gaps_of_one_value_is_one_cluster() -> None:
    assert cluster_gaps([3.0], 1.0).tolist() == [0]


# --- marker ----------------------------------------------------------------------------


def test_marker_windows_carry_their_scheduled_labels(signals: Signals) -> None:
    seg = _find(signals, "marker")
    planned = {w.id: w for w in signals.schedule.axes[0].windows}
    assert seg.source == "marker"
    assert seg.labelled_by == "schedule"
    assert sorted(w.window_id for w in seg.windows if w.window_id is not None) == sorted(planned)
    for window in seg.windows:
        assert window.window_id is not None
        assert signals.marker[window.start] == window.window_id
        plan = planned[window.window_id]
        assert (window.step, window.position_index, window.direction) == (
            plan.step,
            plan.position_index,
            plan.direction,
        )
        assert window.velocity_mm_min == plan.velocity_mm_min
    assert seg.warnings == []


def test_flag_marker_is_matched_by_order_to_the_same_windows(signals: Signals) -> None:
    flag = _signals(simulate([SPEC], seed=1, marker_values="flag"))
    assert set(np.unique(flag.marker)) == {0.0, 1.0}
    schedule = flag.schedule.model_copy(update={"marker_values": "flag"})
    seg = find_windows(
        "X",
        flag.time_s,
        flag.velocity,
        position_mm=flag.position,
        marker=flag.marker,
        schedule=schedule,
    )
    by_id = _find(signals, "marker")
    assert [w.window_id for w in seg.windows] == [w.window_id for w in by_id.windows]
    assert [(w.start, w.stop) for w in seg.windows] == [(w.start, w.stop) for w in by_id.windows]


def test_marker_around_whole_runs_is_cut_at_the_scheduled_window() -> None:
    run = _signals(simulate([SPEC], seed=1, marker_scope="run"))
    seg = find_windows(
        "X", run.time_s, run.velocity, position_mm=run.position, marker=run.marker,
        schedule=run.schedule,
    )  # fmt: skip
    planned = {w.id: w for w in run.schedule.axes[0].windows}
    assert seg.source == "schedule"
    assert len(seg.windows) == PLANNED
    for window in seg.windows:
        assert window.window_id is not None
        plan = planned[window.window_id]
        low = min(plan.window_start_mm, plan.window_end_mm)
        high = max(plan.window_start_mm, plan.window_end_mm)
        x = run.position[window.start : window.stop]
        assert x.min() >= low
        assert x.max() <= high
        # The run includes the ramps; the cut window holds only the constant part.
        assert window.samples < np.count_nonzero(run.marker == window.window_id)


def test_marker_never_set_falls_back_to_the_command(signals: Signals) -> None:
    seg = _find(signals, "marker", marker=np.zeros_like(signals.marker))
    assert seg.source == "command"
    assert "marker: recorded but never set" in seg.tried
    assert any("no marker windows" in w for w in seg.warnings)


def test_a_command_the_axis_never_follows_falls_back_to_plateaus(signals: Signals) -> None:
    # A feed override of 150 %: the actual velocity is never near the commanded one.
    seg = _find(signals, "command", schedule=False, command_mm_min=signals.command / 1.5)
    assert seg.source == "plateau"
    assert seg.warnings[0].startswith("neither marker nor commanded velocity gave windows")
    assert any(w.startswith("commanded velocity: ") and "in none does the actual" in w
               for w in seg.warnings)  # fmt: skip
    assert len(seg.windows) == PLANNED


def test_marker_ids_the_schedule_does_not_know_fall_back(signals: Signals) -> None:
    seg = _find(signals, "marker", marker=np.where(signals.marker > 0, signals.marker + 1e4, 0.0))
    assert seg.source == "command"
    assert f"marker: {PLANNED} marker windows, none fits the schedule" in seg.tried
    assert len(seg.windows) == PLANNED


def test_schedule_without_marker_ignores_a_marker_channel(signals: Signals) -> None:
    schedule = signals.schedule.model_copy(update={"marker_scope": "none"})
    seg = find_windows(
        "X", signals.time_s, signals.velocity, position_mm=signals.position,
        command_mm_min=signals.command, marker=signals.marker, schedule=schedule,
    )  # fmt: skip
    assert seg.source == "command"


# --- command and plateaus, labelled by the schedule ------------------------------------


@pytest.mark.parametrize("method", ["marker", "command", "plateau"])
def test_every_planned_window_is_found_inside_its_run(signals: Signals, method: str) -> None:
    seg = _find(signals, method)
    planned = {w.id: w for w in signals.schedule.axes[0].windows}
    settings = SegmentSettings()
    assert seg.source == method
    assert sorted(w.window_id for w in seg.windows if w.window_id is not None) == sorted(planned)
    for window in seg.windows:
        assert window.window_id is not None
        plan = planned[window.window_id]
        x = signals.position[window.start : window.stop]
        assert x.min() >= min(plan.start_mm, plan.stop_mm)
        assert x.max() <= max(plan.start_mm, plan.stop_mm)
        assert abs(window.level_mm_min - plan.velocity_mm_min) <= settings.tolerance_mm_min(
            plan.velocity_mm_min
        )


@pytest.mark.parametrize("method", ["command", "plateau"])
def test_transient_is_cut_and_the_window_is_steady(signals: Signals, method: str) -> None:
    settings = SegmentSettings()
    seg = _find(signals, method, settings=settings)
    dt = float(np.median(np.diff(signals.time_s)))
    settle_n = round(settings.settle_s / dt)
    for window in seg.windows:
        # The (smoothed) velocity entered its band more than settle_s before the start.
        lead = median_filter(
            signals.velocity[window.start - 3 * settle_n : window.stop], size=5, mode="nearest"
        )
        tolerance = settings.tolerance_mm_min(window.level_mm_min)
        outside = np.flatnonzero(np.abs(lead - window.level_mm_min) > tolerance)
        assert len(outside) > 0  # the ramp before the window is out of the band
        last_outside = outside[-1] - 3 * settle_n + window.start
        assert window.start - last_outside > settle_n
        inside = median_filter(signals.velocity[window.start : window.stop], size=5, mode="nearest")
        assert np.all(np.abs(inside - window.level_mm_min) <= tolerance)


def test_command_windows_start_settle_s_after_the_command_is_constant(signals: Signals) -> None:
    settings = SegmentSettings(settle_s=0.2)
    seg = _find(signals, "command", settings=settings)
    dt = float(np.median(np.diff(signals.time_s)))
    for window in seg.windows:
        before = signals.command[window.start - round(0.2 / dt) : window.start]
        assert np.all(before == window.level_mm_min)


def test_rapids_and_warmup_never_become_windows(signals: Signals) -> None:
    for method in ("command", "plateau"):
        seg = _find(signals, method, schedule=False)
        top = max(SPEC.velocities_mm_min)
        assert max(abs(w.level_mm_min) for w in seg.windows) <= 1.03 * top
        dt = float(np.median(np.diff(signals.time_s)))
        # A warm-up stroke at the top velocity lasts about 3 s; windows about 0.5 s.
        assert max(w.samples for w in seg.windows) * dt < 1.0
        assert any("rapid traverse" in w for w in seg.warnings)
        assert any("warm-up" in w for w in seg.warnings)
        assert len(seg.windows) == PLANNED


# --- without a schedule: clusters ------------------------------------------------------


@pytest.mark.parametrize("method", ["marker", "command", "plateau"])
def test_clusters_find_the_steps_and_positions(signals: Signals, method: str) -> None:
    seg = _find(signals, method, schedule=False)
    labelled = _find(signals, method)
    assert seg.labelled_by == "clusters"
    assert [s.centre for s in seg.steps] == pytest.approx(list(SPEC.velocities_mm_min), rel=0.01)
    assert [p.centre for p in seg.positions] == pytest.approx(list(SPEC.positions_mm), abs=2.0)
    assert all(s.windows == 6 for s in seg.steps)
    assert [p.windows for p in seg.positions] == [24, 24, 24]
    # The same windows with the same labels as with the schedule.
    assert [(w.start, w.stop) for w in seg.windows] == [(w.start, w.stop) for w in labelled.windows]
    assert _labels(seg.windows) == _labels(labelled.windows)


def test_positions_in_another_coordinate_system_still_match_by_velocity_and_order(
    signals: Signals,
) -> None:
    shifted = _find(signals, "command", position_mm=signals.position + 1000.0)
    reference = _find(signals, "command")
    assert any("another coordinate system" in w for w in shifted.warnings)
    assert [w.window_id for w in shifted.windows] == [w.window_id for w in reference.windows]


def test_without_position_the_integrated_velocity_separates_positions(signals: Signals) -> None:
    seg = _find(signals, "command", schedule=False, position_mm=None)
    reference = _find(signals, "command", schedule=False)
    assert any("no position channel" in w for w in seg.warnings)
    assert len(seg.positions) == 3
    assert _labels(seg.windows) == _labels(reference.windows)


# --- a foreign program: plateaus only --------------------------------------------------


def _stairs(levels: list[float], hold_s: float, dt: float = 0.002) -> NDArray[np.float64]:
    """Velocity climbing stairs without stopping between them, with short ramps."""
    parts = [np.zeros(round(0.5 / dt))]
    previous = 0.0
    for level in levels:
        parts.append(np.linspace(previous, level, 6)[1:])  # 10 ms ramp
        parts.append(np.full(round(hold_s / dt), level))
        previous = level
    parts.append(np.linspace(previous, 0.0, 6)[1:])
    parts.append(np.zeros(round(0.5 / dt)))
    return np.concatenate(parts)


def test_plateaus_of_a_foreign_program_touching_levels_apart() -> None:
    rng = np.random.default_rng(3)
    levels = [100.0, 200.0, 400.0, -300.0, -150.0]
    dt = 0.002
    true = _stairs(levels, hold_s=0.6, dt=dt)
    velocity = true + rng.normal(0, 0.5, len(true))
    velocity[rng.integers(0, len(velocity), 10)] += 80.0  # spikes of the reading, not motion
    time_s = np.arange(len(velocity), dtype=np.float64) * dt
    seg = find_windows("X", time_s, velocity, position_mm=np.cumsum(true) * dt / 60)
    assert seg.source == "plateau"
    found = [w.level_mm_min for w in seg.windows]
    assert found == pytest.approx(levels, abs=0.5)
    assert [w.direction for w in seg.windows] == [1, 1, 1, -1, -1]
    assert sorted({w.step for w in seg.windows}) == [0, 1, 2, 3, 4]
    settle_n = round(SegmentSettings().settle_s / dt)
    for window in seg.windows:
        assert window.samples > round(0.6 / dt) - settle_n - 20


def test_a_shorter_plateau_than_plateau_min_s_is_not_a_window() -> None:
    dt = 0.002
    velocity = _stairs([100.0, 200.0], hold_s=0.15, dt=dt)
    time_s = np.arange(len(velocity), dtype=np.float64) * dt
    with pytest.raises(RecordingError, match="no window of constant velocity"):
        find_windows("X", time_s, velocity)
    seg = find_windows("X", time_s, velocity, settings=SegmentSettings(plateau_min_s=0.1,
                                                                      settle_s=0.02))  # fmt: skip
    assert [w.level_mm_min for w in seg.windows] == pytest.approx([100.0, 200.0])


# --- nothing to find -------------------------------------------------------------------


def test_standstill_says_what_was_tried() -> None:
    time_s = np.arange(5000, dtype=np.float64) * 0.004
    still = np.random.default_rng(0).normal(0.0, 0.2, len(time_s))
    with pytest.raises(RecordingError) as caught:
        find_windows(
            "X", time_s, still, position_mm=np.zeros_like(still),
            command_mm_min=np.zeros_like(still), marker=np.zeros_like(still),
        )  # fmt: skip
    text = str(caught.value)
    assert "axis X: no window of constant velocity found" in text
    assert "marker: recorded but never set" in text
    assert "commanded velocity: no constant stretch" in text
    assert "plateaus: no stretch of 0.2 s" in text


def test_forcing_a_method_that_has_no_data_fails_clearly(signals: Signals) -> None:
    with pytest.raises(RecordingError, match="marker: not recorded"):
        _find(signals, "command", settings=SegmentSettings(window_method="marker"))
