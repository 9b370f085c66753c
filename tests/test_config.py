"""The machine file: defaults, overrides, the hash, and what it refuses."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from ncmeasure.config import config_hash, load_machine, parse_machine
from ncmeasure.errors import ConfigError
from ncmeasure.examples import example_machine
from tests.conftest import example_data, small_data


def test_example_is_valid_and_documented_defaults_apply() -> None:
    config = parse_machine(example_data())
    assert [a.name for a in config.axes] == ["X", "Y", "Z"]
    meas = config.measurement
    assert meas.window_duration_s == pytest.approx(0.4)  # 100 × 4 ms
    assert meas.spacing == "geometric"
    assert config.axis("X").rapid_mm_min == 30000
    assert [a.name for a in config.park_sequence()] == ["Z", "X", "Y"]  # vertical first
    assert [a.name for a in config.measure_sequence()] == ["X", "Y", "Z"]


def test_axis_override_replaces_only_its_fields() -> None:
    data = example_data()
    data["axes"][2]["measurement"] = {"max_velocity_mm_min": 5000, "positions": [-400, -100]}
    config = parse_machine(data)
    z = config.measurement_for(config.axis("Z"))
    assert z.max_velocity_mm_min == 5000
    assert z.positions == [-400, -100]
    assert z.velocity_steps == 50
    assert config.measurement_for(config.axis("X")).max_velocity_mm_min == 15000


def test_hash_ignores_layout_but_not_content(machine_file: Callable[[str], Path]) -> None:
    text = example_machine("linuxcnc")
    first = config_hash(load_machine(machine_file(text, "a.toml")))
    reformatted = "\n\n".join(
        line for line in text.splitlines() if not line.startswith("#")
    ).replace(" = ", "=")
    assert config_hash(load_machine(machine_file(reformatted, "b.toml"))) == first
    changed = text.replace("velocity_steps = 50", "velocity_steps = 49")
    assert config_hash(load_machine(machine_file(changed, "c.toml"))) != first


@pytest.mark.parametrize(
    ("mutate", "location"),
    [
        (lambda d: d["axes"][0].update(travel_mm=[10.0, 10.0]), "axes[0].travel_mm"),
        (lambda d: d["axes"][0].update(park_mm=900.0), "axes[0].park_mm"),
        (lambda d: d["axes"][1].update(max_velocity_mm_min=-5), "axes[1].max_velocity_mm_min"),
        (lambda d: d["axes"][1].update(max_jerk_m_s3=0), "axes[1].max_jerk_m_s3"),
        (lambda d: d["axes"][1].update(speed=3), "axes[1].speed"),
        (
            lambda d: d["measurement"].update(max_velocity_mm_min=40000),
            "measurement.max_velocity_mm_min",
        ),
        (
            lambda d: d["measurement"].update(min_velocity_mm_min=20000),
            "measurement.min_velocity_mm_min",
        ),
        (lambda d: d["measurement"].update(positions=[1000.0]), "measurement.positions[0]"),
        (lambda d: d["measurement"].update(positions=0), "measurement.positions"),
        (
            lambda d: d["measurement"].update(window_s=1.0, window_samples=10),
            "measurement.window_s",
        ),
        (lambda d: d["machine"].update(park_order=["X", "Y"]), "machine.park_order"),
        (lambda d: d["axes"].append(dict(d["axes"][0])), "axes[3].name"),
        (lambda d: d["machine"].update(name="A\nM30"), "machine.name"),
        (lambda d: d["machine"].update(program="../X"), "machine.program"),
        (lambda d: d["axes"][0].update(name="X;M30"), "axes[0].name"),
    ],
)
def test_bad_values_name_their_place(mutate: Callable[[dict], None], location: str) -> None:
    data = example_data()
    mutate(data)
    with pytest.raises(ConfigError) as caught:
        parse_machine(data)
    assert any(line.startswith(location) for line in caught.value.problems), caught.value.problems


def test_load_machine_reports_toml_syntax_with_line(machine_file: Callable[[str], Path]) -> None:
    path = machine_file("[machine]\nname = = 3\n")
    with pytest.raises(ConfigError, match=r"invalid TOML.*line 2"):
        load_machine(path)


def test_load_machine_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such file"):
        load_machine(tmp_path / "nope.toml")


def _misspelt_keys(count: int) -> dict[str, Any]:
    data = example_data()
    data["measurement"].update({f"margin_mn{number}": 5.0 for number in range(count)})
    return data


def test_every_problem_is_formatted_once_in_file_order() -> None:
    """20 000 misspelt keys: one line each, in order (formatting is linear in the count)."""
    with pytest.raises(ConfigError) as caught:
        parse_machine(_misspelt_keys(20_000))
    problems = caught.value.problems
    assert len(problems) == 20_000
    assert problems[0].startswith("measurement.margin_mn0: unknown key")
    assert problems[-1].startswith("measurement.margin_mn19999: unknown key")


def test_a_union_type_error_names_every_branch_once() -> None:
    data = example_data()
    data["measurement"]["positions"] = "three"
    data["axes"][0]["park_mm"] = "x"
    with pytest.raises(ConfigError) as caught:
        parse_machine(data)
    assert list(caught.value.problems) == [
        "axes[0].park_mm: expected a number, got the text 'x'",
        "measurement.positions: expected an integer or a list, got the text 'three'",
    ]


def test_keys_added_later_keep_a_machine_files_hash() -> None:
    """The fleet store keys a machine type by its file's hash: a file that does not set
    the keys added since (confirm_start, control_axis, retract_first, safe_end) keeps the
    hash it had before them; one that sets them otherwise gets another."""
    data = small_data("linuxcnc")
    data["machine"]["name"] = "HMX-400 #17"  # the example's name in the first release
    assert config_hash(parse_machine(data)) == "d2be1566a894c0ba"  # as in the first release
    data["machine"]["confirm_start"] = False
    assert config_hash(parse_machine(data)) != "d2be1566a894c0ba"
