"""The rolling median, minimum and maximum equal scipy.ndimage's filters element for element."""

from __future__ import annotations

import subprocess
import sys
import tracemalloc

import numpy as np
import pytest
from scipy import ndimage

from ncmeasure.analysis.windows import rolling
from ncmeasure.analysis.windows.rolling import rolling_max, rolling_median, rolling_min


def _samples(seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for n in (1, 2, 3, 7, 20, 257):
        x = rng.normal(size=n)
        out += [x, np.round(x), np.where(rng.random(n) < 0.2, np.inf, x)]
    return out


@pytest.mark.parametrize("size", [1, 2, 3, 4, 5, 21, 40])
@pytest.mark.parametrize("mode", ["nearest", "reflect"])
def test_min_and_max_are_scipys(size: int, mode: str) -> None:
    for x in _samples(size):
        for origin in sorted({0, -(size // 2), (size - 1) // 2}):
            for ours, theirs in (
                (rolling_min, ndimage.minimum_filter1d),
                (rolling_max, ndimage.maximum_filter1d),
            ):
                expected = theirs(x, size, mode=mode, origin=origin)
                got = ours(x, size, origin=origin, mode=mode)  # type: ignore[arg-type]
                np.testing.assert_array_equal(got, expected, err_msg=f"{x.size} {origin}")


def test_max_of_a_mask_keeps_its_type() -> None:
    ok = (np.random.default_rng(3).random(500) < 0.05).astype(np.int8)
    expected = ndimage.maximum_filter1d(ok, 31, origin=15)
    got = rolling_max(ok, 31, origin=15)
    assert got.dtype == expected.dtype
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("size", [1, 3, 5, 21, 61])
def test_median_is_scipys(size: int) -> None:
    for x in _samples(size):
        expected = ndimage.median_filter(x, size=size, mode="nearest")
        np.testing.assert_array_equal(rolling_median(x, size), expected)


@pytest.mark.parametrize("block", [7, 100, 1 << 18])
def test_median_in_blocks_is_scipys_across_their_joins(
    block: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    values = np.random.default_rng(3).normal(size=5_003)
    values[::11] = 0.25
    monkeypatch.setattr(rolling, "MEDIAN_BLOCK_VALUES", block)
    for size in (1, 3, 21, 201):
        expected = ndimage.median_filter(values, size=size, mode="nearest")
        assert np.array_equal(rolling_median(values, size), expected)


def test_a_long_median_takes_bounded_memory() -> None:
    # The windows are partitioned in blocks: a wide window over a long array must not
    # copy every window at once (200,000 × 201 values would be 320 MB).
    values = np.random.default_rng(4).normal(size=200_000)
    tracemalloc.start()
    try:
        rolling_median(values, 201)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20


def test_bad_sizes_are_refused() -> None:
    with pytest.raises(ValueError, match="odd size"):
        rolling_median(np.zeros(5), 4)
    with pytest.raises(ValueError, match="at least 1"):
        rolling_min(np.zeros(5), 0)
    with pytest.raises(ValueError, match="origin 3 out of range"):
        rolling_max(np.zeros(5), 5, origin=3)


def test_the_analysis_does_not_import_scipy_ndimage() -> None:
    code = "import sys, ncmeasure.analysis.analyze; print('scipy.ndimage' in sys.modules)"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout.strip() == "False"
