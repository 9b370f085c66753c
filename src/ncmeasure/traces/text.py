"""Text and numbers of trace files: lines, decimal marks, units, invalid samples, Windows times.

The controllers' exports are text written on Windows PCs in the locale of the
shop: decimal commas or points, Windows-1252 or UTF-8, LF, CRLF or a bare CR.
What every text importer needs to read such a file into numbers lives here.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
from pathlib import Path
from typing import BinaryIO, Final

import numpy as np
import pydantic_core
from numpy.typing import NDArray

from ncmeasure.errors import RecordingError
from ncmeasure.traces.job import ImportJob

__all__ = [
    "INVALID_ABOVE",
    "PROGRESS_STEP_BYTES",
    "LineBlock",
    "TextLines",
    "block_decimal_mark",
    "comma_separated",
    "decimal_mark",
    "filetime_to_datetime",
    "is_invalid",
    "iso_datetime",
    "normalize_unit",
    "number_rows",
    "parse_number",
    "preamble_date",
    "unit_factor",
]

#: Values at or above this magnitude mark an invalid sample. Sinumerik writes
#: such samples as the bit pattern of +inf read as a 64-bit integer
#: (0x7FF0000000000000 = 9218868437227405312); the public parser
#: eliasrhoden/Trace-Tools rejects every value above 9218868437227405000.
INVALID_ABOVE: Final = 9.218868437227405e18
#: Bytes read before the progress callback is called again.
PROGRESS_STEP_BYTES: Final = 1 << 20
_SNIFF_BYTES: Final = 1 << 16
_READ_BYTES: Final = 1 << 16
#: At most this many bytes are read at a time for a block of lines (:meth:`TextLines.take_block`).
_SPAN_BYTES: Final = 1 << 22


def is_invalid(value: float) -> bool:
    """True for a sample the controller marked invalid (or one that is not a number)."""
    return not math.isfinite(value) or abs(value) >= INVALID_ABOVE


def parse_number(text: str, decimal: str = ".") -> float:
    """A float from trace text, with ``decimal`` as the decimal mark.

    Raises:
        ValueError: ``text`` is not a number in that notation (a decimal
            comma in a file that uses points, or the other way round).
    """
    cell = text.strip()
    if decimal == ",":
        if "." in cell:
            raise ValueError(f"{cell!r} has a decimal point; this file uses decimal commas")
        cell = cell.replace(",", ".")
    elif "," in cell:
        raise ValueError(f"{cell!r} has a decimal comma; this file uses decimal points")
    return float(cell)


_COMMA_NUMBER = re.compile(r"[+-]?\d+,\d+(?:[eE][+-]?\d+)?")
_POINT_NUMBER = re.compile(r"[+-]?\d*\.\d+(?:[eE][+-]?\d+)?")


def decimal_mark(cells: Sequence[str]) -> str | None:
    """The decimal mark that the first number with a fraction in ``cells`` shows, if any."""
    for cell in cells:
        text = cell.strip()
        if _COMMA_NUMBER.fullmatch(text):
            return ","
        if _POINT_NUMBER.fullmatch(text):
            return "."
    return None


def block_decimal_mark(lines: Sequence[str], separator: str) -> str | None:
    """The decimal mark of a block of lines, as a row-by-row reading fixes it: that of the
    first row showing one (:func:`decimal_mark` of its cells)."""
    for line in lines:
        found = decimal_mark(line.split(separator))
        if found is not None:
            return found
    return None


#: The bytes of the numbers that :func:`number_rows` reads (JSON numbers), between ``,``
#: and ``\n``.
_NUMBER_BYTES: Final = b"0123456789.-+eE"
#: ... and the letters of ``NaN`` and ``Infinity``, once ``nan`` and ``inf`` are renamed.
_NUMBER_BYTES_NAN: Final = _NUMBER_BYTES + b"NaIfinty"


def comma_separated(
    lines: Sequence[str] | bytes, separator: str, decimal: str | None
) -> bytes | None:
    """Lines of a file's notation as :func:`number_rows` reads them: ``,`` between cells and
    ``.`` in numbers, UTF-8; None where that cannot be told (a comma that is neither the
    separator nor the decimal mark, a point beside a decimal comma). The lines may be given
    as UTF-8 bytes, each ended by LF (:attr:`LineBlock.plain`)."""
    data = lines if isinstance(lines, bytes) else "\n".join(lines).encode()
    if separator == ",":
        return data
    if b"," in data and decimal != ",":
        return None
    if decimal == "," and b"." in data:
        return None
    mark = separator.encode()
    if len(mark) != 1:
        return (data.replace(b",", b".") if decimal == "," else data).replace(mark, b",")
    # one pass: the decimal comma becomes a point as the separator becomes a comma
    table = bytes.maketrans(mark + b",", b",.") if decimal == "," else bytes.maketrans(mark, b",")
    return data.translate(table)


def number_rows(block: bytes, width: int, *, empty: bool = False) -> NDArray[np.float64] | None:
    """Rows of ``width`` numbers, ``,``-separated, one per ``\n``-ended line, read fast.

    The block is read as JSON (pydantic's parser, correctly rounded like
    ``float``), which takes only plain numbers (``-1.5``, ``2e-05``, ``nan``,
    ``inf``, ``-inf``). Anything else gives None, and the caller reads the block
    its own slower way, which knows more spellings and says what is wrong: a
    sign ``+``, ``.5``, ``5.``, a leading zero, blank lines or cells, spaces,
    quotes, rows of another width, ``-0`` (an integer zero to JSON, -0.0 to
    ``float``). So a block read here holds exactly the floats that ``float``
    reads from its cells.

    With ``empty``, a cell may be empty (not the first of a row): it is NaN in
    the result, and a block that spells NaN or inf in a cell gives None, so a
    NaN always means an empty cell.
    """
    body = block.rstrip(b"\n")
    if not body:
        return None
    number_bytes = _NUMBER_BYTES
    blanks = None
    if empty:
        if b"n" in body or b"N" in body or b"a" in body:
            return None
        # a blank line or an empty first cell is found below, among the empty cells
        body, blanks = _fill_blanks(body)
    elif b"n" in body:
        body = body.replace(b"nan", b"NaN").replace(b"inf", b"Infinity")
        number_bytes = _NUMBER_BYTES_NAN
    # without the numbers' bytes, a block of rows is its separators: every line width - 1
    # commas and a line end; anything else is left over
    separators = body.translate(None, number_bytes) + b"\n"
    if separators != (b"," * (width - 1) + b"\n") * (len(separators) // width):
        return None  # a blank line among them (one empty cell: a row of one)
    if blanks is not None and (blanks % width == 0).any():
        return None  # a row's first cell empty (a blank line in rows of one)
    try:  # one flat array: no list per row for the parser to make and the collector to visit
        flat = b"[" + body.replace(b"\n", b",") + b"]"
        parsed = pydantic_core.from_json(flat, allow_inf_nan=True)
        values = np.array(parsed, dtype=np.float64)
    except (ValueError, TypeError, OverflowError):
        return None
    if values.shape != (len(separators) // width * width,):
        return None
    if blanks is not None:
        values[blanks] = np.nan
    if (values == 0).any() and _MINUS_ZERO.search(body):
        return None
    return values.reshape(-1, width)


def _fill_blanks(body: bytes) -> tuple[bytes, NDArray[np.intp]]:
    """``body`` with a ``0`` in every empty cell, and the indices of those cells (counted
    over all rows)."""
    text = np.frombuffer(body, np.uint8)
    ends = np.append(np.flatnonzero((text == _COMMA) | (text == _NEWLINE)), len(text))
    starts = np.concatenate([[0], ends[:-1] + 1])
    blanks = np.flatnonzero(starts == ends)
    if len(blanks):
        body = np.insert(text, starts[blanks], _ZERO).tobytes()
    return body, blanks


_ZERO, _COMMA, _NEWLINE = b"0,\n"

#: A cell ``-0``: an integer zero to JSON, -0.0 to ``float``.
_MINUS_ZERO: Final = re.compile(rb"-0(?:[,\n]|\Z)")


# --- units -----------------------------------------------------------------------------

_UNIT_FACTORS: Final[Mapping[str, Mapping[str, float]]] = {
    "position_mm": {"mm": 1.0, "um": 1e-3, "m": 1e3},
    "velocity_mm_min": {"mm/min": 1.0, "mm/s": 60.0, "m/min": 1e3, "m/s": 6e4},
    "velocity_cmd_mm_min": {"mm/min": 1.0, "mm/s": 60.0, "m/min": 1e3, "m/s": 6e4},
    "current_a": {"a": 1.0, "ma": 1e-3},
    "marker": {"1": 1.0, "": 1.0},
}


def normalize_unit(unit: str) -> str:
    """A unit as written in a trace, reduced to a lookup key (``"µm"`` -> ``"um"``)."""
    text = unit.strip().strip("[]()").strip()
    text = text.replace("µ", "u").replace("μ", "u").replace(" ", "")
    return text.lower()


def unit_factor(signal: str, unit: str) -> float | None:
    """The factor that turns ``unit`` into the ncmeasure unit of ``signal``, if known."""
    return _UNIT_FACTORS.get(signal, {}).get(normalize_unit(unit))


# --- reading text ----------------------------------------------------------------------


class LineBlock:
    """Lines taken at once (:meth:`TextLines.take_block`): :attr:`lines` as
    :meth:`TextLines.take` gives them, decoded when first asked for, and :attr:`plain`,
    their bytes with LF line ends where the block is plain ASCII (else None)."""

    def __init__(
        self, plain: bytes | None, lines: list[str] | Callable[[], list[str]], count: int
    ) -> None:
        self.plain = plain
        self._lines = lines
        self._count = count

    def __len__(self) -> int:
        return self._count

    @property
    def lines(self) -> list[str]:
        """The lines, without their line ends."""
        if callable(self._lines):
            self._lines = self._lines()
        return self._lines


class TextLines:
    """The lines of a text file, read once, with their numbers and a byte count for progress.

    UTF-8 (with or without BOM) is tried first; a file that is not UTF-8 is
    read as Windows-1252, the code page of the controllers' Windows PCs. A
    line ends with LF, CRLF or a bare CR (old Mac-style exports still occur);
    the file is read in blocks, so a file without LF is not read whole. Use
    it as a context manager, so the file is closed when an import stops early.
    """

    def __init__(self, path: Path, job: ImportJob) -> None:
        self.path = path
        self.job = job
        with path.open("rb") as file:
            head = file.read(_SNIFF_BYTES)
        self.encoding = "utf-8"
        try:
            head.decode("utf-8")
        except UnicodeDecodeError as exc:
            if exc.start < len(head) - 4:  # not merely a character cut at the sniff limit
                self.encoding = "cp1252"
                job.note(f"{path.name} is not UTF-8 text; read as Windows-1252")
        self.line_number = 0
        self._file: BinaryIO | None = None
        self._rest = b""  # read from the file, not split into lines yet (a line's start)
        self._pending: list[bytes] = []  # raw lines read from the file, not given out yet
        self._at = 0  # ... from this index on
        self._bytes_read = 0
        self._reported = 0
        self._finished = False
        self._lines: Generator[str, None, None] = self._read()

    def __iter__(self) -> Iterator[str]:
        return self._lines

    def __next__(self) -> str:
        return next(self._lines)

    def __enter__(self) -> TextLines:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._lines.close()
        if self._file is not None:
            self._file.close()

    def _next_lines(self, file: BinaryIO) -> list[bytes]:
        """The next lines of ``file`` with their endings, a list per block read ([] at the
        end); bytes.splitlines knows LF, CRLF and CR."""
        while block := file.read(_READ_BYTES):
            lines = (self._rest + block).splitlines(keepends=True)
            # the last line may continue in the next block (a CR may be half of a CRLF)
            self._rest = b"" if lines[-1].endswith(b"\n") else lines.pop()
            if lines:
                return lines
        rest, self._rest = self._rest, b""
        return [rest] if rest else []

    def _open(self) -> BinaryIO:
        if self._file is None:
            self._file = self.path.open("rb")
        return self._file

    def _refill(self) -> bool:
        """Read the next block of raw lines when all are given out; False at the end."""
        if self._at < len(self._pending):
            return True
        self._pending = self._next_lines(self._open())
        self._at = 0
        return bool(self._pending)

    def _span(self, count: int) -> tuple[bytes, int]:
        """The next ``count`` lines (fewer at the end) as the file holds them, read in one
        piece, and how many they are; no line pending. Where a line among them ends in a
        bare CR, what was read is left pending as lines instead, and ``(b"", 0)`` returned."""
        file = self._open()
        line_bytes = self._bytes_read // max(self.line_number, 1) + 1
        chunks = [self._rest]
        newlines = self._rest.count(b"\n")
        at_end = False
        while newlines < count:
            block = file.read(min(max((count - newlines) * line_bytes, _READ_BYTES), _SPAN_BYTES))
            if not block:
                at_end = True
                break
            chunks.append(block)
            newlines += block.count(b"\n")
        data = b"".join(chunks)
        if at_end:  # the last line may end without LF
            cut, count = len(data), newlines + (bool(data) and not data.endswith(b"\n"))
        else:
            cut = int(np.flatnonzero(np.frombuffer(data, np.uint8) == _NEWLINE)[count - 1]) + 1
        span = data[:cut]
        if b"\r" in span and span.count(b"\r") != span.count(b"\r\n"):
            # lines as _next_lines splits them: the last may continue in the file
            lines = data.splitlines(keepends=True)
            self._rest = b"" if at_end or lines[-1].endswith(b"\n") else lines.pop()
            self._pending, self._at = lines, 0
            return b"", 0
        self._rest = data[cut:]
        return span, count

    def _raw(self, count: int) -> list[bytes]:
        """The next ``count`` raw lines (fewer at the end), shared by iteration and :meth:`take`."""
        taken: list[bytes] = []
        while len(taken) < count and self._refill():
            end = self._at + count - len(taken)
            taken += self._pending[self._at : end]
            self._at = min(end, len(self._pending))
        return taken

    def _progress(self, count: int) -> None:
        self._bytes_read += count
        if self._bytes_read - self._reported >= PROGRESS_STEP_BYTES:
            self.job.tick(self._bytes_read)
            self._reported = self._bytes_read

    def _finish(self) -> None:
        if not self._finished:
            self._finished = True
            self.job.tick(self._bytes_read)

    def _decode(self, raw: bytes, line_number: int) -> str:
        try:
            return raw.decode(self.encoding)
        except UnicodeDecodeError as exc:
            raise RecordingError(
                f"{self.path}:{line_number}: not valid {self.encoding} text "
                f"(byte {exc.start + 1} of the line)"
            ) from exc

    def _read(self) -> Generator[str, None, None]:
        while self._refill():
            raw = self._pending[self._at]
            self._at += 1
            self.line_number += 1
            self._progress(len(raw))
            text = self._decode(raw, self.line_number)
            if self.line_number == 1:
                text = text.lstrip("\ufeff")
            yield text.rstrip("\r\n")
        self._finish()

    def take(self, count: int) -> list[str]:
        """The next ``count`` lines (fewer at the end, none after it) as iteration gives
        them, decoded at once: the way to read the many lines of the data.

        After it, :attr:`line_number` is the number of the last line taken.
        """
        return self.take_block(count).lines

    def take_block(self, count: int) -> LineBlock:
        """:meth:`take`, with the lines' bytes for a reader that parses bytes: where every
        byte is ASCII and no line ends in a bare CR, :attr:`LineBlock.plain` holds the lines
        each ended by LF (the last perhaps by nothing), and the lines are decoded only when
        asked for. The lines not read yet come from the file in one piece, not line by
        line."""
        first = self.line_number + 1
        # the lines pending, then the rest from the file in one piece (line by line where a
        # line ends in a bare CR: _span leaves them pending)
        before = self._pending[self._at : self._at + count]
        self._at += len(before)
        span, in_span = self._span(count - len(before)) if count > len(before) else (b"", 0)
        after = self._raw(count - len(before) - in_span) if not in_span else []
        taken = len(before) + in_span + len(after)
        if not taken:
            self._finish()
            return LineBlock(None, [], 0)
        data = b"".join([*before, span, *after])
        self._progress(len(data))
        plain: bytes | None = None
        if first > 1 and data.isascii():  # no BOM, the same text in UTF-8 and Windows-1252
            plain = data.replace(b"\r\n", b"\n") if b"\r" in data else data
            if b"\r" in plain:  # a line ended by a bare CR
                plain = None

        def decoded() -> list[str]:
            raw = [*before, *span.splitlines(keepends=True), *after]
            return self._decoded(raw, data, first)

        block = LineBlock(plain, decoded if plain is not None else decoded(), taken)
        self.line_number += taken
        return block

    def _decoded(self, raw: list[bytes], data: bytes, first: int) -> list[str]:
        """The lines of ``raw`` (``data`` joined), the first line number ``first``, decoded."""
        try:
            text = data.decode(self.encoding)
        except UnicodeDecodeError:
            for offset, line in enumerate(raw):  # the line and byte, as line by line
                self._decode(line, first + offset)
            raise
        # a raw line holds CR or LF only at its end; str.splitlines also splits at other
        # characters (form feed, U+2028 ...), which gives more lines than were read
        lines = text.splitlines()
        if len(lines) != len(raw):  # line by line then
            lines = [self._decode(line, first + i).rstrip("\r\n") for i, line in enumerate(raw)]
        if first == 1:
            lines[0] = lines[0].lstrip("\ufeff")
        return lines

    def where(self) -> str:
        """``file:line`` of the line last read."""
        return f"{self.path}:{self.line_number}"


def filetime_to_datetime(ticks: int) -> dt.datetime:
    """A Windows FILETIME (100 ns ticks since 1601-01-01 UTC) as an aware datetime."""
    return dt.datetime(1601, 1, 1, tzinfo=dt.UTC) + dt.timedelta(microseconds=ticks // 10)


_ISO_DATETIME: Final = re.compile(
    r"(?<![\w.:/-])(\d{4}-\d{2}-\d{2})[T ](\d{2}:\d{2}(?::\d{2}(?:[.,]\d{1,9})?)?)"
    r"(Z|[+-]\d{2}(?::?\d{2})?)?(?![\w.:/-])"
)
"""An ISO 8601 date-time in text: ``2024-03-05 14:22:10``, ``2024-03-05T14:22:10.5+01:00``.
A date alone, or a date written another way (``05.03.2024``, ``03/05/24``), is not one:
its reading depends on the locale."""


def _as_utc(when: dt.datetime) -> dt.datetime:
    return when if when.tzinfo is not None else when.replace(tzinfo=dt.UTC)


def _iso_datetimes(text: str) -> dict[dt.datetime, dt.datetime]:
    """The ISO 8601 date-times in ``text``: in UTC -> as written (naive without a zone)."""
    found: dict[dt.datetime, dt.datetime] = {}
    for match in _ISO_DATETIME.finditer(text):
        date, time, zone = match.groups()
        try:
            when = dt.datetime.fromisoformat(f"{date}T{time.replace(',', '.')}{zone or ''}")
        except ValueError:
            continue
        found.setdefault(_as_utc(when), when)
    return found


def iso_datetime(text: str) -> dt.datetime | None:
    """The ISO 8601 date-time that ``text`` is (a cell) or holds (a line); None: none, or
    several different; without a zone it is naive (the caller takes it as UTC)."""
    found = _iso_datetimes(text)
    return next(iter(found.values())) if len(found) == 1 else None


def preamble_date(lines: Sequence[str]) -> tuple[dt.datetime | None, str]:
    """The date-time of a preamble (the lines before a file's header): the one ISO 8601
    date-time its lines hold, and where (``line 2 'Date: 2024-03-05 14:22:10'``).

    Returns:
        ``(None, why)`` when the lines hold several different ones; ``(None, "")`` for none.
    """
    found: dict[dt.datetime, tuple[dt.datetime, str]] = {}
    for number, line in enumerate(lines, start=1):
        for key, when in _iso_datetimes(line).items():
            found.setdefault(key, (when, f"line {number} {line.strip()[:60]!r}"))
    if len(found) == 1:
        return next(iter(found.values()))
    if found:
        return None, f"the lines before the header hold {len(found)} different date-times"
    return None, ""
