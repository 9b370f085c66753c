"""The OPC UA server against a real asyncua client: browse, read, subscribe, refuse.

The server runs in a thread on a free loopback port over a SQLite store; the
client browses Machines → M17 → Axes → X, reads the values the store holds with
their units and times, subscribes to Coulomb and sees it change after a new
``store add``. Anything but loopback without a user and certificate is refused
in one line; a wrong password is refused by the server.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from ncmeasure.errors import ConfigError
from ncmeasure.formats.comparison import Limits
from ncmeasure.formats.results import Results
from ncmeasure.publish.opcua import NAMESPACE, OpcUaSettings, engineering_units, serve_opcua
from ncmeasure.store import MeasurementInfo, open_store
from tests.publish.broker import free_port
from tests.publish.certificates import self_signed_rsa
from tests.publish.conftest import SERVICE_FACTOR
from tests.publish.opcua_client import subscribe_changes

WAIT_S = 60.0


class Running:
    def __init__(self, endpoint: str, thread: threading.Thread, stop: threading.Event) -> None:
        self.endpoint, self.thread, self.stop = endpoint, thread, stop
        self.error: BaseException | None = None


def start(
    url: str, tmp_path: Path, limits: Limits | None = None, **settings: Any
) -> Iterator[Running]:
    stop, ready = threading.Event(), threading.Event()
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}"
    running: list[Running] = []

    def target() -> None:
        try:
            serve_opcua(
                url,
                OpcUaSettings(endpoint=endpoint, **settings),
                limits=limits,
                on_ready=lambda _: ready.set(),
                stop=stop,
            )
        except BaseException as exc:
            running[0].error = exc
            ready.set()

    thread = threading.Thread(target=target, daemon=True)
    running.append(Running(endpoint, thread, stop))
    thread.start()
    assert ready.wait(WAIT_S), "the server did not start"
    assert running[0].error is None, running[0].error
    try:
        yield running[0]
    finally:
        stop.set()
        thread.join(WAIT_S)
        assert not thread.is_alive()


@pytest.fixture
def server(store_with_machine: str, tmp_path: Path) -> Iterator[Running]:
    yield from start(store_with_machine, tmp_path, refresh_s=0.2)


async def _browse(client: Any, *names: str) -> Any:
    ns = await client.get_namespace_index(NAMESPACE)
    return await client.nodes.objects.get_child([f"{ns}:{name}" for name in names])


def test_the_client_reads_the_store_and_sees_a_change(
    server: Running, store_with_machine: str, make_results: Callable[..., Results]
) -> None:
    from asyncua import Client, ua

    with open_store(store_with_machine) as store:
        trend = store.trend("M17", "X")

    async def scenario() -> None:
        async with Client(server.endpoint, timeout=30) as client:
            machine = await _browse(client, "Machines", "M17")
            assert (await machine.read_browse_name()).Name == "M17"
            assert await (
                await machine.get_child(f"{machine.nodeid.NamespaceIndex}:MachineType")
            ).read_value()
            axis = await _browse(client, "Machines", "M17", "Axes", "X")
            ns = axis.nodeid.NamespaceIndex
            coulomb = await axis.get_child(f"{ns}:Coulomb")
            value = await coulomb.read_data_value()
            latest = trend[-1]
            assert value.Value.Value == pytest.approx(latest.coulomb)
            measured = dt.datetime.fromisoformat(latest.measured_utc)
            assert value.SourceTimestamp.replace(tzinfo=dt.UTC) == measured
            units = await (await coulomb.get_child("0:EngineeringUnits")).read_value()
            assert units.UnitId == engineering_units(latest.unit)[1]
            assert units.DisplayName.Text == latest.unit
            spread_units = await (
                await axis.get_child(f"{ns}:Spread/0:EngineeringUnits")
            ).read_value()
            assert spread_units.UnitId == 20529  # P1, percent
            change = await (await axis.get_child(f"{ns}:CoulombChange")).read_value()
            assert change == pytest.approx(-24.0, abs=0.5)
            health = await axis.get_child(f"{ns}:DeviceHealth")
            # −24 %: a warning; X's fault is its unchanged fingerprint, so no FAILURE
            assert await health.read_value() == 4  # MAINTENANCE_REQUIRED
            health_type = await health.read_data_type()
            di = await client.get_namespace_index("http://opcfoundation.org/UA/DI/")
            assert health_type == ua.NodeId(6244, di)
            # read-only: a write is refused
            with pytest.raises(ua.UaStatusCodeError):
                await coulomb.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))

            subscription, changes = await subscribe_changes(client, coulomb)
            first = await asyncio.wait_for(changes.get(), WAIT_S)  # the current value
            assert first == pytest.approx(latest.coulomb)

            def add() -> None:
                with open_store(store_with_machine, write=True) as store:
                    store.add(
                        make_results("2031-01-10T08:00:00+00:00", 0.5),
                        MeasurementInfo(serial="M17"),
                    )

            await asyncio.to_thread(add)
            newer = await asyncio.wait_for(changes.get(), WAIT_S)
            assert newer == pytest.approx(latest.coulomb / SERVICE_FACTOR * 0.5, rel=0.02)
            await subscription.delete()

    asyncio.run(scenario())


def test_the_limits_judge_status_and_health(store_with_machine: str, tmp_path: Path) -> None:
    """--warning/--critical as for store report: −24 % beyond a 20 % critical limit."""
    running = start(store_with_machine, tmp_path, Limits(warning_percent=10, critical_percent=20))
    server = next(running)

    async def scenario() -> None:
        from asyncua import Client

        async with Client(server.endpoint, timeout=30) as client:
            machines = await _browse(client, "Machines")
            ns = machines.nodeid.NamespaceIndex
            assert await (await machines.get_child(f"{ns}:WarningLimit")).read_value() == 10.0
            assert await (await machines.get_child(f"{ns}:CriticalLimit")).read_value() == 20.0
            for name in ("X", "Z"):
                axis = await _browse(client, "Machines", "M17", "Axes", name)
                verdict = await (await axis.get_child(f"{ns}:Verdict")).read_value()
                status = await (await axis.get_child(f"{ns}:Status")).read_value()
                health = await (await axis.get_child(f"{ns}:DeviceHealth")).read_value()
                assert status == "critical"
                # X's fault from its pattern is its fingerprint, unchanged: OFF_SPEC, as Z
                assert (verdict, health) == ("fault" if name == "X" else "ok", 3)

    try:
        asyncio.run(scenario())
    finally:
        with pytest.raises(StopIteration):
            next(running)


def test_the_docs_draw_the_address_space(server: Running) -> None:
    """Every node docs/shop-floor.md draws under Machines is there, and nothing else."""
    import re

    doc = (Path(__file__).parents[2] / "docs" / "shop-floor.md").read_text(encoding="utf-8")
    tree = doc[doc.index("### The address space") :]
    tree = tree[tree.index("```\nObjects") : tree.index("```", tree.index("Objects"))]
    drawn = [
        name for line in tree.splitlines() for name in re.findall(r"[├└]── ([\w, ]+?)  ", line)
    ]
    names = {n.strip() for group in drawn for n in group.split(",")}

    async def browse() -> tuple[set[str], set[str], set[str]]:
        from asyncua import Client

        async with Client(server.endpoint, timeout=30) as client:
            machines = await _browse(client, "Machines")
            machine = await _browse(client, "Machines", "M17")
            axis = await _browse(client, "Machines", "M17", "Axes", "X")

            async def children(node: Any) -> set[str]:
                return {(await c.read_browse_name()).Name for c in await node.get_children()}

            return await children(machines), await children(machine), await children(axis)

    under_machines, under_machine, under_axis = asyncio.run(browse())
    assert under_machines == {"WarningLimit", "CriticalLimit", "M17"}
    assert names == {"Machines", "X"} | under_machines | under_machine | under_axis


def test_settings_are_checked() -> None:
    for settings, words in (
        (OpcUaSettings(endpoint="http://127.0.0.1:4840"), "expected opc.tcp://HOST:PORT"),
        (OpcUaSettings(endpoint="opc.tcp://0.0.0.0:4840"), "needs a user"),
        (
            OpcUaSettings(endpoint="opc.tcp://0.0.0.0:4840", username="u", password="p"),
            "needs a user",
        ),
        (OpcUaSettings(username="u"), "go together"),
        (OpcUaSettings(refresh_s=0), "between 0.1 and 86400"),
        (OpcUaSettings(certificate=Path("c.pem")), "go together"),
    ):
        with pytest.raises(ConfigError) as caught:
            settings.checked()
        assert words in caught.value.message, (settings, caught.value.message)


def test_a_user_and_a_certificate(store_with_machine: str, tmp_path: Path) -> None:
    from asyncua import Client, ua

    cert, key = self_signed_rsa(tmp_path)
    running = start(
        store_with_machine, tmp_path, username="line3", password="s3cret-pw",
        certificate=cert, private_key=key,
    )  # fmt: skip
    server = next(running)
    client_cert, client_key = self_signed_rsa(tmp_path / "client")

    async def connect(password: str) -> float:
        client = Client(server.endpoint, timeout=30)
        client.set_user("line3")
        client.set_password(password)
        await client.set_security_string(
            f"Basic256Sha256,SignAndEncrypt,{client_cert},{client_key}"
        )
        async with client:
            axis = await _browse(client, "Machines", "M17", "Axes", "X")
            return float(
                await (await axis.get_child(f"{axis.nodeid.NamespaceIndex}:Coulomb")).read_value()
            )

    try:
        assert asyncio.run(connect("s3cret-pw")) > 0
        with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
            asyncio.run(connect("wrong"))
    finally:
        with pytest.raises(StopIteration):
            next(running)


def test_the_command_refuses_bad_input_in_one_line(store_with_machine: str) -> None:
    from typer.testing import CliRunner

    from ncmeasure.cli import app

    for args, words in (
        (["--endpoint", "opc.tcp://0.0.0.0:4840"], "needs a user"),
        (["--endpoint", "opc.tcp://127.0.0.1"], "expected opc.tcp://HOST:PORT"),
        (["--user", "line3"], "go together"),
    ):
        result = CliRunner().invoke(
            app, ["publish", "opcua", "--store", store_with_machine, *args], env={}
        )
        lines = result.stderr.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and words in lines[0], result.stderr
