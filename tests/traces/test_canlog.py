"""CAN logs become recordings: decoded as the CANopen link reads the live bus."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import can
import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.acquire import record
from ncmeasure.cli import app
from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.formats.identity import iso_utc
from ncmeasure.recording import read_recording
from ncmeasure.samples import SimulatedClock
from ncmeasure.traces import detect_format, import_trace
from tests.test_acquire_links import canopen_machine

runner = CliRunner()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """A recording of three simulated drives in lockstep, with its raw log (.blf).

    Node 2 is silent for 30 cycles, so the log holds a gap too.
    """
    folder = tmp_path_factory.mktemp("canlog")
    clock = SimulatedClock()
    with canopen_machine(clock=clock) as (config, drives):
        drives.at_sync(100, drives[1].stop_answering)
        drives.at_sync(130, drives[1].resume)
        drives.at_sync(300, lambda: drives[0].send_emcy(0x7121))
        record(
            config,
            out=folder / "live",
            duration_s=2.0,
            clock=clock,
            link_settings={"raw_log": str(folder / "bus.blf")},
        )
    faults = [e.message for e in read_recording(folder / "live").events if e.kind == "fault"]
    assert not [m for m in faults if "raw CAN log" in m]
    return folder, config


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".trc", ".log"])
@pytest.mark.parametrize("name", ["acq-3cf90770", "can0", "vcan99999999"])
def test_the_raw_log_holds_the_frames_whatever_the_channel_is_called(
    name: str, suffix: str, tmp_path: Path
) -> None:
    """python-can's writers number the channel by the name's last digits (BLF: at most 65535)."""
    clock = SimulatedClock()
    log = tmp_path / f"bus{suffix}"
    channel = f"{tmp_path.name}-{name}"  # unique, and ends as the name does
    with canopen_machine(clock=clock, channel=channel) as (config, _):
        record(
            config,
            out=tmp_path / "live",
            duration_s=0.2,
            clock=clock,
            link_settings={"raw_log": str(log)},
        )
    events = read_recording(tmp_path / "live").events
    assert not [e.message for e in events if "raw CAN log" in e.message]
    frames = list(can.LogReader(str(log)))
    assert sum(1 for m in frames if m.arbitration_id == 0x80) >= 50  # 0.2 s of SYNC at 250 Hz


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_a_raw_log_imported_gives_the_samples_of_the_live_recording(
    recorded: tuple[Path, object], suffix: str, tmp_path: Path
) -> None:
    folder, config = recorded
    log = folder / "bus.blf"
    if suffix != ".blf":  # the same frames in another format python-can writes
        log = tmp_path / f"bus{suffix}"
        with can.Logger(str(log)) as writer:
            for msg in can.LogReader(str(folder / "bus.blf")):
                writer.on_message_received(msg)
    live = read_recording(folder / "live")
    result = import_trace(log, tmp_path / "imported", machine=config)  # type: ignore[arg-type]
    imported = result.recording
    # the log goes on until the link closed, after the live recording's end
    assert len(imported) > len(live)
    assert np.array_equal(live.time_s, imported.time_s[: len(live)])
    assert np.array_equal(live.values, imported.values[: len(live)])
    assert [c.name for c in live.channels] == [c.name for c in imported.channels]
    gaps = [(e.time_s, e.lost_samples, e.axis) for e in imported.events if e.kind == "gap"]
    assert gaps == [(pytest.approx(0.4), 30, "Y")]
    emcy = [e for e in imported.events if e.kind == "emcy"]
    assert len(emcy) == 1 and "motor blocked" in emcy[0].message
    assert emcy[0].time_s == pytest.approx(300 * 0.004)
    assert imported.meta.source == "import:can-log" and imported.meta.status == "incomplete"
    assert any("SYNC cycles" in line for line in result.report)


def test_the_command_line_imports_a_log_by_its_ending(
    recorded: tuple[Path, object], tmp_path: Path
) -> None:
    folder, _ = recorded
    machine = tmp_path / "m.toml"
    assert detect_format(folder / "bus.blf") == "can-log"
    live = read_recording(folder / "live")
    machine.write_text(_machine_toml(live.meta.link), encoding="utf-8")
    result = runner.invoke(
        app,
        ["import", str(folder / "bus.blf"), "--machine", str(machine), "-o", str(tmp_path / "r")],
    )
    assert result.exit_code == 0, result.output
    imported = read_recording(tmp_path / "r")
    assert np.array_equal(live.values, imported.values[: len(live)])


def test_the_command_reads_a_log_without_loading_mdf_support(
    recorded: tuple[Path, object], tmp_path: Path
) -> None:
    # python-can imports asammdf (and pandas) when it is installed, for MF4 logs that
    # the import never reads: the command keeps them out.
    import subprocess
    import sys

    folder, _ = recorded
    machine = tmp_path / "m.toml"
    machine.write_text(_machine_toml(read_recording(folder / "live").meta.link), "utf-8")
    args = ["import", str(folder / "bus.blf"), "--machine", str(machine), "-o", str(tmp_path / "r")]
    code = (
        "import sys\n"
        f"sys.argv = ['ncmeasure', *{args!r}, '-q']\n"
        "from ncmeasure.__main__ import main\n"
        "try:\n    main()\nexcept SystemExit as exc:\n    assert not exc.code, exc.code\n"
        "print(' '.join(sorted({name.split('.')[0] for name in sys.modules})))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    loaded = set(done.stdout.split())
    assert "can" in loaded and "canopen" in loaded
    assert not loaded & {"asammdf", "pandas"}, sorted(loaded & {"asammdf", "pandas"})
    assert len(read_recording(tmp_path / "r")) > 0


def _machine_toml(link: dict[str, object]) -> str:
    """The example machine of the tests with the live recording's CANopen link."""
    from tests.conftest import example_data, machine_toml

    data = example_data()
    settings = dict(link["link"])  # type: ignore[call-overload]
    data["link"] = {
        "type": "canopen",
        "channel": settings["channel"],
        "sync_hz": settings["sync_hz"],
    }
    for i, axis in enumerate(data["axes"]):
        axis["link"] = {"node_id": i + 1, "increments_per_rev": 10_000}
    return machine_toml(data)


def test_a_log_needs_the_machine_files_canopen_link(
    recorded: tuple[Path, object], tmp_path: Path
) -> None:
    folder, _ = recorded
    with pytest.raises(ConfigError, match="CANopen settings"):
        import_trace(folder / "bus.blf", tmp_path / "r")
    result = runner.invoke(app, ["import", str(folder / "bus.blf"), "-o", str(tmp_path / "r")])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert not (tmp_path / "r").exists()


def test_a_log_of_other_nodes_is_refused_and_leaves_nothing(
    recorded: tuple[Path, object], tmp_path: Path
) -> None:
    folder, config = recorded
    data = config.model_dump()  # type: ignore[attr-defined]
    for i, axis in enumerate(data["axes"]):
        axis["link"]["node_id"] = 40 + i
    other = type(config).model_validate(data)
    with pytest.raises(RecordingError, match="no complete SYNC cycle of the nodes 40, 41, 42"):
        import_trace(folder / "bus.blf", tmp_path / "r", machine=other)
    assert not (tmp_path / "r").exists()


def test_a_damaged_log_is_a_clear_error(recorded: tuple[Path, object], tmp_path: Path) -> None:
    _, config = recorded
    broken = tmp_path / "broken.blf"
    broken.write_bytes(b"LOGG" + bytes(200))
    with pytest.raises(RecordingError, match=str(broken)):
        import_trace(broken, tmp_path / "r", machine=config)  # type: ignore[arg-type]
    assert not (tmp_path / "r").exists()


def test_a_log_dates_the_measurement_by_absolute_time_stamps(
    recorded: tuple[Path, object], tmp_path: Path
) -> None:
    """Time stamps in seconds since 1970 (BLF, candump) date the measurement by the first
    frame; a log that counts from 0 gives no date (never the time of the import)."""
    folder, config = recorded
    first_s = next(iter(can.LogReader(str(folder / "bus.blf")))).timestamp
    result = import_trace(folder / "bus.blf", tmp_path / "rec", machine=config)  # type: ignore[arg-type]
    assert result.meta.start_utc == iso_utc(dt.datetime.fromtimestamp(first_s, dt.UTC))
    assert any("from the first frame's time stamp" in line for line in result.report)
    relative = tmp_path / "relative.log"
    with can.Logger(str(relative)) as writer:
        for msg in can.LogReader(str(folder / "bus.blf")):
            msg.timestamp -= first_s
            writer.on_message_received(msg)
    undated = import_trace(relative, tmp_path / "undated", machine=config)  # type: ignore[arg-type]
    assert undated.meta.start_utc is None
