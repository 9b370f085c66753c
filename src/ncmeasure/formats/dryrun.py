"""A dry run's ``dryrun.json``: how far the virtual machine went, against the machine's limits.

Written by ``ncmeasure dryrun`` (:mod:`ncmeasure.dryrun`) after the virtual
machine ran the generated programs. Per axis (:class:`AxisReach`): the
machine file's limits (soft limits, maximum velocity and acceleration), the
extremes of the *commanded* motion (the interpolator's setpoints, which a
controller holds against those limits, and which the verdict judges), the
extremes of the *actual* motion (the servo loop's response, which overshoots
the setpoints a little after every ramp; for the record), and what was
exceeded. ``excursions`` name the blocks that ask for more than a limit.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field

from ncmeasure.errors import ConfigError
from ncmeasure.files import write_whole
from ncmeasure.formats.header import FileHeader, read_file

__all__ = [
    "DRYRUN_FILE",
    "DRYRUN_FORMAT",
    "DRYRUN_FORMAT_VERSION",
    "AxisLimits",
    "AxisReach",
    "DryRun",
    "Excess",
    "Limit",
    "Reach",
    "load_dryrun",
    "write_dryrun",
]

log = logging.getLogger(__name__)

DRYRUN_FILE = "dryrun.json"
DRYRUN_FORMAT = "ncmeasure-dryrun"
DRYRUN_FORMAT_VERSION = 1
MAX_DRYRUN_BYTES = 16 * 1024 * 1024
"""Largest dryrun.json read."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Reach(_Model):
    """The extremes of one axis' motion over the whole run."""

    min_position_mm: float
    max_position_mm: float
    max_velocity_mm_min: float = Field(description="Largest velocity, either direction.")
    max_acceleration_m_s2: float = Field(
        description="Largest acceleration or deceleration, either direction."
    )


class AxisLimits(_Model):
    """The machine file's limits of one axis."""

    travel_mm: tuple[float, float] = Field(description="Soft limits [min, max].")
    max_velocity_mm_min: float
    max_acceleration_m_s2: float


Limit = Literal["travel_min", "travel_max", "max_velocity_mm_min", "max_acceleration_m_s2"]
"""A limit of the machine file: either soft limit, the maximum velocity or acceleration."""


class Excess(_Model):
    """One limit the commanded motion of an axis exceeded."""

    limit: Limit
    limit_value: float = Field(description="The machine file's value (mm, mm/min, m/s²).")
    reached: float = Field(description="The commanded extreme, in the same unit.")
    message: str = Field(description="The same in a sentence.")


class AxisReach(_Model):
    """One axis: its limits, how far it went, and which limit it exceeded."""

    name: str
    limits: AxisLimits
    commanded: Reach = Field(
        description="The interpolator's setpoints: what a controller holds against the limits."
    )
    actual: Reach = Field(
        description="The servo loop's response (velocity as the drive reports it): it "
        "overshoots the setpoints a little after every ramp."
    )
    exceeded: list[Excess] = Field(
        default_factory=list, description="Each limit the commanded motion exceeded."
    )

    def exceeds(self, limit: Limit) -> bool:
        """True when the axis exceeded ``limit``."""
        return any(excess.limit == limit for excess in self.exceeded)


class DryRun(FileHeader):
    """``dryrun.json``: the virtual machine's reach on every axis against the machine file."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    FORMAT: ClassVar[str] = DRYRUN_FORMAT
    FORMAT_VERSION: ClassVar[int] = DRYRUN_FORMAT_VERSION
    WRITTEN_BY: ClassVar[str] = "ncmeasure dryrun"

    machine: str
    controller: str
    config_hash: str
    programs: str = Field(description="The folder of the programs that ran.")
    machine_file: str
    machine_time_s: float = Field(description="Machine time of the run, standstill included.")
    axes: list[AxisReach]
    excursions: list[str] = Field(
        default_factory=list,
        description="file:line and what, per block that takes an axis beyond its travel or "
        "feeds it above its maximum velocity, whether the axis got there or not (a short "
        "move may never reach a feed); the first ones, excursions_total counts them all.",
    )
    excursions_total: int = 0

    @property
    def within_limits(self) -> bool:
        """True when no axis exceeded a limit and no block asked for more than one."""
        return not any(axis.exceeded for axis in self.axes) and not self.excursions_total

    @property
    def exceeded(self) -> list[str]:
        """Every exceeded limit in a sentence, axis by axis."""
        return [excess.message for axis in self.axes for excess in axis.exceeded]


def write_dryrun(dryrun: DryRun, path: str | os.PathLike[str]) -> Path:
    """Write ``dryrun.json``, whole (its folder is created when missing).

    Raises:
        OutputError: The file or its folder cannot be written.
    """
    target = write_whole(path, dryrun.model_dump_json(indent=2) + "\n", fsync=True, parents=True)
    log.info("wrote %s", target)
    return target


def load_dryrun(path: str | os.PathLike[str]) -> DryRun:
    """Read a ``dryrun.json`` written by :func:`write_dryrun`.

    Raises:
        ConfigError: missing, not JSON, not a dry run, of a newer version, or not valid.
    """
    return read_file(
        Path(path),
        DryRun,
        ConfigError,
        what="dry run",
        max_bytes=MAX_DRYRUN_BYTES,
        missing=f"{path}: no such dry run file",
    )
