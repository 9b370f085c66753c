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
from ncmeasure.config import parse_machine
from ncmeasure.errors import DialectError
from ncmeasure.program import generate_programs
from ncmeasure.program.sandbox import MAX_RANGE, MAX_TEXT
from ncmeasure.resources import builtin_dir
from tests.conftest import FIXED_TIME, machine_toml, small_data

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
    assert "(3 AXES HMX-400 #17 2)" in (tmp_path / "out" / "friction.ngc").read_text()
