"""Any delimited text file, read through a column map: the file's columns become channels.

Data collectors, PLC loggers and spreadsheets write CSV files with their own
column names, units and number formats. A column map (a small TOML file) says
which column holds which ncmeasure channel and how to convert it, so such a
file imports without a script::

    period_s = 0.1                      # no time column: row k is at k x 0.1 s
    # time = { column = "t", scale = 0.001 }   # or: a time column (here ms)
    [channels]
    X_current_a = { column = "X1_CurrentFeedback" }
    X_velocity_mm_min = { column = "X1_ActualVelocity", scale = 60 }   # mm/s -> mm/min

Every value becomes ``raw x scale + offset``. The separator (comma,
semicolon, tab) is the one whose split of the header finds the mapped
columns, the decimal mark (point or comma) is fixed by the first mapped
number with a fraction; ``delimiter`` and ``decimal`` force either. Lines may
end with LF, CRLF or CR; quoted cells are read as the :mod:`csv` module reads
them. Columns the map does not name are never parsed (text columns are
fine) and are listed in the report; an empty cell becomes NaN and is
counted. The file is read as a stream: rows go to the recording in chunks of
:data:`~ncmeasure.traces.merge.CHUNK_ROWS`.

Reference of every key: ``docs/traces.md``, section "Any CSV with a column map".
"""

from __future__ import annotations

import csv
import datetime as dt
import itertools
import logging
import math
import os
from array import array
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Final, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
)
from pydantic_core import PydanticCustomError

from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.inputs import format_validation_error
from ncmeasure.recording import channel_from_name, check_times
from ncmeasure.samples import SIGNAL_UNITS, Channel
from ncmeasure.traces.job import (
    ImportJob,
    ProgressFn,
    TraceImport,
    check_source,
    check_target,
    order_channels,
    run_import,
)
from ncmeasure.traces.matlab import import_matlab_meta, is_matlab
from ncmeasure.traces.merge import CHUNK_ROWS
from ncmeasure.traces.parquet import import_parquet_meta, is_parquet
from ncmeasure.traces.text import (
    TextLines,
    decimal_mark,
    iso_datetime,
    normalize_unit,
    parse_number,
    preamble_date,
    unit_factor,
)

if TYPE_CHECKING:  # the machine-file models: exporting a recording reads no machine file
    from ncmeasure.config import MachineConfig

__all__ = ["ChannelColumn", "ColumnMap", "TimeColumn", "import_columns", "load_column_map"]

log = logging.getLogger(__name__)

#: The name of the format in ``meta.json`` (``link.format``) and the recording's source.
FORMAT_NAME: Final = "columns"
_SEPARATORS: Final = (",", ";", "\t")
_SEPARATOR_NAMES: Final = {",": "comma", ";": "semicolon", "\t": "tab"}
_PREAMBLE_DATE_LINES: Final = 200
"""Lines of a preamble searched for the measurement's date."""

_Finite = Annotated[float, Field(allow_inf_nan=False)]
ColumnRef = Annotated[str, Field(min_length=1)] | Annotated[int, Field(ge=1)]
"""A column: its text in the header row, or its 1-based position (``column = 1``)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


def _nonzero(value: float) -> float:
    if value == 0:
        raise PydanticCustomError("scale", "must not be 0 (every value would become the offset)")
    return value


def _channel_name(name: str) -> str:
    if channel_from_name(name) is None:
        raise PydanticCustomError(
            "channel_name",
            "{name} is not an ncmeasure channel name: <AXIS>_<signal> with signal one of "
            "{signals} (e.g. X_current_a)",
            {"name": name, "signals": ", ".join(SIGNAL_UNITS)},
        )
    return name


_ChannelName = Annotated[str, AfterValidator(_channel_name)]


class ChannelColumn(_Model):
    """Where one channel comes from: ``{ column = "...", scale = 60, offset = 0 }``."""

    column: ColumnRef = Field(
        description="The column's name in the file's header row (exactly as written), its "
        "1-based position (column = 2), or in a MATLAB file the variable (data.current)."
    )
    scale: _Finite = Field(
        default=1.0, description="Multiplies the raw value into the channel's unit (mm/s -> 60)."
    )
    offset: _Finite = Field(default=0.0, description="Added after scaling, in the channel's unit.")

    _check_scale = field_validator("scale")(classmethod(lambda cls, v: _nonzero(v)))


class TimeColumn(_Model):
    """The time column: ``{ column = "t", scale = 0.001 }`` for milliseconds."""

    column: ColumnRef = Field(
        description="The column's name in the file's header row, its 1-based position "
        "(column = 1, e.g. under an empty header cell), or in a MATLAB file the variable."
    )
    scale: Annotated[_Finite, Field(gt=0)] = Field(
        default=1.0, description="Multiplies the raw time into seconds (ms -> 0.001)."
    )
    offset: _Finite = Field(default=0.0, description="Added after scaling, in seconds.")
    format: Literal["number", "iso"] | None = Field(
        default=None,
        description="number: the column holds times in numbers (x scale into seconds); iso: "
        "ISO 8601 date-times (2024-03-05 14:22:10.250, UTC without a zone), and the first "
        "row is the measurement's start. Default: told from the first row.",
    )

    @field_validator("format")
    @classmethod
    def _iso_unscaled(cls, value: str | None, info: ValidationInfo) -> str | None:
        if value == "iso" and (info.data.get("scale", 1.0) != 1 or info.data.get("offset", 0.0)):
            raise PydanticCustomError(
                "time_format", "date-times are not scaled: leave scale and offset out"
            )
        return value


class ColumnMap(_Model):
    """A column map: how the columns of a delimited text file become channels.

    Exactly one of ``period_s`` and ``time`` is given. ``channels`` maps
    ncmeasure channel names (``<AXIS>_<signal>``, e.g. ``X_current_a``) to
    columns of the file.
    """

    period_s: Annotated[_Finite, Field(gt=0)] | None = Field(
        default=None,
        description="Sample period when the file has no time column: row k is at k x period_s.",
    )
    time: TimeColumn | None = Field(
        default=None, description="The time column, when the file has one."
    )
    channels: dict[_ChannelName, ChannelColumn] = Field(
        min_length=1, description="Channel name (<AXIS>_<signal>) -> column."
    )
    delimiter: Literal[",", ";", "\t"] | None = Field(
        default=None, description="Force the separator; detected from the header when not given."
    )
    decimal: Literal[".", ","] | None = Field(
        default=None,
        description="Force the decimal mark; detected from the first mapped number with a "
        "fraction when not given.",
    )
    skip_lines: Annotated[int, Field(ge=0)] = Field(
        default=0,
        description="Lines skipped before the header is looked for. Not needed for a "
        "preamble: the header is the first line holding every column named by its text. One "
        "ISO 8601 date-time in the lines before the header (Date: 2024-03-05 14:22:10) is the "
        "measurement's start.",
    )

    @field_validator("time")
    @classmethod
    def _one_time_base(cls, value: TimeColumn | None, info: ValidationInfo) -> TimeColumn | None:
        if "period_s" not in info.data:
            return value  # period_s itself is invalid and reported
        if value is None and info.data["period_s"] is None:
            raise PydanticCustomError(
                "time_base",
                "the map needs a time base: period_s = <seconds> when the file has no time "
                'column, or time = { column = "<name>" }',
            )
        if value is not None and info.data["period_s"] is not None:
            raise PydanticCustomError(
                "time_base", "give either period_s or time, not both (time comes from one of them)"
            )
        return value

    @field_validator("decimal")
    @classmethod
    def _decimal_not_delimiter(cls, value: str | None, info: ValidationInfo) -> str | None:
        if value == "," and info.data.get("delimiter") == ",":
            raise PydanticCustomError(
                "decimal", "a decimal comma does not work with delimiter = ','"
            )
        return value


def load_column_map(path: str | os.PathLike[str]) -> ColumnMap:
    """Read and validate a column map (TOML).

    Raises:
        ConfigError: The file is missing, is not TOML, or is not a valid
            column map; one ``MAP.toml: location: message`` line per problem.
    """
    from ncmeasure.config import read_toml  # the machine file's models: an import only

    source = Path(path)
    data = read_toml(source, "a column map")
    try:
        return ColumnMap.model_validate(data)
    except ValidationError as exc:
        lines = format_validation_error(
            exc, schema_hint="docs/traces.md, column map", tables={"channels"}
        )
        raise ConfigError(
            f"{source} is not a valid column map", [f"{source}: {line}" for line in lines]
        ) from exc


def import_columns(
    path: str | os.PathLike[str],
    directory: str | os.PathLike[str],
    mapping: ColumnMap | str | os.PathLike[str],
    *,
    machine: MachineConfig | None = None,
    progress: ProgressFn | None = None,
    measured_at: dt.datetime | None = None,
) -> TraceImport:
    """Make a recording from a delimited text file through a column map.

    Args:
        path: The text file (comma, semicolon or tab separated, with a header row).
        directory: The new recording (must not exist or be empty).
        mapping: The column map, or the path of its TOML file (:func:`load_column_map`).
        machine: The machine file: the mapped axes must be its axes; their
            data go into ``meta.json``.
        progress: Called now and then with ``(bytes_read, total_bytes)``.
        measured_at: When the machine was measured; else the first row of a
            date-time column, else one ISO 8601 date-time in the skipped preamble,
            else unknown (``start_utc`` null).

    Returns:
        The recording (source ``import:columns``) and the report: which column
        became which channel, separator and decimal mark, the columns left
        out, empty cells.

    Raises:
        ConfigError: The column map is not valid, or names an axis the
            machine does not have.
        RecordingError: ``file:line: problem`` for a mapped column missing
            from the header, a cell that is not a number, a time that does
            not increase, or a recording that cannot be written. Nothing is
            left in ``directory`` then.
    """
    if isinstance(mapping, ColumnMap):
        column_map, map_label, map_file = mapping, "the column map", None
    else:
        column_map, map_label, map_file = load_column_map(mapping), str(mapping), Path(mapping).name
    _check_axes(column_map, machine, map_label)
    source, target = Path(path), Path(directory)
    check_source(source)
    check_target(target)
    job = ImportJob(
        source,
        target,
        FORMAT_NAME,
        machine=machine,
        axis_names=None,
        progress=progress,
        measured_at=measured_at,
    )
    job.link["mapping"] = map_file
    job.link["column_map"] = column_map.model_dump(mode="json", exclude_none=True)

    def read(job: ImportJob) -> RecordingMeta:
        if is_matlab(job.path):
            return _read_matlab(job, column_map, map_label)
        if is_parquet(job.path):
            return _read_parquet(job, column_map, map_label)
        with TextLines(job.path, job) as lines:
            try:
                return _Reader(job, column_map, map_label, lines).read()
            except csv.Error as exc:
                raise RecordingError(
                    f"{lines.where()}: the line cannot be split into cells ({exc}; a quote "
                    '" that is never closed joins all lines after it into one cell)'
                ) from exc

    return run_import(job, read)


def _read_matlab(job: ImportJob, mapping: ColumnMap, map_label: str) -> RecordingMeta:
    """A MATLAB file through the map: each ``column`` names a variable (:mod:`.matlab`)."""
    refs, scales, open_sink = _whole_file_columns(job, mapping, map_label, "variable")
    return import_matlab_meta(job, refs, scales, mapping.period_s, map_label, open_sink)


def _read_parquet(job: ImportJob, mapping: ColumnMap, map_label: str) -> RecordingMeta:
    """A Parquet file through the map: each ``column`` names a column (:mod:`.parquet`)."""
    refs, scales, open_sink = _whole_file_columns(job, mapping, map_label, "column")
    return import_parquet_meta(job, refs, scales, mapping.period_s, open_sink)


def _whole_file_columns(
    job: ImportJob, mapping: ColumnMap, map_label: str, word: str
) -> tuple[
    dict[str, str | int],
    dict[str, tuple[float, float]],
    Callable[[], Callable[[NDArray[np.float64], NDArray[np.float64]], None]],
]:
    """What a binary file's reader needs from the map: target -> column (``time_s``
    first, then the channels in the recording's order), target -> (scale, offset), and
    how to open the recording; the report's lines on them."""
    channels = _ordered_channels(mapping, job.machine)
    refs: dict[str, str | int] = {}
    scales: dict[str, tuple[float, float]] = {}
    if mapping.time is not None:
        refs["time_s"] = mapping.time.column
        scales["time_s"] = (mapping.time.scale, mapping.time.offset)
        job.note(
            f"time_s [s]: from {word} {mapping.time.column!r} "
            f"({_conversion(mapping.time.scale, mapping.time.offset)})"
        )
    else:
        job.note(f"time_s [s]: no time {word}; sample k is at k x {mapping.period_s:.10g} s")
    for channel in channels:
        spec = mapping.channels[channel.name]
        refs[channel.name] = spec.column
        scales[channel.name] = (spec.scale, spec.offset)
        job.note(
            f"{channel.name} [{channel.unit}]: from {word} {spec.column!r} "
            f"({_conversion(spec.scale, spec.offset)})"
        )
    unused = [k for k in ("delimiter", "decimal", "skip_lines") if k in mapping.model_fields_set]
    if unused:
        job.note(f"{', '.join(unused)} of {map_label}: not used for this file")

    def open_sink() -> Callable[[NDArray[np.float64], NDArray[np.float64]], None]:
        return job.open_sink(channels, nominal_period_s=mapping.period_s).append

    return refs, scales, open_sink


def _check_axes(mapping: ColumnMap, machine: MachineConfig | None, map_label: str) -> None:
    if machine is None:
        return
    known = [axis.name for axis in machine.axes]
    problems = []
    for name in mapping.channels:
        channel = channel_from_name(name)
        if channel is not None and channel.axis not in known:
            problems.append(
                f"{map_label}: channels.{name}: axis {channel.axis} is not an "
                f"axis of machine {machine.machine.name!r} ({', '.join(known)})"
            )
    if problems:
        raise ConfigError("the column map does not fit the machine file", problems)


@dataclass(frozen=True)
class _Column:
    """A column the map reads: its place in the row and how its values convert."""

    name: str
    """How messages name it: ``'X1_Current'``, or ``2`` / ``2 ('Velocity')`` by position."""
    index: int
    scale: float
    offset: float
    target: str


def _conversion(scale: float, offset: float) -> str:
    parts = [f"x {scale:.10g}"] if scale != 1 else []
    if offset:
        parts.append(f"{'+' if offset > 0 else '-'} {abs(offset):.10g}")
    return " ".join(parts) if parts else "no conversion"


def _label(ref: str | int, header: Sequence[str]) -> str:
    """A column as messages name it: its text, or its position (with the header's text)."""
    if isinstance(ref, str):
        return repr(ref)
    text = header[ref - 1] if ref <= len(header) else ""
    return f"{ref} ({text!r})" if text else str(ref)


#: Lines searched for the header (the first line holding every column named by its text).
HEADER_SEARCH_LINES: Final = 1000
_TIME_UNITS: Final = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "min": 60.0}


@dataclass(frozen=True)
class _Header:
    """The header row: where, its cells and its separator, and the lines before it."""

    line: int
    cells: list[str]
    separator: str
    text: str


class _Reader:
    """One pass over the file: header, units row, then rows in chunks to the recording."""

    def __init__(self, job: ImportJob, mapping: ColumnMap, map_name: str, lines: TextLines) -> None:
        self.job = job
        self.mapping = mapping
        self.map_name = map_name
        self.lines = lines
        self.rows: Iterator[str] = iter(lines)
        self.preamble: list[str] = []
        self.units_line = 0
        self.first_row: str | None = None
        self.deferred: list[str] = []
        """Report lines that follow the header's."""

    def read(self) -> RecordingMeta:
        mapping = self.mapping
        refs = ([mapping.time.column] if mapping.time else []) + [
            c.column for c in mapping.channels.values()
        ]
        named = list(dict.fromkeys(r for r in refs if isinstance(r, str)))
        head = self._header(named)
        header, separator, header_line = head.cells, head.separator, head.line
        index = self._column_indices(header, refs, header_line)
        channels = _ordered_channels(mapping, self.job.machine)
        specs = [mapping.channels[c.name] for c in channels]
        rows: Iterator[str] = self.rows
        units: dict[str | int, str] = {}
        first = self._first_row()
        if first is not None:
            units = self._units_row(first, separator, refs, index, header, header_line)
            if not units:
                rows = itertools.chain([first], rows)  # a data row: read it as one
        scales = {
            name: self._scale(spec, units.get(spec.column), name, header)
            for name, spec in zip((c.name for c in channels), specs, strict=True)
        }
        columns = [
            _Column(
                _label(spec.column, header),
                index[spec.column],
                scales[channel.name],
                spec.offset,
                channel.name,
            )
            for channel, spec in zip(channels, specs, strict=True)
        ]
        time_spec = mapping.time
        time_column = (
            _Column(
                _label(time_spec.column, header),
                index[time_spec.column],
                self._time_scale(time_spec, units.get(time_spec.column), header),
                time_spec.offset,
                "time_s",
            )
            if time_spec is not None
            else None
        )
        self._report_header(separator, header, header_line, channels, columns, time_column)
        for line in self.deferred:
            self.job.note(line)
        start, where = preamble_date(self.preamble)
        if start is None and where:
            self.job.note(f"{where}: none is taken as the measurement's start")
        sink = self.job.open_sink(
            channels,
            nominal_period_s=mapping.period_s,
            start_utc=start,
            start_source=f"the preamble, {where}",
        )
        decimal = self._read_rows(
            csv.reader(rows, delimiter=separator),
            separator,
            header,
            header_line,
            columns,
            time_column,
            sink.append,
        )
        if decimal is not None:
            how = "from the column map" if mapping.decimal else "detected"
            self.job.note(f"numbers use a decimal {'comma' if decimal == ',' else 'point'} ({how})")
        return self.job.finish()

    def _skip(self) -> None:
        skip = self.mapping.skip_lines
        for _ in range(skip):
            line = next(self.rows, None)
            if line is None:
                raise RecordingError(
                    f"{self.job.path}: the file ends after {self.lines.line_number} line(s), "
                    f"before the header (skip_lines = {skip} in {self.map_name})"
                )
            self._keep(line)
        if skip:
            self.job.note(f"{skip} line(s) before the header skipped (skip_lines)")

    def _keep(self, line: str) -> None:
        if len(self.preamble) < _PREAMBLE_DATE_LINES:
            self.preamble.append(line)

    def _header(self, named: Sequence[str]) -> _Header:
        """The header: the first non-blank line holding every column named by its text, or
        the last of consecutive such lines (a preamble may list the channels just above
        it); the first non-blank line when the map names every column by position."""
        self._skip()
        path = self.job.path
        best: tuple[int, int, str] | None = None  # named columns found, line, text
        found_header: _Header | None = None
        searched = 0
        for line in self.rows:
            if not line.strip():
                continue
            separator = self.mapping.delimiter or _detect_separator(
                line, named, self.mapping.decimal
            )
            cells = [c.strip() for c in next(csv.reader([line], delimiter=separator), [])]
            found = sum(name in cells for name in named)
            if not named:
                return _Header(self.lines.line_number, cells, separator, line)
            if found == len(named):
                if found_header is not None:
                    self._keep(found_header.text)
                found_header = _Header(self.lines.line_number, cells, separator, line)
                continue
            if found_header is not None:
                self.first_row = line  # the line after the header: units or data
                return found_header
            if best is None or found >= best[0]:
                best = (found, self.lines.line_number, line)
            self._keep(line)
            searched += 1
            if searched >= HEADER_SEARCH_LINES:
                break
        if found_header is not None:
            return found_header  # the file ends after the header
        if best is None:
            if self.lines.line_number == 0:
                raise RecordingError(f"{path}: the file is empty")
            raise RecordingError(f"{path}: no header row (only blank lines)")
        _, number, text = best
        separator = self.mapping.delimiter or _detect_separator(text, named, self.mapping.decimal)
        cells = [c.strip() for c in next(csv.reader([text], delimiter=separator), [])]
        missing = [name for name in named if name not in cells]
        raise RecordingError(
            f"{path}:{number}: column(s) named in {self.map_name} not in the header: "
            f"{', '.join(map(repr, missing))}",
            [
                f"the header has: {', '.join(map(repr, cells))}",
                f"no line of the first {searched} holds every named column (the last line "
                "with the most of them is taken for the header); check the names, or name a "
                "column by its position (column = 1)",
            ],
        )

    def _column_indices(
        self, header: Sequence[str], refs: Sequence[str | int], header_line: int
    ) -> dict[str | int, int]:
        where = f"{self.job.path}:{header_line}"
        repeated = [r for r in dict.fromkeys(refs) if isinstance(r, str) and header.count(r) > 1]
        if repeated:
            raise RecordingError(
                f"{where}: the header has more than one column named "
                f"{', '.join(map(repr, repeated))}; the column map cannot tell them apart "
                "(name them by position: column = 3)"
            )
        beyond = [r for r in refs if isinstance(r, int) and r > len(header)]
        if beyond:
            raise RecordingError(
                f"{where}: column {beyond[0]} of {self.map_name} is beyond the header's "
                f"{len(header)} cell(s): {', '.join(map(repr, header))}"
            )
        return {r: (r - 1 if isinstance(r, int) else header.index(r)) for r in refs}

    def _first_row(self) -> str | None:
        """The first non-blank line after the header (None: the file ends)."""
        if self.first_row is not None:
            return self.first_row
        for line in self.rows:
            if line.strip():
                return line
        return None

    def _units_row(
        self,
        line: str,
        separator: str,
        refs: Sequence[str | int],
        index: dict[str | int, int],
        header: Sequence[str],
        header_line: int,
    ) -> dict[str | int, str]:
        """The units of the mapped columns when ``line`` is a units row (``ms;rpm;mA``: the
        mapped cells are words, no number), else nothing (it is a data row)."""
        cells = next(csv.reader([line], delimiter=separator), [])
        mapped = {r: cells[index[r]].strip() if index[r] < len(cells) else "" for r in refs}
        words = [c for c in mapped.values() if c]
        if not words or any(not _is_not_number(c) or iso_datetime(c) for c in words):
            return {}
        number = self.lines.line_number
        listed = ", ".join(c.strip() or "(empty)" for c in cells)
        self.deferred.append(f"units row at line {number} (under the header, not data): {listed}")
        if len(cells) > len(header) and any(c.strip() for c in cells[len(header) :]):
            raise RecordingError(
                f"{self.job.path}:{number}: the units row has {len(cells)} cells, the header "
                f"(line {header_line}) {len(header)}"
            )
        self.units_line = number
        return {r: unit for r, unit in mapped.items() if unit}

    def _scale(
        self, spec: ChannelColumn, unit: str | None, name: str, header: Sequence[str]
    ) -> float:
        """The channel's scale: the map's, else the units row's factor; checked against it."""
        if unit is None:
            return spec.scale
        channel = channel_from_name(name)
        assert channel is not None
        factor = unit_factor(channel.signal, unit)
        return self._checked(
            "scale" in spec.model_fields_set,
            spec.scale,
            factor,
            unit,
            f"{name} [{channel.unit}]",
            f"channels.{name}.scale",
        )

    def _time_scale(self, spec: TimeColumn, unit: str | None, header: Sequence[str]) -> float:
        if unit is None:
            return spec.scale
        factor = _TIME_UNITS.get(normalize_unit(unit))
        return self._checked(
            "scale" in spec.model_fields_set, spec.scale, factor, unit, "time_s [s]", "time.scale"
        )

    def _checked(
        self, given: bool, scale: float, factor: float | None, unit: str, what: str, key: str
    ) -> float:
        where = f"{self.job.path}:{self.units_line}"
        if given:
            if factor is None:
                self.deferred.append(
                    f"{what}: the units row says {unit!r}, converted with the column map's "
                    f"{key} = {scale:.10g}"
                )
            elif not math.isclose(scale, factor, rel_tol=1e-9):
                self.deferred.append(
                    f"{what}: the units row says {unit!r} (x {factor:.10g}), the column map's "
                    f"{key} = {scale:.10g} is used"
                )
            return scale
        if factor is None:
            raise RecordingError(
                f"{where}: {what}: the units row says {unit!r}, which the column map cannot "
                f"convert; give {key} (the factor from {unit!r} into the channel's unit)"
            )
        if factor != 1:
            self.deferred.append(f"{what}: x {factor:.10g} from the units row's {unit!r}")
        return factor

    def _report_header(
        self,
        separator: str,
        header: Sequence[str],
        header_line: int,
        channels: Sequence[Channel],
        columns: Sequence[_Column],
        time_column: _Column | None,
    ) -> None:
        note = self.job.note
        if len(header) == 1:
            note(f"header at line {header_line}: one column")
        else:
            how = "from the column map" if self.mapping.delimiter else "detected"
            before = header_line - 1 - self.mapping.skip_lines
            after = (
                f"; the {before} line(s) before it are no data (the first line holding every "
                "column named by its text)"
                if before > 0
                else ""
            )
            note(
                f"header at line {header_line}: {len(header)} columns separated by "
                f"{_SEPARATOR_NAMES[separator]} ({how}){after}"
            )
        if time_column is not None:
            note(
                f"time_s [s]: from column {time_column.name} "
                f"({_conversion(time_column.scale, time_column.offset)})"
            )
        else:
            note(f"time_s [s]: no time column; row k is at k x {self.mapping.period_s:.10g} s")
        for channel, column in zip(channels, columns, strict=True):
            note(
                f"{channel.name} [{channel.unit}]: from column {column.name} "
                f"({_conversion(column.scale, column.offset)})"
            )
        used = {c.index for c in columns} | ({time_column.index} if time_column else set())
        ignored = [name for i, name in enumerate(header) if i not in used and name]
        if ignored:
            note(
                f"{len(ignored)} column(s) not in the column map, not imported: "
                f"{', '.join(map(repr, ignored))}"
            )

    def _read_rows(
        self,
        reader: Iterator[list[str]],
        separator: str,
        header: Sequence[str],
        header_line: int,
        columns: Sequence[_Column],
        time_column: _Column | None,
        append: Callable[[NDArray[np.float64], NDArray[np.float64]], None],
    ) -> str | None:
        """Parse, convert and hand on the rows; returns the decimal mark seen (if any)."""
        path = self.job.path
        decimal: str | None = self.mapping.decimal or ("." if separator == "," else None)
        read = ([time_column] if time_column is not None else []) + list(columns)
        indices = [c.index for c in read]
        needed = max(indices) + 1
        width = len(header)
        empty = [0] * len(read)
        first_empty: list[str | None] = [None] * len(read)
        period_s = self.mapping.period_s if time_column is None else None
        chunk = _Chunk(path, columns, time_column, period_s, append)
        raw, line_numbers = chunk.raw, chunk.line_numbers  # emptied in place by each flush
        dates = _DateTimes(
            self.job, self.mapping.time, time_column.name if time_column is not None else ""
        )

        for cells in reader:
            if not any(cell.strip() for cell in cells):
                continue
            line = self.lines.line_number
            if len(cells) < needed:
                short = next(c for c in read if c.index >= len(cells))
                raise RecordingError(
                    f"{path}:{line}: {len(cells)} cell(s); column {short.name} is cell "
                    f"{short.index + 1} of {width} in the header (line {header_line})"
                )
            if len(cells) > width and any(cell.strip() for cell in cells[width:]):
                hint = " (a decimal comma in a comma-separated file?)" if separator == "," else ""
                raise RecordingError(
                    f"{path}:{line}: {len(cells)} cells, the header (line {header_line}) "
                    f"has {width}{hint}"
                )
            if decimal is None:
                decimal = decimal_mark([cells[i] for i in indices])
            for k, column in enumerate(read):
                cell = cells[column.index].strip()
                if k == 0 and time_column is not None:
                    if not cell:
                        raise RecordingError(
                            f"{path}:{line}: the time column {column.name} is empty"
                        )
                    if dates.seconds(cell, f"{path}:{line}", raw):
                        continue
                if not cell:
                    empty[k] += 1
                    if first_empty[k] is None:
                        first_empty[k] = f"{path}:{line}"
                    raw.append(math.nan)
                    continue
                try:
                    raw.append(parse_number(cell, decimal or "."))
                except ValueError as exc:
                    other_mark = ("," if decimal != "," else ".") in cell
                    reason = f" ({exc})" if other_mark else ""
                    raise RecordingError(
                        f"{path}:{line}: column {column.name}: {cell!r} is not a number{reason}"
                    ) from exc
            line_numbers.append(line)
            if len(line_numbers) >= CHUNK_ROWS:
                chunk.flush()
        chunk.flush()
        self._check_rows(chunk.rows, header_line, period_s)
        for column, count, first in zip(read, empty, first_empty, strict=True):
            if count:
                self.job.note(
                    f"{column.target}: {count} empty cell(s) in column {column.name} stored "
                    f"as NaN; first at {first}"
                )
        return decimal

    def _check_rows(self, rows: int, header_line: int, period_s: float | None) -> None:
        """Refuse a file with too few data rows to be a recording."""
        path = self.job.path
        if rows == 0:
            raise RecordingError(f"{path}: no data rows after the header (line {header_line})")
        if rows == 1 and period_s is None:
            raise RecordingError(
                f"{path}: a single data row; the sample period needs at least two rows "
                "(or period_s in the column map instead of a time column)"
            )


class _DateTimes:
    """A time column of ISO 8601 date-times: seconds from its first row, which is the
    measurement's start (``time.format = "iso"``, or told from the first row)."""

    def __init__(self, job: ImportJob, spec: TimeColumn | None, label: str = "") -> None:
        self.job = job
        self.spec = spec
        self.label = label
        self.iso: bool | None = None if spec is None else _ISO_FORMATS.get(spec.format)
        self.first: dt.datetime | None = None

    def seconds(self, cell: str, where: str, raw: array[float]) -> bool:
        """Append the seconds of ``cell`` to ``raw`` when the column holds date-times;
        False when it holds numbers.

        Raises:
            RecordingError: a cell of a date-time column is not an ISO 8601 date-time.
        """
        assert self.spec is not None
        if self.iso is None:
            self.iso = (
                self.spec.scale == 1
                and self.spec.offset == 0
                and iso_datetime(cell) is not None
                and _is_not_number(cell)
            )
            if self.iso:
                self.job.note(
                    f"time column {self.label} holds ISO 8601 date-times (detected): "
                    "times from them, the first row is the measurement's start"
                )
        if not self.iso:
            return False
        try:
            written = dt.datetime.fromisoformat(cell)
        except ValueError as exc:
            raise RecordingError(
                f"{where}: time column {self.label}: {cell!r} is not an ISO 8601 "
                "date-time (2024-03-05 14:22:10.250)"
            ) from exc
        when = written if written.tzinfo is not None else written.replace(tzinfo=dt.UTC)
        if self.first is None:
            self.first = when
            self.job.found_start(written, f"the first row of time column {self.label}")
        raw.append((when - self.first).total_seconds())
        return True


_ISO_FORMATS: Final[dict[str | None, bool | None]] = {"iso": True, "number": False, None: None}


def _is_not_number(cell: str) -> bool:
    try:
        parse_number(cell, ",")
    except ValueError:
        try:
            parse_number(cell, ".")
        except ValueError:
            return True
    return False


class _Chunk:
    """The rows parsed since the last flush, as raw numbers, with their line numbers.

    :meth:`flush` converts them (the time from the time column or the
    period, the values scaled) and hands them on as one block.
    """

    def __init__(
        self,
        path: Path,
        columns: Sequence[_Column],
        time_column: _Column | None,
        period_s: float | None,
        append: Callable[[NDArray[np.float64], NDArray[np.float64]], None],
    ) -> None:
        self._path = path
        self._width = len(columns) + (time_column is not None)
        self._time_column = time_column
        self._period_s = period_s
        self._append = append
        self._scales = np.array([c.scale for c in columns], dtype=np.float64)
        self._offsets = np.array([c.offset for c in columns], dtype=np.float64)
        self.raw: array[float] = array("d")
        self.line_numbers: array[int] = array("q")
        self.rows = 0  # rows handed on before the current chunk
        self._previous_s = -math.inf

    def flush(self) -> None:
        """Hand the rows on (none: nothing to do) and start an empty chunk."""
        raw, line_numbers, path = self.raw, self.line_numbers, self._path
        time_column, period_s, rows = self._time_column, self._period_s, self.rows
        count = len(line_numbers)
        if not count:
            return
        block = np.array(raw, dtype=np.float64).reshape(count, self._width)
        if period_s is not None:
            time_s = np.arange(rows, rows + count, dtype=np.float64) * period_s
            values = block
        elif time_column is not None:
            time_s = block[:, 0] * time_column.scale + time_column.offset
            numbers = line_numbers.tolist()
            check_times(time_s, self._previous_s, lambda i: f"{path}:{numbers[i]}")
            self._previous_s = float(time_s[-1])
            values = block[:, 1:]
        self._append(time_s, values * self._scales + self._offsets)
        self.rows += count
        del raw[:], line_numbers[:]


def _detect_separator(line: str, wanted: Sequence[str], decimal: str | None) -> str:
    """The separator that splits the header into the most mapped columns (then the most cells)."""
    candidates = [s for s in _SEPARATORS if not (s == "," and decimal == ",")]

    def score(separator: str) -> tuple[int, int]:
        cells = [c.strip() for c in next(csv.reader([line], delimiter=separator), [])]
        return sum(name in cells for name in wanted), len(cells)

    best = max(candidates, key=score)  # the first of equals: comma, semicolon, tab
    if score(best)[1] == 1:
        # One column: no separator shows; take one that cannot clash with a decimal comma.
        return "\t"
    return best


def _ordered_channels(mapping: ColumnMap, machine: MachineConfig | None) -> list[Channel]:
    """The channels in the order the other importers use: by axis, then by signal."""
    channels = [c for c in map(channel_from_name, mapping.channels) if c is not None]
    return order_channels(channels, machine)
