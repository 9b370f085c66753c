"""What a feed axis is, mechanically: the one model of the facts every stage needs.

The machine file states them (:class:`~ncmeasure.config.AxisConfig`), the
schedule repeats them for the analysis
(:class:`~ncmeasure.formats.schedule.AxisSummary`), a recording carries them in
its ``meta.json`` (:class:`~ncmeasure.formats.recording.RecordedAxis`), the
results say which were used (:class:`~ncmeasure.formats.results.AxisResult`),
and the simulators build their drives from them: all of them derive from
:class:`AxisMechanics` instead of declaring the fields again. Here a fact
nobody stated is ``None``; the machine file gives its own defaults.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["AXIS_NAME_PATTERN", "AxisMechanics", "BearingEnd", "StatedMechanics"]

AXIS_NAME_PATTERN = r"^[A-Z][A-Z0-9]{0,7}$"
"""An axis name: an upper-case letter, then up to 7 upper-case letters or digits. Here,
not in the machine file's models: a recording's channels are named by it too."""

BearingEnd = Literal["min", "max"]
"""The end of the travel that carries the ball screw's fixed bearing."""


class AxisMechanics(BaseModel):
    """The mechanical facts of one feed axis; ``None`` where nobody stated one."""

    model_config = ConfigDict(frozen=True)

    travel_mm: tuple[float, float] | None = Field(
        default=None, description="Soft limits [min, max] in mm. No program position leaves them."
    )
    vertical: bool | None = Field(
        default=None, description="A vertical axis (gravity acts on the motor torque)."
    )
    fixed_bearing_end: BearingEnd | None = Field(
        default=None, description="Which end of the travel carries the screw's fixed bearing."
    )
    torque_constant_nm_per_a: Annotated[float, Field(gt=0, le=1000)] | None = Field(
        default=None, description="Motor torque constant k_T in Nm/A (for the analysis)."
    )
    rated_current_a: Annotated[float, Field(gt=0, le=10_000)] | None = Field(
        default=None, description="Motor rated current in A (drives report current in ‰ of it)."
    )
    screw_lead_mm: Annotated[float, Field(gt=0, le=1000)] | None = Field(
        default=None, description="Ball-screw lead in mm per revolution."
    )

    def mechanics(self) -> AxisMechanics:
        """These facts alone, without what a subclass adds."""
        return AxisMechanics.model_validate(
            {name: getattr(self, name) for name in AxisMechanics.model_fields}
        )


class StatedMechanics(AxisMechanics):
    """The facts as a machine file states them: the travel always, the rest with defaults.

    The machine file's axes and the schedule's axes are of this kind; a
    recording or a results file may know less (:class:`AxisMechanics`).
    """

    travel_mm: tuple[float, float] = Field(
        description="Soft limits [min, max] in mm. No program position ever leaves them."
    )
    vertical: bool = Field(
        default=False, description="A vertical axis (gravity acts on the motor torque)."
    )
    fixed_bearing_end: BearingEnd = Field(
        default="min", description="Which end of the travel carries the screw's fixed bearing."
    )
