"""Fixtures of the store tests: results of a fleet, and a real PostgreSQL server.

The server is Debian's ``postgresql`` package, started once per test session in a
temporary folder as a non-root user (``postgres``, else ``nobody``, when the tests
run as root), on a free loopback port, with trust authentication. Without the
package the PostgreSQL tests skip on a developer's machine and fail under
``CI=true``: CI installs it (``.ci/run``).
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from ncmeasure.formats.results import Results
from tests.pg import PostgresMissingError, temporary_postgres
from tests.report.example import build_results, scaled_axis, simulate


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """The URL of a fresh PostgreSQL server's ``postgres`` database (as superuser ``ncm``)."""
    try:
        with temporary_postgres() as url:
            yield url
    except PostgresMissingError as exc:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{exc}: .ci/run installs it")
        pytest.skip(str(exc))


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
