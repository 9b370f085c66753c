"""An axis' whole-signal statistics read chunk by chunk equal those of the whole arrays (oracle)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ncmeasure.analysis.windows import scan as scan_module
from ncmeasure.analysis.windows.scan import AxisStatistics, Rows, axes_statistics
from ncmeasure.recording import Recording, RecordingWriter, iter_chunks
from ncmeasure.samples import SampleBlock
from ncmeasure.sim.synthetic import SyntheticAxis, synthetic_recording
from ncmeasure.validity import Implausible
from tests.analysis.oracle import bridge, find_windows, noise_sigma, quantum

AXES = [
    SyntheticAxis(name="X", velocities_mm_min=(10.0, 100.0, 1000.0), positions_mm=(50.0, 600.0)),
    SyntheticAxis(
        name="Y",
        velocities_mm_min=(20.0, 400.0),
        velocity_quantum_mm_min=8.5,
        current_quantum=0.01,
    ),
]
LIMITS = {"X_current_a": 40.0, "Y_velocity_mm_min": 30_000.0}


def statistics(recording: Recording, axes: tuple[str, ...], rows: int) -> dict[str, AxisStatistics]:
    """The statistics of ``axes`` from the recording's file read ``rows`` rows at a time."""
    names = recording.channel_names
    limits = {name: LIMITS.get(name) for name in names}
    column = {name: k for k, name in enumerate(names)}
    source = Rows(
        lambda: iter_chunks(recording.directory, rows, names), column, rows, limits=limits
    )
    return axes_statistics(source, axes)


def _damaged(source: Recording, directory: Path) -> Recording:
    """The recording with gaps of NaN (some across chunk edges) and no-value codes."""
    values = source.values.copy()
    names = list(source.channel_names)
    rng = np.random.default_rng(4)
    for name in ("X_velocity_mm_min", "X_position_mm", "Y_velocity_mm_min", "X_current_a"):
        column = names.index(name)
        for start in rng.integers(0, len(values) - 50, size=40).tolist():
            values[start : start + int(rng.integers(1, 40)), column] = np.nan
        values[rng.integers(0, len(values), size=5), column] = -999_999.0
    values[:7, names.index("X_velocity_mm_min")] = np.nan  # NaN at both ends
    values[-12:, names.index("X_velocity_mm_min")] = np.nan
    values[rng.integers(0, len(values), size=3), names.index("X_current_a")] = 55.0
    channels = [c.to_channel() for c in source.meta.channels]
    with RecordingWriter.create(directory, channels, nominal_period_s=0.004) as writer:
        writer.append(SampleBlock(source.time_s, values))
    return Recording.open(directory)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> list[Recording]:
    base = tmp_path_factory.mktemp("scan")
    clean, _ = synthetic_recording(base / "clean", AXES)
    return [clean, _damaged(clean, base / "damaged")]


@pytest.mark.parametrize(
    ("axis", "kind", "rows"),
    [("X", 1, 37), ("Y", 1, 1000), ("Y", 0, 1000), ("X", 0, 1 << 16)],
    ids=["X-damaged-37", "Y-damaged-1000", "Y-clean-1000", "X-clean-65536"],
)
def test_statistics_equal_those_of_the_whole_arrays(
    recordings: list[Recording], kind: int, axis: str, rows: int
) -> None:
    recording = recordings[kind]
    found = statistics(recording, (axis,), rows)[axis]
    checker = Implausible({n: LIMITS.get(n) for n in recording.channel_names})
    t = recording.time_s

    def signal(name: str) -> np.ndarray:
        return checker.clean(f"{axis}_{name}", t, recording.column(f"{axis}_{name}"))

    velocity, bridged = bridge(signal("velocity_mm_min"), t)
    position, _ = bridge(signal("position_mm"), t)
    current = signal("current_a")
    assert found.rows == len(t)
    assert found.sample_period_s == float(np.median(np.diff(t)))
    assert found.velocity_bridged == bridged
    assert found.velocity_quantum_mm_min == quantum(velocity)
    assert found.velocity_sigma_mm_min == noise_sigma(velocity)
    assert found.position_usable
    assert found.position_quantum_mm == quantum(position)
    assert found.position_sigma_mm == noise_sigma(position)
    assert found.current_quantum_a == quantum(current)
    assert found.implausible is not None
    assert found.implausible.counts == checker.counts
    assert found.implausible.first == checker.first
    if axis == "Y" and kind == 0:  # bridged gaps take a quantised signal off its lattice
        assert found.velocity_quantum_mm_min > 0
        assert found.current_quantum_a > 0
    # The windows of the whole arrays are found with the same period and counts.
    segmentation = find_windows(
        axis, t, signal("velocity_mm_min"), position_mm=signal("position_mm")
    )
    assert segmentation.sample_period_s == found.sample_period_s
    assert segmentation.velocity_quantum_mm_min == found.velocity_quantum_mm_min
    assert segmentation.position_quantum_mm == found.position_quantum_mm


def test_axes_read_together_equal_each_read_alone(recordings: list[Recording]) -> None:
    recording = recordings[1]
    together = statistics(recording, ("X", "Y"), 500)
    for axis in ("X", "Y"):
        alone = statistics(recording, (axis,), 500)[axis]
        assert together[axis].implausible is not None and alone.implausible is not None
        assert together[axis].implausible.counts == alone.implausible.counts
        together[axis].implausible = alone.implausible = None
        assert together[axis] == alone


def test_later_readings_check_only_the_chunks_holding_implausible_values(
    recordings: list[Recording], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The first pass notes the chunks of a channel without an implausible value; the
    later readings take those as they are (statistics the same: the test above)."""
    checked: list[bool] = []
    original = scan_module.implausible

    def counted(values: np.ndarray, limit: float | None = None) -> np.ndarray:
        bad = original(values, limit)
        checked.append(bool(bad.any()))
        return bad

    monkeypatch.setattr(scan_module, "implausible", counted)
    statistics(recordings[1], ("X", "Y"), 1000)
    assert checked and all(checked)
