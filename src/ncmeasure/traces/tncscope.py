"""Heidenhain TNCscope text export (``.sco``): curves with their own cycle time.

The layout, as verified against a public MATLAB reader of TNCscope files
(function ``read_tncscope_file``: ``%[GLOBAL]`` and ``%[CURVE n]`` blocks that end at a
line holding only ``%``, the keys ``%CHANNELTYPE``, ``%AXISTYPE``,
``%DIMENSION`` (unit), ``%COUNT`` (samples) and ``%CYCLETIME`` (microseconds),
then ``%[DATA]`` with ``;``-terminated rows: a time column and one column per
curve, curve ``i`` holding its first ``COUNT`` values; the time of sample ``k``
is ``k x CYCLETIME``)::

    %[GLOBAL]
    %...
    %
    %[CURVE 1]
    %CHANNELTYPE=v act.
    %AXISTYPE=X
    %DIMENSION=mm/min
    %COUNT=4096
    %CYCLETIME=3000
    %
    %[DATA]
    0;1250.0;3.25;
    3000;1250.5;3.31;

Channel types verified in public sources (the HEIDENHAIN technical manuals of
the TNC 426/430 and iTNC 530, integrated oscilloscope; a public conversion of
TNCscope exports with "s actual", "v act.", "i ist"; the MATLAB reader above):
"s actual", "Actual pos" [mm]; "v act.", "Actl. speed" (from the position
encoder) and "V (act rpm)" (from the speed encoder) [mm/min]; "Noml. speed",
"V (nom rpm)" [mm/min]; "i ist", "I nominal" (the torque-determining current)
[A]; "M actual" [Nm]; "DSP-Debug" ``id(10)`` (torque-generating current [A]).
Other spellings of the same signals (``s act.``, ``v nom.``, ``I actual``, ...)
are accepted as well; they were not found in a source. The unit comes from
``%DIMENSION``.

Curves with different cycle times are merged on the union of their sample
times, each holding its last value. The time column of ``%[DATA]`` must
increase; its unit is not documented, so the times come from ``COUNT`` and
``CYCLETIME`` as in the reader above.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import math
import re
from array import array
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.samples import SIGNAL_UNITS
from ncmeasure.traces import merge as merging
from ncmeasure.traces.axes import Candidate, Needs, plan_sources
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.merge import SeriesMerge
from ncmeasure.traces.text import (
    TextLines,
    block_decimal_mark,
    decimal_mark,
    number_rows,
    parse_number,
    unit_factor,
)

__all__ = ["import_tncscope"]

log = logging.getLogger(__name__)

_CURVE = re.compile(r"^%\[CURVE\s*(?P<number>\d*)\s*\]$", re.IGNORECASE)
_KEY = re.compile(r"^%(?P<key>[A-Za-z_][A-Za-z0-9_ ]*?)\s*=\s*(?P<value>.*)$")

#: normalized CHANNELTYPE -> (signal, unit when DIMENSION is missing, rank, needs)
_CHANNEL_TYPES: Final[dict[str, tuple[str, str, int, Needs]]] = {
    "s actual": ("position_mm", "mm", 0, ""),
    "s act.": ("position_mm", "mm", 0, ""),
    "actual pos": ("position_mm", "mm", 0, ""),
    "actual pos.": ("position_mm", "mm", 0, ""),
    "s ist": ("position_mm", "mm", 0, ""),
    "v act.": ("velocity_mm_min", "mm/min", 0, ""),
    "v actual": ("velocity_mm_min", "mm/min", 0, ""),
    "actl. speed": ("velocity_mm_min", "mm/min", 0, ""),
    "v ist": ("velocity_mm_min", "mm/min", 0, ""),
    "v (act rpm)": ("velocity_mm_min", "mm/min", 1, ""),
    "v nom.": ("velocity_cmd_mm_min", "mm/min", 0, ""),
    "v nominal": ("velocity_cmd_mm_min", "mm/min", 0, ""),
    "noml. speed": ("velocity_cmd_mm_min", "mm/min", 0, ""),
    "v soll": ("velocity_cmd_mm_min", "mm/min", 0, ""),
    "v (nom rpm)": ("velocity_cmd_mm_min", "mm/min", 1, ""),
    "i actual": ("current_a", "A", 0, ""),
    "i act.": ("current_a", "A", 0, ""),
    "i ist": ("current_a", "A", 0, ""),
    "i nominal": ("current_a", "A", 1, ""),
    "i nom.": ("current_a", "A", 1, ""),
    "i soll": ("current_a", "A", 1, ""),
    "m actual": ("current_a", "Nm", 5, "torque_constant"),
}
_DSP_DEBUG_CURRENT: Final = "id(10)"
#: Lines read and parsed at a time (a block of plain rows is parsed as a whole).
_BLOCK_LINES: Final = 20_000


@dataclass
class _Curve:
    number: str
    line: int
    keys: dict[str, str] = field(default_factory=dict)

    @property
    def label(self) -> str:
        kind = self.keys.get("CHANNELTYPE", "?")
        axis = self.keys.get("AXISTYPE", "")
        return f"curve {self.number} ({kind}{' ' + axis if axis else ''})"


_DOTTED_DATE: Final = re.compile(r"(\d{1,2})\.(\d{1,2})\.(\d{4})")
_CLOCK: Final = re.compile(r"(\d{1,2}):(\d{2})(?::(\d{2}))?")


def _start(global_keys: dict[str, str]) -> tuple[dt.datetime | None, str]:
    """The measurement's start of the ``%[GLOBAL]`` block: ``%DATE=06.05.2024`` (day first,
    as the TNC writes dates) or ISO 8601, with ``%TIME=14:22:10`` or the time after the
    date where given. No zone: UTC (the report says so); a date alone is its midnight."""
    text = global_keys.get("DATE", "").strip()
    if not text:
        return None, ""
    with contextlib.suppress(ValueError):
        if "T" in text or (":" in text and "-" in text):
            return dt.datetime.fromisoformat(text), "%DATE"
    date_text, _, rest = text.partition(" ")
    clock_text = global_keys.get("TIME", "").strip() or rest.strip()
    day = _DOTTED_DATE.fullmatch(date_text)
    clock = _CLOCK.fullmatch(clock_text)
    try:
        date = (
            dt.date(int(day[3]), int(day[2]), int(day[1]))
            if day is not None
            else dt.date.fromisoformat(date_text)
        )
        time = dt.time(int(clock[1]), int(clock[2]), int(clock[3] or 0)) if clock else None
    except ValueError:
        return None, ""
    if time is None:
        return dt.datetime.combine(date, dt.time()), "%DATE, a date alone: its midnight"
    return dt.datetime.combine(date, time), "%DATE and %TIME"


def _normalize(text: str) -> str:
    return " ".join(text.lower().split())


def _read_header(lines: TextLines, job: ImportJob) -> tuple[list[_Curve], dict[str, str]]:
    curves: list[_Curve] = []
    global_keys: dict[str, str] = {}
    block: dict[str, str] | None = None
    for line in lines:
        text = line.strip()
        if text.upper() == "%[DATA]":
            return curves, global_keys
        if not text:
            continue
        if text == "%":
            block = None
            continue
        if text.upper() == "%[GLOBAL]":
            block = global_keys
            continue
        match = _CURVE.match(text)
        if match:
            curve = _Curve(match["number"] or str(len(curves) + 1), lines.line_number)
            curves.append(curve)
            block = curve.keys
            continue
        if not text.startswith("%"):
            raise RecordingError(
                f"{lines.where()}: {text[:40]!r} before %[DATA]: not a TNCscope header line"
            )
        key = _KEY.match(text)
        if key and block is not None:
            block[key["key"].strip().upper()] = key["value"].strip()
    if lines.line_number == 0:
        raise RecordingError(f"{job.path}: the file is empty")
    raise RecordingError(f"{job.path}: no %[DATA] line: not a TNCscope export, or cut short")


def _timing(curve: _Curve, job: ImportJob) -> tuple[int, float]:
    try:
        count = int(curve.keys["COUNT"])
        cycle_us = float(curve.keys["CYCLETIME"].replace(",", "."))
    except KeyError as exc:
        raise RecordingError(
            f"{job.path}:{curve.line}: {curve.label} has no %{exc.args[0]}= line"
        ) from exc
    except ValueError as exc:
        raise RecordingError(
            f"{job.path}:{curve.line}: {curve.label}: COUNT or CYCLETIME is not a number"
        ) from exc
    if count < 1 or not (math.isfinite(cycle_us) and cycle_us > 0):
        raise RecordingError(
            f"{job.path}:{curve.line}: {curve.label}: COUNT {count} and CYCLETIME "
            f"{cycle_us:g} us must be positive"
        )
    return count, cycle_us


def _candidate(curve: _Curve, job: ImportJob) -> Candidate | None:
    kind = curve.keys.get("CHANNELTYPE", "")
    dimension = curve.keys.get("DIMENSION", "")
    axis = curve.keys.get("AXISTYPE", "").strip()
    if _normalize(kind) == "dsp-debug" and dimension.strip().lower() == _DSP_DEBUG_CURRENT:
        signal, default_unit, rank = "current_a", "A", 2
        needs: Needs = ""
        dimension = "A"
    elif _normalize(kind) in _CHANNEL_TYPES:
        signal, default_unit, rank, needs = _CHANNEL_TYPES[_normalize(kind)]
    else:
        job.note(f"{curve.label}: not imported (no ncmeasure signal for channel type {kind!r})")
        return None
    if not axis:
        job.note(f"{curve.label}: not imported (no %AXISTYPE: the axis is unknown)")
        return None
    unit = dimension or default_unit
    if needs == "torque_constant":
        if unit.strip().lower() != "nm":
            job.note(f"{curve.label}: not imported (torque in {unit!r}, expected Nm)")
            return None
        return Candidate(curve.label, axis, signal, 1.0, needs, rank, "")
    factor = unit_factor(signal, unit)
    if factor is None:
        job.note(
            f"{curve.label}: not imported (DIMENSION {unit!r} cannot be converted to "
            f"{SIGNAL_UNITS[signal]})"
        )
        return None
    target = SIGNAL_UNITS[signal]
    if not dimension:
        conversion = f"no DIMENSION, {default_unit} assumed"
    elif factor == 1:
        conversion = "no unit conversion"
    else:
        conversion = f"{unit} x {factor:g} = {target}"
    return Candidate(curve.label, axis, signal, factor, "", rank, conversion)


def import_tncscope(job: ImportJob) -> RecordingMeta:
    """Import a TNCscope text export (see the module docstring).

    Raises:
        RecordingError: ``file:line: problem`` for a header without
            ``%[DATA]``, a curve without COUNT or CYCLETIME, a cell that is not
            a number, a time column that does not increase, data cut short of
            a curve's COUNT, or no curve that can be imported.
    """
    with TextLines(job.path, job) as lines:
        return _read(job, lines)


def _read(job: ImportJob, lines: TextLines) -> RecordingMeta:
    curves, global_keys = _read_header(lines, job)
    if not curves:
        raise RecordingError(f"{job.path}: no %[CURVE n] block before %[DATA]")
    if global_keys:
        job.link["global"] = global_keys
    timing = [_timing(curve, job) for curve in curves]
    candidates = [_candidate(curve, job) for curve in curves]
    used = plan_sources(range(len(curves)), candidates, job)
    longest = max(count for count, _ in timing)
    period = min(timing[index][1] for index, _ in used) * 1e-6
    start, where = _start(global_keys)
    sink = job.open_sink(
        [m.channel for _, m in used], nominal_period_s=period, start_utc=start, start_source=where
    )
    merge = SeriesMerge(
        sink,
        [m.channel.name for _, m in used],
        [m.factor for _, m in used],
        batch_rows=merging.MERGE_ROWS,
        spill_rows=merging.SPILL_ROWS,
    )
    samples = _CurveSamples(merge, [timing[index][1] for index, _ in used])
    values = samples.values  # the list stays, its arrays are replaced by each hand-over

    chunk_rows = merging.CHUNK_ROWS
    decimal: str | None = None
    last_time = -math.inf
    rows = 0
    try:
        while block := lines.take(_BLOCK_LINES):
            first_line = lines.line_number - len(block) + 1
            mark = decimal if decimal is not None else block_decimal_mark(block, ";")
            data = _plain_block(block, mark, 1 + len(curves), last_time)
            if data is not None:
                decimal = mark
                for k, (index, _) in enumerate(used):
                    take = max(0, min(len(data), timing[index][0] - rows))
                    values[k].frombytes(np.ascontiguousarray(data[:take, 1 + index]).tobytes())
                rows += len(data)
                last_time = float(data[-1, 0])
                samples.hand_over()
                continue
            for offset, line in enumerate(block):
                if not line.strip():
                    continue
                where = f"{job.path}:{first_line + offset}"
                cells = line.strip().split(";")
                if cells and not cells[-1].strip():
                    cells.pop()  # rows end with ';'
                if len(cells) < 1 + len(curves):
                    shown = line.strip()[:40]
                    raise RecordingError(
                        f"{where}: {len(cells)} cells, expected a time and {len(curves)} "
                        f"curve(s): {shown!r}"
                    )
                if decimal is None:
                    decimal = decimal_mark(cells)
                try:
                    time_value = parse_number(cells[0], decimal or ".")
                except ValueError as exc:
                    raise RecordingError(f"{where}: time {cells[0].strip()!r}: {exc}") from exc
                if not time_value > last_time:
                    raise RecordingError(
                        f"{where}: time {cells[0].strip()} is not later than the row before; "
                        "times must increase"
                    )
                last_time = time_value
                for k, (index, _) in enumerate(used):
                    if rows >= timing[index][0]:
                        continue
                    cell = cells[1 + index]
                    try:
                        values[k].append(parse_number(cell, decimal or "."))
                    except ValueError as exc:
                        raise RecordingError(
                            f"{where}: {curves[index].label}: {cell.strip()!r} is not a number "
                            f"({exc})"
                        ) from exc
                rows += 1
                if rows % chunk_rows == 0:
                    samples.hand_over()
        if rows < longest:
            short = [c.label for c, (count, _) in zip(curves, timing, strict=True) if count > rows]
            raise RecordingError(
                f"{job.path}: %[DATA] has {rows} rows, but {', '.join(short)} declare(s) more "
                f"(COUNT up to {longest}); the file is cut short"
            )
        samples.hand_over()
    except BaseException:
        merge.close()  # on success, finish() closes it after the last rows
        raise
    if rows > longest:
        job.note(f"{rows - longest} row(s) after the longest curve ignored")
    if decimal == ",":
        job.note("numbers use a decimal comma")
    job.note("time of sample k of a curve = k x CYCLETIME of that curve")
    merge.finish(job)
    return job.finish()


_DECIMAL_COMMA: Final = bytes.maketrans(b";,", b",.")
_DECIMAL_POINT: Final = bytes.maketrans(b";", b",")


def _plain_block(
    block: list[str], decimal: str | None, width: int, last_time: float
) -> NDArray[np.float64] | None:
    """The rows of a block of plain rows, read at once (:func:`number_rows`); None: not plain.

    Plain: ``;``-ended rows of exactly a time and one number per curve in the
    notation of the file, nothing else (no spaces, no blank lines), times increasing.
    Anything else is read row by row, which says what is wrong where.
    """
    text = "\n".join(block)
    if decimal == ",":
        if "." in text:
            return None
        table = _DECIMAL_COMMA
    elif "," in text:
        return None
    else:
        table = _DECIMAL_POINT
    # the ";" that ends every row goes, the others separate cells
    cells = text.encode().replace(b";\n", b"\n").translate(table)
    if cells.endswith(b","):
        cells = cells[:-1]
    data = number_rows(cells, width)
    if data is None or not (np.diff(data[:, 0], prepend=last_time) > 0).all():
        return None
    return data


class _CurveSamples:
    """The values parsed of each imported curve since the last hand-over to the merge."""

    def __init__(self, merge: SeriesMerge, cycles_us: list[float]) -> None:
        self._merge = merge
        self._cycles_us = cycles_us
        self.values: list[array[float]] = [array("d") for _ in cycles_us]
        self._handed = [0] * len(cycles_us)  # samples of each curve given to the merge

    def hand_over(self) -> None:
        """The values parsed so far go to the merge, at k x CYCLETIME of their curve."""
        values, handed, merge = self.values, self._handed, self._merge
        for k, cycle_us in enumerate(self._cycles_us):
            if not values[k]:
                continue
            stop = handed[k] + len(values[k])
            # whole microseconds first, so that curves at multiple cycle times meet exactly
            time_s = np.arange(handed[k], stop, dtype=np.float64) * cycle_us / 1e6
            merge.add(k, time_s, np.frombuffer(values[k]))
            handed[k] = stop
            values[k] = array("d")
        merge.flush()
