"""The test rig's mechanics: one declaration every simulator embeds."""

from __future__ import annotations

import pytest

from ncmeasure.config import AxisConfig
from ncmeasure.errors import ConfigError
from ncmeasure.formats.axis import AxisMechanics
from ncmeasure.sim.axis import AxisModel, AxisParameters
from ncmeasure.sim.cia402 import DriveScaling
from ncmeasure.sim.modbus_drive import ModbusDriveScaling, SimulatedUnit
from ncmeasure.sim.rig import RIG_MECHANICS, rig_mechanics
from ncmeasure.sim.synthetic import SyntheticAxis


def test_the_rig_is_the_methods_test_rig() -> None:
    # method, "Reference numbers": MSK 100C-0200 (I_0 17.7 A, k_T ≈ 2.1 Nm/A),
    # ball screw 40 mm with 20 mm lead, travel ≈ 750 mm
    assert RIG_MECHANICS.travel_mm == (0.0, 750.0)
    assert RIG_MECHANICS.vertical is False
    assert RIG_MECHANICS.fixed_bearing_end == "min"
    assert RIG_MECHANICS.torque_constant_nm_per_a == 2.1
    assert RIG_MECHANICS.rated_current_a == 17.7
    assert RIG_MECHANICS.screw_lead_mm == 20.0


def test_every_simulator_embeds_the_rig_by_default() -> None:
    assert AxisParameters().mechanics is RIG_MECHANICS
    assert DriveScaling().mechanics is RIG_MECHANICS
    assert ModbusDriveScaling().mechanics is RIG_MECHANICS
    assert SimulatedUnit("X", 1).mechanics is RIG_MECHANICS
    assert SyntheticAxis().mechanics is RIG_MECHANICS


def test_stated_facts_replace_the_rigs_and_unstated_ones_keep_them() -> None:
    stated = AxisMechanics(travel_mm=(-500.0, 0.0), vertical=True, screw_lead_mm=10.0)
    mechanics = rig_mechanics(stated, rated_current_a=8.0)
    assert mechanics.travel_mm == (-500.0, 0.0)
    assert mechanics.vertical is True
    assert mechanics.screw_lead_mm == 10.0
    assert mechanics.rated_current_a == 8.0  # a keyword fact wins
    assert mechanics.fixed_bearing_end == "min"  # the rig's
    assert mechanics.torque_constant_nm_per_a == 2.1  # the rig's
    assert rig_mechanics() == RIG_MECHANICS
    # a keyword None says the fact is unknown
    assert rig_mechanics(torque_constant_nm_per_a=None).torque_constant_nm_per_a is None


def test_a_machine_files_axis_goes_on_the_rig() -> None:
    axis = AxisConfig(
        name="Z",
        travel_mm=(-500.0, 0.0),
        park_mm=-5.0,
        max_velocity_mm_min=20000.0,
        max_acceleration_m_s2=2.0,
        max_jerk_m_s3=50.0,
        fixed_bearing_end="max",
        vertical=True,
        rated_current_a=8.0,
    )
    params = AxisParameters.from_config(axis, moved_mass_kg=300.0)
    assert params.mechanics == rig_mechanics(axis.mechanics())
    assert params.mechanics.rated_current_a == 8.0
    assert (params.torque_constant_nm_per_a, params.screw_lead_mm) == (2.1, 20.0)  # the rig's
    assert params.moved_mass_kg == 300.0
    assert AxisModel(axis).axis.mechanics == params.mechanics


def test_invalid_facts_are_config_errors() -> None:
    with pytest.raises(ConfigError) as unknown:
        rig_mechanics(lead_mm=10.0)
    assert unknown.value.problems[0].startswith("lead_mm: not a mechanical fact (known: ")
    with pytest.raises(ConfigError) as bad:
        rig_mechanics(screw_lead_mm=0.0, rated_current_a=-1.0)
    assert [line.split(":")[0] for line in bad.value.problems] == [
        "rated_current_a",
        "screw_lead_mm",
    ]
    with pytest.raises(ConfigError, match="screw_lead_mm: a simulated CiA 402 drive needs it"):
        DriveScaling(mechanics=rig_mechanics(screw_lead_mm=None))
