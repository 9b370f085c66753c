"""`ncmeasure record`, `export` and `import` from the command line (replay link)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ncmeasure.acquire import Progress
from ncmeasure.cli import app
from ncmeasure.cli.record import _progress_table
from ncmeasure.config import parse_machine
from ncmeasure.examples import example_machine
from ncmeasure.recording import RecordingWriter, read_recording
from ncmeasure.samples import LinkEvent, SampleBlock, channels_for
from tests.conftest import example_data
from tests.test_recording import FullDisk

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


def test_record_on_a_full_disk_says_so_and_a_retry_goes_into_the_same_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = _source(tmp_path / "run1")
    machine = _machine(tmp_path)
    # 8 s of samples at 4x: several flushes; the disk is full after the first
    args = ("record", machine, "--link", "replay", "--source", source, "--speed", "4", "--quiet")
    disk = FullDisk(monkeypatch, samples_syncs=1)
    code, _, err = run(*args, "-o", tmp_path / "run2")
    assert code == 2, err
    assert "disk full" in err and str(tmp_path / "run2") in err and "Traceback" not in err
    assert not [p.name for p in (tmp_path / "run2").iterdir() if p.name.endswith(".tmp")]
    kept = read_recording(tmp_path / "run2")
    assert 0 < len(kept.time_s) < 2000
    np.testing.assert_array_equal(kept.values, read_recording(source).values[: len(kept.time_s)])

    disk.free()
    code, _, err = run(*args, "-o", tmp_path / "run2")
    assert code == 0, err
    assert f"moved to {tmp_path / 'run2.failed-1'}" in err
    assert len(read_recording(tmp_path / "run2").time_s) == 2000
    assert len(read_recording(tmp_path / "run2.failed-1").time_s) == len(kept.time_s)
    code, _, err = run(*args, "-o", tmp_path / "run2")  # a finished recording stays
    assert code == 2 and "finished recording" in err


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


def test_export_never_writes_through_a_symlink_at_a_temporary_name(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me", encoding="utf-8")
    (tmp_path / "out.csv.tmp").symlink_to(victim)
    (tmp_path / ".out.csv.tmp").symlink_to(victim)
    code, _, err = run("export", _source(tmp_path / "run", rows=10), "-o", tmp_path / "out.csv")
    assert code == 0, err
    assert victim.read_text(encoding="utf-8") == "keep me"
    assert (tmp_path / "out.csv").read_text().startswith("time_s,X_current_a")


def test_export_and_import_bad_input(tmp_path: Path) -> None:
    code, _, err = run("export", tmp_path / "nothing", "-o", tmp_path / "x.csv")
    assert code == 2 and "nothing" in err
    code, _, err = run("export", _source(tmp_path / "run"), "--format", "xlsx")
    assert code == 2 and "expected one of csv, mdf4" in err
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,X_current_a\n0.0,1.0\n0.004,oops\n")
    code, _, err = run("import", bad, "-o", tmp_path / "imp")
    assert code == 2 and "bad.csv:3" in err


def _machine_with(tmp_path: Path, link: str, axis_link: str = "") -> Path:
    path = tmp_path / "m.toml"
    text = example_machine("linuxcnc")
    if axis_link:
        text = text.replace("screw_lead_mm = 20.0", f"screw_lead_mm = 20.0\nlink = {axis_link}")
    path.write_text(text + "\n[link]\n" + link + "\n")
    return path


def test_link_bad_input_from_the_command_line(tmp_path: Path) -> None:
    # missing node id: the canopen link names the axis and the key
    machine = _machine_with(tmp_path, 'type = "canopen"\nchannel = "cli-missing-node"')
    code, _, err = run("record", machine, "-o", tmp_path / "r", "--duration", "1")
    assert code == 2 and "axes[0].link.node_id" in err
    # an EDS that cannot be parsed
    eds = tmp_path / "broken.eds"
    eds.write_text("[DeviceInfo\nthis is not an EDS\n")
    machine = _machine_with(
        tmp_path, 'type = "canopen"\nchannel = "cli-bad-eds"', "{ increments_per_rev = 10000 }"
    )
    code, _, err = run(
        "record",
        machine,
        "--node",
        "X=1",
        "--node",
        "Y=2",
        "--node",
        "Z=3",
        "--eds",
        eds,
        "-o",
        tmp_path / "r",
    )
    assert code in (2, 4) and "broken.eds" in err
    # a register map with overlapping entries
    bad_map = tmp_path / "overlap.toml"
    bad_map.write_text(
        (Path(__file__).parents[1] / "src/ncmeasure/links/modbus/registermaps/generic.toml")
        .read_text()
        .replace("address = 2", "address = 1", 1)
    )
    machine = _machine_with(tmp_path, 'type = "modbus"')
    code, _, err = run(
        "record",
        machine,
        "--unit",
        "X=1",
        "--unit",
        "Y=2",
        "--unit",
        "Z=3",
        "--register-map",
        bad_map,
        "-o",
        tmp_path / "r",
    )
    assert code == 2 and "overlap" in err.lower()
    # an unreachable host (nothing listens on this loopback port)
    code, _, err = run(
        "record",
        machine,
        "--unit",
        "X=1",
        "--unit",
        "Y=2",
        "--unit",
        "Z=3",
        "--register-map",
        "generic",
        "--port",
        "1",
        "-o",
        tmp_path / "r",
    )
    assert code == 4 and "127.0.0.1:1" in err
    assert "Traceback" not in err
    assert not (tmp_path / "r").exists()


def _help_example(command: str) -> list[str]:
    """The example line of a command's --help, as arguments after ``ncmeasure``."""
    import shlex

    code, out, _ = run(command, "--help")
    assert code == 0
    text = " ".join(out.replace("│", " ").split())
    line = text.split("Example: ncmeasure ", 1)[1].split(" -o ", 1)
    return [*shlex.split(line[0]), "-o", line[1].split()[0]]


def test_the_record_help_example_gets_past_validation_on_an_init_file(tmp_path: Path) -> None:
    """The example, word for word on the file `init` writes, reaches the bus (can0 is
    absent here: a link error, exit 4, never a machine-file or option error)."""
    example = _help_example("record")
    assert example[:2] == ["record", "m.toml"]
    code, init, _ = run("init")
    assert code == 0
    (tmp_path / "m.toml").write_text(init)
    args = [str(tmp_path / "m.toml"), *example[2:-1], str(tmp_path / "run1")]
    code, _, err = run("record", *args)
    assert code == 4, err
    assert "cannot open the CAN interface socketcan channel can0" in err
    assert not (tmp_path / "run1").exists()


def test_the_record_help_example_records_simulated_drives(tmp_path: Path) -> None:
    """The example on an init file, on this process' virtual bus with simulated drives
    (instead of SocketCAN's can0) and 1 s instead of 60, records all three axes."""
    import threading
    import uuid

    from ncmeasure.links.canopen.settings import CanOpenSettings
    from ncmeasure.sim.cia402 import serve

    channel = f"help-{uuid.uuid4().hex[:8]}"
    example = _help_example("record")
    swap = {"socketcan": "virtual", "can0": channel, "60": "1", "m.toml": str(tmp_path / "m.toml"),
            "run1": str(tmp_path / "run1")}  # fmt: skip
    (tmp_path / "m.toml").write_text(run("init")[1])
    stop, ready = threading.Event(), threading.Event()
    drives = threading.Thread(
        target=serve,
        args=(CanOpenSettings(type="canopen", channel=channel), [1, 2, 3]),
        kwargs={"stop": stop, "on_ready": lambda _: ready.set()},
        daemon=True,
    )
    drives.start()
    try:
        assert ready.wait(60)
        code, _, err = run(*(swap.get(word, word) for word in example), "--quiet")
    finally:
        stop.set()
        drives.join(10)
    assert code == 0, err
    recording = read_recording(tmp_path / "run1")
    assert recording.axes == ("X", "Y", "Z")
    # real time: 250 SYNC cycles in 1 s, each a row or a counted loss on a busy machine
    rows, lost = len(recording.time_s), recording.meta.lost_samples or 0
    assert rows <= 250 <= rows + lost


def test_axis_set_gives_per_axis_link_settings(tmp_path: Path) -> None:
    machine = _machine(tmp_path)
    nodes = ["--node", "X=1", "--node", "Y=2", "--node", "Z=3"]
    base = ["record", machine, "--link", "canopen", "--interface", "nosuch", *nodes]
    code, _, err = run(*base, "--axis-set", "X.increments_per_rev=0", "-o", tmp_path / "r")
    assert code == 2 and "axes[0].link.increments_per_rev" in err, err  # checked like the file
    code, _, err = run(*base, "--axis-set", "W.node_id=4", "-o", tmp_path / "r")
    assert code == 2 and "--axis-set 'W.node_id=4': the machine has no axis W" in err, err
    code, _, err = run(*base, "--axis-set", "increments_per_rev", "-o", tmp_path / "r")
    assert code == 2 and "expected [AXIS.]KEY=VALUE" in err, err
    code, _, err = run(*base, "--axis-set", "gear_ratio=2", "-o", tmp_path / "r")
    assert code == 2 and "axes[1].link.increments_per_rev" in err, err  # for Y: still missing
    code, _, err = run(
        *base, "--axis-set", "increments_per_rev=4096", "--axis-set", "X.gear_ratio=2.5",
        "-o", tmp_path / "r",
    )  # fmt: skip
    # valid settings: the link gets to the interface, which python-can does not know
    assert code == 2 and "link.interface nosuch: python-can has no such interface" in err, err


def test_a_serial_port_alone_records_over_rtu_not_tcp(tmp_path: Path) -> None:
    machine = _machine(tmp_path)
    units = ["--unit", "X=1", "--unit", "Y=2", "--unit", "Z=3", "--register-map", "generic"]
    port = tmp_path / "ttyX"  # no such device
    code, _, err = run(
        "record", machine, "--link", "modbus", "--serial-port", port, *units, "--duration", "1",
        "-o", tmp_path / "r",
    )  # fmt: skip
    assert code == 4 and str(port) in err, err
    assert "127.0.0.1" not in err and "502" not in err
    code, _, err = run(
        "record", machine, "--link", "modbus", "--serial-port", port, "--set", "mode=tcp",
        *units, "-o", tmp_path / "r",
    )  # fmt: skip
    assert code == 2 and "link.serial_port: a serial port is for mode 'rtu'" in err, err


def test_simulate_drive_port_in_use(tmp_path: Path) -> None:
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, _, err = run(
            "simulate-drive", "--link", "modbus", "--port", str(port), "--duration", "2"
        )
    assert code == 4 and str(port) in err and "Traceback" not in err  # the link cannot serve


def test_simulate_drive_canopen_interface_that_cannot_open(tmp_path: Path) -> None:
    code, _, err = run(
        "simulate-drive", "--link", "canopen", "--interface", "socketcan", "--channel", "nope0",
        "--duration", "1",
    )  # fmt: skip
    assert code == 4 and "Traceback" not in err, err
    assert "cannot open the CAN interface socketcan channel nope0" in err
    code, _, err = run(
        "simulate-drive", "--link", "canopen", "--interface", "nosuch", "--channel", "x",
        "--duration", "1",
    )  # fmt: skip
    assert code == 2 and "Traceback" not in err, err
    assert "--interface nosuch: python-can has no such interface" in err and "socketcan" in err


def test_simulate_drive_on_the_virtual_bus_says_it_serves_this_process_only() -> None:
    code, _, err = run(
        "simulate-drive", "--link", "canopen", "--channel", "only-here", "--duration", "0.3"
    )
    assert code == 0, err
    text = " ".join(err.split())
    assert "on virtual:only-here" in text
    assert "only this process" in text and "another terminal" in text
    assert "--interface socketcan --channel vcan0" in text and "udp_multicast" in text


def test_sigterm_closes_the_recording_and_exits_130(tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import sys
    import time

    source = _source(tmp_path / "run1", rows=10_000)  # 40 s at recorded speed
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ncmeasure",
            "record",
            str(_machine(tmp_path)),
            "--link",
            "replay",
            "--source",
            str(source),
            "-o",
            str(tmp_path / "run2"),
            "--quiet",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    deadline = time.monotonic() + 60  # a guard against a hang, not a timing
    samples = tmp_path / "run2" / "samples.bin"
    while time.monotonic() < deadline:  # stop once some rows are on disk, whenever that is
        if samples.exists() and samples.stat().st_size > 200 * 8 * 10:
            break
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    recording = read_recording(tmp_path / "run2")
    assert recording.meta.status == "interrupted"
    assert 100 < len(recording.time_s) < 10_000
    np.testing.assert_array_equal(
        recording.values, read_recording(source).values[: len(recording.time_s)]
    )


def test_simulate_drive_canopen_serves_a_recording(tmp_path: Path) -> None:
    import threading
    import uuid

    from ncmeasure.acquire import record
    from ncmeasure.config import load_machine

    channel = f"cli-sim-{uuid.uuid4().hex[:8]}"
    done: list[int] = []
    server = threading.Thread(
        target=lambda: done.append(
            run(
                "simulate-drive",
                "--link",
                "canopen",
                "--interface",
                "virtual",
                "--channel",
                channel,
                "--duration",
                "6",
            )[0]
        ),
        daemon=True,
    )
    server.start()
    _wait_for_node(channel, 1)
    machine = _machine_with(
        tmp_path,
        f'type = "canopen"\ninterface = "virtual"\nchannel = "{channel}"',
        "{ increments_per_rev = 10000 }",
    )
    # the command line runs the drives; the recording is made through the Python API
    result = record(
        load_machine(machine),
        out=tmp_path / "r",
        duration_s=1.0,
        axis_settings={"X": {"node_id": 1}, "Y": {"node_id": 2}, "Z": {"node_id": 3}},
    )
    server.join(timeout=30)
    # real time (the drives serve another program): a busy host may skip SYNC cycles,
    # but every cycle of the second is a row or a counted loss
    assert result.status in ("complete", "incomplete")
    rows = len(read_recording(tmp_path / "r").time_s)
    assert rows <= 250 <= rows + result.lost_samples
    assert done == [0]


def _wait_for_node(channel: str, node_id: int) -> None:
    """Until the simulated drive answers an SDO request (a guard of 60 s, not a timing)."""
    import time

    import canopen

    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    try:
        remote = canopen.RemoteNode(node_id, canopen.ObjectDictionary())  # type: ignore[no-untyped-call]
        remote.sdo.RESPONSE_TIMEOUT = 0.2
        network.add_node(remote)
        deadline = time.monotonic() + 60
        while True:
            try:
                remote.sdo.upload(0x1000, 0)
                return
            except canopen.SdoCommunicationError:
                assert time.monotonic() < deadline, "the simulated drive never answered"
    finally:
        network.disconnect()


@pytest.mark.parametrize("duration", ["0", "nan", "-3", "inf"])
def test_a_duration_that_is_no_duration_is_refused(tmp_path: Path, duration: str) -> None:
    source = _source(tmp_path / "run1")
    code, _, err = run(
        "record", _machine(tmp_path), "--link", "replay", "--source", source,
        "--duration", duration, "-o", tmp_path / "r",
    )  # fmt: skip
    assert code == 2 and "a recording lasts a positive, finite number of seconds" in err
    assert "Traceback" not in err and not (tmp_path / "r").exists()


def test_record_warns_of_lost_samples_and_the_recording_says_incomplete(tmp_path: Path) -> None:
    source = tmp_path / "run1"
    config = parse_machine(example_data())
    channels = channels_for(["X", "Y", "Z"])
    with RecordingWriter.create(source, channels, nominal_period_s=0.004, machine=config) as w:
        w.append(SampleBlock(np.arange(1000) * 0.004, np.zeros((1000, len(channels)))))
        w.add_event(LinkEvent(1.0, "gap", "25 samples dropped: no PDOs", lost_samples=25))
    code, _, err = run(
        "record", _machine(tmp_path), "--link", "replay", "--source", source, "--set", "speed=0",
        "-o", tmp_path / "run2",
    )  # fmt: skip
    assert code == 0, err  # a recording with gaps is kept and usable: a warning, no error
    assert "incomplete: 1000 samples" in err
    assert "warning: 25 samples lost in 1 gap(s), 2.4 % of the recording" in err
    meta = read_recording(tmp_path / "run2").meta
    assert (meta.status, meta.gaps, meta.lost_samples) == ("incomplete", 1, 25)


def test_shared_fixtures_missing_under_ci_is_a_failure(monkeypatch: pytest.MonkeyPatch) -> None:
    """A test that needs ../shared/fixtures fails, not skips, where CI must have them."""
    from tests import conftest

    monkeypatch.setattr(conftest, "SHARED_FIXTURES", Path("/nonexistent/shared/fixtures"))
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match=r"CI has \.\./shared beside the clone"):
        conftest.shared_fixture("eds", "elmo_gold.dcf")
    monkeypatch.setenv("CI", "false")
    with pytest.raises(pytest.skip.Exception):
        conftest.shared_fixture("eds", "elmo_gold.dcf")


def test_record_says_which_limit_ended_it(tmp_path: Path) -> None:
    """--duration shorter than --schedule's end: honoured, named, and warned about."""
    machine = _machine(tmp_path)
    assert run("generate", machine, "-o", tmp_path / "prog", "-q")[0] == 0
    source = _source(tmp_path / "run1")
    code, _, err = run(
        "record",
        machine,
        "--link",
        "replay",
        "--source",
        source,
        "--set",
        "speed=0",
        "--schedule",
        tmp_path / "prog" / "schedule.json",
        "--duration",
        "2",
        "-o",
        tmp_path / "run2",
    )
    text = " ".join(err.split())
    assert code == 0, err
    assert len(read_recording(tmp_path / "run2").time_s) == 500
    assert "ended by --duration 2 s; the schedule's end with its margin (" in text
    assert "--duration 2 s ended the recording before the schedule's end" in text


def test_record_says_the_share_of_cycles_the_link_skipped(tmp_path: Path) -> None:
    """SYNC cycles the producer skipped are lost samples and, apart, a share of the
    recording: in the summary and in meta.json, never behind "0 rows lost"."""
    source = tmp_path / "run1"
    config = parse_machine(example_data())
    channels = channels_for(["X", "Y", "Z"])
    with RecordingWriter.create(source, channels, nominal_period_s=0.001, machine=config) as w:
        w.append(SampleBlock(np.arange(900) * 0.001, np.zeros((900, len(channels)))))
        w.add_event(
            LinkEvent(
                0.5, "gap", "100 samples dropped: 100 SYNC cycles not sent (the host fell "
                "behind)", lost_samples=100, details={"missing_sync": 100, "skipped_cycles": 100},
            )
        )  # fmt: skip
    assert read_recording(source).meta.skipped_cycles == 100
    code, _, err = run(
        "record", _machine(tmp_path), "--link", "replay", "--source", source, "--set", "speed=0",
        "-o", tmp_path / "run2",
    )  # fmt: skip
    assert code == 0, err
    text = " ".join(err.split())
    assert "100 samples lost in 1 gap(s), 10 % of the recording" in text
    assert (
        "100 cycles skipped by the link (the host fell behind): 10 % of the recording, "
        "900 Hz instead of 1000 Hz" in text
    )
    meta = read_recording(tmp_path / "run2").meta
    assert (meta.lost_samples, meta.skipped_cycles, meta.skipped_share) == (100, 100, 0.1)
    progress = Progress(1.0, 1.0, 900, 900.0, {}, gaps=1, lost_samples=100, faults=0)
    assert _progress_table(progress).caption == "gaps 1 (100 samples lost) · faults 0"
    progress.skipped_cycles = 100  # the live display says them too
    assert _progress_table(progress).caption == (
        "gaps 1 (100 samples lost, 100 cycles skipped) · faults 0"
    )
