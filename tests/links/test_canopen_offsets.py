"""`ncmeasure apply-compensation`: the reviewed torque offsets written to simulated CiA 402 drives.

The writes are the links' (:mod:`ncmeasure.links.canopen.offsets`); the file is read by
:mod:`ncmeasure.compensation.offset_file`.

The drives are ncmeasure's simulated CiA 402 drives (:mod:`ncmeasure.sim.cia402`) on
python-can's virtual bus, a channel of their own per test, in this process. The file
is the one `ncmeasure compensation --controller cia402` writes; the machine file's
[link] names the bus as for `ncmeasure record`. Every wait is bounded by the link's
SDO time-out.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from ncmeasure.cli import app
from ncmeasure.formats.results import write_results
from ncmeasure.sim.cia402 import (
    ABORT_READ_ONLY,
    DriveScaling,
    SimulatedDrive,
    SimulatedDrives,
)
from ncmeasure.sim.rig import rig_mechanics
from ncmeasure.sim.signals import PatternSource
from tests.compensation.example import Z_OFFSET_A, example_results

RATED_CURRENT_A = 17.7
VALUE = round(1000 * Z_OFFSET_A / RATED_CURRENT_A)  # 113 ‰, as in the golden file
NODES = {"X": 1, "Y": 2, "Z": 3}
ANSWER_S = 30.0
"""The SDO time-out of the machine file: a guard against a hang, however loaded the computer."""


def run(*args: str | Path) -> tuple[int, str, str]:
    result = CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "250"})
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture
def channel() -> str:
    return f"ncm-apply-{uuid.uuid4().hex}-bus"


def machine_text(channel: str, link: str = "", nodes: dict[str, int] | None = None) -> str:
    code, text, _ = run("init", "--controller", "linuxcnc")
    assert code == 0
    for axis, node in (nodes or NODES).items():
        text = text.replace(
            f'[[axes]]\nname = "{axis}"',
            f'[[axes]]\nname = "{axis}"\nlink = {{ node_id = {node}, increments_per_rev = 10000 }}',
        )
    table = link or f'type = "canopen"\ninterface = "virtual"\nchannel = "{channel}"'
    return text + f"\n[link]\n{table}\nsdo_timeout_s = {ANSWER_S}\n"


@pytest.fixture
def machine_file(tmp_path: Path, channel: str) -> Path:
    path = tmp_path / "machine.toml"
    path.write_text(machine_text(channel), encoding="utf-8")
    return path


@pytest.fixture
def offsets(tmp_path: Path, machine_file: Path) -> Path:
    """The reviewed file: `ncmeasure compensation --controller cia402`, as a user makes it."""
    results = write_results(example_results(), tmp_path / "run1.results.json")
    target = tmp_path / "z-offset.toml"
    code, _, err = run("compensation", results, "--controller", "cia402",
                       "--machine", machine_file, "-o", target)  # fmt: skip
    assert code == 0, err
    return target


@pytest.fixture
def drives(channel: str) -> Iterator[SimulatedDrives]:
    scaling = DriveScaling(mechanics=rig_mechanics(rated_current_a=RATED_CURRENT_A))
    with SimulatedDrives.start(
        channel, {0: 1, 1: 2, 2: 3}, PatternSource(), scaling=scaling
    ) as sim:
        yield sim


def offset_of(drive: SimulatedDrive) -> int:
    return int.from_bytes(drive.value(0x60B2, 0), "little", signed=True)


def test_without_yes_nothing_is_sent(
    offsets: Path, machine_file: Path, drives: SimulatedDrives, channel: str
) -> None:
    code, out, err = run("apply-compensation", offsets, "--machine", machine_file)
    assert code == 0, err
    assert f"axis Z: node 3, 0x60B2:00 = {VALUE} (‰ of the rated torque, 11.3 %)" in out
    assert f"interface virtual, channel {channel}, 1000000 bit/s" in out
    assert "nothing was sent" in out and "--yes" in out
    assert all(d.sdo_requests == 0 for d in drives.drives)
    assert offset_of(drives.node(3)) == 0


def test_yes_writes_reads_back_and_writes_nothing_else(
    offsets: Path, machine_file: Path, drives: SimulatedDrives, channel: str
) -> None:
    import can

    with can.Bus(interface="virtual", channel=channel) as listener:  # what goes over the bus
        code, out, err = run("apply-compensation", offsets, "--machine", machine_file, "--yes")
        frames = []
        while (frame := listener.recv(timeout=0)) is not None:
            frames.append((frame.arbitration_id, bytes(frame.data).hex().upper()))
    assert code == 0, err
    sent = [data for cob_id, data in frames if cob_id == 0x603]  # the client's SDO requests
    assert sent == ["40B2600000000000", "2BB2600071000000", "40B2600000000000"]
    assert f"data {sent[1]}" in offsets.read_text(encoding="utf-8")  # the frame the file lists
    assert {cob_id for cob_id, _ in frames} == {0x603, 0x583}  # SDO only: no NMT, no SYNC
    assert f"axis Z: node 3, 0x60B2:00 was 0, wrote {VALUE}, read back {VALUE}" in out
    assert "wrote 1 torque offset(s)" in out
    z = drives.node(3)
    assert offset_of(z) == VALUE
    assert (z.sdo_requests, z.sdo_writes) == (3, 1)  # read, write, read back
    assert drives.node(1).sdo_requests == drives.node(2).sdo_requests == 0
    code, out, err = run("apply-compensation", offsets, "--machine", machine_file, "--yes")
    assert code == 0 and f"was {VALUE}, wrote {VALUE}" in out, err


def test_a_drive_that_takes_0x60b2_only_by_pdo(
    offsets: Path, machine_file: Path, drives: SimulatedDrives
) -> None:
    drives.node(3).abort_sdo(0x60B2, ABORT_READ_ONLY, upload=False)
    code, out, err = run("apply-compensation", offsets, "--machine", machine_file, "--yes")
    assert code == 4, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert f"axis Z (node 3): writing 0x60B2:00 = {VALUE} failed: SDO abort 0x06010002" in lines[0]
    assert "RPDO" in lines[0] and lines[0].endswith("no other axis was written")
    assert offset_of(drives.node(3)) == 0


def test_no_drive_answers(offsets: Path, machine_file: Path) -> None:
    # no drive on the bus: no answer, however long one waits
    code, out, err = run("apply-compensation", offsets, "--machine", machine_file, "--yes",
                         "--set", "sdo_timeout_s=0.3")  # fmt: skip
    assert code == 4, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "axis Z (node 3): reading 0x60B2:00 failed" in lines[0], err
    assert "no SDO answer within 0.3 s" in lines[0] and "check the node id" in lines[0]


def test_a_value_the_drive_does_not_keep(
    offsets: Path, machine_file: Path, drives: SimulatedDrives, monkeypatch: pytest.MonkeyPatch
) -> None:
    z = drives.node(3)
    original = z._write

    def clamping(index: int, subindex: int, data: bytes) -> None:  # a drive that limits it
        if index == 0x60B2:
            data = (100).to_bytes(2, "little", signed=True)
        original(index, subindex, data)

    monkeypatch.setattr(z, "_write", clamping)
    code, out, err = run("apply-compensation", offsets, "--machine", machine_file, "--yes")
    assert code == 4, (out, err)
    assert f"wrote 0x60B2:00 = {VALUE} but read back 100 (it was 0)" in err
    assert err.count("\n") == 1


def test_a_failure_says_what_was_written_before(
    tmp_path: Path, machine_file: Path, drives: SimulatedDrives
) -> None:
    two = tmp_path / "two.toml"
    two.write_text(
        "".join(
            f'[[sdo_write]]\naxis = "{axis}"\nnode_id = {node}\nindex = 0x60B2\nsubindex = 0\n'
            f'data_type = "INTEGER16"\nvalue = {value}\n\n'
            for axis, node, value in (("Y", 2, 50), ("Z", 3, -7))
        ),
        encoding="utf-8",
    )
    drives.node(3).abort_sdo(0x60B2, ABORT_READ_ONLY, upload=False)
    code, out, err = run("apply-compensation", two, "--machine", machine_file, "--yes")
    assert code == 4, (out, err)
    assert "axis Y: node 2, 0x60B2:00 was 0, wrote 50, read back 50" in out
    assert err.strip().endswith("written before it: axis Y 0 -> 50"), err
    assert offset_of(drives.node(2)) == 50 and offset_of(drives.node(3)) == 0


def _entry(**changes: Any) -> str:
    entry: dict[str, Any] = {"axis": '"Z"', "node_id": 3, "index": "0x60B2", "subindex": 0,
                             "data_type": '"INTEGER16"', "value": VALUE}  # fmt: skip
    entry.update(changes)
    return "[[sdo_write]]\n" + "".join(f"{k} = {v}\n" for k, v in entry.items())


@pytest.mark.parametrize(
    ("text", "words"),
    [
        (_entry(index="0x6071"), "writes 0x6071:00; ncmeasure writes only the torque offset"),
        (_entry(subindex=1), "writes 0x60B2:01"),
        (_entry(data_type='"INTEGER32"'), "0x60B2 is INTEGER16, not 'INTEGER32'"),
        (_entry(value=40000), "value must be an INTEGER16, not 40000"),
        (_entry(value=-1200), "value -1200 is -120 % of the rated torque"),
        (_entry(node_id=4), "the file writes to node 4, the machine file names node 3"),
        (_entry(axis='"W"'), "axis W of the file is not in the machine file"),
        (_entry() + _entry(), "axis Z more than once"),
        ("frict_comp.mode = 3\n", "not a cia402 compensation file"),
        ("", "not a cia402 compensation file"),
    ],
)
def test_a_file_that_is_not_reviewed_offsets_is_refused(
    tmp_path: Path, machine_file: Path, text: str, words: str
) -> None:
    path = tmp_path / "offsets.toml"
    path.write_text(text, encoding="utf-8")
    code, out, err = run("apply-compensation", path, "--machine", machine_file, "--yes")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and words in lines[0], err
    assert out == ""


@pytest.mark.parametrize(
    ("link", "words"),
    [
        ('type = "modbus"\nhost = "127.0.0.1"', "the machine file's link is 'modbus'"),
        ('type = "canopen"\nlisten_only = true\nsync_producer = false\nnmt_control = false',
         "link.listen_only: the machine file says the controller owns this bus"),
    ],
)  # fmt: skip
def test_a_link_that_may_not_write_is_refused(
    tmp_path: Path, offsets: Path, channel: str, link: str, words: str
) -> None:
    machine = tmp_path / "other.toml"
    machine.write_text(machine_text(channel, link=link), encoding="utf-8")
    code, _, err = run("apply-compensation", offsets, "--machine", machine, "--yes")
    assert code == 2 and words in err and err.count("\n") == 1, err


def test_the_link_settings_of_the_command_line(
    tmp_path: Path, offsets: Path, drives: SimulatedDrives, channel: str
) -> None:
    """--channel and --set over the machine file's [link], as `ncmeasure record` takes them."""
    machine = tmp_path / "elsewhere.toml"
    machine.write_text(machine_text("another-bus"), encoding="utf-8")
    code, _, err = run("apply-compensation", offsets, "--machine", machine, "--yes",
                       "--channel", channel, "--set", "sdo_timeout_s=20")  # fmt: skip
    assert code == 0, err
    assert offset_of(drives.node(3)) == VALUE
    code, _, err = run("apply-compensation", offsets, "--machine", machine, "--set", "bitrate=0")
    assert code == 2 and "link.bitrate" in err


def test_help_teaches() -> None:
    code, out, _ = run("apply-compensation", "--help")
    assert code == 0
    for words in ("0x60B2", "--yes", "--machine", "read back", "compensation --controller cia402"):
        assert words in out, words
