"""What-if studies with the axis model: friction over position × velocity per variation.

Behind ``ncmeasure simulate``: a designer lists assembly variations (a
shifted loose bearing, a nut shifted, a preload loss, ...) and sees, side by
side, how each changes the friction along the travel compared with a
well-assembled axis — before anything is built.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

from ncmeasure.config import AxisConfig, Measurement
from ncmeasure.sim.axis import AxisModel, Variation, parse_variation

__all__ = ["Scenario", "Study", "plot_study", "study"]


class Scenario(BaseModel):
    """One variation of one axis: its friction map and what it does along the travel."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    """The variation as given (``nominal`` for none)."""
    friction_nm: list[list[float]]
    """Friction torque [Nm], positions × velocities (positive direction)."""
    mean_nm: float
    spread_percent: float
    """(max − min) / mean of the friction along the travel, averaged over velocities."""
    change_percent: list[float]
    """Per position, the change against the nominal axis, averaged over velocities."""


class Study(BaseModel):
    """Several variations of one axis, side by side (what ``simulate --json`` prints)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    axis: str
    positions_mm: list[float]
    velocities_mm_min: list[float]
    scenarios: list[Scenario]


@dataclass(frozen=True)
class _Grid:
    positions_mm: NDArray[np.float64]
    velocities_mm_min: NDArray[np.float64]


def _grid(axis: AxisConfig, measurement: Measurement, positions: int, velocities: int) -> _Grid:
    low = axis.travel_mm[0] + measurement.margin_mm
    high = axis.travel_mm[1] - measurement.margin_mm
    top = measurement.max_velocity_mm_min or measurement.max_velocity_fraction * (
        axis.max_velocity_mm_min
    )
    return _Grid(
        np.linspace(low, high, positions),
        np.geomspace(measurement.min_velocity_mm_min, top, velocities),
    )


def _named(variation: str | Variation) -> tuple[str, Variation]:
    if isinstance(variation, Variation):
        return variation.as_text() or "nominal", variation
    return variation, parse_variation(variation)


def study(
    axis: AxisConfig,
    measurement: Measurement,
    variations: Sequence[str | Variation],
    *,
    positions: int = 11,
    velocities: int = 12,
) -> Study:
    """Friction maps of ``axis`` for the nominal assembly and each variation.

    Args:
        axis: The axis (travel, bearing end, k_T, lead come from it).
        measurement: Its measurement settings (velocity range, margin).
        variations: One scenario each: a ``key=value`` text (see
            :func:`~ncmeasure.sim.axis.parse_variation`) or a
            :class:`~ncmeasure.sim.axis.Variation`, named by its
            :meth:`~ncmeasure.sim.axis.Variation.as_text` (e.g. the values of
            :data:`~ncmeasure.sim.axis.EXAMPLE_VARIATIONS`).
        positions: Grid points along the usable travel.
        velocities: Grid points over the measured velocity range (geometric).

    Raises:
        ConfigError: a variation cannot be parsed.
    """
    grid = _grid(axis, measurement, positions, velocities)
    scenarios: list[Scenario] = []
    nominal: NDArray[np.float64] | None = None
    for name, variation in [("nominal", Variation()), *map(_named, variations)]:
        friction = AxisModel(axis, variation=variation).friction_map(
            grid.positions_mm, grid.velocities_mm_min
        )
        if nominal is None:
            nominal = friction
        along = (friction / friction.mean(axis=0)).mean(axis=1) * friction.mean()
        change = ((friction / nominal - 1.0) * 100.0).mean(axis=1)
        scenarios.append(
            Scenario(
                name=name,
                friction_nm=friction.round(6).tolist(),
                mean_nm=round(float(friction.mean()), 6),
                spread_percent=round(float((along.max() - along.min()) / along.mean() * 100), 3),
                change_percent=change.round(3).tolist(),
            )
        )
    return Study(
        axis=axis.name,
        positions_mm=grid.positions_mm.round(3).tolist(),
        velocities_mm_min=grid.velocities_mm_min.round(3).tolist(),
        scenarios=scenarios,
    )


def plot_study(result: Study, path: str | Path) -> Path:
    """Contour plots side by side: the nominal friction, then each variation's change in %."""
    from matplotlib.figure import Figure  # here: a study without --plot draws nothing

    path = Path(path)
    count = len(result.scenarios)
    figure = Figure(figsize=(4.2 * count, 3.6), dpi=100, layout="constrained")
    axes = figure.subplots(1, count, squeeze=False)[0]
    positions = np.asarray(result.positions_mm)
    velocities = np.asarray(result.velocities_mm_min)
    nominal = np.asarray(result.scenarios[0].friction_nm)
    for ax, scenario in zip(axes, result.scenarios, strict=True):
        friction = np.asarray(scenario.friction_nm)
        if scenario is result.scenarios[0]:
            # The nominal axis in Nm; every variation as its change against it.
            levels = ax.contourf(positions, velocities, friction.T, levels=14, cmap="viridis")
            label = "friction torque [Nm]"
        else:
            change = (friction / nominal - 1.0) * 100.0
            limit = max(float(np.abs(change).max()), 0.1)
            levels = ax.contourf(
                positions,
                velocities,
                change.T,
                cmap="RdBu_r",
                levels=np.linspace(-limit, limit, 15),
            )
            label = "change against nominal [%]"
        ax.set_yscale("log")
        ax.set_xlabel("position [mm]")
        ax.set_title(f"{scenario.name}\nspread {scenario.spread_percent:.1f} %", fontsize=9)
        figure.colorbar(levels, ax=ax, label=label, format="%.1f")
    axes[0].set_ylabel("velocity [mm/min]")
    figure.suptitle(f"Axis {result.axis}: friction over position and velocity")
    figure.savefig(path)
    return path
