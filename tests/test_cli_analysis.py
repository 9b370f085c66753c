"""`ncmeasure analyze`, `compare` and `schema results` from the command line."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ncmeasure.analysis.judgement.summary import axis_headline
from ncmeasure.cli import app
from ncmeasure.formats.results import load_results
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording
from tests.report.example import DEAD_Y_REASON, healthy_recording

runner = CliRunner()
P3 = (50.0, 375.0, 700.0)


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def _run(folder: Path, coulomb: tuple[float, ...], seed: int = 0) -> tuple[Path, Path]:
    spec = SyntheticAxis(
        positions_mm=P3, coulomb=coulomb, velocities_mm_min=geometric_velocities(10.0, 15000.0, 20)
    )
    _, schedule = synthetic_recording(folder, [spec], seed=seed)
    assert schedule is not None
    path = folder.with_suffix(".schedule.json")
    path.write_text(schedule.model_dump_json())
    return folder, path


def test_analyze_writes_results_and_report(tmp_path: Path) -> None:
    run_dir, schedule = _run(tmp_path / "run1", (2.0, 2.3, 2.6))
    code, out, err = run(
        "analyze", run_dir, "--schedule", schedule, "--report", tmp_path / "report.html", "--quiet"
    )
    assert code == 0, err
    results = load_results(tmp_path / "run1.results.json")
    x = results.axes["X"]
    assert x.quantity == "torque_nm" and len(x.positions) == 3
    assert x.position_dependency is not None
    assert x.position_dependency.signature == "rising_to_loose_bearing"
    assert x.position_dependency.causes[0].cause == "loose_bearing"
    fit = x.positions[0].directions["positive"]
    assert fit is not None and fit.fit is not None
    assert abs(fit.fit.coulomb - 2.0) < 0.02
    html = (tmp_path / "report.html").read_text()
    assert html.count("<svg ") == 3 and "loose" in html  # the raw data, curves, travel
    code, out, _ = run("analyze", run_dir, "-o", tmp_path / "r2.json")
    assert code == 0
    line = next(line for line in out.splitlines() if line.startswith("axis X:"))
    assert line.startswith(f"axis X: {x.verdict.level} · Coulomb friction ")
    assert x.verdict.level == "fault" and "rising towards the loose bearing" in line
    assert "likely a shifted or tilted loose bearing" in line
    assert "What to do: Check the alignment" in line


def test_a_recording_problem_is_told_once(tmp_path: Path) -> None:
    """A torn tail: the reader's line says so, and the command does not repeat it."""
    run_dir, schedule = _run(tmp_path / "run1", (2.0, 2.3, 2.6))
    with (run_dir / "samples.bin").open("ab") as file:
        file.write(b"\x13" * 40)  # half a frame header, as a crash leaves it
    done = subprocess.run(
        [sys.executable, "-m", "ncmeasure", "analyze", run_dir, "--schedule", schedule],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    said = done.stdout + done.stderr
    assert said.count("torn tail: 40 bytes") == 1, said
    assert "axis X:" in done.stdout


def test_console_line_is_the_report_headline(tmp_path: Path) -> None:
    """Verdict first, then exactly the Coulomb figure the report shows; skipped axes after."""
    _, schedule = healthy_recording(tmp_path / "run")
    schedule_file = tmp_path / "schedule.json"
    schedule_file.write_text(schedule.model_dump_json())
    report = tmp_path / "report.html"
    code, out, err = run(
        "analyze", tmp_path / "run", "--schedule", schedule_file, "--report", report
    )
    assert code == 0, err  # one axis analysed is a success
    results = load_results(tmp_path / "run.results.json")
    assert set(results.axes) == {"X"} and set(results.skipped) == {"Y"}
    headline = axis_headline(results.axes["X"])
    assert headline.verdict.level == "ok" and headline.coulomb is not None
    assert abs(headline.coulomb - 2.0) < 0.05  # the synthetic axis' Coulomb friction
    lines = out.splitlines()
    assert lines[0] == (
        f"axis X: ok · Coulomb friction {headline.coulomb_text}; {headline.travel_text}. "
        f"{headline.verdict.reason}"
    )
    assert lines[1].startswith(f"axis Y: not analysed · {DEAD_Y_REASON}")
    html = report.read_text(encoding="utf-8")
    assert f'<span class="headline">Coulomb friction {headline.coulomb_text}</span>' in html
    verdicts = html.split('<table class="verdicts">', 1)[1].split("</table>", 1)[0]
    assert f'<td class="num">{headline.coulomb_text}</td>' in verdicts
    assert '<span class="badge level-skipped">not analysed</span>' in verdicts
    assert DEAD_Y_REASON in verdicts


def test_compare_lifetime_exit_codes(tmp_path: Path) -> None:
    base_dir, _ = _run(tmp_path / "base", (2.0, 2.0, 2.0))
    same_dir, _ = _run(tmp_path / "same", (2.02, 2.0, 1.98), seed=1)
    worn_dir, _ = _run(tmp_path / "worn", (1.0, 1.0, 1.0), seed=2)
    for folder in (base_dir, same_dir, worn_dir):
        assert run("analyze", folder, "--quiet")[0] == 0
    base = tmp_path / "base.results.json"
    code, out, _ = run("compare", base, tmp_path / "same.results.json")
    assert code == 0, out
    code, out, _ = run("compare", base, tmp_path / "worn.results.json", "-o", tmp_path / "cmp.json")
    assert code == 3, out
    worn = load_results(tmp_path / "worn.results.json").axes["X"]
    figure = axis_headline(worn).coulomb_text
    assert f"worn.results: axis X: fault · Coulomb friction {figure};" in out
    assert re.search(r"Against the reference: friction -\d+\.\d % on average, alike along the "
                     r"travel; at most -\d+\.\d % at position \d \(\d+ mm\), \w+, beyond the "
                     r"critical limit; likely a preload loss of the ball-screw nut",
                     out), out  # fmt: skip
    assert json.loads((tmp_path / "cmp.json").read_text())["format"] == "ncmeasure-comparison"
    code, out, _ = run(
        "compare",
        base,
        tmp_path / "worn.results.json",
        "--critical",
        "60",
        "--report",
        tmp_path / "cmp.html",
    )
    assert code == 1, out
    html = (tmp_path / "cmp.html").read_text()
    assert "Comparison" in html and "warning" in html.lower()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three analysed machines, each as results.json in a folder of its own (m17, m18, m19)."""
    folder = tmp_path_factory.mktemp("fleet")
    for seed, name in enumerate(("m17", "m18", "m19")):
        run_dir, _ = _run(folder / "runs" / name, (2.0 + 0.01 * seed, 2.0, 2.0), seed=seed)
        (folder / name).mkdir()
        code, _, err = run("analyze", run_dir, "-o", folder / name / "results.json", "--quiet")
        assert code == 0, err
    return folder


def test_compare_labels_files_of_the_same_name_by_their_folders(fleet: Path) -> None:
    files = [fleet / name / "results.json" for name in ("m17", "m18", "m19")]
    code, out, err = run("compare", *files, "-o", fleet / "cmp.json")
    assert code == 0, out + err
    assert "m18/results: axis X: ok" in out and "m19/results: axis X: ok" in out
    comparison = json.loads((fleet / "cmp.json").read_text())
    assert comparison["others"] == ["m18/results", "m19/results"]
    # the same file twice is still told apart
    code, out, err = run("compare", files[0], files[1], files[1])
    assert code == 0, out + err
    assert "m18/results #1: axis X" in out and "m18/results #2: axis X" in out


def test_compare_takes_a_label_per_compared_file(fleet: Path) -> None:
    files = [fleet / name / "results.json" for name in ("m17", "m18", "m19")]
    code, out, err = run("compare", *files, "--label", "M-18 [rebuilt]", "--label", "M-19")
    assert code == 0, out + err
    assert "M-18 [rebuilt]: axis X: ok" in out and "M-19: axis X: ok" in out
    code, out, err = run("compare", *files, "--label", "M-17", "--label", "M-18", "--label", "x")
    assert code == 0, out + err  # one per file, the base's first
    assert "M-18: axis X" in out and "x: axis X" in out
    for labels, message in [
        (["only one"], "--label: 1 label for 2 compared files"),
        (["a", "a"], "--label: 'a' is given twice"),
        (["a", " "], "--label: a label is empty"),
    ]:
        code, out, err = run(
            "compare", *files, *[x for label in labels for x in ("--label", label)]
        )
        assert code == 2 and message in err and "Traceback" not in err, err


def test_compare_output_that_cannot_be_written_is_bad_input(fleet: Path, tmp_path: Path) -> None:
    files = [fleet / "m17" / "results.json", fleet / "m18" / "results.json"]
    (tmp_path / "blocker").write_text("a file, not a folder")
    code, _, err = run("compare", *files, "-o", tmp_path / "blocker" / "x.json")
    assert code == 2 and "Traceback" not in err, err
    assert f"{tmp_path / 'blocker' / 'x.json'}: cannot be written" in err
    code, _, err = run("compare", *files, "--report", tmp_path / "blocker" / "x.html")
    assert code == 2 and "Traceback" not in err and "blocker" in err, err
    # a folder that does not exist yet is made, as analyze -o and --report make theirs
    code, _, err = run("compare", *files, "-o", tmp_path / "missing" / "dir" / "x.json")
    assert code == 0, err
    assert json.loads((tmp_path / "missing" / "dir" / "x.json").read_text())["others"] == [
        "m18/results"
    ]


def test_analysis_bad_input(tmp_path: Path) -> None:
    code, _, err = run("analyze", tmp_path / "nothing")
    assert code == 2 and "nothing" in err and "Traceback" not in err
    (tmp_path / "x.json").write_text("{}")
    code, _, err = run("compare", tmp_path / "x.json", tmp_path / "x.json")
    assert code == 2 and "x.json" in err
    code, out, _ = run("schema", "results")
    assert (
        code == 0 and "position_dependency" in json.loads(out)["$defs"]["AxisResult"]["properties"]
    )


def test_analyze_skips_a_dead_axis_and_takes_settings_and_axes(tmp_path: Path) -> None:
    """Real data: the Z current reads 0.0 A in every row. X is analysed, Z is named."""
    from tests.analysis.real_data import measure, write

    axes = [
        SyntheticAxis(name=name, velocities_mm_min=geometric_velocities(20.0, 6000.0, 6))
        for name in ("X", "Z")
    ]
    data = measure(axes)
    data = data.set("Z_current_a", 0.0 * data.column("Z_current_a"))
    run_dir = tmp_path / "run"
    write(run_dir, data, axes)
    code, out, err = run("analyze", run_dir, "--set", "settle_s=0.15")
    assert code == 0, err
    assert "axis Z: not analysed · Z_current_a is 0 A in every row" in out
    results = load_results(tmp_path / "run.results.json")
    assert list(results.axes) == ["X"]
    assert "dead channel" in results.skipped["Z"]
    assert results.settings["settle_s"] == 0.15
    code, out, err = run("analyze", run_dir, "--axis", "X", "-o", tmp_path / "x.json", "-q")
    assert code == 0, err
    only = load_results(tmp_path / "x.json")
    assert list(only.axes) == ["X"] and only.skipped == {}
    code, out, err = run("analyze", run_dir, "--axis", "Z", "-o", tmp_path / "z.json")
    assert code == 2
    assert "no axis could be analysed" in err and "dead channel" in err
    assert not (tmp_path / "z.json").exists()
    for bad, message in (
        ("settle_s=soon", "settle_s"),
        ("nonsense=1", "nonsense"),
        ("settle_s", "expected KEY=VALUE"),
    ):
        code, _, err = run("analyze", run_dir, "--set", bad)
        assert code == 2 and message in err and "Traceback" not in err, err
    code, _, err = run("analyze", run_dir, "--axis", "Q")
    assert code == 2 and "axis Q not recorded" in err


def test_a_data_collector_csv_is_imported_and_analysed(tmp_path: Path) -> None:
    """A CNC data collector's CSV: its own column names, mm/s, no time column (100 ms),
    three significant digits, a text column. Imported with a column map, then analysed
    with the defaults: every window is found, and the data is called coarse."""
    from tests.analysis.real_data import decimate, measure

    spec = SyntheticAxis(
        velocities_mm_min=(300.0, 600.0, 1200.0, 2400.0, 4800.0), window_s=0.8, stribeck=0.3
    )
    data = decimate(measure([spec], with_marker=False), 25)
    current = data.column("X_current_a")
    velocity = data.column("X_velocity_mm_min") / 60.0
    command = data.column("X_velocity_cmd_mm_min") / 60.0
    position = data.column("X_position_mm")
    lines = ["Timestamp,X1_CurrentFeedback,X1_ActualVelocity,X1_ActualPosition,X1_CommandVelocity"]
    for k in range(len(current)):
        lines.append(
            f"2024-03-05 10:{k // 600:02d}:{k % 600 / 10:04.1f},{current[k]:.2E},"
            f"{velocity[k]:.2E},{position[k]:.2E},{command[k]:.2E}"
        )
    csv_path = tmp_path / "collector.csv"
    csv_path.write_text("\r\n".join(lines) + "\r\n", encoding="utf-8")
    mapping = tmp_path / "collector.toml"
    mapping.write_text(
        "period_s = 0.1\n[channels]\n"
        'X_current_a = { column = "X1_CurrentFeedback" }\n'
        'X_velocity_mm_min = { column = "X1_ActualVelocity", scale = 60 }\n'
        'X_position_mm = { column = "X1_ActualPosition" }\n'
        'X_velocity_cmd_mm_min = { column = "X1_CommandVelocity", scale = 60 }\n',
        encoding="utf-8",
    )
    code, _, err = run("import", csv_path, "--columns", mapping, "-o", tmp_path / "run")
    assert code == 0, err
    assert "Timestamp" in err  # the ignored text column is reported
    # The program's top feed tells its steps from the rapids between them.
    code, _, err = run("analyze", tmp_path / "run", "-q", "--set", "max_velocity_mm_min=5000")
    assert code == 0, err
    x = load_results(tmp_path / "run.results.json").axes["X"]
    assert x.window_source == "command"
    assert x.coarse and x.sample_period_s == pytest.approx(0.1)
    speeds = sorted(
        {round(abs(p.velocity_mm_min)) for pos in x.positions for d in pos.directions.values()
         if d for p in d.points}
    )  # fmt: skip
    assert speeds == [300, 600, 1200, 2400, 4800]
    assert len(x.positions) == 3
    for position in x.positions:
        for direction in position.directions.values():
            assert direction is not None and direction.fit is not None
            # No machine file: friction stays motor current, k_T = 2.1 Nm/A.
            truth = spec.parameter("coulomb", position.position_index) / 2.1
            assert x.unit == "A"
            assert direction.fit.coulomb == pytest.approx(truth, rel=0.05)


def test_analyze_help_lists_every_setting() -> None:
    from ncmeasure.analysis.analyze import AnalysisSettings
    from ncmeasure.cli.analysis import ANALYSIS_SETTINGS

    assert tuple(AnalysisSettings.model_fields) == ANALYSIS_SETTINGS
    code, out, _ = run("analyze", "--help")
    assert code == 0
    words = set(out.replace("│", " ").replace(",", " ").split())
    for name in ANALYSIS_SETTINGS:
        assert name in words
