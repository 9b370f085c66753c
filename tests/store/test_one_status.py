"""One status of a machine on every surface, from one store.

The machine's Coulomb friction rose by 21 % since its delivery while the friction
of each measured point rose by less (the viscous part did not move): the point
by point and the Coulomb figures fall on either side of a limit, the case in
which ``store check``, ``store report``, the dashboard, MQTT and OPC UA used to
disagree. Every surface must show the status of the one rule
(:func:`ncmeasure.analysis.judgement.status.machine_status`).
"""

from __future__ import annotations

import re
import statistics
from collections.abc import Callable
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from ncmeasure.analysis.judgement.compare import compare_results
from ncmeasure.analysis.judgement.status import figures_of, machine_status
from ncmeasure.formats.comparison import Status
from ncmeasure.formats.results import AxisResult, Results, Verdict
from ncmeasure.publish.summary import axis_summaries, device_health, worst_health
from ncmeasure.store import MeasurementInfo, open_store
from ncmeasure.store.check import check_machine
from ncmeasure.store.overview import fleet_overview
from ncmeasure.store.report import write_fleet_report
from ncmeasure.web import create_app

Make = Callable[..., Results]

RISE = 0.21
"""Coulomb friction's rise: beyond the warning limit, below the critical one."""

_HEALTH_STATUS: dict[str, Status] = {
    "NORMAL": "ok",
    "MAINTENANCE_REQUIRED": "warning",
    "OFF_SPEC": "critical",
    "FAILURE": "critical",
}


def _healthy(axis: AxisResult) -> AxisResult:
    """The axis with the verdict ok (the change, not the fingerprint, is under test)."""
    return axis.model_copy(update={"verdict": Verdict(level="ok", reason="flat", action="none")})


def _coulomb_raised(axis: AxisResult, rise: float) -> AxisResult:
    """The axis with Coulomb friction ``rise`` × its mean higher, viscous friction unchanged."""
    coulombs = [
        found.fit.coulomb
        for p in axis.positions
        for found in p.directions.values()
        if found is not None and found.fit is not None and found.fit.coulomb is not None
    ]
    added = rise * statistics.fmean(coulombs)
    positions = []
    for position in axis.positions:
        directions = {}
        for name, found in position.directions.items():
            if found is None:
                directions[name] = None
                continue
            sign = 1.0 if name == "positive" else -1.0
            fit = found.fit
            if fit is not None and fit.coulomb is not None:
                fit = fit.model_copy(update={"coulomb": fit.coulomb + added})
            points = [
                p.model_copy(update={"median": p.median + sign * added}) for p in found.points
            ]
            directions[name] = found.model_copy(update={"points": points, "fit": fit})
        positions.append(position.model_copy(update={"directions": directions}))
    return axis.model_copy(update={"positions": positions})


def _results(base: Results, when: str, rise: float = 0.0) -> Results:
    axes = {name: _coulomb_raised(_healthy(axis), rise) for name, axis in base.axes.items()}
    recording = base.recording.model_copy(update={"directory": f"runs/{when}", "start_utc": when})
    return base.model_copy(update={"axes": axes, "recording": recording, "created_utc": when})


@pytest.fixture
def one_machine(tmp_path: Path, base_results: Results) -> tuple[str, Results, Results]:
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    delivered = _results(base_results, "2026-01-10T08:00:00+00:00")
    now = _results(base_results, "2027-01-10T08:00:00+00:00", RISE)
    with open_store(url, write=True) as store:
        store.add(delivered, MeasurementInfo(serial="M7", label="delivery", site="Hall 3"))
        store.add(now, MeasurementInfo(serial="M7", label="service"))
    return url, delivered, now


def test_every_surface_shows_the_one_status(
    one_machine: tuple[str, Results, Results], tmp_path: Path
) -> None:
    url, delivered, now = one_machine
    rule = machine_status(figures_of(now), baseline=figures_of(delivered)).status
    assert rule == "warning"  # Coulomb +21 %: above the warning limit, below the critical one

    comparison = compare_results(delivered, [now], labels=["delivery", "service"])
    # the points moved less than Coulomb friction: the case where surfaces disagreed
    assert max(r.max_abs_deviation_percent for r in comparison.runs) < RISE * 100

    with open_store(url) as store:
        check = check_machine(store, "M7")
        overview = fleet_overview(store)
        page = write_fleet_report(store, overview, tmp_path / "fleet.html", trends=0)
    report_html = page.read_text(encoding="utf-8")
    (report_counts,) = [
        status
        for status in ("ok", "warning", "critical")
        if re.search(rf">1 {status}<", report_html)
    ]
    (machine,) = overview.machines
    summaries = axis_summaries(overview)
    mqtt = {s.message()["status"] for s in summaries}
    opcua = _HEALTH_STATUS[worst_health(device_health(a) for a in machine.axes.values())]

    with TestClient(create_app(url), base_url="http://127.0.0.1") as client:
        fleet_html = client.get("/").text
        machine_html = client.get("/machines/M7").text
    (fleet_page,) = re.findall(r'class="light check-(\w+)"', fleet_html)
    machine_page = re.search(r'<h1>Machine M7 <span class="badge status-(\w+)"', machine_html)
    assert machine_page is not None

    shown = {
        "compare": comparison.status,
        "store check": check.status,
        "store report": report_counts,
        "overview": machine.status,
        "fleet page": fleet_page,
        "machine page": machine_page.group(1),
        "MQTT": mqtt.pop() if len(mqtt) == 1 else f"several: {mqtt}",
        "OPC UA": opcua,
    }
    assert shown == dict.fromkeys(shown, rule)
    # per axis too: store check, compare and the overview agree axis by axis
    per_axis = {name: a.status for name, a in machine.axes.items()}
    assert check.axis_status == per_axis
    assert comparison.runs[0].axis_status == per_axis
