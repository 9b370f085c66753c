"""The dashboard: the HTML of the grid and the pages, and what Chromium makes of it."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx2 as httpx
import numpy as np
import pytest
from markupsafe import escape

from ncmeasure.formats.results import AxisResult
from ncmeasure.web import ServerInfo
from tests.browser import pixels_like, screenshot
from tests.web.conftest import SCRIPT_SITE, TOKEN, WAIT_S, Fleet

FAULT_BACKGROUND = "#f7cfcb"
OK_BACKGROUND = "#cdebd5"


@pytest.fixture(scope="module")
def browser(server: ServerInfo) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=server.url, timeout=WAIT_S) as found:
        yield found


def _row(page: str, serial: str) -> str:
    match = re.search(rf"<tr>\s*<td><a href=\"/machines/{serial}\">.*?</tr>", page, re.S)
    assert match, serial
    return match.group(0)


def test_the_grid_shows_every_machine_and_axis(browser: httpx.Client) -> None:
    found = browser.get("/")
    assert found.status_code == 200
    assert found.headers["content-type"].startswith("text/html")
    page = found.text
    assert re.search(r"<th>X</th>\s*<th>Y</th>", page)
    # a light: the axis' status, reading its verdict; its tooltip says why
    lights = {
        serial: re.findall(
            r'class="light axis check-(\w+)"[^>]*>(?:<a [^>]*>)?([^<]*)<', _row(page, serial)
        )
        for serial in ("M-100", "M-101", "M-102", "M-103")
    }
    assert lights == {
        "M-100": [("ok", "ok"), ("ok", "ok")],
        "M-101": [("ok", "ok"), ("critical", "fault")],
        "M-102": [("ok", "ok"), ("warning", "check")],
        "M-103": [("ok", "ok"), ("none", "–")],  # no axis Y
    }
    assert '<a href="/machines/M-101/axes/Y">fault</a>' in page
    (tooltip,) = re.findall(r'title="(status: critical[^"]*)"', _row(page, "M-101"))
    assert tooltip.startswith("status: critical\nverdict fault\n")
    assert "likely a shifted or tilted loose bearing" in tooltip
    counts = re.findall(r'class="badge check-(\w+)">(\d+) ', page)
    assert counts == [("ok", "5"), ("warning", "1"), ("critical", "1")]
    assert re.search(r'<td class="light check-(ok|warning|critical)"', _row(page, "M-100"))
    assert "<script" not in page.lower()
    assert str(escape(SCRIPT_SITE)) in page


def _serials(page: str) -> list[str]:
    return re.findall(r'<tr>\s*<td><a href="/machines/([^"]+)"><strong>', page)


def test_the_grid_goes_in_pages_and_finds_machines(browser: httpx.Client) -> None:
    first = browser.get("/", params={"limit": 2}).text
    assert _serials(first) == ["M-100", "M-101"]
    assert "2 of 4 machines, status per axis" in first
    (following,) = re.findall(r'<a href="([^"]+)" rel="next">', first)
    assert following == "/?limit=2&amp;after=M-101"
    second = browser.get("/", params={"limit": 2, "after": "M-101"}).text
    assert _serials(second) == ["M-102", "M-103"]
    assert 'rel="next"' not in second and '<a href="/?limit=2">first page</a>' in second
    # the search: serial, type or site, any case; the status: the machine's
    assert _serials(browser.get("/", params={"q": "hall 1"}).text) == ["M-100", "M-101"]
    found = browser.get("/", params={"status": "critical"}).text
    assert _serials(found) == ["M-101"] and "1 machine that match" in found
    assert 'value="hall 1"' in browser.get("/", params={"q": "hall 1"}).text
    none = browser.get("/", params={"q": "nowhere"}).text
    assert _serials(none) == [] and "No machine matches" in none
    assert browser.get("/", params={"limit": 0}).status_code == 422
    assert browser.get("/", params={"status": "bad"}).status_code == 422


def test_pages_forbid_scripts_and_keep_the_token_out_of_referrers(browser: httpx.Client) -> None:
    headers = browser.get("/").headers
    assert "default-src 'none'" in headers["content-security-policy"]
    assert "script-src" not in headers["content-security-policy"]
    assert headers["referrer-policy"] == "no-referrer"
    assert headers["x-content-type-options"] == "nosniff"


def test_a_machine_page_has_measurements_check_and_trends(browser: httpx.Client) -> None:
    found = browser.get("/machines/M-100")
    assert found.status_code == 200
    page = found.text
    assert "Machine M-100" in page and 'id="check"' in page
    assert "A. Technician" in page and "B. Service" in page
    assert "21.5 °C" in page and "2012 h" in page
    assert "2025-01-10 09:00 UTC" in page and "2025-07-10 09:00 UTC" in page
    # one trend per axis, an image the browser fetches after the page (no plot drawn for it)
    assert "<svg" not in page
    trends = re.findall(r'<img src="(/machines/M-100/axes/\w+/trend\.svg)"', page)
    assert trends == ["/machines/M-100/axes/X/trend.svg", "/machines/M-100/axes/Y/trend.svg"]
    for trend in trends:
        image = browser.get(trend)
        assert image.status_code == 200
        assert image.headers["content-type"].startswith("image/svg+xml")
        assert image.text.startswith("<svg") and 'xmlns="http://www.w3.org/2000/svg"' in image.text
        assert "over the machine" in image.text  # the trend's title
    assert '<a href="/machines/M-100/axes/X">' in page
    assert re.search(r'href="/api/v1/measurements/\d+/results"', page)
    escaped = browser.get("/machines/M-103").text
    assert "&lt;script&gt;" in escaped and "<script" not in escaped.lower()


def test_an_axis_page_has_the_trend_and_the_latest_curves(browser: httpx.Client) -> None:
    page = browser.get("/machines/M-101/axes/Y").text
    assert 'class="badge verdict-fault">fault</span>' in page
    assert "loose bearing" in page  # the verdict's reason
    assert page.count("<svg") == 3  # trend, friction curves, friction along the travel
    assert re.search(r"<td class=\"light verdict-ok\">ok</td>.*verdict-fault", page, re.S)
    ids = re.findall(r'\bid="([^"]+)"', page)
    assert len(ids) == len(set(ids)), "element ids of the inline SVGs collide"


def test_unknown_pages_are_404_pages(browser: httpx.Client) -> None:
    for path in (
        "/machines/NO-SUCH",
        "/machines/M-103/axes/Y",
        "/machines/M-100/axes/Q",
        "/machines/M-100/axes/Q/trend.svg",
        "/machines/NO-SUCH/axes/X/trend.svg",
    ):
        found = browser.get(path)
        assert found.status_code == 404, path
        assert found.headers["content-type"].startswith("text/html")
        assert "Traceback" not in found.text
    assert "NO-SUCH" in browser.get("/machines/NO-SUCH").text
    assert browser.get("/machines/%3Cscript%3E").status_code == 404
    assert "<script>" not in browser.get("/machines/%3Cscript%3E").text


# --- in a browser ------------------------------------------------------------------


def test_chromium_renders_the_grid(token_server: ServerInfo, tmp_path: Path) -> None:
    """Through the token sign-in a browser does: ``?token=``, a redirect, the cookie."""
    image = screenshot(f"{token_server.url}?token={TOKEN}", tmp_path, 900)
    assert image.shape == (900, 1280, 3)
    assert image.std() > 0.05, "a blank page"
    assert pixels_like(image, FAULT_BACKGROUND, 0.03) > 500  # M-101's Y light
    assert pixels_like(image, OK_BACKGROUND, 0.03) > 5 * 500  # the ok lights


def test_chromium_renders_a_machine_page_with_its_plots(
    token_server: ServerInfo, tmp_path: Path
) -> None:
    image = screenshot(f"{token_server.url}machines/M-101?token={TOKEN}", tmp_path, 2200)
    assert image.std() > 0.05, "a blank page"
    ink = np.any(image < 0.94, axis=2)
    assert ink.mean() > 0.04, f"only {ink.mean():.1%} of the page is not white"
    # the trend plots' markers: the fault of Y in red, the ok points in green
    assert pixels_like(image, "#c0392b", 0.05) > 30
    assert pixels_like(image, "#2e8b3e", 0.05) > 100


def test_chromium_renders_an_axis_page_with_its_friction_figures(
    token_server: ServerInfo, tmp_path: Path
) -> None:
    """The figures written as SVG show in a browser: the positions' colours of the
    friction over velocity, the average's orange along the travel."""
    from ncmeasure.report.colours import PALETTE

    image = screenshot(f"{token_server.url}machines/M-101/axes/Y?token={TOKEN}", tmp_path, 2600)
    assert image.std() > 0.05, "a blank page"
    # the first position's blue and the second's orange (also the average along the
    # travel): colours no other part of the dashboard draws (a machine's page has none)
    for colour in PALETTE[:2]:
        assert pixels_like(image, colour, 0.05) > 500, colour


def test_without_the_token_chromium_gets_no_page(token_server: ServerInfo, tmp_path: Path) -> None:
    image = screenshot(token_server.url, tmp_path, 600)
    assert pixels_like(image, OK_BACKGROUND, 0.03) == 0  # a plain 401 line, no grid


def test_an_axis_pages_curves_are_drawn_once_per_measurement(
    fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A measurement's friction curves do not change: a measurement added to another
    machine leaves them cached; the axis' own new measurement is drawn."""
    from fastapi.testclient import TestClient

    import ncmeasure.web.pages as pages
    from ncmeasure.store import MeasurementInfo, open_store
    from ncmeasure.web import create_app

    copy = tmp_path / "fleet.db"
    copy.write_bytes(Path(fleet.url.removeprefix("sqlite:///")).read_bytes())
    url = f"sqlite:///{copy}"
    drawn: list[str] = []
    original = pages.curves_svg

    def counted(axis: str, result: AxisResult) -> str:
        drawn.append(axis)
        return original(axis, result)

    monkeypatch.setattr(pages, "curves_svg", counted)

    def add(serial: str, when: str) -> int:
        results = fleet.spare.model_copy(update={"created_utc": when})
        with open_store(url, write=True) as store:
            info = MeasurementInfo(serial=serial, label="service", measured_utc=when)
            return store.add(results, info).measurement_id

    with TestClient(create_app(url), base_url="http://127.0.0.1") as client:
        first = client.get("/machines/M-100/axes/X")
        assert first.status_code == 200 and first.text.count("<svg") == 3
        assert len(drawn) == 1
        assert client.get("/machines/M-100/axes/X").text == first.text
        add("M-102", "2026-02-01T08:00:00Z")  # another machine: the store's version moves
        assert client.get("/machines/M-100/axes/X").status_code == 200
        assert len(drawn) == 1
        newest = add("M-100", "2026-03-01T08:00:00Z")
        page = client.get("/machines/M-100/axes/X").text
        assert drawn == ["X", "X"]  # the new latest measurement's curves
        assert f"/api/v1/measurements/{newest}/results" in page


def test_a_check_after_the_grid_is_the_stores_check(fleet: Fleet, tmp_path: Path) -> None:
    """Once the grid has read the fleet's statuses, a check takes the other machines'
    figures from them (read on after a change): the same check as the store's."""
    from fastapi.testclient import TestClient

    from ncmeasure.store import MeasurementInfo, open_store
    from ncmeasure.store.check import check_machine
    from ncmeasure.web import create_app

    copy = tmp_path / "fleet.db"
    copy.write_bytes(Path(fleet.url.removeprefix("sqlite:///")).read_bytes())
    url = f"sqlite:///{copy}"

    def timeless(found: dict[str, Any]) -> dict[str, Any]:
        if found.get("comparison"):
            found["comparison"].pop("created_utc")
        return found

    def same(client: Any, serial: str) -> None:
        served = client.get(f"/api/v1/machines/{serial}/check")
        assert served.status_code == 200
        with open_store(url) as store:
            expected = check_machine(store, serial).model_dump(mode="json")
        assert timeless(served.json()) == timeless(expected)

    with TestClient(create_app(url), base_url="http://127.0.0.1") as client:
        assert client.get("/").status_code == 200
        for serial in ("M-100", "M-101", "M-103"):
            same(client, serial)
        results = fleet.spare.model_copy(update={"created_utc": "2026-04-01T08:00:00Z"})
        with open_store(url, write=True) as store:
            store.add(results, MeasurementInfo(serial="M-102", label="service"))
        assert client.get("/").status_code == 200
        for serial in ("M-100", "M-102"):
            same(client, serial)
