"""A machine file names a machine type; the serial of the machine measured comes with the
measurement and travels from the recording into the results, the store and the report."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.analysis.analyze import analyze
from ncmeasure.cli import app
from ncmeasure.config import parse_machine
from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.examples import example_machine
from ncmeasure.formats.results import load_results
from ncmeasure.recording import Recording, RecordingHead, RecordingWriter
from ncmeasure.report import write_report
from ncmeasure.samples import SampleBlock, channels_for
from ncmeasure.sim.synthetic import (
    SyntheticAxis,
    geometric_velocities,
    machine_config,
    synthetic_recording,
)
from tests.conftest import example_data

runner = CliRunner()
AXIS = SyntheticAxis(
    positions_mm=(50.0, 375.0),
    coulomb=(2.0, 2.0),
    velocities_mm_min=geometric_velocities(10.0, 15000.0, 8),
)


def run(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture(scope="module")
def unnamed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recording made without a machine file: no machine name, no axis data."""
    folder = tmp_path_factory.mktemp("identity") / "run"
    synthetic_recording(folder, [AXIS], axis_metadata=False)
    return folder


def _with_serial(source: Path, target: Path, serial: str | None) -> Path:
    """A copy of ``source`` whose meta.json carries ``serial`` (None: no key, as before)."""
    import shutil

    shutil.copytree(source, target)
    meta = json.loads((target / "meta.json").read_text())
    meta.pop("serial", None)
    if serial is not None:
        meta["serial"] = serial
    (target / "meta.json").write_text(json.dumps(meta))
    return target


def test_the_example_machine_file_names_a_type() -> None:
    text = example_machine("linuxcnc")
    assert 'name = "HMX-400"' in text and "#17" not in text
    assert "the machine type" in text and "--serial" in text
    code, out, _ = run("init", "--controller", "linuxcnc")
    assert code == 0 and out == text
    code, out, _ = run("schema", "machine")
    assert "serial number is given at measurement" in out


def test_the_writer_keeps_the_serial_and_old_files_read(tmp_path: Path) -> None:
    channels = channels_for(["X"])
    config = parse_machine(example_data())
    with RecordingWriter.create(
        tmp_path / "r", channels, nominal_period_s=0.001, machine=config, serial="M17"
    ) as writer:
        writer.append(SampleBlock(np.arange(3) * 0.001, np.ones((3, len(channels)))))
    assert Recording.open(tmp_path / "r").meta.serial == "M17"
    old = _with_serial(tmp_path / "r", tmp_path / "old", None)
    meta = RecordingHead.open(old).meta
    assert meta.serial is None and meta.machine == "HMX-400"
    with pytest.raises(RecordingError) as caught:
        RecordingWriter.create(tmp_path / "bad", channels, nominal_period_s=0.001, serial=" M1")
    assert "serial" in "\n".join(caught.value.problems)


def test_analyze_keeps_the_machine_files_name_and_the_serial(unnamed: Path) -> None:
    results = analyze(unnamed, machine=machine_config([AXIS], name="HMX-400"), serial="M17")
    assert results.recording.machine == "HMX-400"
    assert results.recording.serial == "M17"
    plain = analyze(unnamed)
    assert plain.recording.machine is None and plain.recording.serial is None


def test_analyze_refuses_a_serial_other_than_the_recordings(unnamed: Path, tmp_path: Path) -> None:
    recorded = _with_serial(unnamed, tmp_path / "m17", "M17")
    assert analyze(recorded).recording.serial == "M17"
    assert analyze(recorded, serial="M17").recording.serial == "M17"
    with pytest.raises(ConfigError, match=r"made on machine 'M17'.*not on 'M18'"):
        analyze(recorded, serial="M18")
    code, _, err = run("analyze", recorded, "--serial", "M18", "-q")
    assert code == 2 and "not on 'M18'" in err and "Traceback" not in err


def test_analyze_serial_and_store(unnamed: Path, tmp_path: Path) -> None:
    """--serial goes into the results, also without --store; --store takes the
    recording's serial; --measured-at gives a store the time an import lacked."""
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    code, _, err = run("analyze", unnamed, "--serial", "M17", "-o", tmp_path / "a.json", "-q")
    assert code == 0, err
    assert load_results(tmp_path / "a.json").recording.serial == "M17"

    recorded = _with_serial(unnamed, tmp_path / "m17", "M17")
    store = f"sqlite:///{tmp_path / 'fleet.db'}"
    code, out, err = run("analyze", recorded, "--store", store, "--machine", machine,
                         "-o", tmp_path / "b.json")  # fmt: skip
    assert code == 0 and "stored as measurement 1 of M17" in out, err
    results = load_results(tmp_path / "b.json")
    assert (results.recording.machine, results.recording.serial) == ("HMX-400", "M17")

    code, _, err = run("analyze", unnamed, "--store", store, "-q")
    assert code == 2 and "--store needs the machine's serial number: give --serial" in err
    code, _, err = run("analyze", unnamed, "--measured-at", "2024-01-01", "-q")
    assert code == 2 and "are for --store" in err

    undated = _with_serial(unnamed, tmp_path / "undated", "M18")
    meta = json.loads((undated / "meta.json").read_text())
    meta["start_utc"] = None
    (undated / "meta.json").write_text(json.dumps(meta))
    code, _, err = run("analyze", undated, "--store", store, "--machine", machine, "-q")
    assert code == 2 and "store it with --measured-at" in err
    code, _, err = run("analyze", undated, "--store", store, "--machine", machine, "-q",
                       "--measured-at", "2024-03-05T14:22:10+01:00")  # fmt: skip
    assert code == 0, err
    code, out, _ = run("store", "show", "M18", "--store", store)
    assert "2024-03-05 13:22:10" in out and "type HMX-400" in out


def test_record_takes_a_serial(tmp_path: Path) -> None:
    config = parse_machine(example_data())
    channels = channels_for(["X", "Y", "Z"])
    with RecordingWriter.create(
        tmp_path / "source", channels, nominal_period_s=0.004, machine=config, source="test"
    ) as writer:
        writer.append(SampleBlock(np.arange(50) * 0.004, np.zeros((50, len(channels)))))
    machine = tmp_path / "m.toml"
    machine.write_text(example_machine("linuxcnc"))
    code, _, err = run("record", machine, "--link", "replay", "--source", tmp_path / "source",
                       "--speed", "0", "-o", tmp_path / "run", "--serial", "M17", "-q")  # fmt: skip
    assert code == 0, err
    meta = RecordingHead.open(tmp_path / "run").meta
    assert (meta.machine, meta.serial) == ("HMX-400", "M17")
    code, _, err = run("record", machine, "--link", "replay", "--source", tmp_path / "source",
                       "-o", tmp_path / "bad", "--serial", "M 17 ", "-q")  # fmt: skip
    assert code == 2 and "serial 'M 17 '" in err and not (tmp_path / "bad").exists()


def test_the_report_names_the_serial_and_an_unknown_time(unnamed: Path, tmp_path: Path) -> None:
    results = analyze(unnamed, machine=machine_config([AXIS], name="HMX-400"), serial="M17")
    info = results.recording.model_copy(update={"start_utc": None})
    page = write_report(results.model_copy(update={"recording": info}), tmp_path / "r.html")
    html = page.read_text()
    assert "Serial number" in html and "M17" in html and "HMX-400" in html
    assert "unknown (no date)" in html
