"""One status of a machine on every surface, from one store.

Every surface (``store check``, ``store report``, the dashboard's fleet grid and
machine page, the REST API, MQTT and OPC UA) must show the status of the one
rule (:func:`ncmeasure.analysis.judgement.status.machine_status`), in the cases
in which they used to disagree:

* Coulomb friction rose by 21 % since delivery while the friction of each
  measured point rose by less (the viscous part did not move): the point by
  point and the Coulomb figures fall on either side of a limit;
* an axis whose own verdict is ``fault`` from its pattern along the travel, that
  pattern unchanged since delivery (the machine's fingerprint): ok;
* friction raised at one end of the travel since delivery: a local change, a
  warning although no characteristic crossed a limit.
"""

from __future__ import annotations

import html as html_lib
import re
import statistics
from collections.abc import Callable
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from ncmeasure.analysis.judgement.compare import compare_results
from ncmeasure.formats.comparison import Status, worst_status
from ncmeasure.formats.results import AxisResult, Results, Verdict
from ncmeasure.publish.summary import axis_summaries, device_health, worst_health
from ncmeasure.store import MeasurementInfo, open_store
from ncmeasure.store.check import check_machine
from ncmeasure.store.overview import fleet_overview
from ncmeasure.store.report import write_fleet_report
from ncmeasure.web import create_app
from tests.report.example import scaled_axis

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


def _raised_at_the_end(axis: AxisResult, factor: float) -> AxisResult:
    """The axis with the friction of its last position ``factor`` times as high."""
    raised = scaled_axis(axis, factor)
    return axis.model_copy(update={"positions": [*axis.positions[:-1], raised.positions[-1]]})


def _measured(base: Results, when: str, change: Callable[[str, AxisResult], AxisResult]) -> Results:
    axes = {name: change(name, axis) for name, axis in base.axes.items()}
    recording = base.recording.model_copy(update={"directory": f"runs/{when}", "start_utc": when})
    return base.model_copy(update={"axes": axes, "recording": recording, "created_utc": when})


EXPLAINED: dict[str, tuple[str, str]] = {
    "coulomb rise": ("X", "Coulomb friction +21"),
    "fingerprint unchanged": ("X", "unchanged since the baseline"),
    "local change": ("Z", "likely a "),
}
"""Per case: the axis whose finding makes the status, and words of the finding that every
surface's explanation of that axis names."""

DELIVERED = "2026-01-10T08:00:00+00:00"
NOW = "2027-01-10T08:00:00+00:00"
CASES: dict[str, tuple[Callable[[Results], tuple[Results, Results]], Status]] = {
    # Coulomb friction +21 %, the points less: a warning
    "coulomb rise": (
        lambda base: (_results(base, DELIVERED), _results(base, NOW, RISE)),
        "warning",
    ),
    # axis X's own verdict is fault (a shifted loose bearing), re-measured 1 % higher
    # everywhere: the pattern is unchanged, no change; but a fault-sized pattern is to be
    # confirmed against the baseline's acceptance: a warning, not critical
    "fingerprint unchanged": (
        lambda base: (
            _measured(base, DELIVERED, lambda _, axis: axis),
            _measured(base, NOW, lambda _, axis: scaled_axis(axis, 1.01)),
        ),
        "warning",
    ),
    # axis Z's friction +8 % at one end (Coulomb friction +2.7 %, within every limit):
    # a local change since delivery, a warning
    "local change": (
        lambda base: (
            _measured(base, DELIVERED, lambda _, axis: _healthy(axis)),
            _measured(
                base,
                NOW,
                lambda name, axis: (
                    _raised_at_the_end(_healthy(axis), 1.08) if name == "Z" else _healthy(axis)
                ),
            ),
        ),
        "warning",
    ),
}


@pytest.fixture(params=list(CASES))
def case(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def one_machine(
    case: str, tmp_path: Path, base_results: Results
) -> tuple[str, Results, Results, Status]:
    build, expected = CASES[case]
    delivered, now = build(base_results)
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    with open_store(url, write=True) as store:
        store.add(delivered, MeasurementInfo(serial="M7", label="delivery", site="Hall 3"))
        store.add(now, MeasurementInfo(serial="M7", label="service"))
    return url, delivered, now, expected


def test_every_surface_shows_the_one_status(
    one_machine: tuple[str, Results, Results, Status], tmp_path: Path
) -> None:
    url, delivered, now, expected = one_machine
    comparison = compare_results(delivered, [now], labels=["delivery", "service"])
    rule = comparison.runs[0].status
    assert rule == expected

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
    mqtt = {s.axis.axis: s.message()["status"] for s in summaries}
    opcua = _HEALTH_STATUS[worst_health(device_health(a) for a in machine.axes.values())]

    with TestClient(create_app(url), base_url="http://127.0.0.1") as client:
        fleet_html = client.get("/").text
        machine_html = client.get("/machines/M7").text
        api_check = client.get("/api/v1/machines/M7/check").json()
        axis_pages = {name: client.get(f"/machines/M7/axes/{name}").text for name in now.axes}
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
        "REST": api_check["status"],
        "MQTT": worst_status(mqtt.values()),
        "OPC UA": opcua,
    }
    assert shown == dict.fromkeys(shown, rule)
    # per axis too: store check, compare and the overview agree axis by axis
    per_axis = {name: a.status for name, a in machine.axes.items()}
    assert check.axis_status == per_axis
    assert mqtt == per_axis
    assert comparison.runs[0].axis_status == per_axis
    # the axis page: its status, and the verdict judged against the baseline, as compare says
    level = {"ok": "ok", "warning": "check", "critical": "fault"}
    for name, html in axis_pages.items():
        badges = re.findall(r'<span class="badge (verdict|status)-(\w+)"', html)
        assert badges == [("verdict", level[per_axis[name]]), ("status", per_axis[name])], name
    # the MQTT message's change_status is the change's part of the same rule
    changes = {s.axis.axis: s.message()["change_status"] for s in summaries}
    assert changes == comparison.runs[0].change_status


_CELL = re.compile(
    r'<td class="light (?:axis check-)?(\w+)" title="(status: [^"]*)">(?:<a [^>]*>)?([^<]*)<'
)


def _cells(html: str) -> list[tuple[str, str, str]]:
    """The grid's axis cells in order: (colour, tooltip, text)."""
    return [(c, html_lib.unescape(t), html_lib.unescape(x)) for c, t, x in _CELL.findall(html)]


def test_every_surface_explains_the_status_by_its_reason(
    case: str, one_machine: tuple[str, Results, Results, Status], tmp_path: Path
) -> None:
    url, _, _, expected = one_machine
    name, words = EXPLAINED[case]
    with open_store(url) as store:
        overview = fleet_overview(store)
        page = write_fleet_report(store, overview, tmp_path / "fleet.html", trends=2)
    (machine,) = overview.machines
    axis = machine.axes[name]
    assert axis.status == expected
    assert any(words in r for r in (*axis.reasons, *axis.notes))
    report_html = page.read_text(encoding="utf-8")
    with TestClient(create_app(url), base_url="http://127.0.0.1") as client:
        fleet_html = client.get("/").text

    for surface, html in (("store report", report_html), ("fleet page", fleet_html)):
        cells = dict(zip(overview.axes, _cells(html), strict=True))
        colour, tooltip, text = cells[name]
        # coloured by the axis' status, never by its verdict; the tooltip names the reason
        assert colour == expected, surface
        assert words in tooltip, (surface, tooltip)
        assert text.startswith(axis.verdict), surface
        if case == "fingerprint unchanged":
            assert text.startswith(f"{axis.verdict} · fingerprint since delivery"), surface
    # the machine's tooltip in the grid names it too, and so does the report's trend
    (findings,) = re.findall(r'class="light check-\w+" title="([^"]*)"', fleet_html)
    assert words in html_lib.unescape(findings)
    if expected != "ok":
        trends = html_lib.unescape(report_html.split("<h2>Trends</h2>")[1])
        assert words in trends
    # the fleet page's badges count the axes' statuses
    counts = {s: int(n) for n, s in re.findall(r'class="badge check-\w+">(\d+) (\w+)<', fleet_html)}
    assert counts == {
        s: sum(a.status == s for a in machine.axes.values()) for s in ("ok", "warning", "critical")
    }
