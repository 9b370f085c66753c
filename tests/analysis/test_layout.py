"""The layout of a measurement: what it can show along the travel, and a line where it holds one.

A controller trace of a trapezoid program runs every speed on its own part of
the travel (slow near the ends, fast in the middle), and the two directions
of one speed at different places. Position effects then cannot be told from
speed and direction effects, and no position holds enough speeds for a line.
The windows and their current are built here as the window finder hands them
to :func:`~ncmeasure.analysis.axis.finish_axis`: one window per speed and
direction, its samples with the drive's noise, labelled with the measuring
position its place falls into.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
import pytest

from ncmeasure.analysis.axis import AxisFacts, AxisFound, finish_axis
from ncmeasure.analysis.judgement.summary import axis_headline
from ncmeasure.analysis.windows.model import Cluster, Segmentation, VelocityWindow
from ncmeasure.formats.results import AxisResult

SPEEDS = np.geomspace(100.0, 3000.0, 10)  # mm/min
TRAVEL = (0.0, 800.0)
COULOMB = 20.0  # N
VISCOUS = 0.004  # N per mm/min
SAMPLES = 500  # per window
NOISE = 0.8  # N, per sample


def offset_of(speed: float, asymmetric: bool) -> float:
    """The direction offset: −1.9 N at the slowest speed, −5.0 N at the fastest."""
    if not asymmetric:
        return 0.0
    share = (speed - SPEEDS[0]) / (SPEEDS[-1] - SPEEDS[0])
    return -1.9 - 3.1 * float(share)


Cell = tuple[int, Literal[1, -1], int]  # position index, direction, step


def trapezoid() -> tuple[list[float], list[Cell]]:
    """Each speed at its own places, slow near the ends, the directions apart.

    Every stroke steps up through the odd speeds and down through the even
    ones; the positive stroke runs from the min end, the negative one from
    the max end, so place k holds the positive run of one speed and the
    negative run of another.
    """
    order = [0, 2, 4, 6, 8, 9, 7, 5, 3, 1]
    places = np.linspace(40.0, 760.0, len(order)).tolist()
    cells: list[Cell] = []
    for k in range(len(order)):
        cells.append((k, 1, order[k]))
        cells.append((k, -1, order[len(order) - 1 - k]))
    return places, cells


def grid(positions: int = 5) -> tuple[list[float], list[Cell]]:
    """Every speed at every position, both directions."""
    places = np.linspace(50.0, 750.0, positions).tolist()
    cells: list[Cell] = [
        (k, sign, j) for k in range(positions) for sign in (1, -1) for j in range(len(SPEEDS))
    ]
    return places, cells


def axis_result(
    layout: tuple[list[float], list[Cell]],
    *,
    asymmetric: bool = True,
    along: Callable[[float], float] = lambda x: 1.0,
    seed: int = 0,
) -> AxisResult:
    """The axis' result from windows of the layout; friction × ``along(position)``."""
    places, cells = layout
    rng = np.random.default_rng(seed)
    windows: list[VelocityWindow] = []
    current: list[np.ndarray] = []
    start = 0
    for index, sign, step in sorted(cells, key=lambda c: (c[2], c[1])):
        speed = float(SPEEDS[step])
        friction = (COULOMB + VISCOUS * speed) * along(places[index])
        level = sign * friction + offset_of(speed, asymmetric)
        # Drive noise: white, plus a slow ripple and the window's own level error.
        ripple = 0.3 * np.sin(np.linspace(0.0, 6.0 * np.pi, SAMPLES) + rng.uniform(0, 6.3))
        samples = level + rng.normal(0.0, NOISE, SAMPLES) + ripple + rng.normal(0.0, 0.05)
        windows.append(
            VelocityWindow(
                axis="X",
                start=start,
                stop=start + SAMPLES,
                velocity_mm_min=sign * speed,
                level_mm_min=sign * speed,
                direction=sign,
                position_mm=places[index],
                position_index=index,
                step=step,
                source="plateau",
            )
        )
        current.append(samples)
        start += SAMPLES + 200
    segmentation = Segmentation(
        axis="X",
        windows=windows,
        source="plateau",
        labelled_by="clusters",
        steps=[Cluster(j, float(v), float(v), float(v), 0) for j, v in enumerate(SPEEDS)],
        positions=[
            Cluster(k, x, x, x, sum(1 for c in cells if c[0] == k)) for k, x in enumerate(places)
        ],
        sample_period_s=0.004,
    )
    found = AxisFound(
        segmentation=segmentation,
        window_current=current,
        window_times=[(w.start * 0.004, (w.stop - 1) * 0.004) for w in windows],
        current_dead=None,
        current_quantum_a=0.0,
        implausible_counts={},
        implausible_lines=[],
    )
    facts = AxisFacts(
        name="X", torque_constant_nm_per_a=1.0, travel_mm=TRAVEL, fixed_bearing_end="min"
    )
    return finish_axis("X", facts, None, found, report=lambda _text, _share: None, gap_share=0.0)


@pytest.mark.parametrize("asymmetric", [True, False])
def test_trapezoid_layout_names_no_cause(asymmetric: bool) -> None:
    result = axis_result(trapezoid(), asymmetric=asymmetric)
    verdict = result.verdict
    # Before: "ok · friction varies by 116 % along the travel, within the noise".
    assert "each speed was measured at its own positions" in verdict.reason
    assert "cannot be told from the speed dependence" in verdict.reason
    assert verdict.level == "check"
    text = (verdict.reason + verdict.action).lower()
    for words in ("guide rail", "bearing", "nut", "cover", "changes by", "varies by"):
        assert words not in text
    dependency = result.position_dependency
    assert dependency is not None
    assert not dependency.identifiable
    assert dependency.signature == "not_identifiable"
    assert dependency.compared_groups == 0
    assert [c.cause for c in dependency.causes] == ["none"]
    headline = axis_headline(result)
    assert headline.spread_percent is None
    assert "each speed at its own positions" in headline.travel_text


@pytest.mark.parametrize("asymmetric", [True, False])
def test_trapezoid_layout_gives_a_pooled_line(asymmetric: bool) -> None:
    result = axis_result(trapezoid(), asymmetric=asymmetric)
    headline = axis_headline(result)
    # Before: "Coulomb friction not determined".
    assert headline.coulomb == pytest.approx(COULOMB, rel=0.01)
    # One speed per direction at every position: no line of its own.
    assert all(
        d is None or d.fit is None or d.fit.coulomb is None
        for p in result.positions
        for d in p.directions.values()
    )
    pooled = result.pooled
    assert pooled is not None
    assert len(pooled.positions_mm) == 10
    assert "pooled per direction" in pooled.note
    assert any("pooled per direction" in w for w in result.warnings)
    assert result.offset is not None  # paired across positions, then taken out
    fits = [d.fit for d in pooled.directions.values() if d is not None]
    assert len(fits) == 2
    coulomb = np.mean([f.coulomb for f in fits if f is not None and f.coulomb is not None])
    viscous = np.mean(
        [f.viscous_per_mm_min for f in fits if f is not None and f.viscous_per_mm_min is not None]
    )
    assert coulomb == pytest.approx(COULOMB, rel=0.01)
    assert viscous == pytest.approx(VISCOUS, rel=0.01)
    headline = axis_headline(result)
    assert headline.coulomb == pytest.approx(COULOMB, rel=0.01)
    assert headline.viscous_per_m_min == pytest.approx(VISCOUS * 1000.0, rel=0.01)
    assert "positions pooled" in headline.coulomb_text


@pytest.mark.parametrize("seed", range(3))
def test_flat_grid_reports_no_spread_beyond_its_own_null(seed: int) -> None:
    result = axis_result(grid(), seed=seed)
    dependency = result.position_dependency
    assert dependency is not None and dependency.identifiable
    assert dependency.signature == "flat"
    assert dependency.noise_spread_percent is not None
    assert dependency.compared_groups == len(SPEEDS)  # both directions at every speed
    assert result.pooled is None
    assert result.verdict.level == "ok"


def test_grid_with_a_misaligned_rail_is_still_found() -> None:
    bumps = {50.0: 0.0, 225.0: 0.18, 400.0: 0.02, 575.0: 0.22, 750.0: 0.05}
    result = axis_result(grid(), along=lambda x: 1.0 + bumps[x])
    dependency = result.position_dependency
    assert dependency is not None and dependency.identifiable
    assert dependency.signature == "irregular"
    assert dependency.causes[0].cause == "guide_rail"
    assert dependency.noise_spread_percent is not None
    assert dependency.spread_percent > 3 * dependency.noise_spread_percent
    assert result.verdict.level == "fault"
    assert "misaligned guide rail" in result.verdict.reason


def test_one_direction_at_two_places_is_compared_only_with_itself() -> None:
    """Both directions at every position, but at different speeds there: no comparison."""
    places = [100.0, 300.0, 500.0, 700.0]
    # Positive runs at the slow speeds, negative runs at the fast ones, each speed at
    # two neighbouring positions in one direction: positions 1–2 and 3–4 are linked,
    # but never with each other at one speed and direction.
    cells: list[Cell] = []
    for j in range(5):
        cells += [(0, 1, j), (1, 1, j), (2, -1, j), (3, -1, j)]
    for j in range(5, 10):
        cells += [(0, -1, j), (1, -1, j), (2, 1, j), (3, 1, j)]
    result = axis_result((places, cells))
    dependency = result.position_dependency
    assert dependency is not None
    # Positions 1–2 and 3–4 form two sets: the profile covers one of them only.
    average = dependency.profiles[0]
    assert len(average.positions_mm) == 2
    assert dependency.signature == "insufficient_data"
    assert result.verdict.level == "check"
    assert "guide rail" not in result.verdict.reason
