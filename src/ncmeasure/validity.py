"""Which sample values can be real: physical ranges and the "no value" codes of loggers.

Controllers and data loggers write a number where they have no value:
``-999999`` is the most common, others use a row of nines, the largest
float32 or float64, or 9.9E37 (the overflow value of many instruments).
Such a number imported as a measurement wrecks every statistic it touches (a
window mean of −58 331 A), and nothing downstream can tell it from data. So
every value is checked once, where it enters ncmeasure (an import) and again
where it is analysed (a recording from any source), against:

* the known codes (:data:`SENTINELS`), exactly, in any channel;
* a physical range per signal (:func:`signal_limit`): the axis' rated current
  and maximum velocity where the machine file gives them (with a margin for
  peaks and overshoot), else generous fixed bounds no feed axis reaches.

A value outside is not a sample: it becomes NaN and is counted, never
clipped or guessed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CURRENT_PEAK_FACTOR",
    "FIXED_LIMITS",
    "SENTINELS",
    "VELOCITY_OVERSHOOT_FACTOR",
    "Implausible",
    "implausible",
    "signal_limit",
]

FloatArray = NDArray[np.float64]

SENTINELS: Final[tuple[float, ...]] = (
    999_999.0,
    9_999_999.0,
    99_999_999.0,
    999_999_999.0,
    9.9e37,
    float(np.finfo(np.float32).max),
    float(np.finfo(np.float64).max),
)
""""No value" codes of controllers and loggers, matched exactly with either sign.

Rows of nines from six digits up (five nines, 99 999 mm/min, is a rapid
traverse some machines reach), 9.9E37 (instrument overflow), and the largest
float32 and float64 (an uninitialised or saturated value).
"""

FIXED_LIMITS: Final[Mapping[str, float]] = {
    "current_a": 2_000.0,
    "velocity_mm_min": 1_200_000.0,
    "velocity_cmd_mm_min": 1_200_000.0,
    "position_mm": 100_000.0,
}
"""Magnitudes no feed axis reaches, used where the machine file says nothing.

2 kA (the largest servo drives for machine tools stay below 1 kA), 20 m/s
(linear-motor axes reach 2–5 m/s), 100 m of travel.
"""

CURRENT_PEAK_FACTOR: Final = 10.0
"""A current beyond this many times the rated current is not real (drives peak at 3–5×)."""

VELOCITY_OVERSHOOT_FACTOR: Final = 2.0
"""A velocity beyond this many times the axis' maximum velocity is not real."""

_LEAST_SENTINEL: Final = min(SENTINELS)

_ABSURD: Final = 1e15
"""Any magnitude at or beyond this is not a measurement of any signal (Sinumerik's
invalid-value marker, 9.2e18, is one)."""


def signal_limit(
    signal: str,
    *,
    rated_current_a: float | None = None,
    max_velocity_mm_min: float | None = None,
) -> float | None:
    """The largest magnitude a real sample of ``signal`` can have, or None for no bound.

    Args:
        signal: An ncmeasure signal (``current_a``, ``velocity_mm_min``, ...).
        rated_current_a: The axis' rated current, when known.
        max_velocity_mm_min: The axis' maximum velocity, when known.
    """
    if signal == "current_a" and rated_current_a is not None and rated_current_a > 0:
        return CURRENT_PEAK_FACTOR * rated_current_a
    if (
        signal in ("velocity_mm_min", "velocity_cmd_mm_min")
        and max_velocity_mm_min is not None
        and max_velocity_mm_min > 0
    ):
        return VELOCITY_OVERSHOOT_FACTOR * max_velocity_mm_min
    return FIXED_LIMITS.get(signal)


def implausible(values: FloatArray, limit: float | None = None) -> NDArray[np.bool_]:
    """True where a value is a "no value" code or beyond ``limit`` in magnitude.

    NaN is not implausible (it already says "no value").
    """
    data = np.asarray(values, dtype=np.float64)
    magnitude = np.abs(data)
    # inf, and every code, is at least the least code: only those few are looked up.
    bad = magnitude >= _LEAST_SENTINEL
    if bad.any():
        large = np.flatnonzero(bad)
        high = magnitude[large]
        bad[large] = np.isin(high, SENTINELS) | (high >= _ABSURD)
    if limit is not None:
        bad |= magnitude > limit
    return bad


@dataclass
class Implausible:
    """A running count of the implausible values of each channel, for a report.

    Attributes:
        limits: The bound applied per channel name (None: codes only).
        counts: Values left out per channel.
        first: Time and value of the first one per channel.
    """

    limits: dict[str, float | None]
    counts: dict[str, int] = field(default_factory=dict)
    first: dict[str, tuple[float, float]] = field(default_factory=dict)

    @classmethod
    def for_channels(
        cls, channels: Mapping[str, str], axes: Mapping[str, Mapping[str, Any]] | None = None
    ) -> Implausible:
        """Limits for channels given as {name: signal} with axis facts per channel name.

        Args:
            channels: Channel name to its signal.
            axes: Channel name to the facts of its axis (``rated_current_a``,
                ``max_velocity_mm_min``), where known.
        """
        facts = axes or {}
        limits = {
            name: signal_limit(
                signal,
                rated_current_a=_number(facts.get(name, {}).get("rated_current_a")),
                max_velocity_mm_min=_number(facts.get(name, {}).get("max_velocity_mm_min")),
            )
            for name, signal in channels.items()
        }
        return cls(limits)

    def clean(self, name: str, time_s: FloatArray, values: FloatArray) -> FloatArray:
        """``values`` with the implausible ones replaced by NaN (a copy where any is)."""
        bad = implausible(values, self.limits.get(name))
        if not bad.any():
            return values
        where = np.flatnonzero(bad)
        self.counts[name] = self.counts.get(name, 0) + len(where)
        if name not in self.first:
            self.first[name] = (float(time_s[where[0]]), float(values[where[0]]))
        cleaned = np.array(values, dtype=np.float64, copy=True)
        cleaned[bad] = np.nan
        return cleaned

    def lines(self) -> list[str]:
        """One sentence per channel with values left out."""
        result = []
        for name, count in self.counts.items():
            time_s, value = self.first[name]
            limit = self.limits.get(name)
            bound = f" or beyond ±{limit:g}" if limit is not None else ""
            result.append(
                f"{name}: {count} value(s) left out as not physically possible (a 'no value' "
                f"code such as -999999{bound}); first {value:g} at t = {time_s:g} s"
            )
        return result


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
