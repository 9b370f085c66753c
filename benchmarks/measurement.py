"""The simulated measurement the analysis benchmarks share: three axes, one after the other.

X with friction rising along the travel, Y plain, Z vertical with a gravity
offset; ``steps`` geometric velocities 10..15 000 mm/min at each position, both
directions, ``repetitions`` times. ``benchmarks/analysis.py``,
``analysis_memory.py`` and ``fit_report.py`` simulate it.
"""

from __future__ import annotations

from collections.abc import Sequence

from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities

POSITIONS = (50.0, 212.5, 375.0, 537.5, 700.0)


def measurement_axes(
    steps: int, repetitions: int, positions: Sequence[float] = POSITIONS
) -> list[SyntheticAxis]:
    """The three simulated axes of the measurement."""
    common = {
        "positions_mm": tuple(positions),
        "velocities_mm_min": geometric_velocities(10.0, 15000.0, steps),
        "repetitions": repetitions,
        "dwell_s": 0.2,
    }
    vertical = rig_mechanics(vertical=True)
    return [
        SyntheticAxis(name="X", coulomb=(2.0, 2.1, 2.2, 2.3, 2.4)[: len(positions)], **common),  # type: ignore[arg-type]
        SyntheticAxis(name="Y", coulomb=1.5, **common),  # type: ignore[arg-type]
        SyntheticAxis(name="Z", coulomb=2.5, offset=3.0, mechanics=vertical, **common),  # type: ignore[arg-type]
    ]
