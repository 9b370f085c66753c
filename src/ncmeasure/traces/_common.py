"""What the trace importers share: axis mapping, units, invalid samples, the target recording.

Every importer turns the signals of a controller trace into *candidates*
(this trace column could be that ncmeasure signal of that controller axis, in
this unit), lets :func:`plan_channels` decide which become channels of the
recording, and streams rows into a :class:`~ncmeasure.recording.ImportSink`. Two ways of
building rows exist, matching the two ways controllers write traces:

* :class:`CarryForward` for record-oriented traces (Sinumerik) where a record
  holds only the signals sampled at that instant and the others keep their
  last value;
* :class:`SeriesMerge` for column-oriented traces (TwinCAT Scope, TNCscope)
  where every channel has its own timeline, merged on the union of the times
  as the samples arrive (:func:`merge_series` is the same merge over whole
  arrays, its definition).

A failed import removes everything it wrote (:meth:`~ncmeasure.recording.ImportSink.discard`).
"""

from __future__ import annotations

import csv
import datetime as dt
import functools
import logging
import math
import re
import tempfile
from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Final, Literal

import numpy as np
from numpy.typing import NDArray

from ncmeasure.config import AXIS_NAME_PATTERN, MachineConfig
from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.recording import ImportSink, Recording, machine_axis
from ncmeasure.samples import SIGNAL_UNITS, Channel

__all__ = [
    "CHUNK_ROWS",
    "INVALID_ABOVE",
    "MERGE_ROWS",
    "SPILL_ROWS",
    "Candidate",
    "CarryForward",
    "ImportJob",
    "Mapped",
    "Needs",
    "ProgressFn",
    "Series",
    "SeriesMerge",
    "TextLines",
    "TraceImport",
    "check_source",
    "check_target",
    "decimal_mark",
    "filetime_to_datetime",
    "is_invalid",
    "merge_series",
    "normalize_unit",
    "parse_number",
    "plan_channels",
    "resolve_axes",
    "run_import",
    "unit_factor",
]

log = logging.getLogger(__name__)

ProgressFn = Callable[[int, int], None]

#: Values at or above this magnitude mark an invalid sample. Sinumerik writes
#: such samples as the bit pattern of +inf read as a 64-bit integer
#: (0x7FF0000000000000 = 9218868437227405312); the public parser
#: eliasrhoden/Trace-Tools rejects every value above 9218868437227405000.
INVALID_ABOVE: Final = 9.218868437227405e18
#: Rows handed to the recording at a time: bounds the memory of a streaming import.
CHUNK_ROWS: Final = 8192
#: Rows merged at a time from column-oriented traces (:class:`SeriesMerge`).
MERGE_ROWS: Final = 1 << 16
#: Samples of a channel that runs ahead of the others kept in memory; more wait on disk.
SPILL_ROWS: Final = 1 << 16
#: Bytes read before the progress callback is called again.
PROGRESS_STEP_BYTES: Final = 1 << 20
_SNIFF_BYTES: Final = 1 << 16
_READ_BYTES: Final = 1 << 16


@dataclass(frozen=True)
class TraceImport:
    """The result of an import: the new recording and what happened on the way.

    Attributes:
        directory: The new recording's directory.
        meta: Its ``meta.json`` (channels, number of samples, period, report).
        report: One sentence per fact: which trace signal became which
            channel (with unit conversions), what was not imported and why,
            invalid samples, dropped rows.
    """

    directory: Path
    meta: RecordingMeta
    report: list[str]

    @functools.cached_property
    def recording(self) -> Recording:
        """The recording, read from disk on first use (an import itself never holds it whole)."""
        return Recording.open(self.directory)


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
        self._lines: Generator[str, None, None] = self._read()

    def __iter__(self) -> Iterator[str]:
        return self._lines

    def __next__(self) -> str:
        return next(self._lines)

    def __enter__(self) -> TextLines:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._lines.close()

    def _raw_lines(self, file: BinaryIO) -> Iterator[bytes]:
        """The lines of ``file`` with their endings; bytes.splitlines knows LF, CRLF and CR."""
        rest = b""
        while block := file.read(_READ_BYTES):
            lines = (rest + block).splitlines(keepends=True)
            # the last line may continue in the next block (a CR may be half of a CRLF)
            rest = b"" if lines[-1].endswith(b"\n") else lines.pop()
            yield from lines
        if rest:
            yield rest

    def _read(self) -> Generator[str, None, None]:
        bytes_read = 0
        reported = 0
        with self.path.open("rb") as file:
            for raw in self._raw_lines(file):
                self.line_number += 1
                bytes_read += len(raw)
                if bytes_read - reported >= PROGRESS_STEP_BYTES:
                    self.job.tick(bytes_read)
                    reported = bytes_read
                try:
                    text = raw.decode(self.encoding)
                except UnicodeDecodeError as exc:
                    raise RecordingError(
                        f"{self.path}:{self.line_number}: not valid {self.encoding} text "
                        f"(byte {exc.start + 1} of the line)"
                    ) from exc
                if self.line_number == 1:
                    text = text.lstrip("\ufeff")
                yield text.rstrip("\r\n")
        self.job.tick(bytes_read)

    def where(self) -> str:
        """``file:line`` of the line last read."""
        return f"{self.path}:{self.line_number}"


# --- the import job --------------------------------------------------------------------


class ImportJob:
    """One import: its arguments, the report it builds and the progress it reports."""

    def __init__(
        self,
        path: Path,
        directory: Path,
        format_name: str,
        *,
        machine: MachineConfig | None,
        axis_names: Mapping[str, str] | None,
        progress: ProgressFn | None,
    ) -> None:
        self.path = path
        self.directory = directory
        self.format_name = format_name
        self.machine = machine
        self.axis_names = dict(axis_names) if axis_names is not None else None
        self._progress = progress
        self.total_bytes = path.stat().st_size
        self.report: list[str] = []
        self.link: dict[str, Any] = {"type": "import", "format": format_name, "file": path.name}
        self.sink: ImportSink | None = None

    def note(self, line: str) -> None:
        """Add a sentence to the report."""
        log.info("%s: %s", self.path.name, line)
        self.report.append(line)

    def tick(self, bytes_read: int) -> None:
        """Tell the progress callback how far the import got."""
        if self._progress is not None:
            self._progress(min(bytes_read, self.total_bytes), self.total_bytes)

    def open_sink(
        self,
        channels: Sequence[Channel],
        *,
        nominal_period_s: float | None,
        start_utc: dt.datetime | None = None,
    ) -> ImportSink:
        """The recording the rows go to (created on disk when the first rows arrive)."""
        self.sink = ImportSink(
            self.directory,
            channels,
            machine=self.machine,
            nominal_period_s=nominal_period_s,
            what="the trace",
            start_utc=start_utc,
            source=f"import:{self.format_name}",
            notes=f"imported from {self.path.name}",
            link=self.link,
        )
        return self.sink

    def finish(self) -> RecordingMeta:
        """Close the recording with the complete report (it is not read back)."""
        if self.sink is None:
            raise RecordingError(f"{self.path}: no samples to import")
        for line in self.sink.validity_lines():
            self.note(line)
        self.link["report"] = list(self.report)
        meta = self.sink.close("complete", link=dict(self.link))
        self.tick(self.total_bytes)  # the whole file is done, even if an end marker stopped reading
        return meta

    def discard(self) -> None:
        """Remove what this import wrote."""
        if self.sink is not None:
            self.sink.discard()


def check_source(path: Path) -> None:
    """Fail with a clear message when ``path`` is not a file that can be imported."""
    if not path.is_file():
        if path.is_dir():
            raise RecordingError(f"{path}: is a directory, expected a trace file")
        raise RecordingError(f"{path}: no such file")


def run_import(job: ImportJob, read: Callable[[ImportJob], RecordingMeta]) -> TraceImport:
    """Run an importer on ``job``; on any failure remove what it wrote.

    Returns:
        The recording ``read`` finished and the job's report.

    Raises:
        RecordingError: What ``read`` raised, or a read error of the file
            (not text, cannot be read) turned into one.
    """
    try:
        meta = read(job)
    except BaseException as exc:
        job.discard()
        if isinstance(exc, UnicodeDecodeError):
            raise RecordingError(f"{job.path}: not a text file") from exc
        if isinstance(exc, csv.Error):
            raise RecordingError(f"{job.path}: cannot be split into cells ({exc})") from exc
        if isinstance(exc, OSError) and not isinstance(exc, RecordingError):
            raise RecordingError(f"{job.path}: cannot be read ({exc.strerror or exc})") from exc
        raise
    log.info(
        "imported %s (%s) into %s: %d samples",
        job.path,
        job.format_name,
        job.directory,
        meta.samples,
    )
    return TraceImport(job.directory, meta, job.report)


def check_target(directory: Path) -> None:
    """Fail before reading a large trace when the recording could not be written anyway."""
    if directory.exists():
        if not directory.is_dir():
            raise RecordingError(f"{directory}: exists and is not a directory")
        if any(directory.iterdir()):
            raise RecordingError(
                f"{directory}: directory is not empty; a recording needs a new or empty directory"
            )


# --- mapping trace signals to channels -------------------------------------------------

Needs = Literal["", "screw_lead", "torque_constant"]


@dataclass(frozen=True)
class Candidate:
    """A trace signal that can become an ncmeasure channel.

    Attributes:
        source: The signal as the trace names it.
        axis_id: The controller's axis (an index such as ``"1"`` or a name).
        signal: The ncmeasure signal (a key of ``SIGNAL_UNITS``).
        factor: Multiplies the trace values into ncmeasure units (before ``needs``).
        needs: Machine data the conversion needs: ``screw_lead`` (motor rpm
            to mm/min) or ``torque_constant`` (Nm to A).
        rank: Lower wins when several signals give the same channel; it
            also decides the measuring system of an axis (see below).
        conversion: How the unit is converted, for the report.
        measuring_system: The measuring system (encoder) whose value this
            is, e.g. ``"measuring system 2"``; empty for a value tied to
            none (a current, a motor speed). The channels of one axis that
            come from a measuring system all come from the same one: that of
            the best-ranked such candidate that is imported. A candidate of
            another measuring system of that axis is not imported.
        measuring_system_reason: Why this measuring system is the one to use
            if it is chosen, for the report ("the command position ... refers
            to it").
    """

    source: str
    axis_id: str
    signal: str
    factor: float = 1.0
    needs: Needs = ""
    rank: int = 0
    conversion: str = ""
    measuring_system: str = ""
    measuring_system_reason: str = ""


@dataclass(frozen=True)
class Mapped:
    """A candidate that became a channel, with the factor that converts its values."""

    candidate: Candidate
    channel: Channel
    factor: float
    conversion: str


def _id_order(ids: Sequence[str]) -> list[str]:
    numeric = sorted((i for i in ids if i.isdigit()), key=int)
    return numeric + [i for i in ids if not i.isdigit()]


def resolve_axes(
    ids: Sequence[str],
    machine: MachineConfig | None,
    axis_names: Mapping[str, str] | None,
    report: list[str],
) -> dict[str, str]:
    """Machine axis names for controller axes; the ones left out are reported.

    ``axis_names`` decides alone when given; else controller axes named like a
    machine axis take that axis and the others take the remaining machine
    axes in order (numeric indices ascending); without a machine file a
    controller axis keeps a name that is a valid axis name and an index ``n``
    becomes ``An``.

    Raises:
        ConfigError: ``axis_names`` names an invalid or unknown axis, or two
            controller axes get the same name.
    """
    known = [a.name for a in machine.axes] if machine is not None else None
    result: dict[str, str] = {}
    if axis_names is not None:
        problems: list[str] = []
        for key, name in axis_names.items():
            if not re.fullmatch(AXIS_NAME_PATTERN, name):
                problems.append(
                    f"axis_names[{key!r}]: {name!r} is not an axis name (X, Y, Z1, ...)"
                )
            elif known is not None and name not in known:
                problems.append(
                    f"axis_names[{key!r}]: {name} is not an axis of the machine "
                    f"({', '.join(known)})"
                )
        targets = list(axis_names.values())
        for name in sorted({n for n in targets if targets.count(n) > 1}):
            problems.append(f"axis_names: more than one controller axis is mapped to {name}")
        if problems:
            raise ConfigError("axis_names does not fit", problems)
        for axis_id in ids:
            if axis_id in axis_names:
                result[axis_id] = axis_names[axis_id]
                report.append(f"controller axis {axis_id} -> {axis_names[axis_id]} (axis_names)")
            else:
                report.append(f"controller axis {axis_id}: not imported (not in axis_names)")
        for key in axis_names:
            if key not in ids:
                report.append(f"axis_names: controller axis {key!r} does not appear in the trace")
        return result
    if known is not None:
        free = list(known)
        for axis_id in ids:
            if axis_id in free:
                result[axis_id] = axis_id
                free.remove(axis_id)
                report.append(f"controller axis {axis_id} -> {axis_id} (same name in the machine)")
        for axis_id in _id_order([i for i in ids if i not in result]):
            if not free:
                report.append(
                    f"controller axis {axis_id}: not imported (the machine file has no further "
                    "axis; pass axis_names)"
                )
                continue
            result[axis_id] = free.pop(0)
            report.append(
                f"controller axis {axis_id} -> {result[axis_id]} (machine axes in order; "
                "pass axis_names to choose)"
            )
        return result
    used: set[str] = set()
    for axis_id in _id_order(ids):
        if re.fullmatch(AXIS_NAME_PATTERN, axis_id):
            name = axis_id
        elif axis_id.isdigit() and re.fullmatch(AXIS_NAME_PATTERN, f"A{int(axis_id)}"):
            name = f"A{int(axis_id)}"
        else:
            name = next(f"A{k}" for k in range(1, 10_000) if f"A{k}" not in used)
        if name in used:
            name = next(f"A{k}" for k in range(1, 10_000) if f"A{k}" not in used)
        used.add(name)
        result[axis_id] = name
        report.append(
            f"controller axis {axis_id} -> {name} (no machine file or axis_names; default name)"
        )
    return result


def plan_channels(candidates: Sequence[Candidate], job: ImportJob) -> list[Mapped]:
    """Decide which candidates become channels; report every decision.

    Returns:
        The channels, axis by axis in the order of the axes, signals in the
        order of ``SIGNAL_UNITS``.

    Raises:
        RecordingError: No candidate can be imported.
        ConfigError: ``axis_names`` does not fit (see :func:`resolve_axes`).
    """
    ids = list(dict.fromkeys(c.axis_id for c in candidates))
    axis_map = resolve_axes(ids, job.machine, job.axis_names, job.report)
    chosen: dict[Channel, Mapped] = {}
    # axis -> the candidate that decided the axis' measuring system
    systems: dict[str, Candidate] = {}
    for cand in sorted(candidates, key=lambda c: c.rank):
        axis = axis_map.get(cand.axis_id)
        if axis is None:
            job.note(f"{cand.source}: not imported (controller axis {cand.axis_id} has no name)")
            continue
        channel = Channel(axis, cand.signal, SIGNAL_UNITS[cand.signal])
        if channel in chosen:
            job.note(
                f"{cand.source}: not imported ({channel.name} already comes from "
                f"{chosen[channel].candidate.source})"
            )
            continue
        decided = systems.get(axis)
        if (
            cand.measuring_system
            and decided is not None
            and decided.measuring_system != cand.measuring_system
        ):
            job.note(
                f"{cand.source}: not imported (axis {axis} takes its values from "
                f"{decided.measuring_system}; this is {cand.measuring_system}, and the two "
                "are not mixed)"
            )
            continue
        factor = cand.factor
        conversion = cand.conversion or "no unit conversion"
        axis_config = machine_axis(job.machine, axis)
        where = "of the machine file" if job.machine is not None else "(no machine file given)"
        if cand.needs == "screw_lead":
            lead = axis_config.screw_lead_mm if axis_config is not None else None
            if lead is None:
                job.note(
                    f"{cand.source}: velocity not converted, not imported: motor speed in rpm "
                    f"needs screw_lead_mm of axis {axis} {where}"
                )
                continue
            factor *= lead
            conversion = (
                f"motor rpm x screw lead {lead:g} mm/rev = mm/min, assuming the motor "
                "drives the screw directly"
            )
        elif cand.needs == "torque_constant":
            k_t = axis_config.torque_constant_nm_per_a if axis_config is not None else None
            if k_t is None:
                job.note(
                    f"{cand.source}: torque not converted, not imported: Nm to A needs "
                    f"torque_constant_nm_per_a of axis {axis} {where}"
                )
                continue
            factor /= k_t
            conversion = f"torque Nm / torque constant {k_t:g} Nm/A = A"
        chosen[channel] = Mapped(cand, channel, factor, conversion)
        if cand.measuring_system and decided is None:
            systems[axis] = cand
    axis_order = list(dict.fromkeys(axis_map[i] for i in ids if i in axis_map))
    if job.machine is not None:
        names = [a.name for a in job.machine.axes]
        axis_order.sort(key=lambda a: names.index(a) if a in names else len(names))
    signal_order = list(SIGNAL_UNITS)
    mapped = sorted(
        chosen.values(),
        key=lambda m: (axis_order.index(m.channel.axis), signal_order.index(m.channel.signal)),
    )
    for axis in axis_order:
        if axis in systems:
            job.note(_measuring_system_sentence(axis, systems[axis], mapped, candidates, axis_map))
    for m in mapped:
        job.note(f"{m.channel.name} [{m.channel.unit}]: from {m.candidate.source} ({m.conversion})")
    if not mapped:
        raise RecordingError(
            f"{job.path}: no signal of the trace can be imported as an ncmeasure channel",
            job.report,
        )
    return mapped


def _quantity(signal: str) -> str:
    """``position_mm`` -> ``position``: the word for a signal in a report sentence."""
    return re.sub(r"_(mm_min|mm|a)$", "", signal).replace("_", " ")


def _measuring_system_sentence(
    axis: str,
    decider: Candidate,
    mapped: Sequence[Mapped],
    candidates: Sequence[Candidate],
    axis_map: Mapping[str, str],
) -> str:
    """``axis X: position and velocity from measuring system 2 (reason)``, and what it lacks."""
    system = decider.measuring_system
    taken = [
        m.channel.signal
        for m in mapped
        if m.channel.axis == axis and m.candidate.measuring_system == system
    ]
    offered = list(
        dict.fromkeys(
            c.signal for c in candidates if c.measuring_system and axis_map.get(c.axis_id) == axis
        )
    )
    lacking = [s for s in offered if s not in taken]
    taken.sort(key=lambda s: s != "position_mm")  # "position and velocity"
    words = " and ".join(_quantity(s) for s in taken)
    sentence = f"axis {axis}: {words} from {system} ({decider.measuring_system_reason})"
    if lacking:
        sentence += (
            f"; the trace has no {' and no '.join(_quantity(s) for s in lacking)} of {system}, "
            "and that of another measuring system is not mixed in"
        )
    return sentence


# --- the target recording --------------------------------------------------------------


# --- building rows ---------------------------------------------------------------------


class CarryForward:
    """Rows from records that hold only some signals: the others keep their last value.

    A record before every channel has had a value is dropped (counted in
    :attr:`dropped_leading`). An invalid sample (:func:`is_invalid`) makes its
    channel NaN until the next valid value and is counted per channel.
    """

    def __init__(
        self,
        sink: ImportSink,
        names: Sequence[str],
        factors: Sequence[float],
        chunk_rows: int | None = None,
    ) -> None:
        self._sink = sink
        self.names = list(names)
        self._factors = list(factors)
        self._chunk_rows = chunk_rows or CHUNK_ROWS  # read now: tests make it small
        self._current = [math.nan] * len(names)
        self._seen = [False] * len(names)
        self._unseen = len(names)
        self._times: list[float] = []
        self._rows: list[list[float]] = []
        self._last_time = -math.inf
        self.records = 0
        self.dropped_leading = 0
        self.first_complete_s: float | None = None
        self.invalid = [0] * len(names)
        self.first_invalid: list[str | None] = [None] * len(names)

    def set(self, column: int, raw: float, where: Callable[[], str]) -> None:
        """Give ``column`` a new value (as the trace writes it) in the current record."""
        if not self._seen[column]:
            self._seen[column] = True
            self._unseen -= 1
        if is_invalid(raw):
            self.invalid[column] += 1
            if self.first_invalid[column] is None:
                self.first_invalid[column] = where()
            self._current[column] = math.nan
        else:
            self._current[column] = raw * self._factors[column]

    def commit(self, time_s: float, where: Callable[[], str]) -> None:
        """End the current record at ``time_s``.

        Raises:
            RecordingError: The time is not a finite number or not later than
                the record before.
        """
        if not math.isfinite(time_s):
            raise RecordingError(f"{where()}: time {time_s!r} is not a finite number")
        if not time_s > self._last_time:
            raise RecordingError(
                f"{where()}: time {time_s!r} s is not later than the record before "
                f"({self._last_time!r} s); times must increase"
            )
        self._last_time = time_s
        self.records += 1
        if self._unseen:
            self.dropped_leading += 1
            return
        if self.first_complete_s is None:
            self.first_complete_s = time_s
        self._times.append(time_s)
        self._rows.append(self._current.copy())
        if len(self._times) >= self._chunk_rows:
            self.flush()

    def flush(self) -> None:
        """Hand the collected rows to the recording."""
        if not self._times:
            return
        time_s = np.array(self._times, dtype=np.float64)
        values = np.array(self._rows, dtype=np.float64).reshape(len(self._times), len(self.names))
        self._times, self._rows = [], []
        self._sink.append(time_s, values)

    def missing(self) -> list[str]:
        """The channels that never had a value."""
        return [n for n, seen in zip(self.names, self._seen, strict=True) if not seen]

    def summarize(self, job: ImportJob, unit: str = "records") -> None:
        """Report dropped leading rows and invalid samples."""
        if self.dropped_leading and self.first_complete_s is not None:
            job.note(
                f"{self.dropped_leading} leading {unit} dropped: not every channel had a value "
                f"before t = {self.first_complete_s:g} s"
            )
        for name, count, first in zip(self.names, self.invalid, self.first_invalid, strict=True):
            if count:
                job.note(
                    f"{name}: {count} invalid sample(s) (controller's invalid-value marker) "
                    f"stored as NaN until the next valid value; first at {first}"
                )


@dataclass(frozen=True)
class Series:
    """One channel of a column-oriented trace: its own times and values."""

    name: str
    time_s: NDArray[np.float64]
    values: NDArray[np.float64]
    factor: float = 1.0


def merge_series(
    series: Sequence[Series], job: ImportJob
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rows on the union of the channels' times; each channel holds its last value.

    Rows before every channel has a value and after the first channel ends
    are dropped (a held value is not extrapolated past a channel's end);
    invalid samples become NaN. Both are reported.

    Raises:
        RecordingError: A channel has no valid time.
    """
    for s in series:
        if len(s.time_s) == 0:
            raise RecordingError(f"{job.path}: channel {s.name} holds no samples")
    start = max(float(s.time_s[0]) for s in series)
    end = min(float(s.time_s[-1]) for s in series)
    all_times = np.unique(np.concatenate([s.time_s for s in series]))
    keep = (all_times >= start) & (all_times <= end)
    before = int(np.count_nonzero(all_times < start))
    after = int(np.count_nonzero(all_times > end))
    times = all_times[keep]
    values = np.empty((len(times), len(series)), dtype=np.float64)
    for column, s in enumerate(series):
        index = np.searchsorted(s.time_s, times, side="right") - 1
        raw = np.asarray(s.values, dtype=np.float64)
        bad = ~np.isfinite(raw) | (np.abs(raw) >= INVALID_ABOVE)
        column_values = raw * s.factor
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            job.note(
                f"{s.name}: {int(bad.sum())} invalid sample(s) stored as NaN until the next "
                f"valid value; first at t = {float(s.time_s[first]):g} s"
            )
            column_values[bad] = np.nan
        values[:, column] = column_values[index]
    rates = {len(s.time_s) for s in series}
    if len(rates) > 1 or any(not np.array_equal(series[0].time_s, s.time_s) for s in series):
        job.note(
            f"channels have different timelines: merged on the union of their times "
            f"({len(times)} rows); each channel holds its last value between its samples"
        )
    if before:
        job.note(
            f"{before} leading row(s) dropped: not every channel had a value before t = {start:g} s"
        )
    if after:
        job.note(f"{after} trailing row(s) dropped: a channel ends at t = {end:g} s")
    return times, values


class _SampleQueue:
    """One channel's samples waiting to be merged, oldest first; beyond a bound, on disk.

    A channel of a column-oriented trace can run ahead of the others in the
    file (a 2 ms channel beside 1 ms channels gets twice the time per row), so
    its samples wait until the others catch up: up to ``spill_rows`` in
    memory, the older ones in an unnamed temporary file, read back in order.
    """

    def __init__(self, spill_rows: int) -> None:
        self._spill_rows = spill_rows
        self._front = np.empty((0, 2), dtype=np.float64)  # the oldest, ready to be read
        self._file: BinaryIO | None = None
        self._file_rows = 0  # rows in the file not read back yet
        self._read_at = 0
        self._back: list[NDArray[np.float64]] = []  # the newest, after the file's
        self._back_rows = 0

    def __len__(self) -> int:
        return len(self._front) + self._file_rows + self._back_rows

    def push(self, time_s: NDArray[np.float64], values: NDArray[np.float64]) -> None:
        """Add samples later than every sample queued before."""
        self._back.append(np.column_stack([time_s, values]))
        self._back_rows += len(time_s)
        if self._back_rows > self._spill_rows:
            if self._file is None:
                self._file = tempfile.TemporaryFile(prefix="ncmeasure-merge-")  # noqa: SIM115
            self._file.seek(0, 2)
            for block in self._back:
                self._file.write(np.ascontiguousarray(block).tobytes())
            self._file_rows += self._back_rows
            self._back, self._back_rows = [], 0

    def peek(self, limit: int) -> NDArray[np.float64]:
        """Up to ``limit`` of the oldest samples (rows of time, value), left in the queue."""
        parts = [self._front]
        have = len(self._front)
        if have < limit and self._file_rows:
            assert self._file is not None
            count = min(limit - have, self._file_rows)
            self._file.seek(self._read_at)
            data = self._file.read(count * 16)
            parts.append(np.frombuffer(data, dtype=np.float64).reshape(count, 2))
            self._read_at += count * 16
            self._file_rows -= count
            have += count
            if not self._file_rows:  # all read back: the file starts again from empty
                self._file.seek(0)
                self._file.truncate()
                self._read_at = 0
        if have < limit and not self._file_rows and self._back:
            parts.extend(self._back)
            self._back, self._back_rows = [], 0
        if len(parts) > 1:
            self._front = np.concatenate(parts)
        return self._front[:limit]

    def consume(self, count: int) -> None:
        """Drop the ``count`` oldest samples (after :meth:`peek`)."""
        self._front = self._front[count:]

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class SeriesMerge:
    """:func:`merge_series` as a stream: samples go in channel by channel, rows come out.

    Channels hand over their samples (times strictly increasing per channel)
    in any portions; a row at a time of the union is written once every
    channel has reached that time, so a channel ahead waits (on disk beyond
    ``spill_rows``) and memory stays bounded by the portions. The rows, the
    values and the report sentences are exactly those of :func:`merge_series`
    over all samples at once; :meth:`finish` adds the sentences.
    """

    def __init__(
        self,
        sink: ImportSink,
        names: Sequence[str],
        factors: Sequence[float],
        *,
        batch_rows: int,
        spill_rows: int,
    ) -> None:
        self._sink = sink
        self.names = list(names)
        self._factors = list(factors)
        self._batch_rows = batch_rows
        self._queues = [_SampleQueue(spill_rows) for _ in names]
        self._first = [math.nan] * len(names)
        self._latest = [-math.inf] * len(names)
        self._samples = [0] * len(names)
        self._carry = [math.nan] * len(names)
        self._invalid = [0] * len(names)
        self._first_invalid_s = [math.nan] * len(names)
        self._waiting = len(names)  # channels without a sample yet
        self._start = math.nan
        self.rows = 0
        self._union = 0
        self._before = 0

    def add(self, column: int, time_s: NDArray[np.float64], raw: NDArray[np.float64]) -> None:
        """Hand over samples of a channel, in the trace's unit (later than its samples before)."""
        if len(time_s) == 0:
            return
        raw = np.asarray(raw, dtype=np.float64)
        bad = ~np.isfinite(raw) | (np.abs(raw) >= INVALID_ABOVE)
        values = raw * self._factors[column]
        if bad.any():
            if not self._invalid[column]:
                self._first_invalid_s[column] = float(time_s[int(np.flatnonzero(bad)[0])])
            self._invalid[column] += int(bad.sum())
            values[bad] = np.nan
        if not self._samples[column]:
            self._first[column] = float(time_s[0])
            self._waiting -= 1
            if not self._waiting:
                self._start = max(self._first)
        self._samples[column] += len(time_s)
        self._latest[column] = float(time_s[-1])
        self._queues[column].push(np.asarray(time_s, dtype=np.float64), values)

    def flush(self) -> None:
        """Write the rows up to the time that every channel has reached."""
        if not self._waiting:
            self._drain(min(self._latest), write=True)

    def finish(self, job: ImportJob) -> None:
        """Write the last rows, drop those after the first channel's end, report.

        Raises:
            RecordingError: A channel has no sample.
        """
        try:
            for name, count in zip(self.names, self._samples, strict=True):
                if not count:
                    raise RecordingError(f"{job.path}: channel {name} holds no samples")
            end = min(self._latest)
            self._drain(end, write=True)
            after = self._union
            self._drain(math.inf, write=False)  # after the end: only counted
            after = self._union - after
        finally:
            self.close()
        for name, count, first in zip(
            self.names, self._invalid, self._first_invalid_s, strict=True
        ):
            if count:
                job.note(
                    f"{name}: {count} invalid sample(s) stored as NaN until the next "
                    f"valid value; first at t = {first:g} s"
                )
        if any(count != self._union for count in self._samples):
            job.note(
                f"channels have different timelines: merged on the union of their times "
                f"({self.rows} rows); each channel holds its last value between its samples"
            )
        if self._before:
            job.note(
                f"{self._before} leading row(s) dropped: not every channel had a value before "
                f"t = {self._start:g} s"
            )
        if after:
            job.note(f"{after} trailing row(s) dropped: a channel ends at t = {end:g} s")

    def close(self) -> None:
        """Remove the temporary files of channels that ran ahead."""
        for queue in self._queues:
            queue.close()

    def _drain(self, horizon: float, *, write: bool) -> None:
        """Merge the queued samples at times up to ``horizon``, a batch at a time."""
        while True:
            heads = [queue.peek(self._batch_rows) for queue in self._queues]
            upto = horizon
            for queue, head in zip(self._queues, heads, strict=True):
                if len(head) == self._batch_rows and len(queue) > len(head):
                    upto = min(upto, float(head[-1, 0]))  # more of this channel may follow
            counts = [int(np.searchsorted(h[:, 0], upto, side="right")) for h in heads]
            if not any(counts):
                return
            taken = [head[:n, 0] for head, n in zip(heads, counts, strict=True)]
            union = np.unique(np.concatenate(taken))
            self._union += len(union)
            keep = union >= self._start
            times = union[keep]
            rows = np.empty((len(times), len(heads)), dtype=np.float64)
            for column, (queue, head, count) in enumerate(
                zip(self._queues, heads, counts, strict=True)
            ):
                # value at t: the channel's last sample at or before t, from this batch or before
                held = np.concatenate([[self._carry[column]], head[:count, 1]])
                index = np.searchsorted(head[:count, 0], times, side="right")
                rows[:, column] = held[index]
                if count:
                    self._carry[column] = float(head[count - 1, 1])
                queue.consume(count)
            self._before += int(len(union) - len(times))
            if write and len(times):
                self.rows += len(times)
                self._sink.append(times, rows)


def filetime_to_datetime(ticks: int) -> dt.datetime:
    """A Windows FILETIME (100 ns ticks since 1601-01-01 UTC) as an aware datetime."""
    return dt.datetime(1601, 1, 1, tzinfo=dt.UTC) + dt.timedelta(microseconds=ticks // 10)
