"""ncmeasure's own CSV exchange: a recording as one bit-exact CSV file and back.

:func:`export_csv` writes ``time_s`` and the channels with the shortest float
repr that reads back to the same float64; :func:`import_csv` reads such a file
(or any file in that layout) into a new recording.
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Final, TextIO

import numpy as np
import pydantic_core
from numpy.typing import NDArray

from ncmeasure.errors import RecordingError
from ncmeasure.files import replace_binary
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.recording.format import PathArg, channel_from_name
from ncmeasure.recording.reader import Recording, RecordingHead, rows_of
from ncmeasure.recording.sink import ImportSink, check_times
from ncmeasure.samples import SIGNAL_UNITS, Channel
from ncmeasure.traces.text import number_rows

if TYPE_CHECKING:  # the machine-file models: `export` reads no machine file
    from ncmeasure.config import MachineConfig

log = logging.getLogger(__name__)

#: Rows read from the recording at a time.
_CSV_CHUNK_ROWS = 50_000
#: Rows formatted at a time (:func:`csv_rows`). Formatting makes a Python float of every
#: value: 1,000 rows of 14 columns are 14,000 floats, 336 kB, within one of the
#: interpreter's 1 MiB allocation arenas, which it keeps from one piece to the next; the
#: floats of 20,000 rows took seven arenas, handed back to the system and mapped again
#: (page faults) for every piece, which cost as much time as the formatting.
_FORMAT_ROWS = 1_000


def export_csv(recording: Recording | RecordingHead | PathArg, path: PathArg) -> Path:
    """Write a recording as one CSV file: ``time_s`` and the channels, bit-exact.

    The header row names the columns (``time_s,X_current_a,...``); every value
    is written as Python's shortest repr that reads back to the same float64
    (``0.1``, ``1e-300``, ``-0.0``, ``nan``), so :func:`import_csv` restores the
    samples bit for bit. The file is written in chunks and renamed into place
    when complete; a recording given by its directory (or head) is read chunk
    by chunk and formatted :data:`_FORMAT_ROWS` rows at a time, so memory does
    not grow with its length.

    Args:
        recording: A recording, its head, or its directory. A head's ``rows``
            and ``problems`` are filled in by the export.
        path: The CSV file to write (replaced if it exists).

    Returns:
        The path written.

    Raises:
        RecordingError: The recording cannot be read or the file cannot be written.
    """
    rec, chunks = rows_of(recording, _CSV_CHUNK_ROWS)
    target = Path(path)
    count = 0
    try:
        with replace_binary(target) as file:
            file.write((",".join(["time_s", *rec.channel_names]) + "\n").encode())
            for chunk in chunks:
                rows = np.empty((len(chunk.time_s), 1 + chunk.values.shape[1]))
                rows[:, 0] = chunk.time_s
                rows[:, 1:] = chunk.values
                count += len(rows)
                for first in range(0, len(rows), _FORMAT_ROWS):
                    file.write(csv_rows(rows[first : first + _FORMAT_ROWS]))
    except OSError as exc:
        raise RecordingError(f"{target}: cannot be written ({exc.strerror or exc})") from exc
    log.info("exported %d samples of %s to %s", count, rec.directory, target)
    return target


#: Below this magnitude (not zero) Python's repr writes an exponent (``1e-05``) where
#: the JSON encoder writes digits (``0.00001``); such rows are written with repr itself.
_REPR_EXPONENT_BELOW: Final = 1e-4

#: The JSON encoder for a list of floats: told the type, it skips inferring each item's;
#: NaN and infinities as ``NaN``, ``Infinity`` and ``-Infinity``.
_FLOATS_JSON: Final = pydantic_core.SchemaSerializer(
    pydantic_core.core_schema.list_schema(pydantic_core.core_schema.float_schema()),
    pydantic_core.core_schema.CoreConfig(ser_json_inf_nan="constants"),
)
_COMMA: Final = ord(",")
_NEWLINE: Final = ord("\n")


def csv_rows(rows: NDArray[np.float64]) -> bytes:
    """Rows of float64 as CSV lines of Python's shortest reprs, ``,``-separated, ``\n``-ended.

    ``float.__repr__`` is the shortest text that reads back to the same float64, and
    the one nearest to it among those (``0.1``, ``1e+16``, ``-0.0``, ``nan``). pydantic's
    JSON encoder writes the same digits (shortest and nearest) several times faster,
    with the same text for every finite value from 1e-4 on. The rows go to it as one
    flat list (no list per row), and every row's last ``,`` becomes a line end; its
    ``NaN`` and ``Infinity`` are renamed, and a row with a smaller value is written
    with repr. The result is byte for byte ``",".join(map(repr, row)) + "\n"`` for
    every row.
    """
    if len(rows) == 0:
        return b""
    width = rows.shape[1]
    text = _FLOATS_JSON.to_json(rows.ravel().tolist())
    # b"[a,b,c,d]" -> b"a,b\nc,d\n": every width-th comma ends a row (a number holds none)
    body = bytearray(text)
    body[-1] = _NEWLINE
    cells = np.frombuffer(body, np.uint8)
    ends = np.flatnonzero(cells == _COMMA)[width - 1 :: width]
    cells[ends] = _NEWLINE
    with np.errstate(invalid="ignore"):
        tiny = np.flatnonzero(((np.abs(rows) < _REPR_EXPONENT_BELOW) & (rows != 0)).any(axis=1))
    if len(tiny):  # those rows as repr writes them, between the others' bytes
        view = memoryview(body)
        parts: list[bytes | memoryview] = []
        done = 1
        for index in tiny.tolist():
            start = int(ends[index - 1]) + 1 if index else 1
            parts += [view[done:start], _repr_line(rows[index])]
            done = int(ends[index]) + 1 if index < len(ends) else len(body)
        parts.append(view[done:])
        lines = b"".join(parts)
    else:
        lines = bytes(memoryview(body)[1:])
    if b"N" in lines or b"I" in lines:
        lines = lines.replace(b"NaN", b"nan").replace(b"Infinity", b"inf")
    return lines


def _repr_line(row: NDArray[np.float64]) -> bytes:
    return (",".join(map(repr, row.tolist())) + "\n").encode()


#: Characters of the file read and parsed at a time (whole lines: up to the next line end).
#: The text, its numbers and its rows are a few times this in memory.
_BLOCK_CHARS: Final = 1 << 20


def _text_blocks(file: TextIO) -> Iterator[str]:
    """The rest of a text file in blocks of whole lines (only the last may lack its ``\n``)."""
    while text := file.read(_BLOCK_CHARS):
        if not text.endswith("\n"):
            text += file.readline()
        yield text


def _lines(text: str) -> list[str]:
    """The lines of a block as iterating over the file gives them (with their ``\n``)."""
    lines = [line + "\n" for line in text.split("\n")]
    last = lines.pop()[:-1]
    return [*lines, last] if last else lines


def _parse_csv_header(path: Path, line: str) -> list[Channel]:
    if not line:
        raise RecordingError(f"{path}:1: the file is empty; expected a header row")
    cells = [cell.strip() for cell in line.lstrip("\ufeff").rstrip("\r\n").split(",")]
    if cells[0] != "time_s":
        raise RecordingError(f"{path}:1: the first column must be time_s, not {cells[0]!r}")
    if len(cells) < 2:
        raise RecordingError(f"{path}:1: no channel columns after time_s")
    channels: list[Channel] = []
    for number, name in enumerate(cells[1:], start=2):
        channel = channel_from_name(name)
        if channel is None:
            raise RecordingError(
                f"{path}:1: column {number} {name!r} is not <AXIS>_<signal> with a known "
                f"signal ({', '.join(SIGNAL_UNITS)})"
            )
        if channel in channels:
            raise RecordingError(f"{path}:1: column {number} {name!r} appears twice")
        channels.append(channel)
    return channels


def _csv_line_error(path: Path, lines: Sequence[str], first_line: int, names: Sequence[str]) -> str:
    """Find the first bad line of a chunk the fast parser refused, as ``file:line: problem``."""
    for offset, line in enumerate(lines):
        text = line.rstrip("\r\n")
        if not text.strip():
            continue
        cells = text.split(",")
        where = f"{path}:{first_line + offset}"
        if len(cells) != len(names):
            return f"{where}: {len(cells)} cells, expected {len(names)} ({', '.join(names)})"
        for name, cell in zip(names, cells, strict=True):
            try:
                float(cell)
            except ValueError:
                return f"{where}: column {name}: {cell.strip()!r} is not a number"
    return f"{path}:{first_line}-{first_line + len(lines) - 1}: cannot be read as numbers"


def _line_numbers(lines: Sequence[str], first_line: int) -> list[int]:
    """File line number of every data row of a chunk (blank lines hold no row)."""
    return [first_line + i for i, line in enumerate(lines) if line.strip()]


def _csv_where(path: Path, text: str, first_line: int) -> Callable[[int], str]:
    """``file:line`` of the data row at an index of a block (blank lines hold no row)."""

    def where(index: int) -> str:
        return f"{path}:{_line_numbers(_lines(text), first_line)[index]}"

    return where


def import_csv(
    path: PathArg,
    directory: PathArg,
    *,
    machine: MachineConfig | None = None,
    nominal_period_s: float | None = None,
    start_utc: dt.datetime | None = None,
) -> Recording:
    """Make a recording from a CSV file in the layout of :func:`export_csv`.

    The header names ``time_s`` and the channels (``<AXIS>_<signal>``, e.g.
    ``X_current_a``; units follow from the signal). The file is read in chunks;
    a block of plain numbers is parsed at once (:func:`~ncmeasure.traces.text.number_rows`),
    any other with numpy's parser; both read every float back bit-exact.

    Args:
        path: The CSV file.
        directory: The new recording (must not exist or be empty).
        machine: The machine file, for the axis data in ``meta.json``.
        nominal_period_s: The sample period; the median time step when not given.
        start_utc: When the machine was measured: the file holds no date, so
            without it the recording's start is unknown (null).

    Returns:
        The new recording, read back.

    Raises:
        RecordingError: ``file:line: problem`` for a bad header, a row with the
            wrong number of cells, a cell that is not a number, or times that do
            not increase; or the recording cannot be written. What the import
            wrote is removed again then.
    """
    import_csv_meta(
        path, directory, machine=machine, nominal_period_s=nominal_period_s, start_utc=start_utc
    )
    return Recording.open(directory)


def import_csv_meta(
    path: PathArg,
    directory: PathArg,
    *,
    machine: MachineConfig | None = None,
    nominal_period_s: float | None = None,
    start_utc: dt.datetime | None = None,
) -> RecordingMeta:
    """:func:`import_csv` without reading the recording back: its ``meta.json``.

    Memory stays within one chunk of rows whatever the size of the file.
    """
    source = Path(path)
    target: ImportSink | None = None
    try:
        with source.open("r", encoding="utf-8") as file:
            channels = _parse_csv_header(source, file.readline())
            names = ["time_s", *(c.name for c in channels)]
            target = ImportSink(
                Path(directory),
                channels,
                machine=machine,
                nominal_period_s=nominal_period_s,
                start_utc=start_utc,
                source="import:csv",
                notes=f"imported from {source.name}",
            )
            line_number = 1
            previous_s = -np.inf
            width = len(names)
            for text in _text_blocks(file):
                first_line = line_number + 1
                line_number += text.count("\n") + (not text.endswith("\n"))
                data = number_rows(text.encode(), width)
                if data is None:  # a spelling JSON does not know, or an error: numpy's parser
                    lines = _lines(text)
                    try:
                        data = np.loadtxt(
                            lines, delimiter=",", comments=None, dtype=np.float64, ndmin=2
                        )
                    except ValueError as exc:
                        error = _csv_line_error(source, lines, first_line, names)
                        raise RecordingError(error) from exc
                    if data.shape[0] == 0:
                        continue
                    if data.shape[1] != width:
                        raise RecordingError(_csv_line_error(source, lines, first_line, names))
                check_times(data[:, 0], previous_s, _csv_where(source, text, first_line))
                previous_s = float(data[-1, 0])
                target.append(data[:, 0], data[:, 1:])
        return target.close()
    except BaseException as exc:
        if target is not None:
            target.discard()
        if isinstance(exc, FileNotFoundError) and target is None:
            raise RecordingError(f"{source}: no such file") from exc
        if isinstance(exc, UnicodeDecodeError):
            raise RecordingError(f"{source}: not a text file (UTF-8 expected)") from exc
        if isinstance(exc, OSError) and not isinstance(exc, RecordingError):
            raise RecordingError(f"{source}: cannot be read ({exc.strerror or exc})") from exc
        raise
