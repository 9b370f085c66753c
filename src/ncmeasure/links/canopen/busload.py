"""CAN bus load of a TPDO layout: bits on the wire per SYNC cycle, nominal and worst case."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = [
    "BusLoad",
    "bus_load",
    "frame_bits",
]

log = logging.getLogger(__name__)

# --- bus load ---------------------------------------------------------------------------


def frame_bits(data_bytes: int, *, worst_case: bool = False) -> int:
    """Bits on the wire of one classical CAN data frame with an 11-bit identifier.

    Nominal: 47 + 8n (start of frame to interframe space). Worst case adds the
    stuff bits: at most one per 4 bits of the 34 + 8n stuffed bits, i.e.
    floor((34 + 8n - 1) / 4); an 8-byte frame is 111 bits nominal, 135 worst.
    """
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"a CAN frame carries 0 to 8 bytes, not {data_bytes}")
    bits = 47 + 8 * data_bytes
    if worst_case:
        bits += (34 + 8 * data_bytes - 1) // 4
    return bits


@dataclass(frozen=True)
class BusLoad:
    """Bus load of one SYNC cycle repeated at ``sync_hz``."""

    frames_per_cycle: int
    bits_per_cycle: int
    worst_bits_per_cycle: int
    sync_hz: float
    bitrate: int

    @property
    def load(self) -> float:
        """Fraction of the bitrate used, nominal frame lengths."""
        return self.bits_per_cycle * self.sync_hz / self.bitrate

    @property
    def worst_load(self) -> float:
        """Fraction of the bitrate used with worst-case bit stuffing."""
        return self.worst_bits_per_cycle * self.sync_hz / self.bitrate

    def max_sync_hz(self, max_load: float) -> float:
        """The highest SYNC rate whose worst-case load stays at ``max_load``."""
        return max_load * self.bitrate / self.worst_bits_per_cycle

    def describe(self) -> str:
        """One line with the numbers."""
        return (
            f"{self.frames_per_cycle} frames per SYNC cycle, {self.bits_per_cycle} bits "
            f"({self.worst_bits_per_cycle} with worst-case bit stuffing) at "
            f"{self.sync_hz:g} Hz on {self.bitrate / 1000:g} kbit/s = "
            f"{100 * self.load:.1f} % ({100 * self.worst_load:.1f} % worst case)"
        )


def bus_load(
    pdo_bytes: Sequence[int], sync_hz: float, bitrate: int, *, sync_frame: bool = True
) -> BusLoad:
    """Bus load of a SYNC frame plus the given PDOs per cycle.

    Args:
        pdo_bytes: Data length of every PDO sent per SYNC cycle (all nodes).
        sync_hz: SYNC frequency.
        bitrate: Bus bitrate in bit/s.
        sync_frame: Count the (empty) SYNC frame itself.

    Example: one 8-byte PDO with SYNC at 1 kHz on 1 Mbit/s is 47 + 111 = 158
    bits per cycle, a load of 0.158 (0.190 worst case: 55 + 135 bits).
    """
    if sync_hz <= 0 or bitrate <= 0:
        raise ValueError("sync_hz and bitrate must be positive")
    sizes = [*([0] if sync_frame else []), *pdo_bytes]
    return BusLoad(
        frames_per_cycle=len(sizes),
        bits_per_cycle=sum(frame_bits(n) for n in sizes),
        worst_bits_per_cycle=sum(frame_bits(n, worst_case=True) for n in sizes),
        sync_hz=sync_hz,
        bitrate=bitrate,
    )
