"""The bounded least-squares solver against scipy's ``least_squares`` on the same problems."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize

import ncmeasure.analysis.friction.stribeck as stribeck
from ncmeasure.analysis.friction.solver import bounded_least_squares

SPEEDS = np.geomspace(10.0, 15000.0, 50)


def _curve(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A noisy Stribeck curve with a rolling term, parameters drawn at random."""
    tc, hump = rng.uniform(0.2, 3.0), rng.uniform(0.0, 1.5)
    vs, delta = 10 ** rng.uniform(0.5, 3.5), rng.uniform(0.4, 2.5)
    b, fw, k = 10 ** rng.uniform(-6.0, -3.5), rng.uniform(-0.5, 0.5), rng.uniform(0.4, 1.9)
    value = tc + hump * np.exp(-((SPEEDS / vs) ** delta)) + b * SPEEDS + fw * (SPEEDS / 1e3) ** k
    noise = rng.uniform(0.001, 0.05)
    return value + rng.normal(0.0, noise, SPEEDS.size), np.full(SPEEDS.size, noise)


@pytest.mark.parametrize("extended", [False, True])
@pytest.mark.parametrize("seed", range(12))
def test_the_minimum_of_least_squares_from_the_same_start(seed: int, extended: bool) -> None:
    """From each start of a fit: a cost no higher than trf's, and a solution inside the box."""
    rng = np.random.default_rng(seed)
    value, sigma = _curve(rng)
    p = stribeck._Problem(
        u=SPEEDS / SPEEDS.max(), y=value / np.median(value), s=sigma / np.median(value),
        v_ref=float(SPEEDS.max()), t_ref=float(np.median(value)), extended=extended,
    )  # fmt: skip
    lower, upper = stribeck._bounds(p)

    def residual(x: np.ndarray) -> np.ndarray:
        return (stribeck._model_internal(x, p)[0] - p.y) / p.s

    def jacobian(x: np.ndarray) -> np.ndarray:
        return stribeck._model_internal(x, p)[1] / p.s[:, None]

    same_valley = 0
    for x0 in stribeck._starts(p):
        x0 = np.clip(x0, np.add(lower, 1e-9), np.subtract(upper, 1e-9))
        with np.errstate(all="ignore"):
            theirs = optimize.least_squares(
                residual, x0, jac=jacobian, bounds=(lower, upper), method="trf", x_scale="jac"
            )
            mine = bounded_least_squares(residual, jacobian, x0, lower, upper)
        if theirs.status == 0:
            # A crawl along the valley in which b and f_w trade off as k → 1 (the
            # reason the fit also solves the projected problem): ours gets no less far.
            assert mine.cost <= theirs.cost * (1 + 1e-6)
            continue
        assert mine.status > 0
        assert np.all(mine.x >= lower) and np.all(mine.x <= upper)
        assert mine.cost == pytest.approx(float(residual(mine.x) @ residual(mine.x)) / 2)
        # A local search may end in another valley than trf's; where both end in the
        # same one, the cost agrees to the tolerance, and it is never much higher.
        if np.allclose(mine.x, theirs.x, rtol=1e-2, atol=1e-3):
            assert mine.cost == pytest.approx(theirs.cost, rel=1e-6)
            same_valley += 1
    assert same_valley >= 1


def test_a_bound_that_holds_the_solution_is_reported_as_trf_reports_it() -> None:
    """A line whose slope the box holds above its free value ends on the bound, mask −1 as trf's."""
    x = np.linspace(0.0, 1.0, 20)
    y = 2.0 + 0.5 * x  # the free slope is 0.5, below the box [1, 5]
    design = np.column_stack([np.ones_like(x), x])

    def residual(p: np.ndarray) -> np.ndarray:
        return design @ p - y

    def jacobian(p: np.ndarray) -> np.ndarray:
        return design

    lower, upper = [-np.inf, 1.0], [np.inf, 5.0]
    mine = bounded_least_squares(residual, jacobian, np.array([0.0, 3.0]), lower, upper)
    theirs = optimize.least_squares(
        residual, [0.0, 3.0], jac=jacobian, bounds=(lower, upper), method="trf"
    )
    assert mine.status > 0
    assert mine.x[1] == 1.0
    assert list(mine.active_mask) == list(theirs.active_mask) == [0, -1]
    # On the bound, the intercept is the best for that slope: the mean of y − x.
    assert mine.x[0] == pytest.approx(float(np.mean(y - x)), rel=1e-9)


def test_rosenbrock_from_the_textbook_start() -> None:
    """The banana valley: converges to (1, 1), and stops with status 0 when evaluations run out."""

    def residual(p: np.ndarray) -> np.ndarray:
        return np.array([10.0 * (p[1] - p[0] ** 2), 1.0 - p[0]])

    def jacobian(p: np.ndarray) -> np.ndarray:
        return np.array([[-20.0 * p[0], 10.0], [-1.0, 0.0]])

    start = np.array([-1.2, 1.0])
    free = ([-np.inf, -np.inf], [np.inf, np.inf])
    solved = bounded_least_squares(residual, jacobian, start, *free)
    assert solved.status > 0
    np.testing.assert_allclose(solved.x, [1.0, 1.0], atol=1e-6)
    cut = bounded_least_squares(residual, jacobian, start, *free, max_nfev=3)
    assert cut.status == 0
    assert cut.nfev == 3


def test_a_start_where_the_model_is_not_finite_fails_plainly() -> None:
    def residual(p: np.ndarray) -> np.ndarray:
        return np.array([np.log(p[0]) - 1.0])

    def jacobian(p: np.ndarray) -> np.ndarray:
        return np.array([[1.0 / p[0]]])

    with np.errstate(all="ignore"):
        result = bounded_least_squares(residual, jacobian, np.array([-1.0]), [-5.0], [5.0])
    assert result.status == -1
