"""The acquisition service: every way of stopping closes the recording with what arrived."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.acquire import Progress, acquire, record
from ncmeasure.config import MachineConfig, parse_machine
from ncmeasure.errors import ConfigError, LinkError
from ncmeasure.links.base import AxisBinding, AxisLinkSettings, DriveLink, LinkSettings
from ncmeasure.recording import RecordingWriter, read_recording
from ncmeasure.samples import Channel, LinkEvent, SampleBlock, channels_for
from tests.conftest import example_data

PERIOD_S = 0.004


def machine(**link: Any) -> MachineConfig:
    data = example_data()
    if link:
        data["link"] = link
    return parse_machine(data)


class CountingLink(DriveLink):
    """A link whose rows are a counter: row k at k × 4 ms, values k + column / 100.

    ``fail_after`` rows it raises LinkError, as a link whose bus went away.
    """

    name = "counting"

    def __init__(
        self,
        settings: LinkSettings,
        axes: Sequence[AxisBinding],
        rows_per_read: int = 50,
        fail_after: int | None = None,
        total: int | None = None,
        silent_after: int | None = None,
        ahead_s: float = 0.0,
    ) -> None:
        super().__init__(settings, axes)
        self.rows_per_read = rows_per_read
        self.fail_after = fail_after
        self.total = total
        self.silent_after = silent_after
        self.ahead_s = ahead_s
        self.next = 0
        self.reads = 0

    @property
    def channels(self) -> tuple[Channel, ...]:
        return channels_for([b.name for b in self.axes])

    @property
    def nominal_period_s(self) -> float:
        return PERIOD_S

    def _open(self) -> None:
        self.next = 0

    def now_s(self) -> float | None:
        """The link's time: a cycle per read, ``ahead_s`` ahead of its rows."""
        return self.reads * self.rows_per_read * PERIOD_S + self.ahead_s

    def _read(self, timeout_s: float) -> SampleBlock | None:
        self.reads += 1
        if self.total is not None and self.next >= self.total:
            return None
        if self.silent_after is not None and self.next >= self.silent_after:
            return self.empty_block()  # the drives fell silent: no row, ever
        if self.fail_after is not None and self.next >= self.fail_after:
            self._event(LinkEvent(self.next * PERIOD_S, "fault", "bus off"))
            raise LinkError("bus off")
        k = np.arange(self.next, self.next + self.rows_per_read, dtype=np.float64)
        if self.total is not None:
            k = k[k < self.total]
        self.next += len(k)
        m = len(self.channels)
        values = k[:, None] + np.arange(m)[None, :] / 100
        return SampleBlock(k * PERIOD_S, values)

    def _close(self) -> None:
        pass


def counting_link(config: MachineConfig, **kwargs: Any) -> CountingLink:
    bindings = [AxisBinding(a, AxisLinkSettings()) for a in config.axes]
    return CountingLink(LinkSettings(type="counting"), bindings, **kwargs)


def writer_for(link: DriveLink, folder: Path, config: MachineConfig) -> RecordingWriter:
    return RecordingWriter.create(
        folder,
        link.channels,
        nominal_period_s=link.nominal_period_s,
        machine=config,
        link=link.describe(),
        source=link.name,
    )


def test_duration_stops_on_the_link_clock(tmp_path: Path) -> None:
    config = machine()
    link = counting_link(config)
    with link:
        result = acquire(link, writer_for(link, tmp_path / "run", config), duration_s=1.0)
    assert result.status == "complete"
    recording = read_recording(tmp_path / "run")
    assert len(recording.time_s) == 250  # 0 .. 0.996 s at 4 ms
    assert recording.meta.status == "complete"
    np.testing.assert_array_equal(recording.values[:, 0], np.arange(250))
    assert recording.problems == []


def test_drives_that_fall_silent_still_end_the_recording_on_time(tmp_path: Path) -> None:
    """The duration is checked on the link's clock whether rows arrive or not."""
    config = machine()
    link = counting_link(config, silent_after=100)
    with link:
        result = acquire(link, writer_for(link, tmp_path / "run", config), duration_s=2.0)
    assert result.status == "complete" and result.rows == 100
    assert link.now_s() is not None and link.now_s() >= 2.0  # it ended by the clock


def test_a_link_ahead_of_its_reader_loses_no_row(tmp_path: Path) -> None:
    """A link whose time runs ahead of the rows it still holds (lockstep, a slow reader)."""
    config = machine()
    link = counting_link(config, ahead_s=100.0)
    with link:
        result = acquire(link, writer_for(link, tmp_path / "run", config), duration_s=2.0)
    assert result.status == "complete" and result.rows == 500  # 2 s at 4 ms, every one


@pytest.mark.parametrize("duration", [0.0, -1.0, float("nan"), float("inf")])
def test_a_duration_must_be_positive_and_finite(tmp_path: Path, duration: float) -> None:
    config = machine()
    link = counting_link(config)
    with (
        link,
        writer_for(link, tmp_path / "run", config) as writer,
        pytest.raises(ConfigError, match="a recording lasts a positive, finite"),
    ):
        acquire(link, writer, duration_s=duration)
    with pytest.raises(ConfigError, match="a recording lasts a positive, finite"):
        record(config, out=tmp_path / "r", link="replay", duration_s=duration)
    assert not (tmp_path / "r").exists()


def test_stop_request_closes_as_interrupted(tmp_path: Path) -> None:
    config = machine()
    link = counting_link(config)
    stop = threading.Event()
    seen: list[Progress] = []

    def on_progress(progress: Progress) -> None:
        seen.append(progress)
        if progress.rows > 1000:
            stop.set()

    with link:
        result = acquire(
            link,
            writer_for(link, tmp_path / "run", config),
            stop=stop,
            on_progress=on_progress,
            progress_interval_s=0.0,
        )
    assert result.status == "interrupted"
    recording = read_recording(tmp_path / "run")
    assert recording.meta.status == "interrupted"
    assert len(recording.time_s) == result.rows > 1000
    assert seen and seen[-1].latest["X_current_a"] == pytest.approx(result.rows - 1)


def test_link_failure_keeps_every_sample_before_it(tmp_path: Path) -> None:
    config = machine()
    link = counting_link(config, fail_after=500)
    with link:
        result = acquire(link, writer_for(link, tmp_path / "run", config))
    assert result.status == "link_lost" and "bus off" in (result.error or "")
    recording = read_recording(tmp_path / "run")
    assert recording.meta.status == "link_lost"
    np.testing.assert_array_equal(recording.values[:, 0], np.arange(500))
    assert [e.kind for e in recording.events] == ["fault"]


def test_end_of_source_is_complete(tmp_path: Path) -> None:
    config = machine()
    link = counting_link(config, total=333)
    with link:
        result = acquire(link, writer_for(link, tmp_path / "run", config))
    assert result.status == "complete" and result.rows == 333


def _source_recording(folder: Path, config: MachineConfig, rows: int = 1500) -> Path:
    link = counting_link(config, total=rows, rows_per_read=97)
    writer = writer_for(link, folder, config)
    writer.add_event(LinkEvent(1.0, "gap", "two cycles missing", axis="Y", lost_samples=2))
    with link:
        acquire(link, writer)
    return folder


@pytest.mark.parametrize("speed", [0.0, 4.0])
def test_replay_of_a_recording_records_the_same_samples(tmp_path: Path, speed: float) -> None:
    config = machine()
    source = _source_recording(tmp_path / "source", config)
    result = record(
        config,
        out=tmp_path / "replayed",
        link="replay",
        link_settings={"source": str(source), "speed": speed, "block_rows": 64},
    )
    assert result.status == "incomplete"  # the source's gap is replayed: samples were lost
    assert (result.gaps, result.lost_samples) == (1, 2)
    original, replayed = read_recording(source), read_recording(tmp_path / "replayed")
    np.testing.assert_array_equal(original.time_s, replayed.time_s)
    np.testing.assert_array_equal(original.values, replayed.values)
    assert [c.name for c in original.channels] == [c.name for c in replayed.channels]
    assert [(e.time_s, e.kind, e.axis) for e in replayed.events] == [(1.0, "gap", "Y")]
    assert replayed.meta.source == "replay"
    assert replayed.meta.faster_than_real_time is True
    assert replayed.meta.time_scale == speed


def test_replay_of_a_subset_of_axes(tmp_path: Path) -> None:
    config = machine()
    source = _source_recording(tmp_path / "source", config, rows=200)
    data = example_data()
    data["axes"] = data["axes"][1:2]  # only Y
    result = record(
        parse_machine(data),
        out=tmp_path / "y",
        link="replay",
        link_settings={"source": str(source), "speed": 0},
    )
    replayed = read_recording(result.directory)
    assert [c.name for c in replayed.channels] == [
        "Y_current_a",
        "Y_velocity_mm_min",
        "Y_position_mm",
    ]
    np.testing.assert_array_equal(replayed.values, read_recording(source).values[:, 3:6])


def test_schedule_sets_the_end_and_the_config_hash(tmp_path: Path) -> None:
    from ncmeasure.plan import plan_machine

    config = machine()
    source = _source_recording(tmp_path / "source", config, rows=2500)  # 10 s
    schedule, _ = plan_machine(config)
    short = schedule.model_copy(update={"duration_s": 2.0})
    result = record(
        config,
        out=tmp_path / "run",
        link="replay",
        link_settings={"source": str(source), "speed": 0},
        schedule=short,
        schedule_margin_s=1.0,
    )
    recording = read_recording(result.directory)
    assert result.status == "incomplete"  # the source's gap at 1 s
    assert (recording.meta.status, recording.meta.gaps, recording.meta.lost_samples) == (
        "incomplete",
        1,
        2,
    )
    assert len(recording.time_s) == 750  # 3 s at 4 ms
    assert recording.meta.config_hash == schedule.config_hash


def test_link_blocks_iterator_ends_with_the_source(tmp_path: Path) -> None:
    from ncmeasure.links import make_link

    config = machine()
    source = _source_recording(tmp_path / "source", config, rows=1000)
    with make_link(config, "replay", {"source": str(source), "speed": 0}) as link:
        rows = sum(len(block) for block in link.blocks())
    assert rows == 1000


def test_raw_can_log_replays_onto_a_virtual_bus(tmp_path: Path) -> None:
    import uuid

    import can

    from ncmeasure.links.replay import replay_can_log

    log = tmp_path / "trace.asc"
    with can.Logger(str(log)) as writer:
        for k in range(50):
            writer.on_message_received(
                can.Message(
                    timestamp=k * 0.001,
                    arbitration_id=0x181 + k % 3,
                    data=k.to_bytes(2, "little"),
                    is_extended_id=False,
                )
            )
    channel = f"raw-{uuid.uuid4().hex[:8]}"
    with can.Bus(interface="virtual", channel=channel) as listener:
        sent = replay_can_log(log, channel=channel, speed=0)
        received = []
        while (message := listener.recv(timeout=0.5)) is not None:
            received.append(message)
    assert sent == 50
    assert [m.arbitration_id for m in received] == [0x181 + k % 3 for k in range(50)]
    assert [int.from_bytes(m.data, "little") for m in received] == list(range(50))


def test_a_duration_is_a_limit_the_schedule_a_guide(tmp_path: Path) -> None:
    """--duration with --schedule: the user's duration is honoured, longer or shorter than
    the schedule's end, and the result says which ended the recording."""
    from ncmeasure.cli.record import ended_message
    from ncmeasure.plan import plan_machine

    config = machine()
    source = _source_recording(tmp_path / "source", config, rows=2500)  # 10 s at 4 ms
    schedule, _ = plan_machine(config)
    short = schedule.model_copy(update={"duration_s": 2.0})  # its end: 3 s with the margin
    runs = {}
    for name, duration_s in (("longer", 6.0), ("shorter", 1.0), ("none", None)):
        runs[name] = record(
            config,
            out=tmp_path / name,
            link="replay",
            link_settings={"source": str(source), "speed": 0},
            schedule=short,
            schedule_margin_s=1.0,
            duration_s=duration_s,
        )
    assert len(read_recording(runs["longer"].directory).time_s) == 1500  # 6 s, not 3
    assert runs["longer"].ended_by == "duration"
    assert ended_message(runs["longer"]) == (
        "ended by --duration 6 s; the schedule's end with its margin (3 s) is only a guide"
    )
    assert len(read_recording(runs["shorter"].directory).time_s) == 250
    assert runs["shorter"].ended_by == "duration"
    assert len(read_recording(runs["none"].directory).time_s) == 750
    assert runs["none"].ended_by == "schedule"
    assert ended_message(runs["none"]).startswith("ended at the schedule's end with its margin")
