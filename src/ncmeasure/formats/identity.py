"""Which machine was measured, and when: the serial number and the measurement's time.

A machine file names a machine *type* (one file and one program serve every
machine of the type); the serial number of the machine measured is given at
measurement and travels with the data: ``meta.json`` (``serial``),
``results.json`` (``recording.serial``), the fleet store, the report.

The time of a measurement is when its samples were taken, never when a file was
imported or analysed: a recording made here knows it, an import takes it from the
data or from the user (``--measured-at``), else it is unknown (``start_utc`` null).
"""

from __future__ import annotations

import datetime as dt
import re
from typing import Annotated, Final

from pydantic import StringConstraints

from ncmeasure.errors import ConfigError

__all__ = [
    "SERIAL_PATTERN",
    "SERIAL_WORDS",
    "Serial",
    "check_serial",
    "iso_utc",
    "parse_utc",
]

SERIAL_PATTERN: Final = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9 ._+#-]{0,62}[A-Za-z0-9._+#-])?")
"""A serial: letters, digits, space and ``. _ + # -``, 1–64 characters, no space at an end."""
SERIAL_WORDS: Final = "letters, digits, space and . _ + # - (1 to 64 characters)"

Serial = Annotated[str, StringConstraints(pattern=f"^{SERIAL_PATTERN.pattern}$")]
"""A serial number as a model field."""


def check_serial(serial: str) -> str:
    """``serial`` if it is a valid serial number, else a :class:`ConfigError` in words."""
    if not SERIAL_PATTERN.fullmatch(serial):
        raise ConfigError(f"serial {serial!r}: use {SERIAL_WORDS}")
    return serial


def parse_utc(text: str, what: str) -> dt.datetime:
    """An ISO 8601 date-time as an aware UTC datetime; without a zone it is taken as UTC.

    Args:
        text: ``2024-03-05T14:22:10+01:00``, ``2024-03-05 14:22:10`` (UTC), ``2024-03-05``.
        what: What the text is, for the message (``--measured-at``).

    Raises:
        ConfigError: ``text`` is not an ISO 8601 date or date-time.
    """
    try:
        when = dt.datetime.fromisoformat(text.strip())
    except ValueError as exc:
        raise ConfigError(
            f"{what} {text!r}: not an ISO 8601 date-time (e.g. 2024-03-05T14:22:10+01:00, "
            "or 2024-03-05 14:22:10 in UTC)"
        ) from exc
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.UTC)
    return when.astimezone(dt.UTC)


def iso_utc(when: dt.datetime) -> str:
    """``when`` as ISO 8601 text in UTC, to the millisecond (as ``meta.json`` keeps it)."""
    return when.astimezone(dt.UTC).isoformat(timespec="milliseconds")
