"""Plain words for the report: what a signature or a cause means, numbers as text.

The vocabulary follows the assembly diagnosis of the method ("What the
patterns mean"): each pattern of friction along the travel points at parts
of the feed drive a technician can check.
"""

from __future__ import annotations

import datetime as dt
import math
from typing import Final

from ncmeasure.analysis.judgement.summary import format_number
from ncmeasure.formats.results import CauseName, Signature

__all__ = [
    "CAUSE_CHECKS",
    "CAUSE_TITLES",
    "SIGNATURE_SHORT",
    "SIGNATURE_TEXT",
    "format_date",
    "format_mm",
    "format_number",
    "format_with_error",
]

SIGNATURE_TEXT: Final[dict[Signature, str]] = {
    "flat": "Friction is about the same along the whole travel.",
    "rising_to_loose_bearing": "Friction rises as the nut moves towards the loose bearing.",
    "rising_to_fixed_bearing": "Friction rises as the nut moves towards the fixed bearing.",
    "high_at_both_ends": (
        "Friction is high near both ends of the travel and lowest in the middle."
    ),
    "step": "Friction changes in a step between two positions.",
    "irregular": "Friction varies along the travel without a clear pattern.",
    "insufficient_data": "Too few positions were measured to judge the travel.",
    "not_identifiable": (
        "Each speed was measured at its own positions: the pattern along the travel cannot "
        "be told from the speed dependence."
    ),
}
"""One sentence per signature of friction along the travel."""

SIGNATURE_SHORT: Final[dict[Signature, str]] = {
    "flat": "flat",
    "rising_to_loose_bearing": "rises towards the loose bearing",
    "rising_to_fixed_bearing": "rises towards the fixed bearing",
    "high_at_both_ends": "high at both ends",
    "step": "step",
    "irregular": "irregular",
    "insufficient_data": "too few positions",
    "not_identifiable": "not separable from speed",
}
"""A few words per signature, for the summary table."""

CAUSE_TITLES: Final[dict[CauseName, str]] = {
    "none": "No assembly fault indicated",
    "preload_or_carriage": "Preload (bearings, ball-screw nut) or guide carriages",
    "loose_bearing": "Loose bearing shifted or tilted",
    "fixed_bearing": "Fixed bearing shifted or tilted",
    "screw_nut": "Ball-screw nut shifted or tilted",
    "guide_rail": "Guide rail misaligned",
    "cover_or_seal": "Cover, seal or cable chain sticking",
}
"""A short title per assembly cause."""

CAUSE_CHECKS: Final[dict[CauseName, str]] = {
    "none": "Friction along the travel shows no pattern of an assembly deviation.",
    "preload_or_carriage": (
        "Raises friction by the same amount everywhere. Check the preload of the "
        "bearings and the ball-screw nut, and the guide carriages (shift, tilt, preload)."
    ),
    "loose_bearing": (
        "Bends the screw most when the nut is close to the loose bearing. Check the "
        "radial position and tilt of the loose-bearing housing against the nut."
    ),
    "fixed_bearing": (
        "Bends the screw most when the nut is close to the fixed bearing. Check the "
        "radial position and tilt of the fixed-bearing housing against the nut."
    ),
    "screw_nut": (
        "Raises friction near both bearings, not in the middle. Check the position "
        "and tilt of the ball-screw nut in its housing."
    ),
    "guide_rail": (
        "Friction follows the rail's deviation, e.g. a ramp. Check the alignment of "
        "the guide rails to each other and to the screw."
    ),
    "cover_or_seal": (
        "Gives a constant offset or a step. Check telescopic covers, wipers, seals and "
        "the cable chain for sticking or bad alignment."
    ),
}
"""What a cause does to friction and what to check, per cause."""


def _decimals(value: float, significant: int) -> int:
    """Decimals that show ``value`` to ``significant`` figures (never negative)."""
    if value == 0 or not math.isfinite(value):
        return 0
    return max(0, significant - 1 - math.floor(math.log10(abs(value))))


def format_with_error(value: float | None, error: float | None, digits: int = 3) -> str:
    """``value ± error`` in common decimals a technician can read: ``1.62 ± 0.03``.

    The value keeps ``digits`` significant figures and gains one decimal at most
    where its error is smaller; a value smaller than its error is shown to the
    error's precision. An error that would round to zero keeps one figure.
    """
    text = format_number(value, digits)
    if value is None or not math.isfinite(value) or error is None or not math.isfinite(error):
        return text
    error = abs(error)
    if "e" in text or error == 0:
        return f"{text} ± {format_number(error, 2)}"
    value_decimals = _decimals(value, digits)
    error_decimals = _decimals(error, 1)
    if abs(value) < error:
        decimals = error_decimals + 1
    else:
        decimals = min(max(error_decimals, value_decimals), value_decimals + 1)
    value_text = f"{value:.{decimals}f}"
    if float(value_text) == 0:
        value_text = value_text.lstrip("-")
    error_text = f"{error:.{decimals}f}"
    if float(error_text) == 0:
        error_text = format_number(error, 1)
    return f"{value_text} ± {error_text}"


def format_mm(value: float) -> str:
    """A position in mm to 0.1 mm, without trailing zeros: ``61.5``, ``750``, ``-458.5``."""
    rounded = round(value, 1) + 0.0  # + 0.0 turns -0.0 into 0.0
    return f"{rounded:g}" if abs(rounded) < 1e6 else f"{rounded:.0f}"


def format_date(iso: str | None) -> str:
    """An ISO timestamp as ``2026-01-15 08:30 UTC``; the text itself when it does not parse."""
    if not iso:
        return "–"
    try:
        moment = dt.datetime.fromisoformat(iso)
    except ValueError:
        return iso
    if moment.tzinfo is not None:
        moment = moment.astimezone(dt.UTC)
        return moment.strftime("%Y-%m-%d %H:%M UTC")
    return moment.strftime("%Y-%m-%d %H:%M")
