"""The layers of the package: data flows one way, nothing imports upward.

The package docstring (``src/ncmeasure/__init__.py``) draws them; this test keeps
the code to that drawing by reading every module's imports.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import ncmeasure

SRC = Path(ncmeasure.__file__).parent

#: Top-level module or package -> its layer; a module imports from its layer and below.
LAYERS: dict[str, int] = {
    "_version": 0,
    "errors": 0,
    "inputs": 0,
    "hosts": 0,
    "samples": 0,
    "validity": 0,
    "resources": 0,
    "profile": 0,
    "examples": 0,
    "files": 0,
    "config": 1,
    "plan": 2,
    "program": 3,
    "recording": 4,
    "links": 5,
    "acquire": 6,
    "traces": 6,
    "sim": 6,
    "analysis": 7,
    "report": 8,
    "compensation": 8,
    "store": 9,
    "demo": 9,
    "web": 10,
    "publish": 10,
    "cli": 11,
    "__main__": 12,
}
#: What the simulated drives may take from the links: the protocol knowledge only, and
#: the Modbus link's settings models, which the simulated Modbus drive serves with.
SIM_MAY_IMPORT = {
    "ncmeasure.links.canopen.bus",
    "ncmeasure.links.canopen.objects",
    "ncmeasure.links.modbus.registers",
    "ncmeasure.links.modbus.settings",
}


def _imports(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return {name for name in found if name.startswith("ncmeasure.")}


def _top(module: str) -> str:
    return module.split(".")[1]


MODULES = sorted(p for p in SRC.rglob("*.py") if p != SRC / "__init__.py")


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(SRC)))
def test_no_module_imports_a_layer_above_its_own(path: Path) -> None:
    own = path.relative_to(SRC).parts[0].removesuffix(".py")
    assert own in LAYERS, f"{own}: a new top-level module needs its layer in LAYERS"
    for module in _imports(path):
        other = _top(module)
        assert LAYERS[other] <= LAYERS[own], f"{own} imports {module}, a layer above it"
        if own == "sim" and other == "links":
            assert module in SIM_MAY_IMPORT, f"{path.name} imports {module}, not only protocol"


def test_the_bottom_imports_nothing_of_ncmeasure_but_the_bottom() -> None:
    for name in ("samples.py", "errors.py", "_version.py", "validity.py"):
        assert all(LAYERS[_top(m)] == 0 for m in _imports(SRC / name)), name
