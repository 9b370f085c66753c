"""The fleet store: every fingerprint of every machine over its life, in a database.

SQLAlchemy over SQLite (a file, the default) or PostgreSQL (psycopg 3), chosen by
a URL; the schema is versioned with Alembic and upgraded on opening. Raw
recordings stay files; the store keeps the results as queryable rows (points,
fits, offset, position signature, verdict) and as lossless JSON.

    with open_store("sqlite:///fleet.db", write=True) as store:
        store.add(results, MeasurementInfo(serial="M17", label="delivery"))
        check = check_machine(store, "M17")

Needs the ``store`` extra: ``pip install 'ncmeasure[store]'``.
"""

from __future__ import annotations

from ncmeasure.store.database import STORE_ENV, default_store, store_url
from ncmeasure.store.records import (
    Added,
    MachineSummary,
    MeasurementInfo,
    MeasurementSummary,
    TrendPoint,
    check_serial,
    measurement_info,
)
from ncmeasure.store.store import Store, open_store

__all__ = [
    "STORE_ENV",
    "Added",
    "MachineSummary",
    "MeasurementInfo",
    "MeasurementSummary",
    "Store",
    "TrendPoint",
    "check_serial",
    "default_store",
    "measurement_info",
    "open_store",
    "store_url",
]
