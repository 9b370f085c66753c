"""Several files into one recording, and a velocity derived from the position.

A drive's tool often writes one file per capture: EPOS Studio exports one
file per speed and direction. :func:`import_files` reads each file with the
importer it needs (into a temporary recording) and then writes them into one
recording, file after file, each file a *segment*:

* where every file names its start (a date in its preamble, a date-time
  column, an XML start time), a segment sits at its own start time, relative
  to the first file's;
* otherwise (or where a file would start before the previous one ends plus
  the gap), segments follow one another with a gap of :data:`GAP_S` (at least
  ten sample periods) between them, so that nothing of two files is ever
  read as one stretch of motion.

Every segment starts with an ``info`` event (``details = {"segment": file}``),
so a reader knows where a file begins; a time step at a segment's start is no
lost sample. A channel one file lacks is NaN in its segment.

When an axis has a position channel but no velocity channel, the velocity is
derived from the position (:func:`derive_velocity`, per segment) so the
recording can be analysed; the report says so.
"""

from __future__ import annotations

import datetime as dt
import glob
import logging
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from ncmeasure.errors import RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.recording import ImportSink
from ncmeasure.recording.reader import rows_of
from ncmeasure.samples import Channel, LinkEvent
from ncmeasure.traces.job import ProgressFn, TraceImport, check_target, order_channels

if TYPE_CHECKING:  # the machine-file models: exporting a recording reads no machine file
    from ncmeasure.config import MachineConfig

__all__ = [
    "GAP_S",
    "ImportOne",
    "expand_sources",
    "join_imports",
]

log = logging.getLogger(__name__)

#: The least time between two files' segments when they are placed one after another.
GAP_S: Final = 1.0
_GAP_PERIODS: Final = 10
_CHUNK_ROWS: Final = 1 << 15
_GLOB: Final = re.compile(r"[*?[]")

#: Reads one file into a new recording: ``(file, directory, measured_at, progress)``.
ImportOne = Callable[[Path, Path, "dt.datetime | None", "ProgressFn | None"], TraceImport]


def expand_sources(sources: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """The files of the arguments: a file, a folder (its files, in natural name order) or
    a glob pattern (``'captures/*.csv'``, its matches in natural name order).

    Raises:
        RecordingError: An argument names nothing, a folder holds no file or a
            pattern matches none, or a file is given twice.
    """
    files: list[Path] = []
    for source in sources:
        path = Path(source)
        text = os.fspath(source)
        if path.is_dir():
            found = [p for p in path.iterdir() if p.is_file() and not p.name.startswith(".")]
            if not found:
                raise RecordingError(f"{path}: the folder holds no file to import")
            files.extend(sorted(found, key=_natural))
        elif not path.exists() and _GLOB.search(text):
            # an absolute pattern too, which Path.glob does not take
            matches = [Path(m) for m in glob.glob(text) if Path(m).is_file()]  # noqa: PTH207
            if not matches:
                raise RecordingError(f"{text}: the pattern matches no file")
            files.extend(sorted(matches, key=_natural))
        else:
            files.append(path)  # a missing file is the importer's to report
    seen: set[Path] = set()
    for file in files:
        key = file.resolve()
        if key in seen:
            raise RecordingError(f"{file}: given twice")
        seen.add(key)
    return files


def _natural(path: Path) -> list[int | str]:
    """``v2`` before ``v10``: digits compare as numbers."""
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", path.name)]


def join_imports(
    sources: Sequence[Path],
    directory: Path,
    import_one: ImportOne,
    *,
    machine: MachineConfig | None,
    measured_at: dt.datetime | None,
    progress: ProgressFn | None = None,
) -> TraceImport:
    """Import every file and write them into one recording, segment after segment.

    One file is imported directly into ``directory``.

    Args:
        sources: The files, in order.
        directory: The new recording (must not exist or be empty).
        import_one: Reads one file into a new recording.
        machine: The machine file, for the axis data and channel order.
        measured_at: When the machine was measured (wins over the files' dates).
        progress: Called with ``(bytes_read, total_bytes)`` over all files.

    Raises:
        RecordingError: A file cannot be imported (the message names it), or the
            recording cannot be written. Nothing is left in ``directory`` then.
    """
    if not sources:
        raise RecordingError("no file to import")
    check_target(directory)
    if len(sources) == 1:
        return import_one(sources[0], directory, measured_at, progress)
    sizes = [p.stat().st_size if p.is_file() else 0 for p in sources]
    total = sum(sizes)
    directory.parent.mkdir(parents=True, exist_ok=True)
    # beside the recording, on its file system
    work = Path(tempfile.mkdtemp(prefix=f".{directory.name}-import-", dir=directory.parent))
    try:
        parts: list[tuple[Path, TraceImport]] = []
        for k, source in enumerate(sources):
            done = sum(sizes[:k])

            def step(read: int, _size: int, done: int = done) -> None:
                if progress is not None:
                    progress(done + read, total)

            # each file keeps the date its data hold; measured_at is the whole's
            parts.append((source, import_one(source, work / str(k), None, step)))
        return _join(parts, directory, machine, measured_at)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _start(meta: RecordingMeta) -> dt.datetime | None:
    return dt.datetime.fromisoformat(meta.start_utc) if meta.start_utc else None


def _join(
    parts: Sequence[tuple[Path, TraceImport]],
    directory: Path,
    machine: MachineConfig | None,
    measured_at: dt.datetime | None,
) -> TraceImport:
    """Write the parts' rows into one recording, segment after segment."""
    starts = [_start(part.meta) for _, part in parts]
    own_times = all(s is not None for s in starts)
    if own_times:  # in the order they were measured (a stable sort: equal starts keep theirs)
        order = sorted(range(len(parts)), key=lambda k: starts[k] or dt.datetime.min)
        parts, starts = [parts[k] for k in order], [starts[k] for k in order]
    per_part = [[m.to_channel() for m in part.meta.channels] for _, part in parts]
    union: list[Channel] = list(dict.fromkeys(c for cs in per_part for c in cs))
    channels = order_channels(union, machine)
    column = {c.name: i for i, c in enumerate(channels)}
    periods = [part.meta.nominal_period_s for _, part in parts]
    gap_s = max(GAP_S, _GAP_PERIODS * max(periods))
    first_start = starts[0] if own_times else None
    report: list[str] = []
    report.append(
        f"{len(parts)} files, one segment each, "
        + (
            "each at its own start time (from the files' dates), in the order measured"
            if own_times
            else f"one after another with {gap_s:g} s between them (not every file "
            "holds its start time)"
        )
    )
    sink = ImportSink(
        directory,
        channels,
        machine=machine,
        nominal_period_s=None,
        what="the files",
        source=parts[0][1].meta.source,
        notes="imported from " + ", ".join(p.name for p, _ in parts),
        link={},
        start_utc=measured_at or first_start,
    )
    link: dict[str, Any] = {
        "type": "import",
        "format": parts[0][1].meta.link.get("format"),
        "files": [p.name for p, _ in parts],
    }
    implausible: dict[str, int] = {}
    for _, part in parts:
        for name, count in part.meta.link.get("implausible", {}).items():
            implausible[name] = implausible.get(name, 0) + int(count)
    if implausible:
        link["implausible"] = implausible
    try:
        end_s = -np.inf
        segments = []
        for k, ((source, part), own) in enumerate(zip(parts, per_part, strict=True)):
            where = [column[c.name] for c in own]
            placed: float | None = None
            shift_s = 0.0
            rows = 0
            first_s = last_s = np.nan
            _, chunks = rows_of(part.directory, _CHUNK_ROWS)
            for chunk in chunks:
                time_s, values = chunk.time_s, chunk.values
                if not len(time_s):
                    continue
                if placed is None:
                    placed, note = _place(k, starts, first_start, own_times, end_s, gap_s)
                    if note:
                        report.append(f"{source.name}: {note}")
                    shift_s = placed - float(time_s[0])
                    first_s = float(time_s[0] + shift_s)  # as written, to the bit
                block = np.full((len(time_s), len(channels)), np.nan)
                block[:, where] = values
                sink.append(time_s + shift_s, block)
                rows += len(time_s)
                last_s = float(time_s[-1] + shift_s)
            if placed is None:
                raise RecordingError(f"{source}: holds no sample")
            end_s = last_s
            segments.append((source, first_s, last_s, rows, part.meta.nominal_period_s))
        writer = sink.ensure_writer()
        for source, first_s, last_s, rows, period_s in segments:
            writer.add_event(
                LinkEvent(
                    first_s,
                    "info",
                    f"segment: {source.name}",
                    details={"segment": source.name, "end_s": last_s},
                )
            )
            report.append(
                f"{source.name}: {rows} samples at {period_s * 1e3:.4g} ms, "
                f"t = {first_s:.6g} … {last_s:.6g} s"
            )
        if len(set(periods)) > 1:
            report.append(
                f"the files differ in sample period ({min(periods) * 1e3:.4g}–"
                f"{max(periods) * 1e3:.4g} ms); the recording's is the median time step"
            )
        for source, part in parts:
            report.extend(f"{source.name}: {line}" for line in part.report)
        report.extend(sink.validity_lines())
        link["report"] = report
        meta = sink.close("complete", link=link)
    except BaseException:
        sink.discard()
        raise
    return TraceImport(directory, meta, report)


def _place(
    k: int,
    starts: Sequence[dt.datetime | None],
    first_start: dt.datetime | None,
    own_times: bool,
    end_s: float,
    gap_s: float,
) -> tuple[float, str]:
    """Where segment ``k`` begins, and a note when it cannot sit at its own time."""
    if k == 0:
        return 0.0, ""
    after = end_s + gap_s
    if not own_times:
        return after, ""
    start = starts[k]
    assert start is not None and first_start is not None
    own = (start - first_start).total_seconds()
    if own < after:
        return after, (
            f"its start ({start.isoformat()}) is not {gap_s:g} s after the end of the file "
            f"before: placed {gap_s:g} s after it"
        )
    return own, ""
