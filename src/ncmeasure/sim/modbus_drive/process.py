"""A simulated Modbus drive server in another process, for tests, benchmarks and the demo.

:func:`running_server` starts it (multiprocessing ``spawn``), waits until it
listens and yields a :class:`ServerHandle` that sets faults, drops
connections, resets and reads the request counters through a pipe.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import socket
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from ncmeasure.errors import ConfigError, LinkError
from ncmeasure.links.modbus.settings import ModbusSettings
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.modbus_drive.drive import ServerInfo, SimulatedModbusDrive, SimulatedUnit
from ncmeasure.sim.modbus_drive.faults import NO_FAULT, Fault
from ncmeasure.sim.signals import SignalSource

__all__ = ["ServerHandle", "running_server"]


@dataclass(frozen=True)
class _ProcessConfig:
    units: tuple[SimulatedUnit, ...]
    source: SignalSource | None
    step_s: float | None
    settings: ModbusSettings
    free_port: bool
    clock: SimulatedClock | None = None


def _child_main(config: _ProcessConfig, conn: Connection) -> None:
    """Entry of the server process: serve, and obey commands from the pipe."""
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # this process' own console
    stop = threading.Event()
    try:
        drive = SimulatedModbusDrive(
            config.units, source=config.source, step_s=config.step_s, clock=config.clock
        )
    except ConfigError as exc:
        conn.send(("error", str(exc)))
        return

    def obey() -> None:
        while not stop.is_set():
            try:
                if not conn.poll(0.1):
                    continue
                command, argument = conn.recv()
            except (EOFError, OSError):
                stop.set()
                return
            payload: Any = None
            if command == "fault":
                drive.faults.set(argument)
            elif command == "drop":
                drive.faults.drop_connections()
            elif command == "reset":
                drive.reset()
            elif command == "stats":
                payload = drive.stats()
            elif command == "outputs":
                payload = drive.outputs()
            elif command == "output_writes":
                payload = drive.output_writes()
            elif command == "stop":
                stop.set()
            conn.send(("ok", payload))

    def ready(info: ServerInfo) -> None:
        conn.send(("ready", info.port))
        threading.Thread(target=obey, daemon=True).start()

    try:
        drive.serve_forever(config.settings, free_port=config.free_port, ready=ready, stop=stop)
    except LinkError as exc:
        conn.send(("error", str(exc)))


class ServerHandle:
    """Control of a simulated drive server running in another process."""

    def __init__(
        self,
        process: multiprocessing.process.BaseProcess,
        conn: Connection,
        host: str,
        port: int,
        units: Mapping[str, int],
    ) -> None:
        self.process = process
        self.host = host
        self.port = port
        self.units = dict(units)
        self._conn = conn
        self._lock = threading.Lock()

    def _command(self, command: str, argument: Any = None, timeout_s: float = 10.0) -> Any:
        with self._lock:
            self._conn.send((command, argument))
            if not self._conn.poll(timeout_s):
                raise LinkError(f"the simulated drive did not confirm {command!r}")
            status, payload = self._conn.recv()
        if status != "ok":
            raise LinkError(f"the simulated drive refused {command!r}: {payload}")
        return payload

    def set_fault(self, fault: Fault) -> None:
        """Make the drives misbehave (see :class:`Fault`)."""
        self._command("fault", fault)

    def clear_faults(self) -> None:
        """Back to normal answers."""
        self._command("fault", NO_FAULT)

    def drop_connections(self) -> None:
        """Close every TCP connection the server has open."""
        self._command("drop")

    def reset(self) -> None:
        """Clear faults and restart the request counters and the clock."""
        self._command("reset")

    def stats(self) -> dict[int, int]:
        """Answered read requests per unit id."""
        result: dict[int, int] = self._command("stats")
        return result

    def output_writes(self) -> dict[int, list[int]]:
        """Per unit id, every value a link wrote to its ready output, in order."""
        result: dict[int, list[int]] = self._command("output_writes")
        return result

    def outputs(self) -> dict[int, dict[str, int]]:
        """Per unit id, what a link wrote to its ready output (see
        :meth:`SimulatedModbusDrive.outputs`)."""
        result: dict[int, dict[str, int]] = self._command("outputs")
        return result


_PROCESS_NAME = "ncmeasure-modbus-drive"
_MAIN_REIMPORTED_EXIT = 86
"""Exit code of a drive process that found itself starting a server while importing the
main module (a script without the ``if __name__ == "__main__":`` guard)."""
_MAIN_GUARD = (
    "running_server() was called while the simulated drive process imported your main "
    "module again (multiprocessing starts it with 'spawn', which runs the script's top "
    'level once more): call it under `if __name__ == "__main__":` in the script'
)


def _importing_main_in_child() -> bool:
    """True in a spawned process while it still imports the parent's main module."""
    return bool(getattr(multiprocessing.current_process(), "_inheriting", False))


@contextlib.contextmanager
def running_server(
    units: Mapping[str, int] | Sequence[SimulatedUnit] | None = None,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    register_map: str = "generic",
    source: SignalSource | None = None,
    step_s: float | None = None,
    start_timeout_s: float = 30.0,
    clock: SimulatedClock | None = None,
) -> Iterator[ServerHandle]:
    """A simulated Modbus TCP drive server in another process, for tests and benchmarks.

    Waits until the server accepts connections, yields a :class:`ServerHandle`
    and stops the process afterwards.

    Args:
        units: Axis name -> unit id (all with ``register_map``), or
            :class:`SimulatedUnit` entries; default ``{"X": 1}``.
        host: Address to listen on.
        port: TCP port; 0 picks a free one (``handle.port``).
        register_map: Map for units given by name.
        source: Axis states (must be picklable); default :class:`PatternSource`.
        step_s: Deterministic mode.
        start_timeout_s: How long to wait for the server to listen.
        clock: A :class:`~ncmeasure.samples.SimulatedClock` shared with the link
            (lockstep, through shared memory); ``None``: wall-clock.

    A script that uses it must call it under ``if __name__ == "__main__":``:
    the server process is started with ``spawn``, which imports the script
    again; without the guard this is refused at once with that remedy.

    Raises:
        LinkError: the server did not start (port in use, ...), or the script
            calls it without the ``__main__`` guard.
    """
    if _importing_main_in_child():
        # Inside the new process, importing the script again: starting a server
        # here would fail in multiprocessing's bootstrapping. Leave quietly; the
        # parent sees the exit code and says why.
        raise SystemExit(_MAIN_REIMPORTED_EXIT)
    if units is None:
        units = {"X": 1}
    if isinstance(units, Mapping):
        unit_list = tuple(
            SimulatedUnit(axis, uid, register_map, i) for i, (axis, uid) in enumerate(units.items())
        )
    else:
        unit_list = tuple(units)
    # where a link reading the drives connects (port 0: any free one, told by the server)
    settings = ModbusSettings(host=host, port=port or 502, register_map=register_map)
    config = _ProcessConfig(unit_list, source, step_s, settings, port == 0, clock)
    context = multiprocessing.get_context("spawn")
    parent, child = context.Pipe()
    process = context.Process(
        target=_child_main, args=(config, child), name=_PROCESS_NAME, daemon=True
    )
    process.start()
    child.close()
    try:
        deadline = time.monotonic() + start_timeout_s
        message: tuple[str, Any] | None = None
        while time.monotonic() < deadline:
            if parent.poll(0.1):
                with contextlib.suppress(EOFError, OSError):
                    message = parent.recv()
                break
            if not process.is_alive():
                break
        if message is None:
            process.join(timeout=5)  # a closed pipe comes before the exit code
            if process.exitcode == _MAIN_REIMPORTED_EXIT:
                raise LinkError(_MAIN_GUARD)
            if process.exitcode is None:
                raise LinkError(
                    f"the simulated Modbus drive process did not start within "
                    f"{start_timeout_s:g} s (a script that starts it must do so under "
                    '`if __name__ == "__main__":`, or the process imports it again)'
                )
            raise LinkError(
                f"the simulated Modbus drive process did not start (exit code {process.exitcode})"
            )
        status, payload = message
        if status != "ready":
            raise LinkError(str(payload))
        bound = int(payload)
        _wait_for_port(host, bound, deadline)
        yield ServerHandle(process, parent, host, bound, {u.axis: u.unit_id for u in unit_list})
    finally:
        with contextlib.suppress(OSError, EOFError, ValueError):
            parent.send(("stop", None))
        process.join(timeout=5)
        if process.is_alive():
            process.terminate()
            process.join(timeout=5)
        if process.is_alive():
            process.kill()
            process.join(timeout=5)
        parent.close()


def _wait_for_port(host: str, port: int, deadline: float) -> None:
    while True:
        try:
            with socket.create_connection((host, port), timeout=1.0):
                return
        except OSError as exc:
            if time.monotonic() > deadline:
                raise LinkError(
                    f"the simulated Modbus drive does not answer on {host}:{port}: {exc}"
                ) from exc
            time.sleep(0.05)
