"""Shared fixtures: example machines, the golden-file switch, LinuxCNC's rs274."""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import threading
import tomllib
from collections.abc import Callable, Iterator
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


def optional(module: str) -> Any:
    """An optional library a test needs: skipped where it is not installed, except in CI,
    which installs every extra (a missing one there is a failure, not a silent skip)."""
    if os.environ.get("CI"):
        import importlib

        return importlib.import_module(module)
    return pytest.importorskip(module)


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


def _unblock_later(fifo: Path, seconds: float) -> None:
    """Open ``fifo`` for writing after ``seconds``: a reader stuck on it gets end-of-file."""

    def unblock() -> None:
        if not done.wait(seconds):
            try:
                fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:  # nobody reads it: nothing to unblock
                return
            os.close(fd)

    done = threading.Event()
    threading.Thread(target=unblock, daemon=True).start()
    _UNBLOCKERS.append(done)


_UNBLOCKERS: list[threading.Event] = []


@pytest.fixture
def special_file(tmp_path: Path) -> Iterator[Callable[[str, Path], Path]]:
    """Put a file no reader should read whole at a path: a FIFO, a device, a huge file.

    ``fifo``: a named pipe nobody writes (opened for writing after 10 s, so a reader that
    waits on it ends instead of hanging the tests); ``device``: a symbolic link to
    /dev/null (a character device); ``huge``: a sparse file of 20 MiB.
    """

    def make(kind: str, path: Path) -> Path:
        path.unlink(missing_ok=True)
        if kind == "fifo":
            os.mkfifo(path)
            _unblock_later(path, 10.0)
        elif kind == "device":
            path.symlink_to("/dev/null")
        elif kind == "huge":
            with path.open("wb") as file:
                file.truncate(20 * 1024 * 1024)
        else:
            raise ValueError(kind)
        return path

    yield make
    for done in _UNBLOCKERS:
        done.set()
    _UNBLOCKERS.clear()


SPECIAL_REFUSALS = {
    "fifo": "not a regular file",
    "device": "not a regular file",
    "huge": "more than the",
}
"""What a reader says about each kind of :func:`special_file`."""


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        # A JSON string is a TOML basic string, once characters beyond U+FFFF are written
        # as themselves (JSON's surrogate pairs are no TOML escape) and DEL is escaped.
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
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
