"""Start-up: ``ncmeasure --version`` and ``--help`` import only the command line itself.

What a command imports is counted, not timed: ``python -X importtime`` names every
module a process imports, whatever else the machine is doing.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

#: Packages a command imports only when it works with them.
HEAVY = ("numpy", "scipy", "pandas", "pydantic", "jinja2", "can", "canopen", "pymodbus",
         "asammdf", "matplotlib", "sqlalchemy")  # fmt: skip


def imported(*args: str) -> set[str]:
    """The top-level names of the modules ``ncmeasure ARGS`` imports."""
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "ncmeasure", *args],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    names = set()
    for line in done.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            names.add(line.rsplit("|", 1)[1].strip().split(".")[0])
    return names


@pytest.mark.parametrize(
    ("args", "allowed"),
    [
        (("--version",), set()),
        (("--help",), set()),
        (("generate", "--help"), {"pydantic"}),  # typer's own coercion of the arguments
    ],
)
def test_version_and_help_import_no_heavy_package(args: tuple[str, ...], allowed: set[str]) -> None:
    loaded = imported(*args)
    assert "ncmeasure" in loaded  # the parse saw the imports at all
    assert not loaded & (set(HEAVY) - allowed), sorted(loaded & set(HEAVY))


def test_the_public_api_is_still_there() -> None:
    import ncmeasure

    assert callable(ncmeasure.load_machine) and callable(ncmeasure.generate_programs)
    assert ncmeasure.Schedule.__name__ == "Schedule"
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        _ = ncmeasure.nonsense  # type: ignore[attr-defined]
    assert set(ncmeasure.__all__) <= set(dir(ncmeasure))
