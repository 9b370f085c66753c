"""The Stribeck and extended Stribeck models, fitted by bounded nonlinear least squares.

In the sense of one direction, friction a positive magnitude over speed
v = |velocity| (mm/min)::

      T(v) = T_C + (T_S − T_C)·exp(−(v/v_S)^δ) + b·v                      (Stribeck)
      T(v) = T_C + (T_S − T_C)·exp(−(v/v_S)^δ) + b·v + f_w·(v / 1000 mm/min)^k   (extended)

The rolling term of the extended model is that of ball screws with many
loaded balls (``f_w < 0`` bends the curve down at high speed). Start values,
the search and the identifiability rule: :func:`fit_nonlinear` and
``docs/analysis-models.md``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ncmeasure.analysis.friction.linear import clean_points, covariance
from ncmeasure.formats.results import NonlinearFit

if TYPE_CHECKING:
    from scipy import optimize

__all__ = [
    "DELTA_BOUNDS",
    "EXTENDED_PARAMETERS",
    "QUICK_EVALUATIONS",
    "ROLLING_EXPONENT_BOUNDS",
    "ROLLING_REFERENCE_MM_MIN",
    "STRIBECK_PARAMETERS",
    "STRIBECK_VELOCITY_MIN_FRACTION",
    "fit_nonlinear",
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


_T95 = 0.975


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
    from scipy import optimize  # here: drawing a fitted curve needs no scipy

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
        v, y, s = clean_points(speed_mm_min, value, sigma)
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
    return _judged(model, problem, solutions[0], v, y, s)


def _judged(
    model: Literal["stribeck", "extended"],
    problem: _Problem,
    best: optimize.OptimizeResult,
    v: FloatArray,
    y: FloatArray,
    s: FloatArray | None,
) -> NonlinearFit | None:
    """The fit at the solution ``best``: χ², covariance, 95 % intervals, identifiability."""
    from scipy import special  # here: drawing a fitted curve needs no scipy

    names = EXTENDED_PARAMETERS if problem.extended else STRIBECK_PARAMETERS
    m = len(names)
    n = v.size
    params = _physical(best.x, problem)

    fitted = _model_internal(best.x, problem)[0] * problem.t_ref
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
    cov = scale2 * covariance(jac.T @ jac)
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    t = float(special.stdtrit(dof, _T95))  # stats.t.ppf(_T95, dof)
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
