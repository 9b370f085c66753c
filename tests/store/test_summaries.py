"""The machines' summary rows: current after every add, paged and filtered in the database,
rebuilt by the migration and by ``store refresh``; the statuses of one fleet version."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from alembic import command
from sqlalchemy import create_engine, select
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results
from ncmeasure.store import MeasurementInfo, Store, open_store
from ncmeasure.store import schema as t
from ncmeasure.store.database import _alembic_config, _parse
from ncmeasure.store.overview import fleet_overview
from ncmeasure.store.summaries import statuses_current, update_summaries

Make = Callable[..., Results]
runner = CliRunner()


def _fill(store: Store, make: Make) -> None:
    """Five machines; M2 and M4 lose friction since delivery (critical)."""
    for m in range(5):
        site = "Hall 1" if m < 3 else "hall 2"
        store.add(
            make(f"2026-0{m + 1}-01T08:00:00+00:00"),
            MeasurementInfo(serial=f"M{m}", label="delivery", site=site),
        )
        store.add(
            make(f"2027-0{m + 1}-01T08:00:00+00:00", 0.5 if m in (2, 4) else 1.0),
            MeasurementInfo(serial=f"M{m}", label="service"),
        )


def _summaries(store: Store) -> list[tuple[object, ...]]:
    s = t.machine_summaries
    columns = [c for c in s.c if c.name not in ("status", "fleet_version")]
    with store.reading("summaries") as db:
        return [tuple(r) for r in db.execute(select(*columns).order_by(s.c.serial))]


def test_pages_filters_and_the_rows_after_adding(store_url: str, make_results: Make) -> None:
    with open_store(store_url, write=True) as store:
        _fill(store, make_results)
        every = store.machines()
        assert [m.serial for m in every] == ["M0", "M1", "M2", "M3", "M4"]
        assert {m.measurements for m in every} == {2}
        assert {m.latest_label for m in every} == {"service"}
        first = store.machine_page(limit=2)
        assert [m.serial for m in first.machines] == ["M0", "M1"]
        assert (first.total, first.next_cursor) == (5, "M1")
        last = store.machine_page(limit=2, after="M3")
        assert [m.serial for m in last.machines] == ["M4"] and last.next_cursor is None
        found = store.machine_page(search="HALL 2")
        assert [m.serial for m in found.machines] == ["M3", "M4"] and found.total == 2
        assert store.machine_page(search="_").total == 0  # a character, not a pattern
        with pytest.raises(ConfigError, match="limit 0: a page holds 1 to 1000"):
            store.machine_page(limit=0)
        # the rows rebuilt from the measurements are the ones kept on adding
        kept = _summaries(store)
        with store.writing("test") as db:
            update_summaries(db)
        assert _summaries(store) == kept


def test_a_search_folds_case_as_the_grid_does(store_url: str, make_results: Make) -> None:
    """Sites as a German maker writes them: the lists' search finds what the grid's finds
    (Python's case folding), on SQLite and on PostgreSQL of the C locale (whose ILIKE,
    like SQLite's LIKE, folds ASCII letters only)."""
    from ncmeasure.store.statuses import fleet_statuses

    sites = ["Würzburg", "WÜRZBURG-SÜD", "Straße 5", "Ulm", None]
    with open_store(store_url, write=True) as store:
        for m, site in enumerate(sites):
            store.add(
                make_results(f"2026-0{m + 1}-01T08:00:00+00:00"),
                MeasurementInfo(serial=f"M{m}", label="delivery", site=site),
            )
        grid = fleet_statuses(store)
        for search in ["würzburg", "WÜRZBURG", "süd", "STRASSE", "ulm", "m3", "_", "%", "5"]:
            listed = [m.serial for m in store.machine_page(search=search).machines]
            found = sorted(grid.serials[i] for i in grid.matching(search))
            assert listed == found, search
        assert [m.serial for m in store.machine_page(search="WÜRZBURG").machines] == ["M0", "M1"]
        assert [m.serial for m in store.machine_page(search="strasse").machines] == ["M2"]
        assert store.machine_page(search="m0\x1fhmx").total == 0  # not across two fields
        assert store.machine_page(search="\x00").total == 0  # PostgreSQL's text holds none
        # a machine moved to another site is found there, and no longer where it was
        store.add(
            make_results("2026-09-01T08:00:00+00:00"),
            MeasurementInfo(serial="M3", label="service", site="Schweinfurt"),
        )
        assert [m.serial for m in store.machine_page(search="SCHWEINFURT").machines] == ["M3"]
        assert store.machine_page(search="ulm").total == 0


def test_statuses_are_those_of_one_fleet(store_url: str, make_results: Make) -> None:
    with open_store(store_url, write=True) as store:
        _fill(store, make_results)
        with store.reading("test") as db:
            assert not statuses_current(db)  # never judged
        overview = fleet_overview(store)  # open for writing: keeps them
        with store.reading("test") as db:
            assert statuses_current(db)
        critical = store.machine_page(status="critical")
        expected = sorted(m.serial for m in overview.machines if m.status == "critical")
        assert [m.serial for m in critical.machines] == expected == ["M2", "M4"]
        store.add(make_results("2028-01-01T08:00:00+00:00", 0.5), MeasurementInfo(serial="M0"))
        with store.reading("test") as db:
            assert not statuses_current(db)  # the fleet moved
        assert store.refresh_summaries() == 5
        with store.reading("test") as db:
            assert statuses_current(db)
        assert [m.serial for m in store.machine_page(status="critical").machines] == [
            "M0",
            "M2",
            "M4",
        ]


def test_the_migration_summarises_a_store_filled_before(tmp_path: Path, make_results: Make) -> None:
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    with open_store(url, write=True) as store:
        _fill(store, make_results)
        store.add(  # a second delivery: the first stays the baseline
            make_results("2028-01-01T08:00:00+00:00"),
            MeasurementInfo(serial="M1", label="delivery"),
        )
        kept = _summaries(store)
    engine = create_engine(_parse(url))
    with engine.begin() as connection:
        command.downgrade(_alembic_config(connection), "0002")
    engine.dispose()
    with open_store(url, write=True) as store:  # upgrades: 0003 fills the rows
        assert _summaries(store) == kept
        with store.reading("test") as db:
            baseline = db.execute(
                select(t.machine_summaries.c.baseline_utc).where(
                    t.machine_summaries.c.serial == "M1"
                )
            ).scalar_one()
        assert baseline.startswith("2026-02-01")


def test_store_list_pages_filters_and_prints_json(tmp_path: Path, make_results: Make) -> None:
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    with open_store(url, write=True) as store:
        _fill(store, make_results)
    listed = runner.invoke(app, ["store", "list", "--store", url, "--limit", "2"])
    assert listed.exit_code == 0, listed.output
    assert "2 of 5 machine(s)" in listed.stdout and "M1" in listed.stdout
    assert "more after M1: --after M1" in listed.stdout and "M2" not in listed.stdout
    shown = runner.invoke(app, ["store", "list", "--store", url, "--json", "--after", "M3"])
    page = json.loads(shown.stdout)
    assert [m["serial"] for m in page["machines"]] == ["M4"]
    assert (page["total"], page["next_cursor"]) == (5, None)
    assert page["machines"][0]["latest_verdicts"]
    # --status reads each machine's own status as its adds kept it
    status = ["store", "list", "--store", url, "--status", "critical"]
    found = runner.invoke(app, status)
    assert found.exit_code == 0, found.output
    assert "store refresh" not in found.stderr
    assert "2 machine(s)" in found.stdout and "M4" in found.stdout and "M0" not in found.stdout
    # a store without them (filled by an older ncmeasure) is judged on the spot, and says so
    with open_store(url, write=True) as store, store.writing("forget the statuses") as db:
        db.execute(t.axis_statuses.delete())
    found = runner.invoke(app, status)
    assert found.exit_code == 0, found.output
    assert "store refresh" in found.stderr
    assert "2 machine(s)" in found.stdout and "M4" in found.stdout and "M0" not in found.stdout
    assert runner.invoke(app, ["store", "refresh", "-q", "--store", url]).exit_code == 0
    found = runner.invoke(
        app, ["store", "list", "--store", url, "--status", "critical", "--search", "hall 1"]
    )
    assert "store refresh" not in found.stderr
    assert "1 machine(s)" in found.stdout and "M2" in found.stdout
    none = runner.invoke(app, ["store", "list", "--store", url, "--search", "nowhere"])
    assert none.exit_code == 0 and "no machines that match" in none.stdout
    for bad, message in (
        (["--limit", "5000"], "--limit 5000: a page holds 1 to 1000 machines"),
        (["--status", "red"], "--status red: one of ok, warning, critical"),
    ):
        refused = runner.invoke(app, ["store", "list", "--store", url, *bad])
        assert refused.exit_code == 2 and message in refused.stderr
        assert "Traceback" not in refused.output
