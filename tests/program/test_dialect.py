"""A controller definition from --controllers-dir is checked when it is loaded.

Its format strings, regular expressions and file names are data a user wrote;
a broken one is a ``DialectError`` naming the file and the key, never a
traceback later, and no file name may lead out of the output folder.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.errors import DialectError, OutputError
from ncmeasure.program import generate_programs, load_dialect
from ncmeasure.resources import builtin_dir

Make = Callable[..., MachineConfig]


def _own(tmp_path: Path, dialect: str, pattern: str, replacement: str) -> Path:
    """A copy of a built-in controller definition with one line changed."""
    text = (builtin_dir("controllers") / f"{dialect}.toml").read_text(encoding="utf-8")
    changed, count = re.subn(pattern, lambda _: replacement, text, count=1, flags=re.M)
    assert count == 1, pattern
    folder = tmp_path / "controllers"
    folder.mkdir(exist_ok=True)
    (folder / f"{dialect}.toml").write_text(changed, encoding="utf-8")
    return folder


# (dialect, line pattern, replacement, the key and words of the refusal)
BROKEN = {
    "unknown field in main": (
        "linuxcnc",
        r"^main = .*$",
        'main = "{x}"',
        "names.main: {x} is not one of {program}, {axis}",
    ),
    "unclosed brace": (
        "linuxcnc",
        r"^main = .*$",
        'main = "{program"',
        "names.main: not a format string",
    ),
    "huge width": (
        "linuxcnc",
        r"^main = .*$",
        'main = "{program:>99999999999999999999}"',
        "names.main: width 99999999999999999999 is more than 32",
    ),
    "index access": (
        "linuxcnc",
        r"^sub = .*$",
        'sub = "{program}_{axis[5]}"',
        "names.sub: {axis[5]} is not one of {program}, {axis}",
    ),
    "attribute access": (
        "linuxcnc",
        r"^sub = .*$",
        'sub = "{program.__class__}"',
        "names.sub: {program.__class__} is not one of",
    ),
    "misspelt axis word": (
        "linuxcnc",
        r"^axis_word = .*$",
        'axis_word = "{axis}{valu}"',
        "names.axis_word: {valu} is not one of {axis}, {value}",
    ),
    "line break in the axis word": (
        "linuxcnc",
        r"^axis_word = .*$",
        'axis_word = "{axis}{value}\\nM3"',
        "names.axis_word: '\\n' is not a character of a program word",
    ),
    "huge number width": (
        "fanuc",
        r"^number_format = .*$",
        'number_format = "O{number:099999999999d}"',
        "names.number_format: width 099999999999 is more than 32",
    ),
    "text format of a number": (
        "fanuc",
        r"^number_format = .*$",
        'number_format = "O{number:s}"',
        "names.number_format: Unknown format code 's'",
    ),
    "conversion": (
        "fanuc",
        r"^number_format = .*$",
        'number_format = "O{number!r}"',
        "names.number_format: no conversion",
    ),
    "fill that is a slash": (
        "fanuc",
        r"^number_format = .*$",
        'number_format = "O{number:/>8}"',
        "names.number_format: fill character '/'",
    ),
    "nested field in a spec": (
        "fanuc",
        r"^number_format = .*$",
        'number_format = "O{number:{number}}"',
        "names.number_format: a field inside a format spec",
    ),
    "main file in the parent folder": (
        "linuxcnc",
        r"^main_file = .*$",
        'main_file = "../{name}.ngc"',
        "names.main_file: '../FRICTION_X.ngc' is not a plain file name",
    ),
    "absolute main file": (
        "linuxcnc",
        r"^main_file = .*$",
        'main_file = "/tmp/evil_{name}.ngc"',
        "names.main_file: '/tmp/evil_FRICTION_X.ngc' is not a plain file name",
    ),
    "sub file in a sub folder": (
        "linuxcnc",
        r"^sub_file = .*$",
        'sub_file = "sub/{name}.ngc"',
        "names.sub_file: 'sub/FRICTION_X.ngc' is not a plain file name",
    ),
    "main file without extension": (
        "linuxcnc",
        r"^main_file = .*$",
        'main_file = "{name}"',
        "names.main_file: needs an extension",
    ),
    "program files named like the schedule": (
        "linuxcnc",
        r"^main_file = .*$",
        'main_file = "{name}.json"',
        "names.main_file: .json is the schedule's extension",
    ),
    "program files named like the setup sheet": (
        "linuxcnc",
        r"^sub_file = .*$",
        'sub_file = "{name}.md"',
        "names.sub_file: .md is the setup sheet's extension",
    ),
    "slash in a program name": (
        "linuxcnc",
        r"^main = .*$",
        'main = "x/{program}"',
        "names.main: '/' is not a character of a program name",
    ),
    "unbalanced reader pattern": (
        "linuxcnc",
        r"^end = .*$",
        "end = '^M(0?2|30'",
        "reader.end: invalid regular expression",
    ),
    "call without its key group": (
        "linuxcnc",
        r"^call = .*$",
        "call = '^O<[A-Z0-9_]+>\\s*CALL$'",
        "reader.call: needs the group (?P<key>...)",
    ),
    "unbalanced marker pattern with an option": (
        "linuxcnc",
        r"^marker = .*$",
        "marker = ['^M62\\s*P<<marker_bit>>(']",
        "reader.marker[0]: invalid regular expression",
    ),
    "unbalanced block skip": (
        "heidenhain-iso",
        r"^skip = .*$",
        "skip = '^(%|N'",
        "blocks.skip: invalid regular expression",
    ),
    "line break in a comment opener": (
        "linuxcnc",
        r"^open = .*$",
        'open = "\\nM3 ("',
        "comments.open: '\\n' is a control character",
    ),
    "negative block step": (
        "heidenhain-iso",
        r"^step = .*$",
        "step = -10",
        "blocks.step",
    ),
    "integer of 5000 digits": (
        "linuxcnc",
        r"^program_kb = .*$",
        "program_kb = " + "1" * 5000,
        "invalid TOML: an integer of more than 4300 digits",
    ),
    "nested 1000 deep": (
        "linuxcnc",
        r"^left_out = .*$",
        "left_out = " + "[" * 1000 + "]" * 1000,
        "invalid TOML: arrays or tables nested too deep",
    ),
    "dwell scale that is not a number": (
        "linuxcnc",
        r"^dwell_scale = .*$",
        "dwell_scale = nan",
        "reader.dwell_scale",
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_a_broken_definition_is_refused_when_loaded(case: str, tmp_path: Path) -> None:
    dialect, pattern, replacement, expected = BROKEN[case]
    folder = _own(tmp_path, dialect, pattern, replacement)
    with pytest.raises(DialectError) as caught:
        load_dialect(dialect, [folder])
    text = str(caught.value)
    assert text.startswith(str(folder / f"{dialect}.toml")), text
    assert expected in text, text


def test_two_programs_in_one_file_are_refused(make_config: Make, tmp_path: Path) -> None:
    folder = _own(tmp_path, "linuxcnc", r"^sub_file = .*$", 'sub_file = "friction_all.ngc"')
    config = make_config("linuxcnc", small=True)
    with pytest.raises(DialectError, match=r"names.sub_file: .*friction_all.ngc.* twice"):
        generate_programs(config, controllers_dirs=[folder])


def test_the_writer_refuses_a_file_name_outside_the_folder(
    make_config: Make, tmp_path: Path
) -> None:
    """Whatever named the files: nothing is written beside or above the output folder."""
    result = generate_programs(make_config("linuxcnc", small=True))
    name, render = result._renders[0]
    for bad in ("../friction.ngc", str(tmp_path / "abs.ngc"), ".hidden.ngc", "a/b.ngc"):
        result._renders[0] = (bad, render)
        out = tmp_path / "work" / "out"
        out.mkdir(parents=True, exist_ok=True)
        (out / "notes.txt").write_text("notes")
        with pytest.raises(OutputError, match="not a plain file name"):
            result.write(out)
        assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["out"]
        assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert not (tmp_path / "abs.ngc").exists()
    result._renders[0] = (name, render)
