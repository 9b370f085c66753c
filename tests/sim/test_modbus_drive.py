"""The simulated Modbus drive, read with a bare pymodbus client: registers, time, faults."""

from __future__ import annotations

import os
import select
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusIOException

from ncmeasure.errors import ConfigError, LinkError
from ncmeasure.links.modbus.registers import decode_words
from ncmeasure.links.modbus.settings import ModbusAxis, ModbusSettings
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.modbus_drive import (
    DriveFaults,
    Fault,
    ServerInfo,
    SimulatedModbusDrive,
    SimulatedUnit,
    pty_null_modem,
    running_server,
    serve,
)
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.signals import AxisState, PatternSource

STEP_S = 0.01
SOURCE = PatternSource()
ANSWER_S = 30.0
"""How long a client waits for an answer that comes: a guard, however late the host is."""
SILENT_S = 0.3
"""How long a client waits for an answer that does not come (a silent unit)."""


def link_settings(**link: Any) -> ModbusSettings:
    """The settings of a link reading the simulated drive (generic map unless given)."""
    return ModbusSettings.model_validate({"register_map": "generic", **link})


def link_axes(units: Mapping[str, int]) -> dict[str, ModbusAxis]:
    return {axis: ModbusAxis(unit_id=unit_id) for axis, unit_id in units.items()}


class Ramp:
    """Position 10 mm per second of the source's time."""

    def state(self, axis: int, time_s: float) -> AxisState:
        return AxisState(position_mm=10.0 * time_s, velocity_mm_min=600.0, current_a=1.0)


@contextmanager
def server_thread(
    units: Mapping[str, int] | None = None,
    link: Mapping[str, Any] | None = None,
    axes: Mapping[str, ModbusAxis] | None = None,
    **kwargs: Any,
) -> Iterator[tuple[ServerInfo, DriveFaults]]:
    """``serve`` in a thread of this process on a free port.

    ``link``: more link settings; ``axes``: the axes' link settings instead of ``units``.
    """
    faults = DriveFaults()
    stop = threading.Event()
    ready = threading.Event()
    infos: list[ServerInfo] = []

    def on_ready(info: ServerInfo) -> None:
        infos.append(info)
        ready.set()

    errors: list[BaseException] = []

    def run() -> None:
        try:
            serve(
                link_settings(**(link or {})),
                axes or link_axes(units or {}),
                free_port=True,
                faults=faults,
                ready=on_ready,
                stop=stop,
                **kwargs,
            )
        except BaseException as exc:  # reported by the test
            errors.append(exc)
            ready.set()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        assert ready.wait(ANSWER_S)
        if errors:
            raise errors[0]
        yield infos[0], faults
    finally:
        stop.set()
        thread.join(timeout=10)


@contextmanager
def tcp_client(info: ServerInfo, timeout_s: float = ANSWER_S) -> Iterator[ModbusTcpClient]:
    client = ModbusTcpClient(str(info.host), port=int(info.port or 0), timeout=timeout_s, retries=0)
    assert connect(client)
    try:
        yield client
    finally:
        close(client)


def connect(client: ModbusTcpClient | ModbusSerialClient) -> bool:
    return bool(client.connect())


def close(client: ModbusTcpClient | ModbusSerialClient) -> None:
    client.close()  # type: ignore[no-untyped-call]


def generic_position(words: Sequence[int]) -> float:
    return decode_words(words[0:2], "int32") * 0.001


def test_registers_follow_the_map_and_the_request_count() -> None:
    with (
        server_thread(units={"X": 1, "Y": 7}, step_s=STEP_S) as (info, _),
        tcp_client(info) as client,
    ):
        assert info.units == {"X": 1, "Y": 7}
        for n in range(3):
            for unit, axis_index in ((1, 0), (7, 1)):
                response = client.read_input_registers(0, count=8, device_id=unit)
                assert not response.isError()
                state = SOURCE.state(axis_index, n * STEP_S)
                words = response.registers
                assert decode_words(words[0:2], "int32") == round(state.position_mm / 0.001)
                assert decode_words(words[2:4], "int32") == round(state.velocity_mm_min / 0.01)
                assert decode_words(words[4:6], "float32") == pytest.approx(
                    state.current_a, rel=1e-6
                )
                assert decode_words(words[6:8], "int32") == round(state.velocity_cmd_mm_min / 0.01)
        # No holding registers in the generic map: the drive says so.
        response = client.read_holding_registers(0, count=2, device_id=1)
        assert response.isError() and response.exception_code == 2
        # A range beyond the map's registers is an illegal address too.
        response = client.read_input_registers(4, count=10, device_id=1)
        assert response.isError() and response.exception_code == 2


def test_serve_shows_what_a_link_with_the_same_settings_reads() -> None:
    """serve() takes the link's settings: each axis' map, counts per revolution, scales."""
    axes = {
        "X": ModbusAxis(unit_id=1, scales={"position_mm": 0.01}),
        "Z": ModbusAxis(unit_id=3, register_map="ats-rt20", counts_per_rev=4096),
    }
    with server_thread(axes=axes, step_s=STEP_S) as (info, _), tcp_client(info) as client:
        assert info.units == {"X": 1, "Z": 3}
        x = client.read_input_registers(0, count=2, device_id=1).registers
        z = client.read_holding_registers(0x0301, count=2, device_id=3).registers
        torque = client.read_holding_registers(0x0307, count=1, device_id=3).registers
    assert decode_words(x, "int32") == round(SOURCE.state(0, 0.0).position_mm / 0.01)
    # the default mechanics, the rig's: 20 mm screw lead; the axis' own 4096 counts per revolution
    counts = decode_words(z, "int32", "little")
    assert counts == round(SOURCE.state(1, 0.0).position_mm / (20.0 / 4096))
    # and the rig's 17.7 A rated current (the unit's second request: the state at one step)
    permille = decode_words(torque, "int16")
    assert permille == round(SOURCE.state(1, STEP_S).current_a / 17.7 * 1000)


def test_unknown_unit_behind_tcp_is_a_gateway_exception() -> None:
    with server_thread(units={"X": 1}) as (info, _), tcp_client(info) as client:
        response = client.read_input_registers(0, count=2, device_id=9)
        assert response.isError() and response.exception_code == 11


def test_registers_of_a_real_drive_map() -> None:
    drive = SimulatedModbusDrive(
        [
            SimulatedUnit(
                "Z",
                3,
                "ats-rt20",
                0,
                mechanics=rig_mechanics(screw_lead_mm=5.0, rated_current_a=4.0),
                counts_per_rev=10_000,
            )
        ],
        step_s=STEP_S,
    )
    state = AxisState(
        position_mm=12.3456, velocity_mm_min=-1500.0, current_a=-1.0, velocity_cmd_mm_min=1000.0
    )
    words = drive.registers(3, "holding", state)
    assert words[0x0300] == (-300) & 0xFFFF  # -1500 mm/min / 5 mm = -300 rpm
    assert (
        words[0x0301] == 24691 and words[0x0302] == 0
    )  # low word first: 12.3456 mm = 24691 counts
    assert words[0x0307] == (-250) & 0xFFFF  # -1 A of 4 A rated = -25.0 % = -250 × 0.1 %
    assert words[0x030C] == 200
    assert drive.registers(3, "input", state) == {}


def test_time_mode_follows_the_clock() -> None:
    with server_thread(units={"X": 1}) as (info, _), tcp_client(info) as client:
        first = generic_position(client.read_input_registers(0, count=8, device_id=1).registers)
        threading.Event().wait(0.2)
        second = generic_position(client.read_input_registers(0, count=8, device_id=1).registers)
    assert first != second


def test_on_a_simulated_clock_the_server_time_is_the_links() -> None:
    clock = SimulatedClock()
    drive = SimulatedModbusDrive([SimulatedUnit("X", 1)], clock=clock)
    time.sleep(0.01)
    assert drive.elapsed_s() == 0.0  # the wall clock does not move simulated time
    clock.advance_to(12.5)
    assert drive.elapsed_s() == 12.5
    plain = SimulatedModbusDrive([SimulatedUnit("X", 1)])
    assert plain.clock is None and 0.0 < plain.elapsed_s() < 12.5


def test_server_in_lockstep_serves_the_state_at_the_links_time() -> None:
    clock = SimulatedClock()
    with (
        server_thread(units={"X": 1}, source=Ramp(), clock=clock) as (info, faults),
        tcp_client(info) as client,
    ):
        clock.advance_to(1.0)
        first = generic_position(client.read_input_registers(0, count=8, device_id=1).registers)
        time.sleep(0.05)
        again = generic_position(client.read_input_registers(0, count=8, device_id=1).registers)
        clock.advance_to(3.5)
        later = generic_position(client.read_input_registers(0, count=8, device_id=1).registers)
        faults.set(Fault(silent=True, from_s=4.0, until_s=5.0))
        assert not client.read_input_registers(0, count=8, device_id=1).isError()  # 3.5 s
    # 10 mm per second of simulated time, whatever the wall clock did meanwhile
    assert (first, again, later) == (pytest.approx(10.0), pytest.approx(10.0), pytest.approx(35.0))


def test_in_lockstep_a_silent_unit_says_so_on_the_clock() -> None:
    """A link in lockstep stops waiting when the drive says it stays silent (see the link)."""
    clock = SimulatedClock()
    with (
        server_thread(units={"X": 1, "Y": 2}, clock=clock) as (info, faults),
        tcp_client(info) as client,
        tcp_client(info, timeout_s=SILENT_S) as impatient,
    ):
        assert not client.read_input_registers(0, count=8, device_id=1).isError()
        faults.set(Fault(silent=True, units=frozenset({2})))
        with pytest.raises(ModbusIOException):
            impatient.read_input_registers(0, count=8, device_id=2)
        deadline = time.monotonic() + ANSWER_S  # the server's thread may not have run yet
        while clock.unanswered() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not client.read_input_registers(0, count=8, device_id=1).isError()
    assert clock.unanswered() == 1  # the silent request only, not the answered ones


def test_a_fault_holds_only_inside_its_time_window() -> None:
    fault = Fault(silent=True, units=frozenset({2}), from_s=1.0, until_s=2.0)
    assert not fault.applies_to(1, 1.5)
    assert [fault.applies_to(2, t) for t in (0.99, 1.0, 1.99, 2.0)] == [False, True, True, False]
    assert fault.applies_to(2)  # without a time: the unit decides


def test_faults_silent_exception_delay_and_units() -> None:
    with (
        server_thread(units={"X": 1, "Y": 2}, step_s=STEP_S) as (info, faults),
        tcp_client(info) as client,
        tcp_client(info, timeout_s=SILENT_S) as impatient,
    ):
        faults.set(Fault(exception_code=3, units=frozenset({2})))
        assert not client.read_input_registers(0, count=8, device_id=1).isError()
        response = client.read_input_registers(0, count=8, device_id=2)
        assert response.isError() and response.exception_code == 3
        faults.set(Fault(delay_s=0.05))
        assert not client.read_input_registers(0, count=8, device_id=2).isError()
        faults.set(Fault(silent=True, units=frozenset({1})))
        with pytest.raises(ModbusIOException):
            impatient.read_input_registers(0, count=8, device_id=1)
    with (
        server_thread(units={"X": 1}, step_s=STEP_S) as (info, faults),
        tcp_client(info, timeout_s=SILENT_S) as client,
    ):
        faults.set(Fault(silent=True))
        with pytest.raises(ModbusIOException):
            client.read_input_registers(0, count=8, device_id=1)
    with server_thread(units={"X": 1}, step_s=STEP_S) as (info, faults), tcp_client(info) as client:
        faults.set(Fault(silent=True))
        close(client)
        faults.clear()
        assert connect(client)
        # Silent requests were never answered, so they do not count: request 0 comes now.
        words = client.read_input_registers(0, count=8, device_id=1).registers
        assert generic_position(words) == round(SOURCE.state(0, 0.0).position_mm / 0.001) * 0.001


def test_drop_connections_closes_the_client_socket() -> None:
    with server_thread(units={"X": 1}) as (info, faults), tcp_client(info) as client:
        assert not client.read_input_registers(0, count=2, device_id=1).isError()
        faults.drop_connections()
        # the server closes it from its own thread: wait until the end of the stream is here
        assert select.select([client.socket], [], [], ANSWER_S)[0]
        with pytest.raises(ConnectionException):
            client.read_input_registers(0, count=2, device_id=1)
        close(client)
        assert connect(client)
        assert not client.read_input_registers(0, count=2, device_id=1).isError()


def test_bad_faults_and_units() -> None:
    with pytest.raises(ValueError, match="exception code 9"):
        Fault(exception_code=9)
    with pytest.raises(ValueError):
        Fault(delay_s=-1)
    with pytest.raises(ConfigError, match="given twice"):
        SimulatedModbusDrive([SimulatedUnit("X", 1), SimulatedUnit("Y", 1)])
    with pytest.raises(ConfigError, match=r"not in 1\.\.247"):
        SimulatedModbusDrive([SimulatedUnit("X", 0)])
    with pytest.raises(ConfigError, match="unknown register map"):
        SimulatedModbusDrive([SimulatedUnit("X", 1, "nope")])


UNGUARDED_SCRIPT = """
from ncmeasure.sim.modbus_drive import running_server

with running_server({"X": 1}, start_timeout_s=%s) as server:
    print("serving on", server.port, flush=True)
"""


@pytest.mark.parametrize("guarded", [False, True])
def test_a_script_without_the_main_guard_is_told_so(tmp_path: Path, guarded: bool) -> None:
    """multiprocessing's spawn imports the script again in the drive process: without the
    `if __name__ == "__main__":` guard that would start a server there too. It is refused
    at once with the remedy, not a hang or a bootstrapping traceback."""
    script = tmp_path / "script.py"
    text = UNGUARDED_SCRIPT % 300
    if guarded:
        body = text.split("\n\n", 1)[1]
        text = (
            text.split("\n\n", 1)[0]
            + '\n\nif __name__ == "__main__":\n'
            + "".join(f"    {line}\n" for line in body.strip().splitlines())
        )
    script.write_text(text, encoding="utf-8")
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=120
    )
    if guarded:
        assert done.returncode == 0 and "serving on" in done.stdout, done.stderr
        return
    assert time.monotonic() - started < 60  # well before the 300 s start timeout
    assert done.returncode == 1
    assert 'if __name__ == "__main__":' in done.stderr
    assert "LinkError" in done.stderr and "main module" in done.stderr
    assert "bootstrapping phase" not in done.stderr  # multiprocessing's own traceback


def test_port_in_use_is_a_clear_error() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(LinkError) as info:
            serve(link_settings(port=port), link_axes({"X": 1}))
    assert str(info.value).startswith(
        f"the simulated Modbus drive cannot listen on 127.0.0.1:{port}"
    )
    assert "address already in use" in str(info.value)


def test_running_server_in_another_process_is_controllable() -> None:
    with running_server({"X": 1, "Y": 2}, step_s=STEP_S) as handle:
        assert handle.process.pid != os.getpid()
        info = ServerInfo(handle.host, handle.port, None, handle.units)
        with tcp_client(info) as client:
            for _ in range(3):
                client.read_input_registers(0, count=8, device_id=1)
            assert handle.stats() == {1: 3, 2: 0}
            handle.set_fault(Fault(exception_code=10))
            response = client.read_input_registers(0, count=8, device_id=2)
            assert response.isError() and response.exception_code == 10
            handle.reset()
            assert handle.stats() == {1: 0, 2: 0}
            words = client.read_input_registers(0, count=8, device_id=2).registers
            assert (
                generic_position(words) == round(SOURCE.state(1, 0.0).position_mm / 0.001) * 0.001
            )
            handle.drop_connections()
    assert not handle.process.is_alive()


def test_rtu_over_a_null_modem() -> None:
    drive = SimulatedModbusDrive([SimulatedUnit("X", 5, "iai-robo-cylinder")], step_s=STEP_S)
    with pty_null_modem() as (server_port, client_port):
        stop = threading.Event()
        ready = threading.Event()
        line = link_settings(serial_port=server_port, baudrate=115200, parity="N")
        thread = threading.Thread(
            target=drive.serve_forever,
            args=(line,),
            kwargs={"ready": lambda _: ready.set(), "stop": stop},
            daemon=True,
        )
        thread.start()
        client = ModbusSerialClient(
            client_port, baudrate=115200, parity="N", timeout=ANSWER_S, retries=0
        )
        impatient = ModbusSerialClient(
            client_port, baudrate=115200, parity="N", timeout=SILENT_S, retries=0
        )
        try:
            assert ready.wait(ANSWER_S)
            assert connect(client)
            words = client.read_holding_registers(0x9000, count=14, device_id=5).registers
            state = SOURCE.state(0, 0.0)
            assert decode_words(words[0:2], "int32") == round(state.position_mm / 0.01)
            assert decode_words(words[10:12], "int32") == round(state.velocity_mm_min / 0.6)
            assert decode_words(words[12:14], "int32") == round(state.current_a / 0.001)
            close(client)
            # Nobody answers an unknown unit on a serial line.
            assert connect(impatient)
            with pytest.raises(ModbusIOException):
                impatient.read_holding_registers(0x9000, count=2, device_id=6)
        finally:
            close(client)
            close(impatient)
            stop.set()
            thread.join(timeout=10)
    assert drive.stats() == {5: 1}


def test_bad_serial_port_is_a_link_error() -> None:
    with (
        pytest.raises(LinkError, match="/nonexistent/tty"),
        server_thread(units={"X": 1}, link={"serial_port": "/nonexistent/tty"}),
    ):
        pass


def test_simulate_drive_command_serves_until_stopped() -> None:
    """`ncmeasure simulate-drive --link modbus` is the one command line of the simulated drive."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ncmeasure",
            "simulate-drive",
            "--link",
            "modbus",
            "--port",
            str(port),
            "--unit",
            "X=1",
            "--unit",
            "Y=2",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stderr is not None
        readable, _, _ = select.select([process.stderr], [], [], 60)
        assert readable, "the server printed nothing"
        line = process.stderr.readline()
        assert line.startswith(f"simulated Modbus drives on 127.0.0.1:{port}, units X=1, Y=2")
        info = ServerInfo("127.0.0.1", port, None, {"X": 1, "Y": 2})
        with tcp_client(info) as client:
            assert not client.read_input_registers(0, count=8, device_id=2).isError()
    finally:
        process.terminate()
        process.wait(timeout=10)
