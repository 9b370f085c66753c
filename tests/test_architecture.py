"""The layers are kept by tools: import-linter's contracts and ruff's rule against relative imports.

``pyproject.toml`` holds the contracts (``[tool.importlinter]``) that ``.ci/run``
checks with ``lint-imports``; ``docs/architecture.md`` draws them. These tests
plant each kind of violation in a copy of the package and show that the tools
refuse it, so a contract that stopped checking anything would be noticed.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import ncmeasure

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "src" / "ncmeasure"
PLANNER = Path("plan") / "axis.py"
"""A module low in the pipeline, where an upward import is a violation."""
ANALYSIS = Path("analysis") / "__init__.py"
"""A module that may import the layers below it, but neither a drive link nor a program."""
SIMULATOR = Path("sim") / "cia402" / "drive.py"
"""A simulated drive: it may know the protocol (object maps, settings), not the link."""
TIMEOUT_S = 600


def _tool(name: str) -> str:
    found = shutil.which(name) or shutil.which(name, path=str(Path(sys.executable).parent))
    assert found is not None, f"{name} is not installed (pip install '.[dev]')"
    return found


@pytest.fixture
def copy(tmp_path: Path) -> Path:
    """The package and its configuration, copied where a planted import harms nothing."""
    assert SOURCE.is_dir(), f"{SOURCE}: the tests run from a checkout of the project"
    shutil.copytree(
        SOURCE, tmp_path / "src" / "ncmeasure", ignore=shutil.ignore_patterns("__pycache__")
    )
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


def _lint_imports(folder: Path) -> subprocess.CompletedProcess[str]:
    # The copy comes first on the path, before any installed ncmeasure.
    environment = {**os.environ, "PYTHONPATH": str(folder / "src")}
    return subprocess.run(
        [_tool("lint-imports"), "--no-cache", str(folder / "pyproject.toml")],
        cwd=folder,
        env=environment,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )


def _ruff(folder: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [_tool("ruff"), "check", "--no-cache", "--select", "TID", "src"],
        cwd=folder,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )


def _plant(folder: Path, line: str, module: Path = PLANNER) -> None:
    path = folder / "src" / "ncmeasure" / module
    with path.open("a", encoding="utf-8") as file:
        file.write(f"\n{line}  # noqa: E402, F401\n")


def test_the_package_keeps_its_contracts(copy: Path) -> None:
    found = _lint_imports(copy)
    assert found.returncode == 0, found.stdout + found.stderr
    assert "BROKEN" not in found.stdout and "KEPT" in found.stdout
    assert _ruff(copy).returncode == 0


@pytest.mark.parametrize(
    ("module", "line", "contract"),
    [
        (PLANNER, "from ncmeasure.cli import app", "a layer imports only the layers below it"),
        (PLANNER, "from ..cli import app", "a layer imports only the layers below it"),
        (PLANNER, "from ncmeasure import load_machine", "not from ncmeasure"),
        (PLANNER, "import ncmeasure", "not from ncmeasure"),
        (ANALYSIS, "from ncmeasure.links.base import DriveLink", "know nothing of each other"),
        (ANALYSIS, "import can", "never talk to a drive"),
        (SIMULATOR, "from ncmeasure.links.canopen.link import CanOpenLink", "not the links"),
    ],
    ids=["upward", "upward-relative", "from-the-package", "the-package", "sibling", "bus", "sim"],
)
def test_lint_imports_refuses_a_planted_import(
    copy: Path, module: Path, line: str, contract: str
) -> None:
    _plant(copy, line, module)
    found = _lint_imports(copy)
    assert found.returncode != 0, found.stdout
    broken = found.stdout.split("Broken contracts", 1)[-1]
    assert contract in " ".join(broken.split()), found.stdout


@pytest.mark.parametrize("line", ["from .moves import to_mm", "from ..cli import app"])
def test_ruff_refuses_a_relative_import(copy: Path, line: str) -> None:
    _plant(copy, line)
    found = _ruff(copy)
    assert found.returncode != 0 and "TID252" in found.stdout, found.stdout


def test_the_copy_is_what_lint_imports_reads(copy: Path) -> None:
    """The planted copy, not the installed package, is analysed (else every plant passes)."""
    environment = {**os.environ, "PYTHONPATH": str(copy / "src")}
    where = subprocess.run(
        [sys.executable, "-c", "import ncmeasure; print(ncmeasure.__file__)"],
        env=environment,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=True,
    ).stdout.strip()
    assert Path(where).is_relative_to(copy), (where, ncmeasure.__file__)


def test_every_module_of_the_package_has_its_layer() -> None:
    """A module in no layer is bound by no layers contract: a new one must be placed."""
    with (ROOT / "pyproject.toml").open("rb") as file:
        contracts = tomllib.load(file)["tool"]["importlinter"]["contracts"]
    layers = next(c for c in contracts if c["type"] == "layers")["layers"]
    placed = {name.strip() for layer in layers for name in re.split(r"[|:]", layer)}
    present = {
        f"ncmeasure.{path.name.removesuffix('.py')}"
        for path in SOURCE.iterdir()
        if (path.suffix == ".py" and path.name != "__init__.py")
        or (path.is_dir() and (path / "__init__.py").is_file())
    }
    assert present - placed == set(), "add them to the layers contract in pyproject.toml"
    assert placed - present == set(), "the layers contract names modules that are gone"
