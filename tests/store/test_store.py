"""The fleet store on SQLite and on a real PostgreSQL server: the same behaviour."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from sqlalchemy import func, select

from ncmeasure.errors import ConfigError
from ncmeasure.formats.results import Results, Verdict
from ncmeasure.store import MeasurementInfo, measurement_info, open_store
from ncmeasure.store import schema as t
from ncmeasure.store.check import check_machine

Make = Callable[..., Results]


def _count(store, table) -> int:  # type: ignore[no-untyped-def]
    with store.reading("count") as db:
        return int(db.execute(select(func.count()).select_from(table)).scalar_one())


def test_results_round_trip_and_become_rows(store_url: str, make_results: Make) -> None:
    results = make_results("2026-01-10T08:00:00+00:00")
    with open_store(store_url, write=True) as store:
        added = store.add(results, MeasurementInfo(serial="M17", label="delivery", site="Ulm"))
        assert added.new
        assert store.results(added.measurement_id) == results  # lossless
        expected_points = sum(
            len(found.points)
            for axis in results.axes.values()
            for position in axis.positions
            for found in position.directions.values()
            if found is not None
        )
        assert _count(store, t.points) == expected_points
        assert _count(store, t.axis_results) == len(results.axes)
        with store.reading("query") as db:  # the rows answer questions without the JSON
            medians = (
                db.execute(
                    select(t.points.c.median)
                    .join(t.axis_results, t.axis_results.c.id == t.points.c.axis_result_id)
                    .where(t.axis_results.c.axis == "X", t.points.c.direction == "positive")
                )
                .scalars()
                .all()
            )
            fits = db.execute(
                select(func.count()).select_from(t.fits).where(t.fits.c.model == "linear")
            ).scalar_one()
        x_positive = [
            p.median
            for position in results.axes["X"].positions
            if (found := position.directions["positive"]) is not None
            for p in found.points
        ]
        assert sorted(medians) == sorted(x_positive)
        assert fits > 0


def test_the_same_results_are_stored_once(store_url: str, make_results: Make) -> None:
    results = make_results("2026-01-10T08:00:00+00:00")
    with open_store(store_url, write=True) as store:
        first = store.add(results, MeasurementInfo(serial="M17"))
        again = store.add(results, MeasurementInfo(serial="M17", label="delivery"))
        assert (again.measurement_id, again.new) == (first.measurement_id, False)
        with pytest.raises(ConfigError, match=r"already stored as measurement .* of machine 'M17'"):
            store.add(results, MeasurementInfo(serial="M18"))
        assert _count(store, t.measurements) == 1
        assert _count(store, t.machines) == 1


def test_machines_measurements_and_trend(store_url: str, make_results: Make) -> None:
    with open_store(store_url, write=True) as store:
        store.add(
            make_results("2026-01-10T08:00:00+00:00"),
            MeasurementInfo(serial="M17", label="delivery", temperature_c=21.5),
        )
        store.add(
            make_results("2029-03-01T08:00:00+00:00", factor=0.7),
            MeasurementInfo(serial="M17", label="service", operating_hours=12000),
        )
        # added later, measured in between: the latest stays the 2029 one
        store.add(make_results("2027-06-01T08:00:00+00:00", 0.9), MeasurementInfo(serial="M17"))
        store.add(make_results("2026-02-01T08:00:00+00:00"), MeasurementInfo(serial="M18"))
    with open_store(store_url) as store:
        machines = {m.serial: m for m in store.machines()}
        assert set(machines) == {"M17", "M18"}
        assert machines["M17"].measurements == 3
        assert machines["M17"].latest_label == "service"
        assert machines["M17"].latest_verdicts.keys() == {"X", "Z"}
        _, measurements = store.machine("M17")
        assert [m.label for m in measurements] == ["delivery", None, "service"]
        assert measurements[0].temperature_c == 21.5
        trend = store.trend("M17", "X")
        coulomb = [p.coulomb for p in trend]
        assert all(c is not None for c in coulomb)
        assert coulomb[1] == pytest.approx(0.9 * coulomb[0], rel=1e-9)
        assert coulomb[2] == pytest.approx(0.7 * coulomb[0], rel=1e-9)
        with pytest.raises(ConfigError, match=r"has no axis 'Q'.*X, Z"):
            store.trend("M17", "Q")
        with pytest.raises(ConfigError, match="no machine 'M99'"):
            store.machine("M99")


def _ok(results: Results) -> Results:
    """The same results with every axis' own verdict ok: the status follows the change alone."""
    ok = Verdict(level="ok", reason="flat along the travel", action="none")
    axes = {name: a.model_copy(update={"verdict": ok}) for name, a in results.axes.items()}
    return results.model_copy(update={"axes": axes})


def test_check_against_delivery_and_fleet(store_url: str, make_results: Make) -> None:
    with open_store(store_url, write=True) as store:
        store.add(
            _ok(make_results("2026-01-10T08:00:00+00:00")),
            MeasurementInfo(serial="M17", label="delivery"),
        )
        store.add(
            _ok(make_results("2029-01-10T08:00:00+00:00", factor=0.5)),  # lost half its friction
            MeasurementInfo(serial="M17", label="service"),
        )
        for index, factor in enumerate((0.96, 1.0, 1.03, 0.98, 1.02)):
            store.add(
                _ok(make_results(f"2026-0{index + 2}-01T08:00:00+00:00", factor)),
                MeasurementInfo(serial=f"M{20 + index}", label="delivery"),
            )
        check = check_machine(store, "M17")
        other = check_machine(store, "M21")
    assert check.baseline is not None and check.baseline.label == "delivery"
    assert check.latest.label == "service"
    assert check.status == "critical"  # −50 % against delivery, beyond the 25 % limit
    assert check.axis_status == {"X": "critical", "Z": "critical"}
    assert any(
        "axis X: Coulomb friction -50.0 % since the baseline (critical)" in finding
        for finding in check.findings
    )
    assert check.fleet_machines == 5
    coulomb = {f.axis: f for f in check.fleet if f.characteristic == "coulomb"}
    assert coulomb["X"].outlier and coulomb["X"].modified_z is not None
    assert coulomb["X"].modified_z < -3.5
    assert any("outlier of its type" in finding for finding in check.findings)
    assert other.status == "ok" and other.baseline is None
    assert not any(f.outlier for f in other.fleet)


def test_a_fault_verdict_makes_the_check_critical(store_url: str, make_results: Make) -> None:
    """The fixture's axis X has the verdict fault, from its pattern along the travel:
    critical on its own; against a baseline with the same pattern no change shows, and the
    pattern is a warning to confirm, not a fault."""
    results = make_results("2026-01-10T08:00:00+00:00")
    assert results.axes["X"].verdict.level == "fault"
    with open_store(store_url, write=True) as store:
        store.add(results, MeasurementInfo(serial="M17", label="delivery"))
        alone = check_machine(store, "M17")
        store.add(
            make_results("2029-01-10T08:00:00+00:00"),
            MeasurementInfo(serial="M17", label="service"),
        )
        unchanged = check_machine(store, "M17")
    assert alone.status == "critical"
    assert alone.axis_status["X"] == "critical"
    assert "axis X: verdict fault" in alone.findings
    assert unchanged.baseline is not None and alone.baseline is None
    # no change since the baseline: not critical, but a fault-sized pattern to confirm
    assert unchanged.status == "warning" and unchanged.axis_status["X"] == "warning"
    assert "axis X: verdict fault" not in unchanged.findings
    assert any("unchanged since the baseline: confirm" in f for f in unchanged.findings)


def test_comparability_is_stated(store_url: str, make_results: Make) -> None:
    later = make_results("2029-01-10T08:00:00+00:00")
    later = later.model_copy(
        update={"recording": later.recording.model_copy(update={"source": "modbus"})}
    )
    with open_store(store_url, write=True) as store:
        store.add(
            make_results("2026-01-10T08:00:00+00:00"),
            MeasurementInfo(serial="M17", label="delivery", temperature_c=20.0),
        )
        store.add(later, MeasurementInfo(serial="M17", label="service", temperature_c=32.0))
        check = check_machine(store, "M17")
    assert check.comparability is not None and check.comparability.refused is None
    text = " ".join(check.comparability.differences)
    assert "temperatures differ by 12.0 K" in text
    assert "another link (simulation against modbus)" in text


def test_a_failed_add_leaves_nothing(
    store_url: str, make_results: Make, monkeypatch: pytest.MonkeyPatch
) -> None:
    from ncmeasure.store import writing

    original = writing._add_axes

    def failing(db, *rest):  # type: ignore[no-untyped-def]
        original(db, *rest)  # every row is written ...
        assert db.execute(select(func.count()).select_from(t.points)).scalar_one() > 0
        raise ConfigError("injected failure after the rows")  # ... and then it fails

    monkeypatch.setattr(writing, "_add_axes", failing)
    with open_store(store_url, write=True) as store:
        with pytest.raises(ConfigError, match="injected"):
            store.add(make_results("2026-01-10T08:00:00+00:00"), MeasurementInfo(serial="M17"))
        for table in (t.measurements, t.machines, t.axes, t.axis_results, t.points):
            assert _count(store, table) == 0, table.name


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("serial", "../etc/passwd", "serial"),
        ("serial", "M1'; DROP TABLE machines; --", "serial"),
        ("serial", "", "serial"),
        ("label", "Delivery Day", "label"),
        ("temperature_c", float("nan"), "temperature"),
        ("operating_hours", -1.0, "operating hours"),
        ("site", "x" * 500, "site"),
    ],
)
def test_bad_info_is_refused_before_anything_is_written(
    tmp_path, make_results: Make, field: str, value: object, message: str
) -> None:  # type: ignore[no-untyped-def]
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    info = {"serial": "M17", field: value}
    with open_store(url, write=True) as store:
        with pytest.raises(ConfigError, match=message):
            store.add(make_results("2026-01-10T08:00:00+00:00"), measurement_info(**info))
        assert store.machines() == []
