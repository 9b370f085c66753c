"""Every number of the machine file is finite and inside a physical range; types are strict.

Each case is a value a user's typo or a fuzzer produced that used to pass the
validator and end in a traceback, a silent conversion, or a `null` in
schedule.json.
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import MAX_FEED, MAX_POSITION_MM, MIN_FEED, parse_machine
from ncmeasure.errors import ConfigError, PlanError
from ncmeasure.plan import SizeLimit, plan_machine
from ncmeasure.program import generate_programs
from tests.conftest import DIALECTS, example_data, machine_toml

Edit = Callable[[dict[str, Any]], None]


def axis(key: str, value: Any) -> Edit:
    return lambda data: data["axes"][0].__setitem__(key, value)


def measurement(key: str, value: Any) -> Edit:
    return lambda data: data["measurement"].__setitem__(key, value)


# (edit, the line the refusal must contain)
REFUSED: dict[str, tuple[Edit, str]] = {
    "min velocity below a writable feed": (
        measurement("min_velocity_mm_min", 0.0005),
        "measurement.min_velocity_mm_min: Input should be greater than or equal to 0.01",
    ),
    "warm-up velocity below a writable feed": (
        measurement("warmup_velocity_mm_min", 0.0001),
        "measurement.warmup_velocity_mm_min: Input should be greater than or equal to 0.01",
    ),
    "infinite travel": (
        axis("travel_mm", [0.0, math.inf]),
        "axes[0].travel_mm[1]: Input should be a finite number",
    ),
    "travel of 1e300": (
        axis("travel_mm", [0.0, 1e300]),
        "axes[0].travel_mm[1]: Input should be less than or equal to 100000",
    ),
    "NaN park": (axis("park_mm", math.nan), "axes[0].park_mm: Input should be a finite number"),
    "denormal acceleration": (
        axis("max_acceleration_m_s2", 5e-324),
        "axes[0].max_acceleration_m_s2: Input should be greater than or equal to 0.001",
    ),
    "denormal jerk": (
        axis("max_jerk_m_s3", 5e-324),
        "axes[0].max_jerk_m_s3: Input should be greater than or equal to 0.001",
    ),
    "infinite torque constant": (
        axis("torque_constant_nm_per_a", math.inf),
        "axes[0].torque_constant_nm_per_a: Input should be a finite number",
    ),
    "infinite rated current": (
        axis("rated_current_a", math.inf),
        "axes[0].rated_current_a: Input should be a finite number",
    ),
    "infinite screw lead": (
        axis("screw_lead_mm", math.inf),
        "axes[0].screw_lead_mm: Input should be a finite number",
    ),
    "a number as text": (
        axis("max_velocity_mm_min", "40"),
        "axes[0].max_velocity_mm_min: expected a number, got the text '40'",
    ),
    "a boolean as text": (
        axis("vertical", "no"),
        "axes[0].vertical: expected true/false, got the text 'no'",
    ),
    "a count as float": (
        measurement("velocity_steps", 50.0),
        "measurement.velocity_steps: expected an integer, got 50.0",
    ),
    "an option as text": (
        lambda d: d["machine"].__setitem__("controller_options", {"marker_bit": "1"}),
        "machine.controller_options.marker_bit: expected an integer or true/false, got the text",
    ),
    "unknown key with capitals": (axis("Park_mm", 1.0), "axes[0].Park_mm: unknown key"),
    "unknown key with a hyphen": (axis("park-mm", 1.0), "axes[0]['park-mm']: unknown key"),
    "unknown nested key": (
        axis("measurement", {"Window_S": 1.0}),
        "axes[0].measurement.Window_S: unknown key",
    ),
    "unknown table": (lambda d: d.__setitem__("Measurement", {}), "Measurement: unknown key"),
    "positions on the same micrometre": (
        lambda d: d["axes"][0].__setitem__("measurement", {"positions": [100.0, 100.0004]}),
        "axes[0].measurement.positions[1]: 100.0004 mm and 100 mm are the same micrometre",
    ),
    "more positions than micrometres": (
        lambda d: d["axes"][0].update(
            travel_mm=[0.0, 10.02], park_mm=5.0, measurement={"positions": 50, "margin_mm": 5.0}
        ),
        "axes[0].measurement.positions: 50 positions need at least 49 µm of usable travel",
    ),
    "a dwell under a millisecond": (
        measurement("dwell_s", 0.0004),
        "measurement.dwell_s: a dwell is 0 or at least 0.001 s",
    ),
    "a window of days": (
        lambda d: d["measurement"].update(window_samples=1_000_000, sample_period_ms=1000.0),
        "measurement.window_samples: 1000000 samples of 1000 ms make a window of 1000000 s",
    ),
    "margin beyond any travel": (
        measurement("margin_mm", 1e9),
        "measurement.margin_mm: Input should be less than or equal to 100000",
    ),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_values_that_used_to_pass_are_refused_at_their_place(case: str) -> None:
    edit, expected = REFUSED[case]
    data = example_data("linuxcnc")
    edit(data)
    with pytest.raises(ConfigError) as caught:
        parse_machine(data)
    assert any(expected in line for line in caught.value.problems), caught.value.problems


def test_an_option_out_of_range_is_one_problem_not_one_per_type() -> None:
    """An integer option beyond its range is judged by the integer branch alone; the
    boolean branch's "expected true/false" would tell the user something wrong."""
    data = example_data("sinumerik-840d")
    data["machine"]["controller_options"] = {"marker_r": 100_000}
    with pytest.raises(ConfigError) as caught:
        parse_machine(data)
    assert list(caught.value.problems) == [
        "machine.controller_options.marker_r: Input should be less than or equal to 99999"
    ]


def test_numbers_in_messages_are_shown_as_written() -> None:
    data = example_data("linuxcnc")
    data["axes"][0]["max_velocity_mm_min"] = 999_999.9999
    data["measurement"]["max_velocity_mm_min"] = 999_999.99999
    with pytest.raises(ConfigError) as caught:
        parse_machine(data)
    assert any(
        "999999.99999 mm/min exceeds the maximum velocity of axis X (999999.9999 mm/min)" in line
        for line in caught.value.problems
    ), caught.value.problems


@pytest.mark.parametrize(
    "case",
    [
        "min velocity below a writable feed",
        "denormal acceleration",
        "infinite travel",
        "a boolean as text",
        "unknown key with a hyphen",
    ],
)
@pytest.mark.parametrize("dialect", DIALECTS)
def test_generate_refuses_them_with_exit_2_and_no_traceback(
    case: str, dialect: str, tmp_path: Path
) -> None:
    edit, expected = REFUSED[case]
    data = example_data(dialect)
    edit(data)
    machine = tmp_path / "m.toml"
    machine.write_text(machine_toml(data), encoding="utf-8")
    result = CliRunner().invoke(app, ["generate", str(machine), "-o", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert expected in result.stderr
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert not (tmp_path / "out").exists()


def test_velocity_steps_closer_than_a_writable_feed_are_a_warning_in_the_schedule() -> None:
    data = example_data("linuxcnc")
    data["measurement"].update(
        min_velocity_mm_min=0.01, max_velocity_mm_min=0.02, velocity_steps=40
    )
    schedule, _ = plan_machine(parse_machine(data), SizeLimit(max_duration_s=1e12))
    steps = schedule.axes[0].velocities_mm_min
    assert len(steps) == len(set(steps)) < 40
    assert any("closer than the 0.001 mm/min a program can write" in w for w in schedule.warnings)


def test_a_dwell_is_planned_as_the_program_writes_it() -> None:
    data = example_data("linuxcnc")
    data["measurement"].update(dwell_s=0.0016, velocity_steps=2)
    _, plans = plan_machine(parse_machine(data))
    dwells = {m.seconds for m in plans[0].moves if m.kind == "dwell"}
    assert dwells == {0.002}


# --- the planner at the corners of the ranges ---------------------------------------------

CORNERS = {
    "travel_mm": (
        [-MAX_POSITION_MM, -MAX_POSITION_MM + 1.0],
        [0.0, 2 * MAX_POSITION_MM - 1.0],
        [-MAX_POSITION_MM, MAX_POSITION_MM],
    ),
    "max_velocity_mm_min": (MIN_FEED, MAX_FEED),
    "max_acceleration_m_s2": (0.001, 200.0),
    "max_jerk_m_s3": (0.001, 100_000.0),
    "window_s": (0.001, 600.0),
}


@pytest.mark.parametrize("combination", list(itertools.product(*CORNERS.values())))
def test_the_planner_at_the_corners_of_the_ranges_refuses_cleanly_or_plans(
    combination: tuple[Any, ...],
) -> None:
    travel, velocity, acceleration, jerk, window_s = combination
    data = copy.deepcopy(example_data("linuxcnc"))
    data["axes"] = [
        {
            "name": "X",
            "travel_mm": travel,
            "park_mm": travel[0],
            "max_velocity_mm_min": velocity,
            "max_acceleration_m_s2": acceleration,
            "max_jerk_m_s3": jerk,
        }
    ]
    data["measurement"] = {
        "min_velocity_mm_min": MIN_FEED,
        "max_velocity_fraction": 1.0,
        "window_s": window_s,
        "velocity_steps": 3,
        "unfit_steps": "drop",
        "margin_mm": 0.0,
    }
    try:
        config = parse_machine(data)
    except ConfigError:
        return  # refused with its place (the lowest velocity is not below the highest)
    try:
        result = generate_programs(config)
    except PlanError as exc:
        assert exc.message  # a refusal with its numbers, never another exception
        return
    schedule = result.schedule
    assert math.isfinite(schedule.duration_s) and schedule.blocks > 0


@pytest.mark.parametrize(
    ("travel", "margin", "ends"),
    [
        ((0.0, 750.3), 5.1, (5.1, 745.2)),  # 750.3 - 5.1 = 745.1999999999999 in floats
        ((0.1, 600.7), 0.2, (0.3, 600.5)),  # 0.1 + 0.2 = 0.30000000000000004
        ((-500.3, -0.1), 5.1, (-495.2, -5.2)),
        ((0.0, 100.0), 0.0, (0.0, 100.0)),
    ],
)
def test_positions_at_the_ends_of_the_usable_travel_are_accepted(
    travel: tuple[float, float], margin: float, ends: tuple[float, float]
) -> None:
    """Compared in whole micrometres, as planned: an end is inside, 1 µm beyond is not."""
    data = example_data()
    data["axes"] = [data["axes"][0]]
    data["axes"][0].update(travel_mm=list(travel), park_mm=(travel[0] + travel[1]) / 2)
    data["measurement"].update(positions=list(ends), margin_mm=margin, velocity_steps=3)
    data["measurement"].update(max_velocity_mm_min=1000)
    schedule, _ = plan_machine(parse_machine(data))
    assert schedule.axes[0].usable_mm == ends
    assert schedule.axes[0].nominal_positions_mm == list(ends)
    for beyond in (ends[0] - 0.001, ends[1] + 0.001):
        data["measurement"]["positions"] = [beyond, (ends[0] + ends[1]) / 2]
        data["measurement"]["positions"].sort()
        with pytest.raises(ConfigError) as caught:
            parse_machine(data)
        line = next(p for p in caught.value.problems if "outside the usable travel" in p)
        assert f"[{ends[0]:g}, {ends[1]:g}] mm" in line and f"{beyond:g} mm" in line, line


def test_a_list_of_positions_is_bounded_like_a_count() -> None:
    data = example_data()
    data["axes"] = data["axes"][:1]
    data["measurement"]["positions"] = [5.0 + n for n in range(51)]
    with pytest.raises(ConfigError) as caught:
        parse_machine(data)
    assert any(p.startswith("measurement.positions:") for p in caught.value.problems)
    data["measurement"]["positions"] = [5.0 + n for n in range(50)]
    parse_machine(data)
