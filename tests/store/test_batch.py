"""Adding many measurements at once: a few statements per batch, one comparison per machine,
and the same rows and changes as adding them one by one."""

from __future__ import annotations

import io
import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import event, func, select

from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results
from ncmeasure.store import MeasurementInfo, Store, open_store
from ncmeasure.store import schema as t
from ncmeasure.store.changes import stored_changes
from ncmeasure.store.overview import fleet_overview
from ncmeasure.store.transfer import export_lines, import_lines

Make = Callable[..., Results]


@contextmanager
def _statements(store: Store) -> Iterator[list[str]]:
    """The SQL statements the store runs meanwhile (an executemany counts once)."""
    seen: list[str] = []

    def count(*args: Any) -> None:
        seen.append(args[2])

    event.listen(store.engine, "before_cursor_execute", count)
    try:
        yield seen
    finally:
        event.remove(store.engine, "before_cursor_execute", count)


def _fleet(make: Make, machines: int, each: int) -> list[tuple[Results, MeasurementInfo]]:
    return [
        (
            make(f"{2026 + k}-0{1 + m}-01T08:00:00+00:00", 1.0 + 0.01 * k + 0.001 * m),
            MeasurementInfo(serial=f"M{m}", label="delivery" if k == 0 else "service"),
        )
        for m in range(machines)
        for k in range(each)
    ]


def _table_counts(store: Store) -> dict[str, int]:
    """Rows per table; the changes of a machine's former (latest, baseline) pairs left out
    (single adds compare every pair on the way, a batch only the last)."""
    with store.reading("count") as db:
        return {
            table.name: db.execute(select(func.count()).select_from(table)).scalar_one()
            for table in t.metadata.sorted_tables
            if table not in (t.baseline_changes, t.axis_changes)
        }


def _current_changes(store: Store) -> list[Any]:
    """The stored change of each machine's current pair, by serial."""
    pairs = {m.serial: (m.latest_id, m.baseline_id) for m in fleet_overview(store).machines}
    with store.reading("changes") as db:
        found = stored_changes(db, list(pairs.values()))
    return [(serial, found.get(pair)) for serial, pair in sorted(pairs.items())]


def test_a_batch_costs_statements_per_table_not_per_row(
    store_url: str, make_results: Make, monkeypatch: pytest.MonkeyPatch
) -> None:
    compared: list[int] = []
    from ncmeasure.store import changes

    real = changes.diagnose_with_baseline

    def counted(*args: Any, **kwargs: Any) -> Any:
        compared.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(changes, "diagnose_with_baseline", counted)
    small = _fleet(make_results, 2, 2)
    large = [one for n, one in enumerate(_fleet(make_results, 2, 6)) if n % 6 >= 2]
    with open_store(store_url, write=True) as store:
        with _statements(store) as few:
            store.add_many(small)
        with _statements(store) as many:
            store.add_many(large)
    # the measurements' own INSERTs grow with the batch; nothing else does
    per_row = [s for s in many if s.lstrip().upper().startswith("INSERT INTO MEASUREMENTS")]
    assert len(per_row) == len(large)
    assert len(many) - len(per_row) <= len(few) - len(small) + 2
    assert len(compared) == 4  # once per machine and batch, its latest with its baseline


def test_a_batch_stores_what_single_adds_store(tmp_path: Path, make_results: Make) -> None:
    fleet = _fleet(make_results, 3, 3)
    with open_store(f"sqlite:///{tmp_path / 'one.db'}", write=True) as one:
        for results, info in fleet:
            one.add(results, info)
        single = (
            _table_counts(one),
            _current_changes(one),
            [
                (m.serial, m.status, {a: x.status for a, x in m.axes.items()})
                for m in fleet_overview(one).machines
            ],
        )
        listed = one.machines()
    with open_store(f"sqlite:///{tmp_path / 'many.db'}", write=True) as many:
        added = many.add_many([*fleet, fleet[0]])  # the same results twice: stored once
        assert [a.new for a in added] == [True] * len(fleet) + [False]
        assert added[-1].measurement_id == added[0].measurement_id
        batched = (
            _table_counts(many),
            _current_changes(many),
            [
                (m.serial, m.status, {a: x.status for a, x in m.axes.items()})
                for m in fleet_overview(many).machines
            ],
        )
        assert many.machines() == listed
    assert batched == single


def test_a_bad_measurement_in_a_batch_stores_none(store_url: str, make_results: Make) -> None:
    fleet = _fleet(make_results, 2, 2)
    with open_store(store_url, write=True) as store:
        store.add(*fleet[0])
        before = _table_counts(store)
        # the same results as M0's first, for another machine
        bad = (fleet[0][0], MeasurementInfo(serial="M9"))
        with pytest.raises(ConfigError, match=r"already stored as measurement \d+ of machine 'M0'"):
            store.add_many([fleet[1], fleet[2], bad])
        assert _table_counts(store) == before


def test_import_goes_in_batches_and_keeps_what_came_before_a_bad_line(
    tmp_path: Path, make_results: Make, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("ncmeasure.store.transfer.IMPORT_BATCH", 2)
    with open_store(f"sqlite:///{tmp_path / 'from.db'}", write=True) as source:
        source.add_many(_fleet(make_results, 2, 3))
        lines = list(export_lines(source))
    other = json.loads(lines[4])  # oldest first: M0, M1, M0, M1 (its second), ...
    other["serial"] = "M7"  # results of M1 stored under another serial: refused
    text = "\n".join([*lines[:4], json.dumps(other), *lines[5:]]) + "\n"
    with open_store(f"sqlite:///{tmp_path / 'to.db'}", write=True) as target:
        seen: list[int] = []
        target.add_many([_fleet(make_results, 2, 3)[4]])  # M1's second: stored already
        with pytest.raises(ConfigError, match="before it are in the store") as failed:
            import_lines(
                target, io.BytesIO(text.encode()), "fleet.jsonl", lambda n, _: seen.append(n)
            )
        assert "the 3 measurements" in str(failed.value)
        assert seen == [1, 2, 3]
        assert _table_counts(target)["measurements"] == 4
        added, existing = import_lines(target, io.BytesIO("\n".join(lines).encode()), "f.jsonl")
        assert (added, existing) == (2, 4)
