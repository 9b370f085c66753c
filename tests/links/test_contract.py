"""One contract, every registered link: the same behaviour whatever is behind it.

Each link gets a factory that builds it against its real counterpart on this
machine (simulated CiA 402 drives on python-can's virtual bus, the simulated
Modbus server in another process, a recording on disk). A link registered
without a factory fails here, so no link escapes the contract.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.config import AxisConfig, parse_machine
from ncmeasure.errors import ConfigError, LinkError
from ncmeasure.links import REAL_TIME, available_links, link_class
from ncmeasure.links.base import DriveLink
from ncmeasure.recording import RecordingWriter
from ncmeasure.samples import SIGNAL_UNITS, SampleBlock, SimulatedClock, channels_for
from ncmeasure.sim.signals import PatternSource
from tests.conftest import example_data

AXES = ("X", "Y", "Z")


def machine_axes() -> list[AxisConfig]:
    return list(parse_machine(example_data()).axes)


@contextlib.contextmanager
def replay_link(tmp_path: Path) -> Iterator[tuple[DriveLink, dict[str, Any]]]:
    source = tmp_path / "source"
    channels = channels_for(AXES)
    with RecordingWriter.create(source, channels, nominal_period_s=0.004) as writer:
        time_s = np.arange(3000) * 0.004
        writer.append(SampleBlock(time_s, np.tile(time_s[:, None], (1, len(channels)))))
    table = {"source": str(source), "speed": 0}
    link = link_class("replay").from_tables(table, [(a, {}) for a in machine_axes()])
    yield link, table


@contextlib.contextmanager
def modbus_link(tmp_path: Path) -> Iterator[tuple[DriveLink, dict[str, Any]]]:
    from ncmeasure.sim.modbus_drive import running_server

    with running_server(dict(zip(AXES, (1, 2, 3), strict=True))) as server:
        table = {"port": server.port, "register_map": "generic", "poll_hz": 200}
        axes = [(a, {"unit_id": i + 1}) for i, a in enumerate(machine_axes())]
        yield link_class("modbus").from_tables(table, axes), table


@contextlib.contextmanager
def canopen_link(tmp_path: Path) -> Iterator[tuple[DriveLink, dict[str, Any]]]:
    from ncmeasure.sim.cia402 import DriveScaling, SimulatedDrives
    from ncmeasure.sim.rig import rig_mechanics

    channel = f"contract-{uuid.uuid4().hex[:8]}"
    scaling = {  # the drives move the axes the link reads
        i: DriveScaling(mechanics=rig_mechanics(a.mechanics()), increments_per_rev=10_000)
        for i, a in enumerate(machine_axes())
    }
    with SimulatedDrives.start(channel, {0: 1, 1: 2, 2: 3}, PatternSource(), scaling=scaling):
        table = {"interface": "virtual", "channel": channel, "sync_hz": 250}
        axes = [
            (a, {"node_id": i + 1, "increments_per_rev": 10_000})
            for i, a in enumerate(machine_axes())
        ]
        yield link_class("canopen").from_tables(table, axes), table


FACTORIES: dict[
    str, Callable[[Path], contextlib.AbstractContextManager[tuple[DriveLink, dict[str, Any]]]]
] = {
    "replay": replay_link,
    "modbus": modbus_link,
    "canopen": canopen_link,
}


@pytest.mark.parametrize("name", available_links())
def test_link_keeps_the_contract(name: str, tmp_path: Path) -> None:
    assert name in FACTORIES, f"link {name!r} is registered but has no contract factory"
    with FACTORIES[name](tmp_path) as (link, table):
        assert link.name == name and isinstance(link, link_class(name))
        names = [c.name for c in link.channels]
        assert len(names) == len(set(names))
        for axis in AXES:
            for signal in ("current_a", "velocity_mm_min", "position_mm"):
                assert f"{axis}_{signal}" in names
        assert all(c.unit == SIGNAL_UNITS[c.signal] for c in link.channels)
        assert link.nominal_period_s > 0
        json.dumps(link.describe())

        with pytest.raises(LinkError, match="not open"):
            link.read()
        assert link.clock is REAL_TIME
        with link:
            assert link.is_open
            with pytest.raises(LinkError, match="already open"):
                link.open()
            with pytest.raises(LinkError, match="while it is open"):
                link.use_clock(SimulatedClock())
            rows, last = 0, -np.inf
            deadline = time.monotonic() + 60  # a guard against a hang, however busy the host
            for _ in itertools.count():
                block = link.read(timeout_s=0.5)
                assert block is not None
                assert block.values.shape == (len(block), len(link.channels))
                if len(block):
                    assert block.time_s[0] > last and np.all(np.diff(block.time_s) > 0)
                    last = float(block.time_s[-1])
                    rows += len(block)
                if rows >= 100 or time.monotonic() > deadline:
                    break
            assert rows >= 100
            assert isinstance(link.events(), list)
        assert not link.is_open
        link.close()  # a second close is harmless
        with pytest.raises(LinkError):
            link.read()
        with pytest.raises(LinkError, match="closed"):
            link.open()

        with pytest.raises(ConfigError) as caught:
            type(link).from_tables(
                {**table, "no_such_setting": 1}, [(a, {}) for a in machine_axes()]
            )
        assert any(p.startswith("link.no_such_setting") for p in caught.value.problems)


@pytest.mark.parametrize("name", ["canopen", "modbus", "replay"])
def test_link_settings_are_strict_like_the_machine_file(name: str) -> None:
    """Text where a number or a boolean belongs is refused at its place, never converted."""
    axes = list(parse_machine(example_data()).axes)
    table: dict[str, object] = {
        "canopen": {"sync_hz": "250", "listen_only": "no"},
        "modbus": {"register_map": "generic", "port": "502"},
        "replay": {"source": "run1", "speed": "0"},
    }[name]
    axis_table: dict[str, object] = {
        "canopen": {"node_id": "1", "increments_per_rev": 10_000},
        "modbus": {"unit_id": "1"},
        "replay": {},
    }[name]
    with pytest.raises(ConfigError) as info:
        link_class(name).from_tables(table, [(a, dict(axis_table)) for a in axes])
    text = "\n".join(info.value.problems)
    expected = {
        "canopen": ["link.sync_hz: expected a number, got the text '250'",
                    "link.listen_only: expected true/false, got the text 'no'",
                    "axes[0].link.node_id: expected an integer, got the text '1'"],
        "modbus": ["link.port: expected an integer, got the text '502'",
                   "axes[0].link.unit_id: expected an integer, got the text '1'"],
        "replay": ["link.speed: expected a number, got the text '0'"],
    }[name]  # fmt: skip
    for line in expected:
        assert line in text
