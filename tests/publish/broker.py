"""A throw-away mosquitto broker for the MQTT tests.

Debian's ``mosquitto`` runs from a configuration file in a temporary folder,
listening on 127.0.0.1 only, on a free port: anonymous, or with a password file
(``mosquitto_passwd``) and optionally an access control list, optionally with
TLS (a self-signed certificate for 127.0.0.1 made here with ``cryptography``).
As root it stays root (``user root``): the files live in the test's private
temporary folder.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import ipaddress
import os
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path


class MosquittoMissingError(RuntimeError):
    """mosquitto is not installed."""


@dataclass(frozen=True)
class Broker:
    port: int
    ca_file: Path | None = None


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _mosquitto() -> str:
    for candidate in (shutil.which("mosquitto"), "/usr/sbin/mosquitto"):
        if candidate and Path(candidate).is_file():
            return candidate
    raise MosquittoMissingError("mosquitto (Debian package mosquitto) is not installed")


def self_signed(folder: Path) -> tuple[Path, Path]:
    """A certificate and key for 127.0.0.1 (its own CA): (cert.pem, key.pem)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "127.0.0.1")])
    now = dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(days=1))
        .not_valid_after(now + dt.timedelta(days=2))
        .add_extension(
            x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False,
        )
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )
    cert_file, key_file = folder / "cert.pem", folder / "key.pem"
    cert_file.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_file.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )
    key_file.chmod(0o600)
    return cert_file, key_file


@contextlib.contextmanager
def temporary_mosquitto(
    folder: Path,
    *,
    user: tuple[str, str] | None = None,
    tls: bool = False,
    acl: str | None = None,
) -> Iterator[Broker]:
    """A running broker on a free loopback port; stopped on exit.

    Args:
        folder: Where its configuration (and password file, certificate) go.
        user: (name, password): the only client let in; else anonymous clients.
        tls: Listen with TLS (a self-signed certificate for 127.0.0.1).
        acl: The text of mosquitto's acl_file (mosquitto.conf(5)): what each user
            may read and write.
    """
    binary = _mosquitto()
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["persistence false", "log_dest stderr", "log_type error", "log_type warning"]
    if os.geteuid() == 0:
        lines.append("user root")
    if user is not None:
        passwords = folder / "passwords"
        subprocess.run(
            ["mosquitto_passwd", "-c", "-b", passwords, *user],
            check=True, capture_output=True, timeout=60,
        )  # fmt: skip
        passwords.chmod(0o600)
        lines += ["allow_anonymous false", f"password_file {passwords}"]
    else:
        lines.append("allow_anonymous true")
    if acl is not None:
        acl_file = folder / "acl"
        acl_file.write_text(acl, encoding="utf-8")
        acl_file.chmod(0o600)
        lines.append(f"acl_file {acl_file}")
    ca_file = None
    if tls:
        ca_file, key_file = self_signed(folder)
        lines += [f"certfile {ca_file}", f"keyfile {key_file}"]
    for _ in range(5):  # another process may take the port between probe and start
        port = free_port()
        config = folder / "mosquitto.conf"
        config.write_text("\n".join([f"listener {port} 127.0.0.1", *lines]) + "\n")
        log = (folder / "broker.log").open("wb")
        process = subprocess.Popen([binary, "-c", str(config)], stdout=log, stderr=log)
        deadline = time.monotonic() + 60
        listening = False
        while not listening and process.poll() is None and time.monotonic() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", port), 1):
                    listening = True
            except OSError:
                time.sleep(0.05)
        if listening:
            break
        process.kill()
        process.wait(timeout=30)
        log.close()
    else:
        raise RuntimeError(f"mosquitto did not start: {(folder / 'broker.log').read_text()}")
    try:
        yield Broker(port=port, ca_file=ca_file)
    finally:
        process.terminate()
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=30)
        log.close()
