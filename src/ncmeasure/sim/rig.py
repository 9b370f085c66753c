"""The method's test rig: the feed axis every simulator stands for unless told otherwise.

The friction the method builds on was identified on a test rig (*method:
Reference numbers*): a Bosch Rexroth MSK 100C-0200 motor (I_0 = 17.7 A,
M_0 = 38 Nm, so k_T ≈ 2.1 Nm/A) drives a ball screw of 40 mm diameter and
20 mm lead over a travel of about 750 mm. The method does not say how the
rig stands; here it is horizontal, with the fixed bearing at the travel's
minimum (its position 1). :data:`RIG_MECHANICS` states these facts once, as the
machine file states an axis' (:class:`~ncmeasure.formats.axis.StatedMechanics`);
the axis friction model (:mod:`ncmeasure.sim.axis`), the synthetic recordings
(:mod:`ncmeasure.sim.synthetic`) and the simulated CiA 402 and Modbus drives
embed them. :func:`rig_mechanics` puts a machine file's axis, or single facts,
on the rig: what it states replaces the rig's value, the rest stays the rig's.
The rig's physics beyond these facts (screw core, stiffnesses, inertia,
friction components) is the axis model's.
"""

from __future__ import annotations

from pydantic import ValidationError

from ncmeasure.errors import ConfigError
from ncmeasure.formats.axis import AxisMechanics, StatedMechanics
from ncmeasure.inputs import format_validation_error

__all__ = ["RIG_MECHANICS", "rig_mechanics"]

RIG_MECHANICS = StatedMechanics(
    travel_mm=(0.0, 750.0),
    vertical=False,
    fixed_bearing_end="min",
    torque_constant_nm_per_a=2.1,
    rated_current_a=17.7,
    screw_lead_mm=20.0,
)
"""The test rig's axis: travel 0..750 mm, k_T 2.1 Nm/A, rated current 17.7 A, lead
20 mm (method, "Reference numbers"); horizontal, fixed bearing at min."""


def rig_mechanics(stated: AxisMechanics | None = None, **facts: object) -> StatedMechanics:
    """The rig's mechanics with the facts stated instead of the rig's own.

    Example: ``rig_mechanics(axis.mechanics())`` for a machine file's axis,
    ``rig_mechanics(vertical=True, screw_lead_mm=10.0)`` for a test.

    Args:
        stated: An axis' mechanics (a machine file's ``axis.mechanics()``); a
            fact it leaves ``None`` keeps the rig's value.
        facts: Single facts by name, over both; ``None`` here says the fact
            is not known (``torque_constant_nm_per_a=None``).

    Raises:
        ConfigError: an unknown fact or a value out of range, one
            ``location: message`` line each.
    """
    unknown = sorted(set(facts) - set(AxisMechanics.model_fields))
    if unknown:
        raise ConfigError(
            "invalid axis mechanics",
            [
                f"{name}: not a mechanical fact (known: {', '.join(AxisMechanics.model_fields)})"
                for name in unknown
            ],
        )
    values = RIG_MECHANICS.mechanics().model_dump()
    if stated is not None:
        given = stated.mechanics().model_dump()
        values.update({name: value for name, value in given.items() if value is not None})
    values.update(facts)
    try:
        return StatedMechanics.model_validate(values)
    except ValidationError as exc:
        raise ConfigError("invalid axis mechanics", format_validation_error(exc)) from exc
