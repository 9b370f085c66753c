"""Friction models fitted to the points of one position and direction. Pure numpy/scipy.

Three static models of friction T over speed v = |velocity| (mm/min), all in
the sense of one direction so that friction is a positive magnitude:

- linear (Coulomb + viscous), linear least squares::

      T(v) = T_C + t_v·v

- Stribeck, nonlinear least squares (:func:`scipy.optimize.least_squares`)::

      T(v) = T_C + (T_S − T_C)·exp(−(v/v_S)^δ) + b·v

- extended Stribeck, with the rolling term of ball screws with many loaded
  balls (``f_w < 0`` bends the curve down at high speed)::

      T(v) = T_C + (T_S − T_C)·exp(−(v/v_S)^δ) + b·v + f_w·(v / 1000 mm/min)^k

How σ, the χ² test and the identifiability rule are defined is written out
in ``docs/analysis-models.md`` and in the docstrings below. Nothing here
raises on bad data: a fit that cannot be made returns ``None``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize, stats

from ncmeasure.formats.results import (
    DirectionResult,
    LinearFit,
    ModelName,
    NonlinearFit,
    OffsetResult,
    Point,
)

__all__ = [
    "EXTENDED_PARAMETERS",
    "LINEAR_REGION_DECAY",
    "MEDIAN_SE_FACTOR",
    "MIN_LINEAR_POINTS",
    "MIN_LINEAR_POINTS_ABOVE_STRIBECK",
    "SPEED_MATCH_TOLERANCE",
    "STRIBECK_PARAMETERS",
    "fit_direction",
    "fit_linear",
    "fit_nonlinear",
    "point_sigma",
    "separate_offset",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

STRIBECK_PARAMETERS: tuple[str, ...] = ("T_C", "T_S", "v_S", "delta", "b")
"""Keys of :attr:`NonlinearFit.parameters` for the Stribeck model.

Units: ``T_C``, ``T_S`` in the friction quantity (Nm or A), ``v_S`` in mm/min,
``delta`` dimensionless, ``b`` per mm/min.
"""

EXTENDED_PARAMETERS: tuple[str, ...] = (*STRIBECK_PARAMETERS, "f_w", "k")
"""Keys for the extended model: ``f_w`` in the quantity (rolling term at 1 m/min), ``k``."""

ROLLING_REFERENCE_MM_MIN = 1000.0
"""The rolling term is f_w·(v / 1000 mm/min)^k: f_w is its value at 1 m/min, in the quantity."""

DELTA_BOUNDS = (0.3, 3.0)
"""Bounds of the Stribeck shape exponent δ."""

ROLLING_EXPONENT_BOUNDS = (0.3, 2.0)
"""Bounds of the rolling-term exponent k."""

STRIBECK_VELOCITY_MIN_FRACTION = 0.1
"""v_S may go down to this fraction of the lowest measured speed (and up to the highest)."""

LINEAR_REGION_DECAY = 0.01
"""The linear fit starts where the Stribeck hump has decayed to this fraction of its height."""

MIN_LINEAR_POINTS_ABOVE_STRIBECK = 5
"""Fewest points above the Stribeck region for a linear fit restricted to them."""

MIN_LINEAR_POINTS = 4
"""Fewest points a linear fit keeps when the slowest are left out to find its range."""

SPEED_MATCH_TOLERANCE = 0.005
"""Relative tolerance when speeds of the two directions are paired (0.5 %)."""

MEDIAN_SE_FACTOR = math.sqrt(math.pi / 2)
"""Standard error of a median of n normal samples: √(π/2)·std/√n (≈ 1.25 × the mean's)."""

SIGMA_FLOOR_FRACTION = 0.1
"""Per-point σ below this fraction of the median σ is raised to it (guards std = 0)."""

_INFO_EIGEN_FLOOR = 1e-12
_T95 = 0.975


# --------------------------------------------------------------------------- helpers


def _as_float(values: ArrayLike) -> FloatArray:
    return np.atleast_1d(np.asarray(values, dtype=np.float64)).ravel()


def _clean(
    speed_mm_min: ArrayLike, value: ArrayLike, sigma: ArrayLike | None
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Speeds as |v|, values and σ with every non-finite or non-positive-σ point dropped."""
    v = np.abs(_as_float(speed_mm_min))
    y = _as_float(value)
    if v.shape != y.shape:
        raise ValueError(f"speed ({v.size}) and value ({y.size}) differ in length")
    keep = np.isfinite(v) & np.isfinite(y)
    s: FloatArray | None = None
    if sigma is not None:
        s = _as_float(sigma)
        if s.shape != y.shape:
            raise ValueError(f"sigma ({s.size}) and value ({y.size}) differ in length")
        keep &= np.isfinite(s) & (s > 0)
        s = s[keep]
    return v[keep], y[keep], s


def _covariance(info: FloatArray) -> FloatArray:
    """(JᵀWJ)⁻¹, finite even when the data cannot determine a parameter.

    The columns are scaled to unit norm first (parameters differ by orders of
    magnitude); eigenvalues of the scaled matrix are floored at 1e-12 of the
    largest, so a parameter the data do not determine gets a huge but finite
    variance (results.json is plain JSON: no inf, no NaN).
    """
    scale = np.sqrt(np.clip(np.diag(info), 0.0, None))
    scale[scale == 0] = 1.0
    scaled = info / np.outer(scale, scale)
    eigval, eigvec = np.linalg.eigh(scaled)
    top = float(eigval.max()) if eigval.size and eigval.max() > 0 else 1.0
    eigval = np.maximum(eigval, top * _INFO_EIGEN_FLOOR)
    inverse = (eigvec / eigval) @ eigvec.T
    return np.asarray(inverse / np.outer(scale, scale), dtype=np.float64)


# --------------------------------------------------------------------------- linear


def fit_linear(
    speed_mm_min: ArrayLike,
    value: ArrayLike,
    sigma: ArrayLike | None = None,
    *,
    k_accept: float = 10.0,
) -> LinearFit | None:
    """Coulomb + viscous friction T(v) = T_C + t_v·v by linear least squares.

    Regressor rows are [v_k, 1] with v = |speed|; the estimate is
    ŷ = (HᵀWH)⁻¹HᵀWx, solved with :func:`numpy.linalg.lstsq` on the
    √W-scaled system.

    σ, the scatter of the points, is defined in one of two ways:

    - ``sigma`` given (per point, e.g. the standard error std/√n of each
      point's window samples): weighted least squares with W = diag(1/σ²);
      χ²_red = Σ(ê/σ)²/(n − m). This is the informative case: χ²_red ≫ 1
      means the points scatter around the line more than they scatter in
      themselves, i.e. the model is wrong. Standard errors are
      √diag((HᵀWH)⁻¹), multiplied by √χ²_red when χ²_red > 1 (the points'
      own σ then understates the scatter, e.g. correlated samples).
    - ``sigma`` omitted: σ² = Σê²/(n − m), the residual variance, and standard
      errors from σ²(HᵀH)⁻¹. χ²_red is then 1 by construction and the test
      always accepts: without an independent σ it says nothing.

    The fit is accepted when Σ(ê/σ)² ≤ k·(n − m), i.e. χ²_red ≤ ``k_accept``
    (method: accepted for k < 10). m = 2.

    Args:
        speed_mm_min: Speeds |v| in mm/min (signs are dropped).
        value: Friction magnitudes at those speeds (positive).
        sigma: Standard error of each value, or None. Points with a
            non-finite or non-positive σ are dropped, as are non-finite points.
        k_accept: The χ² acceptance factor k.

    Returns:
        The fit, or None with fewer than 3 usable points or fewer than 2
        distinct speeds.
    """
    v, y, s = _clean(speed_mm_min, value, sigma)
    n, m = v.size, 2
    if n < 3 or np.unique(v).size < 2:
        return None
    design = np.column_stack([v, np.ones_like(v)])
    weight = np.ones_like(v) if s is None else 1.0 / s
    coef, *_ = np.linalg.lstsq(design * weight[:, None], y * weight, rcond=None)
    residual = y - design @ coef
    dof = n - m
    inverse = _covariance((design * weight[:, None]).T @ (design * weight[:, None]))
    if s is None:
        sigma2 = float(residual @ residual) / dof
        cov = sigma2 * inverse
        chi2 = 1.0 if sigma2 > 0 else 0.0
    else:
        chi2 = float(np.sum((residual / s) ** 2)) / dof
        cov = inverse * max(1.0, chi2)
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    if not (np.all(np.isfinite(coef)) and np.all(np.isfinite(stderr)) and math.isfinite(chi2)):
        return None
    span = (float(v.min()), float(v.max()))
    if coef[1] < 0:
        # Friction is a positive magnitude: a negative intercept says the points are not
        # friction (an offset such as gravity not taken out) or not a line at all.
        return LinearFit(
            coulomb=None,
            viscous_per_mm_min=None,
            coulomb_stderr=None,
            viscous_stderr=None,
            chi2_reduced=chi2,
            accepted=False,
            n_points=int(n),
            velocity_range_mm_min=span,
            reason=f"the line through the points crosses zero ({coef[1]:.4g} at standstill): "
            "they do not describe friction (an offset such as gravity not separated?)",
        )
    return LinearFit(
        coulomb=float(coef[1]),
        viscous_per_mm_min=float(coef[0]),
        coulomb_stderr=float(stderr[1]),
        viscous_stderr=float(stderr[0]),
        chi2_reduced=chi2,
        accepted=bool(chi2 <= k_accept),
        n_points=int(n),
        velocity_range_mm_min=span,
    )


# --------------------------------------------------------------------------- nonlinear


@dataclass(frozen=True)
class _Problem:
    """Normalised data: u = v / v_ref, y = T / T_ref, s = σ / T_ref (or ones)."""

    u: FloatArray
    y: FloatArray
    s: FloatArray
    v_ref: float
    t_ref: float
    extended: bool


def _model_internal(x: FloatArray, p: _Problem) -> tuple[FloatArray, FloatArray]:
    """Model values and Jacobian in the internal parameters.

    Internal parameters: tc, h = ts − tc (≥ 0), ln(u_S), δ, bb (and fw, k),
    all on normalised scales so the optimiser sees numbers of order one.
    """
    tc, h, lus, delta, bb = x[:5]
    z = (p.u / math.exp(lus)) ** delta
    e = np.exp(-z)
    log_ratio = np.log(p.u) - lus
    value = tc + h * e + bb * p.u
    cols = [np.ones_like(p.u), e, h * e * z * delta, -h * e * z * log_ratio, p.u]
    if p.extended:
        fw, k = x[5], x[6]
        uk = p.u**k
        value = value + fw * uk
        cols += [uk, fw * uk * np.log(p.u)]
    return value, np.column_stack(cols)


def _jacobian_physical(params: dict[str, float], v: FloatArray) -> FloatArray:
    """∂T/∂(T_C, T_S, v_S, δ, b[, f_w, k]) at the solution, in physical units."""
    tc, ts, vs, delta, _ = (params[name] for name in STRIBECK_PARAMETERS)
    z = (v / vs) ** delta
    e = np.exp(-z)
    hump = ts - tc
    cols = [1.0 - e, e, hump * e * z * delta / vs, -hump * e * z * np.log(v / vs), v]
    if "f_w" in params:
        fw, k = params["f_w"], params["k"]
        ratio = v / ROLLING_REFERENCE_MM_MIN
        vk = ratio**k
        cols += [vk, fw * vk * np.log(ratio)]
    return np.column_stack(cols)


_DELTA_GRID = (0.4, 0.6, 0.8, 1.0, 1.4, 2.0, 2.8)
"""δ of the start grid."""

_K_GRID = (0.4, 0.7, 1.3, 1.6, 1.9)
"""k of the start grid (extended model)."""


def _linear_part(
    p: _Problem, lus: float, delta: float, k: float | None
) -> tuple[float, FloatArray]:
    """Best linear coefficients for fixed (v_S, δ[, k]): the model is linear in the rest.

    Returns the weighted residual sum of squares and (tc, h, bb[, fw]); h ≥ 0 is
    kept by dropping the hump column when the free solution makes it negative.
    """
    e = np.exp(-((p.u / math.exp(lus)) ** delta))
    cols = [np.ones_like(p.u), e, p.u] + ([] if k is None else [p.u**k])
    basis = np.column_stack(cols) / p.s[:, None]
    target = p.y / p.s
    coef, *_ = np.linalg.lstsq(basis, target, rcond=None)
    if coef[1] < 0:
        reduced, *_ = np.linalg.lstsq(np.delete(basis, 1, axis=1), target, rcond=None)
        coef = np.insert(reduced, 1, 0.0)
    rss = float(np.sum((basis @ coef - target) ** 2))
    return rss, np.asarray(coef, dtype=np.float64)


def _grid_rss(p: _Problem, lus: FloatArray, delta: FloatArray, k: float | None) -> FloatArray:
    """The residual sum of squares of :func:`_linear_part` for many (v_S, δ) and one k at once.

    The columns that do not depend on (v_S, δ), [1, u(, u^k)], are made
    orthonormal once (QR); each grid point's hump column e is projected off
    them, and its best coefficient follows in closed form:
    RSS = |r_y|² − (r_e·r_y)²/|r_e|², with r the parts orthogonal to the fixed
    columns. A negative hump coefficient drops the column (RSS = |r_y|²), as
    does a hump column that vanishes within rounding (lstsq's rank cut-off).
    Rows of the result follow ``lus``/``delta``.
    """
    weight = 1.0 / p.s
    fixed = [np.ones_like(p.u), p.u] + ([] if k is None else [p.u**k])
    q_mat, _ = np.linalg.qr(np.column_stack(fixed) * weight[:, None])
    target = p.y * weight
    r_y = target - q_mat @ (q_mat.T @ target)
    hump = np.exp(-((p.u[None, :] / np.exp(lus)[:, None]) ** delta[:, None])) * weight
    r_e = hump - (hump @ q_mat) @ q_mat.T
    cross = r_e @ r_y
    norm2 = np.einsum("gn,gn->g", r_e, r_e)
    base = float(r_y @ r_y)
    scale = np.sqrt(np.einsum("gn,gn->g", hump, hump))
    usable = (cross > 0) & (np.sqrt(norm2) > np.finfo(np.float64).eps * p.u.size * scale)
    gain = np.divide(cross**2, norm2, out=np.zeros_like(cross), where=usable)
    return np.asarray(np.maximum(base - gain, 0.0), dtype=np.float64)


def _starts(p: _Problem, count: int = 3) -> list[FloatArray]:
    """Starting points from a grid over the nonlinear parameters (variable projection).

    For each (v_S, δ[, k]) on the grid the linear parameters follow by linear
    least squares; the ``count`` best grid points with distinct v_S start the
    full optimisation. The grid is ranked by :func:`_grid_rss` (the same
    least-squares problems, solved together); the starts' linear parameters
    come from :func:`_linear_part`.
    """
    lo, hi = _log_us_bounds(p)
    lus_grid = np.linspace(lo, hi, 25)[1:-1]
    k_grid: tuple[float | None, ...] = _K_GRID if p.extended else (None,)
    # Grid points in the order lus, then δ, then k: the order ties are broken in.
    lus_index, delta_index = (a.ravel() for a in np.indices((lus_grid.size, len(_DELTA_GRID))))
    lus_values = lus_grid[lus_index]
    delta_values = np.array(_DELTA_GRID)[delta_index]
    with np.errstate(all="ignore"):
        rss = np.column_stack([_grid_rss(p, lus_values, delta_values, k) for k in k_grid])
    flat = rss.ravel()
    finite = np.flatnonzero(np.isfinite(flat))
    ranked = finite[np.argsort(flat[finite], kind="stable")]
    starts: list[FloatArray] = []
    taken: list[float] = []
    for i in ranked:
        point, k_number = divmod(int(i), len(k_grid))
        lus = float(lus_values[point])
        if any(abs(lus - other) < 0.3 for other in taken):
            continue
        delta, k = float(delta_values[point]), k_grid[k_number]
        _, coef = _linear_part(p, lus, delta, k)
        tc, h, bb = float(coef[0]), max(float(coef[1]), 1e-3), float(coef[2])
        x0 = [tc, h, lus, delta, bb]
        if k is not None:
            x0 += [float(coef[3]), k]
        starts.append(np.array(x0))
        taken.append(lus)
        if len(starts) == count:
            break
    return starts


def _log_us_bounds(p: _Problem) -> tuple[float, float]:
    return math.log(STRIBECK_VELOCITY_MIN_FRACTION * float(p.u.min())), 0.0


def _bounds(p: _Problem) -> tuple[list[float], list[float]]:
    lo, hi = _log_us_bounds(p)
    lower = [-np.inf, 0.0, lo, DELTA_BOUNDS[0], -np.inf]
    upper = [np.inf, np.inf, hi, DELTA_BOUNDS[1], np.inf]
    if p.extended:
        lower += [-np.inf, ROLLING_EXPONENT_BOUNDS[0]]
        upper += [np.inf, ROLLING_EXPONENT_BOUNDS[1]]
    return lower, upper


def _projection(p: _Problem, theta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The model with its linear parameters eliminated (variable projection).

    For fixed nonlinear parameters θ = (ln u_S, δ[, k]) the model is linear in
    (tc, h, bb[, fw]); they are the weighted least-squares solution, h ≥ 0 kept
    by leaving the hump column out when the free solution makes it negative
    (for one bound the constrained optimum then lies on it). Returns the
    weighted residual (model − y)/s, the linear coefficients and the Jacobian
    of the residual in θ (Golub and Pereyra's, of the projected functional).
    """
    lus, delta = float(theta[0]), float(theta[1])
    z = (p.u / math.exp(lus)) ** delta
    e = np.exp(-z)
    cols = [np.ones_like(p.u), e, p.u]
    # ∂column/∂θ_j and the column it belongs to: the hump (ln u_S, δ), u^k (k).
    derivative = [e * z * delta / p.s, -e * z * (np.log(p.u) - lus) / p.s]
    column_of = [1, 1]
    if p.extended:
        uk = p.u ** float(theta[2])
        cols.append(uk)
        derivative.append(uk * np.log(p.u) / p.s)
        column_of.append(3)
    basis = np.column_stack(cols) / p.s[:, None]
    target = p.y / p.s
    used = np.ones(basis.shape[1], dtype=bool)
    coef = np.zeros(basis.shape[1])
    for _ in range(2):
        active = basis[:, used]
        u_mat, sv, vt = np.linalg.svd(active, full_matrices=False)
        keep = sv > np.finfo(np.float64).eps * max(active.shape) * sv[0]
        u_mat, sv, vt = u_mat[:, keep], sv[keep], vt[keep]
        coef[used] = vt.T @ ((u_mat.T @ target) / sv)
        if not used[1] or coef[1] >= 0:
            break
        used[1] = False
        coef[1] = 0.0
    residual = basis @ coef - target
    position = np.cumsum(used) - 1
    jac = np.empty((p.u.size, len(derivative)))
    for j, (d_col, column) in enumerate(zip(derivative, column_of, strict=True)):
        d_model = coef[column] * d_col
        # dr/dθ_j = P⊥·(∂A/∂θ_j)·c − (A⁺)ᵀ·(∂A/∂θ_j)ᵀ·r
        jac[:, j] = d_model - u_mat @ (u_mat.T @ d_model)
        if used[column]:
            w = np.zeros(int(used.sum()))
            w[position[column]] = float(d_col @ residual)
            jac[:, j] -= u_mat @ ((vt @ w) / sv)
    return residual, coef, jac


def _full(p: _Problem, theta: FloatArray, coef: FloatArray) -> FloatArray:
    """The internal parameter vector of :func:`_model_internal` from θ and the linear ones."""
    x = [coef[0], coef[1], theta[0], theta[1], coef[2]]
    if p.extended:
        x += [coef[3], theta[2]]
    return np.array(x, dtype=np.float64)


def _least_squares(
    fun: Callable[[FloatArray], FloatArray],
    jac: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    lower: Sequence[float],
    upper: Sequence[float],
    max_nfev: int = 1000,
) -> optimize.OptimizeResult | None:
    """One bounded ``trf`` run from ``x0`` (clipped inside the bounds); None when it fails.

    A run that stops at ``max_nfev`` is returned (status 0): the caller decides.
    """
    x0 = np.clip(x0, np.add(lower, 1e-9), np.subtract(upper, 1e-9))
    try:
        with np.errstate(all="ignore"):
            res = optimize.least_squares(
                fun,
                x0,
                jac=jac,
                bounds=(lower, upper),
                method="trf",
                x_scale="jac",
                max_nfev=max_nfev,
            )
    except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        log.debug("least_squares failed from %s: %s", x0, exc)
        return None
    if res.status >= 0 and np.isfinite(res.cost) and np.all(np.isfinite(res.x)):
        return res
    return None


def _solve_full(
    p: _Problem, starts: Sequence[FloatArray], max_nfev: int = 1000
) -> tuple[list[optimize.OptimizeResult], bool]:
    """``least_squares`` on all parameters from every start.

    Returns the converged runs, best (lowest cost) first, and whether a run
    stopped at ``max_nfev`` before converging.
    """
    cache: dict[bytes, tuple[FloatArray, FloatArray]] = {}

    def evaluate(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = _model_internal(x, p)
        return cache[key]

    def residual(x: FloatArray) -> FloatArray:
        return (evaluate(x)[0] - p.y) / p.s

    def jacobian(x: FloatArray) -> FloatArray:
        return evaluate(x)[1] / p.s[:, None]

    lower, upper = _bounds(p)
    runs = [_least_squares(residual, jacobian, x0, lower, upper, max_nfev) for x0 in starts]
    found = [r for r in runs if r is not None and r.status > 0]
    found.sort(key=lambda r: float(r.cost))
    return found, any(r is not None and r.status == 0 for r in runs)


def _solve_projected(p: _Problem, starts: Sequence[FloatArray]) -> list[optimize.OptimizeResult]:
    """The best optimum of the projected problem, confirmed on all parameters.

    Every start is optimised in the nonlinear parameters only, the linear ones
    eliminated (:func:`_projection`: 2 or 3 parameters instead of 5 or 7). In
    a valley in which the linear parameters trade off against each other (b
    against f_w as k → 1) this takes some ten evaluations where the full
    problem crawls for hundreds. The best of them starts ``least_squares`` on
    all parameters, which confirms it and says which parameters sit on a
    bound. Returns that run, or nothing.
    """
    lower, upper = _bounds(p)
    nonlinear = [2, 3, 6] if p.extended else [2, 3]
    cache: dict[bytes, tuple[FloatArray, FloatArray, FloatArray]] = {}

    def evaluate(theta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        key = theta.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = _projection(p, theta)
        return cache[key]

    projected = []
    for x0 in starts:
        res = _least_squares(
            lambda theta: evaluate(theta)[0],
            lambda theta: evaluate(theta)[2],
            np.asarray(x0, dtype=np.float64)[nonlinear],
            [lower[i] for i in nonlinear],
            [upper[i] for i in nonlinear],
        )
        if res is not None and res.status > 0:
            projected.append(res)
    if not projected:
        return []
    best = min(projected, key=lambda r: float(r.cost))
    return _solve_full(p, [_full(p, best.x, _projection(p, best.x)[1])])[0]


QUICK_EVALUATIONS = 40
"""Evaluations a full fit from a grid start may take before the projected fit is tried too.

On the industrial data (50 steps, 5 positions) a fit from a grid start either converges
within 35 evaluations or crawls along a valley for 190 to 520.
"""


def _solve(p: _Problem, starts: Sequence[FloatArray]) -> list[optimize.OptimizeResult]:
    """Run least_squares from every start; successful runs, best (lowest cost) first.

    Each start is fitted on all parameters for at most
    :data:`QUICK_EVALUATIONS` evaluations. Where every run converges within
    them, that is the answer. Where one does not (a crawl along a valley), the
    projected fit (:func:`_solve_projected`) joins the runs that converged,
    and the lowest cost wins.
    """
    found, unfinished = _solve_full(p, starts, QUICK_EVALUATIONS)
    if unfinished or not found:
        found = sorted([*found, *_solve_projected(p, starts)], key=lambda r: float(r.cost))
    return found


def _physical(x: FloatArray, p: _Problem) -> dict[str, float]:
    tc, h, lus, delta, bb = (float(val) for val in x[:5])
    params = {
        "T_C": tc * p.t_ref,
        "T_S": (tc + h) * p.t_ref,
        "v_S": math.exp(lus) * p.v_ref,
        "delta": delta,
        "b": bb * p.t_ref / p.v_ref,
    }
    if p.extended:
        fw, k = float(x[5]), float(x[6])
        params["f_w"] = fw * p.t_ref * (ROLLING_REFERENCE_MM_MIN / p.v_ref) ** k
        params["k"] = k
    return params


def fit_nonlinear(
    speed_mm_min: ArrayLike,
    value: ArrayLike,
    sigma: ArrayLike | None = None,
    *,
    model: Literal["stribeck", "extended"],
) -> NonlinearFit | None:
    """Fit the Stribeck or the extended Stribeck model by bounded nonlinear least squares.

    ``stribeck``: T = T_C + (T_S − T_C)·exp(−(v/v_S)^δ) + b·v, parameters
    :data:`STRIBECK_PARAMETERS`. ``extended`` adds f_w·(v/1000)^k
    (:data:`EXTENDED_PARAMETERS`); f_w may have either sign.

    Bounds: T_S ≥ T_C (a Stribeck hump, never a dip), v_S between 0.1 × the
    lowest and the highest speed, δ in [0.3, 3], k in [0.3, 2]; T_C, b and f_w
    are free. The rolling term is written with v in m/min, f_w·(v/1000)^k,
    so f_w is the rolling friction at 1 m/min in the friction quantity; with
    v in mm/min f_w's unit would depend on k and its interval would be
    dominated by the uncertainty of k.

    Starting values come from the data: the model is linear in T_C, T_S − T_C,
    b (and f_w) once v_S, δ (and k) are fixed, so a grid over v_S (23 values
    across the speed range) × δ (7) [× k (5)] is solved by linear least
    squares, and the three best grid points with distinct v_S start
    :func:`scipy.optimize.least_squares` (``trf``, analytic Jacobian) on all
    parameters, each for at most :data:`QUICK_EVALUATIONS` evaluations. Where
    one of them does not converge within them (a crawl along a valley in which
    b and f_w trade off as k → 1), the same starts are also optimised with the
    linear parameters eliminated (variable projection) and the best of these
    is confirmed on all parameters. The lowest cost wins; a run that stops
    without converging does not count.

    σ and χ²_red as in :func:`fit_linear`, with m the number of parameters.
    The covariance is s²(JᵀWJ)⁻¹ with J the Jacobian in the physical
    parameters at the solution, s² = max(1, χ²_red) with ``sigma`` and the
    residual variance without. 95 % intervals: value ± t₀.₉₇₅(n − m)·stderr.

    ``identifiable`` is True only when all of these hold:

    - every interval is narrower than |value| (hi − lo < |value|, so it also
      excludes zero): each parameter is known to better than ±50 %;
    - no parameter sits on a bound (the data push it outside the model);
    - the hump T_S − T_C is positive beyond its own 95 % interval.

    Pure Coulomb + viscous data leave v_S and δ undetermined (the hump is
    zero), so they are reported as not identifiable.

    Args:
        speed_mm_min: Speeds |v| in mm/min; points at zero speed are dropped.
        value: Friction magnitudes.
        sigma: Standard error per point, or None.
        model: ``"stribeck"`` or ``"extended"``.

    Returns:
        The fit, or None with fewer than (parameters + 2) usable points, fewer
        than 3 distinct speeds, or when no start converges.
    """
    try:
        v, y, s = _clean(speed_mm_min, value, sigma)
    except ValueError as exc:
        log.debug("nonlinear fit skipped: %s", exc)
        return None
    positive = v > 0
    v, y = v[positive], y[positive]
    s = None if s is None else s[positive]
    names = STRIBECK_PARAMETERS if model == "stribeck" else EXTENDED_PARAMETERS
    m = len(names)
    n = v.size
    if n < m + 2 or np.unique(v).size < 3:
        return None
    v_ref = float(v.max())
    t_ref = float(np.median(np.abs(y))) or 1.0
    problem = _Problem(
        u=v / v_ref,
        y=y / t_ref,
        s=np.ones_like(y) if s is None else s / t_ref,
        v_ref=v_ref,
        t_ref=t_ref,
        extended=model == "extended",
    )
    solutions = _solve(problem, _starts(problem))
    if not solutions:
        log.debug("%s fit did not converge from any start", model)
        return None
    best = solutions[0]
    params = _physical(best.x, problem)

    fitted = _model_internal(best.x, problem)[0] * t_ref
    residual = y - fitted
    dof = n - m
    jac = _jacobian_physical(params, v)
    if s is not None:
        jac = jac / s[:, None]
        chi2 = float(np.sum((residual / s) ** 2)) / dof
        scale2 = max(1.0, chi2)
    else:
        chi2 = 1.0
        scale2 = float(residual @ residual) / dof
    if not (math.isfinite(chi2) and np.all(np.isfinite(jac))):
        return None
    cov = scale2 * _covariance(jac.T @ jac)
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    t = float(stats.t.ppf(_T95, dof))
    ci = {
        name: (params[name] - t * float(stderr[i]), params[name] + t * float(stderr[i]))
        for i, name in enumerate(names)
    }
    hump = params["T_S"] - params["T_C"]
    hump_se = math.sqrt(max(float(cov[0, 0] + cov[1, 1] - 2 * cov[0, 1]), 0.0))
    wide = [name for name, (lo, hi) in ci.items() if not hi - lo < abs(params[name])]
    bound = [name for name, active in zip(names, best.active_mask, strict=True) if active != 0]
    if not all(math.isfinite(x) for pair in ci.values() for x in pair):
        return None
    reasons = []
    if wide:
        reasons.append(f"{', '.join(wide)} not determined (95 % interval wider than the value)")
    if bound:
        reasons.append(f"{', '.join(bound)} at the bound of its range")
    if not hump - t * hump_se > 0:
        reasons.append("no Stribeck hump beyond its uncertainty")
    if params["T_C"] <= 0:
        reasons.append(f"T_C {params['T_C']:.4g} is not a friction")
    if reasons:
        return NonlinearFit(
            model=model,
            parameters=None,
            ci95=None,
            identifiable=False,
            chi2_reduced=chi2,
            reason="; ".join(reasons),
        )
    return NonlinearFit(
        model=model,
        parameters=params,
        ci95=ci,
        identifiable=True,
        chi2_reduced=chi2,
        stribeck_velocity_mm_min=params["v_S"],
    )


# --------------------------------------------------------------------------- per direction


def point_sigma(points: Sequence[Point]) -> FloatArray | None:
    """σ per point: the standard error of its median.

    The point's own ``stderr`` where the friction table gave one (the scatter
    of batch medians: samples of a window are correlated, batches nearly
    not), else √(π/2)·std/√n, the standard error of the median of n
    independent normal samples.

    Guards: a point without a usable figure gets the median σ of the others;
    any σ below 0.1 × that median is raised to it (a current quantised to a
    constant reading has std 0, not infinite precision). None when no point
    has a usable σ.
    """
    raw = np.array(
        [
            p.stderr
            if p.stderr is not None and p.stderr > 0
            else (MEDIAN_SE_FACTOR * p.std / math.sqrt(p.n) if p.n >= 1 and p.std > 0 else math.nan)
            for p in points
        ],
        dtype=np.float64,
    )
    valid = np.isfinite(raw) & (raw > 0)
    if not np.any(valid):
        return None
    typical = float(np.median(raw[valid]))
    sigma = np.where(valid, raw, typical)
    return np.asarray(np.maximum(sigma, SIGMA_FLOOR_FRACTION * typical), dtype=np.float64)


def _linear_region(
    speed: FloatArray,
    magnitude: FloatArray,
    sigma: FloatArray | None,
    first: int,
    k_accept: float,
) -> tuple[LinearFit | None, int]:
    """The linear fit over the widest range of speeds, from the top down, where it holds.

    Points are sorted by speed. Starting with the points from ``first`` on,
    the slowest point is left out as long as the fit is rejected and at least
    :data:`MIN_LINEAR_POINTS` remain: the hump of a Stribeck curve lifts the
    slow points, and a line through them describes neither region. Returns the
    first accepted fit, else the fit over all points from ``first``, and the
    number of points below its range.
    """
    n = speed.size
    widest = fit_linear(
        speed[first:],
        magnitude[first:],
        None if sigma is None else sigma[first:],
        k_accept=k_accept,
    )
    if widest is None or widest.accepted or sigma is None:
        return widest, first
    for start in range(first + 1, n - MIN_LINEAR_POINTS + 1):
        candidate = fit_linear(speed[start:], magnitude[start:], sigma[start:], k_accept=k_accept)
        if candidate is not None and candidate.accepted:
            return candidate, start
    return widest, first


def _better_extended(stribeck: NonlinearFit, extended: NonlinearFit, points: int) -> bool:
    """True when the rolling term lowers χ² significantly (F-test at 1 %)."""
    extra = len(EXTENDED_PARAMETERS) - len(STRIBECK_PARAMETERS)
    dof = points - len(EXTENDED_PARAMETERS)
    if dof <= 0:
        return False
    rss_s = stribeck.chi2_reduced * (points - len(STRIBECK_PARAMETERS))
    rss_e = extended.chi2_reduced * dof
    if rss_e <= 0:
        return rss_s > 0
    statistic = (rss_s - rss_e) / extra / (rss_e / dof)
    return bool(stats.f.sf(statistic, extra, dof) < 0.01)


def fit_direction(
    points: Sequence[Point],
    direction: Literal[1, -1],
    *,
    offset: OffsetResult | None = None,
    coarse: bool = False,
    k_accept: float = 10.0,
) -> DirectionResult:
    """All fits of one position and direction, and the model that describes the curve.

    Points carry signed velocities and signed medians (the negative direction
    has negative friction). The fits see speed |v| and the friction magnitude
    ``direction × (median − offset)``: the axis' offset (gravity on a vertical
    axis, a bias of the current) is taken out first, so that both directions
    describe friction. σ per point from :func:`point_sigma`.

    The Stribeck and extended models are fitted to all points. The linear
    Coulomb + viscous fit is fitted where the line holds: above the Stribeck
    region where the Stribeck fit is identifiable (speeds where the hump has
    decayed to 1 % of its height, v ≥ v_S·(ln 100)^(1/δ), and at least 3·v_S,
    when at least 5 points remain), and from there leaving out the slowest
    points as long as the line is rejected (:func:`_linear_region`). Its
    ``velocity_range_mm_min`` and ``points_below_range`` say where it holds.

    The model that describes the curve is the simplest that fits every point
    (linear, else Stribeck, else extended where its rolling term is
    significant), else the linear model over its range; on coarse data the
    Stribeck models are not trusted. ``model`` is None when none fits.

    Returns:
        The direction's result with its points as given.
    """
    if not points:
        return DirectionResult(points=[], fit=None, model=None, model_reason="no points")
    order = np.argsort(np.abs([p.velocity_mm_min for p in points]), kind="stable")
    ordered = [points[i] for i in order]
    speed = np.abs(np.array([p.velocity_mm_min for p in ordered], dtype=np.float64))
    shift = offset.value if offset is not None else 0.0
    magnitude = direction * (np.array([p.median for p in ordered], dtype=np.float64) - shift)
    sigma = point_sigma(ordered)
    stribeck = fit_nonlinear(speed, magnitude, sigma, model="stribeck")
    extended = fit_nonlinear(speed, magnitude, sigma, model="extended")
    if coarse:
        stribeck, extended = (
            None
            if fit is None
            else fit.model_copy(
                update={
                    "parameters": None,
                    "ci95": None,
                    "identifiable": False,
                    "stribeck_velocity_mm_min": None,
                    "reason": "the data is too coarse for a Stribeck curve (few samples per "
                    "window)",
                }
            )
            for fit in (stribeck, extended)
        )
    first = 0
    if stribeck is not None and stribeck.parameters is not None:
        vs, delta = stribeck.parameters["v_S"], stribeck.parameters["delta"]
        cut = max(3.0 * vs, vs * math.log(1.0 / LINEAR_REGION_DECAY) ** (1.0 / delta))
        above = int(np.searchsorted(speed, cut))
        if speed.size - above >= MIN_LINEAR_POINTS_ABOVE_STRIBECK:
            first = above
        else:
            log.debug(
                "only %d points above the Stribeck region (%.4g mm/min)", speed.size - above, cut
            )
    linear, below = _linear_region(speed, magnitude, sigma, first, k_accept)
    if linear is not None:
        updates: dict[str, object] = {"points_below_range": below}
        if offset is not None and offset.stderr and linear.coulomb_stderr is not None:
            # The offset shifts every point alike: it moves the Coulomb friction only.
            updates["coulomb_stderr"] = math.hypot(linear.coulomb_stderr, offset.stderr)
        linear = linear.model_copy(update=updates)
    model, reason = _choose_model(linear, stribeck, extended, speed.size, k_accept)
    return DirectionResult(
        points=list(points),
        fit=linear,
        stribeck=stribeck,
        extended=extended,
        offset_removed=offset.value if offset is not None else None,
        model=model,
        model_reason=reason,
    )


def _choose_model(
    linear: LinearFit | None,
    stribeck: NonlinearFit | None,
    extended: NonlinearFit | None,
    points: int,
    k_accept: float,
) -> tuple[ModelName | None, str]:
    """The simplest model that describes the curve, and why, in one sentence."""
    linear_ok = linear is not None and linear.accepted and linear.coulomb is not None
    if linear_ok and linear is not None and linear.points_below_range == 0:
        return "linear", (
            f"Coulomb + viscous friction describes every point (χ²ᵣ {linear.chi2_reduced:.2g})."
        )
    s_ok = stribeck is not None and stribeck.identifiable and stribeck.chi2_reduced <= k_accept
    e_ok = extended is not None and extended.identifiable and extended.chi2_reduced <= k_accept
    if s_ok and stribeck is not None:
        if e_ok and extended is not None and _better_extended(stribeck, extended, points):
            return "extended", (
                f"The extended Stribeck model describes every point (χ²ᵣ "
                f"{extended.chi2_reduced:.2g}); its rolling term is significant."
            )
        return "stribeck", (
            f"The Stribeck model describes every point (χ²ᵣ {stribeck.chi2_reduced:.2g}): "
            "friction rises towards standstill."
        )
    if e_ok and extended is not None:
        return "extended", (
            f"The extended Stribeck model describes every point (χ²ᵣ {extended.chi2_reduced:.2g})."
        )
    if linear_ok and linear is not None:
        low, high = linear.velocity_range_mm_min
        return "linear", (
            f"Coulomb + viscous friction holds from {low:.4g} to {high:.4g} mm/min (χ²ᵣ "
            f"{linear.chi2_reduced:.2g}); the {linear.points_below_range} slower point(s) rise "
            "above the line (Stribeck region) and no Stribeck model is determined by them."
        )
    why = []
    if linear is None:
        why.append("too few points for a line")
    elif linear.reason:
        why.append(f"linear: {linear.reason}")
    else:
        why.append(f"linear: χ²ᵣ {linear.chi2_reduced:.3g} over its best range")
    for fit in (stribeck, extended):
        if fit is not None:
            why.append(f"{fit.model}: {fit.reason or f'χ²ᵣ {fit.chi2_reduced:.3g}'}")
    return None, "No model describes the points (" + "; ".join(why) + ")."


# --------------------------------------------------------------------------- offset


def separate_offset(positive: Sequence[Point], negative: Sequence[Point]) -> OffsetResult | None:
    """The direction-independent part of the signal, from both directions at equal speed.

    With T₊ = F + o and T₋ = −F + o at the same |v|, o = (T₊ + T₋)/2 for
    every speed measured in both directions (|v| equal within 0.5 %; each
    positive point is paired with the nearest unused negative one). The
    result is the mean of those offsets; its standard error is the scatter of
    the per-speed offsets / √m (m ≥ 2), or from the two points' σ when only
    one speed matches.

    Returns:
        The offset, or None when no speed is measured in both directions.
    """
    neg = [p for p in negative if p.velocity_mm_min != 0 and math.isfinite(p.median)]
    neg_speed = np.array([abs(p.velocity_mm_min) for p in neg], dtype=np.float64)
    used = np.zeros(len(neg), dtype=bool)
    offsets: list[float] = []
    pair_se: list[float] = []
    speeds: list[float] = []
    for p in sorted(positive, key=lambda q: abs(q.velocity_mm_min)):
        speed = abs(p.velocity_mm_min)
        if speed == 0 or not math.isfinite(p.median) or not neg:
            continue
        gap = np.where(used, np.inf, np.abs(neg_speed - speed) / np.maximum(neg_speed, speed))
        j = int(np.argmin(gap))
        if gap[j] > SPEED_MATCH_TOLERANCE:
            continue
        used[j] = True
        q = neg[j]
        offsets.append(0.5 * (p.median + q.median))
        speeds.append(speed)
        se = [
            x.stderr if x.stderr else MEDIAN_SE_FACTOR * x.std / math.sqrt(x.n)
            for x in (p, q)
            if x.n >= 1 and (x.std > 0 or x.stderr)
        ]
        pair_se.append(0.5 * math.sqrt(sum(e * e for e in se)) if len(se) == 2 else math.nan)
    if not offsets:
        return None
    values = np.array(offsets)
    mean = float(values.mean())
    if values.size >= 2:
        stderr: float | None = float(values.std(ddof=1) / math.sqrt(values.size))
    else:
        stderr = pair_se[0] if math.isfinite(pair_se[0]) else None
    if stderr is not None and stderr > 0:
        verdict = (
            "significant" if abs(mean) > 2 * stderr else "not distinguishable from zero"
        ) + f" (±{stderr:.3g} standard error)"
    else:
        verdict = "no standard error available"
    explanation = (
        f"Direction-independent part o = (T₊ + T₋)/2 = {mean:.4g}, {verdict}, over "
        f"{values.size} speed(s) measured in both directions "
        f"({min(speeds):.4g}–{max(speeds):.4g} mm/min; per-speed offsets "
        f"{values.min():.4g} to {values.max():.4g}). On a vertical axis this is gravity "
        "(the weight's torque on the screw, M = F·h/2π); on a horizontal axis a bias of the "
        "torque or current signal, or friction that differs between the directions. "
        "Friction per direction is the half difference (T₊ − T₋)/2."
    )
    return OffsetResult(value=mean, stderr=stderr, explanation=explanation)
