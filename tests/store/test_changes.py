"""The change since the baseline, stored when a measurement is added: the same diagnosis
``store check`` computes, read back by the fleet overview (and so by every surface)."""

from __future__ import annotations

import io
import logging
from collections.abc import Callable

import pytest
from sqlalchemy import delete, select, update

from ncmeasure.formats.comparison import Limits
from ncmeasure.formats.results import AxisResult, Results
from ncmeasure.store import MeasurementInfo, Store, open_store
from ncmeasure.store import schema as t
from ncmeasure.store.changes import StoredChange, stored_changes
from ncmeasure.store.check import check_machine
from ncmeasure.store.overview import fleet_overview
from ncmeasure.store.transfer import export_lines, import_lines
from tests.report.example import scaled_axis

Make = Callable[..., Results]


def _raised_at_the_end(results: Results, axis: str, factor: float) -> Results:
    """``results`` with the friction of ``axis``' last position ``factor`` times as high."""
    found: AxisResult = results.axes[axis]
    raised = scaled_axis(found, factor)
    positions = [*found.positions[:-1], raised.positions[-1]]
    axes = {**results.axes, axis: found.model_copy(update={"positions": positions})}
    return results.model_copy(update={"axes": axes})


def _pairs(store: Store) -> dict[tuple[int, int], StoredChange]:
    with store.reading("test") as db:
        rows = db.execute(
            select(t.baseline_changes.c.measurement_id, t.baseline_changes.c.baseline_id)
        ).all()
        return stored_changes(db, [(r.measurement_id, r.baseline_id) for r in rows])


def _agree(store: Store, serial: str, limits: Limits | None = None) -> None:
    """The overview's status of the machine, axis by axis, is ``store check``'s."""
    check = check_machine(store, serial, limits)
    (machine,) = [m for m in fleet_overview(store, limits).machines if m.serial == serial]
    assert {name: a.status for name, a in machine.axes.items()} == check.axis_status
    assert machine.status == check.status


def test_the_stored_change_is_the_one_store_check_passes(
    store_url: str, make_results: Make
) -> None:
    delivered = make_results("2026-03-01T08:00:00+00:00")
    later = _raised_at_the_end(make_results("2027-03-01T08:00:00+00:00", 1.01), "Z", 1.2)
    with open_store(store_url, write=True) as store:
        first = store.add(delivered, MeasurementInfo(serial="M3", label="delivery"))
        assert _pairs(store) == {}  # one measurement: nothing to compare
        second = store.add(later, MeasurementInfo(serial="M3", label="service"))
        check = check_machine(store, "M3")
        assert check.comparison is not None
        from ncmeasure.analysis.judgement.status import ChangeFigures

        expected = {c.axis: ChangeFigures.of(c) for c in check.comparison.changes}
        assert expected["Z"].local  # a local change: the case the overview used to miss
        stored = _pairs(store)
        assert stored == {
            (second.measurement_id, first.measurement_id): StoredChange(True, expected)
        }
        assert check.status == "critical"  # a local change of 20 %, beyond 15 %
        for limits in (None, Limits(warning_percent=2.0, critical_percent=30.0)):
            _agree(store, "M3", limits)

        # an export imported elsewhere stores the same change
        exported = "\n".join(export_lines(store)).encode() + b"\n"
    other = store_url + "_copy" if store_url.startswith("sqlite") else None
    if other is not None:
        with open_store(other, write=True) as copy:
            assert import_lines(copy, io.BytesIO(exported), "fleet.jsonl") == (2, 0)
            assert list(_pairs(copy).values()) == [StoredChange(True, expected)]
            _agree(copy, "M3")


def test_a_back_filled_delivery_changes_the_pair(store_url: str, make_results: Make) -> None:
    with open_store(store_url, write=True) as store:
        commissioning = store.add(
            make_results("2026-01-01T08:00:00+00:00", 0.9), MeasurementInfo(serial="M4")
        )
        latest = store.add(
            _raised_at_the_end(make_results("2028-01-01T08:00:00+00:00"), "Z", 1.08),
            MeasurementInfo(serial="M4", label="service"),
        )
        assert set(_pairs(store)) == {(latest.measurement_id, commissioning.measurement_id)}
        delivery = store.add(
            make_results("2026-06-01T08:00:00+00:00"),
            MeasurementInfo(serial="M4", label="delivery"),
        )
        assert (latest.measurement_id, delivery.measurement_id) in _pairs(store)
        check = check_machine(store, "M4")
        assert check.baseline is not None and check.baseline.id == delivery.measurement_id
        _agree(store, "M4")


def test_a_refused_comparison_is_stored_as_such(store_url: str, make_results: Make) -> None:
    base = make_results("2026-01-01T08:00:00+00:00")
    renamed = make_results("2027-01-01T08:00:00+00:00")
    renamed = renamed.model_copy(update={"axes": {f"{n}2": a for n, a in renamed.axes.items()}})
    with open_store(store_url, write=True) as store:
        store.add(base, MeasurementInfo(serial="M5", label="delivery"))
        store.add(renamed, MeasurementInfo(serial="M5"))
        assert list(_pairs(store).values()) == [StoredChange(False, None)]
        check = check_machine(store, "M5")
        assert check.comparability is not None and check.comparability.refused is not None
        _agree(store, "M5")


def test_a_store_without_the_change_compares_when_read(
    store_url: str, make_results: Make, caplog: pytest.LogCaptureFixture
) -> None:
    with open_store(store_url, write=True) as store:
        for day, serial in ((1, "M1"), (2, "M2")):
            store.add(
                make_results(f"2026-01-0{day}T08:00:00+00:00"), MeasurementInfo(serial=serial)
            )
            store.add(
                _raised_at_the_end(make_results(f"2027-01-0{day}T08:00:00+00:00"), "Z", 1.08),
                MeasurementInfo(serial=serial),
            )
        with store.engine.begin() as db:  # as an older ncmeasure left them: M1 none, M2 stale
            (pair,) = db.execute(
                select(t.machines.c.latest_measurement_id).where(t.machines.c.serial == "M1")
            ).all()
            db.execute(
                delete(t.baseline_changes).where(t.baseline_changes.c.measurement_id == pair[0])
            )
            db.execute(update(t.baseline_changes).values(ncmeasure_version="0.0.1"))
        assert _pairs(store) == {}
        with caplog.at_level(logging.WARNING, logger="ncmeasure.store.overview"):
            overview = fleet_overview(store)
        assert "2 machine(s) without a stored change since their baseline" in caplog.text
        for machine in overview.machines:
            assert machine.status == check_machine(store, machine.serial).status == "warning"
        # the next measurement of a machine stores its change again
        store.add(make_results("2028-01-01T08:00:00+00:00"), MeasurementInfo(serial="M1"))
        assert len(_pairs(store)) == 1
