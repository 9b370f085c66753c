"""Only the dialect's own M functions, variables and outputs: in the options and in the programs.

Each controller definition states its reserved M functions and the variable and
output ranges a marker may use (``[codes]``); ``generate`` refuses options
outside them, and ``check`` refuses any program that writes something else.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest

from ncmeasure.config import parse_machine
from ncmeasure.errors import ConfigError, DialectError, ProgramCheckError
from ncmeasure.program import check_programs, generate_programs, load_dialect
from ncmeasure.resources import builtin_dir
from tests.conftest import DIALECTS, FIXED_TIME, small_data


def machine(dialect: str, **options: Any) -> dict[str, Any]:
    data = small_data(dialect)
    data["machine"]["controller_options"] = options
    return data


# (dialect, options, the place and the words of the refusal)
REFUSED = {
    "heidenhain spindle on and program end": (
        "heidenhain-iso",
        {"marker_m_on": 3, "marker_m_off": 2},
        ["marker_m_on: M3 is reserved", "spindle on", "marker_m_off: M2 is reserved"],
    ),
    "heidenhain on equals off": (
        "heidenhain-iso",
        {"marker_m_on": 250, "marker_m_off": 250},
        ["marker_m_off: M250 is also machine.controller_options.marker_m_on"],
    ),
    "heidenhain beyond M999": (
        "heidenhain-iso",
        {"marker_m_on": 1250, "marker_m_off": 251},
        ["marker_m_on: M1250 is not an M function"],
    ),
    "twincat spindle on": ("twincat", {"marker_m": 3}, ["marker_m: M3 is reserved"]),
    "twincat on equals off": (
        "twincat",
        {"marker_m": 81, "marker_m_off": 81},
        ["marker_m_off: M81 is also machine.controller_options.marker_m"],
    ),
    "twincat subroutine end": ("twincat", {"marker_m_off": 17}, ["M17 is reserved"]),
    "fanuc tool change": (
        "fanuc",
        {"marker_sync_m": 6},
        ["marker_sync_m: M6 is reserved", "tool change"],
    ),
    "fanuc subprogram call": ("fanuc", {"marker_sync_m": 98}, ["marker_sync_m: M98 is reserved"]),
    "fanuc macro alarm": (
        "fanuc",
        {"marker_variable": 3000},
        ["marker_variable: 3000 is not a common macro variable"],
    ),
    "fanuc tool wear offset": (
        "fanuc",
        {"marker_variable": 2001},
        ["marker_variable: 2001 is not a common"],
    ),
    "fanuc read-only position": (
        "fanuc",
        {"marker_variable": 5001},
        ["marker_variable: 5001 is not a common"],
    ),
    "fanuc null variable": (
        "fanuc",
        {"marker_variable": 0},
        ["marker_variable: 0 is not a common"],
    ),
    "sinumerik R beyond the default count": (
        "sinumerik-840d",
        {"marker_r": 99999},
        ["marker_r: 99999 is not an R parameter"],
    ),
    "linuxcnc output beyond 63": (
        "linuxcnc",
        {"marker_bit": 64},
        ["marker_bit: 64 is not a digital output"],
    ),
    "linuxcnc analog beyond 63": (
        "linuxcnc",
        {"marker_analog": 99},
        ["marker_analog: 99 is not an analog output"],
    ),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_reserved_or_out_of_range_marker_options_are_refused(case: str, tmp_path: Path) -> None:
    dialect, options, expected = REFUSED[case]
    config = parse_machine(machine(dialect, **options))
    with pytest.raises(ConfigError) as caught:
        generate_programs(config)
    text = "\n".join(caught.value.problems)
    for words in expected:
        assert words in text, text
    assert "machine.controller_options." in text


@pytest.mark.parametrize("dialect", DIALECTS)
def test_every_dialect_states_its_codes_with_sources(dialect: str) -> None:
    codes = load_dialect(dialect).codes
    assert codes.sources
    # stops, ends, spindle, tool change, coolant, subprogram call and end
    for number in (*range(10), 30, 98, 99):
        assert codes.reserved(number) or number in codes.program_m, number
    assert all(rule.source for rule in codes.options.values())


def slip_in(folder: Path, edits: list[tuple[str, str]], options: dict[str, Any]) -> None:
    """A hand edit: the programs and their schedule.json say another marker."""
    changed = 0
    for path in folder.iterdir():
        if path.name != "schedule.json":
            text = path.read_text()
            for old, new in edits:
                text, count = re.subn(old, new, text, flags=re.M)
                changed += count
            path.write_text(text)
    assert changed
    schedule = json.loads((folder / "schedule.json").read_text())
    schedule["controller_options"].update(options)
    (folder / "schedule.json").write_text(json.dumps(schedule))


# (dialect, valid options, edits of every program file, options slipped into schedule.json)
SLIPPED: dict[str, tuple[str, dict[str, int], list[tuple[str, str]], dict[str, int]]] = {
    "heidenhain M3": (
        "heidenhain-iso",
        {"marker_m_on": 250, "marker_m_off": 251},
        [(r"\bM250\b", "M3")],
        {"marker_m_on": 3},
    ),
    "twincat M3": ("twincat", {}, [(r"^M80=", "M3=")], {"marker_m": 3}),
    "fanuc #3000": ("fanuc", {}, [(r"^#500=", "#3000=")], {"marker_variable": 3000}),
    "sinumerik R99999": (
        "sinumerik-840d",
        {},
        [(r"\$R\[1\]", "$R[99999]"), (r"^R1=", "R99999=")],
        {"marker_r": 99999},
    ),
    "linuxcnc P64": ("linuxcnc", {}, [(r"^M6([235]) P0$", r"M6\1 P64")], {"marker_bit": 64}),
}


@pytest.mark.parametrize("case", sorted(SLIPPED))
def test_check_refuses_a_reserved_code_slipped_into_a_program(case: str, tmp_path: Path) -> None:
    dialect, valid, edits, options = SLIPPED[case]
    generate_programs(parse_machine(machine(dialect, **valid)), generated=FIXED_TIME).write(
        tmp_path
    )
    assert check_programs(tmp_path).ok
    slip_in(tmp_path, edits, options)
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(tmp_path)
    problems = caught.value.problems
    assert any(p.startswith("schedule.json: controller_options.") for p in problems), problems
    assert any(re.match(r"\S+\.\w+:\d+: ", p) for p in problems), problems


def test_check_refuses_a_code_the_schedule_does_not_name(tmp_path: Path) -> None:
    """The options are valid, but the program writes another variable than they say."""
    generate_programs(parse_machine(machine("fanuc")), generated=FIXED_TIME).write(tmp_path)
    path = tmp_path / "O1001.nc"
    path.write_text(path.read_text().replace("#500=0", "#501=0", 1))
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(tmp_path)
    expected = "variable 501 is written, but the marker is controller_options.marker_variable = 500"
    assert any(expected in p for p in caught.value.problems), caught.value.problems


def test_a_template_that_starts_the_spindle_is_not_written(tmp_path: Path) -> None:
    templates = tmp_path / "templates"
    shutil.copytree(builtin_dir("templates") / "linuxcnc", templates / "linuxcnc")
    main = templates / "linuxcnc" / "main.j2"
    main.write_text(main.read_text().replace("G64 P0.005", "G64 P0.005\nM3 S1000"))
    out = tmp_path / "out"
    result = generate_programs(parse_machine(machine("linuxcnc")), templates_dirs=[templates])
    with pytest.raises(DialectError, match="fail ncmeasure's own check") as caught:
        result.write(out)
    assert any("M3 (spindle on, clockwise) is reserved" in p for p in caught.value.problems)
    assert not out.exists()


def test_fanuc_comments_are_ascii_and_check_refuses_other_text(tmp_path: Path) -> None:
    data = machine("fanuc")
    data["machine"]["name"] = "Fräse 3 机床 Müller"
    result = generate_programs(parse_machine(data), generated=FIXED_TIME)
    result.write(tmp_path)
    main = (tmp_path / "O1000.nc").read_text(encoding="utf-8")
    assert "(MACHINE FRASE 3  MULLER)" in main
    assert all(p.read_bytes().isascii() for p in tmp_path.glob("*.nc"))
    assert check_programs(tmp_path).ok
    path = tmp_path / "O1001.nc"
    lines = path.read_text().splitlines()
    lines.insert(3, "(ACHSE X – FRÄSE)")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(ProgramCheckError) as caught:
        check_programs(tmp_path)
    assert (
        "O1001.nc:4: character '–' (U+2013) is not ASCII: FANUC 0i / 30i (custom macro B) "
        "reads printable ASCII only (ISO/EIA code)"
    ) in caught.value.problems


@pytest.mark.parametrize(
    ("dialect", "name"),
    [("sinumerik-840d", "I"), ("sinumerik-840d", "J"), ("sinumerik-840d", "K"), ("twincat", "XX")],
)
def test_axis_names_a_control_reads_as_something_else_are_refused(dialect: str, name: str) -> None:
    data = machine(dialect)
    data["axes"][0]["name"] = name
    with pytest.raises(ConfigError, match=rf"axes\[0\]\.name: '{name}' is not an axis name"):
        generate_programs(parse_machine(data))


@pytest.mark.parametrize("dialect", ["sinumerik-840d", "twincat"])
def test_numbered_axis_names_are_written_and_read(dialect: str, tmp_path: Path) -> None:
    data = machine(dialect)
    data["axes"][0]["name"] = "X1"
    generate_programs(parse_machine(data), generated=FIXED_TIME).write(tmp_path)
    assert "X1=" in "".join(p.read_text() for p in tmp_path.iterdir() if p.suffix != ".json")
    assert check_programs(tmp_path).ok


def test_a_dialect_option_without_a_rule_is_a_broken_dialect(tmp_path: Path) -> None:
    text = (builtin_dir("controllers") / "linuxcnc.toml").read_text()
    text = text.replace("marker_analog = 0\n", "marker_analog = 0\nmarker_extra = 5\n", 1)
    (tmp_path / "linuxcnc.toml").write_text(text)
    with pytest.raises(DialectError, match=r"option marker_extra has no rule"):
        load_dialect("linuxcnc", [tmp_path])


@pytest.mark.parametrize("dialect", DIALECTS)
def test_the_documented_codes_are_the_dialects(dialect: str) -> None:
    """docs/controllers.md lists what each controller definition says."""
    docs = (Path(__file__).parents[2] / "docs" / "controllers.md").read_text(encoding="utf-8")
    row = next(line for line in docs.splitlines() if line.startswith(f"| `{dialect}` | M"))
    codes = load_dialect(dialect).codes
    assert row.split(" | ")[1] == ", ".join(f"M{m}" for m in codes.program_m)
    reserved = ", ".join(f"{a}" if a == b else f"{a}–{b}" for a, b in codes.reserved_m)
    assert row.split(" | ")[2] == reserved
    for key, rule in codes.options.items():
        assert f"`{key}`" in row
        allowed = ", ".join(f"{a}" if a == b else f"{a}–{b}" for a, b in rule.allowed)
        assert allowed in row, (key, allowed)


def test_a_marker_rule_beyond_the_m_range_is_a_broken_dialect(tmp_path: Path) -> None:
    text = (builtin_dir("controllers") / "twincat.toml").read_text()
    text = text.replace("m_range = [0, 999]", "m_range = [0, 99]", 1)
    (tmp_path / "twincat.toml").write_text(text)
    with pytest.raises(DialectError, match=r"allows M functions outside m_range 0-99"):
        load_dialect("twincat", [tmp_path])
