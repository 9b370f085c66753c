"""Shared fixtures: example machines, the golden-file switch, LinuxCNC's rs274."""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.examples import example_machine
from ncmeasure.program import available_dialects

DIALECTS = sorted(available_dialects())
SHARED_FIXTURES = Path(__file__).resolve().parents[2] / "shared" / "fixtures"
"""The project's read-only fixtures beside the clone (real drives' EDS files, traces)."""


def shared_fixture(*parts: str) -> Path:
    """A file of ../shared/fixtures; its folder missing fails under CI=true, else skips."""
    folder = SHARED_FIXTURES / parts[0]
    if not folder.is_dir():
        message = f"fixtures folder {folder} is absent"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{message}: CI has ../shared beside the clone")
        pytest.skip(message)
    return SHARED_FIXTURES.joinpath(*parts)


FIXED_TIME = dt.datetime(2026, 1, 15, 8, 30, tzinfo=dt.UTC)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--update-golden",
        action="store_true",
        help="rewrite tests/golden/ from the current output instead of comparing",
    )


@pytest.fixture
def update_golden(request: pytest.FixtureRequest) -> bool:
    return bool(request.config.getoption("--update-golden"))


def example_data(controller: str = "linuxcnc") -> dict[str, Any]:
    """The `ncmeasure init` example as a dict (50 steps, 3 positions, 3 axes)."""
    return tomllib.loads(example_machine(controller))


def small_data(controller: str = "linuxcnc") -> dict[str, Any]:
    """The example reduced to a few steps, for golden files that stay readable."""
    data = example_data(controller)
    data["measurement"].update(velocity_steps=4, warmup_strokes=1, min_velocity_mm_min=100)
    return data


@pytest.fixture
def make_config() -> Callable[..., MachineConfig]:
    def make(
        controller: str = "linuxcnc", small: bool = False, **measurement: Any
    ) -> MachineConfig:
        data = small_data(controller) if small else example_data(controller)
        data["measurement"].update(measurement)
        return parse_machine(data)

    return make


@pytest.fixture
def machine_file(tmp_path: Path) -> Callable[[str], Path]:
    def write(text: str, name: str = "machine.toml") -> Path:
        path = tmp_path / name
        path.write_text(text, encoding="utf-8")
        return path

    return write


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return (
            "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()) + " }"
        )
    return repr(value)  # ints and floats, inf and nan included, are TOML as Python writes them


def machine_toml(data: dict[str, Any]) -> str:
    """A machine dict as TOML text: top-level tables, then one [[axes]] table per axis."""
    lines = []
    for key, value in data.items():
        if isinstance(value, dict):
            lines.append(f"[{_toml_key(key)}]")
            lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()]
        elif key != "axes" or not isinstance(value, list):
            lines.insert(0, f"{_toml_key(key)} = {_toml_value(value)}")
    for axis in data.get("axes", []) if isinstance(data.get("axes"), list) else []:
        lines.append("[[axes]]")
        if isinstance(axis, dict):
            lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in axis.items()]
    return "\n".join(lines) + "\n"
