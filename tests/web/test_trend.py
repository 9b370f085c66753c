"""The dashboard's trend of an axis, written as SVG without matplotlib."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from typing import Any

from ncmeasure.report.colours import VERDICT_COLOURS
from ncmeasure.store.records import TrendPoint
from ncmeasure.web.trend import trend_svg
from tests.web.conftest import matplotlib_loaded_by

SVG = "{http://www.w3.org/2000/svg}"


def _point(day: str, verdict: str, coulomb: float | None, **changes: Any) -> TrendPoint:
    values: dict[str, Any] = {
        "measurement_id": 1,
        "measured_utc": f"{day}T09:00:00+00:00",
        "label": None,
        "operating_hours": None,
        "unit": "Nm",
        "verdict": verdict,
        "coulomb": coulomb,
        "coulomb_positive": None,
        "coulomb_negative": None,
        "viscous_per_m_min": -0.05 if coulomb is None else 0.02 * coulomb,
        "spread_percent": 4.0,
        "signature": None,
        "offset": None,
    }
    values.update(changes)
    return TrendPoint(**values)


def _trend() -> list[TrendPoint]:
    return [
        _point("2025-01-10", "ok", 2.0),
        _point("2025-04-10", "ok", None),
        _point("2025-07-10", "check", 2.4),
        _point("2025-09-10", "fault", 3.1, unit="A"),
        _point("2026-01-10", "fault", 3.3),
    ]


def _circles(panel: ET.Element) -> list[str]:
    return [c.get("fill", "") for c in panel.findall(f"{SVG}circle")]


def test_three_panels_with_points_in_their_verdicts_colours() -> None:
    svg = ET.fromstring(trend_svg("M-1", "Y&<Z>", _trend()))  # well-formed: the texts escaped
    panels = svg.findall(f"{SVG}g")
    assert len(panels) == 3
    # the point in amperes is left out; Coulomb friction not determined is left out of its panel
    coulomb, viscous, spread = (_circles(p) for p in panels)
    colours = VERDICT_COLOURS
    assert coulomb == [colours["ok"], colours["check"], colours["fault"]]
    assert viscous == [colours["ok"], colours["ok"], colours["check"], colours["fault"]]
    assert len(spread) == 4
    texts = "".join(svg.itertext())
    assert (
        "Axis Y&<Z> over the machine's life (1 measurement(s) in another unit not drawn)" in texts
    )
    assert "Coulomb friction [Nm]" in texts and "viscous friction [Nm per m/min]" in texts
    # the legend: one marker per verdict shown, in the order ok, check, fault
    legend = [c.get("fill") for c in svg.findall(f"{SVG}circle")]
    assert legend == [colours["ok"], colours["check"], colours["fault"]]
    top = [t.text for t in svg.findall(f"{SVG}text")]
    assert [t for t in top if t in colours] == ["ok", "check", "fault"]


def test_levels_start_at_zero_and_the_newest_point_is_highest() -> None:
    svg = ET.fromstring(trend_svg("M-1", "X", _trend()))
    coulomb = svg.findall(f"{SVG}g")[0]
    ticks = [t.text for t in coulomb.findall(f"{SVG}text")[1:] if t.get("text-anchor") == "end"]
    assert ticks[0] == "0"  # Coulomb friction from zero: a change looks its size
    heights = [float(c.get("cy", "0")) for c in coulomb.findall(f"{SVG}circle")]
    assert heights == sorted(heights, reverse=True)  # 2.0, 2.4, 3.3 Nm: higher up the page
    # the viscous slope may be negative: its panel is not pinned at zero
    viscous = svg.findall(f"{SVG}g")[1]
    shown = [t.text for t in viscous.findall(f"{SVG}text") if t.get("text-anchor") == "end"]
    assert shown[0] and shown[0].startswith("\u2212")  # a minus sign, not a hyphen
    assert float(shown[0].replace("\u2212", "-")) < 0


def test_one_measurement_and_the_date_ticks() -> None:
    text = trend_svg("M-1", "X", [_point("2025-01-10", "ok", 2.0)])
    ET.fromstring(text)
    days = re.findall(r">(\d{4}-\d\d-\d\d)<", text)
    assert 2 * 3 <= len(days) <= 3 * 3  # two or three per panel, a fortnight around the day
    assert ' id="' not in text  # any number of them can share a page


def test_drawing_the_trend_imports_no_matplotlib() -> None:
    script = (
        "from ncmeasure.store.records import TrendPoint\n"
        "from ncmeasure.web.trend import trend_svg\n"
        "p = TrendPoint(measurement_id=1, measured_utc='2025-01-10T09:00:00+00:00', label=None,"
        " operating_hours=None, unit='A', verdict='ok', coulomb=1.0, coulomb_positive=None,"
        " coulomb_negative=None, viscous_per_m_min=0.1, spread_percent=3.0, signature=None,"
        " offset=None)\n"
        "assert trend_svg('M', 'X', [p]).startswith('<svg')\n"
    )
    assert matplotlib_loaded_by(script) == []
