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


def test_version_answers_before_the_command_line_is_imported() -> None:
    loaded = imported("--version")
    assert "ncmeasure" in loaded
    assert not loaded & {"typer", "click", "rich"}, sorted(loaded & {"typer", "click", "rich"})


def test_help_is_plain_and_imports_no_rich() -> None:
    # typer's rich help would import rich and markdown-it: half of --help's start-up.
    loaded = imported("--help")
    assert "typer" in loaded
    assert not loaded & {"rich", "markdown_it"}, sorted(loaded & {"rich", "markdown_it"})


def test_version_is_the_same_through_both_paths() -> None:
    from typer.testing import CliRunner

    from ncmeasure._version import __version__
    from ncmeasure.cli import app

    fast = subprocess.run(
        [sys.executable, "-m", "ncmeasure", "--version"],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    # "--debug --version" is not the fast path: typer's eager option answers it.
    full = CliRunner().invoke(app, ["--debug", "--version"])
    assert fast.stdout == full.output == f"ncmeasure {__version__}\n"


def test_the_public_api_is_still_there() -> None:
    import ncmeasure

    assert callable(ncmeasure.load_machine) and callable(ncmeasure.generate_programs)
    assert ncmeasure.Schedule.__name__ == "Schedule"
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        _ = ncmeasure.nonsense  # type: ignore[attr-defined]
    assert set(ncmeasure.__all__) <= set(dir(ncmeasure))


def test_python_can_without_mdf_support_leaves_asammdf_importable() -> None:
    code = (
        "import sys\n"
        "from ncmeasure.cli._startup import CanWithoutMdf\n"
        "sys.meta_path.insert(0, CanWithoutMdf())\n"
        "import can\n"
        "assert 'asammdf' not in sys.modules, 'python-can loaded asammdf'\n"
        "assert not any(isinstance(f, CanWithoutMdf) for f in sys.meta_path)\n"
        "import importlib.util\n"
        "if importlib.util.find_spec('asammdf') is not None:\n"
        "    import asammdf\n"
        "    assert asammdf.MDF is not None\n"
        "print(can.Message(arbitration_id=0x181, data=b'\\x01').arbitration_id)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout == "385\n"


def test_the_trace_importers_load_python_can_only_for_a_can_log() -> None:
    code = "import sys, ncmeasure.traces; print(' '.join(sorted(sys.modules)))"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )  # fmt: skip
    loaded = {name.split(".")[0] for name in done.stdout.split()}
    assert "ncmeasure" in loaded
    assert not loaded & {"can", "canopen", "pymodbus"}, sorted(loaded & {"can", "canopen"})
