"""A small fleet in a temporary store, and ``ncmeasure serve`` running on it in a thread.

The results are synthetic recordings analysed for real (two axes, 8 velocities,
a fraction of a second each). The fleet:

========  ===========================================  ==============================
M-100     delivery, then a service 2000 h later         both axes ok
M-101     delivery ok, then axis Y rising to the        the latest Y fault
          loose bearing (28 % along the travel)
M-102     one measurement, Y with a moderate pattern    Y check
M-103     one measurement of axis X only; its site is   X ok, no Y
          markup (``<script>``) that must stay text
========  ===========================================  ==============================
"""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

from ncmeasure.analysis.analyze import analyze
from ncmeasure.formats.results import Results
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording
from ncmeasure.store import MeasurementInfo, open_store
from ncmeasure.web import ServerInfo, serve

WAIT_S = 30.0
"""The longest wait for the server to start or stop: generous, for a loaded machine."""
VELOCITIES = geometric_velocities(10.0, 15000.0, 8)
SCRIPT_SITE = "<script>alert('site')</script> Hall 3"
TOKEN = "test-token-0123456789-abcdefghij"


def matplotlib_loaded_by(script: str) -> list[str]:
    """The matplotlib modules a fresh interpreter has imported after running ``script``
    (which must succeed): the dashboard's figures are drawn without it."""
    done = subprocess.run(
        [sys.executable, "-c", script + "\nimport sys\n"
         "print(*sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))\n"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


def analysed(directory: Path, y_coulomb: float | tuple[float, ...] | None, seed: int) -> Results:
    """Results of axis X (flat, 2 Nm) and, unless None, axis Y with this Coulomb friction."""
    axes = [SyntheticAxis(name="X", coulomb=2.0, velocities_mm_min=VELOCITIES)]
    if y_coulomb is not None:
        axes.append(SyntheticAxis(name="Y", coulomb=y_coulomb, velocities_mm_min=VELOCITIES))
    recording, schedule = synthetic_recording(directory, axes, seed=seed)
    return analyze(recording, schedule=schedule)


@dataclass(frozen=True)
class Stored:
    """One measurement put into the test store."""

    info: MeasurementInfo
    results: Results
    measurement_id: int


@dataclass(frozen=True)
class Fleet:
    """The test store and what was put into it."""

    url: str
    stored: list[Stored]
    spare: Results
    """Analysed but not stored: for adding through the API."""

    def of(self, serial: str) -> list[Stored]:
        """The stored measurements of one machine, oldest first."""
        return [s for s in self.stored if s.info.serial == serial]


_PLAN: list[tuple[MeasurementInfo, float | tuple[float, ...] | None]] = [
    (
        MeasurementInfo(
            serial="M-100",
            label="delivery",
            site="Hall 1",
            operator="A. Technician",
            temperature_c=21.5,
            operating_hours=12.0,
            measured_utc="2025-01-10T09:00:00+00:00",
        ),
        2.0,
    ),
    (
        MeasurementInfo(
            serial="M-100",
            label="service",
            operator="B. Service",
            temperature_c=23.0,
            operating_hours=2012.0,
            measured_utc="2025-07-10T09:00:00+00:00",
        ),
        2.0,
    ),
    (
        MeasurementInfo(
            serial="M-101", label="delivery", site="Hall 1", measured_utc="2025-02-01T10:00:00Z"
        ),
        2.0,
    ),
    (
        MeasurementInfo(serial="M-101", label="after-crash", measured_utc="2025-09-01T10:00:00Z"),
        (2.0, 2.4, 2.8),
    ),
    (
        MeasurementInfo(serial="M-102", label="delivery", measured_utc="2025-03-01T08:00:00Z"),
        (2.0, 2.1, 2.2),
    ),
    (
        MeasurementInfo(
            serial="M-103", label="delivery", site=SCRIPT_SITE, measured_utc="2025-04-01T08:00:00Z"
        ),
        None,
    ),
]


@pytest.fixture(scope="session")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Fleet:
    """The store of the module docstring (SQLite in a temporary folder)."""
    folder = tmp_path_factory.mktemp("fleet")
    url = f"sqlite:///{folder / 'fleet.db'}"
    stored = []
    with open_store(url, write=True) as store:
        for seed, (info, y_coulomb) in enumerate(_PLAN):
            results = analysed(folder / f"run{seed}", y_coulomb, seed)
            added = store.add(results, info)
            stored.append(Stored(info, results, added.measurement_id))
    spare = analysed(folder / "spare", 2.0, len(_PLAN))
    return Fleet(url, stored, spare)


@contextmanager
def running(url: str, token: str | None = None) -> Iterator[ServerInfo]:
    """``serve`` on 127.0.0.1 and a free port in a thread; stopped and joined on exit."""
    ready: queue.Queue[ServerInfo | BaseException | None] = queue.Queue()
    stop = threading.Event()

    def target() -> None:
        try:
            serve(url, "127.0.0.1", 0, token, on_ready=ready.put, stop=stop, log_level="warning")
        except BaseException as exc:
            ready.put(exc)
        else:
            ready.put(None)

    thread = threading.Thread(target=target, name="ncmeasure-serve", daemon=True)
    thread.start()
    try:
        started = ready.get(timeout=WAIT_S)
        if isinstance(started, BaseException):
            raise started
        assert started is not None, "the server ended before it was ready"
        yield started
    finally:
        stop.set()
        thread.join(timeout=WAIT_S)
        assert not thread.is_alive(), "the server did not stop"


@pytest.fixture(scope="session")
def server(fleet: Fleet) -> Iterator[ServerInfo]:
    """The server on the fleet's store, without a token (loopback only)."""
    with running(fleet.url) as info:
        yield info


@pytest.fixture(scope="session")
def token_server(fleet: Fleet) -> Iterator[ServerInfo]:
    """The server on the fleet's store with :data:`TOKEN`."""
    with running(fleet.url, TOKEN) as info:
        yield info
