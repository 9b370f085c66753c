"""An axis' friction figures, the dashboard's and the report's: SVG without matplotlib."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from ncmeasure.formats.results import AxisResult, DirectionResult, Point
from ncmeasure.report.bearings import bearing_layout
from ncmeasure.report.colours import PALETTE
from ncmeasure.report.friction_svg import curves_svg, travel_svg
from tests.web.conftest import Fleet, matplotlib_loaded_by

SVG = "{http://www.w3.org/2000/svg}"


def _axis(fleet: Fleet, serial: str, axis: str) -> AxisResult:
    return fleet.of(serial)[-1].results.axes[axis]


def _points(direction: DirectionResult | None) -> list[Point]:
    return list(direction.points) if direction is not None else []


def _texts(svg: ET.Element) -> str:
    return "".join(svg.itertext())


def test_friction_over_velocity_has_every_point_in_its_positions_colour(fleet: Fleet) -> None:
    result = _axis(fleet, "M-101", "Y")
    svg = ET.fromstring(curves_svg("Y", result))  # well-formed XML
    negative, positive = svg.findall(f"{SVG}g")[:2]
    for panel, side in ((negative, "negative"), (positive, "positive")):
        circles = [c.get("fill") for c in panel.findall(f"{SVG}circle")]
        expected = [
            PALETTE[i % len(PALETTE)]
            for i, position in enumerate(result.positions)
            for p in _points(position.directions[side])
            if p.velocity_mm_min != 0
        ]
        assert circles == expected, side
        # a bar of ± std per point, a dashed linear fit per position
        assert len(panel.findall(f"{SVG}path")) == len(expected) + 1  # and the panel's frame
        dashed = panel.findall(f"{SVG}polyline[@stroke-dasharray='4 3']")
        assert len(dashed) == len(result.positions)
    texts = _texts(svg)
    assert "Axis Y: friction over velocity" in texts
    assert "negative direction" in texts and "positive direction" in texts
    assert "−1 000" in texts and "10 000" in texts  # the negative side's speeds signed
    for position in result.positions:
        assert f"position {position.position_index + 1}: " in texts
    assert "friction as motor current [A]" in texts or "friction torque [Nm]" in texts
    assert ' id="' not in curves_svg("Y", result)


def _direction_circles(
    result: AxisResult, svg: ET.Element, side: str
) -> tuple[list[Point], list[ET.Element]]:
    """The first position's points of one direction, slowest first, and their circles."""
    panel = svg.findall(f"{SVG}g")[0 if side == "negative" else 1]
    points = sorted(
        _points(result.positions[0].directions[side]), key=lambda p: abs(p.velocity_mm_min)
    )
    return points, panel.findall(f"{SVG}circle")[: len(points)]


def test_points_sit_where_their_values_are(fleet: Fleet) -> None:
    result = _axis(fleet, "M-100", "X")
    points, circles = _direction_circles(result, ET.fromstring(curves_svg("X", result)), "positive")
    xs = [float(c.get("cx", "nan")) for c in circles]
    ys = [float(c.get("cy", "nan")) for c in circles]
    assert xs == sorted(xs)  # faster: further right
    # y grows downwards: the highest friction is the smallest y
    highest = max(range(len(points)), key=lambda i: points[i].median)
    assert ys[highest] == min(ys)


def test_the_negative_direction_grows_to_the_left(fleet: Fleet) -> None:
    result = _axis(fleet, "M-100", "X")
    svg = ET.fromstring(curves_svg("X", result))
    _, circles = _direction_circles(result, svg, "negative")
    xs = [float(c.get("cx", "nan")) for c in circles]
    assert xs == sorted(xs, reverse=True)  # faster: further left
    negative = svg.findall(f"{SVG}g")[0]
    labels = [
        t.text or "" for t in negative.findall(f"{SVG}text") if t.get("text-anchor") == "middle"
    ]
    assert any(label.startswith("\u2212") for label in labels)  # the speeds signed


def test_a_point_that_is_not_a_number_is_left_out(fleet: Fleet) -> None:
    result = _axis(fleet, "M-100", "X")
    position = result.positions[0]
    direction = position.directions["positive"]
    assert direction is not None
    points = [direction.points[0].model_copy(update={"median": float("nan")})]
    broken = direction.model_copy(update={"points": points + list(direction.points[1:])})
    directions = {**position.directions, "positive": broken}
    first = position.model_copy(update={"directions": directions})
    odd = result.model_copy(update={"positions": [first, *result.positions[1:]]})
    text = curves_svg("X", odd)
    assert "nan" not in text
    ET.fromstring(text)


def test_a_direction_not_measured_says_so(fleet: Fleet) -> None:
    result = _axis(fleet, "M-100", "X")
    one_sided = result.model_copy(
        update={
            "positions": [
                p.model_copy(update={"directions": {**p.directions, "negative": None}})
                for p in result.positions
            ]
        }
    )
    svg = ET.fromstring(curves_svg("X", one_sided))
    negative = svg.findall(f"{SVG}g")[0]
    assert "not measured" in _texts(negative)
    assert negative.findall(f"{SVG}circle") == []


def test_friction_along_the_travel(fleet: Fleet) -> None:
    result = _axis(fleet, "M-101", "Y")
    dependency = result.position_dependency
    assert dependency is not None and dependency.identifiable
    text = travel_svg("Y", result, bearing_layout("Y", None, result))
    assert text is not None
    svg = ET.fromstring(text)
    texts = _texts(svg)
    assert "Axis Y: friction along the travel" in texts
    assert "fixed bearing" in texts and "loose bearing" in texts
    profiles = [p for p in dependency.profiles if p.velocity_mm_min is not None]
    thin = svg.findall(f".//{SVG}polyline[@stroke-width='0.9']")
    assert len(thin) == len(profiles)
    bold = svg.findall(f".//{SVG}polyline[@stroke-width='2.8']")
    assert len(bold) == 1 and bold[0].get("stroke") == PALETTE[1]
    # the slowest velocity's line light, the fastest dark
    slow = min(range(len(profiles)), key=lambda i: abs(profiles[i].velocity_mm_min or 0))
    fast = max(range(len(profiles)), key=lambda i: abs(profiles[i].velocity_mm_min or 0))

    def lightness(colour: str | None) -> int:
        assert colour is not None
        return sum(int(colour[k : k + 2], 16) for k in (1, 3, 5))

    assert lightness(thin[slow].get("stroke")) > lightness(thin[fast].get("stroke"))
    numbers = [
        t.text
        for t in svg.findall(f".//{SVG}text")
        if t.get("font-weight") == "bold" and t.text and t.get("fill") != "#fff"  # not the halo
    ]
    assert [n for n in numbers if n.isdigit()] == [
        str(p.position_index + 1) for p in result.positions
    ]
    scale = [r for r in svg.findall(f"{SVG}rect") if r.get("fill") != "#ffffff"]  # background
    assert len(scale) == 24  # the velocity scale
    assert ' id="' not in text


def test_no_travel_figure_without_its_analysis(fleet: Fleet) -> None:
    result = _axis(fleet, "M-100", "X")
    plain = result.model_copy(update={"position_dependency": None})
    assert travel_svg("X", plain, bearing_layout("X", None, plain)) is None


def test_drawing_the_friction_figures_imports_no_matplotlib(fleet: Fleet, tmp_path: Path) -> None:
    results = tmp_path / "results.json"
    results.write_text(fleet.of("M-101")[-1].results.model_dump_json())
    script = (
        "from ncmeasure.formats.results import Results\n"
        "from ncmeasure.report.bearings import bearing_layout\n"
        "from ncmeasure.report.friction_svg import curves_svg, travel_svg\n"
        f"axis = Results.model_validate_json(open({str(results)!r}).read()).axes['Y']\n"
        "assert curves_svg('Y', axis).startswith('<svg')\n"
        "assert travel_svg('Y', axis, bearing_layout('Y', None, axis)).startswith('<svg')\n"
    )
    assert matplotlib_loaded_by(script) == []
