"""Friction compensation: a measurement's friction as the table or offset a controller takes.

:func:`~ncmeasure.compensation.points.axis_friction` reads the friction of
each axis and direction out of ``results.json`` (pure numpy);
:func:`~ncmeasure.compensation.render.render_compensation` writes it for a
controller through the templates under ``templates/compensation/``: the
TwinCAT CNC friction table, a LinuxCNC HAL snippet, the CiA 402 torque
offset 0x60B2 of vertical axes. ``docs/shop-floor.md`` shows each.
:func:`~ncmeasure.formats.offsets.read_offset_file` reads a reviewed
cia402 file back; ``apply-compensation`` writes it over CANopen
(:mod:`ncmeasure.links.canopen.offsets`): this package reads and writes files only.
"""

from __future__ import annotations

from ncmeasure.compensation.points import AxisFriction, DirectionFriction, axis_friction
from ncmeasure.compensation.render import CONTROLLERS, render_compensation

__all__ = [
    "CONTROLLERS",
    "AxisFriction",
    "DirectionFriction",
    "axis_friction",
    "render_compensation",
]
