"""Every TOML file a user hands ncmeasure is read the same careful way.

Machine files, controller definitions, column maps, object maps and register maps:
a number Python cannot convert, nesting deeper than Python's recursion, a FIFO, a
device or a huge file each end in one message that names the file (and the line),
never in a traceback, a hang or a full memory.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from ncmeasure.config import load_machine
from ncmeasure.errors import ConfigError, DialectError, NcMeasureError
from ncmeasure.inputs import parse_json, parse_toml
from ncmeasure.links.canopen.objects import load_object_map
from ncmeasure.links.modbus.registers import load_register_map
from ncmeasure.program import load_dialect
from ncmeasure.resources import builtin_dir
from ncmeasure.traces.columns import load_column_map
from tests.conftest import SPECIAL_REFUSALS


def _dialect(path: Path) -> object:
    return load_dialect(path.stem, [path.parent])


# (reader, file name, the error it raises)
READERS: dict[str, tuple[Callable[[Path], object], str, type[NcMeasureError]]] = {
    "machine file": (load_machine, "machine.toml", ConfigError),
    "controller definition": (_dialect, "mine.toml", DialectError),
    "column map": (load_column_map, "columns.toml", ConfigError),
    "object map": (load_object_map, "objects.toml", ConfigError),
    "register map": (load_register_map, "registers.toml", ConfigError),
}

UNREADABLE = {
    "integer of 5000 digits": (
        'name = "x"\n\nvalue = ' + "1" * 5000 + "\n",
        "4300 digits (at line 3)",
    ),
    "integer with underscores": ("value = 1" + "_1" * 4400 + "\n", "4300 digits (at line 1)"),
    "nested 1000 deep": (
        "# deep\nvalue = " + "[" * 1000 + "]" * 1000 + "\n",
        "too deep (at line 2)",
    ),
    "tables nested 1000 deep": ("value = " + "{a = " * 1000 + "1" + "}" * 1000, "too deep"),
}


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("case", sorted(UNREADABLE))
def test_what_python_cannot_parse_is_a_located_error(
    reader: str, case: str, tmp_path: Path
) -> None:
    read, name, error = READERS[reader]
    text, expected = UNREADABLE[case]
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    with pytest.raises(error) as caught:
        read(path)
    assert f"{path}: invalid TOML" in str(caught.value) and expected in str(caught.value)


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("kind", sorted(SPECIAL_REFUSALS))
def test_only_regular_files_of_sane_size_are_read(
    reader: str, kind: str, tmp_path: Path, special_file: Callable[[str, Path], Path]
) -> None:
    read, name, error = READERS[reader]
    path = special_file(kind, tmp_path / name)
    with pytest.raises(error) as caught:
        read(path)
    assert str(caught.value).startswith(f"{path}: ") and SPECIAL_REFUSALS[kind] in str(caught.value)


def test_a_valid_copy_of_a_builtin_dialect_still_reads(tmp_path: Path) -> None:
    shutil.copy(builtin_dir("controllers") / "fanuc.toml", tmp_path / "fanuc.toml")
    assert load_dialect("fanuc", [tmp_path]).name == "fanuc"


def test_strings_and_comments_do_not_count_as_nesting() -> None:
    text = 'a = "' + "[" * 500 + '"\n# ' + "{" * 500 + "\nb = '" + "[" * 500 + "'\n"
    assert parse_toml(text, "t.toml")["a"] == "[" * 500
    with pytest.raises(
        ConfigError, match=r"t\.toml: invalid TOML: arrays or tables nested too deep \(at line 4\)"
    ):
        parse_toml(text + "c = " + "[" * 1000 + "]" * 1000, "t.toml")


def test_json_beyond_python_is_located() -> None:
    with pytest.raises(
        ConfigError, match=r"s\.json: invalid JSON: .*nested too deep \(at line 2\)"
    ):
        parse_json("\n" + "[" * 100_000, "s.json", ConfigError)
    with pytest.raises(ConfigError, match=r"s\.json: invalid JSON: an integer of more than 4300"):
        parse_json('{"a": ' + "1" * 5000 + "}", "s.json", ConfigError)


@pytest.mark.parametrize("what", ["results", "meta"])
def test_results_and_recordings_are_read_as_bounded_regular_files(
    tmp_path: Path, what: str
) -> None:
    """results.json and a recording's meta.json: brackets nested deep, or a device, are
    located errors, never a traceback or a read without end."""
    from ncmeasure.errors import NcMeasureError
    from ncmeasure.formats.results import load_results
    from ncmeasure.recording import read_recording

    folder = tmp_path / "run"
    folder.mkdir()
    target = tmp_path / "results.json" if what == "results" else folder / "meta.json"
    (folder / "samples.bin").write_bytes(b"")
    read = (lambda: load_results(target)) if what == "results" else (lambda: read_recording(folder))
    target.write_text("[" * 100_000)
    with pytest.raises(NcMeasureError, match=r"invalid JSON: .*nest"):
        read()
    target.unlink()
    target.symlink_to("/dev/zero")
    with pytest.raises(NcMeasureError, match="not a regular file"):
        read()
