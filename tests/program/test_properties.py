"""Property: for any valid machine, no dialect ever leaves the soft limits or exceeds a feed.

The programs are written, read back with ncmeasure's reader (which knows
nothing of the templates) and held against the limits and the schedule.
"""

from __future__ import annotations

import tempfile
from typing import Any

from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from ncmeasure.config import parse_machine
from ncmeasure.errors import PlanError
from ncmeasure.program import generate_programs
from ncmeasure.program.check import CheckReport, axis_numbers, check_trace
from ncmeasure.program.reader import read_programs
from tests.conftest import DIALECTS, FIXED_TIME

finite = {"allow_nan": False, "allow_infinity": False}


@st.composite
def axis_tables(draw: st.DrawFn, name: str) -> dict[str, Any]:
    low = draw(st.floats(-2000, 2000, **finite))
    length = draw(st.floats(30, 4000, **finite))
    high = low + length
    vertical = draw(st.booleans())
    # a vertical axis parks in the quarter of its travel at its upper (safe) end (inside it)
    park_low = high - 0.24 * length if vertical else low
    return {
        "name": name,
        "travel_mm": [low, high],
        "park_mm": draw(st.floats(park_low, high, **finite)),
        "max_velocity_mm_min": draw(st.floats(500, 60000, **finite)),
        "max_acceleration_m_s2": draw(st.floats(0.2, 20, **finite)),
        "max_jerk_m_s3": draw(st.floats(1, 500, **finite)),
        "vertical": vertical,
    }


@st.composite
def machines(draw: st.DrawFn) -> dict[str, Any]:
    count = draw(st.integers(1, 3))
    axes = [draw(axis_tables(name)) for name in "XYZ"[:count]]
    shortest = min(a["travel_mm"][1] - a["travel_mm"][0] for a in axes)
    margin = draw(st.floats(0, shortest / 4, **finite))
    return {
        "machine": {"name": "prop", "controller": draw(st.sampled_from(DIALECTS))},
        "axes": axes,
        "measurement": {
            "positions": draw(st.integers(1, 5)),
            "velocity_steps": draw(st.integers(1, 12)),
            "min_velocity_mm_min": draw(st.floats(1, 100, **finite)),
            "max_velocity_fraction": draw(st.floats(0.3, 1.0, **finite)),
            "spacing": draw(st.sampled_from(["geometric", "linear"])),
            "window_s": draw(st.floats(0.02, 1.0, **finite)),
            "settle_s": draw(st.floats(0, 0.3, **finite)),
            "margin_mm": margin,
            "warmup_strokes": draw(st.integers(0, 2)),
            "both_directions": draw(st.booleans()),
            "unfit_steps": "drop",
        },
    }


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(machines())
def test_no_dialect_leaves_the_limits(data: dict[str, Any]) -> None:
    config = parse_machine(data)
    try:
        result = generate_programs(config, generated=FIXED_TIME)
    except PlanError:
        assume(False)  # not even the slowest step fits: reported, nothing generated
        return
    with tempfile.TemporaryDirectory() as folder:
        result.write(folder)
        schedule = result.schedule
        trace = read_programs(
            result.dialect,
            folder,
            schedule.main_program,
            {a.name for a in schedule.axes},
            schedule.controller_options,
            axis_numbers(schedule),
        )
    report = CheckReport(directory=folder, controller=result.dialect.name)  # type: ignore[arg-type]
    check_trace(schedule, trace, report)
    assert report.problems == []
    limits = {a.name: a for a in config.axes}
    for motion in trace.motions:
        for name, target in motion.target.items():
            low, high = limits[name].travel_mm
            assert low <= target <= high
            if motion.kind == "feed":
                assert motion.feed_mm_min is not None
                assert motion.feed_mm_min <= limits[name].max_velocity_mm_min
