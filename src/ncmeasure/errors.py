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
    └── OutputError (OSError)            results cannot be written

Third-party exceptions are wrapped at the boundary (``raise ... from exc``).
The command line is the only place that turns these into exit codes.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

__all__ = [
    "ConfigError",
    "DialectError",
    "NcMeasureError",
    "OutputError",
    "PlanError",
    "ProgramCheckError",
    "ProgramError",
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
