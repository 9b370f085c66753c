"""Fixtures of the store tests: results of a fleet, and a real PostgreSQL server.

The server is Debian's ``postgresql`` package, started once per test session in a
temporary folder as a non-root user (``postgres``, else ``nobody``, when the tests
run as root), on a free loopback port, with trust authentication. Without the
package the PostgreSQL tests skip on a developer's machine and fail under
``CI=true``: CI installs it (``.ci/run``).
"""

from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from ncmeasure.analysis.results import AxisResult, Results
from tests.report.example import build_results, simulate

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
    pytest.fail("running as root, and neither user postgres nor nobody exists to run PostgreSQL")


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """The URL of a fresh PostgreSQL server's ``postgres`` database (as superuser ``ncm``)."""
    bin_dir = _pg_bin()
    if bin_dir is None:
        message = "PostgreSQL (Debian package postgresql) is not installed"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{message}: .ci/run installs it")
        pytest.skip(message)
    user = _server_user()
    root = Path(tempfile.mkdtemp(prefix="ncmeasure-pg-"))
    data, sockets, log = root / "data", root / "run", root / "server.log"
    sockets.mkdir()
    if user is not None:
        for path in (root, sockets):
            os.chown(path, user.pw_uid, user.pw_gid)
    as_user = {"user": user.pw_uid, "group": user.pw_gid} if user else {}
    env = {**os.environ, "LC_ALL": "C", "LANG": "C"}
    subprocess.run(
        [bin_dir / "initdb", "-D", data, "-U", PG_USER, "--auth=trust", "-E", "UTF8", "-N"],
        check=True, capture_output=True, timeout=180, env=env, cwd=root, **as_user,
    )  # fmt: skip
    port = None
    for _ in range(5):  # another process may take the port between probe and start
        port = _free_port()
        options = (
            f"-p {port} -k {sockets} -c listen_addresses=127.0.0.1 -c fsync=off "
            "-c max_connections=60 -c shared_buffers=32MB"
        )
        started = subprocess.run(
            [bin_dir / "pg_ctl", "-D", data, "-l", log, "-o", options, "-w", "-t", "120", "start"],
            capture_output=True, text=True, timeout=180, env=env, cwd=root, **as_user,
        )  # fmt: skip
        if started.returncode == 0:
            break
    else:
        pytest.fail(f"PostgreSQL did not start: {log.read_text(errors='replace')[-2000:]}")
    try:
        yield f"postgresql://{PG_USER}@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run(
            [bin_dir / "pg_ctl", "-D", data, "-m", "fast", "-w", "-t", "60", "stop"],
            capture_output=True, timeout=120, env=env, cwd=root, **as_user,
        )  # fmt: skip
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture
def pg_url(postgres_server: str) -> str:
    """A new, empty database on the session's server."""
    import psycopg

    name = f"t_{uuid.uuid4().hex[:12]}"
    admin = postgres_server.replace("postgresql://", "postgresql://", 1)
    with psycopg.connect(admin, autocommit=True, connect_timeout=30) as connection:
        connection.execute(f'CREATE DATABASE "{name}"')
    return postgres_server.rsplit("/", 1)[0] + f"/{name}"


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """An empty store of each kind."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'fleet.db'}"
    return str(request.getfixturevalue("pg_url"))


@pytest.fixture(scope="session")
def base_results(tmp_path_factory: pytest.TempPathFactory) -> Results:
    """Results of a simulated two-axis machine (X with a shifted loose bearing, Z vertical)."""
    recording, windows = simulate(tmp_path_factory.mktemp("store-recording") / "run")
    return build_results(recording, windows)


def scaled_axis(axis: AxisResult, factor: float) -> AxisResult:
    """The axis with all friction ``factor`` times as high (points, fits, offset)."""
    positions = []
    for position in axis.positions:
        directions = {}
        for name, found in position.directions.items():
            if found is None:
                directions[name] = None
                continue
            fit = found.fit
            if fit is not None:
                fit = fit.model_copy(
                    update={
                        "coulomb": None if fit.coulomb is None else fit.coulomb * factor,
                        "viscous_per_mm_min": None
                        if fit.viscous_per_mm_min is None
                        else fit.viscous_per_mm_min * factor,
                    }
                )
            points = [p.model_copy(update={"median": p.median * factor}) for p in found.points]
            directions[name] = found.model_copy(update={"points": points, "fit": fit})
        positions.append(position.model_copy(update={"directions": directions}))
    offset = axis.offset
    if offset is not None:
        offset = offset.model_copy(update={"value": offset.value * factor})
    return axis.model_copy(update={"positions": positions, "offset": offset})


@pytest.fixture(scope="session")
def make_results(base_results: Results) -> Callable[..., Results]:
    """Results of a measurement started at ``when`` (ISO 8601, which makes them unique);
    ``factor`` scales the friction."""

    def make(when: str, factor: float = 1.0) -> Results:
        axes = {name: scaled_axis(axis, factor) for name, axis in base_results.axes.items()}
        recording = base_results.recording.model_copy(
            update={"directory": f"recordings/{when}", "start_utc": when}
        )
        return base_results.model_copy(
            update={"axes": axes, "recording": recording, "created_utc": when}
        )

    return make
