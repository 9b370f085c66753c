"""Position dependency of friction along the travel and the assembly causes it points at.

Input is a table of friction magnitudes, one row per *matched group* (one
velocity, measured in one and the same direction, or as the half difference of
both, at every position of the row) and one column per measuring position. The
table is reduced to one *relative profile* (friction at each position divided
by the mean over the positions, the same for every group) by a least-squares
fit of

    ln T[j, k] = α_j + β_k

(α_j: the level of group j, β_k: the effect of position k). Working in
logarithms normalises every velocity by its own level, so high and low
speeds weigh alike, and missing cells need no special case.

Only groups with two positions or more say anything about position: a group
with one position is absorbed by its own α_j. Positions are compared only
through such groups (the positions linked by them; where they fall apart into
separate sets, the largest set is judged). Where no group holds two positions,
e.g. a trapezoid program that runs every speed on its own part of the travel,
position effects cannot be told from the speed (and direction) dependence: the
result is ``not_identifiable`` and names no cause.

What counts as a spread beyond noise comes from the table itself: the
residuals of every group are permuted among that group's positions
(:data:`PERMUTATIONS`, seeded), which keeps the layout and the noise and holds
no position effect; a pattern needs a spread above all but
:data:`SIGNIFICANCE_LEVEL` of the permuted tables' spreads, besides the F or χ²
test. The shape of the profile is then classified into a
:data:`~ncmeasure.formats.results.Signature` and mapped to ranked causes
following method.md, "What the patterns mean". The rules and the scores are
written out in ``docs/analysis-models.md``.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ncmeasure.formats.results import (
    Cause,
    CauseName,
    PositionDependency,
    Signature,
    VelocityProfile,
)

__all__ = [
    "ALTERNATIVE_FACTOR",
    "BEARING_STEP_FACTOR",
    "END_RISE_FRACTION",
    "FLAT_THRESHOLD_PERCENT",
    "FULL_STRENGTH_PERCENT",
    "MONOTONE_TOLERANCE_FRACTION",
    "NOT_IDENTIFIABLE_TEXT",
    "PERMUTATIONS",
    "SIGNIFICANCE_LEVEL",
    "STEP_RATIO",
    "position_dependency",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

FLAT_THRESHOLD_PERCENT = 5.0
"""A spread of the averaged profile below this is flat, however significant.

Well below the position effects the method reports (~40 % along one axis, a
~20 % step from a sticking cover) and above the few-percent repeatability of
runs 20 min apart.
"""

SIGNIFICANCE_LEVEL = 0.01
"""A position effect must also be significant at this level (F or χ² test)."""

PERMUTATIONS = 199
"""Permutations of the values within the matched groups for the table's own null
(p = (1 + exceeding) / (1 + 199) reaches 0.005, below :data:`SIGNIFICANCE_LEVEL`)."""

_PERMUTATION_SEED = 20_260_101
"""The permutations are seeded: the same table always gets the same verdict."""

NOT_IDENTIFIABLE_TEXT = (
    "each speed was measured at its own positions: the pattern along the travel cannot be "
    "told from the speed dependence"
)
"""Why no position dependency is judged where no group holds two positions."""

STEP_RATIO = 3.0
"""A step is one jump between adjacent positions at least this many times every other jump."""

END_RISE_FRACTION = 1.0 / 3.0
"""High at both ends: each end exceeds the interior minimum by this fraction of the spread."""

MONOTONE_TOLERANCE_FRACTION = 0.15
"""A rising profile may step back by this fraction of the spread (or 2 standard errors)."""

FULL_STRENGTH_PERCENT = 20.0
"""A spread this large (the cover step of method.md) gives a pattern its full weight."""

ALTERNATIVE_FACTOR = 0.5
"""An alternative cause scores this fraction of the leading cause."""

BEARING_STEP_FACTOR = 0.6
"""A step in the last interval before a bearing, rising towards it: that bearing's score factor."""


@dataclass(frozen=True)
class _Profile:
    """The averaged relative profile and what the statistics say about it."""

    positions_mm: FloatArray  # ascending
    numbers: list[int]  # the measuring-position number of each
    relative: FloatArray  # mean 1
    level: float  # mean fitted friction over the grid
    cov_log: FloatArray | None  # covariance of the centred log profile, or None
    p_value: float | None  # position effect test; None when untestable
    velocities_used: int
    null_spread: float | None  # the spread of the table's own null (permutations), or None
    p_permutation: float | None  # share of permuted tables with at least the spread
    left_out: list[int]  # numbers of positions with data outside the compared set


def _as_table(values: ArrayLike, n_velocities: int, n_positions: int, name: str) -> FloatArray:
    table = np.asarray(values, dtype=np.float64)
    if table.ndim == 1 and n_velocities == 1:
        table = table[None, :]
    if table.shape != (n_velocities, n_positions):
        raise ValueError(
            f"{name} has shape {table.shape}, expected (n_velocities, n_positions) = "
            f"({n_velocities}, {n_positions})"
        )
    return table


def _compared_positions(usable: NDArray[np.bool_]) -> tuple[IntArray, IntArray]:
    """The rows and columns judged: the largest set of positions linked by groups of 2+.

    Two positions are linked when one group (row) holds both; position effects
    are estimable between linked positions only. Returns the rows with 2
    positions or more within the set, and the set's columns (ascending).
    """
    rows = np.flatnonzero(np.count_nonzero(usable, axis=1) >= 2)
    parent = list(range(usable.shape[1]))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for j in rows:
        first, *others = np.flatnonzero(usable[j]).tolist()
        for k in others:
            parent[root(k)] = root(first)
    linked = np.any(usable[rows], axis=0)
    roots = np.array([root(k) for k in range(usable.shape[1])])
    if not linked.any():
        return rows[:0], np.flatnonzero(linked)
    sizes = np.bincount(roots[linked], minlength=usable.shape[1])
    cols = np.flatnonzero(linked & (roots == int(np.argmax(sizes))))
    keep = rows[np.any(usable[np.ix_(rows, cols)], axis=1)]
    return keep, cols


def _permuted_spreads(
    y: FloatArray, jj: IntArray, projector: FloatArray, n_v: int, n_p: int
) -> FloatArray | None:
    """The profile's spread with every group's residuals permuted among its positions.

    ``y`` are the residuals of the fit (what the group levels and the position
    effects leave), cell by cell with ``jj`` (each cell's group) ascending; a
    permutation within each group keeps the layout, the weights and the noise,
    and holds no position effect (residuals, not the values: permuted values
    would carry a strong position effect into the null and widen it). ``projector``
    maps values to the coefficients. None where no permutation changes the spread
    (a single group: permuting its positions only reorders the profile).
    """
    if n_v < 2:
        return None
    rng = np.random.default_rng(_PERMUTATION_SEED)
    permuted = np.empty((y.size, PERMUTATIONS))
    # jj ascends (np.nonzero's order): each group's cells are one slice, permuted in place
    bounds = np.searchsorted(jj, np.arange(n_v + 1)).tolist()
    for lo, hi in itertools.pairwise(bounds):
        block = permuted[lo:hi]
        block[:] = y[lo:hi, None]
        rng.permuted(block, axis=0, out=block)
    beta = np.zeros((n_p, PERMUTATIONS))
    beta[1:] = (projector @ permuted)[n_v:]
    shape = np.exp(beta - beta.mean(axis=0))
    return np.asarray((shape.max(axis=0) - shape.min(axis=0)) / shape.mean(axis=0))


def _at_least_zero(statistic: float) -> float:
    """A test statistic below 0 (rounding) as 0: its sf is 1 there, as scipy.stats gives it."""
    return 0.0 if statistic < 0 else statistic


def _fit_profile(
    positions: FloatArray, numbers: Sequence[int], table: FloatArray, noise: FloatArray | None
) -> _Profile | None:
    """Fit ln T = α_j + β_k over the compared cells; None with fewer than 2 compared positions."""
    usable = np.isfinite(table) & (table > 0)
    # Rows need 2 positions to say anything about position; a column dropped
    # here has no value in those rows, so the row counts stay as they are.
    rows, cols = _compared_positions(usable)
    with_data = np.flatnonzero(np.any(usable, axis=0))
    left_out = [int(numbers[int(k)]) for k in with_data if k not in set(cols.tolist())]
    valid = usable[np.ix_(rows, cols)]
    n_v, n_p = rows.size, cols.size
    if n_v == 0 or n_p < 2:
        return None
    sub = table[np.ix_(rows, cols)]
    jj, kk = np.nonzero(valid)
    y = np.log(sub[jj, kk])
    if noise is not None:
        rel_noise = noise[np.ix_(rows, cols)][jj, kk] / sub[jj, kk]
        ok = np.isfinite(rel_noise) & (rel_noise > 0)
        typical = float(np.median(rel_noise[ok])) if np.any(ok) else math.nan
        if not math.isfinite(typical):
            noise = None
            weight = np.ones_like(y)
        else:
            # No cell counts as more precise than the table's typical one: the fastest
            # cells have the smallest relative error, but viscous friction dilutes a
            # position effect there (a fault adds the same torque at every speed), so
            # (T/σ)² weights would let 12,000 mm/min decide the profile.
            rel_noise = np.maximum(np.where(ok, rel_noise, typical), typical)
            weight = 1.0 / rel_noise**2
    else:
        weight = np.ones_like(y)
    design = np.zeros((y.size, n_v + n_p - 1))
    design[np.arange(y.size), jj] = 1.0
    has_pos = kk > 0
    design[np.flatnonzero(has_pos), n_v + kk[has_pos] - 1] = 1.0
    root_w = np.sqrt(weight)
    # One pseudo-inverse serves the fit and every permutation of the null.
    projector: FloatArray = np.asarray(
        np.linalg.pinv(design * root_w[:, None]) * root_w[None, :], dtype=np.float64
    )
    coef = projector @ y
    residual = y - design @ coef
    rss1 = float(np.sum(weight * residual**2))
    dof = y.size - (n_v + n_p - 1)
    # Velocity-only model: each row's weighted mean.
    row_mean = np.bincount(jj, weights=weight * y, minlength=n_v) / np.bincount(
        jj, weights=weight, minlength=n_v
    )
    rss0 = float(np.sum(weight * (y - row_mean[jj]) ** 2))
    delta = max(rss0 - rss1, 0.0)
    q = n_p - 1

    observed = rss1 / dof if dof > 0 else None
    scale2: float | None
    p_value: float | None
    # The χ² and F distributions' sf (scipy.stats' chi2.sf and f.sf, without its import).
    from scipy.special import chdtrc, fdtrc

    if noise is not None:
        # The stated noise, inflated when the cells scatter more than it says.
        scale2 = max(1.0, observed or 0.0)
        p_value = float(chdtrc(q, _at_least_zero(delta / scale2)))
    elif observed is not None and observed > 0:
        scale2 = observed
        p_value = float(fdtrc(q, dof, _at_least_zero(delta / q / observed)))
    elif observed is not None:  # an exact fit: any position effect is real
        scale2 = 0.0
        p_value = 0.0 if delta > 0 else 1.0
    else:
        scale2, p_value = None, None

    beta = np.concatenate([[0.0], coef[n_v:]])
    alpha = coef[:n_v]
    cov_log: FloatArray | None = None
    if scale2 is not None:
        info = (design * weight[:, None]).T @ design
        cov_full = np.linalg.pinv(info) * scale2
        cov_beta = np.zeros((n_p, n_p))
        cov_beta[1:, 1:] = cov_full[n_v:, n_v:]
        centre = np.eye(n_p) - 1.0 / n_p
        cov_log = centre @ cov_beta @ centre.T
    shape = np.exp(beta - beta.mean())
    relative = shape / shape.mean()
    level = float(np.mean(np.exp(alpha[:, None] + beta[None, :])))
    spread = float((relative.max() - relative.min()) / relative.mean())
    null = _permuted_spreads(residual, jj, projector, n_v, n_p)
    null_spread = p_permutation = None
    if null is not None:
        null_spread = float(np.quantile(null, 1.0 - SIGNIFICANCE_LEVEL))
        # A hair of tolerance: a permutation that reproduces the table is no larger.
        exceeding = int(np.count_nonzero(null >= spread * (1.0 - 1e-9)))
        p_permutation = (1 + exceeding) / (1 + PERMUTATIONS)
    return _Profile(
        positions_mm=positions[cols],
        numbers=[int(numbers[int(c)]) for c in cols],
        relative=relative,
        level=level,
        cov_log=cov_log,
        p_value=p_value,
        velocities_used=n_v,
        null_spread=null_spread,
        p_permutation=p_permutation,
        left_out=left_out,
    )


def _profiles(
    positions: FloatArray, numbers: Sequence[int], velocities: FloatArray, table: FloatArray
) -> list[VelocityProfile]:
    out = []
    for j, velocity in enumerate(velocities):
        ok = np.isfinite(table[j]) & (table[j] > 0)
        if np.count_nonzero(ok) < 2:
            continue
        vals = table[j, ok]
        out.append(
            VelocityProfile(
                velocity_mm_min=float(velocity),
                positions_mm=[float(x) for x in positions[ok]],
                position_numbers=[int(n) for n, keep in zip(numbers, ok, strict=True) if keep],
                values=[float(x) for x in vals],
                spread_percent=float((vals.max() - vals.min()) / vals.mean() * 100.0),
            )
        )
    return out


def _explained(profile: FloatArray, basis: FloatArray) -> float:
    """Fraction of the profile's variation a constant + ``basis`` explains (0..1)."""
    centred = profile - profile.mean()
    total = float(centred @ centred)
    if total <= 0:
        return 1.0
    design = np.column_stack([np.ones_like(profile), basis])
    coef, *_ = np.linalg.lstsq(design, profile, rcond=None)
    residual = profile - design @ coef
    return float(np.clip(1.0 - (residual @ residual) / total, 0.0, 1.0))


def _best_step(q: FloatArray) -> tuple[int, float]:
    """Interval index and explained fraction of the best single-step template."""
    best = (0, -1.0)
    for i in range(q.size - 1):
        step = (np.arange(q.size) > i).astype(np.float64)
        score = _explained(q, step)
        if score > best[1]:
            best = (i, score)
    return best


def _pair_se(cov: FloatArray | None, i: int, j: int) -> float:
    if cov is None:
        return 0.0
    return math.sqrt(max(float(cov[i, i] + cov[j, j] - 2.0 * cov[i, j]), 0.0))


def _ratio_pct(reference: float, value: float) -> float:
    """Change from ``reference`` to ``value`` in % of ``reference``."""
    return (value / reference - 1.0) * 100.0


def _cause(name: CauseName, score: float, evidence: str) -> Cause:
    return Cause(cause=name, score=round(float(np.clip(score, 0.0, 1.0)), 3), evidence=evidence)


def position_dependency(
    positions_mm: Sequence[float],
    velocities_mm_min: Sequence[float],
    values: ArrayLike,
    *,
    travel_mm: tuple[float, float],
    fixed_bearing_end: Literal["min", "max"],
    noise: ArrayLike | None = None,
    numbers: Sequence[int] | None = None,
    flat_threshold_percent: float = FLAT_THRESHOLD_PERCENT,
    velocity_profiles: bool = True,
) -> PositionDependency:
    """Describe how friction changes along the travel and rank the likely causes.

    Args:
        positions_mm: Measuring positions (any order).
        velocities_mm_min: Velocity of each row of ``values`` (reported only).
        values: Friction magnitudes, shape (n_velocities, n_positions); NaN
            where missing. Non-positive values count as missing.
        travel_mm: Soft limits (min, max) of the axis, for the evidence texts.
        fixed_bearing_end: Which end of the travel carries the fixed bearing;
            the loose bearing is at the other end.
        noise: Standard error of each value, same shape, or None. With it
            the significance test uses the stated noise (or the observed
            scatter when that is larger); without it only the observed
            scatter between velocities.
        numbers: The number of each measuring position as the report shows it
            (1 = the lowest scheduled position); default 1, 2, ... in
            ascending order. Evidence names positions as "position 2 (375 mm)".
        flat_threshold_percent: A spread below this is flat, however significant:
            :data:`FLAT_THRESHOLD_PERCENT` for one measurement (a healthy axis' own
            profile), less for the change between two measurements of one axis
            (:data:`~ncmeasure.analysis.judgement.compare.CHANGE_FLAT_PERCENT`), where
            the machine's own profile divides out.
        velocity_profiles: Also the profile of each velocity (False: the average alone, for
            a caller that reads no more; the rest is the same).

    Returns:
        Profiles (the average first, ``velocity_mm_min`` None, then one per
        velocity with at least 2 positions), the spread and trend of the
        average, the signature and the causes, best first.

    Raises:
        ValueError: ``values`` or ``noise`` do not have the shape
            (len(velocities_mm_min), len(positions_mm)).
    """
    positions = np.asarray(positions_mm, dtype=np.float64).ravel()
    velocities = np.asarray(velocities_mm_min, dtype=np.float64).ravel()
    table = _as_table(values, velocities.size, positions.size, "values")
    noise_table = (
        None if noise is None else _as_table(noise, velocities.size, positions.size, "noise")
    )
    order = np.argsort(positions, kind="stable")
    positions, table = positions[order], table[:, order]
    if noise_table is not None:
        noise_table = noise_table[:, order]
    if numbers is None:
        labels = list(range(1, positions.size + 1))
    else:
        if len(numbers) != positions.size:
            raise ValueError(f"numbers has {len(numbers)} entries for {positions.size} positions")
        labels = [int(numbers[i]) for i in order]

    profiles = _profiles(positions, labels, velocities, table) if velocity_profiles else []
    fit = _fit_profile(positions, labels, table, noise_table)
    usable = np.isfinite(table) & (table > 0)
    if fit is None and np.count_nonzero(np.any(usable, axis=0)) >= 2:
        return _not_identifiable(labels, usable)
    if fit is None:
        return PositionDependency(
            spread_percent=0.0,
            trend_per_100mm=0.0,
            signature="insufficient_data",
            profiles=profiles,
            causes=[
                _cause(
                    "none",
                    0.0,
                    "Fewer than 2 measuring positions with friction at a common velocity: "
                    "no position dependency can be judged.",
                )
            ],
        )

    x, rel = fit.positions_mm, fit.relative
    spread = float((rel.max() - rel.min()) / rel.mean())
    slope = float(np.polyfit(x, rel, 1)[0]) if np.ptp(x) > 0 else 0.0
    average = VelocityProfile(
        velocity_mm_min=None,
        positions_mm=[float(p) for p in x],
        position_numbers=list(fit.numbers),
        values=[float(r * fit.level) for r in rel],
        spread_percent=spread * 100.0,
    )
    signature, causes = _diagnose(fit, spread, travel_mm, fixed_bearing_end, flat_threshold_percent)
    if fit.left_out:
        listed = ", ".join(str(n) for n in fit.left_out)
        lead = causes[0].evidence + (
            f" Position(s) {listed} share no speed and direction with these and are not compared."
        )
        causes = [causes[0].model_copy(update={"evidence": lead}), *causes[1:]]
    return PositionDependency(
        spread_percent=spread * 100.0,
        trend_per_100mm=slope * 100.0 * 100.0,
        signature=signature,
        profiles=[average, *profiles],
        causes=causes,
        compared_groups=fit.velocities_used,
        noise_spread_percent=None if fit.null_spread is None else fit.null_spread * 100.0,
    )


def _not_identifiable(labels: Sequence[int], usable: NDArray[np.bool_]) -> PositionDependency:
    """Positions with data, but no group holding two of them: nothing to compare."""
    groups = int(np.count_nonzero(np.any(usable, axis=1)))
    with_data = int(np.count_nonzero(np.any(usable, axis=0)))
    return PositionDependency(
        spread_percent=0.0,
        trend_per_100mm=0.0,
        signature="not_identifiable",
        profiles=[],
        causes=[
            _cause(
                "none",
                0.0,
                f"{NOT_IDENTIFIABLE_TEXT[0].upper()}{NOT_IDENTIFIABLE_TEXT[1:]} ({with_data} "
                f"positions, {groups} groups of one speed and direction, none of them at two "
                "positions or more). Measure every speed at the same positions, in both "
                "directions, to judge the travel.",
            )
        ],
        identifiable=False,
        compared_groups=0,
    )


@dataclass(frozen=True)
class _Oriented:
    """The averaged profile from the fixed-bearing end (0) to the loose-bearing end (n − 1)."""

    fit: _Profile
    q: FloatArray  # relative friction
    x: FloatArray  # positions, mm
    numbers: list[int]
    cov: FloatArray | None  # covariance of the log profile
    t: FloatArray  # 0 at the fixed-bearing end of the travel, 1 at the loose one
    flip: bool  # the fixed bearing is at the max end
    spread: float
    p_text: str  # ", p = ..." or ""

    @property
    def n(self) -> int:
        return int(self.q.size)

    @property
    def spread_pct(self) -> float:
        return self.spread * 100.0

    @property
    def strength(self) -> float:
        return min(1.0, self.spread_pct / FULL_STRENGTH_PERCENT)

    def at(self, i: int) -> str:
        return f"position {self.numbers[i]} ({self.x[i]:.0f} mm)"


def _oriented(
    fit: _Profile,
    spread: float,
    travel_mm: tuple[float, float],
    fixed_bearing_end: Literal["min", "max"],
) -> _Oriented:
    # Orient from the fixed-bearing end to the loose-bearing end.
    flip = fixed_bearing_end == "max"
    q = fit.relative[::-1] if flip else fit.relative
    x = fit.positions_mm[::-1] if flip else fit.positions_mm
    numbers = fit.numbers[::-1] if flip else fit.numbers
    cov = None if fit.cov_log is None else (fit.cov_log[::-1, ::-1] if flip else fit.cov_log)
    low_end, high_end = travel_mm
    length = (high_end - low_end) or 1.0
    t = np.abs(x - (high_end if flip else low_end)) / abs(length)  # 0 fixed end, 1 loose end
    if fit.p_value is None:
        p_text = ""
    elif fit.p_value < 1e-6:
        p_text = ", p < 1e-6"
    else:
        p_text = f", p = {fit.p_value:.2g}"
    return _Oriented(fit, q, x, numbers, cov, t, flip, spread, p_text)


Diagnosis = tuple[Signature, list[Cause]]


def _diagnose(
    fit: _Profile,
    spread: float,
    travel_mm: tuple[float, float],
    fixed_bearing_end: Literal["min", "max"],
    flat_threshold_percent: float = FLAT_THRESHOLD_PERCENT,
) -> Diagnosis:
    """Signature and ranked causes of the averaged relative profile.

    The patterns are tried in order: flat (or not significant), high at both
    ends, a step, a rise towards one bearing; what fits none is irregular.
    """
    n = fit.relative.size
    spread_pct = spread * 100.0
    if n < 3:
        return "insufficient_data", [
            _cause(
                "none",
                0.0,
                f"Only {n} measuring positions with data (spread {spread_pct:.1f} %): "
                "the pattern along the travel needs at least 3 (fixed-bearing end, middle, "
                "loose-bearing end).",
            )
        ]
    o = _oriented(fit, spread, travel_mm, fixed_bearing_end)
    significant = (fit.p_value is None or fit.p_value < SIGNIFICANCE_LEVEL) and (
        fit.p_permutation is None or fit.p_permutation < SIGNIFICANCE_LEVEL
    )
    if spread_pct < flat_threshold_percent or not significant:
        return _flat(o, flat_threshold_percent)
    return _both_ends(o) or _step(o) or _rising(o) or _irregular(o)


def _flat(o: _Oriented, threshold_percent: float) -> Diagnosis:
    """No position effect beyond the threshold or the noise."""
    n, spread_pct = o.n, o.spread_pct
    if spread_pct < threshold_percent:
        why = f"below the {threshold_percent:g} % threshold"
        score = 0.9 - 0.4 * spread_pct / threshold_percent
    elif o.fit.null_spread is not None and spread_pct <= o.fit.null_spread * 100.0:
        why = (
            f"within the noise (the same layout shows up to {o.fit.null_spread * 100.0:.1f} % "
            "without a position effect)"
        )
        score = 0.5
    else:
        why = "within the noise between velocities"
        score = 0.5
    return "flat", [
        _cause(
            "none",
            score,
            f"Friction varies by {spread_pct:.1f} % over {n} positions "
            f"({o.at(0)} to {o.at(n - 1)}), {why}{o.p_text}: no local assembly fault shows.",
        ),
        _cause(
            "preload_or_carriage",
            0.1,
            "Preload of bearings or nut and a shifted or tilted guide carriage raise "
            "friction at every position alike; only a comparison against a reference "
            "(the same machine earlier, or identical machines) can show them.",
        ),
    ]


def _both_ends(o: _Oriented) -> Diagnosis | None:
    """Lowest mid-travel and higher at both ends: the ball-screw nut."""
    q, n, cov, spread = o.q, o.n, o.cov, o.spread
    k_min = int(np.argmin(q))
    rise_fixed, rise_loose = q[0] - q[k_min], q[-1] - q[k_min]
    end_se = (_pair_se(cov, 0, k_min), _pair_se(cov, n - 1, k_min))
    if not (
        0 < k_min < n - 1
        and min(rise_fixed, rise_loose) >= END_RISE_FRACTION * spread
        and rise_fixed > 2 * end_se[0]
        and rise_loose > 2 * end_se[1]
    ):
        return None
    explained = _explained(q, np.column_stack([o.t, (2 * o.t - 1) ** 2]))
    lead = 0.3 + 0.6 * explained * o.strength
    return "high_at_both_ends", [
        _cause(
            "screw_nut",
            lead,
            f"Friction is lowest mid-travel at {o.at(k_min)} and higher by "
            f"{_ratio_pct(q[k_min], q[0]):.1f} % next to the fixed bearing ({o.at(0)}) and "
            f"by {_ratio_pct(q[k_min], q[-1]):.1f} % next to the loose bearing "
            f"({o.at(n - 1)}) "
            f"(spread {o.spread_pct:.1f} %{o.p_text}): a shifted or tilted ball-screw nut "
            "bends the screw most where it runs close to a bearing.",
        ),
        _cause(
            "guide_rail",
            ALTERNATIVE_FACTOR * lead,
            "A misaligned guide rail can give any shape along the travel, this one included.",
        ),
    ]


def _jumps(o: _Oriented) -> tuple[FloatArray, FloatArray]:
    """The jumps between adjacent positions and their standard errors."""
    d = np.diff(o.q)
    jump_se = np.array([_pair_se(o.cov, i, i + 1) for i in range(o.n - 1)])
    return d, jump_se


def _step(o: _Oriented) -> Diagnosis | None:
    """One jump between adjacent positions, every other one small: a cover or seal."""
    q, n, flip = o.q, o.n, o.flip
    d, jump_se = _jumps(o)
    big = int(np.argmax(np.abs(d)))
    others = np.delete(np.abs(d), big)
    if not (np.all(np.abs(d[big]) >= STEP_RATIO * others) and abs(d[big]) > 2 * jump_se[big]):
        return None
    explained = _best_step(q)[1]
    if _bearing_rise(o, big, d) >= explained:
        return None  # a convex rise towards the bearing at that end, not a step
    lead = 0.3 + 0.6 * explained * o.strength
    ratio = abs(d[big]) / others.max() if others.size and others.max() > 0 else math.inf
    # Name the two positions in ascending order along the travel.
    lo_side, hi_side = (big + 1, big) if flip else (big, big + 1)
    ratio_text = (
        "all other jumps are negligible (below 0.1 % of it)"
        if ratio >= 1000.0
        else (f"{ratio:.1f} times the next largest jump")
    )
    causes = [
        _cause(
            "cover_or_seal",
            lead,
            f"Friction changes by {_ratio_pct(q[lo_side], q[hi_side]):+.1f} % from "
            f"{o.at(lo_side)} to {o.at(hi_side)}, {ratio_text} (spread "
            f"{o.spread_pct:.1f} %{o.p_text}): a sticking "
            "or misaligned telescopic cover, wiper seal or cable chain acts from where "
            "it engages (method: a ~20 % step).",
        ),
        _cause(
            "guide_rail",
            ALTERNATIVE_FACTOR * lead,
            "A guide rail joint or a local rail deviation can also change friction "
            f"between {o.at(big)} and {o.at(big + 1)}.",
        ),
    ]
    if big == n - 2 and d[big] > 0:
        causes.insert(
            1,
            _cause(
                "loose_bearing",
                BEARING_STEP_FACTOR * lead,
                f"The jump lies next to the loose bearing ({o.at(n - 1)}) and rises towards "
                "it: a shifted loose bearing acts most where the nut comes close.",
            ),
        )
    elif big == 0 and d[big] < 0:
        causes.insert(
            1,
            _cause(
                "fixed_bearing",
                BEARING_STEP_FACTOR * lead,
                f"The jump lies next to the fixed bearing ({o.at(0)}) and rises towards it: "
                "a shifted fixed bearing acts most where the nut comes close.",
            ),
        )
    return "step", causes


def _bearing_rise(o: _Oriented, big: int, d: FloatArray) -> float:
    """How much of the profile a rise towards the bearing next to the largest jump explains.

    A shifted bearing's force grows faster the closer the nut comes (the span to the
    bearing shortens with its cube), so its profile is convex: small rises far from
    it, the largest in the last interval, every jump rising. Such a profile passes
    the step rule once the last jump is three times the others; it is a bearing
    when every jump rises towards it and a power of the distance (t, t², t³)
    explains it at least as well as a step. 0 where the jump is not at an end
    rising towards its bearing, and with fewer than 4 positions.
    """
    n = o.n
    if n < 4:
        return 0.0  # three points fit a step as well as any power: a step stays a step
    if big == n - 2 and d[big] > 0 and np.all(d > 0):
        t = o.t
    elif big == 0 and d[big] < 0 and np.all(d < 0):
        t = 1.0 - o.t
    else:
        return 0.0
    span = float(np.ptp(t)) or 1.0
    u = (t - t.min()) / span
    return max(_explained(o.q, u**power) for power in (1, 2, 3))


def _rising(o: _Oriented) -> Diagnosis | None:
    """A rise, monotone within the tolerance, towards one bearing: that bearing."""
    q, n, spread = o.q, o.n, o.spread
    d, jump_se = _jumps(o)
    rise = q[-1] - q[0]
    sense = 1.0 if rise > 0 else -1.0
    tolerance = np.maximum(MONOTONE_TOLERANCE_FRACTION * spread, 2 * jump_se)
    if not (abs(rise) >= 0.5 * spread and np.all(sense * d >= -tolerance)):
        return None
    explained = _explained(q, o.t)
    lead = 0.3 + 0.6 * explained * o.strength
    shape = "nearly linearly" if explained >= 0.9 else "monotonically"
    if sense > 0:
        near, far, bearing = 0, n - 1, "loose"
        name: CauseName = "loose_bearing"
        signature: Signature = "rising_to_loose_bearing"
    else:
        near, far, bearing = n - 1, 0, "fixed"
        name = "fixed_bearing"
        signature = "rising_to_fixed_bearing"
    other = "fixed" if bearing == "loose" else "loose"
    return signature, [
        _cause(
            name,
            lead,
            f"Friction rises {shape} by {_ratio_pct(q[near], q[far]):.1f} % from {o.at(near)} "
            f"({other}-bearing end) to {o.at(far)} ({bearing}-bearing end); a straight line "
            f"explains {explained * 100:.0f} % of the variation{o.p_text}. A shifted or "
            f"tilted {bearing} bearing bends the screw, more the closer the nut runs "
            "to it (test rig: no change next to the other bearing, a nearly linear rise "
            "towards the shifted one).",
        ),
        _cause(
            "guide_rail",
            ALTERNATIVE_FACTOR * lead,
            "A guide rail misaligned along the travel gives a ramp as well.",
        ),
    ]


def _irregular(o: _Oriented) -> Diagnosis:
    """No bearing, nut or step pattern: a guide rail follows its own deviation."""
    fit = o.fit
    lead = 0.2 + 0.3 * o.strength
    return "irregular", [
        _cause(
            "guide_rail",
            lead,
            f"Friction varies by {o.spread_pct:.1f} % over {o.n} positions without a bearing, "
            "nut or step pattern (relative to the mean: "
            + ", ".join(
                f"{number}: {pos:.0f} mm {val:.2f}"
                for number, pos, val in zip(
                    fit.numbers, fit.positions_mm, fit.relative, strict=True
                )
            )
            + f"{o.p_text}): a misaligned guide rail follows its own deviation.",
        ),
        _cause(
            "cover_or_seal",
            ALTERNATIVE_FACTOR * lead,
            "Covers, seals or the cable chain can add friction over parts of the travel.",
        ),
    ]
