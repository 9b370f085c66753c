"""The friction table against a plain per-group computation; quantised and correlated samples."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import pytest
from numpy.typing import NDArray

from ncmeasure.analysis.friction import table as friction
from ncmeasure.analysis.friction.medians import sample_index
from ncmeasure.analysis.friction.table import (
    friction_table,
    grouped_median,
    window_samples,
    window_table,
)
from ncmeasure.analysis.windows.model import VelocityWindow


def _window(
    start: int, stop: int, *, step: int, position: int, direction: Literal[1, -1], v: float
) -> VelocityWindow:
    return VelocityWindow(
        axis="X",
        start=start,
        stop=stop,
        velocity_mm_min=direction * v,
        level_mm_min=direction * v,
        direction=direction,
        position_mm=100.0 * position,
        position_index=position,
        step=step,
        source="command",
    )


def _random_case(seed: int) -> tuple[NDArray[np.float64], list[VelocityWindow]]:
    """Windows of 3 steps × 2 positions × 2 directions, two repetitions each, shuffled."""
    rng = np.random.default_rng(seed)
    n = 20_000
    current = rng.normal(1.0, 0.3, n)
    windows = []
    start = 10
    for _ in range(2):
        for step, v in enumerate((10.0, 100.0, 1000.0)):
            for position in (0, 1):
                for direction in (1, -1):
                    length = int(rng.integers(20, 400))
                    sign: Literal[1, -1] = 1 if direction > 0 else -1
                    windows.append(
                        _window(
                            start, start + length, step=step, position=position,
                            direction=sign, v=v,
                        )
                    )  # fmt: skip
                    start += length + int(rng.integers(1, 50))
    current[windows[3].start + 2] = np.nan  # one current is missing
    order = rng.permutation(len(windows))
    return current, [windows[i] for i in order]


def _plain(
    current: NDArray[np.float64], windows: list[VelocityWindow]
) -> dict[tuple[int, int, int], tuple[float, float, float, int, int]]:
    """The same statistics, one group at a time, the obvious way."""
    groups: dict[tuple[int, int, int], list[NDArray[np.float64]]] = {}
    for w in windows:
        samples = current[w.start : w.stop]
        groups.setdefault((w.position_index, w.direction, w.step), []).append(
            samples[np.isfinite(samples)]
        )
    result = {}
    for key, parts in groups.items():
        values = np.concatenate(parts)
        result[key] = (
            float(np.median(values)),
            float(np.mean(values)),
            float(np.std(values, ddof=1)),
            len(values),
            len(parts),
        )
    return result


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_table_equals_the_plain_per_group_statistics(seed: int) -> None:
    current, windows = _random_case(seed)
    table = friction_table("X", current, windows)
    expected = _plain(current, windows)
    assert len(table) == len(expected) == 12
    for i in range(len(table)):
        key = (int(table.position_index[i]), int(table.direction[i]), int(table.step[i]))
        median, mean, std, n, count = expected[key]
        assert table.median[i] == pytest.approx(median, rel=1e-12)
        assert table.mean[i] == pytest.approx(mean, rel=1e-12)
        assert table.std[i] == pytest.approx(std, rel=1e-9)
        assert table.n[i] == n
        assert table.windows[i] == count == 2
        # Independent samples: the batches agree with √(π/2)·std/√n, never below it.
        independent = math.sqrt(math.pi / 2) * std / math.sqrt(n)
        assert independent * (1 - 1e-12) <= table.stderr[i] < 3 * independent
    assert table.samples == sum(e[3] for e in expected.values())
    assert table.quantity == "current_a"
    assert table.unit == "A"


def test_rows_are_sorted_by_position_direction_step() -> None:
    current, windows = _random_case(0)
    table = friction_table("X", current, windows)
    keys = list(
        zip(table.position_index.tolist(), table.direction.tolist(), table.step.tolist(),
            strict=True)
    )  # fmt: skip
    assert keys == sorted(keys)


def test_torque_constant_turns_the_table_into_torque() -> None:
    current, windows = _random_case(1)
    amps = friction_table("X", current, windows)
    torque = friction_table("X", current, windows, torque_constant_nm_per_a=2.1)
    assert torque.quantity == "torque_nm"
    assert torque.unit == "Nm"
    assert torque.torque_constant_nm_per_a == 2.1
    np.testing.assert_allclose(torque.median, 2.1 * amps.median)
    np.testing.assert_allclose(torque.mean, 2.1 * amps.mean)
    np.testing.assert_allclose(torque.std, 2.1 * amps.std)
    np.testing.assert_allclose(torque.stderr, 2.1 * amps.stderr)
    np.testing.assert_array_equal(torque.n, amps.n)


def test_every_sample_of_a_window_counts() -> None:
    """The window was checked as a whole; samples are never picked by their velocity."""
    current = np.concatenate([np.full(50, 1.0), np.full(51, 9.0)])
    windows = [_window(0, 101, step=0, position=0, direction=1, v=1000.0)]
    table = friction_table("X", current, windows)
    assert table.n.tolist() == [101]
    assert table.median.tolist() == [9.0]


def test_grouped_median_resolves_a_level_between_the_counts_of_a_quantised_current() -> None:
    """A drive reports its current in counts; noise dithers the reading between two."""
    rng = np.random.default_rng(7)
    count = 0.0177  # A: one per mille of a 17.7 A rated current (CiA 402 0x6078)
    true = 0.8 + 0.3 * count  # between two counts
    readings = np.round((true + rng.normal(0, 0.4 * count, 4000)) / count) * count
    assert len(np.unique(readings)) <= 4
    assert abs(float(np.median(readings)) - true) > 0.25 * count  # the plain median snaps
    assert grouped_median(readings, count) == pytest.approx(true, abs=0.05 * count)
    assert grouped_median(readings, 0.0) == float(np.median(readings))
    windows = [_window(0, 4000, step=0, position=0, direction=1, v=100.0)]
    table = friction_table("X", readings, windows, current_quantum_a=count)
    assert table.median[0] == pytest.approx(true, abs=0.05 * count)


def test_correlated_samples_widen_the_standard_error() -> None:
    """Cogging and the servo loop make neighbouring samples alike: √n would overstate
    the precision. Batches of a window carry the slow part of the ripple."""
    rng = np.random.default_rng(1)
    n = 500
    slow = 0.05 * np.sin(np.linspace(0, 3 * np.pi, n))  # a ripple slower than a batch
    current = 2.0 + slow + rng.normal(0, 0.01, n)
    windows = [_window(0, n, step=0, position=0, direction=1, v=10.0)]
    table = friction_table("X", current, windows)
    independent = math.sqrt(math.pi / 2) * float(table.std[0]) / math.sqrt(n)
    assert table.batches.tolist() == [5]
    assert table.stderr[0] > 3 * independent


def test_points_of_a_position_and_direction_slowest_first() -> None:
    current, windows = _random_case(2)
    table = friction_table("X", current, windows)
    points = table.points(1, -1)
    assert [p.velocity_mm_min for p in points] == [-10.0, -100.0, -1000.0]
    assert [p.step for p in points] == [0, 1, 2]
    assert all(p.windows == 2 for p in points)
    assert all(p.stderr is not None and p.stderr > 0 for p in points)
    assert table.points(5, 1) == []


def test_a_single_sample_has_nan_std_in_the_table_and_zero_in_its_point() -> None:
    windows = [_window(3, 4, step=0, position=0, direction=1, v=100.0)]
    table = friction_table("X", np.arange(10.0), windows)
    assert table.n.tolist() == [1]
    assert math.isnan(table.std[0])
    (point,) = table.points(0, 1)
    assert point.std == 0.0
    assert point.median == point.mean == 3.0


def test_a_group_without_usable_samples_is_left_out() -> None:
    current = np.array([np.nan] * 10 + [2.0] * 10)
    windows = [
        _window(0, 10, step=0, position=0, direction=1, v=100.0),
        _window(10, 20, step=1, position=0, direction=1, v=200.0),
    ]
    table = friction_table("X", current, windows)
    assert table.step.tolist() == [1]


def test_no_windows_make_an_empty_table() -> None:
    table = friction_table("X", np.ones(10), [])
    assert len(table) == 0
    assert table.samples == 0


def test_window_samples_are_the_concatenated_ranges() -> None:
    windows = [
        _window(5, 8, step=0, position=0, direction=1, v=1.0),
        _window(20, 22, step=0, position=0, direction=1, v=1.0),
        _window(0, 2, step=0, position=0, direction=1, v=1.0),
    ]
    index, owner = window_samples(windows)
    assert index.tolist() == [5, 6, 7, 20, 21, 0, 1]
    assert owner.tolist() == [0, 0, 0, 1, 1, 2, 2]


@pytest.mark.parametrize("seed", range(5))
def test_sample_index_is_the_concatenated_ranges_whatever_their_lengths(seed: int) -> None:
    """Runs in any order, overlapping, empty ones first, between and last."""
    rng = np.random.default_rng(seed)
    for _ in range(400):
        count = int(rng.integers(0, 7))
        starts = rng.integers(0, 40, count).astype(np.intp)
        lengths = (rng.integers(0, 5, count) * rng.integers(0, 2, count)).astype(np.intp)
        expected = [i for s, n in zip(starts, lengths, strict=True) for i in range(s, s + n)]
        index = sample_index(starts, lengths)
        assert index.dtype == np.intp
        assert index.tolist() == expected


def test_repeated_windows_that_disagree_widen_the_standard_error() -> None:
    """Two repetitions of a step whose levels differ (drift, the cogging phase at the
    window's place): each window is one draw of that difference, whatever its samples."""
    rng = np.random.default_rng(3)
    first = 2.00 + rng.normal(0, 0.005, 300)
    second = 2.10 + rng.normal(0, 0.005, 300)
    current = np.concatenate([first, second])
    windows = [
        _window(0, 300, step=0, position=0, direction=1, v=100.0),
        _window(300, 600, step=0, position=0, direction=1, v=100.0),
    ]
    table = friction_table("X", current, windows)
    assert table.windows.tolist() == [2]
    # The scatter of the two window medians over √2: about 0.05, not the 0.0003 the
    # samples would claim, nor the 0.017 of ten batches, five on each level.
    assert table.stderr[0] == pytest.approx(0.05, rel=0.1)


def _reference(
    current: NDArray[np.float64], windows: list[VelocityWindow], quantum: float
) -> dict[tuple[int, int, int], tuple[float, float, int, int]]:
    """Median, batch-scatter input and counts, one window and one batch at a time."""
    groups: dict[tuple[int, int, int], list[NDArray[np.float64]]] = {}
    batches: dict[tuple[int, int, int], int] = {}
    for w in sorted(windows, key=lambda w: w.start):
        samples = current[w.start : w.stop]
        samples = samples[np.isfinite(samples)]
        key = (w.position_index, w.direction, w.step)
        groups.setdefault(key, []).append(samples)
        count = max(1, min(5, len(samples) // 5))
        edges = np.linspace(0, len(samples), count + 1).round().astype(int)
        batches[key] = batches.get(key, 0) + int(np.count_nonzero(np.diff(edges) > 0))
    return {
        key: (
            grouped_median(np.concatenate(parts), quantum),
            float(np.mean(np.concatenate(parts))),
            sum(len(p) for p in parts),
            batches[key],
        )
        for key, parts in groups.items()
        if sum(len(p) for p in parts)
    }


@pytest.mark.parametrize(
    ("quantum", "values"),
    [(0.0, "normal"), (0.05, "normal"), (0.0, "float32 ties"), (0.0, "beyond float32"),
     (1e-12, "float32 ties")],
)  # fmt: skip
@pytest.mark.parametrize("seed", [3, 4, 5])
def test_medians_equal_a_straightforward_reference_for_odd_and_even_counts(
    seed: int, quantum: float, values: str
) -> None:
    """Windows of 1 to 5000 samples (one by one and padded blocks), odd and even counts,
    missing currents, a quantised current: the same medians, bit for bit. The medians are
    selected among float32 keys and read back exactly: values closer than a float32 step
    (many distinct values on one key) and beyond the float32 range must not fool them."""
    rng = np.random.default_rng(seed)
    current = rng.normal(1.0, 0.3, 60_000)
    if values == "float32 ties":  # a few float32 keys, each for many float64 values
        current = 1.0 + 1e-7 * rng.integers(-3, 4, len(current)) + 1e-13 * current
    elif values == "beyond float32":
        current *= np.where(rng.random(len(current)) < 0.3, 1e39, 1.0)
        current[rng.random(len(current)) < 0.1] *= -1
    if quantum:
        current = np.round(current / quantum) * quantum
    current[rng.random(len(current)) < 0.01] = np.nan
    windows = []
    start = 0
    for number in range(120):
        length = int(rng.choice([1, 2, 3, 4, 9, 10, 64, 65, 333, 5000]))
        step, position = number % 4, (number // 4) % 3
        sign: Literal[1, -1] = 1 if number % 2 else -1
        windows.append(_window(start, start + length, step=step, position=position,
                               direction=sign, v=10.0 * (step + 1)))  # fmt: skip
        start += length + int(rng.integers(0, 20))
    table = friction_table("X", current, windows, current_quantum_a=quantum)
    expected = _reference(current, windows, quantum)
    assert len(table) == len(expected)
    assert {int(n) % 2 for n in table.n} == {0, 1}
    for i in range(len(table)):
        key = (int(table.position_index[i]), int(table.direction[i]), int(table.step[i]))
        median, mean, n, batches = expected[key]
        assert table.median[i] == median
        assert table.mean[i] == pytest.approx(mean, rel=1e-12)
        assert (int(table.n[i]), int(table.batches[i])) == (n, batches)


def test_window_table_from_the_window_samples_alone_equals_the_table_from_all_samples() -> None:
    current, windows = _random_case(6)
    whole = friction_table("X", current, windows, current_quantum_a=0.01)
    alone = window_table(
        "X", [current[w.start : w.stop].copy() for w in windows], windows, current_quantum_a=0.01
    )
    for name in ("median", "mean", "std", "stderr", "n", "windows", "batches", "step"):
        assert np.array_equal(getattr(whole, name), getattr(alone, name), equal_nan=True)


def _same_tables(first: object, second: object) -> None:
    for name in ("position_index", "direction", "step", "velocity_mm_min", "median", "mean",
                 "std", "stderr", "n", "windows", "batches"):  # fmt: skip
        a, b = getattr(first, name), getattr(second, name)
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), name


@pytest.mark.parametrize("quantum", [0.0, 0.02])
@pytest.mark.parametrize("chunk", [1, 700, 5000])
def test_chunks_of_groups_give_the_same_table_bit_for_bit(
    monkeypatch: pytest.MonkeyPatch, chunk: int, quantum: float
) -> None:
    """The table is built a chunk of groups at a time; missing currents in an early chunk
    shift the batch edges of later ones (they are rounded from offsets among all finite
    samples), so every chunk size must give the same numbers, from a contiguous current,
    a recording's column (gathered by index) and the windows' own currents."""
    rng = np.random.default_rng(11)
    current = rng.normal(1.0, 0.3, 40_000)
    if quantum:
        current = np.round(current / quantum) * quantum
    current[rng.random(len(current)) < 0.02] = np.nan
    current[100:140] = np.inf
    windows = []
    start = 0
    for number in range(160):
        length = int(rng.choice([0, 1, 2, 3, 7, 24, 25, 26, 71, 350, 357, 2000]))
        step, position = number % 8, (number // 8) % 2
        sign: Literal[1, -1] = 1 if (number // 16) % 2 else -1
        windows.append(_window(start, start + length, step=step, position=position,
                               direction=sign, v=10.0 * (step + 1)))  # fmt: skip
        start += length + int(rng.integers(0, 5))
    whole = friction_table("X", current, windows, current_quantum_a=quantum)
    parts = [current[w.start : w.stop].copy() for w in windows]
    column = np.stack([np.zeros_like(current), current], axis=1)[:, 1]  # gathered by index
    monkeypatch.setattr(friction, "_CHUNK_SAMPLES", chunk)
    _same_tables(friction_table("X", current, windows, current_quantum_a=quantum), whole)
    _same_tables(friction_table("X", column, windows, current_quantum_a=quantum), whole)
    _same_tables(window_table("X", parts, windows, current_quantum_a=quantum), whole)


def test_window_medians_where_every_batch_has_the_same_median() -> None:
    """Batches that agree on their median, with different values around it: the window's
    median is that value without a look at the values, and equals the plain median."""
    batch = np.array([0.0, 5.0, 2.0, 9.0, -4.0, 2.0, 3.0, 1.0, 2.0])  # median 2.0
    current = np.concatenate([batch, batch[::-1] + 0.0, np.roll(batch, 3), batch * 1.0, batch])
    windows = [_window(0, len(current), step=0, position=0, direction=1, v=100.0)]
    table = friction_table("X", current, windows)
    assert table.batches.tolist() == [5]
    assert table.median.tolist() == [float(np.median(current))] == [2.0]


@pytest.mark.parametrize("lengths", [(1,), (2,), (1, 1), (1, 2), (2, 2, 1), (4,), (9, 1)])
def test_windows_of_one_or_two_samples(lengths: tuple[int, ...]) -> None:
    """Windows of a sample or two (one batch each) in one group, quantised with ties."""
    current = np.array([1.0, 1.0, 2.0, 1.0, 3.0, 2.0, 2.0, 1.0, 1.0, 2.0, 2.0, 3.0, 1.0])
    windows, start = [], 0
    for length in lengths:
        windows.append(_window(start, start + length, step=0, position=0, direction=1, v=1.0))
        start += length
    values = current[:start]
    for quantum in (0.0, 1.0):
        table = friction_table("X", current, windows, current_quantum_a=quantum)
        assert table.median.tolist() == [grouped_median(values, quantum)]
        assert table.n.tolist() == [start]
        assert table.windows.tolist() == [len(lengths)]
        assert table.batches.tolist() == [len(lengths)]
