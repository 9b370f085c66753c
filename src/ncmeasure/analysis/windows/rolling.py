"""Rolling median, minimum and maximum over a window of samples, in numpy.

The values are those of ``scipy.ndimage``'s ``median_filter``,
``minimum_filter1d`` and ``maximum_filter1d`` with the same size, origin and
mode, element for element (a median of an odd count, a minimum and a maximum
pick one of the samples: there is no arithmetic to round). They spare the
window finding the import of ``scipy.ndimage`` (with the array-API layer it
brings, a tenth of a second of every analysis). The inputs hold no NaN (the
callers replace them first), as the comparison order of NaN differs.
"""

from __future__ import annotations

from typing import Any, Literal, TypeVar

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

__all__ = ["MEDIAN_BLOCK_VALUES", "rolling_max", "rolling_median", "rolling_min"]

Mode = Literal["nearest", "reflect"]
S = TypeVar("S", bound=np.generic)

# scipy.ndimage's boundary modes by numpy.pad's names: "reflect" repeats the edge sample
# (d c b a | a b c d), numpy's "symmetric"; "nearest" is numpy's "edge".
#: Values of the windows :func:`rolling_median` partitions at a time (8 bytes each).
MEDIAN_BLOCK_VALUES = 1 << 18

_PAD: dict[str, Literal["edge", "symmetric"]] = {"nearest": "edge", "reflect": "symmetric"}


def _padded(values: NDArray[S], size: int, origin: int, mode: Mode) -> NDArray[S]:
    """``values`` extended so that output i is the window ``[i, i + size)`` of the result."""
    if size < 1:
        raise ValueError(f"window size must be at least 1, got {size}")
    if not -(size // 2) <= origin <= (size - 1) // 2:
        raise ValueError(f"origin {origin} out of range for a window of {size}")
    before = size // 2 + origin
    return np.pad(values, (before, size - 1 - before), mode=_PAD[mode])


def _extreme(
    values: NDArray[S], size: int, origin: int, mode: Mode, *, largest: bool
) -> NDArray[S]:
    """Rolling minimum or maximum in O(n) whatever the size (van Herk / Gil-Werman)."""
    count = len(values)
    if count == 0:
        return values.copy()
    padded = _padded(values, size, origin, mode)
    op = np.maximum if largest else np.minimum
    # Blocks of `size`: a window is the tail of one block and the head of the next.
    blocks = -(-len(padded) // size)
    filled = np.empty(blocks * size, dtype=padded.dtype)
    filled[: len(padded)] = padded
    filled[len(padded) :] = padded[-1]  # beyond every window's reach
    grid = filled.reshape(blocks, size)
    head = op.accumulate(grid, axis=1).ravel()
    tail = op.accumulate(grid[:, ::-1], axis=1)[:, ::-1].ravel()
    result: NDArray[Any] = op(tail[:count], head[size - 1 : size - 1 + count])
    return result


def rolling_min(
    values: NDArray[S], size: int, *, origin: int = 0, mode: Mode = "reflect"
) -> NDArray[S]:
    """``scipy.ndimage.minimum_filter1d(values, size, mode=mode, origin=origin)``."""
    return _extreme(values, size, origin, mode, largest=False)


def rolling_max(
    values: NDArray[S], size: int, *, origin: int = 0, mode: Mode = "reflect"
) -> NDArray[S]:
    """``scipy.ndimage.maximum_filter1d(values, size, mode=mode, origin=origin)``."""
    return _extreme(values, size, origin, mode, largest=True)


def rolling_median(values: NDArray[np.float64], size: int) -> NDArray[np.float64]:
    """``scipy.ndimage.median_filter(values, size=size, mode="nearest")`` of a 1-D array.

    ``size`` is odd: the median is then one of the samples, the middle one.
    """
    if size % 2 != 1:
        raise ValueError(f"the rolling median needs an odd size, got {size}")
    values = np.asarray(values, dtype=np.float64)
    if len(values) == 0 or size == 1:
        return values.copy()
    padded = _padded(values, size, 0, "nearest")
    middle = size // 2
    result = np.empty(len(values), dtype=np.float64)
    # Blocks of windows: the partition copies its windows (rows × size values), so a
    # block holds about MEDIAN_BLOCK_VALUES of them, in the cache and bounded in memory.
    rows = max(1, MEDIAN_BLOCK_VALUES // size)
    for start in range(0, len(values), rows):
        stop = min(start + rows, len(values))
        windows = sliding_window_view(padded[start : stop + size - 1], size)
        result[start:stop] = np.partition(windows, middle, axis=1)[:, middle]
    return result
