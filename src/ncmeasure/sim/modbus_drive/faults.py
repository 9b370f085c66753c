"""Fault switches of the simulated Modbus drive: silent, exception, late, disconnect.

A :class:`Fault` says how the drives misbehave (for which units, in which
window of server time); :class:`DriveFaults` holds the fault in force and is
safe to change from any thread while the server answers.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

from pymodbus.constants import ExcCodes

__all__ = ["NO_FAULT", "DriveFaults", "Fault"]

_VALID_EXCEPTION_CODES = frozenset(int(code) for code in ExcCodes)


@dataclass(frozen=True)
class Fault:
    """A misbehaviour of the simulated drives.

    Args:
        silent: Read requests get no answer at all.
        exception_code: Answer with this Modbus exception code (1-8, 10, 11).
        delay_s: Answer this late (wall-clock).
        disconnect: Close the TCP connection instead of answering.
        units: The unit ids affected; ``None``: all.
        from_s: The fault starts at this server time (``None``: at once). On a
            :class:`~ncmeasure.samples.SimulatedClock` this is simulated time, so a
            test sets a fault for exactly the poll cycles it means, however slow the
            computer is.
        until_s: The fault ends at this server time (``None``: when cleared).
    """

    silent: bool = False
    exception_code: int | None = None
    delay_s: float = 0.0
    disconnect: bool = False
    units: frozenset[int] | None = None
    from_s: float | None = None
    until_s: float | None = None

    def __post_init__(self) -> None:
        if self.exception_code is not None and self.exception_code not in _VALID_EXCEPTION_CODES:
            known = ", ".join(str(c) for c in sorted(_VALID_EXCEPTION_CODES))
            raise ValueError(f"exception code {self.exception_code} is not one of {known}")
        if self.delay_s < 0:
            raise ValueError("delay_s must not be negative")

    def applies_to(self, unit_id: int, time_s: float | None = None) -> bool:
        """Whether the fault affects ``unit_id`` (at server time ``time_s``, when given)."""
        if self.units is not None and unit_id not in self.units:
            return False
        if time_s is None:
            return True
        return (self.from_s is None or time_s >= self.from_s) and (
            self.until_s is None or time_s < self.until_s
        )


NO_FAULT = Fault()


class DriveFaults:
    """The current fault of a server; safe to change from any thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._fault = NO_FAULT
        self._drop: Callable[[], None] | None = None

    def set(self, fault: Fault) -> None:
        """Replace the current fault."""
        with self._lock:
            self._fault = fault

    def clear(self) -> None:
        """Back to normal answers."""
        self.set(NO_FAULT)

    def current(self) -> Fault:
        """The fault in force."""
        with self._lock:
            return self._fault

    def drop_connections(self) -> None:
        """Close every open TCP connection (clients must reconnect)."""
        with self._lock:
            drop = self._drop
        if drop is not None:
            drop()

    def _attach(self, drop: Callable[[], None] | None) -> None:
        with self._lock:
            self._drop = drop
