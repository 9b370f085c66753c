"""The replay link: plays a recording back through the drive-link interface.

A recording (ncmeasure's own, or one imported from CSV or a controller trace)
comes back as the same blocks and events a live link would deliver, at the
recorded speed or as fast as possible. The rows are cut into blocks by
count, never by the clock, so a replay yields exactly the recorded samples
whatever the speed: recording a replay gives the same recording again.

:func:`replay_can_log` plays a raw CAN log (python-can ``.blf``/``.asc``)
onto a bus instead, so the real CANopen link can decode it.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import Field

from ncmeasure.errors import ConfigError, LinkError, RecordingError
from ncmeasure.links.base import AxisLinkSettings, DriveLink, LinkSettings, PathSetting
from ncmeasure.recording import Recording, read_recording
from ncmeasure.samples import Channel, LinkEvent, SampleBlock

__all__ = ["ReplayAxis", "ReplayLink", "ReplaySettings", "replay_can_log"]

log = logging.getLogger(__name__)


class ReplaySettings(LinkSettings):
    """``[link]`` settings of the replay link."""

    type: str = "replay"
    source: PathSetting = Field(description="The recording (directory) to play back.")
    speed: Annotated[float, Field(ge=0)] = Field(
        default=1.0,
        description="1 = recorded speed, 2 = twice as fast, 0 = as fast as possible.",
    )
    block_rows: Annotated[int, Field(ge=1, le=1_000_000)] = Field(
        default=250, description="Rows per block handed out."
    )


class ReplayAxis(AxisLinkSettings):
    """Per-axis settings of the replay link."""

    source_axis: str | None = Field(
        default=None,
        description="Axis name in the recording, when it differs from the machine's.",
    )


class ReplayLink(DriveLink):
    """Plays a recording back, deterministically."""

    name = "replay"
    settings_model = ReplaySettings
    axis_settings_model = ReplayAxis

    def __init__(self, settings: LinkSettings, axes: Any) -> None:
        super().__init__(settings, axes)
        assert isinstance(settings, ReplaySettings)
        self.replay: ReplaySettings = settings
        self._recording: Recording | None = None
        self._columns: list[int] = []
        self._channels: tuple[Channel, ...] = ()
        self._next_row = 0
        self._next_event = 0
        self._start_wall = 0.0
        self._source_events: list[LinkEvent] = []
        self._load_layout()

    def _load_layout(self) -> None:
        """Read the recording's channels so that ``channels`` is known before open()."""
        try:
            recording = read_recording(self.replay.source)
        except RecordingError as exc:
            raise ConfigError(f"link.source: {exc.message}", exc.problems) from exc
        by_name = {c.name: i for i, c in enumerate(recording.channels)}
        columns: list[int] = []
        channels: list[Channel] = []
        for binding in self.axes:
            assert isinstance(binding.settings, ReplayAxis)
            source_axis = binding.settings.source_axis or binding.name
            found = [c for c in recording.channels if c.axis == source_axis]
            if not found:
                present = sorted({c.axis for c in recording.channels})
                raise ConfigError(
                    f"link.source: {self.replay.source} has no axis {source_axis} "
                    f"(it has {', '.join(present) or 'none'})"
                )
            for channel in found:
                columns.append(by_name[channel.name])
                channels.append(Channel(binding.name, channel.signal, channel.unit))
        self._recording = recording
        self._columns = columns
        self._channels = tuple(channels)

    @property
    def channels(self) -> tuple[Channel, ...]:
        return self._channels

    @property
    def nominal_period_s(self) -> float:
        assert self._recording is not None
        return self._recording.meta.nominal_period_s

    def describe(self) -> dict[str, Any]:
        description = super().describe()
        assert self._recording is not None
        description["source_meta"] = self._recording.meta.model_dump(mode="json")
        return description

    def _open(self) -> None:
        assert self._recording is not None
        names = {b.name for b in self.axes}
        self._source_events = [
            e for e in self._recording.events if e.axis is None or e.axis in names
        ]
        self._next_row = 0
        self._next_event = 0
        self._start_wall = time.monotonic()

    def _read(self, timeout_s: float) -> SampleBlock | None:
        recording = self._recording
        assert recording is not None
        total = len(recording.time_s)
        if self._next_row >= total:
            self._emit_events_until(float("inf"))
            return None
        stop = min(self._next_row + self.replay.block_rows, total)
        if self.replay.speed > 0:
            # Hand out rows only once their time has come; never more than one block.
            first_s = float(recording.time_s[0])
            due_s = first_s + (time.monotonic() - self._start_wall) * self.replay.speed
            if recording.time_s[self._next_row] > due_s:
                wait_s = (recording.time_s[self._next_row] - due_s) / self.replay.speed
                if wait_s > timeout_s:
                    time.sleep(timeout_s)
                    return self.empty_block()
                time.sleep(wait_s)
                due_s = float(recording.time_s[self._next_row])
            stop = min(stop, int(np.searchsorted(recording.time_s, due_s, side="right")))
            stop = max(stop, self._next_row + 1)
        rows = slice(self._next_row, stop)
        block = SampleBlock(
            recording.time_s[rows].copy(),
            recording.values[rows][:, self._columns].copy(),
        )
        self._next_row = stop
        self._emit_events_until(float(block.time_s[-1]))
        return block

    def _emit_events_until(self, time_s: float) -> None:
        while (
            self._next_event < len(self._source_events)
            and self._source_events[self._next_event].time_s <= time_s
        ):
            self._event(self._source_events[self._next_event])
            self._next_event += 1

    def _close(self) -> None:
        self._next_row = 0


def replay_can_log(
    path: str | Path,
    *,
    interface: str = "virtual",
    channel: str = "ncmeasure",
    speed: float = 1.0,
    **bus_kwargs: Any,
) -> int:
    """Send the frames of a python-can log (.blf, .asc, ...) onto a bus.

    Args:
        path: The log file.
        interface: python-can interface to send on (``virtual`` for tests).
        channel: Its channel.
        speed: Any value > 0 keeps the recorded timing; 0 sends as fast as possible.

    Returns:
        The number of frames sent.

    Raises:
        LinkError: the log cannot be read or the bus cannot be opened.
    """
    import can

    path = Path(path)
    if not path.is_file():
        raise LinkError(f"{path}: no such CAN log")
    try:
        reader = can.LogReader(str(path))
    except (ValueError, OSError) as exc:
        raise LinkError(f"{path}: cannot read the CAN log ({exc})") from exc
    messages = can.MessageSync(reader, timestamps=speed > 0, gap=0.0) if speed > 0 else reader
    sent = 0
    try:
        with can.Bus(interface=interface, channel=channel, **bus_kwargs) as bus:
            for message in messages:
                if message.is_error_frame or message.is_remote_frame:
                    continue
                bus.send(message)
                sent += 1
    except can.CanError as exc:
        raise LinkError(f"cannot replay {path} onto {interface}:{channel}: {exc}") from exc
    log.info("replayed %d frames from %s", sent, path)
    return sent
