"""`ncmeasure record`, `export` and `import` from the command line (replay link)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.config import parse_machine
from ncmeasure.examples import example_machine
from ncmeasure.links.base import LinkEvent, SampleBlock, channels_for
from ncmeasure.recording import RecordingWriter, read_recording
from tests.conftest import example_data

runner = CliRunner()


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def _source(folder: Path, rows: int = 2000) -> Path:
    config = parse_machine(example_data())
    channels = channels_for(["X", "Y", "Z"])
    rng = np.random.default_rng(7)
    with RecordingWriter.create(
        folder, channels, nominal_period_s=0.004, machine=config, source="test"
    ) as writer:
        time_s = np.arange(rows) * 0.004
        writer.append(SampleBlock(time_s, rng.normal(size=(rows, len(channels)))))
        writer.add_event(LinkEvent(2.0, "emcy", "0x2310 continuous over-current", axis="X"))
    return folder


def _machine(tmp_path: Path) -> Path:
    path = tmp_path / "m.toml"
    path.write_text(example_machine("linuxcnc"))
    return path


def test_record_replay_export_import_round_trip(tmp_path: Path) -> None:
    source = _source(tmp_path / "run1")
    code, _, err = run(
        "record",
        _machine(tmp_path),
        "--link",
        "replay",
        "--source",
        source,
        "--speed",
        "0",
        "-o",
        tmp_path / "run2",
        "--quiet",
    )
    assert code == 0, err
    original, replayed = read_recording(source), read_recording(tmp_path / "run2")
    np.testing.assert_array_equal(original.values, replayed.values)
    assert [e.message for e in replayed.events] == ["0x2310 continuous over-current"]

    code, _out, err = run("export", tmp_path / "run2", "--format", "csv", "-o", tmp_path / "r.csv")
    assert code == 0, err
    header = (tmp_path / "r.csv").read_text().splitlines()[0]
    assert header.startswith("time_s,X_current_a,X_velocity_mm_min,X_position_mm,Y_current_a")
    code, _out, err = run("import", tmp_path / "r.csv", "--format", "csv", "-o", tmp_path / "run3")
    assert code == 0, err
    back = read_recording(tmp_path / "run3")
    np.testing.assert_array_equal(back.values, original.values)
    np.testing.assert_array_equal(back.time_s, original.time_s)


def test_record_with_duration_and_progress_display(tmp_path: Path) -> None:
    source = _source(tmp_path / "run1")
    code, _, err = run(
        "record",
        _machine(tmp_path),
        "--link",
        "replay",
        "--source",
        source,
        "--set",
        "speed=0",
        "--duration",
        "2",
        "-o",
        tmp_path / "run2",
    )
    assert code == 0, err
    assert "complete: 500 samples" in err
    assert len(read_recording(tmp_path / "run2").time_s) == 500


def test_record_bad_input_is_clear(tmp_path: Path) -> None:
    machine = _machine(tmp_path)
    code, _, err = run("record", machine, "-o", tmp_path / "r")
    assert code == 2 and "no link given" in err
    code, _, err = run("record", machine, "--link", "profibus", "-o", tmp_path / "r")
    assert code == 2 and "unknown link 'profibus'" in err
    code, _, err = run(
        "record", machine, "--link", "replay", "--source", tmp_path / "none", "-o", tmp_path / "r"
    )
    assert code == 2 and "link.source" in err
    code, _, err = run("record", machine, "--link", "replay", "--node", "X1", "-o", tmp_path / "r")
    assert code == 2 and "expected AXIS=NUMBER" in err
    code, _, err = run(
        "record",
        machine,
        "--link",
        "replay",
        "--set",
        "sped=2",
        "--source",
        _source(tmp_path / "s"),
        "-o",
        tmp_path / "r",
    )
    assert code == 2 and "link.sped: unknown key" in err
    assert "Traceback" not in err
    assert not (tmp_path / "r").exists()


def test_export_and_import_bad_input(tmp_path: Path) -> None:
    code, _, err = run("export", tmp_path / "nothing", "-o", tmp_path / "x.csv")
    assert code == 2 and "nothing" in err
    code, _, err = run("export", _source(tmp_path / "run"), "--format", "xlsx")
    assert code == 2 and "expected one of csv, mdf4" in err
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,X_current_a\n0.0,1.0\n0.004,oops\n")
    code, _, err = run("import", bad, "-o", tmp_path / "imp")
    assert code == 2 and "bad.csv:3" in err
