"""The lists' statuses (each machine's own status as kept, the fleet's part on arrays) are
those of the fleet overview, which judges every machine in full."""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
import pytest
from sqlalchemy import func, select

from ncmeasure.formats.results import Results
from ncmeasure.store import MeasurementInfo, open_store, statuses
from ncmeasure.store import schema as t
from ncmeasure.store.check import StoreCheck
from ncmeasure.store.overview import fleet_overview
from ncmeasure.store.report import FleetReport, fleet_report, report_of
from ncmeasure.store.statuses import fleet_statuses, judged_page

Make = Callable[..., Results]

# machine → friction factors of its measurements (delivery first): a fleet with an outlier
# below (M17) and above (M30: beyond the fleet factor), twins (ties in the medians), a
# machine with only its delivery, one worn past the critical limit, one at the warning limit,
# and two that only the fleet tells apart (no change since their delivery)
FLEET = {
    "M17": (1.0, 0.5),
    "M20": (0.96, 0.97),
    "M21": (1.0, 1.12),
    "M22": (1.03, 1.0),
    "M23": (0.98, 1.27),
    "M24": (1.02, 1.02),
    "M25": (1.01,),
    "M26": (1.0, 1.0),
    "M27": (1.0, 1.0),
    "M28": (0.99, 0.99, 1.01),
    "M29": (1.04, 0.9),
    "M30": (1.0, 3.5),
    "M31": (0.55, 0.55),  # an outlier since its delivery: unchanged, the fleet tells
    "M32": (3.5,),  # beyond the fleet factor at delivery
}


def _fill(url: str, make_results: Make) -> None:
    with open_store(url, write=True) as store:
        for index, (serial, factors) in enumerate(FLEET.items()):
            for k, factor in enumerate(factors):
                store.add(
                    make_results(f"20{26 + k}-01-{10 + index}T08:00:00+00:00", factor),
                    MeasurementInfo(
                        serial=serial,
                        label="delivery" if k == 0 else "service",
                        site="Hall 3" if index % 2 else None,
                    ),
                )


def _same_as_the_overview(url: str) -> None:
    with open_store(url) as store:
        overview = fleet_overview(store)
        fleet = fleet_statuses(store)
        ids = [int(fleet.machine_ids[i]) for i in fleet.matching()]
        page = judged_page(store, fleet, ids)
    expected = {m.serial: m.status for m in overview.machines}
    assert fleet.by_serial() == expected
    assert set(expected.values()) == {"warning", "critical"}  # the base has a loose bearing
    assert fleet.serials == sorted(FLEET)
    axes = {
        s: sum(a.status == s for m in overview.machines for a in m.axes.values())
        for s in ("ok", "warning", "critical")
    }
    assert fleet.axis_counts(fleet.matching()) == axes
    assert fleet.axis_names == overview.axes
    assert any(  # the fleet alone makes an axis a warning
        a.status == "warning" and a.outliers and a.change_status == "ok"
        for m in overview.machines
        for a in (x.judged for x in m.axes.values())
        if a is not None
    )
    for machine, judged in zip(overview.machines, page, strict=True):
        assert judged.serial == machine.serial
        assert [(n, a.status, a.reasons, a.notes) for n, a in judged.axes.items()] == [
            (n, a.status, a.reasons, a.notes) for n, a in machine.axes.items()
        ]
    for status in ("ok", "warning", "critical"):
        chosen = [fleet.serials[i] for i in fleet.matching(status=status)]
        assert chosen == sorted(s for s, found in expected.items() if found == status)
    assert [fleet.serials[i] for i in fleet.matching("hall 3")] == [
        s for i, s in enumerate(FLEET) if i % 2
    ]


def test_the_statuses_are_the_overviews(store_url: str, make_results: Make) -> None:
    _fill(store_url, make_results)
    _same_as_the_overview(store_url)  # judged now: none kept by a reader
    with open_store(store_url, write=True) as store:
        fleet_statuses(store)  # a writer keeps them
    _same_as_the_overview(store_url)  # read as kept


def _kept(url: str) -> dict[tuple[int, str], str]:
    """The kept statuses of each machine's current (latest, baseline) pair."""
    s, st = t.machine_summaries, t.axis_statuses
    with open_store(url) as store, store.reading("read the kept statuses") as db:
        rows = db.execute(
            select(st.c.machine_id, st.c.axis, st.c.status).join(
                s,
                (s.c.machine_id == st.c.machine_id)
                & (s.c.latest_id == st.c.latest_id)
                & (s.c.baseline_id == st.c.baseline_id),
            )
        ).all()
    return {(int(r.machine_id), r.axis): r.status for r in rows}


def test_each_machines_own_status_is_kept_when_it_gets_a_measurement(
    store_url: str, make_results: Make, caplog: pytest.LogCaptureFixture
) -> None:
    _fill(store_url, make_results)
    with open_store(store_url, write=True) as store:
        fleet_statuses(store)
        store.add(
            make_results("2031-06-01T08:00:00+00:00", 1.3),
            MeasurementInfo(serial="M20", label="service"),
        )
    with caplog.at_level(logging.WARNING), open_store(store_url) as store:
        fleet = fleet_statuses(store)
    assert "without a current stored status" not in caplog.text  # kept by the add
    assert fleet.by_serial()["M20"] == "critical"  # +30 % since its delivery
    with open_store(store_url, write=True) as store, store.writing("forget M20's") as db:
        m20 = select(t.machines.c.id).where(t.machines.c.serial == "M20").scalar_subquery()
        db.execute(t.axis_statuses.delete().where(t.axis_statuses.c.machine_id == m20))
    with caplog.at_level(logging.WARNING), open_store(store_url) as store:
        assert fleet_statuses(store).by_serial()["M20"] == "critical"
    assert "1 machine(s) without a current stored status" in caplog.text  # judged on reading
    with open_store(store_url, write=True) as store:
        fleet_statuses(store)
        with store.reading("count") as db:
            kept = db.execute(select(func.count()).select_from(t.axis_statuses)).scalar_one()
    axes = len(make_results("2026-01-01T08:00:00+00:00").axes)
    assert kept == axes * len(FLEET)
    _same_as_the_overview(store_url)


def test_a_batch_keeps_every_machines_own_status(
    store_url: str, make_results: Make, caplog: pytest.LogCaptureFixture
) -> None:
    """``add_many`` (``store import``) leaves every machine's own status kept, as judging
    it afresh gives it: no reader judges the fleet again."""
    batch = [
        (
            make_results(f"20{26 + k}-01-{10 + index}T08:00:00+00:00", factor),
            MeasurementInfo(
                serial=serial,
                label="delivery" if k == 0 else "service",
                site="Hall 3" if index % 2 else None,
            ),
        )
        for index, (serial, factors) in enumerate(FLEET.items())
        for k, factor in enumerate(factors)
    ]
    with open_store(store_url, write=True) as store:
        store.add_many(batch[:9])
        store.add_many(batch[9:])  # machines of both batches: judged again in the second
    kept = _kept(store_url)
    axes = len(make_results("2026-01-01T08:00:00+00:00").axes)
    assert len(kept) == axes * len(FLEET)
    with caplog.at_level(logging.WARNING), open_store(store_url) as store:
        fleet_statuses(store)
    assert "without a current stored status" not in caplog.text
    with open_store(store_url, write=True) as store:
        with store.writing("forget them") as db:
            db.execute(t.axis_statuses.delete())
        fleet_statuses(store)  # judged afresh and kept
    assert _kept(store_url) == kept
    assert set(kept.values()) == {"ok", "warning", "critical"}
    _same_as_the_overview(store_url)


def _shown(report: FleetReport) -> object:
    """What a report shows of its fleet, as plain values."""
    return (
        report.machines,
        report.types,
        report.counts,
        report.axes,
        report.unlisted_attention,
        report.unlisted_ok,
        report.outliers,
        report.outlier_count,
        [
            (
                m.serial,
                m.status,
                [
                    (n, a.status, a.reasons, a.notes, a.changes, a.outliers)
                    for n, a in m.axes.items()
                ],
            )
            for m in report.listed
        ],
    )


@pytest.mark.parametrize("grid", [100, 5])
def test_the_report_shows_what_the_overview_shows(
    store_url: str, make_results: Make, grid: int
) -> None:
    """The report reads the kept statuses and judges only its grid's machines in full; what
    it shows is what judging every machine shows, the grid cut short (5) or not."""
    _fill(store_url, make_results)
    with open_store(store_url) as store:
        quick = fleet_report(store, grid=grid)
        full = report_of(fleet_overview(store), grid)
    assert _shown(quick) == _shown(full)
    assert quick.outliers  # the fleet names outliers, ◆ in the grid
    assert any(a.outliers for m in quick.listed for a in m.axes.values())
    assert quick.status == "critical"
    if grid == 5:
        assert len(quick.listed) == 5 and quick.unlisted_attention > 0
    else:  # every machine judged: the same trends
        assert [m.serial for m in quick.judged] == [m.serial for m in full.judged]


def test_a_machine_whose_axes_change_between_the_reads_gets_a_status(
    store_url: str, make_results: Make, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The statuses missing from the first read are judged in a second one; a writer adding
    # a measurement in between may leave the machine without an axis read the first time.
    _fill(store_url, make_results)
    with open_store(store_url, write=True) as store, store.writing("forget M23's") as db:
        m23 = select(t.machines.c.id).where(t.machines.c.serial == "M23").scalar_subquery()
        db.execute(t.axis_statuses.delete().where(t.axis_statuses.c.machine_id == m23))
    judge = statuses._judge_missing

    def axes_renamed(store: object, ids: list[int]) -> dict[int, dict[str, str]]:
        found = judge(store, ids)  # type: ignore[arg-type]
        return {m: {f"{a}2": s for a, s in axes.items()} for m, axes in found.items()}

    monkeypatch.setattr(statuses, "_judge_missing", axes_renamed)
    with open_store(store_url) as store:
        assert fleet_statuses(store).by_serial()["M23"] == "critical"  # +27 % since delivery


def test_the_checks_fleet_figures_are_the_plain_ones(store_url: str, make_results: Make) -> None:
    """``store check`` against its fleet (read from the indexes, as columns) gives the
    figures of the plain computation: every other machine's latest axis rows, read one
    machine at a time, in order of value (the mean deviation, where the MAD is 0, is a sum:
    its last digit follows the order)."""
    from ncmeasure.analysis.judgement.fleet import modified_z_against
    from ncmeasure.analysis.judgement.status import CHARACTERISTICS, is_outlier
    from ncmeasure.formats.comparison import Limits
    from ncmeasure.store.check import check_machine
    from ncmeasure.store.rows import rows_of_axis

    _fill(store_url, make_results)
    with open_store(store_url, write=True) as store:  # a machine of another type: not fleet
        store.add(
            make_results("2031-01-01T08:00:00+00:00", 2.0),
            MeasurementInfo(serial="N1", label="delivery", machine_type="another type"),
        )
    limits = Limits()
    with open_store(store_url) as store:
        fleet = fleet_statuses(store)
        latest: dict[str, dict[tuple[str, str], dict[str, float | None]]] = {}
        for serial in FLEET:  # each machine's latest axis rows, one machine at a time
            with store.reading("the latest rows") as db:
                machine = store.machine_row(db, serial)
                rows = db.execute(
                    select(t.axis_results).where(
                        t.axis_results.c.measurement_id == machine.latest_measurement_id
                    )
                ).all()
            latest[serial] = {
                (row.axis, row.unit): {c.name: getattr(row, c.name) for c in CHARACTERISTICS}
                for row in rows
            }
        own_values = {}
        for serial in FLEET:
            _, measurements = store.machine(serial)
            newest = max(measurements, key=lambda m: m.measured_utc)
            results = store.results(newest.id)
            own_values[serial] = {
                (name, axis.unit): rows_of_axis(name, axis).axis
                for name, axis in results.axes.items()
            }
        for serial in FLEET:
            check = check_machine(store, serial)
            expected = []
            for (name, unit), own in sorted(own_values[serial].items()):
                for c in CHARACTERISTICS:
                    value = own[c.name]
                    others = sorted(
                        figure
                        for other, axes in latest.items()
                        if other != serial
                        and (figure := axes.get((name, unit), {}).get(c.name)) is not None
                    )
                    if value is None or not others:
                        continue
                    enough = len(others) >= limits.outlier_min_runs
                    z = modified_z_against(value, others) if enough else None
                    median = float(np.median(others))
                    expected.append(
                        (name, c.name, value, median, min(others), max(others), len(others), z,
                         is_outlier(c, value, median, z, limits))
                    )  # fmt: skip
            got = [
                (f.axis, f.characteristic, f.value, f.fleet_median, f.fleet_low, f.fleet_high,
                 f.machines, f.modified_z, f.outlier)
                for f in check.fleet
            ]  # fmt: skip
            assert got == expected, serial
            assert check.fleet_machines == len(FLEET) - 1
            # the same from the fleet's statuses (a dashboard that has read them)
            assert _timeless(check_machine(store, serial, statuses=fleet)) == _timeless(check)
        alone = check_machine(store, "N1", statuses=fleet)
        assert alone.fleet == [] and alone.fleet_machines == 0
        assert _timeless(alone) == _timeless(check_machine(store, "N1"))


def _timeless(check: StoreCheck) -> dict[str, object]:
    """The check without the time its comparison was made."""
    found = check.model_dump()
    if found["comparison"] is not None:
        found["comparison"].pop("created_utc")
    return found


def test_a_search_finds_what_each_text_holds() -> None:
    """The search looks in each machine's serial, type and site (any case), held as one
    text per machine: never across two of them."""
    serials = ["AB-1", "cd-2", "EF-3", "GH-4"]
    fleet = statuses.FleetStatuses(
        version="v",
        machine_ids=np.arange(4, dtype=np.int64),
        serials=serials,
        types=["Lathe", "MILL", "mill", "Lathe"],
        sites=["Straße 1", None, "Hall 3", "hall 30"],
        levels=np.zeros(4, dtype=np.int8),
        axis_machine=np.zeros(0, dtype=np.intp),
        axis_levels=np.zeros(0, dtype=np.int8),
        axis_names=[],
    )

    def found(search: str) -> list[str]:
        return [serials[i] for i in fleet.matching(search)]

    assert found("mill") == ["cd-2", "EF-3"]
    assert found("HALL 3") == ["EF-3", "GH-4"]
    assert found("STRASSE") == ["AB-1"]  # case-folded
    assert found("1lathe") == [] and found("1\x00lathe") == []  # never across two texts
    assert found("ab-1") == ["AB-1"] and found("") == serials


def _as_read_afresh(
    store_url: str, previous: statuses.FleetStatuses, read: list[int]
) -> statuses.FleetStatuses:
    """The statuses read on from ``previous``, checked against reading them all afresh;
    ``read`` keeps the rows of each read of the first alone."""
    with open_store(store_url) as store:
        read.clear()
        on = fleet_statuses(store, previous)
        reads = list(read)
        afresh = fleet_statuses(store)
    read[:] = reads
    assert on.version == afresh.version
    assert on.machine_ids.tolist() == afresh.machine_ids.tolist()
    assert (on.serials, on.types, on.sites) == (afresh.serials, afresh.types, afresh.sites)
    assert on.by_serial() == afresh.by_serial()
    assert on.axis_names == afresh.axis_names

    def per_axis(found: statuses.FleetStatuses) -> list[tuple[int, int]]:
        return sorted(zip(found.axis_machine.tolist(), found.axis_levels.tolist(), strict=True))

    assert per_axis(on) == per_axis(afresh)
    assert on.places.keys() == afresh.places.keys()
    for key, group in afresh.places.items():
        mine = on.places[key]
        assert mine.enough == group.enough
        for name in ("ids", "values", "medians", "z"):
            assert np.array_equal(getattr(mine, name), getattr(group, name)), (key, name)
    assert on.outliers() == afresh.outliers()
    return on


def test_statuses_read_on_from_the_last_ones_are_those_read_afresh(
    store_url: str, make_results: Make, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A server reads again only the machines whose latest measurement, baseline or site
    changed: the statuses are those of reading every machine."""
    _fill(store_url, make_results)
    with open_store(store_url) as store:
        fleet = fleet_statuses(store)
    read: list[int] = []
    plain = statuses.plain_rows

    def counted(db: object, query: object) -> list[tuple[object, ...]]:
        rows = plain(db, query)  # type: ignore[arg-type]
        read.append(len(rows))
        return rows

    monkeypatch.setattr(statuses, "plain_rows", counted)
    unchanged = _as_read_afresh(store_url, fleet, read)
    assert read == [len(FLEET)]  # the machines' signatures, and no axis
    changes = [
        # a worn machine (a new latest), a new machine, a first service of a machine that
        # had its delivery alone, and an older measurement that moves a machine to a hall
        ("M20", "2031-06-01T08:00:00+00:00", 1.3, None, "service"),
        ("M40", "2031-06-02T08:00:00+00:00", 1.0, None, "delivery"),
        ("M25", "2031-06-03T08:00:00+00:00", 1.6, None, "service"),
        ("M22", "2025-06-01T08:00:00+00:00", 1.0, "Hall 9", "service"),
    ]
    for serial, when, factor, site, label in changes:
        with open_store(store_url, write=True) as store:
            store.add(
                make_results(when, factor), MeasurementInfo(serial=serial, label=label, site=site)
            )
        unchanged = _as_read_afresh(store_url, unchanged, read)
        assert read[1:] == [len(make_results(when).axes)]  # that machine's axes alone
    assert unchanged.by_serial()["M20"] == "critical"
    assert unchanged.sites[unchanged.serials.index("M22")] == "Hall 9"
