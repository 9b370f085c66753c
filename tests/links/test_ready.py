"""The recorder's ready output: a link sets it, the simulated drive holds what was written.

CANopen: a bit of the drive's digital outputs 0x60FE:01 over SDO, against the simulated
CiA 402 drive on python-can's virtual bus. Modbus: a coil or a holding register bit,
against the simulated drive's pymodbus server on 127.0.0.1. Every wait is bounded.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from typing import Any

import pytest

from ncmeasure.errors import LinkError
from ncmeasure.links.canopen.link import CanOpenLink
from ncmeasure.links.modbus.link import ModbusLink
from ncmeasure.links.modbus.settings import ModbusReady
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.cia402 import SimulatedDrives
from ncmeasure.sim.modbus_drive import ServerHandle, SimulatedUnit, running_server
from ncmeasure.sim.signals import PatternSource
from tests.links.test_canopen import SCALING, axis_config

# --- CANopen --------------------------------------------------------------------------


@pytest.fixture
def channel() -> str:
    return f"ncm-ready-{uuid.uuid4().hex}-bus"


@pytest.fixture
def clock() -> SimulatedClock:
    return SimulatedClock()


@pytest.fixture
def drives(channel: str, clock: SimulatedClock) -> Iterator[SimulatedDrives]:
    with SimulatedDrives.start(
        channel, {0: 1, 1: 2}, PatternSource(), scaling=SCALING, clock=clock
    ) as sim:
        yield sim


def canopen_link(channel: str, clock: SimulatedClock, **y_table: Any) -> CanOpenLink:
    table = {"channel": channel, "sync_hz": 250, "sdo_timeout_s": 30.0}
    axes = [
        (axis_config("X"), {"node_id": 1, "increments_per_rev": 10_000}),
        (axis_config("Y"), {"node_id": 2, "increments_per_rev": 10_000, **y_table}),
    ]
    link = CanOpenLink.from_tables(table, axes)
    link.use_clock(clock)
    return link


def outputs(drives: SimulatedDrives, node: int, subindex: int) -> int:
    drive = next(d for d in drives.drives if d.node_id == node)
    return int.from_bytes(drive.value(0x60FE, subindex), "little")


def test_canopen_sets_and_clears_the_bit_of_0x60fe_leaving_the_others(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    drive = next(d for d in drives.drives if d.node_id == 2)
    drive._write(0x60FE, 1, (0x0001).to_bytes(4, "little"))  # the brake bit, the drive's own
    with canopen_link(channel, clock, ready_output_bit=20) as link:
        assert link.signals_ready
        link.read(0.05)
        link.set_ready(True)
        assert outputs(drives, 2, 1) == (1 << 20) | 1
        assert outputs(drives, 2, 2) == 1 << 20  # enabled in the bit mask
        assert outputs(drives, 1, 1) == 0  # the other drive names no output
        link.set_ready(False)
        assert outputs(drives, 2, 1) == 1


def test_canopen_without_a_ready_output_does_nothing_and_says_so(
    channel: str, drives: SimulatedDrives, clock: SimulatedClock
) -> None:
    with canopen_link(channel, clock) as link:
        assert not link.signals_ready
        link.set_ready(True)
        assert outputs(drives, 1, 1) == outputs(drives, 2, 1) == 0


def test_set_ready_on_a_link_that_is_not_open_is_an_error(channel: str) -> None:
    link = canopen_link(channel, SimulatedClock(), ready_output_bit=16)
    with pytest.raises(LinkError, match="not open"):
        link.set_ready(True)


def test_the_ready_bit_is_a_manufacturer_specific_output(channel: str) -> None:
    from ncmeasure.errors import ConfigError

    with pytest.raises(ConfigError, match="ready_output_bit"):
        canopen_link(channel, SimulatedClock(), ready_output_bit=0)


# --- Modbus ---------------------------------------------------------------------------

COIL = ModbusReady(function="coil", address=5)
REGISTER = ModbusReady(function="holding", address=300, bit=3)


@pytest.fixture(scope="module")
def server() -> Iterator[ServerHandle]:
    units = [
        SimulatedUnit("X", 1, "generic", 0, ready=COIL),
        SimulatedUnit("Y", 2, "generic", 1, ready=REGISTER),
    ]
    with running_server(units, step_s=0.01) as handle:
        yield handle


def modbus_link(server: ServerHandle, axis: str, ready: ModbusReady | None) -> ModbusLink:
    table = {"host": server.host, "port": server.port, "register_map": "generic"}
    table.update(timeout_s=30.0, retries=0)
    units = {"X": 1, "Y": 2}
    ready_table = {} if ready is None else {"ready": ready.model_dump(exclude_none=True)}
    return ModbusLink.from_tables(
        table, [(axis_config(axis), {"unit_id": units[axis], **ready_table})]
    )


def test_modbus_writes_the_coil(server: ServerHandle) -> None:
    with modbus_link(server, "X", COIL) as link:
        assert link.signals_ready
        link.set_ready(True)
        assert server.outputs()[1] == {"coil 5": 1}
        link.read(0.05)
        link.set_ready(False)
        assert server.outputs()[1] == {"coil 5": 0}


def test_modbus_changes_only_its_bit_of_the_holding_register(server: ServerHandle) -> None:
    with modbus_link(server, "Y", REGISTER) as link:
        link.set_ready(True)
        assert server.outputs()[2] == {"holding 300": 1 << 3}
        link.set_ready(False)
        assert server.outputs()[2] == {"holding 300": 0}


def test_modbus_without_a_ready_output_writes_nothing(server: ServerHandle) -> None:
    before = server.outputs()
    with modbus_link(server, "X", None) as link:
        assert not link.signals_ready
        link.set_ready(True)
    assert server.outputs() == before


def test_a_refused_write_is_a_link_error_with_the_meaning(server: ServerHandle) -> None:
    # unit 1 has a coil, not a register: the drive refuses the write
    wrong = ModbusReady(function="holding", address=5, bit=0)
    with modbus_link(server, "X", wrong) as link, pytest.raises(LinkError, match="ready output"):
        link.set_ready(True)
