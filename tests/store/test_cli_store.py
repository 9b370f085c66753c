"""``ncmeasure store ...``: the commands, their exit codes, and bad input in one line."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.formats.results import Results, Verdict, write_results

runner = CliRunner()


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def _one_error_line(code: int, out: str, err: str) -> str:
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in out + err
    return lines[0]


@pytest.fixture
def files(tmp_path: Path, make_results: Callable[..., Results]) -> dict[str, Path]:
    paths = {}
    for name, when, factor in (
        ("delivery", "2026-01-10T08:00:00+00:00", 1.0),
        ("service", "2029-01-10T08:00:00+00:00", 0.85),
        ("worn", "2031-01-10T08:00:00+00:00", 0.5),
    ):
        results = make_results(when, factor)
        ok = Verdict(level="ok", reason="flat along the travel", action="none")
        # the axes' own verdicts ok: these tests follow the change since the delivery
        axes = {n: a.model_copy(update={"verdict": ok}) for n, a in results.axes.items()}
        results = results.model_copy(update={"axes": axes})
        paths[name] = write_results(results, tmp_path / f"{name}.json")
    return paths


def test_a_machine_over_its_life(tmp_path: Path, files: dict[str, Path]) -> None:
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    code, out, _ = run("store", "add", files["delivery"], "--serial", "M17", "--label",
                       "delivery", "--temperature-c", "21.5", "--store", store)  # fmt: skip
    assert code == 0 and "stored as measurement 1 of M17" in out
    code, out, _ = run("store", "add", files["delivery"], "--serial", "M17", "--store", store)
    assert code == 0 and "already stored as measurement 1" in out
    code, out, _ = run("store", "check", "M17", "--store", store)
    assert code == 0 and "only the baseline" in out
    assert run("store", "add", files["service"], "--serial", "M17", "--label", "service",
               "--temperature-c", "22", "--store", store)[0] == 0  # fmt: skip
    code, out, _ = run("store", "check", "M17", "--store", store, "-o", tmp_path / "check.json")
    assert code == 1, out  # −15 %: beyond the 10 % warning limit, within the 25 % critical
    check = json.loads((tmp_path / "check.json").read_text())
    assert check["status"] == "warning" and check["latest"]["label"] == "service"


def test_exit_codes_follow_compare(tmp_path: Path, files: dict[str, Path]) -> None:
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    for name in ("delivery", "worn"):
        assert run("store", "add", files[name], "--serial", "M17", "--label", name,
                   "--store", store)[0] == 0  # fmt: skip
    code, out, _ = run("store", "check", "M17", "--store", store)
    assert code == 3 and "status: critical" in out
    code, out, _ = run("store", "check", "M17", "--store", store, "--critical", "60")
    assert code == 1 and "status: warning" in out
    code, out, _ = run("store", "list", "--store", store)
    assert code == 0 and "M17" in out
    code, out, _ = run("store", "show", "M17", "--store", store)
    assert code == 0 and "delivery" in out and "worn" in out
    png = tmp_path / "trend.png"
    code, out, _ = run("store", "trend", "M17", "--axis", "X", "--plot", png, "--store", store)
    assert code == 0 and png.read_bytes().startswith(b"\x89PNG")


def test_a_trend_plot_without_matplotlib_names_the_extra(
    tmp_path: Path, files: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    assert run("store", "add", files["delivery"], "--serial", "M17", "--store", store)[0] == 0
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib: ImportError
    png = tmp_path / "trend.png"
    code, out, err = run("store", "trend", "M17", "--axis", "X", "--plot", png, "--store", store)
    assert code != 0 and "pip install 'ncmeasure[plot]'" in err, err
    assert "Traceback" not in err and not png.exists() and "M17" not in out


def test_tables_are_whole_when_the_output_is_not_a_terminal(
    tmp_path: Path, files: dict[str, Path]
) -> None:
    """`store list` and `store trend` into a file cut their tables to 80 columns."""
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    site = ("hall 2, line 3, the machine by the north door " * 5)[:200]
    label = "after-repair-of-the-loose-bearing-and-the-nut-of-the-x-axis"
    for name in ("delivery", "service"):
        assert run("store", "add", files[name], "--serial", "M17", "--label",
                   label if name == "service" else name, "--site", site, "--operating-hours",
                   "123456.5", "--store", store)[0] == 0  # fmt: skip
    code, out, _ = run("store", "list", "--store", store)
    assert code == 0, out
    row = next(line for line in out.splitlines() if "M17" in line)
    assert site in row and label in row and "…" not in row, row
    code, out, _ = run("store", "trend", "M17", "--axis", "X", "--store", store)
    assert code == 0, out
    assert "viscous [Nm per m/min]" in out and "…" not in out
    row = next(line for line in out.splitlines() if label in line)
    assert "123456" in row and row.rstrip(" │").endswith(("ok", "check", "fault")), row


def test_export_to_jsonl_and_import_into_postgresql(
    tmp_path: Path, files: dict[str, Path], pg_url: str
) -> None:
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    for name in files:
        assert run("store", "add", files[name], "--serial", "M17", "--label", name,
                   "--store", store)[0] == 0  # fmt: skip
    export = tmp_path / "fleet.jsonl"
    assert run("store", "export", "-o", export, "--store", store)[0] == 0
    assert len(export.read_text().splitlines()) == 1 + len(files)
    code, out, _ = run("store", "import", export, "--store", pg_url)
    assert code == 0 and "added 3 measurement(s)" in out
    code, out, _ = run("store", "import", export, "--store", pg_url)
    assert code == 0 and "added 0 measurement(s)" in out and "3 were already stored" in out
    again = tmp_path / "again.jsonl"
    assert run("store", "export", "-o", again, "--store", pg_url)[0] == 0
    assert again.read_text() == export.read_text()  # lossless both ways


def test_bad_input_is_one_line_and_exit_2(
    tmp_path: Path, files: dict[str, Path], postgres_server: str
) -> None:
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    assert run("store", "add", files["delivery"], "--serial", "M17", "--store", store)[0] == 0
    before = (tmp_path / "fleet.db").read_bytes()

    other = json.loads(files["service"].read_text())
    other["format_version"] = 99
    (tmp_path / "v99.json").write_text(json.dumps(other))
    line = _one_error_line(*run("store", "add", tmp_path / "v99.json", "--serial", "M17",
                                "--store", store))  # fmt: skip
    assert "format_version 99" in line and "update ncmeasure" in line

    for serial in ("../../etc/M17", "M17'; DROP TABLE machines;--"):
        line = _one_error_line(*run("store", "add", files["service"], "--serial", serial,
                                    "--store", store))  # fmt: skip
        assert "serial" in line
    unreachable = postgres_server.rsplit(":", 1)[0] + ":1/postgres"
    line = _one_error_line(*run("store", "list", "--store", unreachable))
    assert "cannot reach the database" in line
    line = _one_error_line(*run("store", "list", "--store", "mysql://db/fleet"))
    assert "not a store ncmeasure knows" in line
    line = _one_error_line(*run("store", "list", "--store", tmp_path / "missing.db"))
    assert "no such file" in line
    assert (tmp_path / "fleet.db").read_bytes() == before  # nothing half written


def test_a_newer_schema_is_one_line(tmp_path: Path, files: dict[str, Path]) -> None:
    import sqlite3

    path = tmp_path / "fleet.db"
    assert run("store", "add", files["delivery"], "--serial", "M17", "--store", path)[0] == 0
    with sqlite3.connect(path) as db:
        db.execute("UPDATE alembic_version SET version_num = '9999'")
    line = _one_error_line(*run("store", "add", files["service"], "--serial", "M17",
                                "--store", path))  # fmt: skip
    assert "newer than this ncmeasure" in line and "update ncmeasure" in line


def test_a_read_only_store_is_one_line(tmp_path: Path, files: dict[str, Path]) -> None:
    """Root writes any file: as root the command runs without the capability to override
    file permissions (setpriv), so the file's mode holds for it as for anyone."""
    folder = tmp_path / "ro"
    folder.mkdir()
    path = folder / "fleet.db"
    assert run("store", "add", files["delivery"], "--serial", "M17", "--store", path)[0] == 0
    before = path.read_bytes()
    path.chmod(0o444)
    folder.chmod(0o555)
    drop = []
    if os.geteuid() == 0:
        setpriv = shutil.which("setpriv")
        assert setpriv, "setpriv (util-linux) is needed to test a read-only store as root"
        drop = [setpriv, "--bounding-set", "-dac_override,-dac_read_search", "--"]
    try:
        done = subprocess.run(
            [*drop, sys.executable, "-m", "ncmeasure", "store", "add", str(files["service"]),
             "--serial", "M17", "--store", str(path)],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
    finally:
        folder.chmod(0o755)
    line = _one_error_line(done.returncode, done.stdout, done.stderr)
    assert "read-only" in line and "nothing was written" in line
    assert path.read_bytes() == before


def test_analyze_adds_to_the_store(tmp_path: Path) -> None:
    from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording

    spec = SyntheticAxis(
        positions_mm=(50.0, 375.0, 700.0),
        coulomb=(2.0, 2.0, 2.0),
        velocities_mm_min=geometric_velocities(10.0, 15000.0, 8),
    )
    folder = tmp_path / "run1"
    _, schedule = synthetic_recording(folder, [spec], seed=1)
    assert schedule is not None
    schedule_file = tmp_path / "schedule.json"
    schedule_file.write_text(schedule.model_dump_json())
    store = tmp_path / "fleet.db"
    code, out, _ = run("analyze", folder, "--schedule", schedule_file, "--store", store)
    assert code == 2  # --store without --serial
    code, out, err = run("analyze", folder, "--schedule", schedule_file, "--store", store,
                         "--serial", "M17", "--label", "delivery")  # fmt: skip
    assert code == 0, err
    assert "stored as measurement 1 of M17" in out
    code, out, _ = run("store", "show", "M17", "--store", store)
    assert code == 0 and "delivery" in out and str(folder.name) in run("store", "export",
        "--store", store)[1]  # fmt: skip


def test_refresh_stores_the_changes_of_an_older_store(
    tmp_path: Path, files: dict[str, Path]
) -> None:
    from sqlalchemy import create_engine, delete

    from ncmeasure.store import schema as t

    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    for name in ("delivery", "service"):
        code, _, _ = run("store", "add", files[name], "--serial", "M17", "--store", store)
        assert code == 0
    engine = create_engine(store)
    with engine.begin() as db:  # as a store filled before the changes were kept
        db.execute(delete(t.baseline_changes))
    engine.dispose()
    code, out, _ = run("store", "refresh", "--quiet", "--store", store)
    assert code == 0, out
    assert "stored the change since the baseline of 1 machine(s)" in out
    code, out, _ = run("store", "refresh", "--quiet", "--store", store)
    assert code == 0 and "of 0 machine(s)" in out
    code, out, _ = run("store", "refresh", "--help")
    assert code == 0 and "--all" in out and "missing or out of date" in " ".join(out.split())
