"""The example machine that ``ncmeasure init`` prints: a commented, valid machine file."""

from __future__ import annotations

__all__ = ["DEMO_LINKS", "DEMO_TEMPLATE", "EXAMPLE_TEMPLATE", "demo_machine", "example_machine"]

EXAMPLE_TEMPLATE = """\
# ncmeasure machine file: one file per machine type; generate the program once
# and use it for every machine of the type, at delivery and over its life.
# Reference of every key: `ncmeasure schema machine`, or the README.

[machine]
name = "HMX-400 #17"            # machine and serial number, written into the programs
controller = "{controller}"     # see `ncmeasure controllers`
program = "FRICTION"            # main program name; subprograms are FRICTION_<axis>
# program_number = 1000         # numbered dialects (Fanuc): O1000, subprograms O1001...
# park_order = ["Z", "X", "Y"]  # default: vertical axes first, then file order
# measure_order = ["X", "Y", "Z"]

# One [[axes]] table per feed axis. Limits are those of the controller's
# machine data; no block of the program ever leaves them.
[[axes]]
name = "X"
travel_mm = [0.0, 750.0]          # soft limits [min, max]
park_mm = 375.0                   # where X waits while the other axes are measured
max_velocity_mm_min = 30000
max_acceleration_m_s2 = 2.0
max_jerk_m_s3 = 40.0
fixed_bearing_end = "min"         # which end carries the screw's fixed bearing
vertical = false
torque_constant_nm_per_a = 2.1    # drive data for the analysis (optional)
rated_current_a = 17.7
screw_lead_mm = 20.0

[[axes]]
name = "Y"
travel_mm = [0.0, 600.0]
park_mm = 300.0
max_velocity_mm_min = 30000
max_acceleration_m_s2 = 2.0
max_jerk_m_s3 = 40.0
fixed_bearing_end = "min"
torque_constant_nm_per_a = 2.1
rated_current_a = 17.7
screw_lead_mm = 20.0

[[axes]]
name = "Z"
travel_mm = [-500.0, 0.0]
park_mm = -5.0                    # retracted: parked first, before X and Y move
max_velocity_mm_min = 24000
max_acceleration_m_s2 = 2.0
max_jerk_m_s3 = 40.0
fixed_bearing_end = "max"
vertical = true
torque_constant_nm_per_a = 2.1
rated_current_a = 17.7
screw_lead_mm = 20.0
# [axes.measurement]              # per-axis overrides of [measurement]
# max_velocity_mm_min = 10000

[measurement]
positions = 3                     # or a list in mm, e.g. [50.0, 375.0, 700.0]
velocity_steps = 50               # per direction; geometric spacing: fine at low speed
min_velocity_mm_min = 10
max_velocity_mm_min = 15000       # default: half the axis maximum
window_samples = 100              # window = 100 samples x 4 ms = 0.4 s of constant velocity
sample_period_ms = 4.0
margin_mm = 5.0                   # kept from both soft limits
warmup_strokes = 2                # back-and-forth strokes before measuring
repetitions = 1
both_directions = true

# [limits]                        # larger plans are refused before anything is written
# max_duration_h = 8.0            # one shift
# max_program_kb = 512            # default: the controller's program memory (controllers --details)
# max_windows = 20000             # measuring windows, all axes together (at most 50 000)
"""


def example_machine(controller: str) -> str:
    """The example machine file for ``controller``."""
    return EXAMPLE_TEMPLATE.format(controller=controller)


DEMO_TEMPLATE = """\
# The machine of `ncmeasure demo`: a virtual machine tool with the feed axis of
# the method's test rig (X: 750 mm travel, 40 mm ball screw with 20 mm lead,
# k_T = 2.1 Nm/A) and a vertical axis built alike (Z). Edit it and run
# `ncmeasure generate` / `ncmeasure simulate` on it like on any machine file.

[machine]
name = "ncmeasure demo"
controller = "{controller}"
program = "FRICTION"

[[axes]]
name = "X"
travel_mm = [0.0, 750.0]
park_mm = 375.0
max_velocity_mm_min = 50000
max_acceleration_m_s2 = 6.0
max_jerk_m_s3 = 150.0
fixed_bearing_end = "min"
torque_constant_nm_per_a = 2.1
rated_current_a = 17.7
screw_lead_mm = 20.0
link = {{ {x_link} }}

[[axes]]
name = "Z"
travel_mm = [-500.0, 0.0]
park_mm = -5.0
max_velocity_mm_min = 40000
max_acceleration_m_s2 = 6.0
max_jerk_m_s3 = 150.0
fixed_bearing_end = "max"
vertical = true
torque_constant_nm_per_a = 2.1
rated_current_a = 17.7
screw_lead_mm = 20.0
link = {{ {z_link} }}

# A short measurement: 5 positions (next to the fixed bearing, between, in the
# middle, between, next to the loose bearing), 8 velocity steps per direction.
# A machine at delivery would use 30 to 50 steps.
[measurement]
positions = 5
velocity_steps = 8
min_velocity_mm_min = 20
max_velocity_mm_min = 12000
window_samples = 50               # 50 x 4 ms = 0.2 s of constant velocity
sample_period_ms = 4.0
warmup_strokes = 1

{link_table}
"""

_DEMO_LINKS = {
    "canopen": (
        "[link]                          # simulated CiA 402 drives on a python-can virtual bus\n"
        'type = "canopen"\n'
        'interface = "virtual"\n'
        'channel = "ncmeasure-demo"\n'
        "sync_hz = 250",
        "node_id = {node}, increments_per_rev = 131072, read_velocity_demand = true",
    ),
    "modbus": (
        "[link]                          # a simulated Modbus TCP drive on this computer\n"
        'type = "modbus"\n'
        'host = "127.0.0.1"\n'
        "port = 5020\n"
        'register_map = "generic"\n'
        "poll_hz = 125                   # Modbus drives are polled; 125 Hz is a brisk rate",
        "unit_id = {node}",
    ),
}

DEMO_LINKS = tuple(_DEMO_LINKS)
"""The links ``ncmeasure demo`` can record through."""


def demo_machine(controller: str = "linuxcnc", link: str = "canopen") -> str:
    """The machine file of ``ncmeasure demo`` for ``controller`` and ``link``."""
    table, axis = _DEMO_LINKS[link]
    return DEMO_TEMPLATE.format(
        controller=controller,
        link_table=table,
        x_link=axis.format(node=1),
        z_link=axis.format(node=2),
    )
