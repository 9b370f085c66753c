"""Coulomb + viscous friction, T(v) = T_C + t_v·v, fitted by linear least squares.

With the helpers every fit shares: the points cleaned (speeds as |v|, non-finite
points and σ dropped) and a covariance that stays finite where the data do not
determine a parameter. σ and the χ² test are defined in :func:`fit_linear` and
``docs/analysis-models.md``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ncmeasure.formats.results import LinearFit

__all__ = ["as_float", "clean_points", "covariance", "fit_linear"]

FloatArray = NDArray[np.float64]

_INFO_EIGEN_FLOOR = 1e-12


def as_float(values: ArrayLike) -> FloatArray:
    return np.atleast_1d(np.asarray(values, dtype=np.float64)).ravel()


def clean_points(
    speed_mm_min: ArrayLike, value: ArrayLike, sigma: ArrayLike | None
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Speeds as |v|, values and σ with every non-finite or non-positive-σ point dropped."""
    v = np.abs(as_float(speed_mm_min))
    y = as_float(value)
    if v.shape != y.shape:
        raise ValueError(f"speed ({v.size}) and value ({y.size}) differ in length")
    keep = np.isfinite(v) & np.isfinite(y)
    s: FloatArray | None = None
    if sigma is not None:
        s = as_float(sigma)
        if s.shape != y.shape:
            raise ValueError(f"sigma ({s.size}) and value ({y.size}) differ in length")
        keep &= np.isfinite(s) & (s > 0)
        s = s[keep]
    return v[keep], y[keep], s


def covariance(info: FloatArray) -> FloatArray:
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
    v, y, s = clean_points(speed_mm_min, value, sigma)
    n, m = v.size, 2
    if n < 3 or np.unique(v).size < 2:
        return None
    design = np.column_stack([v, np.ones_like(v)])
    weight = np.ones_like(v) if s is None else 1.0 / s
    coef, *_ = np.linalg.lstsq(design * weight[:, None], y * weight, rcond=None)
    residual = y - design @ coef
    dof = n - m
    inverse = covariance((design * weight[:, None]).T @ (design * weight[:, None]))
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
