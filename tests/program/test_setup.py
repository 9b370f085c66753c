"""The setup sheet beside the programs: what it says is what the programs do.

Every number of SETUP.md is read back from the text and held against the same
quantity computed here another way: the envelope of an axis from schedule.json
(park, warm-up over the usable travel, every run's start and stop) and from the
programs as ncmeasure's reader runs them; the duration from schedule.json.
"""

from __future__ import annotations

import html.parser
import json
import re
import subprocess
import tomllib
from pathlib import Path
from typing import Any

import pytest
from markdown_it import MarkdownIt
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import parse_machine
from ncmeasure.errors import OutputError
from ncmeasure.program import check_programs, generate_programs, load_dialect
from ncmeasure.program.check import read_generated
from tests.browser import chromium_or_skip
from tests.conftest import DIALECTS, FIXED_TIME, machine_toml, small_data

runner = CliRunner()

ROW = re.compile(
    r"^\| (?P<axis>\w+) \| (?P<low>-?[\d.]+) \| (?P<high>-?[\d.]+) \| (?P<park>-?[\d.]+) "
    r"\| (?P<soft_low>-?[\d.]+) … (?P<soft_high>-?[\d.]+) \| (?P<feed>[\d.]+) "
    r"\| (?P<rapid>[\d.]+) \|$",
    re.M,
)
DURATION = re.compile(r"\*\*Duration: (\d+) min (\d+) s \((\d+) s\)\*\*")


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def generate(tmp_path: Path, text: str, out: str = "out") -> tuple[Path, str]:
    machine = tmp_path / "m.toml"
    machine.write_text(text, encoding="utf-8")
    code, stdout, stderr = run("generate", machine, "-o", tmp_path / out)
    assert code == 0, stdout + stderr
    return tmp_path / out, stdout


def sheet_rows(text: str) -> dict[str, dict[str, float]]:
    return {
        m["axis"]: {key: float(value) for key, value in m.groupdict().items() if key != "axis"}
        for m in ROW.finditer(text)
    }


def schedule_envelope(axis: dict[str, Any]) -> tuple[float, float]:
    """Where the schedule says the axis goes: park, warm-up strokes, each run."""
    positions = [axis["park_mm"]]
    if axis["warmup_strokes"]:
        positions += axis["usable_mm"]
    for window in axis["windows"]:
        positions += [window["start_mm"], window["stop_mm"]]
    return min(positions), max(positions)


def program_envelopes(folder: Path) -> dict[str, tuple[float, float, float]]:
    """Lowest and highest target and fastest feed of every axis, as the reader runs the
    programs."""
    _, _, trace = read_generated(folder)
    targets: dict[str, list[float]] = {}
    feeds: dict[str, list[float]] = {}
    for motion in trace.motions:
        for name, value in motion.target.items():
            targets.setdefault(name, []).append(value)
            if motion.kind == "feed" and motion.feed_mm_min is not None:
                feeds.setdefault(name, []).append(motion.feed_mm_min)
    return {name: (min(v), max(v), max(feeds.get(name, [0.0]))) for name, v in targets.items()}


def assert_sheet_holds_the_plan(out: Path) -> tuple[str, dict[str, Any]]:
    """Every axis' envelope, park, soft limits, feed and rapid and the duration in SETUP.md
    equal what schedule.json and the programs say; returns the sheet and the schedule."""
    text = (out / "SETUP.md").read_text(encoding="utf-8")
    assert (out / "setup.html").is_file()
    schedule = json.loads((out / "schedule.json").read_text(encoding="utf-8"))
    rows = sheet_rows(text)
    assert sorted(rows) == sorted(axis["name"] for axis in schedule["axes"])
    programs = program_envelopes(out)
    for axis in schedule["axes"]:
        row = rows[axis["name"]]
        low, high = schedule_envelope(axis)
        assert (row["low"], row["high"]) == (round(low, 3), round(high, 3)), axis["name"]
        read_low, read_high, read_feed = programs[axis["name"]]
        assert (row["low"], row["high"]) == pytest.approx((read_low, read_high), abs=5e-4)
        assert row["park"] == axis["park_mm"]
        assert (row["soft_low"], row["soft_high"]) == tuple(axis["travel_mm"])
        assert row["soft_low"] <= row["low"] and row["high"] <= row["soft_high"]
        fastest_run = max(abs(w["velocity_mm_min"]) for w in axis["windows"])
        assert row["feed"] == pytest.approx(read_feed, abs=1e-3)
        assert row["feed"] == fastest_run <= axis["max_velocity_mm_min"]
        assert row["rapid"] == axis["rapid_mm_min"]
    duration = DURATION.search(text)
    assert duration, text
    minutes, seconds = divmod(round(schedule["duration_s"]), 60)
    assert [int(g) for g in duration.groups()] == [minutes, seconds, round(schedule["duration_s"])]
    return text, schedule


@pytest.mark.parametrize("dialect", DIALECTS)
def test_every_dialect_writes_a_sheet_with_the_planned_envelope_and_duration(
    dialect: str, tmp_path: Path
) -> None:
    code, example, _ = run("init", "--controller", dialect)
    assert code == 0
    out, stdout = generate(tmp_path, example)
    assert f"wrote {out / 'SETUP.md'}" in stdout and f"wrote {out / 'setup.html'}" in stdout
    text, schedule = assert_sheet_holds_the_plan(out)

    for name in schedule["program_files"]:
        assert f"`{name}`" in text
    assert load_dialect(dialect).title in text
    assert "Z parks first" in text and "`vertical = true`" in text
    loaded = load_dialect(dialect)
    assert "stops before its first move" in text and "waits for cycle start" in text
    assert loaded.start.text in text  # the operator's message, as the control shows it
    # what the operator must do about offsets, as the dialect's manual requires
    assert loaded.coordinates.operator in text.replace("\\", "")
    assert "--schedule <this folder>/schedule.json" in text
    if schedule["marker_scope"] == "none":
        assert "the windows come from positions" in text
    else:
        assert "Marker: " in text and "`marker_input_bit`" in text
        for key, value in schedule["controller_options"].items():
            assert f"`{key} = {value}`" in text

    code, stdout, stderr = run("check", out)
    assert code == 0 and "ok:" in stdout, stdout + stderr


@pytest.mark.parametrize("dialect", DIALECTS)
def test_the_envelope_is_where_the_program_goes_not_the_travel(
    dialect: str, tmp_path: Path
) -> None:
    """No warm-up, runs around inner positions, parks away from them: the envelope is
    neither the soft limits nor the usable travel."""
    data = small_data(dialect)
    data["measurement"]["warmup_strokes"] = 0
    x, y, z = data["axes"]
    x.update(park_mm=740.0, measurement={"positions": [200.0, 400.0]})
    y.update(park_mm=10.0, measurement={"positions": [300.0]})
    z.update(park_mm=-2.0, measurement={"positions": [-300.0, -200.0]})
    out, _ = generate(tmp_path, machine_toml(data))
    _, schedule = assert_sheet_holds_the_plan(out)
    for axis in schedule["axes"]:
        low, high = schedule_envelope(axis)
        assert [low, high] != axis["usable_mm"] and [low, high] != axis["travel_mm"]
        assert axis["park_mm"] in (low, high)
    assert check_programs(out).ok


def test_confirm_start_false_says_the_program_moves_at_once(tmp_path: Path) -> None:
    data = small_data("sinumerik-840d")
    data["machine"]["confirm_start"] = False
    out, _ = generate(tmp_path, machine_toml(data))
    for name in ("SETUP.md", "setup.html"):
        text = (out / name).read_text(encoding="utf-8")
        assert "starts moving at once on cycle start" in text
        assert "stops before its first move" not in text
        assert "confirm_start = false" in text
    default, _ = generate(tmp_path, machine_toml(small_data("sinumerik-840d")), "default")
    text = (default / "SETUP.md").read_text(encoding="utf-8")
    assert "starts moving at once" not in text and "`confirm_start = true`" in text


def test_a_retract_first_axis_is_named_with_its_key(tmp_path: Path) -> None:
    data = small_data("linuxcnc")
    z = data["axes"][2]
    z["vertical"] = False
    z["retract_first"] = True
    out, _ = generate(tmp_path, machine_toml(data))
    text = (out / "SETUP.md").read_text(encoding="utf-8")
    assert "Z parks first, before any other axis moves (`retract_first = true`" in text
    assert "Parking order: Z, X, Y" in text and "measured one after the other (X, Y, Z)" in text


def test_without_a_marker_the_sheet_says_windows_come_from_positions(tmp_path: Path) -> None:
    data = small_data("heidenhain-iso")  # marker_m_on = 0: no marker
    out, _ = generate(tmp_path, machine_toml(data))
    text = (out / "SETUP.md").read_text(encoding="utf-8")
    assert "The programs write no marker: the windows come from positions" in text
    assert "`marker_m_on` and `marker_m_off`" in text
    assert "One program holds the whole measurement" in text
    data["machine"]["controller_options"] = {"marker_m_on": 50, "marker_m_off": 51}
    out, _ = generate(tmp_path, machine_toml(data), "marker")
    text = (out / "SETUP.md").read_text(encoding="utf-8")
    assert "Marker: M50 on the window block and M51 on the run-out block" in text
    assert "`marker_m_on = 50`" in text and "write no marker" not in text


# --- valid Markdown, a self-contained and escaped page -----------------------------------------


class _Page(html.parser.HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []
        self.attributes: list[tuple[str, str | None]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        self.attributes += attrs

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def _page(text: str) -> _Page:
    page = _Page()
    page.feed(text)
    return page


NAME = "<b>HMX & Co<i> | _x_ `z` ~~s~~ <!-- #1 #"
"""Markup of every kind a name may hold (the machine file refuses ``*``, ``[``, ``/``, ...)."""


def test_the_sheet_is_markdown_and_a_page_whatever_the_machine_is_called(tmp_path: Path) -> None:
    data = small_data("linuxcnc")
    data["machine"]["name"] = name = NAME
    out, _ = generate(tmp_path, machine_toml(data))
    markdown = (out / "SETUP.md").read_text(encoding="utf-8")

    tokens = MarkdownIt("commonmark").enable("table").parse(markdown)
    kinds = [t.type for t in tokens]
    assert kinds.count("table_open") == 2
    assert "html_inline" not in kinds and "html_block" not in kinds
    headings = [tokens[i + 1].content for i, t in enumerate(tokens) if t.type == "heading_open"]
    assert headings[1:] == [
        "Programs",
        "Where the axes go",
        "Before cycle start",
        "Recording",
        "Marker",
    ]
    rendered = MarkdownIt("commonmark").enable("table").render(markdown)
    title = _page(rendered.split("</h1>")[0]).text
    assert "".join(title) == f"Setup sheet: friction measurement of {name}"
    rows = re.findall(r"<tr>(.*?)</tr>", rendered, re.S)
    assert [row.count("<td") for row in rows if "<td" in row] == [3] * 4 + [7] * 3
    assert "<b>" not in rendered and "<a " not in rendered and "<em>" not in rendered

    page_text = (out / "setup.html").read_text(encoding="utf-8")
    page = _page(page_text)
    assert "b" not in page.tags and "a" not in page.tags and "script" not in page.tags
    assert "link" not in page.tags and "img" not in page.tags
    assert not [a for a in page.attributes if a[0] in ("src", "href")]
    assert "url(" not in page_text and "http" not in page_text and "@import" not in page_text
    assert f"Setup sheet: friction measurement of {name}" in page.text
    assert "<b>HMX" not in page_text and "&lt;b&gt;HMX &amp; Co&lt;i&gt;" in page_text


def test_the_sheet_of_a_three_axis_machine_prints_on_one_page(tmp_path: Path) -> None:
    browser = chromium_or_skip()
    longest = max(
        (
            generate_programs(
                parse_machine(tomllib.loads(run("init", "--controller", d)[1])),
                generated=FIXED_TIME,
            ).setup_files["setup.html"]
            for d in DIALECTS
        ),
        key=len,
    )
    page = tmp_path / "setup.html"
    page.write_text(longest, encoding="utf-8")
    pdf = tmp_path / "setup.pdf"
    command = [
        str(browser),
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--no-first-run",
        "--no-proxy-server",
        "--disable-background-networking",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--no-pdf-header-footer",
        f"--print-to-pdf={pdf}",
        page.resolve().as_uri(),
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=180, check=False)
    assert done.returncode == 0 and pdf.is_file(), done.stderr[-2000:]
    pages = re.findall(rb"/Type\s*/Page\b(?!s)", pdf.read_bytes())
    assert len(pages) == 1


# --- beside the programs: replaced with them, never over a file of someone else's ---------------


def test_a_new_generation_replaces_the_sheet_and_check_ignores_it(tmp_path: Path) -> None:
    out = tmp_path / "out"
    data = small_data("fanuc")
    generate_programs(parse_machine(data), generated=FIXED_TIME).write(out)
    first = (out / "SETUP.md").read_text(encoding="utf-8")
    data["measurement"]["warmup_strokes"] = 0
    data["axes"] = data["axes"][:2]
    generate_programs(parse_machine(data), generated=FIXED_TIME).write(out)
    second = (out / "SETUP.md").read_text(encoding="utf-8")
    assert second != first and "| Z |" in first and "| Z |" not in second
    assert check_programs(out).ok
    (out / "notes.md").write_text("# notes\n")
    (out / "page.html").write_text("<p>notes</p>\n")
    assert check_programs(out).ok  # only the dialect's program extensions are programs


def test_a_foreign_setup_sheet_is_not_overwritten(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "SETUP.md").write_text("someone's own notes\n")
    with pytest.raises(OutputError, match=r"no schedule\.json there names \(SETUP\.md\)"):
        generate_programs(parse_machine(small_data("linuxcnc"))).write(out)
    assert [p.name for p in out.iterdir()] == ["SETUP.md"]
    assert (out / "SETUP.md").read_text() == "someone's own notes\n"


# --- where the output files are listed ----------------------------------------------------------

ROOT = Path(__file__).resolve().parents[2]


def test_the_docs_list_the_sheet_and_send_the_technician_to_it_first() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    generate_row = next(line for line in readme.splitlines() if "`ncmeasure generate " in line)
    assert "SETUP.md" in generate_row and "setup.html" in generate_row
    assert "wrote programs/schedule.json\nwrote programs/SETUP.md\nwrote programs/setup.html" in (
        readme
    )
    real_machine = readme[readme.index("On the real machine") :]
    first_command = re.search(r"^\$ (.*)$", real_machine, re.M)
    assert first_command and "programs/SETUP.md" in first_command.group(1)
    assert real_machine.index("SETUP.md") < real_machine.index("ncmeasure record")
    machine_file = (ROOT / "docs" / "machine-file.md").read_text(encoding="utf-8")
    assert "## The setup sheet: SETUP.md and setup.html" in machine_file
    assert "programs, schedule.json, SETUP.md" in machine_file
