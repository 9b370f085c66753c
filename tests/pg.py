"""A throw-away PostgreSQL server for the store's tests and its benchmark.

initdb and pg_ctl of the Debian package ``postgresql`` start a server in a
temporary folder, listening on 127.0.0.1 only, on a free port; as root it runs
as the user ``postgres`` (or ``nobody``), since PostgreSQL refuses root.
"""

from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

PG_USER = "ncm"


def _pg_bin() -> Path | None:
    found = shutil.which("initdb")
    if found:
        return Path(found).resolve().parent
    candidates = sorted(Path("/usr/lib/postgresql").glob("*/bin/initdb"))
    return candidates[-1].parent if candidates else None


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _server_user() -> pwd.struct_passwd | None:
    """The user the server runs as: None (ourselves) unless we are root."""
    if os.geteuid() != 0:
        return None
    for name in ("postgres", "nobody"):
        with contextlib.suppress(KeyError):
            return pwd.getpwnam(name)
    raise RuntimeError(
        "running as root, and neither user postgres nor nobody exists to run PostgreSQL"
    )


class PostgresMissingError(RuntimeError):
    """PostgreSQL is not installed."""


@contextlib.contextmanager
def temporary_postgres(
    folder: Path | None = None, *, fsync: bool = False, shared_buffers: str = "32MB"
) -> Iterator[str]:
    """A fresh PostgreSQL server in a temporary folder on a free loopback port, stopped and
    removed on exit: the URL of its ``postgres`` database (superuser ``ncm``, no password).

    With ``folder``, the cluster lives there and is kept: stopped on exit, started again
    (with its data) by the next call with the same folder. ``fsync=False`` (the tests)
    trades durability for speed; a benchmark that compares with SQLite wants ``True``
    and PostgreSQL's default ``shared_buffers="128MB"``.

    Raises:
        PostgresMissingError: initdb is not installed.
        RuntimeError: the server did not start.
    """
    bin_dir = _pg_bin()
    if bin_dir is None:
        raise PostgresMissingError("PostgreSQL (Debian package postgresql) is not installed")
    user = _server_user()
    keep = folder is not None
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    root = folder if folder is not None else Path(tempfile.mkdtemp(prefix="ncmeasure-pg-"))
    data, sockets, log = root / "data", root / "run", root / "server.log"
    sockets.mkdir(exist_ok=True)
    if user is not None:
        for path in (root, sockets):
            os.chown(path, user.pw_uid, user.pw_gid)
    as_user = {"user": user.pw_uid, "group": user.pw_gid} if user else {}
    env = {**os.environ, "LC_ALL": "C", "LANG": "C"}
    if not (data / "PG_VERSION").exists():
        subprocess.run(
            [bin_dir / "initdb", "-D", data, "-U", PG_USER, "--auth=trust", "-E", "UTF8", "-N"],
            check=True, capture_output=True, timeout=180, env=env, cwd=root, **as_user,
        )  # fmt: skip
    port = None
    for _ in range(5):  # another process may take the port between probe and start
        port = _free_port()
        options = (
            f"-p {port} -k {sockets} -c listen_addresses=127.0.0.1 "
            f"-c fsync={'on' if fsync else 'off'} -c max_connections=60 "
            f"-c shared_buffers={shared_buffers}"
        )
        started = subprocess.run(
            [bin_dir / "pg_ctl", "-D", data, "-l", log, "-o", options, "-w", "-t", "120", "start"],
            capture_output=True, text=True, timeout=180, env=env, cwd=root, **as_user,
        )  # fmt: skip
        if started.returncode == 0:
            break
    else:
        raise RuntimeError(f"PostgreSQL did not start: {log.read_text(errors='replace')[-2000:]}")
    try:
        yield f"postgresql://{PG_USER}@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run(
            [bin_dir / "pg_ctl", "-D", data, "-m", "fast", "-w", "-t", "60", "stop"],
            capture_output=True, timeout=120, env=env, cwd=root, **as_user,
        )  # fmt: skip
        if not keep:
            shutil.rmtree(root, ignore_errors=True)
