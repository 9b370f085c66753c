"""A user's template can choose words, not hang the generator, fill the memory or change the plan.

Each template here is one a careless or hostile template folder holds; every
one must end in a located ``DialectError`` (exit 2 on the command line, no
traceback) and leave the output folder as it was.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import MAX_WINDOWS, parse_machine
from ncmeasure.errors import DialectError
from ncmeasure.program import check_programs, generate_programs
from ncmeasure.program.sandbox import BUILT_PER_MOVE, MAX_RANGE, MAX_TEXT, STEPS_PER_MOVE
from ncmeasure.resources import builtin_dir
from tests.conftest import DIALECTS, FIXED_TIME, example_data, machine_toml, small_data

# (what the main template holds, words of the message)
HOSTILE = {
    "a huge range": ("{{ range(10**9) | length }}", f"more than {MAX_RANGE}"),
    "a huge range in a loop": (
        "{% for i in range(10**9) %}x{% endfor %}",
        f"more than {MAX_RANGE}",
    ),
    "nested loops": (
        "{% for i in range(100000) %}{% for j in range(100000) %}{% endfor %}{% endfor %}",
        "steps",
    ),
    "nested loops over a literal": (
        "{% set s = 'abcdefghij' %}{% for a in s %}{% for b in s %}{% for c in s %}"
        "{% for d in s %}{% for e in s %}{% for f in s %}{% for g in s %}{% endfor %}"
        "{% endfor %}{% endfor %}{% endfor %}{% endfor %}{% endfor %}{% endfor %}",
        "steps",
    ),
    "a gigabyte string": ('{{ "x" * 10**9 }}', f"more than {MAX_TEXT}"),
    "a gigabyte list": ("{{ ([1] * 10**9) | length }}", f"more than {MAX_TEXT}"),
    "doubling by concatenation": (
        '{% set ns = namespace(s="x") %}{% for i in range(64) %}{% set ns.s = ns.s ~ ns.s %}'
        "{% endfor %}{{ ns.s | length }}",
        f"more than {MAX_TEXT}",
    ),
    "doubling by addition": (
        '{% set ns = namespace(s="x") %}{% for i in range(64) %}{% set ns.s = ns.s + ns.s %}'
        "{% endfor %}{{ ns.s | length }}",
        f"more than {MAX_TEXT}",
    ),
    "a huge power": ("{{ 2 ** 100000000 }}", "power"),
    "center filter": ('{{ "x" | center(10**9) }}', "No filter named 'center'"),
    "format filter": ('{{ "%1000000000d" | format(1) }}', "No filter named 'format'"),
    "str.format": ('{{ "{:>1000000000}".format(1) }}', "format"),
    "lipsum": ("{{ lipsum(10**9) }}", "lipsum"),
    "recursion": ("{% macro r(n) %}{{ r(n) }}{% endmacro %}{{ r(1) }}", "too deep"),
    "changing the options": ('{{ v.options.update({"marker_bit": 7}) }}', "update"),
    "changing the park list": ("{{ v.park.append(1) }}", "append"),
    "reaching into Python": ("{{ v.__class__.__mro__ }}", "__class__"),
    "joining a huge list": (
        '{% set big = (["x" * 1000000] * 3000) | join %}{{ big | length }}',
        f"more than {MAX_TEXT}",
    ),
    "a huge list as a string": (
        '{{ (["x" * 1000000] * 3000) | string | length }}',
        "writes words and numbers",
    ),
    "a huge list concatenated": ('{{ (["x" * 1000000] * 3000) ~ "" }}', "words and numbers"),
    "a huge list written": ('{{ ["x" * 1000000] * 3000 }}', "writes words and numbers"),
    "many distinct large strings": (
        "{% set ns = namespace(l=[]) %}{% for i in range(3000) %}"
        '{% set ns.l = ns.l + [("x" * 999990) ~ i] %}{% endfor %}',
        "characters in all",
    ),
    "a filter on a large string in a long loop": (
        '{% set ns = namespace(s="x" * 1000000) %}{% for i in range(100000) %}'
        "{% for j in range(10) %}{% set t = ns.s | upper %}{% endfor %}{% endfor %}",
        "characters in all",
    ),
    "a filter reading a large string in a long loop": (
        '{% set ns = namespace(s="x" * 1000000) %}{% for i in range(100000) %}'
        "{% for j in range(10) %}{% if (ns.s | length) > 0 %}{% endif %}{% endfor %}"
        "{% endfor %}",
        "steps",
    ),
    "percent formatting": ('{{ "%1000000000d" % 1 }}', "'%' formatting"),
    "squaring a number again and again": (
        "{% set ns = namespace(n=2) %}{% for i in range(40) %}{% set ns.n = ns.n * ns.n %}"
        "{% endfor %}{{ ns.n > 0 }}",
        "digits",
    ),
    "a block set built in a loop": (
        '{% set x %}{% for i in range(100000) %}{{ "x" * 100000 }}{% endfor %}{% endset %}'
        "{{ x | length }}",
        "characters in all",
    ),
    "a block set of a large literal in a loop": (
        "{% set x %}{% for i in range(100000) %}" + "y" * 100_000 + "{% endfor %}{% endset %}"
        "{{ x | length }}",
        "characters in all",
    ),
    "a macro returning a huge text": (
        "{% macro m() %}{% for i in range(100000) %}{{ 'x' * 100000 }}{% endfor %}"
        "{% endmacro %}{{ m() | length }}",
        "characters in all",
    ),
    "a filter block over a large literal": (
        "{% filter upper %}{% for i in range(100000) %}" + "z" * 100_000 + "{% endfor %}"
        "{% endfilter %}",
        "characters in all",
    ),
    "an operation on the wrong types": ('{{ 1 + "a" }}', "unsupported operand"),
    "a division by zero": ("{{ 1 // 0 }}", "division"),
}


def own_main(tmp_path: Path, text: str) -> Path:
    templates = tmp_path / "templates"
    shutil.copytree(builtin_dir("templates") / "linuxcnc", templates / "linuxcnc")
    (templates / "linuxcnc" / "main.j2").write_text(text + "\n")
    return templates


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_a_hostile_template_is_stopped_with_its_place(case: str, tmp_path: Path) -> None:
    text, words = HOSTILE[case]
    templates = own_main(tmp_path, text)
    out = tmp_path / "out"
    result = generate_programs(
        parse_machine(small_data("linuxcnc")), templates_dirs=[templates], generated=FIXED_TIME
    )
    with pytest.raises(DialectError) as caught:
        result.write(out)
    message = caught.value.message
    assert message.startswith("template ") and "main.j2:1" in message, message
    assert words in message, message
    assert not out.exists()


@pytest.mark.parametrize("case", ["nested loops", "a gigabyte string", "changing the options"])
def test_the_command_line_says_where_and_exits_2(case: str, tmp_path: Path) -> None:
    templates = own_main(tmp_path, HOSTILE[case][0])
    machine = tmp_path / "m.toml"
    machine.write_text(machine_toml(small_data("linuxcnc")))
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("kept")
    result = CliRunner().invoke(
        app, ["generate", str(machine), "-o", str(out), "--templates-dir", str(templates)]
    )
    assert result.exit_code == 2, result.output
    assert "main.j2:1" in result.stderr
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


def test_what_a_template_may_do_still_works(tmp_path: Path) -> None:
    """Loops, namespaces, loop variables, string methods and the dialect's filters."""
    text = (builtin_dir("templates") / "linuxcnc" / "main.j2").read_text()
    extra = (
        "{% set ns = namespace(n=0) %}{% for axis in v.park %}{% set ns.n = ns.n + 1 %}"
        "{% if loop.last %}({{ ns.n }} AXES {{ v.machine.upper() }} "
        "{{ v.options.items() | list | length }}){% endif %}{% endfor %}\n"
    )
    templates = own_main(tmp_path, text.replace("G64 P0.005\n", "G64 P0.005\n" + extra))
    result = generate_programs(
        parse_machine(small_data("linuxcnc")), templates_dirs=[templates], generated=FIXED_TIME
    )
    result.write(tmp_path / "out")
    assert "(3 AXES HMX-400 2)" in (tmp_path / "out" / "friction.ngc").read_text()


@pytest.mark.parametrize("dialect", DIALECTS)
def test_the_builtin_templates_stay_far_inside_the_budgets(dialect: str) -> None:
    """Steps and characters per planned move of the built-in templates, against the budgets:
    the same ratio holds for the largest plan the limits allow."""
    data = example_data(dialect)
    data["measurement"]["dwell_s"] = 0.5 if dialect != "heidenhain-iso" else 0.0
    if dialect == "heidenhain-iso":
        data["machine"]["controller_options"] = {"marker_m_on": 50, "marker_m_off": 51}
    result = generate_programs(parse_machine(data), generated=FIXED_TIME)
    assert result.files  # renders every file once
    steps, built = result._env.used  # type: ignore[union-attr]
    moves = result._moves
    assert steps < STEPS_PER_MOVE * moves / 4, steps / moves
    assert built < BUILT_PER_MOVE * moves / 4, built / moves


def test_the_largest_plan_the_limits_allow_renders(tmp_path: Path) -> None:
    """50 000 windows (limits.max_windows at its ceiling) of 1 ms on a 1 mm axis."""
    data = {
        "machine": {"name": "largest", "controller": "linuxcnc"},
        "axes": [
            {
                "name": "X",
                "travel_mm": [0.0, 1.0],
                "park_mm": 0.5,
                "max_velocity_mm_min": 1_000_000,
                "max_acceleration_m_s2": 200,
                "max_jerk_m_s3": 100_000,
            }
        ],
        "measurement": {
            "positions": 50,
            "velocity_steps": 500,
            "spacing": "linear",
            "min_velocity_mm_min": 100,
            "max_velocity_mm_min": 600,
            "window_s": 0.001,
            "settle_s": 0,
            "dynamics_safety": 1,
            "margin_mm": 0,
            "warmup_strokes": 0,
            "dwell_s": 0.001,
        },
        "limits": {"max_windows": MAX_WINDOWS},
    }
    result = generate_programs(parse_machine(data), generated=FIXED_TIME)
    assert sum(len(axis.windows) for axis in result.schedule.axes) == MAX_WINDOWS
    result.write(tmp_path / "out")
    report = check_programs(tmp_path / "out")
    assert report.windows_found == MAX_WINDOWS
