"""Exact streaming statistics against numpy on the whole array (the oracle's), bit for bit."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest
from numpy.typing import NDArray

from ncmeasure.analysis.windows.streaming import (
    ExactSum,
    chunks_of,
    differences,
    median_task,
    noise_sigma_task,
    quantum_task,
    run_task,
    run_tasks,
    select_task,
    whole,
)
from tests.analysis.oracle import noise_sigma, quantum

FloatArray = NDArray[np.float64]


def _datasets() -> list[tuple[str, FloatArray]]:
    rng = np.random.default_rng(7)
    return [
        ("normal odd", rng.normal(size=10_001)),
        ("normal even", rng.normal(size=10_000)),
        ("one value", np.array([3.5])),
        ("two values", np.array([1.0, -2.0])),
        ("ties", rng.integers(0, 3, size=5_000).astype(np.float64)),
        ("all equal", np.full(4_000, 0.25)),
        ("quantised", np.round(rng.normal(scale=40.0, size=20_000) / 8.5) * 8.5),
        ("sorted", np.arange(9_999, dtype=np.float64)),
        ("reversed", np.arange(8_000, dtype=np.float64)[::-1].copy()),
        ("spread", rng.standard_cauchy(size=7_777) * 1e6),
        ("periodic", np.tile(np.array([5.0, -1.0, 2.0, 2.0, 9.0]), 3_001)),
    ]


DATA = _datasets()


@pytest.mark.parametrize("rows", [1, 7, 1000, 1 << 16])
@pytest.mark.parametrize(("name", "values"), DATA, ids=[n for n, _ in DATA])
def test_median_equals_numpy(name: str, values: FloatArray, rows: int) -> None:
    if rows == 1 and len(values) > 3000:
        values = values[:2999]
    found = run_task(chunks_of(values, rows), median_task(whole))
    assert found == float(np.median(values)), name


@pytest.mark.parametrize(("name", "values"), DATA, ids=[n for n, _ in DATA])
def test_tiny_budgets_narrow_the_bracket_by_histogram(name: str, values: FloatArray) -> None:
    # A subsample of 16 and at most 10 values kept per pass: the histogram narrows.
    task = median_task(whole, sample_budget=16, collect_budget=10)
    assert run_task(chunks_of(values, 333), task) == float(np.median(values)), name


def test_selection_gives_every_rank() -> None:
    values = np.random.default_rng(3).normal(size=2_001)
    ordered = np.sort(values)
    ranks = (0, 17, 1000, 2000)
    count, picked = run_task(
        chunks_of(values, 100), select_task(whole, lambda n: ranks, collect_budget=50)
    )
    assert count == len(values)
    assert picked == [float(ordered[r]) for r in ranks]


def test_median_of_nothing_is_nan() -> None:
    assert math.isnan(run_task(chunks_of(np.empty(0), 10), median_task(whole)))


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("rows", [1, 2, 3, 50])
def test_differences_cross_chunk_boundaries(order: int, rows: int) -> None:
    values = np.random.default_rng(1).normal(size=203)
    parts: list[FloatArray] = []
    apply = differences(whole, order)()
    for chunk in chunks_of(values, rows)():
        parts.append(apply(chunk))
    np.testing.assert_array_equal(np.concatenate(parts), np.diff(values, n=order))


def _signals() -> list[tuple[str, FloatArray]]:
    rng = np.random.default_rng(11)
    ramp = np.cumsum(rng.integers(-3, 4, size=30_000)) * 8.5
    return [
        ("counts of 8.5", ramp),
        ("counts with rounding noise", ramp * (1 + 1e-13 * rng.normal(size=len(ramp)))),
        ("per mille current", np.round(rng.normal(2.0, 0.3, size=20_001) * 1000) / 1000),
        ("continuous", rng.normal(size=10_000)),
        ("constant", np.full(100, 4.0)),
        ("short", np.array([1.0, 2.0, 4.0])),
        ("noisy ramp", np.linspace(0, 500, 12_345) + rng.normal(scale=0.01, size=12_345)),
    ]


SIGNALS = _signals()


@pytest.mark.parametrize("rows", [5, 4096, 1 << 16])
@pytest.mark.parametrize(("name", "values"), SIGNALS, ids=[n for n, _ in SIGNALS])
def test_quantum_and_noise_equal_the_whole_array(name: str, values: FloatArray, rows: int) -> None:
    found = run_tasks(
        chunks_of(values, rows), {"q": quantum_task(whole), "sigma": noise_sigma_task(whole)}
    )
    assert found["q"] == quantum(values), name
    assert found["sigma"] == noise_sigma(values), name


def test_quantum_finds_the_count() -> None:
    def count(values: FloatArray) -> float:
        found: float = run_task(chunks_of(values, 1000), quantum_task(whole))
        return found

    assert count(SIGNALS[0][1]) == pytest.approx(8.5, rel=1e-12)
    assert count(SIGNALS[3][1]) == 0.0


def test_exact_sum_does_not_depend_on_order_or_chunks() -> None:
    rng = np.random.default_rng(5)
    values = rng.normal(size=10_000) * 10.0 ** rng.integers(-8, 8, size=10_000)
    forward, backward = ExactSum(), ExactSum()
    for part in np.array_split(values, 37):
        forward.add(part)
    backward.add(values[::-1].copy())
    assert forward.value() == backward.value() == math.fsum(values.tolist())


def _passes(values: FloatArray, rows: int, task: object) -> tuple[object, int]:
    """A task's value and the readings of the data it took."""
    readings = [0]
    read = chunks_of(values, rows)

    def counted() -> Iterator[FloatArray]:
        readings[0] += 1
        return read()

    return run_task(counted, task), readings[0]  # type: ignore[arg-type]


def test_noise_takes_its_deviations_subsample_from_the_first_pass() -> None:
    # Median of the second differences (a subsample, a bracket), then of the deviations
    # from it: their subsample is the first one's, shifted; no pass of its own.
    values = np.random.default_rng(2).normal(size=50_000)
    found, readings = _passes(values, 4096, noise_sigma_task(whole))
    assert found == noise_sigma(values)
    assert readings == 3


def test_a_bracket_that_misses_moves_to_the_next_stretch_of_the_subsample() -> None:
    # A position standing still most of the time: its second differences are a few tied
    # values about zero, the rest spread. The subsample's bracket is the heaviest tie and
    # the median lies just above it: the next bracket is the subsample's next stretch,
    # not the whole range above (more values than a pass keeps, then histograms).
    rng = np.random.default_rng(4)
    n = 40_000
    ties = np.full(n * 3 // 10, -5.7e-14)
    near = rng.choice(np.array([-2.8e-14, 0.0, 2.8e-14]), size=n // 4)
    spread = rng.normal(scale=1e-3, size=n - len(ties) - len(near))
    values = rng.permutation(np.concatenate((ties, near, spread)))
    task = median_task(whole, sample_budget=512, collect_budget=2_000)
    found, readings = _passes(values, 1000, task)
    assert found == float(np.median(values))
    assert readings == 2


def test_ties_about_the_median_are_counted_in_one_pass() -> None:
    # More values in the bracket than a pass keeps, but few distinct ones: counted.
    values = np.random.default_rng(5).choice(np.array([-1.0, 0.0, 1.0, 2.0]), size=20_000)
    values[::7] = np.random.default_rng(6).normal(size=len(values[::7]))
    task = median_task(whole, sample_budget=256, collect_budget=1_000)
    found, readings = _passes(values, 1000, task)
    assert found == float(np.median(values))
    assert readings == 2


def _bounded_passes(values: FloatArray, rows: int, task: object, most: int) -> tuple[object, int]:
    """:func:`_passes`, failing after ``most`` readings (a task that never ends)."""
    readings = [0]
    read = chunks_of(values, rows)

    def counted() -> Iterator[FloatArray]:
        readings[0] += 1
        if readings[0] > most:
            raise AssertionError(f"still reading after {most} passes")
        return read()

    return run_task(counted, task), readings[0]  # type: ignore[arg-type]


@pytest.mark.parametrize("mirror", [False, True])
def test_a_bracket_with_one_middle_value_inside_widens_towards_the_other(mirror: bool) -> None:
    # An even count: the two middle values, one inside the subsample's bracket at its edge
    # and the other just outside. Moving the bracket to the other one's side loses the
    # first; the bracket must grow to hold both, not swing between the two sides.
    n, stride = 2000, 32
    picks = np.arange(0, n, stride)
    sampled = np.r_[np.arange(23.0), 1000.0 + np.arange(len(picks) - 23)]
    rest = np.setdiff1d(np.arange(float(n)), sampled)
    rng = np.random.default_rng(0)
    values = np.empty(n)
    chosen = np.zeros(n, dtype=bool)
    chosen[picks] = True
    values[picks] = rng.permutation(sampled)
    values[~chosen] = rng.permutation(rest)
    if mirror:
        values = -values
    found, readings = _bounded_passes(values, 1000, median_task(whole, sample_budget=100), 10)
    assert found == float(np.median(values))
    assert readings <= 4
