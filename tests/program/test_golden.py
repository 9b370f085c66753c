"""Golden files: the 3-axis example, reduced to 4 steps, in every dialect.

Run ``pytest --update-golden`` after an intended change of a template and
review the diff of tests/golden/ like code.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig
from ncmeasure.program import generate_programs
from tests.conftest import DIALECTS, FIXED_TIME

GOLDEN = Path(__file__).parent.parent / "golden"


def test_every_dialect_has_golden_files() -> None:
    assert DIALECTS == ["fanuc", "heidenhain-iso", "linuxcnc", "sinumerik-840d", "twincat"]
    for dialect in DIALECTS:
        assert (GOLDEN / dialect).is_dir(), f"run pytest --update-golden to create {dialect}"


@pytest.mark.parametrize("dialect", DIALECTS)
def test_programs_match_golden_files(
    dialect: str, make_config: Callable[..., MachineConfig], update_golden: bool
) -> None:
    result = generate_programs(make_config(dialect, small=True), generated=FIXED_TIME)
    folder = GOLDEN / dialect
    if update_golden:
        folder.mkdir(parents=True, exist_ok=True)
        for old in folder.iterdir():
            old.unlink()
        for name, text in result.files.items():
            (folder / name).write_text(text, encoding="utf-8", newline="\n")
    expected = {p.name: p.read_text(encoding="utf-8") for p in folder.iterdir()}
    assert sorted(result.files) == sorted(expected)
    for name, text in result.files.items():
        assert text == expected[name], f"{dialect}/{name} differs from the golden file"
