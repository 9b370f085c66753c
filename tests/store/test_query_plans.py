"""Every query the CLI and the web make while listing, showing, checking and adding finds
its rows through an index: no full scan of the tables that grow with every measurement.

The statements are those the store really runs (recorded while the commands work), each
asked for its plan with the parameters it ran with: ``EXPLAIN QUERY PLAN`` on SQLite,
``EXPLAIN`` on PostgreSQL (with sequential scans made a last resort, so that a table of
a few rows, which PostgreSQL rightly reads whole, still shows whether an index serves).
Reading the whole fleet (the overview's and the statuses' summary rows) and rebuilding
(``store refresh``, export) read everything by design: the summary rows are not among the
growing tables checked, and the statements that go on from them must use an index.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import Engine, event

from ncmeasure.formats.results import Results
from ncmeasure.store import MeasurementInfo, Store, open_store
from ncmeasure.store.check import check_machine
from ncmeasure.store.statuses import fleet_statuses
from ncmeasure.web import create_app

Make = Callable[..., Results]

GROWING = (
    "measurements",
    "axis_results",
    "points",
    "fits",
    "fit_parameters",
    "causes",
    "baseline_changes",
    "axis_changes",
    "axes",
    "machines",
    "axis_statuses",
)
"""Tables with a row (or hundreds) per measurement or machine."""


@contextmanager
def _recorded() -> Iterator[list[tuple[str, Any]]]:
    """The SELECT statements of every engine meanwhile (the web application opens its own)."""
    seen: list[tuple[str, Any]] = []

    def record(conn: Any, cursor: Any, statement: str, parameters: Any, *_: Any) -> None:
        if statement.lstrip().upper().startswith("SELECT"):
            seen.append((statement, parameters))

    event.listen(Engine, "before_cursor_execute", record)
    try:
        yield seen
    finally:
        event.remove(Engine, "before_cursor_execute", record)


def _full_scans(store: Store, statement: str, parameters: Any) -> list[str]:
    """The growing tables the statement reads whole."""
    raw = store.engine.raw_connection()
    try:
        cursor = raw.cursor()
        if store.engine.dialect.name == "sqlite":
            cursor.execute("EXPLAIN QUERY PLAN " + statement, parameters)
            lines = [str(row[-1]) for row in cursor.fetchall()]
            pattern = r"^SCAN (\w+)"  # SEARCH: through an index; SCAN: every row
        else:
            cursor.execute("SET enable_seqscan = off")
            cursor.execute("EXPLAIN " + statement, parameters)
            lines = [str(row[0]) for row in cursor.fetchall()]
            pattern = r"Seq Scan on (\w+)"
        found = [m.group(1) for line in lines for m in [re.search(pattern, line.strip())] if m]
        return [name for name in found if name in GROWING]
    finally:
        raw.close()


def test_lists_pages_checks_and_adds_use_indexes(store_url: str, make_results: Make) -> None:
    with open_store(store_url, write=True) as store:
        for m in range(3):
            store.add(
                make_results(f"2026-0{m + 1}-01T08:00:00+00:00"),
                MeasurementInfo(serial=f"M{m}", label="delivery", site="Hall 1"),
            )
        with _recorded() as statements:
            # adding: the batch's look-ups and the change since the baseline
            store.add_many(
                [
                    (
                        make_results(f"2027-0{m + 1}-01T08:00:00+00:00", 0.9),
                        MeasurementInfo(serial=f"M{m}", label="service"),
                    )
                    for m in range(3)
                ]
            )
            # the CLI: list (pages, search, status), show, trend, check, a results file
            store.refresh_summaries()
            statements.clear()  # the overview reads every summary row: by design
            store.machine_page(limit=2)
            store.machine_page(limit=2, after="M1")
            store.machine_page(search="hall", status="ok")
            _, measurements = store.machine("M1")
            store.trend("M1", "X")
            store.results(measurements[-1].id)
            check_machine(store, "M1")
            # the lists' statuses (the fleet's figures: every summary row, by design, and
            # through them the latest axes and their kept statuses), as `store list --status`
            # and the grid read them
            fleet_statuses(store)
            # the web: the grid, the REST lists and a machine's page
            with TestClient(create_app(store_url), base_url="http://127.0.0.1") as web:
                assert web.get("/", params={"q": "M1"}).status_code == 200
                assert web.get("/", params={"status": "warning"}).status_code == 200
                assert web.get("/api/v1/machines", params={"limit": 2}).status_code == 200
                assert web.get("/api/v1/machines/M1/measurements").status_code == 200
                assert web.get("/machines/M1").status_code == 200
        assert statements
        scans = {
            statement.split("\nFROM")[0][:120]: tables
            for statement, parameters in statements
            if (tables := _full_scans(store, statement, parameters))
        }
        assert scans == {}


def _plan(store: Store, statement: str, parameters: Any) -> str:
    raw = store.engine.raw_connection()
    try:
        cursor = raw.cursor()
        if store.engine.dialect.name == "sqlite":
            cursor.execute("EXPLAIN QUERY PLAN " + statement, parameters)
            return "\n".join(str(row[-1]) for row in cursor.fetchall())
        cursor.execute("SET enable_seqscan = off")
        cursor.execute("EXPLAIN " + statement, parameters)
        return "\n".join(str(row[0]) for row in cursor.fetchall())
    finally:
        raw.close()


def test_the_checks_fleet_is_read_from_the_indexes(store_url: str, make_results: Make) -> None:
    """``store check`` reads every latest figure of the machine's type: from the type's
    machines by their latest measurement and the axes' figures, both indexes holding
    every column read (SQLite reads no table row)."""
    with open_store(store_url, write=True) as store:
        for m in range(4):
            store.add(
                make_results(f"2026-0{m + 1}-01T08:00:00+00:00", 1.0 + m / 10),
                MeasurementInfo(serial=f"M{m}", label="delivery"),
            )
        with _recorded() as statements:
            check_machine(store, "M1")
        fleet = [
            (statement, parameters)
            for statement, parameters in statements
            if "FROM axis_results JOIN machines" in statement
        ]
        assert len(fleet) == 1
        plan = _plan(store, *fleet[0])
        assert "ix_axis_results_figures" in plan and "ix_machines_type_latest" in plan, plan
        if store.engine.dialect.name == "sqlite":
            assert "COVERING INDEX ix_axis_results_figures" in plan, plan
            assert "COVERING INDEX ix_machines_type_latest" in plan, plan


def test_a_search_finds_any_case_and_sqlite_folds_nothing_per_row(
    store_url: str, make_results: Make
) -> None:
    """The lists' search matches serial, type or site in any case; on SQLite through ``LIKE``
    alone (which ignores the case of ASCII letters, the only ones SQLite's ``lower()`` folds),
    without a ``lower()`` per row."""
    with open_store(store_url, write=True) as store:
        for m, site in enumerate(("Hall 3", "hall 30", None)):
            store.add(
                make_results(f"2026-0{m + 1}-01T08:00:00+00:00"),
                MeasurementInfo(serial=f"Mx-{m}", label="delivery", site=site),
            )
        with _recorded() as statements:
            found = [m.serial for m in store.machine_page(search="HALL 3").machines]
            assert [m.serial for m in store.machine_page(search="mX-2").machines] == ["Mx-2"]
            assert store.machine_page(search="50%").machines == []  # a wildcard is a character
        assert found == ["Mx-0", "Mx-1"]
        if store.engine.dialect.name == "sqlite":
            assert not [s for s, _ in statements if "lower(" in s]
