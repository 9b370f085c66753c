"""Bounded nonlinear least squares for the small friction models, in numpy.

The Stribeck fits are tiny problems: 2 to 7 parameters, some 50 to 100
points, each evaluation a handful of vector operations. For them the cost of
:func:`scipy.optimize.least_squares` is its own bookkeeping (about 0.2 ms per
evaluation, 2.7 ms per run on the 2-core box) and its import (0.4 s), not
the model. :func:`bounded_least_squares` is a Levenberg–Marquardt method
(Moré's scaling, Nielsen's damping update) that keeps every parameter inside
its bounds by projection: a parameter on a bound whose gradient pushes it
outward is held there, the rest take the damped Gauss–Newton step, and the
step is clipped onto the box. It stops by the tests and tolerances of
``least_squares`` (``ftol``, ``xtol``, ``gtol`` = 1e-8) and reports the same
status codes and active-bound mask, so a caller reads it like an
``OptimizeResult``.

The tests hold it to ``least_squares(method="trf")`` on the fits of
``tests/analysis/friction``: the same minimum within the tolerances.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["LeastSquaresResult", "bounded_least_squares"]

FloatArray = NDArray[np.float64]

TOLERANCE = 1e-8
"""``ftol``, ``xtol`` and ``gtol``, as the defaults of ``least_squares``."""


@dataclass(frozen=True)
class LeastSquaresResult:
    """The solution, read as ``scipy.optimize.OptimizeResult`` is.

    ``status``: 1 the gradient vanished (``gtol``), 2 the cost stopped falling
    (``ftol``), 3 the step became negligible (``xtol``), 0 the evaluations ran
    out. ``active_mask``: −1 on the lower bound, 1 on the upper, 0 inside
    (within ``xtol`` relative, as ``least_squares`` reports it).
    """

    x: FloatArray
    cost: float
    fun: FloatArray
    jac: FloatArray
    status: int
    nfev: int
    active_mask: NDArray[np.int_]


def _active(x: FloatArray, lower: FloatArray, upper: FloatArray) -> NDArray[np.int_]:
    """−1/1 where x lies on its lower/upper bound within ``xtol`` relative, else 0."""
    to_lower, to_upper = x - lower, upper - x
    lower_active = np.isfinite(lower) & (
        to_lower <= np.minimum(to_upper, TOLERANCE * np.maximum(1.0, np.abs(lower)))
    )
    upper_active = np.isfinite(upper) & (
        to_upper <= np.minimum(to_lower, TOLERANCE * np.maximum(1.0, np.abs(upper)))
    )
    mask = np.zeros(x.size, dtype=np.int_)
    mask[lower_active] = -1
    mask[upper_active] = 1
    return mask


def _negligible(step: NDArray[np.floating], x: FloatArray) -> bool:
    """``least_squares``' ``xtol`` test: |step| < xtol·(xtol + |x|)."""
    return math.sqrt(float(step @ step)) < TOLERANCE * (TOLERANCE + math.sqrt(float(x @ x)))


def bounded_least_squares(
    fun: Callable[[FloatArray], FloatArray],
    jac: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    lower: Sequence[float],
    upper: Sequence[float],
    max_nfev: int = 1000,
) -> LeastSquaresResult:
    """Minimise ½·|fun(x)|² for lower ≤ x ≤ upper, starting from ``x0`` (clipped into the box).

    ``jac(x)`` is the Jacobian of ``fun`` at x. Raises nothing of its own; a
    residual or Jacobian that is not finite at the start gives status −1.
    """
    lo = np.asarray(lower, dtype=np.float64)
    hi = np.asarray(upper, dtype=np.float64)
    x = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    r = np.asarray(fun(x), dtype=np.float64)
    nfev = 1
    cost = 0.5 * float(r @ r)
    j = np.asarray(jac(x), dtype=np.float64)
    if not (np.isfinite(cost) and np.all(np.isfinite(j))):
        return LeastSquaresResult(x, cost, r, j, -1, nfev, _active(x, lo, hi))
    scale = np.einsum("ij,ij->j", j, j)  # Moré: the largest column norms seen
    damping = 1e-3
    growth = 2.0
    status = 0
    while status == 0:
        gradient = j.T @ r
        held = ((x <= lo) & (gradient > 0)) | ((x >= hi) & (gradient < 0))
        free = ~held
        if not free.any() or float(np.max(np.abs(gradient[free]))) < TOLERANCE:
            status = 1
            break
        normal = j.T @ j
        scale = np.maximum(scale, normal.diagonal())
        every = bool(free.all())
        scale_free = scale if every else scale[free]
        scale_free = np.where(scale_free > 0, scale_free, 1.0)
        system = normal if every else normal[np.ix_(free, free)]
        minus_gradient = -gradient if every else -gradient[free]
        while True:
            if nfev >= max_nfev or not math.isfinite(damping):
                break
            damped = system.copy()
            damped.flat[:: damped.shape[0] + 1] += damping * scale_free
            try:
                step_free = np.linalg.solve(damped, minus_gradient)
            except np.linalg.LinAlgError:
                damping *= growth
                growth *= 2.0
                continue
            if every:
                step = step_free
            else:
                step = np.zeros_like(x)
                step[free] = step_free
            x_new = np.clip(x + step, lo, hi)
            step = x_new - x
            r_new = np.asarray(fun(x_new), dtype=np.float64)
            nfev += 1
            cost_new = 0.5 * float(r_new @ r_new)
            predicted = -float(gradient @ step) - 0.5 * float(step @ normal @ step)
            reduction = cost - cost_new
            if np.isfinite(cost_new) and reduction > 0 and predicted > 0:
                ratio = reduction / predicted
                damping *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
                growth = 2.0
                if reduction < TOLERANCE * cost and ratio > 0.25:
                    status = 2
                elif _negligible(step, x):
                    status = 3
                x, r, cost = x_new, r_new, cost_new
                j = np.asarray(jac(x), dtype=np.float64)
                break
            if _negligible(step, x):
                status = 3  # no step the damping allows changes x any more
                break
            damping *= growth
            growth *= 2.0
        if status == 0 and (nfev >= max_nfev or not math.isfinite(damping)):
            break  # out of evaluations, or no damping gives a step: status 0
    return LeastSquaresResult(x, cost, r, j, status, nfev, _active(x, lo, hi))
