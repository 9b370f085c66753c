"""``store export`` / ``store import``: a store as JSON lines, for backups and moving stores.

The first line is a header, ``{"format": "ncmeasure-store-export", "format_version": 1}``;
every further line is one measurement: the machine (serial, type, site), the
measurement's info and its full results. Importing adds each line as ``store add``
would, so importing the same file twice, or into a store that has some of it,
adds each measurement once. SQLite → PostgreSQL: export from one, import into the other.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from typing import IO, Any

from pydantic import ValidationError
from sqlalchemy import select

from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results
from ncmeasure.store import schema as t
from ncmeasure.store.records import MeasurementInfo, measurement_info
from ncmeasure.store.rows import decompress
from ncmeasure.store.store import Store

__all__ = [
    "EXPORT_FORMAT",
    "EXPORT_FORMAT_VERSION",
    "IMPORT_BATCH",
    "export_lines",
    "import_lines",
]

EXPORT_FORMAT = "ncmeasure-store-export"
EXPORT_FORMAT_VERSION = 1
IMPORT_BATCH = 50
"""Measurements per transaction of an import."""
MAX_LINE_BYTES = 64 * 1024 * 1024
"""One measurement's line; a longer line is not an export of ncmeasure's."""

_INFO_FIELDS = (
    "label",
    "site",
    "machine_type",
    "operator",
    "temperature_c",
    "operating_hours",
    "recording_location",
    "measured_utc",
)


def export_lines(store: Store) -> Iterator[str]:
    """The store as JSON lines (without line ends), oldest measurement first."""
    yield json.dumps({"format": EXPORT_FORMAT, "format_version": EXPORT_FORMAT_VERSION})
    m = t.measurements
    query = (
        select(
            m.c.id,
            t.machines.c.serial,
            t.machines.c.site,
            t.machine_types.c.name.label("machine_type"),
            m.c.label,
            m.c.operator,
            m.c.temperature_c,
            m.c.operating_hours,
            m.c.recording_location,
            m.c.measured_utc,
            m.c.results_json,
        )
        .join(t.machines, t.machines.c.id == m.c.machine_id)
        .join(t.machine_types, t.machine_types.c.id == t.machines.c.type_id)
        .order_by(m.c.measured_utc, m.c.id)
    )
    with store.reading("export the store") as db:
        for row in db.execution_options(yield_per=200).execute(query):
            record: dict[str, Any] = {"serial": row.serial}
            record.update({name: getattr(row, name) for name in _INFO_FIELDS})
            record["results"] = decompress(row.results_json).model_dump(mode="json")
            yield json.dumps(record, separators=(",", ":"), allow_nan=False)


def _records(stream: IO[bytes], where: str) -> Iterator[tuple[int, dict[str, Any]]]:
    for number, raw in enumerate(iter(lambda: stream.readline(MAX_LINE_BYTES + 1), b""), 1):
        if len(raw) > MAX_LINE_BYTES:
            raise ConfigError(f"{where}:{number}: a line longer than {MAX_LINE_BYTES} bytes")
        if not raw.strip():
            continue
        try:
            data = json.loads(raw)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{where}:{number}: not JSON ({exc})") from exc
        if not isinstance(data, dict):
            raise ConfigError(f"{where}:{number}: a line must be a JSON object")
        yield number, data


def import_lines(
    store: Store,
    stream: IO[bytes],
    where: str,
    progress: Callable[[int, bool], None] | None = None,
) -> tuple[int, int]:
    """Add every measurement of an export to ``store``.

    Lines are read and checked one by one and added :data:`IMPORT_BATCH` at a time, in
    one transaction each (memory stays bounded by a batch); each measurement is added
    whole or not at all. A bad line stops the import: the
    error names it and how many were added before it; importing the fixed file
    again skips those. Measurements already in the store are skipped.

    Returns:
        (added, already stored)

    Raises:
        ConfigError: Not an export, another format version, a line that is not a
            measurement (naming the line and the problem).
        StoreError: The database failed (what was added before stays, each
            measurement whole).
    """
    records = _records(stream, where)
    first = next(records, None)
    if first is None:
        raise ConfigError(f"{where}: empty; not an ncmeasure store export")
    _, header = first
    if header.get("format") != EXPORT_FORMAT:
        raise ConfigError(
            f"{where}:1: not an ncmeasure store export (format {header.get('format')!r})"
        )
    if header.get("format_version") != EXPORT_FORMAT_VERSION:
        raise ConfigError(
            f"{where}:1: export format_version {header.get('format_version')!r}; this "
            f"ncmeasure reads {EXPORT_FORMAT_VERSION}"
        )
    added = existing = 0

    def add(batch: list[tuple[Results, MeasurementInfo]]) -> None:
        nonlocal added, existing
        try:
            outcomes = store.add_many(batch)
        except ConfigError:
            if len(batch) == 1:
                raise
            # the batch is stored whole or not at all: one by one, the measurements
            # before the bad one are stored and the error counts them
            for one in batch:
                add([one])
            return
        for outcome in outcomes:
            added += outcome.new
            existing += not outcome.new
            if progress is not None:
                progress(added + existing, outcome.new)

    batch: list[tuple[Results, MeasurementInfo]] = []
    checked = _checked(records, where)
    try:
        while True:
            try:
                one = next(checked, None)
            except ConfigError:
                if batch:  # the measurements before the bad line are stored
                    add(batch)
                raise
            if one is None:
                break
            batch.append(one)
            if len(batch) == IMPORT_BATCH:
                add(batch)
                batch = []
        if batch:
            add(batch)
    except ConfigError as exc:
        if added or existing:
            exc.message += f" (the {added + existing} measurements before it are in the store)"
        raise
    return added, existing


def _checked(
    records: Iterable[tuple[int, dict[str, Any]]], where: str
) -> Iterator[tuple[Results, MeasurementInfo]]:
    for number, data in records:
        unknown = set(data) - {"serial", "results", *_INFO_FIELDS}
        if unknown:
            raise ConfigError(f"{where}:{number}: unknown keys {sorted(unknown)}")
        if not isinstance(data.get("serial"), str):
            raise ConfigError(f"{where}:{number}: no serial")
        try:
            results = Results.model_validate(data.get("results"))
            info = measurement_info(
                serial=data["serial"], **{name: data.get(name) for name in _INFO_FIELDS}
            )
        except ValidationError as exc:
            first = exc.errors()[0]
            place = ".".join(str(part) for part in first["loc"])
            raise ConfigError(f"{where}:{number}: results.{place}: {first['msg']}") from exc
        except (ConfigError, TypeError) as exc:
            raise ConfigError(f"{where}:{number}: {exc}") from exc
        yield results, info
