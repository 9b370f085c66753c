"""Friction models fitted to the points of one position and direction, and the one chosen.

Three static models of friction T over speed v = |velocity| (mm/min), all in
the sense of one direction so that friction is a positive magnitude:

- linear (Coulomb + viscous), linear least squares
  (:func:`~ncmeasure.analysis.friction.linear.fit_linear`)::

      T(v) = T_C + t_v·v

- Stribeck, nonlinear least squares
  (:func:`~ncmeasure.analysis.friction.stribeck.fit_nonlinear`)::

      T(v) = T_C + (T_S − T_C)·exp(−(v/v_S)^δ) + b·v

- extended Stribeck, with the rolling term of ball screws with many loaded
  balls (``f_w < 0`` bends the curve down at high speed)::

      T(v) = T_C + (T_S − T_C)·exp(−(v/v_S)^δ) + b·v + f_w·(v / 1000 mm/min)^k

:func:`fit_direction` fits them to one direction's points and names the
simplest that describes the curve; :func:`separate_offset` takes the
direction-independent part (gravity) from both directions. How σ, the χ² test
and the identifiability rule are defined is written out in
``docs/analysis-models.md`` and in the docstrings. Nothing here raises on bad
data: a fit that cannot be made returns ``None``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.friction.linear import fit_linear
from ncmeasure.analysis.friction.stribeck import (
    EXTENDED_PARAMETERS,
    STRIBECK_PARAMETERS,
    fit_nonlinear,
)
from ncmeasure.formats.results import (
    DirectionResult,
    LinearFit,
    ModelName,
    NonlinearFit,
    OffsetResult,
    Point,
)

__all__ = [
    "LINEAR_REGION_DECAY",
    "MEDIAN_SE_FACTOR",
    "MIN_LINEAR_POINTS",
    "MIN_LINEAR_POINTS_ABOVE_STRIBECK",
    "SPEED_MATCH_TOLERANCE",
    "fit_direction",
    "point_sigma",
    "separate_offset",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

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
    # The F distribution's sf, without scipy.stats' import; here: importing the fits
    # costs nothing until one runs.
    from scipy.special import fdtrc

    return bool(fdtrc(extra, dof, max(statistic, 0.0)) < 0.01)


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
        coulomb_measured=(
            None if linear is None or linear.coulomb is None else linear.coulomb + direction * shift
        ),
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
