"""TwinCAT Scope CSV export: channels with their own timelines, decimal comma or point.

The layout, as verified against Beckhoff's description of the CSV export
(TE13xx Scope View, "Export to csv") and the example exports in the test data
of the public reader CagtayFabry/pytcs (``tests/data/tc3_scope_*.csv``,
``pytcs/pytcs.py``)::

    Name<sep><scope name>
    File<sep><path>
    Starttime of export<sep><FILETIME><sep><date><sep><time>
    Endtime of export<sep><FILETIME><sep>...
    <blank lines>
    Name<sep>var_a<sep>Name<sep>var_b ...         a "Name" cell opens a time column
    Data-Type<sep>REAL64<sep>Data-Type<sep>...      one key/value line per property:
    SampleTime[ms]<sep>1<sep>SampleTime[ms]<sep>0,2 SymbolComment, VariableSize, ...,
    ScaleFactor<sep>1 ...  Offset, Unit ("(None)", "V (Voltage)"), Unit ScaleFactor
    <blank line>
    0<sep>0<sep>0<sep>0                             data: per group a time column [ms]
    1<sep>1<sep>0,2<sep>0,2                         followed by its value columns

* Timelines: "All" gives every channel its own time column (``Name<sep>a<sep>Name<sep>b``);
  "For each sampletime" lets successive channels share one
  (``Name<sep>a<sep>b<sep>Name<sep>c``). A channel that ended leaves a single space
  in its cells; trailing groups may be left out of a row.
* Times are milliseconds from the first data point, or Windows FILETIME ticks
  with "Full Timestamp". Separator: tab, semicolon or comma (also colon);
  a space-separated export cannot be split unambiguously and is refused.
  The decimal mark of the data is a point or a comma ("DecimalMark"); header
  numbers such as ``SampleTime[ms]`` are written with a decimal comma even in
  exports with decimal points, which breaks the columns of a comma-separated
  header: such header lines are skipped and reported.
* "Scale values before export" decides whether the data were multiplied by
  ScaleFactor and shifted by Offset; the file does not say, so the values are
  taken as exported and a channel with a ScaleFactor other than 1 or an
  Offset other than 0 is reported.
* An optional last row ``EOF`` ("Include EOF tag") ends the data.

Channel names: ``<AXIS>_<signal>`` in ncmeasure's units (``X_current_a``; name
the channels so in the Scope), or an NC axis variable of ``NCTOPLC_AXIS_REF``
(``<axis>.NcToPlc.ActPos`` / ``.ActVelo`` / ``.SetVelo``: position in the axis
unit, velocity in axis unit per second, Beckhoff Infosys). The ``Unit`` of the
channel, where given, converts the values (mm, um, m; mm/s, mm/min, m/min,
m/s; A, mA).
"""

from __future__ import annotations

import logging
import math
import re
from array import array
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.recording import channel_from_name
from ncmeasure.samples import SIGNAL_UNITS
from ncmeasure.traces import merge as merging
from ncmeasure.traces.axes import Candidate, Mapped, plan_sources
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.merge import SeriesMerge
from ncmeasure.traces.text import (
    TextLines,
    block_decimal_mark,
    comma_separated,
    decimal_mark,
    filetime_to_datetime,
    number_rows,
    parse_number,
    unit_factor,
)

__all__ = ["import_twincat_csv"]

log = logging.getLogger(__name__)

_SEPARATORS: Final = ("\t", ";", ",", ":")
_HEADER_KEYS: Final = ("SampleTime[ms]", "SampleTime", "Unit", "ScaleFactor", "Offset")
_NC_FIELD = re.compile(r"^(?P<axis>.+?)(?:\.NcToPlc)?\.(?P<field>ActPos|ActVelo|SetVelo)$")
#: NCTOPLC_AXIS_REF field -> (ncmeasure signal, unit when the export gives none)
_NC_FIELDS: Final = {
    "ActPos": ("position_mm", "mm"),
    "ActVelo": ("velocity_mm_min", "mm/s"),
    "SetVelo": ("velocity_cmd_mm_min", "mm/s"),
}
#: Lines read and parsed at a time (a block of plain rows is parsed as a whole).
_BLOCK_LINES: Final = 20_000
#: A time cell with this many digits is a FILETIME ("Full Timestamp"), not milliseconds.
_FILETIME_DIGITS: Final = 15


@dataclass
class _ScopeChannel:
    name: str
    time_col: int
    value_col: int
    info: dict[str, str] = field(default_factory=dict)


def _unit(text: str) -> str:
    """The unit symbol of a Scope unit cell: ``V (Voltage)`` -> ``V``, ``(None)`` -> no unit."""
    first = text.strip().split(" ")[0] if text.strip() else ""
    return "" if first == "(None)" else first


def _header_number(text: str) -> float | None:
    try:
        return float(text.strip().replace(",", "."))
    except ValueError:
        return None


class _Header:
    """The header of a Scope export: separator, start time and channels."""

    def __init__(self, lines: TextLines, job: ImportJob) -> None:
        self.job = job
        self.rows = iter(lines)
        first = next(self.rows, None)
        if first is None:
            raise RecordingError(f"{job.path}: the file is empty")
        if not first.startswith("Name") or len(first) < 5:
            raise RecordingError(
                f"{job.path}:1: not a TwinCAT Scope export (the first line must be "
                "Name<separator><scope name>)"
            )
        separator = first[4]
        if separator == " ":
            raise RecordingError(
                f"{job.path}:1: a space-separated Scope export cannot be split unambiguously "
                "(names and units contain spaces); export with tab or semicolon"
            )
        if separator not in _SEPARATORS:
            raise RecordingError(f"{job.path}:1: unknown separator {separator!r} after 'Name'")
        self.separator = separator
        job.link["scope"] = first[5:].strip(separator + " ")
        self.start_ticks: int | None = None
        name_line: str | None = None
        for line in self.rows:
            cells = line.split(separator)
            if cells[0] == "Starttime of export" and len(cells) > 1:
                try:
                    self.start_ticks = int(cells[1].strip())
                except ValueError:
                    job.note(f"{lines.where()}: start time {cells[1]!r} is not a FILETIME; ignored")
            elif cells[0] == "Name":
                name_line = line
                break
        if name_line is None:
            raise RecordingError(
                f"{job.path}: no channel header (a line Name{separator}<channel>...) found"
            )
        self.name_line_number = lines.line_number
        cells = name_line.split(separator)
        while cells and not cells[-1].strip():
            cells.pop()  # exports of older versions end lines with a separator
        self.width = len(cells)
        self.group_starts = [i for i, cell in enumerate(cells) if cell == "Name"]
        self.channels: list[_ScopeChannel] = []
        group = 0
        for index, cell in enumerate(cells):
            if cell == "Name":
                group = index
            elif cell.strip():
                self.channels.append(_ScopeChannel(cell.strip(), group, index))
        if not self.channels:
            raise RecordingError(f"{lines.where()}: the channel header names no channel")
        self.first_data: str | None = None
        self._read_properties(lines)

    def _read_properties(self, lines: TextLines) -> None:
        separator = self.separator
        unreadable: list[str] = []
        for line in self.rows:
            if not line.strip():
                break
            cells = line.split(separator)
            key = cells[0]
            if _header_number(key) is not None:
                self.first_data = line  # the data follow without a blank line
                break
            width = len(cells) - 1 if len(cells) == self.width + 1 and not cells[-1] else len(cells)
            if width == self.width and all(cells[g] == key for g in self.group_starts):
                for channel in self.channels:
                    cell = cells[channel.value_col] if channel.value_col < len(cells) else ""
                    channel.info[key] = cell.strip()
            elif key in _HEADER_KEYS:
                unreadable.append(f"{key} (line {lines.line_number})")
        for key in unreadable:
            self.job.note(
                f"header line {key} does not split into the channel columns (a decimal comma "
                "in a comma-separated export?); ignored"
            )


def _candidates(channels: list[_ScopeChannel], job: ImportJob) -> list[Candidate | None]:
    result: list[Candidate | None] = []
    for channel in channels:
        direct = channel_from_name(channel.name)
        rank = 0
        if direct is not None:
            signal, axis_id, default_unit = direct.signal, direct.axis, direct.unit
        else:
            match = _NC_FIELD.match(channel.name) or _NC_FIELD.match(
                channel.info.get("SymbolName", "")
            )
            if match is None:
                job.note(
                    f"{channel.name}: not imported (the name is neither <AXIS>_<signal> such as "
                    "X_current_a nor an NC axis variable ...ActPos, ...ActVelo, ...SetVelo)"
                )
                result.append(None)
                continue
            signal, default_unit = _NC_FIELDS[match["field"]]
            axis_id, rank = match["axis"], 1
        unit = _unit(channel.info.get("Unit", ""))
        target = SIGNAL_UNITS[signal]
        factor = unit_factor(signal, unit or default_unit)
        if factor is None:
            job.note(
                f"{channel.name}: not imported (unit {unit or default_unit!r} cannot be "
                f"converted to {target})"
            )
            result.append(None)
            continue
        if unit:
            conversion = "no unit conversion" if factor == 1 else f"{unit} x {factor:g} = {target}"
        else:
            conversion = f"no unit in the export, {default_unit} assumed"
            if factor != 1:
                conversion += f"; x {factor:g} = {target}"
        result.append(Candidate(channel.name, axis_id, signal, factor, "", rank, conversion))
    return result


def import_twincat_csv(job: ImportJob) -> RecordingMeta:
    """Import a TwinCAT Scope CSV export (see the module docstring).

    Raises:
        RecordingError: ``file:line: problem`` for a file that is not a Scope
            export, a cell that is not a number (or has the other decimal
            mark), a time that does not increase within a channel, a channel
            that resumes after it ended, or no channel that can be imported.
    """
    with TextLines(job.path, job) as lines:
        return _read(job, lines)


def _read(job: ImportJob, lines: TextLines) -> RecordingMeta:
    header = _Header(lines, job)
    used = plan_sources(header.channels, _candidates(header.channels, job), job)
    _note_scaling(used, job)

    separator = header.separator
    decimal: str | None = "." if separator == "," else None
    full_timestamp: bool | None = None
    count = len(used)
    merge = _open_merge(job, header, used)
    samples = _ChannelSamples(merge, count, header.start_ticks)
    # the lists stay, their arrays are replaced by each hand-over
    times, ticks, values = samples.times, samples.ticks, samples.values
    last = [-math.inf] * count
    ended = [False] * count
    needed = max(ch.value_col for ch in header.channels) + 1
    first_row = True

    chunk_rows = merging.CHUNK_ROWS
    rows_parsed = 0
    pending = [header.first_data] if header.first_data is not None else []
    try:
        while block := pending or lines.take(_BLOCK_LINES):
            pending = []
            first_line = lines.line_number - len(block) + 1
            if first_row:  # the first row tells whether the times are FILETIME stamps
                pending, block = block[1:], block[:1]
            elif not full_timestamp:
                mark = decimal if decimal is not None else block_decimal_mark(block, separator)
                if _fast_block(block, header, used, mark, samples, last, ended):
                    decimal = mark
                    rows_parsed += len(block)
                    samples.hand_over()
                    continue
            eof = False
            for offset, line in enumerate(block):
                if not line.strip():
                    continue
                where = f"{job.path}:{first_line + offset}"
                if line.strip() == "EOF":
                    eof = True
                    break
                cells = line.split(separator)
                if len(cells) > header.width and any(c.strip() for c in cells[header.width :]):
                    raise _too_many_cells(where, len(cells), header)
                if first_row:
                    first_row = False
                    full_timestamp = samples.full_timestamp = _full_timestamp(
                        where, cells, needed, used[0][0]
                    )
                if decimal is None:
                    decimal = decimal_mark(cells)
                for k, (channel, _) in enumerate(used):
                    t_cell = (
                        cells[channel.time_col].strip() if channel.time_col < len(cells) else ""
                    )
                    v_cell = (
                        cells[channel.value_col].strip() if channel.value_col < len(cells) else ""
                    )
                    if not t_cell and not v_cell:
                        ended[k] = True
                        continue
                    if not t_cell or not v_cell:
                        raise _half_sample(where, channel, separator)
                    if ended[k]:
                        raise RecordingError(
                            f"{where}: channel {channel.name} has samples again after empty cells"
                        )
                    try:
                        if full_timestamp:
                            tick = int(t_cell)
                            t = float(tick)
                        else:
                            t = parse_number(t_cell, decimal or ".")
                        value = parse_number(v_cell, decimal or ".")
                    except ValueError as exc:
                        raise RecordingError(
                            f"{where}: channel {channel.name}: not a number ({exc})"
                        ) from exc
                    if not t > last[k]:
                        raise RecordingError(
                            f"{where}: channel {channel.name}: time {t_cell} is not later than "
                            "the sample before; times must increase"
                        )
                    last[k] = t
                    if full_timestamp:
                        ticks[k].append(tick)
                    else:
                        times[k].append(t)
                    values[k].append(value)
                rows_parsed += 1
                if rows_parsed % chunk_rows == 0:
                    samples.hand_over()
            if eof:
                break

        if first_row:
            raise RecordingError(f"{job.path}: no data rows after the header")
        samples.hand_over()
    except BaseException:
        merge.close()  # on success, finish() closes it after the last rows
        raise
    if full_timestamp:
        job.note("times are FILETIME stamps (Full Timestamp); converted to s from the export start")
    if decimal == ",":
        job.note("numbers use a decimal comma")
    merge.finish(job)
    return job.finish()


def _fast_block(
    block: list[str],
    header: _Header,
    used: list[tuple[_ScopeChannel, Mapped]],
    decimal: str | None,
    samples: _ChannelSamples,
    last: list[float],
    ended: list[bool],
) -> bool:
    """Read a block of plain rows at once (:func:`number_rows`); False: not plain, nothing read.

    Plain: rows exactly as wide as the header of numbers in the notation of the
    file (times in ms), a channel that ended holding a single space in both of
    its cells from there on, times increasing per channel; nothing else (no
    blank lines, no ``EOF``). Anything else is read row by row, which says what
    is wrong where.
    """
    separator = header.separator
    text = comma_separated(block, separator, decimal)
    if text is None:
        return False
    data = text
    if b" " in data:  # a single space is the cell of a channel that ended: an empty cell
        if not _lone_spaces(data):
            return False
        data = data.translate(None, b" ")
    cells = number_rows(data, header.width, empty=True)
    if cells is None:
        return False
    portions = []
    for k, (channel, _) in enumerate(used):
        t, v = cells[:, channel.time_col], cells[:, channel.value_col]
        gone = np.isnan(t)
        if not np.array_equal(gone, np.isnan(v)):
            return False  # a time without a value or a value without a time
        count = int(np.argmax(gone)) if gone.any() else len(t)
        if gone[count:].size and not gone[count:].all():
            return False  # samples again after empty cells
        if count and (ended[k] or not (np.diff(t[:count], prepend=last[k]) > 0).all()):
            return False
        portions.append((k, t[:count], v[:count], count < len(t)))
    for k, t, v, stops in portions:
        if len(t):
            samples.times[k].frombytes(np.ascontiguousarray(t).tobytes())
            samples.values[k].frombytes(np.ascontiguousarray(v).tobytes())
            last[k] = float(t[-1])
        ended[k] = ended[k] or stops
    return True


def _lone_spaces(data: bytes) -> bool:
    """Whether every space of ``,``-separated rows is a cell of its own (a cell of a single
    space between separators or line ends)."""
    text = np.frombuffer(b"\n" + data + b"\n", np.uint8)
    spaces = np.flatnonzero(text == _SPACE)
    before, after = text[spaces - 1], text[spaces + 1]
    return bool(
        (
            ((before == _COMMA) | (before == _NEWLINE)) & ((after == _COMMA) | (after == _NEWLINE))
        ).all()
    )


_SPACE, _COMMA, _NEWLINE = b" ,\n"


def _note_scaling(used: list[tuple[_ScopeChannel, Mapped]], job: ImportJob) -> None:
    """Report the channels whose header declares a scale or offset (not applied)."""
    for channel, _ in used:
        scale = _header_number(channel.info.get("ScaleFactor", "1"))
        offset = _header_number(channel.info.get("Offset", "0"))
        if (scale is not None and scale != 1) or (offset is not None and offset != 0):
            job.note(
                f"{channel.name}: ScaleFactor {channel.info.get('ScaleFactor')}, Offset "
                f"{channel.info.get('Offset')} in the header; values taken as exported (the file "
                "does not say whether 'Scale values before export' was set)"
            )


def _open_merge(
    job: ImportJob, header: _Header, used: list[tuple[_ScopeChannel, Mapped]]
) -> SeriesMerge:
    """The recording of the imported channels (period: the shortest SampleTime) and its merge."""
    sample_times = [
        _header_number(ch.info.get("SampleTime[ms]", ch.info.get("SampleTime", "")))
        for ch, _ in used
    ]
    periods = [p / 1000.0 for p in sample_times if p is not None and p > 0]
    start = filetime_to_datetime(header.start_ticks) if header.start_ticks else None
    sink = job.open_sink(
        [m.channel for _, m in used],
        nominal_period_s=min(periods, default=None),
        start_utc=start,
        start_source="Starttime of export",
    )
    return SeriesMerge(
        sink,
        [m.channel.name for _, m in used],
        [m.factor for _, m in used],
        batch_rows=merging.MERGE_ROWS,
        spill_rows=merging.SPILL_ROWS,
    )


def _full_timestamp(where: str, cells: list[str], needed: int, first: _ScopeChannel) -> bool:
    """Whether the times are FILETIME stamps (Full Timestamp), from the first data row.

    Raises:
        RecordingError: The row lacks the time columns.
    """
    if len(cells) < needed:
        raise RecordingError(
            f"{where}: {len(cells)} cells, the header needs {needed} (a time column "
            "per group and the value columns); exports without time columns are "
            "not supported"
        )
    first_time = cells[first.time_col].strip()
    return first_time.isdigit() and len(first_time) >= _FILETIME_DIGITS


def _too_many_cells(where: str, cells: int, header: _Header) -> RecordingError:
    """The error of a row with more cells than the header."""
    hint = " (a decimal comma in a comma-separated export?)" if header.separator == "," else ""
    return RecordingError(
        f"{where}: {cells} cells, the header (line {header.name_line_number}) "
        f"has {header.width}{hint}"
    )


def _half_sample(where: str, channel: _ScopeChannel, separator: str) -> RecordingError:
    """The error of a channel's time without its value, or a value without its time."""
    hint = " (a decimal comma in a comma-separated export?)" if separator == "," else ""
    return RecordingError(
        f"{where}: channel {channel.name}: a time without a value or a value without a time{hint}"
    )


class _ChannelSamples:
    """The samples parsed of each imported channel since the last hand-over to the merge.

    Times are kept as the export writes them: ms, or FILETIME ticks once the
    first row shows Full Timestamps (:attr:`full_timestamp`).
    """

    def __init__(self, merge: SeriesMerge, count: int, start_ticks: int | None) -> None:
        self._merge = merge
        self.times: list[array[float]] = [array("d") for _ in range(count)]
        self.ticks: list[array[int]] = [array("q") for _ in range(count)]
        self.values: list[array[float]] = [array("d") for _ in range(count)]
        self.full_timestamp: bool | None = None
        self._base = start_ticks

    def hand_over(self) -> None:
        """The samples parsed so far go to the merge, in seconds."""
        full_timestamp, merge = self.full_timestamp, self._merge
        times, ticks, values = self.times, self.ticks, self.values
        if full_timestamp and self._base is None:
            firsts = [int(t[0]) for t in ticks if len(t)]
            self._base = min(firsts) if firsts else None
        base = self._base
        for k in range(len(values)):
            if full_timestamp:
                if base is not None and len(ticks[k]):
                    stamps = np.frombuffer(ticks[k], dtype=np.int64)
                    merge.add(
                        k, (stamps - base).astype(np.float64) * 1e-7, np.frombuffer(values[k])
                    )
                ticks[k] = array("q")
            else:
                t_s = np.frombuffer(times[k], dtype=np.float64) / 1000.0
                merge.add(k, t_s, np.frombuffer(values[k]))
                times[k] = array("d")
            values[k] = array("d")
        merge.flush()
