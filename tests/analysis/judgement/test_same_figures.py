"""The quick paths of the change's diagnosis give the figures of the plain ones, bit for bit.

The store computes the change since the baseline for every machine it adds, so its inner
loops are written for speed (plain floats where numpy's per-call cost dominated, the
permutations filled in place); these tests hold them to the straightforward versions
written here, on layouts that provoke every branch: equal and duplicate velocities, a
zero, velocities of one run only, NaN, ragged groups.
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from ncmeasure.analysis.judgement import compare, diagnosis
from ncmeasure.analysis.judgement.diagnosis import position_dependency


def _matched_with_arrays(b: Any, o: Any) -> list[tuple[int, float, float, float]]:
    """The matching as numpy writes it: the nearest unused relative gap, argmin's first."""
    speeds = np.array([abs(p.velocity_mm_min) for p in o.points], dtype=np.float64)
    used = np.zeros(speeds.size, dtype=bool)
    out = []
    for i, p in enumerate(b.points):
        speed = abs(p.velocity_mm_min)
        if speed == 0 or speeds.size == 0:
            continue
        with np.errstate(invalid="ignore"):
            gap = np.where(used, np.inf, np.abs(speeds - speed) / np.maximum(speeds, speed))
        j = int(np.argmin(gap))
        if gap[j] > compare.VELOCITY_MATCH_TOLERANCE:
            continue
        used[j] = True
        out.append((i, p.velocity_mm_min, p.median, o.points[j].median))
    return out


def _run(velocities: list[float]) -> SimpleNamespace:
    return SimpleNamespace(
        points=[
            SimpleNamespace(velocity_mm_min=v, median=100.0 + k) for k, v in enumerate(velocities)
        ]
    )


LAYOUTS = {
    "equal": ([10.0, 20.0, 40.0], [10.0, 20.0, 40.0]),
    "signed and within tolerance": ([-10.0, 20.0, 40.0], [10.02, 19.95, 40.1]),
    "duplicate velocities": ([10.0, 10.0, 20.0], [10.0, 10.0, 10.0, 20.0]),
    "a zero and a miss": ([0.0, 10.0, 33.0], [10.0, 30.0]),
    "the other run has more": ([10.0], [9.99, 10.0, 10.01, 50.0]),
    "equal gaps": ([10.0], [9.99, 10.01]),
    "NaN in the other run": ([10.0, 20.0], [math.nan, 20.0, 10.0]),
    "NaN in the base": ([math.nan, 20.0], [20.0, 10.0]),
    "nothing to match": ([10.0, 20.0], []),
}


@pytest.mark.parametrize("layout", LAYOUTS)
def test_velocities_match_as_with_arrays(layout: str) -> None:
    base, other = (_run(v) for v in LAYOUTS[layout])
    problems: list[str] = []
    found = compare._match_points("here", base, other, problems)  # type: ignore[arg-type]
    assert found == _matched_with_arrays(base, other)


def test_velocities_match_as_with_arrays_at_random() -> None:
    rng = np.random.default_rng(5)
    steps = [10.0, 10.04, 20.0, 40.0, 80.0, 0.0, 160.0]
    for _ in range(300):
        base = _run([float(v) for v in rng.choice(steps, size=rng.integers(0, 8))])
        other = _run([float(v) for v in rng.choice(steps, size=rng.integers(0, 8))])
        found = compare._match_points("here", base, other, [])  # type: ignore[arg-type]
        assert found == _matched_with_arrays(base, other)


def _permuted_with_masks(
    y: np.ndarray, jj: np.ndarray, projector: np.ndarray, n_v: int, n_p: int
) -> np.ndarray:
    """The null's spreads as first written: each group's cells found by a mask, permuted
    from a broadcast copy."""
    rng = np.random.default_rng(diagnosis._PERMUTATION_SEED)
    count = diagnosis.PERMUTATIONS
    permuted = np.empty((y.size, count))
    for j in range(n_v):
        cells = np.flatnonzero(jj == j)
        block = np.broadcast_to(y[cells][:, None], (cells.size, count))
        permuted[cells] = rng.permuted(block, axis=0)
    beta = np.zeros((n_p, count))
    beta[1:] = (projector @ permuted)[n_v:]
    shape = np.exp(beta - beta.mean(axis=0))
    return np.asarray((shape.max(axis=0) - shape.min(axis=0)) / shape.mean(axis=0))


def test_the_permutations_of_the_null_are_those_of_masks() -> None:
    """The same random stream group by group: the same null, bit for bit."""
    rng = np.random.default_rng(11)
    for _ in range(100):
        n_v, n_p = int(rng.integers(2, 30)), int(rng.integers(2, 8))
        usable = rng.random((n_v, n_p)) < 0.7
        usable[:, :2] = True  # at least two positions per group
        jj, _ = np.nonzero(usable)
        y = rng.normal(size=jj.size)
        projector = rng.normal(size=(n_v + n_p - 1, jj.size))
        found = diagnosis._permuted_spreads(y, jj, projector, n_v, n_p)
        assert found is not None
        assert np.array_equal(found, _permuted_with_masks(y, jj, projector, n_v, n_p))


def test_without_the_velocity_profiles_the_rest_is_the_same() -> None:
    rng = np.random.default_rng(2)
    positions = [50.0, 150.0, 250.0, 350.0, 450.0]
    velocities = [10.0, 100.0, 1000.0, -10.0, -100.0, -1000.0]
    table = 1.0 + 0.01 * rng.normal(size=(len(velocities), len(positions)))
    table[:, -1] *= 1.3  # rising at the max end
    table[2, 1] = np.nan
    common: dict[str, Any] = {"travel_mm": (0.0, 500.0), "fixed_bearing_end": "min"}
    full = position_dependency(positions, velocities, table, **common)
    lean = position_dependency(positions, velocities, table, velocity_profiles=False, **common)
    assert len(full.profiles) == 1 + len(velocities)
    assert lean.profiles == full.profiles[:1]  # the average alone
    assert lean.model_dump(exclude={"profiles"}) == full.model_dump(exclude={"profiles"})


@pytest.mark.parametrize("relative", [True, False])
def test_the_fleets_outliers_on_arrays_are_is_outlier_of_each(relative: bool) -> None:
    from ncmeasure.analysis.judgement.status import (
        CHARACTERISTICS,
        is_outlier,
        outliers_among,
    )
    from ncmeasure.formats.comparison import Limits

    rng = np.random.default_rng(11)
    characteristic = next(c for c in CHARACTERISTICS if c.relative is relative)
    limits = Limits()
    values = rng.normal(10.0, 3.0, size=400)
    medians = values + rng.normal(0.0, 6.0, size=400)
    medians[::17] = -medians[::17]
    z = rng.normal(0.0, 5.0, size=400)
    z[::13] = np.nan
    z[::29] = limits.outlier_z  # on the limit: no outlier
    found = outliers_among(characteristic, values, medians, z, limits)
    each = [
        is_outlier(characteristic, v, m, None if np.isnan(k) else float(k), limits)
        for v, m, k in zip(values.tolist(), medians.tolist(), z.tolist(), strict=True)
    ]
    assert found.tolist() == each
    assert 20 < sum(each) < 380
