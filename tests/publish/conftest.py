"""Fixtures of the shop-floor tests: a store with a machine, a real mosquitto broker.

Without the Debian package ``mosquitto`` the broker tests skip on a developer's
machine and fail under ``CI=true``: CI installs it (``.ci/run``).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from ncmeasure.formats.results import Results
from tests.publish.broker import Broker, MosquittoMissingError, temporary_mosquitto
from tests.store.conftest import base_results, make_results

SERVICE_FACTOR = 0.76
"""The service measurement's friction against delivery's (store_with_machine)."""

__all__ = ["base_results", "make_results"]


def _broker(folder: Path, **options: object) -> Iterator[Broker]:
    try:
        with temporary_mosquitto(folder, **options) as broker:  # type: ignore[arg-type]
            yield broker
    except MosquittoMissingError as exc:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{exc}: .ci/run installs it")
        pytest.skip(str(exc))


@pytest.fixture(scope="session")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Broker]:
    """An anonymous broker for the session."""
    yield from _broker(tmp_path_factory.mktemp("mosquitto"))


@pytest.fixture(scope="session")
def secure_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Broker]:
    """A broker with TLS that lets in the user ``line3`` with the password ``s3cret-pw``."""
    yield from _broker(
        tmp_path_factory.mktemp("mosquitto-tls"), user=("line3", "s3cret-pw"), tls=True
    )


@pytest.fixture(scope="session")
def password_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Broker]:
    """A plain (no TLS) broker that lets in the user ``line3`` with the password ``s3cret-pw``."""
    yield from _broker(tmp_path_factory.mktemp("mosquitto-user"), user=("line3", "s3cret-pw"))


@pytest.fixture(scope="session")
def read_only_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Broker]:
    """A broker whose access rules let ``line3`` (password ``s3cret-pw``) read, not write,
    ``ncmeasure/#`` (and write ``probe/#``, for the subscriber's end marker)."""
    yield from _broker(
        tmp_path_factory.mktemp("mosquitto-acl"),
        user=("line3", "s3cret-pw"),
        acl="user line3\ntopic read ncmeasure/#\ntopic readwrite probe/#\n",
    )


@pytest.fixture
def store_with_machine(tmp_path: Path, make_results: Callable[..., Results]) -> str:
    """A SQLite store: M17 (site plant-2) at delivery and at a service 24 % lower.

    Not 25 %: that is the default critical limit, and a change of exactly −25 % lands
    on either side of it by the last bit of a float (numpy 2.4 put it beyond).
    """
    from ncmeasure.store import MeasurementInfo, open_store

    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    with open_store(url, write=True) as store:
        store.add(
            make_results("2026-01-10T08:00:00+00:00"),
            MeasurementInfo(serial="M17", label="delivery", site="plant-2"),
        )
        store.add(
            make_results("2029-01-10T08:00:00+00:00", SERVICE_FACTOR),
            MeasurementInfo(serial="M17", label="service"),
        )
    return url
