"""The fleet report's trend, written as SVG without matplotlib."""

from __future__ import annotations

import datetime as dt
import re
import xml.etree.ElementTree as ET

from ncmeasure.report.svg import nice_ticks
from ncmeasure.report.trend_svg import trend_svg

SVG = "{http://www.w3.org/2000/svg}"


def _times(*days: int) -> list[dt.datetime]:
    return [dt.datetime(2026, 1, 1, 8, tzinfo=dt.UTC) + dt.timedelta(days=d) for d in days]


def _draw(**changes: object) -> ET.Element:
    options: dict[str, object] = {
        "baseline_index": 0,
        "warning_percent": 10.0,
        "critical_percent": 25.0,
        "labels": ["delivery", None, "service <b>"],
    }
    options.update(changes)
    text = trend_svg(
        "X&Y",
        _times(0, 40, 200),
        [
            ("Coulomb", "Nm", [2.0, None, 2.6]),
            ("viscous", "Nm per m/min", [0.2, 0.21, 0.22]),
            ("spread along the travel", "%", [4.0, 5.0, 6.0]),
        ],
        **options,  # type: ignore[arg-type]
    )
    return ET.fromstring(text)  # well-formed XML: the store's texts escaped


def test_panels_points_labels_and_the_bands_around_the_baseline() -> None:
    svg = _draw()
    panels = svg.findall(f"{SVG}g")
    assert len(panels) == 3
    lines = [p.find(f"{SVG}polyline") for p in panels]
    # a value not determined is left out of its panel's line
    assert [len(line.get("points", "").split()) for line in lines if line is not None] == [2, 3, 3]
    assert [len(p.findall(f"{SVG}circle")) for p in panels] == [2, 3, 3]
    # warning and critical bands with their dashed edges and the dotted baseline, except in %
    bands = [len(p.findall(f"{SVG}rect[@fill-opacity]")) for p in panels]
    assert bands == [2, 2, 0]
    dotted = [len(p.findall(f"{SVG}line[@stroke-dasharray='1 2']")) for p in panels]
    assert dotted == [1, 1, 0]
    texts = "".join(svg.itertext())
    assert "Axis X&Y over the machine's life" in texts
    assert texts.count("delivery") == 3 and texts.count("service <b>") == 3
    assert "[Nm per m/min]" in texts and "measured (UTC)" in texts


def test_the_critical_band_is_wider_than_the_warning_band_and_inside_the_view() -> None:
    svg = _draw()
    coulomb = svg.findall(f"{SVG}g")[0]
    frame, critical, warning = coulomb.findall(f"{SVG}rect")[:3]
    height = [float(r.get("height", "0")) for r in (frame, critical, warning)]
    assert height[0] > height[1] > height[2] > 0
    top = float(frame.get("y", "0"))
    assert float(critical.get("y", "0")) >= top
    # the band is ± 25 % and ± 10 % of the baseline: the heights keep that ratio
    assert abs(height[1] / height[2] - 2.5) < 0.05


def test_one_day_and_date_ticks() -> None:
    text = trend_svg(
        "Z",
        _times(0),
        [("Coulomb", "A", [1.5])],
        baseline_index=0,
        warning_percent=10.0,
        critical_percent=25.0,
    )
    days = re.findall(r">(\d{4}-\d\d-\d\d)<", text)
    assert 2 <= len(days) <= 6
    assert days == sorted(days) and days[0] < "2026-01-01" < days[-1]  # a fortnight around it
    assert len(days) >= 4


def test_nice_ticks() -> None:
    assert nice_ticks(0.0, 1.0) == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert nice_ticks(1.43, 2.87) == [1.5, 2.0, 2.5]
    assert nice_ticks(-0.013, 0.021) == [-0.01, 0.0, 0.01, 0.02]
    assert nice_ticks(3.0, 3.0) == [3.0]


def test_the_line_has_the_colour_of_the_report_plots() -> None:
    from ncmeasure.report.colours import PALETTE

    line = _draw().findall(f"{SVG}g")[0].find(f"{SVG}polyline")
    assert line is not None and line.get("stroke") == PALETTE[0]
