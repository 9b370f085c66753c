"""The one exception tree of ncmeasure.

Every error ncmeasure raises on purpose derives from :class:`NcMeasureError`
and also from the built-in exception it resembles, so callers may catch
either::

    NcMeasureError
    ├── ConfigError (ValueError)         a machine file or setting is invalid
    │   └── PlanError                    the measurement does not fit an axis
    ├── DialectError (ValueError)        a controller definition or template is broken
    ├── ProgramError (ValueError)        an NC program cannot be read
    │   └── ProgramCheckError            a program leaves its limits or its schedule
    ├── OutputError (OSError)            results cannot be written
    ├── ComparisonError (ValueError)     results that cannot be compared
    ├── RecordingError (OSError)         a recording cannot be written or read
    ├── StoreError (OSError)             the fleet store cannot be reached, read or written
    ├── DependencyError (ImportError)    an optional package is missing (names the extra)
    └── LinkError (ConnectionError)      a drive link failed (bus, network, drive)
        ├── LinkTimeoutError (TimeoutError)  a drive did not answer in time
        └── PublishError                 a broker or shop-floor client link failed

Third-party exceptions are wrapped at the boundary (``raise ... from exc``).
The command line is the only place that turns these into exit codes.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

__all__ = [
    "ComparisonError",
    "ConfigError",
    "DependencyError",
    "DialectError",
    "LinkError",
    "LinkTimeoutError",
    "NcMeasureError",
    "OutputError",
    "PlanError",
    "ProgramCheckError",
    "ProgramError",
    "PublishError",
    "RecordingError",
    "StoreError",
]


class NcMeasureError(Exception):
    """Base of every error ncmeasure raises on purpose.

    Args:
        message: One sentence a technician can act on.
        problems: Optional ``location: message`` lines, one per problem.
    """

    def __init__(self, message: str, problems: Iterable[str] = ()) -> None:
        self.message = message
        self.problems: Sequence[str] = tuple(problems)
        super().__init__(message)

    def __str__(self) -> str:
        if not self.problems:
            return self.message
        return self.message + "\n" + "\n".join(f"  {line}" for line in self.problems)


class ConfigError(NcMeasureError, ValueError):
    """A machine file, its TOML syntax, or a setting is invalid."""


class PlanError(ConfigError):
    """The requested measurement cannot be planned inside the axis limits."""


class DialectError(NcMeasureError, ValueError):
    """A controller definition or one of its templates is missing or broken."""


class ProgramError(NcMeasureError, ValueError):
    """An NC program cannot be read by ncmeasure's program reader."""


class ProgramCheckError(ProgramError):
    """A program leaves the axis limits or disagrees with its schedule."""


class OutputError(NcMeasureError, OSError):
    """Output files or directories cannot be written."""


class RecordingError(NcMeasureError, OSError):
    """A recording cannot be written, or is not a readable recording."""


class StoreError(NcMeasureError, OSError):
    """The fleet store cannot be reached, read or written (or is of a newer schema)."""


class DependencyError(NcMeasureError, ImportError):
    """An optional package is missing; the message names the extra to install."""


class LinkError(NcMeasureError, ConnectionError):
    """A drive link failed: bus or network error, a drive refusing or not answering."""


class LinkTimeoutError(LinkError, TimeoutError):
    """A drive or the bus did not answer in time."""


class PublishError(LinkError):
    """Results could not be published: a broker cannot be reached, refuses the
    credentials or the TLS handshake, or does not acknowledge; an OPC UA server
    cannot start."""


class ComparisonError(NcMeasureError, ValueError):
    """Results that cannot be compared at all (different machines, axes or units)."""
