"""The HTML report: the verdict first, self-contained, complete, escaped, rendered by a browser.

The example (tests/report/example.py) is a simulated recording of two axes
with results built from the pydantic models: X with friction rising towards
the loose bearing, Z vertical with a gravity offset. The healthy machine is
a synthetic recording analysed for real: X flat along the travel with a
Stribeck hump, Y with a dead current channel (skipped).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from pydantic import BaseModel

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.judgement.compare import compare_results
from ncmeasure.analysis.judgement.summary import axis_headline
from ncmeasure.formats.comparison import Comparison
from ncmeasure.formats.results import (
    AxisResult,
    Cause,
    LinearFit,
    PositionDependency,
    RecordingInfo,
    Results,
)
from ncmeasure.recording import Recording
from ncmeasure.report import (
    PALETTE,
    ReportProgress,
    bearing_layout,
    comparison_svg,
    curves_svg,
    travel_svg,
    write_report,
)
from ncmeasure.report.curves import linear_curve, linear_spans
from ncmeasure.report.words import CAUSE_TITLES, format_mm, format_number, format_with_error
from tests.browser import pixels_like, screenshot
from tests.report.example import (
    DEAD_Y_REASON,
    Window,
    build_results,
    cut_windows,
    healthy_recording,
    simulate,
)

_SIDES: tuple[tuple[Literal["positive", "negative"], float], ...] = (
    ("positive", 1.0),
    ("negative", -1.0),
)


@dataclass(frozen=True)
class Example:
    recording: Recording
    windows: dict[str, list[Window]]
    results: Results
    comparison: Comparison


@pytest.fixture(scope="module")
def example(tmp_path_factory: pytest.TempPathFactory) -> Example:
    recording, windows = simulate(tmp_path_factory.mktemp("recording") / "run1")
    results = build_results(recording, windows)
    # a re-measurement in which X lost a fifth of its friction (preload loss)
    later = results.model_copy(
        update={
            "recording": results.recording.model_copy(update={"directory": "run2"}),
            "axes": {**results.axes, "X": _scaled(results.axes["X"], 0.8)},
        }
    )
    comparison = compare_results(results, [later], labels=["delivery", "service 2027"])
    return Example(recording, windows, results, comparison)


def _scaled(axis: AxisResult, factor: float) -> AxisResult:
    """The axis with its points' medians times ``factor``, and its lines with them (the line
    through scaled points is the scaled line)."""

    def line(fit: LinearFit | None) -> LinearFit | None:
        if fit is None:
            return None
        names = ("coulomb", "viscous_per_mm_min", "coulomb_stderr", "viscous_stderr")
        values = {name: getattr(fit, name) for name in names}
        scaled = {name: None if v is None else v * factor for name, v in values.items()}
        return fit.model_copy(update=scaled)

    positions = []
    for position in axis.positions:
        directions = {
            name: None
            if found is None
            else found.model_copy(
                update={
                    "points": [
                        p.model_copy(update={"median": p.median * factor}) for p in found.points
                    ],
                    "fit": line(found.fit),
                }
            )
            for name, found in position.directions.items()
        }
        positions.append(position.model_copy(update={"directions": directions}))
    offset = axis.offset
    if offset is not None:  # the offset is part of the medians: it scales with them
        offset = offset.model_copy(update={"value": offset.value * factor})
    return axis.model_copy(update={"positions": positions, "offset": offset})


@pytest.fixture(scope="module")
def report(example: Example, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("report")
    return write_report(
        example.results,
        out / "friction.html",
        recording=example.recording,
        windows=cut_windows(example.windows),
        comparison=example.comparison,
    )


@pytest.fixture(scope="module")
def healthy(tmp_path_factory: pytest.TempPathFactory) -> Results:
    """A correctly assembled machine, analysed: X ok, Y skipped (dead current channel).

    One curve of X is made to look like the demo's: the straight line over all
    speeds rejected (χ²ᵣ 138) because of the Stribeck hump, which the Stribeck
    model describes. That is friction, not a fault.
    """
    directory = tmp_path_factory.mktemp("healthy") / "run"
    recording, schedule = healthy_recording(directory)
    results = analyze(recording, schedule=schedule)
    x = results.axes["X"]
    first = x.positions[0]
    found = first.directions["positive"]
    assert found is not None and found.fit is not None
    rejected = found.model_copy(
        update={
            "fit": found.fit.model_copy(update={"chi2_reduced": 138.3, "accepted": False}),
            "model": "stribeck",
        }
    )
    positions = [
        first.model_copy(update={"directions": {**first.directions, "positive": rejected}}),
        *x.positions[1:],
    ]
    return results.model_copy(update={"axes": {"X": x.model_copy(update={"positions": positions})}})


_SVG = "{http://www.w3.org/2000/svg}"
_NAMESPACE = ' xmlns="http://www.w3.org/2000/svg"'


def _figures(page: str) -> list[str]:
    """The SVG figures embedded in a page."""
    return re.findall(r"<svg .*?</svg>", page, flags=re.DOTALL)


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


ALARM_CLASSES = {
    "no",
    "level-check",
    "level-fault",
    "verdict-check",
    "verdict-fault",
    "status-warning",
    "status-critical",
    "lost-many",
}
"""Classes that colour something amber or red."""


def _classes(page: str) -> set[str]:
    return {c for found in re.findall(r'class="([^"]*)"', page) for c in found.split()}


def _before_first_axis(page: str) -> str:
    return page.split('<section class="axis"', 1)[0]


def _verdict_rows(page: str) -> dict[str, str]:
    """The rows of the verdict table by axis name (the HTML of each row)."""
    table = page.split('<table class="verdicts">', 1)[1].split("</table>", 1)[0]
    rows = re.findall(r"<tr><td>(.*?)</tr>", table, re.DOTALL)
    return {re.sub(r"<[^>]+>", "", row.split("</td>", 1)[0]): row for row in rows}


def _without_details(page: str) -> str:
    return re.sub(r"<details.*?</details>", "", page, flags=re.DOTALL)


# --- the file --------------------------------------------------------------------------


def test_report_is_one_self_contained_file(report: Path) -> None:
    page = _text(report)
    assert page.startswith("<!DOCTYPE html>")
    assert not re.search(r"https?:", page, re.IGNORECASE), "no link to the outside"
    assert "<script" not in page.lower()
    assert "<link" not in page.lower()
    assert "url(" not in page and "@import" not in page
    assert not re.search(r"""src\s*=""", page), "no image from elsewhere"
    figures = _figures(page)
    assert len(figures) == 2 * 3 + 1  # three plots per axis and the comparison
    for svg in figures:
        ET.fromstring(svg)  # well-formed (in the page without its namespace: HTML implies it)
        assert ' id="' not in svg  # any number of them share the page
    assert not re.search(r"""href\s*=\s*["'](?!#)""", page), "only links inside the page"


def test_embedded_figures_are_the_svgs_beside_the_report(report: Path) -> None:
    plots = report.parent / "friction_plots"
    files = sorted(p.name for p in plots.iterdir())
    assert files == [
        "01_X_raw.svg",
        "01_X_stribeck.svg",
        "01_X_travel.svg",
        "02_Z_raw.svg",
        "02_Z_stribeck.svg",
        "02_Z_travel.svg",
        "comparison.svg",
    ]
    # in the page, each is named for screen readers by its alt text
    embedded = sorted(re.sub(r' aria-label="[^"]*"', "", svg) for svg in _figures(_text(report)))
    assert embedded == sorted(
        (plots / name).read_text(encoding="utf-8").replace(_NAMESPACE, "", 1) for name in files
    )
    for name in files:  # a file on its own names SVG's namespace
        assert ET.fromstring((plots / name).read_text(encoding="utf-8")).tag == f"{_SVG}svg"
    assert 'aria-label="Friction over velocity of axis X"' in _text(report)


def test_report_has_every_section(report: Path) -> None:
    page = _text(report)
    for heading in (
        "<h2>Verdict</h2>",
        "<h2>Summary</h2>",
        # X's own pattern is a fault; the comparison shows it unchanged, and its -20 %
        # beyond the warning limit: check
        '<h2>Axis X <span class="badge level-check">check</span></h2>',
        '<h2>Axis Z <span class="badge level-ok">ok</span></h2>',
        "<h3>Friction over velocity</h3>",
        "<h3>Friction along the travel</h3>",
        "<h3>Diagnosis</h3>",
        "<h3>Offset (gravity or bias)</h3>",
        "<h3>Which model describes each curve</h3>",
        "<h3>Raw data</h3>",
        "<h2>Comparison</h2>",
        "<summary>Analysis settings (",
    ):
        assert heading in page, heading
    assert page.count("<h3>Friction over velocity</h3>") == 2
    assert not re.search(r"&lt;/?(p|span|strong|ul|li|br|table|td|a|div)\b", page), "escaped twice"
    assert "(friction_plots/01_X_stribeck.svg)" in page
    assert "HMX-400" in page
    assert "2026-01-15 08:30 UTC" in page  # recorded


def test_report_shows_the_numbers(report: Path, example: Example) -> None:
    page = _text(report)
    x = example.results.axes["X"]
    dependency = x.position_dependency
    assert dependency is not None
    # every linear fit, Coulomb ± stderr and viscous per m/min ± stderr
    for position in x.positions:
        for found in position.directions.values():
            assert found is not None and found.fit is not None
            fit = found.fit
            assert format_with_error(fit.coulomb, fit.coulomb_stderr) in page
            assert (
                format_with_error(fit.viscous_per_mm_min * 1000, fit.viscous_stderr * 1000) in page
            )
            assert format_number(fit.chi2_reduced) in page
    # the diagnosis in words, the causes best first with their evidence
    assert f"{dependency.spread_percent:.0f} % spread, rises towards the loose bearing" in page
    assert "Friction rises as the nut moves towards the loose bearing." in page
    titles = [CAUSE_TITLES[c.cause] for c in dependency.causes]
    x_section = page.split('id="axis-1"', 1)[1].split("</section>", 1)[0]
    found_at = [x_section.index(t) for t in titles]
    assert found_at == sorted(found_at), "causes best first"
    assert "the highest value is at 690 mm" in page
    assert "fixed bearing at the min end (0 mm), loose bearing at the max end (750 mm)" in page
    # the gravity offset of Z, taken out of the fits: both directions are friction
    z = example.results.axes["Z"]
    assert z.offset is not None
    assert format_with_error(z.offset.value, z.offset.stderr) + " Nm" in page
    coulombs = []
    for position in z.positions:
        both = [d.fit.coulomb for d in position.directions.values() if d and d.fit]
        assert all(c is not None and 0 < c < abs(z.offset.value) for c in both)
        coulombs.append(sum(c for c in both if c is not None) / len(both))
    assert f"{format_number(float(np.mean(coulombs)))} Nm" in page
    # the comparison: the run and its finding
    assert "service 2027" in page
    assert "preload loss" in page
    assert "critical" in page
    # and the likely cause of the change per axis
    causes = page.split("Likely cause of the change", 1)[1].split("</table>", 1)[0]
    assert "-20.0 %" in causes
    assert CAUSE_TITLES["preload_or_carriage"] in causes
    assert CAUSE_TITLES["none"] in causes  # axis Z did not change


def test_escapes_names_from_files(example: Example, tmp_path: Path) -> None:
    x = example.results.axes["X"]
    assert x.position_dependency is not None
    evil = "<script>alert(1)</script>"
    dependency = x.position_dependency.model_copy(
        update={
            "causes": [
                Cause(cause="loose_bearing", score=0.7, evidence='rises "a lot" <b>& more</b>')
            ]
        }
    )
    results = example.results.model_copy(
        update={
            "recording": RecordingInfo(
                directory="/data/<img src=x onerror=alert(1)>",
                machine=evil,
                start_utc=None,
                config_hash=None,
                source="import:csv",
            ),
            "axes": {"A$1<&>\x01": x.model_copy(update={"position_dependency": dependency})},
            "settings": {"<i>": "</td>"},
        }
    )
    path = write_report(results, tmp_path / "evil.html")
    page = _text(path)
    assert evil not in page
    assert "<script" not in page.lower()
    assert "<img src=x" not in page and "<b>" not in page and "<i>" not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert "rises &#34;a lot&#34; &lt;b&gt;&amp; more&lt;/b&gt;" in page
    assert "Axis A$1&lt;&amp;&gt;" in page
    names = sorted(p.name for p in (tmp_path / "evil_plots").iterdir())
    assert names == ["01_A_1_stribeck.svg", "01_A_1_travel.svg"]
    for name in names:  # XML, the control character shown as U+FFFD
        figure = ET.fromstring((tmp_path / "evil_plots" / name).read_text(encoding="utf-8"))
        assert "Axis A$1<&>\ufffd: friction" in "".join(figure.itertext())
    assert 'aria-label="Friction over velocity of axis A$1&lt;&amp;&gt;\ufffd"' in page
    assert "No recording was given" in page


def test_the_report_imports_no_matplotlib(example: Example, tmp_path: Path) -> None:
    """Every figure of the report, the comparison's and the raw data's included, is SVG
    written directly: writing a report loads no matplotlib."""
    from tests.web.conftest import matplotlib_loaded_by

    results, comparison = tmp_path / "results.json", tmp_path / "comparison.json"
    results.write_text(example.results.model_dump_json(), encoding="utf-8")
    comparison.write_text(example.comparison.model_dump_json(), encoding="utf-8")
    script = (
        "from pathlib import Path\n"
        "from ncmeasure.formats.comparison import Comparison\n"
        "from ncmeasure.formats.results import Results\n"
        "from ncmeasure.recording import Recording\n"
        "from ncmeasure.report import write_report\n"
        f"results = Results.model_validate_json(Path({str(results)!r}).read_text())\n"
        f"comparison = Comparison.model_validate_json(Path({str(comparison)!r}).read_text())\n"
        f"recording = Recording.open({str(example.recording.directory)!r})\n"
        f"page = write_report(results, {str(tmp_path / 'r.html')!r}, recording=recording,\n"
        "                    comparison=comparison).read_text()\n"
        "assert page.count('<svg') == 7, page.count('<svg')\n"
    )
    assert matplotlib_loaded_by(script) == []


def test_progress_is_reported(example: Example, tmp_path: Path) -> None:
    seen: list[ReportProgress] = []
    write_report(
        example.results,
        tmp_path / "r.html",
        recording=example.recording,
        windows=cut_windows(example.windows),
        on_progress=seen.append,
    )
    assert [p.done for p in seen] == list(range(1, 8))
    assert {p.total for p in seen} == {7}
    assert seen[0].step == "axis X: Stribeck curves"
    assert seen[-1].step == "report page"


def test_windows_are_found_when_not_given(example: Example, tmp_path: Path) -> None:
    page = _text(write_report(example.results, tmp_path / "r.html", recording=example.recording))
    assert page.count("found again in the recording") == 2


def test_any_comparison_model_is_shown(example: Example, tmp_path: Path) -> None:
    class Finding(BaseModel):
        axis: str
        change_percent: float

    class OtherComparison(BaseModel):
        summary: str
        findings: list[Finding]
        reference: str

    other = OtherComparison(
        summary="Axis X lost 25 % <friction>",
        findings=[Finding(axis="X", change_percent=-25.04)],
        reference="delivery 2026",
    )
    page = _text(write_report(example.results, tmp_path / "r.html", comparison=other))
    assert "<h2>Comparison</h2>" in page
    assert "Axis X lost 25 % &lt;friction&gt;" in page
    assert "-25.0" in page and "delivery 2026" in page


def test_plots_without_optional_parts(example: Example) -> None:
    x = example.results.axes["X"]
    bare = x.model_copy(
        update={
            "positions": [
                p.model_copy(update={"directions": {"positive": p.directions["positive"]}})
                for p in x.positions
            ],
            "offset": None,
        }
    )
    svg = ET.fromstring(curves_svg("X", bare))
    assert "not measured" in "".join(svg.itertext())  # the negative side
    dependency = x.position_dependency
    assert isinstance(dependency, PositionDependency)
    assert travel_svg("X", x, bearing_layout("X")) is not None
    assert (
        travel_svg("X", x.model_copy(update={"position_dependency": None}), bearing_layout("X"))
        is None
    )


def test_the_comparison_figure_has_a_row_per_place_and_a_point_per_run(example: Example) -> None:
    comparison = example.comparison
    svg = ET.fromstring(comparison_svg(comparison))
    texts = "".join(svg.itertext())
    assert f"Comparison with {comparison.base}" in texts
    keys = {(g.axis, g.position_index, g.direction) for g in comparison.groups}
    for axis, index, direction in keys:
        assert re.search(rf"{axis} · {index + 1}: -?[\d.]+ mm · {direction}", texts)
    points = svg.findall(f"{_SVG}circle")  # the legend's are in its entries' groups
    assert len(points) == len(comparison.groups)
    assert len(svg.findall(f"{_SVG}g/{_SVG}circle")) == len({g.label for g in comparison.groups})
    labels = list(dict.fromkeys(g.label for g in comparison.groups))
    rims = {"ok": "#ffffff", "warning": "#e07b00", "critical": "#c0392b"}
    ordered = sorted(comparison.groups, key=lambda g: labels.index(g.label))
    assert [c.get("fill") for c in points] == [PALETTE[labels.index(g.label)] for g in ordered]
    assert [c.get("stroke") for c in points] == [rims[g.status] for g in ordered]
    assert {g.status for g in ordered} - {"ok"}, "a rim other than white is checked"
    # further from zero is further from the middle line, on its side
    zero = next(
        float(line.get("x1", "nan"))
        for line in svg.findall(f"{_SVG}line")
        if line.get("stroke") == "#555555"
    )
    for circle, group in zip(points, ordered, strict=True):
        side = float(circle.get("cx", "nan")) - zero
        assert np.sign(side) == np.sign(group.median_deviation_percent) or abs(side) < 0.1


def test_the_comparison_figure_bands_and_ticks(example: Example) -> None:
    """Left to right: critical, warning, within, warning, critical; the tick values grow to
    the right, negative left of zero with a minus sign."""
    svg = ET.fromstring(comparison_svg(example.comparison))
    bands = sorted(
        (float(r.get("x", "nan")), r.get("fill"))
        for r in svg.findall(f"{_SVG}rect")
        if r.get("fill-opacity")
    )
    assert [fill for _, fill in bands] == ["#c0392b", "#e07b00", "#2e8b3e", "#e07b00", "#c0392b"]
    limits = example.comparison.limits
    ticks = [
        (float(t.get("x", "nan")), float((t.text or "").replace("\u2212", "-")))
        for t in svg.findall(f"{_SVG}text")
        if t.get("text-anchor") == "middle" and re.fullmatch(r"\u2212?\d+", t.text or "")
    ]
    assert len(ticks) >= 5 and [v for _, v in ticks] == sorted(v for _, v in ticks)
    assert [x for x, _ in ticks] == sorted(x for x, _ in ticks)
    zero = next(x for x, v in ticks if v == 0)
    scale = (ticks[-1][0] - zero) / ticks[-1][1]
    # the warning band starts where −warning % lies on that scale
    assert bands[1][0] == pytest.approx(zero - scale * limits.critical_percent, abs=0.15)
    assert bands[2][0] == pytest.approx(zero - scale * limits.warning_percent, abs=0.15)


def test_the_comparison_figure_escapes_its_labels(example: Example) -> None:
    evil = example.comparison.model_copy(
        update={
            "base": "<b>base</b>\x1f",
            "groups": [
                g.model_copy(update={"label": "<script>x</script>\x00", "axis": "X<i>"})
                for g in example.comparison.groups
            ],
        }
    )
    text = comparison_svg(evil)
    assert "<script>" not in text and "<b>" not in text and "<i>" not in text
    svg = ET.fromstring(text)  # XML: the control characters shown as U+FFFD
    texts = "".join(svg.itertext())
    assert "Comparison with <b>base</b>\ufffd" in texts and "X<i> · 1: " in texts
    assert "<script>x</script>\ufffd" in texts


def test_the_trend_png_holds_the_pixels_savefig_draws() -> None:
    """``store trend --plot``'s figure through figure_png: the pixels of matplotlib's
    savefig, RGB at 110 dpi, on its Agg canvas and through savefig on any other."""
    import datetime as dt
    import io

    from matplotlib.backend_bases import FigureCanvasBase
    from PIL import Image

    from ncmeasure.report.plots import DPI, figure_png, plot_trend

    start = dt.datetime(2026, 1, 1, tzinfo=dt.UTC)

    def make() -> Any:
        return plot_trend(
            "X",
            [start + dt.timedelta(days=90 * n) for n in range(4)],
            [("Coulomb friction", "A", [1.0, 1.04, None, 1.2]), ("spread", "%", [3, 4, 6, 5])],
            baseline_index=0,
            warning_percent=10,
            critical_percent=20,
            labels=["delivery", None, None, "service"],
        )

    reference = make()
    raw = io.BytesIO()
    reference.savefig(raw, format="rgba", dpi=DPI, facecolor="white")
    width, height = reference.canvas.get_width_height(physical=True)
    drawn = np.frombuffer(raw.getvalue(), np.uint8).reshape(height, width, 4)[:, :, :3]
    image = Image.open(io.BytesIO(figure_png(make())))
    assert image.mode == "RGB"
    assert [round(d) for d in image.info["dpi"]] == [DPI, DPI]
    assert np.array_equal(np.asarray(image), drawn)
    other = make()
    FigureCanvasBase(other)  # not an Agg canvas: drawn through savefig
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(figure_png(other)))), drawn)


def test_fit_lines_follow_the_points(example: Example) -> None:
    """The negative direction's line is negative; Z's offset shifts it where the points are."""
    for name in ("X", "Z"):
        axis = example.results.axes[name]
        offset = axis.offset.value if axis.offset else None
        for position in axis.positions:
            for key, sign in _SIDES:
                found = position.directions[key]
                assert found is not None and found.fit is not None
                fast = [p for p in found.points if abs(p.velocity_mm_min) >= 800]
                velocity = np.array([p.velocity_mm_min for p in fast])
                line = linear_curve(found.fit, velocity, sign, fast, offset)
                medians = np.array([p.median for p in fast])
                assert np.max(np.abs(line - medians)) < 0.05


def test_a_fit_line_spans_its_speeds_and_is_extrapolated_down_to_the_slowest(
    example: Example,
) -> None:
    """Both back-ends draw a fit over these speeds: its own span from the slowest drawn
    on, and, lighter, from the slowest up to where it was fitted."""
    fit = next(
        d.fit
        for position in example.results.axes["X"].positions
        for d in position.directions.values()
        if d is not None and d.fit is not None
    )
    low, high = fit.velocity_range_mm_min
    inside, below = linear_spans(fit, low / 10, 40)
    assert (inside[0], inside[-1], inside.size) == pytest.approx((low, high, 40))
    assert below is not None
    assert (below[0], below[-1], below.size) == pytest.approx((low / 10, low, 20))
    inside, below = linear_spans(fit, low * 2, 40)  # fitted below the figure's start
    assert inside[0] == pytest.approx(low * 2) and inside[-1] == pytest.approx(high)
    assert below is None


def test_numbers_for_technicians() -> None:
    assert format_number(1.6234) == "1.62"
    assert format_number(7500.4) == "7500"
    assert format_number(0.01234) == "0.0123"
    assert format_number(float("nan")) == "–"
    assert format_with_error(1.5103, 0.0021) == "1.510 ± 0.002"
    assert format_with_error(1.51, 0.3) == "1.51 ± 0.30"
    assert format_with_error(-0.000292, 0.000752) == "-0.00029 ± 0.00075"
    assert format_with_error(-0.0001, 0.02) == "0.000 ± 0.020"
    assert format_mm(61.506) == "61.5"
    assert format_mm(750.0) == "750"
    assert format_mm(-0.04) == "0"


# --- the verdict first -----------------------------------------------------------------


def test_healthy_machine_reads_ok_without_alarm(healthy: Results, tmp_path: Path) -> None:
    page = _text(write_report(healthy, tmp_path / "healthy.html"))
    # the verdict comes before anything else: right after the title
    assert page.index('<section class="verdict">') < page.index('<dl class="facts">')
    rows = _verdict_rows(page)
    assert set(rows) == {"X", "Y"}
    assert '<span class="badge level-ok">ok</span>' in rows["X"]
    assert "No assembly fault shows" in rows["X"] and "What to do: None." in rows["X"]
    # the skipped axis, with its reason
    assert '<span class="badge level-skipped">not analysed</span>' in rows["Y"]
    assert DEAD_Y_REASON in rows["Y"]
    # nothing amber or red, no "no" anywhere: the rejected straight line of a Stribeck
    # curve is not a failure
    assert not _classes(page) & ALARM_CLASSES, _classes(page) & ALARM_CLASSES
    assert not re.search(r">\s*no\s*<", page)
    assert "Accepted" not in page and "Fits accepted" not in page
    models = page.split("<h3>Which model describes each curve</h3>", 1)[1].split("</table>")[0]
    assert models.count("<strong>Stribeck</strong>") == 6
    assert "138" in models  # the line's χ²ᵣ is shown, plainly


def test_the_page_never_follows_a_planted_temporary_file(healthy: Results, tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me", encoding="utf-8")
    (tmp_path / ".page.html.tmp").symlink_to(victim)
    write_report(healthy, tmp_path / "page.html")
    assert victim.read_text(encoding="utf-8") == "keep me"
    assert (tmp_path / ".page.html.tmp").is_symlink()
    assert "<html" in (tmp_path / "page.html").read_text(encoding="utf-8")


def test_faulty_axis_reads_fault_with_reason(
    report: Path, example: Example, tmp_path: Path
) -> None:
    x = example.results.axes["X"]
    assert x.verdict.level == "fault"
    page = _text(write_report(example.results, tmp_path / "alone.html"))
    top = _before_first_axis(page)
    row = _verdict_rows(top)["X"]
    assert '<span class="badge level-fault">fault</span>' in row
    assert x.verdict.reason in row
    assert f"What to do: {x.verdict.action}" in row
    assert "level-fault" in _classes(page)  # the alarm check above can fail
    # against a reference in which the pattern was the same, the pattern is the machine's
    # own fingerprint: the change is judged (-20 %, beyond the warning limit), not it
    row = _verdict_rows(_before_first_axis(_text(report)))["X"]
    assert '<span class="badge level-check">check</span>' in row
    assert "beyond the warning limit" in row


def test_comparison_comes_first_and_combines_the_verdict(example: Example, tmp_path: Path) -> None:
    """Z is fine on its own but lost 15 % against the reference: check, for that reason."""
    results = example.results
    later = results.model_copy(
        update={"axes": {**results.axes, "Z": _scaled(results.axes["Z"], 0.85)}}
    )
    comparison = compare_results(results, [later], labels=["delivery", "service 2027"])
    page = _text(write_report(later, tmp_path / "r.html", comparison=comparison))
    verdict = page.index('<section class="verdict">')
    compared = page.index('<section class="comparison">')
    summary = page.index('<section class="summary">')
    first_axis = page.index('<section class="axis"')
    assert verdict < compared < summary < first_axis
    rows = _verdict_rows(page)
    assert later.axes["Z"].verdict.level == "ok"
    assert '<span class="badge level-check">check</span>' in rows["Z"]
    assert re.search(
        r"Against the reference: friction -15\.0 % on average, alike along the travel; "
        r"at most -15\.0 % at position \d \(-?\d+ mm\), \w+, beyond the warning limit; "
        r"likely a preload loss of the ball-screw nut or the bearings",
        rows["Z"],
    ), rows["Z"]
    assert '<span class="status-warning">warning</span>' in rows["Z"]
    # X's own fault is its pattern along the travel, which did not change: no change, but a
    # fault-sized pattern to confirm against the reference (check, not fault)
    assert '<span class="badge level-check">check</span>' in rows["X"]
    assert "not a change, but as strong as a fault on its own" in rows["X"]
    assert '<span class="status-ok">ok</span>' in rows["X"]
    # the axis section says the same as the verdict table
    z_section = page.split('id="axis-2"', 1)[1]
    assert '<h2>Axis Z <span class="badge level-check">check</span></h2>' in z_section


def test_gaps_are_visible_in_the_header(healthy: Results, tmp_path: Path) -> None:
    info = healthy.recording
    assert info.gaps == 0 and info.status == "complete"
    page = _text(write_report(healthy, tmp_path / "r.html"))
    assert "<dt>Status</dt><dd>complete, no sample lost</dd>" in _before_first_axis(page)
    samples = info.samples
    assert samples is not None and info.duration_s is not None
    assert f"<dt>Samples</dt><dd>{samples} over {info.duration_s:.0f} s</dd>" in page
    lossy = healthy.model_copy(
        update={
            "recording": info.model_copy(
                update={"gaps": 27, "gap_samples": 324, "gap_share": 324 / (samples + 324)}
            )
        }
    )
    page = _text(write_report(lossy, tmp_path / "r.html"))
    share = 324 / (samples + 324) * 100
    header = _without_details(_before_first_axis(page))
    assert f"<dd>complete, 27 gaps: 324 samples, {share:.1f} % lost</dd>" in header
    many = healthy.model_copy(
        update={
            "recording": info.model_copy(
                update={"gaps": 300, "gap_samples": 5000, "gap_share": 0.18}
            )
        }
    )
    page = _text(write_report(many, tmp_path / "r.html"))
    assert '<span class="lost-many">complete, 300 gaps: 5000 samples, 18.0 % lost</span>' in page
    skipping = healthy.model_copy(
        update={
            "recording": info.model_copy(
                update={
                    "gaps": 2, "gap_samples": 324, "gap_share": 324 / (samples + 324),
                    "skipped_cycles": 300,
                }
            )
        }
    )  # fmt: skip
    page = _text(write_report(skipping, tmp_path / "r.html"))
    skipped = 300 / (samples + 324) * 100
    assert (
        f"<dd>complete, 2 gaps: 324 samples, {share:.1f} % lost; 300 cycles of them skipped "
        f"by the link (the host fell behind), {skipped:.1f} % of the recording</dd>"
    ) in _without_details(_before_first_axis(page))


def test_notes_are_folded_away_with_their_count(report: Path, example: Example) -> None:
    page = _text(report)
    blocks = re.findall(r"<details([^>]*)><summary>(.*?)</summary>(.*?)</details>", page, re.S)
    assert blocks
    assert all("open" not in attributes for attributes, _, _ in blocks), "closed by default"
    summaries = {summary: body for _, summary, body in blocks}
    z_notes = next(body for summary, body in summaries.items() if "Notes on axis Z" in summary)
    counted = re.search(r"Notes on axis Z \((\d+)\)", " ".join(summaries))
    assert counted is not None
    assert int(counted[1]) == z_notes.count("<li>") >= 1
    assert any(summary.startswith("Analysis settings (") for summary in summaries)
    # every warning is in the page, but only inside a closed block
    outside = _without_details(page)
    for axis in example.results.axes.values():
        for warning in axis.warnings:
            escaped = warning.replace("'", "&#39;")
            assert escaped in page
            assert escaped not in outside


def test_positions_are_numbered_alike(healthy: Results, tmp_path: Path) -> None:
    page = _text(write_report(healthy, tmp_path / "r.html"))
    x = healthy.axes["X"]
    labels = {p.position_index + 1: p.position_mm for p in x.positions}
    assert labels == {1: 50.0, 2: 375.0, 3: 700.0}
    models = page.split("<h3>Which model describes each curve</h3>", 1)[1].split("</table>")[0]
    for number, mm in labels.items():
        label = f"{number}:\u00a0{format_mm(mm)}\u00a0mm"
        assert models.count(label) == 2, label  # both directions
        assert label in page.split("<dt>Positions</dt>", 1)[1].split("</dd>", 1)[0]
    # the diagnosis' evidence names them the same way: "position 2 (375 mm)"
    assert x.position_dependency is not None
    mentioned = re.findall(r"position (\d+) \((-?[\d.]+) mm\)", page)
    assert mentioned
    for number, mm in mentioned:
        assert abs(labels[int(number)] - float(mm)) < 1, (number, mm)
    # and the plot along the travel
    travel = travel_svg("X", x, bearing_layout("X", result=x))
    assert travel is not None
    texts = list(ET.fromstring(travel).iter(f"{_SVG}text"))
    ticks = [t.text for t in texts if t.text and " mm" in t.text]
    assert ticks == ["1: 50 mm", "2: 375 mm", "3: 700 mm"]
    numbers = [
        t.text
        for t in texts
        if t.get("font-weight") == "bold" and (t.text or "").isdigit() and t.get("fill") != "#fff"
    ]
    assert numbers == ["1", "2", "3"]


def test_comparison_numbers_positions_alike(report: Path, example: Example) -> None:
    page = _text(report)
    section = page.split('<section class="comparison">', 1)[1].split("</section>", 1)[0]
    for group in example.comparison.groups:
        label = f"{group.position_index + 1}:\u00a0{format_mm(group.position_mm)}\u00a0mm"
        assert label in section
    places = {
        (p.position_index + 1, p.position_mm)
        for axis in example.results.axes.values()
        for p in axis.positions
    }
    mentioned = re.findall(r"position (\d+) \((-?[\d.]+) mm\)", section)
    assert mentioned  # the change in words: "at most -20.0 % at position 3 (690 mm), ..."
    for number, mm in mentioned:
        assert any(n == int(number) and abs(x - float(mm)) < 1 for n, x in places), (number, mm)


def test_report_headline_is_the_summary_function(report: Path, example: Example) -> None:
    page = _text(report)
    for name, axis in example.results.axes.items():
        figure = axis_headline(axis).coulomb_text
        assert figure in _verdict_rows(page)[name]
        assert f'<span class="headline">Coulomb friction {figure}</span>' in page


# --- in a browser ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def plain_report(example: Example, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The example's report without a comparison: the first axis follows the summary."""
    out = tmp_path_factory.mktemp("plain")
    return write_report(
        example.results,
        out / "friction.html",
        recording=example.recording,
        windows=cut_windows(example.windows),
    )


def test_chromium_renders_the_plots(plain_report: Path, tmp_path: Path) -> None:
    image = screenshot(plain_report, tmp_path, 2400)
    assert image.shape == (2400, 1280, 3)
    ink = np.any(image < 0.94, axis=2)
    assert ink.mean() > 0.04, f"only {ink.mean():.1%} of the page is not white: blank?"
    # the plot colours reach the screen: positions 1-3 of the Stribeck curves,
    # the average along the travel (the page's own CSS uses none of them)
    for colour in PALETTE[:3]:
        assert pixels_like(image, colour) > 400, colour
    # the first axis' Stribeck plot is inside the first 2400 px, below the verdict,
    # the recording and the summary, and it is a plot (hundreds of rows), not a stray pixel
    rows_with_blue = np.flatnonzero(
        np.all(np.abs(image - np.array([0x1F, 0x5F, 0xA8]) / 255) <= 0.06, axis=2).any(axis=1)
    )
    assert 600 < rows_with_blue.min() < 1900
    assert rows_with_blue.max() - rows_with_blue.min() > 300


def test_chromium_without_figures_has_no_plot_colours(plain_report: Path, tmp_path: Path) -> None:
    """The colour check above is not fooled by the page itself: without images it fails."""
    bare = tmp_path / "bare.html"
    bare.write_text(
        re.sub(r"<svg .*?</svg>", "", _text(plain_report), flags=re.DOTALL), encoding="utf-8"
    )
    image = screenshot(bare, tmp_path, 2400)
    assert all(pixels_like(image, colour) < 50 for colour in PALETTE[:3])


def test_a_trapezoid_trace_reads_check_without_a_cause(healthy: Results, tmp_path: Path) -> None:
    """Each speed at its own positions: the page says so, names no cause, shows the line."""
    from tests.analysis.test_layout import axis_result, trapezoid

    results = healthy.model_copy(update={"axes": {"X": axis_result(trapezoid())}})
    page = _text(write_report(results, tmp_path / "trapezoid.html"))
    rows = _verdict_rows(page)
    assert '<span class="badge level-check">check</span>' in rows["X"]
    assert "each speed was measured at its own positions" in rows["X"]
    assert "Guide rail" not in page and "guide rail" not in page
    assert "positions pooled" in page
