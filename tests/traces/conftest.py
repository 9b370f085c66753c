"""Fixtures of the trace importer tests: the fixture files and a machine with drive data."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from ncmeasure.config import MachineConfig

FIXTURES = Path(__file__).parent / "fixtures"


@pytest.fixture
def machine(make_config: Callable[..., MachineConfig]) -> MachineConfig:
    """The example machine: axes X, Y, Z, screw lead 20 mm, torque constant 2.1 Nm/A."""
    return make_config()


@pytest.fixture
def fixture_text() -> Callable[[str], str]:
    def read(name: str) -> str:
        return (FIXTURES / name).read_text(encoding="utf-8")

    return read
