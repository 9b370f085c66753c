"""The change since the baseline, stored when a measurement is added: the same diagnosis
``store check`` computes, read back by the fleet overview (and so by every surface)."""

from __future__ import annotations

import io
import logging
from collections.abc import Callable
from pathlib import Path

import pytest
from sqlalchemy import delete, select, update

from ncmeasure.formats.comparison import Limits
from ncmeasure.formats.results import AxisResult, Results
from ncmeasure.store import MeasurementInfo, Store, open_store
from ncmeasure.store import schema as t
from ncmeasure.store.changes import (
    DIAGNOSIS_VERSION,
    StoredChange,
    compare_with_baseline,
    diagnose_with_baseline,
    stored_changes,
)
from ncmeasure.store.check import check_machine
from ncmeasure.store.overview import fleet_overview
from ncmeasure.store.records import MeasurementSummary
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


def _two_machines_left_by_an_older_diagnosis(store: Store, make_results: Make) -> None:
    """M1 and M2, each with a local change since delivery; M1's change not stored, M2's of
    an older :data:`DIAGNOSIS_VERSION`."""
    for day, serial in ((1, "M1"), (2, "M2")):
        store.add(make_results(f"2026-01-0{day}T08:00:00+00:00"), MeasurementInfo(serial=serial))
        store.add(
            _raised_at_the_end(make_results(f"2027-01-0{day}T08:00:00+00:00"), "Z", 1.08),
            MeasurementInfo(serial=serial),
        )
    with store.engine.begin() as db:
        (pair,) = db.execute(
            select(t.machines.c.latest_measurement_id).where(t.machines.c.serial == "M1")
        ).all()
        db.execute(delete(t.baseline_changes).where(t.baseline_changes.c.measurement_id == pair[0]))
        db.execute(update(t.baseline_changes).values(diagnosis_version=DIAGNOSIS_VERSION - 1))


def test_a_store_without_the_change_compares_when_read(
    store_url: str, make_results: Make, caplog: pytest.LogCaptureFixture
) -> None:
    with open_store(store_url, write=True) as store:
        _two_machines_left_by_an_older_diagnosis(store, make_results)
        assert _pairs(store) == {}
    with open_store(store_url) as store:  # a reader: compares on every reading, says how to stop
        for _ in range(2):
            caplog.clear()
            with caplog.at_level(logging.WARNING, logger="ncmeasure.store.overview"):
                overview = fleet_overview(store)
            assert "2 machine(s) without a current stored change" in caplog.text
            assert "`ncmeasure store refresh` stores them" in caplog.text
            for machine in overview.machines:
                assert machine.status == check_machine(store, machine.serial).status == "warning"
        assert _pairs(store) == {}
    with open_store(store_url, write=True) as store:  # a writer keeps what it compared
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="ncmeasure.store.overview"):
            statuses = [m.status for m in fleet_overview(store).machines]
        assert "compared now and stored" in caplog.text
        assert statuses == ["warning", "warning"]
        assert len(_pairs(store)) == 2
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="ncmeasure.store.overview"):
            assert [m.status for m in fleet_overview(store).machines] == statuses
        assert caplog.text == ""


def test_refresh_stores_what_is_missing_or_of_another_diagnosis_version(
    store_url: str, make_results: Make
) -> None:
    with open_store(store_url, write=True) as store:
        _two_machines_left_by_an_older_diagnosis(store, make_results)
        store.add(make_results("2026-01-03T08:00:00+00:00"), MeasurementInfo(serial="M3"))
        store.add(make_results("2027-01-03T08:00:00+00:00", 1.3), MeasurementInfo(serial="M3"))
        store.add(make_results("2026-01-04T08:00:00+00:00"), MeasurementInfo(serial="M4"))
        assert len(_pairs(store)) == 1  # M3's, current; M4 has only its baseline
    with open_store(store_url) as store:
        before = {m.serial: m.status for m in fleet_overview(store).machines}
    with open_store(store_url, write=True) as store:
        revision = _revision(store)
        seen: list[tuple[int, int]] = []
        assert store.refresh_changes(progress=lambda d, n: seen.append((d, n))) == 2
        assert seen == [(2, 2)]
        assert len(_pairs(store)) == 3
        assert _revision(store) == revision + 1  # a running dashboard reads it again
        assert store.refresh_changes() == 0  # nothing left
        assert _revision(store) == revision + 1
        assert store.refresh_changes(every=True) == 3  # M4 has no pair
        assert {m.serial: m.status for m in fleet_overview(store).machines} == before
        assert before == {"M1": "warning", "M2": "warning", "M3": "critical", "M4": "critical"}


def _revision(store: Store) -> int:
    from ncmeasure.store.summaries import store_revision

    with store.reading("the revision") as db:
        return store_revision(db)


def test_refresh_goes_in_batches(
    tmp_path: Path, make_results: Make, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("ncmeasure.store.store.REFRESH_BATCH", 2)
    with open_store(f"sqlite:///{tmp_path / 'fleet.db'}", write=True) as store:
        for n in range(5):
            store.add(
                make_results(f"2026-01-0{n + 1}T08:00:00+00:00"), MeasurementInfo(serial=f"M{n}")
            )
            store.add(
                make_results(f"2027-01-0{n + 1}T08:00:00+00:00"), MeasurementInfo(serial=f"M{n}")
            )
        with store.engine.begin() as db:
            db.execute(delete(t.baseline_changes))
        seen: list[tuple[int, int]] = []
        assert store.refresh_changes(progress=lambda d, n: seen.append((d, n))) == 5
        assert seen == [(2, 5), (4, 5), (5, 5)]
        assert len(_pairs(store)) == 5


def _summary(measurement_id: int, label: str, when: str) -> MeasurementSummary:
    return MeasurementSummary(
        id=measurement_id,
        measured_utc=when,
        label=label,
        operator=None,
        temperature_c=None,
        operating_hours=None,
        link="canopen",
        config_hash="",
        ncmeasure_version="1",
        recording_location=None,
        verdicts={},
    )


def _other_velocities(results: Results) -> Results:
    """``results`` measured at three times every velocity: no point matches it."""
    data = results.model_dump(mode="json")
    for axis in data["axes"].values():
        for position in axis["positions"]:
            for found in position["directions"].values():
                for point in found["points"] if found else ():
                    point["velocity_mm_min"] *= 3.0
    return Results.model_validate(data)


def test_the_stored_diagnosis_is_that_of_the_full_comparison(make_results: Make) -> None:
    """What adding stores (the outcome and each axis' change, without the rest of the
    comparison) is what the full comparison with the baseline holds: compared (a local
    change among them), refused and failed alike."""
    base = make_results("2026-01-01T08:00:00+00:00")
    renamed = make_results("2027-01-01T08:00:00+00:00")
    renamed = renamed.model_copy(update={"axes": {f"{n}2": a for n, a in renamed.axes.items()}})
    cases = {
        "compared": _raised_at_the_end(make_results("2027-01-01T08:00:00+00:00", 1.03), "Z", 1.2),
        "unchanged": make_results("2027-01-01T08:00:00+00:00"),
        "refused": renamed,
        "failed": _other_velocities(make_results("2027-01-01T08:00:00+00:00")),
    }
    first = _summary(1, "delivery", "2026-01-01T08:00:00+00:00")
    latest = _summary(2, "service", "2027-01-01T08:00:00+00:00")
    outcomes = {}
    for name, later in cases.items():
        full = compare_with_baseline(first, base, latest, later)
        outcome, changes = diagnose_with_baseline(first, base, latest, later)
        assert (outcome, changes) == (full.outcome, full.changes), name
        outcomes[name] = outcome
    assert outcomes == {
        "compared": "compared",
        "unchanged": "compared",
        "refused": "refused",
        "failed": "failed",
    }
