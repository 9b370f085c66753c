"""Sinumerik trace CSV: the same servo signals as the XML, one row per instant.

What public code that reads these exports shows:

* a header row with a ``time`` column (seconds) followed by the signal names,
  then one row per instant (``pandas.read_csv`` with defaults in a public
  milling-signal pipeline, signal column ``+/Nck/!SD/nckServoDataActCurr32 [u1; 4]``);
* the comma inside ``[u1, 1]`` is written differently so it cannot clash with
  the separator: ``[u1; 1]`` (the pipeline above), ``[u1  1]`` (the public MATLAB
  importer ``load_siemens_data.m``), and ``[u1, 1]`` where the name is quoted
  or the separator is not a comma; a leading ``+`` may precede the name.

The layout that the MATLAB importer reads (one signal per header line, names
in the fifth column) was not verified far enough to be read safely; such a
file is refused ("no header row").

ncmeasure therefore looks for the first row whose first cell is a time label
(``time``, ``time [s]``, ``Zeit``, ...) and whose other cells include signal
names; rows before it are skipped and reported. A name that the separator
split inside ``[...]`` is joined again. The separator is ``,``, ``;``
or tab, whichever splits that row into the most signal names. The decimal mark
is the point, or the comma where the separator is not a comma; it is fixed by
the first number that shows one, and a number written the other way is an
error. An empty cell means the signal has no new sample at that instant: it
keeps its last value (as in the XML). Invalid-sample markers become NaN.

Which signals become channels, in which unit, and from which measuring system
an axis' position and velocity come, is decided as for the XML
(:func:`~ncmeasure.traces.sinumerik_xml.sinumerik_candidates`).
"""

from __future__ import annotations

import csv
import logging
import re
from collections.abc import Callable, Iterator
from typing import Final

import numpy as np

from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.traces.axes import plan_channels
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.merge import CarryForward
from ncmeasure.traces.sinumerik_xml import parse_signal_name, sinumerik_candidates
from ncmeasure.traces.text import (
    LineBlock,
    TextLines,
    block_decimal_mark,
    comma_separated,
    decimal_mark,
    number_rows,
    parse_number,
    preamble_date,
)

__all__ = ["import_sinumerik_csv"]

log = logging.getLogger(__name__)

_HEADER_SEARCH_LINES: Final = 200
#: Lines read and parsed at a time (a block of plain rows is parsed as a whole).
_BLOCK_LINES: Final = 20_000
_SEPARATORS: Final = (",", ";", "\t")
_TIME_LABEL = re.compile(
    r"^(?:time|zeit|t)\s*(?:[\[(]\s*(?P<unit>s|ms|us|µs)\s*[\])])?$",
    re.IGNORECASE,
)
_TIME_FACTORS: Final = {None: 1.0, "s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}


def _split(line: str, separator: str) -> list[str]:
    """The cells of a header row; a name split inside ``[...]`` by the separator is rejoined."""
    cells: list[str] = []
    for cell in next(csv.reader([line], delimiter=separator, quotechar='"')):
        if cells and cells[-1].count("[") > cells[-1].count("]"):
            cells[-1] += separator + cell
        else:
            cells.append(cell)
    return cells


def _header(line: str) -> tuple[str, list[str], float] | None:
    """Separator, cells and time factor of a header row, or None if ``line`` is none."""
    best: tuple[str, list[str], float] | None = None
    best_count = 0
    for separator in _SEPARATORS:
        cells = [c.strip() for c in _split(line, separator)] if line.strip() else []
        if len(cells) < 2:
            continue
        match = _TIME_LABEL.match(cells[0])
        if match is None:
            continue
        count = sum(parse_signal_name(c) is not None for c in cells[1:])
        if count > best_count:
            unit = match["unit"].lower() if match["unit"] else None
            best, best_count = (separator, cells, _TIME_FACTORS[unit]), count
    return best


def import_sinumerik_csv(job: ImportJob) -> RecordingMeta:
    """Import a Sinumerik trace CSV export (see the module docstring).

    Raises:
        RecordingError: ``file:line: problem`` for a missing header, a row
            with too many cells, a cell that is not a number (or has the
            other decimal mark), times that do not increase, or no signal
            that can be imported.
    """
    with TextLines(job.path, job) as lines:
        return _read(job, lines)


def _read(job: ImportJob, lines: TextLines) -> RecordingMeta:
    rows: Iterator[str] = iter(lines)
    found: tuple[str, list[str], float] | None = None
    skipped = 0
    preamble: list[str] = []
    for line in rows:
        found = _header(line)
        if found is not None:
            break
        skipped += 1
        preamble.append(line)
        if lines.line_number >= _HEADER_SEARCH_LINES:
            break
    if found is None:
        if lines.line_number == 0:
            raise RecordingError(f"{job.path}: the file is empty")
        raise RecordingError(
            f"{job.path}: no header row in the first {lines.line_number} lines: expected a time "
            "column followed by signal names such as /Nck/!SD/nckServoDataActCurr64 [u1, 1]"
        )
    separator, header, time_factor = found
    header_line = lines.line_number
    if skipped:
        job.note(f"{skipped} line(s) before the header row (line {header_line}) skipped")
    names = header[1:]
    candidates = sinumerik_candidates(names, job)
    mapped = plan_channels([c for c in candidates if c is not None], job)
    column_of = {id(m.candidate): i for i, m in enumerate(mapped)}
    # (cell index, channel column) of every imported signal column
    columns = [
        (1 + i, column_of[id(c)])
        for i, c in enumerate(candidates)
        if c is not None and id(c) in column_of
    ]
    if time_factor != 1.0:
        job.note(f"time column {header[0]!r} converted to seconds (x {time_factor:g})")
    start, where = preamble_date(preamble)
    if start is None and where:
        job.note(f"{where}: none is taken as the measurement's start")
    sink = job.open_sink(
        [m.channel for m in mapped],
        nominal_period_s=None,
        start_utc=start,
        start_source=f"the lines before the header, {where}",
    )
    assembler = CarryForward(sink, [m.channel.name for m in mapped], [m.factor for m in mapped])
    decimal: str | None = "." if separator == "," else None
    width = len(header)
    while taken := lines.take_block(_BLOCK_LINES):
        first_line = lines.line_number - len(taken) + 1
        place = _Where(job, first_line)
        mark = decimal if decimal is not None else block_decimal_mark(taken.lines, separator)
        if _fast_block(taken, place, separator, mark, width, time_factor, columns, assembler):
            decimal = mark
            continue
        reader = csv.reader(taken.lines, delimiter=separator, quotechar='"')
        for cells in reader:
            at = place(reader.line_num - 1)
            if not any(c.strip() for c in cells):
                continue
            if len(cells) > width:
                hint = " (a decimal comma in a comma-separated file?)" if separator == "," else ""
                raise RecordingError(
                    f"{at}: {len(cells)} cells, the header (line {header_line}) has {width}{hint}"
                )
            if decimal is None:
                decimal = decimal_mark(cells)
            try:
                time_s = parse_number(cells[0], decimal or ".") * time_factor
            except ValueError as exc:
                raise RecordingError(
                    f"{at}: time {cells[0].strip()!r} is not a number ({exc})"
                ) from exc
            for index, column in columns:
                cell = cells[index] if index < len(cells) else ""
                if not cell.strip():
                    continue
                try:
                    value = parse_number(cell, decimal or ".")
                except ValueError as exc:
                    raise RecordingError(
                        f"{at}: column {header[index]!r}: {cell.strip()!r} is not a number ({exc})"
                    ) from exc
                assembler.set(column, value, _at(at))
            assembler.commit(time_s, _at(at))
    if assembler.records == 0:
        raise RecordingError(f"{job.path}: no data rows after the header (line {header_line})")
    assembler.flush()
    missing = assembler.missing()
    if missing:
        raise RecordingError(
            f"{job.path}: {', '.join(missing)} never has a value in {assembler.records} rows"
        )
    assembler.summarize(job, "rows")
    if decimal == ",":
        job.note("numbers use a decimal comma")
    return job.finish()


def _at(where: str) -> Callable[[], str]:
    return lambda: where


class _Where:
    """``file:line`` of the line at an index of a block."""

    def __init__(self, job: ImportJob, first_line: int) -> None:
        self.path = job.path
        self.first_line = first_line

    def __call__(self, index: int) -> str:
        return f"{self.path}:{self.first_line + index}"


def _fast_block(
    block: LineBlock,
    where: _Where,
    separator: str,
    decimal: str | None,
    width: int,
    time_factor: float,
    columns: list[tuple[int, int]],
    assembler: CarryForward,
) -> bool:
    """Read a block of plain rows at once (:func:`number_rows`); False: not plain, nothing read.

    Plain: numbers in the notation of the file, the separator between them and no
    other character (no quotes, spaces or blank lines), every row as wide as the
    header, a time in every row. Anything else is read row by row
    (:func:`_slow_block`), which says what is wrong where.
    """
    text = comma_separated(block.lines if block.plain is None else block.plain, separator, decimal)
    if text is None:
        return False
    cells = number_rows(text, width, empty=True)
    if cells is None or np.isnan(cells[:, 0]).any():
        return False
    raw = np.full((len(cells), len(assembler.names)), np.nan)
    for index, column in columns:
        raw[:, column] = cells[:, index]
    assembler.commit_block(cells[:, 0] * time_factor, raw, where)
    return True
