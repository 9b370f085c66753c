"""The drive-link contract: what every link (CANopen, Modbus, replay, third-party) offers.

Modelled on python-can's ``BusABC``: the public methods live here and do the
shared work (state checks, argument checks, idempotent close, context
manager); a backend implements the underscore hooks ``_open``, ``_read`` and
``_close``.

A link reads the drive signals of several axes and hands them out as
:class:`~ncmeasure.samples.SampleBlock` objects (the vocabulary of
:mod:`ncmeasure.samples`); things that happen on the way are
:class:`~ncmeasure.samples.LinkEvent` objects, collected with
:meth:`DriveLink.events`.

Settings: every backend declares a pydantic model for the link-wide settings
(:attr:`DriveLink.settings_model`, the ``[link]`` table of the machine file)
and one for the per-axis settings (:attr:`DriveLink.axis_settings_model`, the
``link`` table of an ``[[axes]]`` entry, e.g. a node id).

Clock: a link paces itself and stamps its rows by its
:class:`~ncmeasure.samples.LinkClock`, real time for real drives. With
ncmeasure's own simulated drives it runs on a
:class:`~ncmeasure.samples.SimulatedClock` (:meth:`DriveLink.use_clock`):
link and simulator in lockstep, cycle by cycle, the time stamps seconds of the
simulated machine, as fast as the computer allows.
"""

from __future__ import annotations

import logging
import threading
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Annotated, Any, ClassVar, Literal, Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Strict, ValidationError

from ncmeasure.config import AxisConfig, format_validation_error
from ncmeasure.errors import ConfigError, LinkError
from ncmeasure.samples import REAL_TIME, Channel, LinkClock, LinkEvent, SampleBlock

__all__ = [
    "AxisBinding",
    "AxisLinkSettings",
    "DriveLink",
    "LinkSettings",
    "PathSetting",
]

log = logging.getLogger(__name__)


PathSetting = Annotated[Path, Strict(False)]
"""A file named in link settings: TOML gives it as text."""


class LinkSettings(BaseModel):
    """Base of a link's ``[link]`` settings; ``type`` names the link.

    Types are strict, as in the machine file: ``"250"`` is text, not a number.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    type: str


class AxisLinkSettings(BaseModel):
    """Base of a link's per-axis settings (``[axes.link]``); types are strict."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


@dataclass(frozen=True)
class AxisBinding:
    """An axis of the machine file with the link's settings for it."""

    axis: AxisConfig
    settings: AxisLinkSettings

    @property
    def name(self) -> str:
        """The axis name."""
        return self.axis.name


class DriveLink(ABC):
    """A connection to the drives of several axes that yields sample blocks.

    Use it as a context manager::

        with make_link(config) as link:
            while (block := link.read(timeout_s=1.0)) is not None: ...

    Subclasses set :attr:`name`, :attr:`settings_model`,
    :attr:`axis_settings_model` and implement ``_open``, ``_read`` and
    ``_close``; ``_read`` returns an empty block when nothing arrived within
    the timeout and ``None`` at the end of the data (replay).
    """

    name: ClassVar[str] = ""
    settings_model: ClassVar[type[LinkSettings]] = LinkSettings
    axis_settings_model: ClassVar[type[AxisLinkSettings]] = AxisLinkSettings

    def __init__(self, settings: LinkSettings, axes: Sequence[AxisBinding]) -> None:
        if not axes:
            raise ConfigError("a drive link needs at least one axis")
        self.settings = settings
        self.axes = tuple(axes)
        self._state: Literal["new", "open", "closed"] = "new"
        self._ready_on = False
        self._events: list[LinkEvent] = []
        self._events_lock = threading.Lock()
        self._clock = REAL_TIME

    # --- construction from the machine file ------------------------------------------

    @classmethod
    def from_tables(
        cls,
        link_table: Mapping[str, Any],
        axes: Sequence[tuple[AxisConfig, Mapping[str, Any]]],
    ) -> Self:
        """Validate the ``[link]`` table and the per-axis tables, then build the link.

        Raises:
            ConfigError: one ``location: message`` line per problem, located in
                the machine file (``link.bitrate``, ``axes[1].link.node_id``).
        """
        problems: list[str] = []
        settings: LinkSettings | None = None
        try:
            settings = cls.settings_model.model_validate({"type": cls.name, **link_table})
        except ValidationError as exc:
            problems += format_validation_error(exc, "link")
        bindings: list[AxisBinding] = []
        for index, (axis, table) in enumerate(axes):
            try:
                bindings.append(AxisBinding(axis, cls.axis_settings_model.model_validate(table)))
            except ValidationError as exc:
                problems += format_validation_error(exc, f"axes[{index}].link")
        if problems or settings is None:
            problems = list(dict.fromkeys(problems))  # a link-wide problem, once
            raise ConfigError(f"the settings of the {cls.name} link are not valid", problems)
        return cls(settings, bindings)

    # --- what a backend provides ------------------------------------------------------

    @property
    @abstractmethod
    def channels(self) -> tuple[Channel, ...]:
        """The columns of every block this link yields, in order."""

    @property
    @abstractmethod
    def nominal_period_s(self) -> float:
        """The intended time between two rows (SYNC period, poll period, ...)."""

    def describe(self) -> dict[str, Any]:
        """Link settings and scale factors for a recording's metadata.

        ``clock`` says ``simulated`` when the link ran in lockstep with a
        simulator (:class:`~ncmeasure.samples.SimulatedClock`), else ``real time``.
        """
        return {
            "link": self.settings.model_dump(mode="json"),
            "axes": {b.name: b.settings.model_dump(mode="json") for b in self.axes},
            "clock": "simulated" if self._clock.lockstep else "real time",
        }

    def now_s(self) -> float | None:
        """The link's time now, on the time axis of its rows; None where it has none.

        Ends a recording on time when rows stop arriving (a silent drive, a
        lost connection): the acquisition checks its duration against this.
        """
        return None

    @abstractmethod
    def _open(self) -> None:
        """Connect, configure the drives, start streaming."""

    @abstractmethod
    def _read(self, timeout_s: float) -> SampleBlock | None:
        """Return the rows that arrived, waiting at most ``timeout_s`` for the first."""

    @abstractmethod
    def _close(self) -> None:
        """Stop streaming and release the bus, socket or port. Must not raise."""

    # --- the public methods -----------------------------------------------------------

    @property
    def clock(self) -> LinkClock:
        """The clock the link paces itself by and stamps rows with (default real time)."""
        return self._clock

    def use_clock(self, clock: LinkClock) -> None:
        """Run the link on ``clock``: a :class:`~ncmeasure.samples.SimulatedClock`, in lockstep.

        Only ncmeasure's own simulated drives follow a simulated clock; real
        drives need :data:`~ncmeasure.samples.REAL_TIME`.

        Raises:
            LinkError: the link is open (set the clock before :meth:`open`).
            TypeError: ``clock`` is not a :class:`LinkClock`.
        """
        if not isinstance(clock, LinkClock):
            raise TypeError(f"use_clock needs a LinkClock, not {type(clock).__name__}")
        if self._state == "open":
            raise LinkError(
                f"the clock of the {self.name} link cannot change while it is open; "
                "set it before open()"
            )
        self._clock = clock

    @property
    def is_open(self) -> bool:
        """True between a successful :meth:`open` and :meth:`close`."""
        return self._state == "open"

    def open(self) -> None:
        """Connect and start streaming.

        Raises:
            LinkError: the bus, host or drives cannot be reached or configured.
        """
        if self._state == "open":
            raise LinkError(f"{self.name} link is already open")
        if self._state == "closed":
            raise LinkError(f"{self.name} link was closed; make a new one")
        try:
            self._open()
        except BaseException:
            self._safe_close()
            raise
        self._state = "open"
        log.debug(
            "%s link open: %d axes, %d channels", self.name, len(self.axes), len(self.channels)
        )

    def read(self, timeout_s: float = 1.0) -> SampleBlock | None:
        """The samples that arrived since the last call.

        Args:
            timeout_s: How long to wait for the first new row.

        Returns:
            A block (empty when nothing came within the timeout), or ``None``
            when the source has no more data (end of a replay).

        Raises:
            LinkError: the link failed and cannot go on.
        """
        if self._state != "open":
            raise LinkError(f"{self.name} link is not open")
        if timeout_s < 0:
            raise ValueError("timeout_s must not be negative")
        return self._read(timeout_s)

    def blocks(self, timeout_s: float = 1.0) -> Iterator[SampleBlock]:
        """Yield the blocks with rows as they arrive, until the source ends (replay).

        For scripts::

            with make_link(config) as link:
                for block in link.blocks():
                    print(block.time_s[-1], block.values[-1])
        """
        while (block := self.read(timeout_s)) is not None:
            if len(block):
                yield block

    def events(self) -> list[LinkEvent]:
        """Events since the last call (gaps, faults, reboots, reconnects)."""
        with self._events_lock:
            events, self._events = self._events, []
        return events

    def close(self) -> None:
        """Stop and release everything (a ready output left on is set off first, as far
        as the drive still answers). Safe to call more than once."""
        if self._state == "closed":
            return
        if self._state == "open" and self._ready_on:
            try:
                self._set_ready(False)
                self._ready_on = False
            except Exception as exc:  # a lost link cannot set it off: say so, close anyway
                log.warning("%s link: the ready output could not be set off: %s", self.name, exc)
        self._safe_close()

    def _safe_close(self) -> None:
        self._state = "closed"
        try:
            self._close()
        except Exception:  # closing must never hide the error that led here
            log.exception("error while closing the %s link", self.name)

    def _event(self, event: LinkEvent) -> None:
        """Record an event (backends call this, from any thread)."""
        log.info(
            "%s link: %s%s: %s",
            self.name,
            event.kind,
            f" ({event.axis})" if event.axis else "",
            event.message,
        )
        with self._events_lock:
            self._events.append(event)

    # --- the recorder's ready signal ------------------------------------------------------

    @property
    def signals_ready(self) -> bool:
        """True when the link can set an output the controller waits on before its
        program moves (the machine file names one: a drive's digital output, a coil)."""
        return False

    def set_ready(self, on: bool) -> None:
        """Set the recorder's ready output on (recording) or off.

        The main program waits for it (the machine file's ``machine.ready_input``)
        before its first move. A link that cannot signal ready (:attr:`signals_ready`
        False) does nothing and logs that it did not.

        Raises:
            LinkError: the link is not open, or the drive or PLC refused the write.
        """
        if self._state != "open":
            raise LinkError(f"{self.name} link is not open")
        if not self.signals_ready:
            log.info("%s link: no ready output named; the ready signal is not set", self.name)
            return
        self._set_ready(bool(on))
        self._ready_on = bool(on)

    def _set_ready(self, on: bool) -> None:
        """Write the ready output (backends with :attr:`signals_ready`)."""
        raise NotImplementedError

    def empty_block(self) -> SampleBlock:
        """A block without rows, for a read that timed out."""
        return SampleBlock(np.empty(0), np.empty((0, len(self.channels))))

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
