"""`ncmeasure publish opcua` as a user starts it: its own process, a real asyncua client, a signal.

The command runs as a subprocess on a free loopback port over a SQLite store. An
asyncua client browses to an axis, reads what the store holds, is refused when
it writes or adds a node, subscribes to a characteristic and sees it change
after a `store add` in another process; Ctrl-C (SIGINT) or SIGTERM stop the
server with exit code 0. With a user, a certificate and a trust list, only a
trusted client with the right password gets in. Every wait is bounded.
"""

from __future__ import annotations

import asyncio
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.formats.results import Results, write_results
from ncmeasure.publish.opcua import NAMESPACE, PASSWORD_ENV, TrustList, load_trusted_clients
from ncmeasure.store import open_store
from tests.publish.broker import free_port
from tests.publish.certificates import rsa_certificate
from tests.publish.conftest import SERVICE_FACTOR
from tests.publish.opcua_client import subscribe_changes

WAIT_S = 60.0
"""A guard against a hang, never part of what a test asserts."""


@dataclass
class Server:
    process: subprocess.Popen[str]
    endpoint: str
    lines: queue.Queue[str | None] = field(default_factory=queue.Queue)

    def stop(self, sig: int = signal.SIGINT) -> tuple[int, str, str]:
        """Send ``sig`` and wait: exit code, the rest of stdout, stderr."""
        self.process.send_signal(sig)
        try:
            self.process.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=WAIT_S)
            raise
        rest = []
        while (line := self.lines.get(timeout=WAIT_S)) is not None:
            rest.append(line)
        assert self.process.stderr is not None
        return self.process.returncode, "".join(rest), self.process.stderr.read()


def _pump(stream: Any, lines: queue.Queue[str | None]) -> None:
    for line in stream:
        lines.put(line)
    lines.put(None)


def _source_path() -> str:
    """PYTHONPATH for the command: the ncmeasure these tests import, then the caller's."""
    import ncmeasure

    here = str(Path(ncmeasure.__file__).resolve().parents[1])
    return os.pathsep.join(p for p in (here, os.environ.get("PYTHONPATH")) if p)


@contextmanager
def command(store: str, *options: str, env: dict[str, str] | None = None) -> Iterator[Server]:
    """``ncmeasure publish opcua`` on a free loopback port, until the block ends.

    Another process may take the port between the probe and the start: the
    command then refuses in one line and is started again on another port.
    """
    for _ in range(5):
        endpoint = f"opc.tcp://127.0.0.1:{free_port()}"
        process = subprocess.Popen(
            [sys.executable, "-m", "ncmeasure", "publish", "opcua", "--store", store,
             "--endpoint", endpoint, "--refresh-s", "0.2", *options],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env={**os.environ, **(env or {}), "COLUMNS": "200", "PYTHONPATH": _source_path()},
        )  # fmt: skip
        server = Server(process, endpoint)
        threading.Thread(target=_pump, args=(process.stdout, server.lines), daemon=True).start()
        first = server.lines.get(timeout=WAIT_S)
        if first is not None and first.startswith("serving "):
            break
        process.wait(timeout=WAIT_S)
        assert process.stderr is not None
        err = process.stderr.read()
        assert "cannot listen" in err, (first, err)
    else:
        pytest.fail("no free port for the OPC UA server in five attempts")
    assert first == f"serving {store} at {endpoint}; Ctrl-C stops\n"
    try:
        yield server
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=WAIT_S)


async def _axis(client: Any, serial: str, axis: str) -> Any:
    ns = await client.get_namespace_index(NAMESPACE)
    return await client.nodes.objects.get_child(
        [f"{ns}:Machines", f"{ns}:{serial}", f"{ns}:Axes", f"{ns}:{axis}"]
    )


def test_the_command_serves_the_store_and_notifies_a_change(
    store_with_machine: str, tmp_path: Path, make_results: Callable[..., Results]
) -> None:
    from asyncua import Client, ua

    with open_store(store_with_machine) as store:
        latest = store.trend("M17", "X")[-1]
    newer = write_results(make_results("2031-01-10T08:00:00+00:00", 0.5), tmp_path / "r.json")

    with command(store_with_machine) as server:

        async def scenario() -> tuple[float, float]:
            async with Client(server.endpoint, timeout=30) as client:
                axis = await _axis(client, "M17", "X")
                ns = axis.nodeid.NamespaceIndex
                coulomb = await axis.get_child(f"{ns}:Coulomb")
                value = await coulomb.read_data_value()
                assert value.Value.Value == pytest.approx(latest.coulomb)
                assert value.SourceTimestamp is not None
                assert (await (await axis.get_child(f"{ns}:Verdict")).read_value()) == (
                    latest.verdict
                )
                health = await (await axis.get_child(f"{ns}:DeviceHealth")).read_data_value()
                assert health.SourceTimestamp == value.SourceTimestamp
                units = await (await coulomb.get_child("0:EngineeringUnits")).read_value()
                assert units.DisplayName.Text == latest.unit
                # read-only for the anonymous user: no write, no new node
                with pytest.raises(ua.UaStatusCodeError):
                    await coulomb.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))
                with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                    await client.nodes.objects.add_folder(f"ns={ns};s=Intruder", f"{ns}:Intruder")

                subscription, changes = await subscribe_changes(client, coulomb)
                first = await asyncio.wait_for(changes.get(), WAIT_S)  # the current value

                def store_add() -> None:  # another process' store add, as on the shop floor
                    result = CliRunner().invoke(
                        app, ["store", "add", str(newer), "--serial", "M17",
                              "--store", store_with_machine],
                    )  # fmt: skip
                    assert result.exit_code == 0, result.stderr

                await asyncio.to_thread(store_add)
                changed = await asyncio.wait_for(changes.get(), WAIT_S)
                await subscription.delete()
                return first, changed

        first, changed = asyncio.run(scenario())
        code, out, err = server.stop(signal.SIGINT)

    assert first == pytest.approx(latest.coulomb)
    with open_store(store_with_machine) as store:
        assert changed == pytest.approx(store.trend("M17", "X")[-1].coulomb)
    assert changed == pytest.approx(latest.coulomb / SERVICE_FACTOR * 0.5, rel=0.02)
    assert code == 0, err
    assert out == "stopped\n" and "Traceback" not in err


def test_the_command_with_a_user_a_certificate_and_a_trust_list(
    store_with_machine: str, tmp_path: Path
) -> None:
    from asyncua import Client, ua

    server_cert = rsa_certificate(tmp_path / "server", "server")
    trusted = rsa_certificate(tmp_path / "clients", "line3-hmi")
    stranger = rsa_certificate(tmp_path / "elsewhere", "stranger")
    trust_folder = tmp_path / "trusted"
    trust_folder.mkdir()
    shutil.copy(trusted.cert_file, trust_folder / "line3-hmi.pem")

    async def read(
        endpoint: str, client_cert: Any, user: str | None, password: str | None
    ) -> float:
        client = Client(endpoint, timeout=30)
        if user is not None:
            client.set_user(user)
        if password is not None:
            client.set_password(password)
        await client.set_security_string(
            f"Basic256Sha256,SignAndEncrypt,{client_cert.cert_file},{client_cert.key_file}"
        )
        async with client:
            axis = await _axis(client, "M17", "X")
            node = await axis.get_child(f"{axis.nodeid.NamespaceIndex}:Coulomb")
            return float(await node.read_value())

    with command(
        store_with_machine,
        "--user", "line3",
        "--certificate", str(server_cert.cert_file),
        "--private-key", str(server_cert.key_file),
        "--trusted-clients", str(trust_folder),
        env={PASSWORD_ENV: "s3cret-pw"},
    ) as server:  # fmt: skip
        assert asyncio.run(read(server.endpoint, trusted, "line3", "s3cret-pw")) > 0
        with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
            asyncio.run(read(server.endpoint, trusted, "line3", "wrong"))
        with pytest.raises(ua.UaStatusCodeError, match="BadCertificateUntrusted"):
            asyncio.run(read(server.endpoint, stranger, "line3", "s3cret-pw"))
        with pytest.raises(ua.UaStatusCodeError, match="BadIdentityTokenRejected"):
            asyncio.run(read(server.endpoint, trusted, None, None))  # anonymous: not offered

        async def unencrypted() -> None:
            async with Client(server.endpoint, timeout=30) as client:
                await _axis(client, "M17", "X")

        with pytest.raises(ua.UaError, match="No matching endpoints"):
            asyncio.run(unencrypted())  # no unencrypted endpoint
        code, out, err = server.stop(signal.SIGTERM)
    assert code == 0 and out == "stopped\n", err
    assert "Traceback" not in err


def test_the_trust_list_takes_certificates_and_their_cas(tmp_path: Path) -> None:
    ca = rsa_certificate(tmp_path / "ca", "plant-ca", ca=True)
    issued = rsa_certificate(tmp_path / "hmi", "hmi", issuer=ca)
    other_ca = rsa_certificate(tmp_path / "other", "other-ca", ca=True)
    foreign = rsa_certificate(tmp_path / "foreign", "foreign", issuer=other_ca)
    own = rsa_certificate(tmp_path / "own", "own")
    expired = rsa_certificate(tmp_path / "old", "old", valid_days=(-10, -1))
    folder = tmp_path / "trusted"
    folder.mkdir()
    for source in (ca, own, expired):
        shutil.copy(source.cert_file, folder / source.cert_file.name)
    (folder / "README.txt").write_text("not a certificate, not read", encoding="utf-8")
    trust = TrustList(load_trusted_clients(folder))
    assert trust.trusts(issued.certificate)  # issued by a CA in the folder
    assert trust.trusts(own.certificate)  # itself in the folder
    assert not trust.trusts(foreign.certificate)
    assert not trust.trusts(other_ca.certificate)
    assert not trust.trusts(expired.certificate)  # in the folder, but no longer valid


def test_a_bad_trust_list_is_refused_in_one_line(store_with_machine: str, tmp_path: Path) -> None:
    server_cert = rsa_certificate(tmp_path / "server", "server")
    keys = tmp_path / "keys"
    keys.mkdir()
    shutil.copy(server_cert.key_file, keys / "server-key.pem")
    empty = tmp_path / "empty"
    empty.mkdir()
    secure = ["--user", "line3", "--certificate", str(server_cert.cert_file),
              "--private-key", str(server_cert.key_file)]  # fmt: skip
    for options, words in (
        (["--trusted-clients", str(empty)], "no certificate in it"),
        (["--trusted-clients", str(keys)], "server-key.pem: not a certificate"),
        (["--trusted-clients", str(tmp_path / "none")], "no such folder"),
    ):
        result = CliRunner().invoke(
            app,
            ["publish", "opcua", "--store", store_with_machine, *secure, *options],
            env={PASSWORD_ENV: "pw"},
        )
        lines = result.stderr.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and words in lines[0], result.stderr
    result = CliRunner().invoke(
        app, ["publish", "opcua", "--store", store_with_machine, "--trusted-clients", str(empty)]
    )
    assert result.exit_code == 2 and "give --certificate and --private-key" in result.stderr
