"""Shared fixtures: example machines, the golden-file switch, LinuxCNC's rs274."""

from __future__ import annotations

import datetime as dt
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.examples import example_machine
from ncmeasure.program import available_dialects

DIALECTS = sorted(available_dialects())
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
