"""The header every JSON file of ncmeasure starts with, and the one way such a file is read.

Each file (``schedule.json``, a recording's ``meta.json``, ``results.json``, a
comparison) begins with the same three keys::

    format              what the file is: "ncmeasure-schedule", "ncmeasure-results", ...
    format_version      the version of that format; a reader refuses a newer one
    ncmeasure_version   the ncmeasure that wrote the file (for the record only)

:class:`FileHeader` declares them once; a file's model derives from it and
names its format and version in two class variables. :func:`read_file` reads
any of them the same way: a bounded regular file, JSON, the header checked
(a file of another kind or of a newer version is refused with one line that
says so), then the whole model, with one ``location: message`` line per problem.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from ncmeasure._version import __version__
from ncmeasure.errors import NcMeasureError
from ncmeasure.inputs import format_validation_error, parse_json, read_text

__all__ = ["FileHeader", "check_header", "read_file"]

_M = TypeVar("_M", bound="FileHeader")


def _schema_of_header(schema: dict[str, Any], model: type[BaseModel]) -> None:
    """The JSON Schema says which format and version a file of this kind carries."""
    fmt, version = getattr(model, "FORMAT", ""), getattr(model, "FORMAT_VERSION", 0)
    properties = schema.get("properties", {})
    if fmt and "format" in properties:
        properties["format"].update(const=fmt, default=fmt)
        properties["format_version"].update(default=version)


class FileHeader(BaseModel):
    """``format``, ``format_version`` and ``ncmeasure_version``: the start of every file.

    A subclass sets :attr:`FORMAT` and :attr:`FORMAT_VERSION`; a model built in
    code gets them without naming them, a file read from disk must carry them.
    """

    model_config = ConfigDict(json_schema_extra=_schema_of_header)

    FORMAT: ClassVar[str] = ""
    """The value of ``format`` in files of this kind."""
    FORMAT_VERSION: ClassVar[int] = 0
    """The version this ncmeasure writes and reads."""
    WRITTEN_BY: ClassVar[str] = ""
    """The command that writes such a file, for messages (``ncmeasure analyze``)."""

    format: str = Field(default="", description="What the file is.")
    format_version: int = Field(default=0, description="Version of the file's format.")
    ncmeasure_version: str = Field(
        default=__version__, description="The ncmeasure that wrote the file."
    )

    @model_validator(mode="before")
    @classmethod
    def _stamp(cls, data: Any) -> Any:
        """A model built in code carries its format and version without naming them."""
        if isinstance(data, dict) and cls.FORMAT:
            return {"format": cls.FORMAT, "format_version": cls.FORMAT_VERSION, **data}
        return data

    @field_validator("format")
    @classmethod
    def _check_format(cls, value: str) -> str:
        if cls.FORMAT and value != cls.FORMAT:
            raise ValueError(f"format must be {cls.FORMAT!r}, not {value!r}")
        return value


def check_header(
    data: Any,
    model: type[FileHeader],
    source: str | Path,
    error: type[NcMeasureError],
    *,
    what: str,
    older: str | None = None,
) -> None:
    """Refuse a file of another kind, or of a version this ncmeasure does not read.

    Args:
        data: The file's parsed JSON.
        model: The file's model (its ``FORMAT`` and ``FORMAT_VERSION``).
        source: The file, for the messages.
        error: The exception to raise.
        what: What the file is, in words (``results file``, ``recording``).
        older: What to do about an older version; None: an older version is read
            (the model then says what it cannot take).

    Raises:
        error: Another format, a newer version, or an older one where ``older`` is given.
    """
    if not isinstance(data, dict) or data.get("format") != model.FORMAT:
        found = data.get("format") if isinstance(data, dict) else type(data).__name__
        writer = f"; `{model.WRITTEN_BY}` writes one" if model.WRITTEN_BY else ""
        raise error(
            f"{source}: not an ncmeasure {what} (format is {found!r}, expected "
            f"{model.FORMAT!r}{writer})"
        )
    version = data.get("format_version")
    if isinstance(version, int) and version > model.FORMAT_VERSION:
        raise error(
            f"{source}: {what} format_version {version} is newer than this ncmeasure reads "
            f"({model.FORMAT_VERSION}); update ncmeasure"
        )
    if older is not None and version != model.FORMAT_VERSION:
        raise error(
            f"{source}: {what} format_version {version!r}, this ncmeasure reads "
            f"{model.FORMAT_VERSION}; {older}"
        )


def read_file(
    path: str | Path,
    model: type[_M],
    error: type[NcMeasureError],
    *,
    what: str,
    max_bytes: int,
    missing: str | None = None,
    older: str | None = None,
) -> _M:
    """Read one of ncmeasure's JSON files: bounded, parsed, header checked, validated.

    Args:
        path: The file.
        model: Its model.
        error: The exception to raise for anything wrong with it.
        what: What the file is, in words (``results file``).
        max_bytes: The largest file read (a larger one is refused, not loaded).
        missing: The message when the file does not exist.
        older: What to do about an older version (see :func:`check_header`).

    Raises:
        error: The file is missing, too large, not JSON, of another kind or version,
            or not valid (one ``location: message`` line per problem).
    """
    source = Path(path)
    text = read_text(source, f"a {what}", max_bytes, error, missing)
    data = parse_json(text, str(source), error)
    check_header(data, model, source, error, what=what, older=older)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise error(f"{source}: not a valid {what}", format_validation_error(exc)) from exc
