"""The fleet at a glance: the overview agrees with ``store check``; the report shows it."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.formats.comparison import Limits
from ncmeasure.formats.results import Results
from ncmeasure.store import MeasurementInfo, open_store
from ncmeasure.store.check import check_machine
from ncmeasure.store.overview import fleet_overview
from ncmeasure.store.report import write_fleet_report
from tests.browser import pixels_like, screenshot

Make = Callable[..., Results]
runner = CliRunner()

# machine → (factor at delivery, factor now); M17 lost half its friction
FLEET = {
    "M17": (1.0, 0.5),
    "M20": (0.96, 0.97),
    "M21": (1.0, 1.12),
    "M22": (1.03, 1.0),
    "M23": (0.98, 1.27),
    "M24": (1.02, 1.02),
    "M25": (1.01, None),  # only the delivery measurement
}


def _fill(url: str, make_results: Make) -> None:
    with open_store(url, write=True) as store:
        for index, (serial, (delivered, now)) in enumerate(FLEET.items()):
            store.add(
                make_results(f"2026-01-{10 + index}T08:00:00+00:00", delivered),
                MeasurementInfo(
                    serial=serial, label="delivery", site="Hall 3" if index % 2 else None
                ),
            )
            if now is not None:
                store.add(
                    make_results(f"2029-01-{10 + index}T08:00:00+00:00", now),
                    MeasurementInfo(serial=serial, label="service"),
                )


@pytest.fixture
def fleet_url(store_url: str, make_results: Make) -> str:
    _fill(store_url, make_results)
    return store_url


def test_the_overview_names_the_outliers_store_check_names(fleet_url: str) -> None:
    with open_store(fleet_url) as store:
        overview = fleet_overview(store)
        checks = {serial: check_machine(store, serial) for serial in FLEET}
    assert [m.serial for m in overview.machines] == sorted(FLEET)
    for machine in overview.machines:
        check = checks[machine.serial]
        expected = {(f.axis, f.characteristic) for f in check.fleet if f.outlier}
        found = {(o.axis, o.characteristic) for a in machine.axes.values() for o in a.outliers}
        assert found == expected, machine.serial
        for figure in check.fleet:
            if figure.outlier:
                outlier = next(
                    o
                    for o in machine.axes[figure.axis].outliers
                    if o.characteristic == figure.characteristic
                )
                assert outlier.modified_z == pytest.approx(figure.modified_z, rel=1e-9)
                assert outlier.fleet_median == pytest.approx(figure.fleet_median, rel=1e-12)
    assert any(o.serial == "M17" and o.characteristic == "coulomb" for o in overview.outliers)


def test_the_overview_changes_against_the_baseline(fleet_url: str) -> None:
    with open_store(fleet_url) as store:
        overview = fleet_overview(store, Limits(warning_percent=20, critical_percent=40))
    machines = {m.serial: m for m in overview.machines}
    coulomb = {
        serial: {c.characteristic: c for c in m.axes["X"].changes}.get("coulomb")
        for serial, m in machines.items()
    }
    assert coulomb["M17"] is not None and coulomb["M17"].change == pytest.approx(-50.0)
    assert coulomb["M17"].status == "critical" and machines["M17"].status == "critical"
    assert coulomb["M23"] is not None and coulomb["M23"].status == "warning"  # +29.6 %
    assert coulomb["M21"] is not None and coulomb["M21"].status == "ok"  # +12 %
    assert coulomb["M25"] is None and machines["M25"].measurements == 1  # nothing to compare
    assert overview.count("critical") >= 1 and overview.axes == ["X", "Z"]
    assert overview.types == {machines["M17"].machine_type: len(FLEET)}


def test_an_empty_store_gives_an_empty_overview_and_report(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    with open_store(url, write=True):
        pass
    result = runner.invoke(app, ["store", "report", "-o", str(tmp_path / "f.html"), "--store", url])
    assert result.exit_code == 0, result.output
    assert "holds no machine" in (tmp_path / "f.html").read_text(encoding="utf-8")


def test_the_report_command_writes_the_grid_outliers_and_trends(
    fleet_url: str, tmp_path: Path
) -> None:
    out = tmp_path / "fleet.html"
    result = runner.invoke(
        app, ["store", "report", "-o", str(out), "--store", fleet_url, "--trends", "3", "-q"]
    )
    assert result.exit_code == 3, result.output  # M17: a critical change
    assert "7 machine(s)" in result.stdout and f"wrote {out}" in result.stdout
    page = out.read_text(encoding="utf-8")
    assert "<script" not in page
    for serial in FLEET:
        assert f"<strong>{serial}</strong>" in page
    row = page[page.index("<strong>M17</strong>") :].split("</tr>")[0]
    assert re.findall(r'class="light (\w+)"', row) == ["critical", "critical"]
    outliers = page[page.index("<h2>Outliers</h2>") : page.index("<h2>Trends</h2>")]
    assert "<td>M17</td>" in outliers and "Coulomb friction" in outliers
    trends = page[page.index("<h2>Trends</h2>") :]
    assert trends.count("<svg ") == 3 and "data:image" not in trends
    assert "M17 · axis X" in trends  # the largest change first


def test_serials_and_sites_are_text_in_the_report(tmp_path: Path, make_results: Make) -> None:
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    with open_store(url, write=True) as store:
        store.add(
            make_results("2026-01-10T08:00:00+00:00"), MeasurementInfo(serial="M1", site="<b>x")
        )
        overview = fleet_overview(store)
        write_fleet_report(store, overview, tmp_path / "f.html")
    page = (tmp_path / "f.html").read_text(encoding="utf-8")
    assert "<b>x" not in page and "&lt;b&gt;x" in page


CRITICAL_BACKGROUND = "#f7cfcb"
OK_BACKGROUND = "#cdebd5"


def test_chromium_renders_the_fleet_report(tmp_path: Path, make_results: Make) -> None:
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    _fill(url, make_results)
    with open_store(url) as store:
        page = write_fleet_report(store, fleet_overview(store), tmp_path / "fleet.html")
    image = screenshot(page, tmp_path, 2400)
    assert image.shape == (2400, 1280, 3)
    assert pixels_like(image, CRITICAL_BACKGROUND, 0.03) > 400  # M17's two cells at least
    assert pixels_like(image, OK_BACKGROUND, 0.03) > 4 * 400
    # the trend plots reach the screen: the line colour of the report's plots
    from ncmeasure.report.plots import PALETTE

    assert pixels_like(image, PALETTE[0]) > 200
    ink = np.any(image < 0.94, axis=2)
    assert ink.mean() > 0.03


def test_a_fleet_at_noise_level_names_no_outlier_for_a_small_difference(
    tmp_path: Path, make_results: Make
) -> None:
    """Machines alike to 0.1 %: one 5 % off has a huge z, but 5 % is no fault (warning: 20 %)."""
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    factors = {"M1": 1.0, "M2": 1.001, "M3": 0.999, "M4": 1.0005, "M5": 0.9995, "M6": 1.05}
    with open_store(url, write=True) as store:
        for index, (serial, factor) in enumerate(factors.items()):
            store.add(
                make_results(f"2026-02-{index + 1:02d}T08:00:00+00:00", factor),
                MeasurementInfo(serial=serial, label="delivery"),
            )
        check = check_machine(store, "M6")
        overview = fleet_overview(store)
        bigger = fleet_overview(store, Limits(warning_percent=4, critical_percent=40))
    coulomb = next(f for f in check.fleet if f.axis == "X" and f.characteristic == "coulomb")
    assert coulomb.modified_z is not None and coulomb.modified_z > 3.5  # far out, statistically
    assert not coulomb.outlier and not overview.outliers  # but 5 % is within any healthy spread
    # with a warning limit below the difference, the same machine is an outlier
    assert {(o.serial, o.characteristic) for o in bigger.outliers} >= {("M6", "coulomb")}
