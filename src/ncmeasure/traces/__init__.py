"""Controller trace importers: a controller's own trace export becomes an ncmeasure recording.

Where no drive link can be used, the controller's oscilloscope records the
measurement program instead; these importers turn its export into a
recording that the analysis reads like any other::

    from ncmeasure.traces import import_trace

    result = import_trace("X_friction.xml", "runs/x-trace", machine=config,
                          axis_names={"1": "X"})
    result.recording.axis_signal("X", "current_a")
    for line in result.report:
        print(line)

Formats (:data:`FORMATS`):

``sinumerik-xml``  Sinumerik Operate / SinuCom trace XML (streamed)   :mod:`.sinumerik_xml`
``sinumerik-csv``  its CSV export                                       :mod:`.sinumerik_csv`
``twincat-csv``    TwinCAT Scope CSV export                             :mod:`.twincat_csv`
``tncscope``       Heidenhain TNCscope text export (``.sco``)           :mod:`.tncscope`
``csv``            the layout of ``ncmeasure export`` (``traces.csv.import_csv``)
``can-log``        a CAN log of a CANopen bus (``.blf``, ``.asc``, ``.log``, ``.trc``),
                   decoded with the machine file's CANopen link settings   :mod:`.canlog`

Any other delimited text file (a data collector's CSV, a PLC log, an EPOS
Studio export), a MATLAB ``.mat`` file or a Parquet file imports through a
column map that names the column (or variable) of each channel:
:func:`import_columns` (or ``import_trace(..., columns="map.toml")``),
:mod:`.columns`, :mod:`.matlab`, :mod:`.parquet`.

Several files become one recording, each a segment (:func:`import_traces`,
:mod:`.files`); an axis with a position and no velocity channel gets a
velocity derived from the position (:mod:`.derive`).

Each importer maps the controller's axes (an index or a name) to axis names
(``axis_names``, else the machine file's axes, else a default name), converts
units into ncmeasure's (A, mm/min, mm), and reports every decision in
:attr:`TraceImport.report`. Bad input raises a
:class:`~ncmeasure.errors.RecordingError` that names ``file:line`` (or the
element) and the problem; a failed import leaves nothing in the target
directory. The formats and what was verified about them: ``docs/traces.md``.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Final

from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.formats.recording import RecordingMeta
from ncmeasure.traces.canlog import import_can_log, is_can_log
from ncmeasure.traces.columns import ColumnMap, import_columns, load_column_map
from ncmeasure.traces.csv import import_csv_meta
from ncmeasure.traces.files import ImportOne, expand_sources, join_imports
from ncmeasure.traces.job import (
    ImportJob,
    ProgressFn,
    TraceImport,
    check_source,
    check_target,
    run_import,
)
from ncmeasure.traces.matlab import is_matlab
from ncmeasure.traces.sinumerik_csv import import_sinumerik_csv
from ncmeasure.traces.sinumerik_xml import import_sinumerik_xml
from ncmeasure.traces.tncscope import import_tncscope
from ncmeasure.traces.twincat_csv import import_twincat_csv

if TYPE_CHECKING:  # the machine-file models: exporting a recording reads no machine file
    from ncmeasure.config import MachineConfig

__all__ = [
    "FORMATS",
    "ColumnMap",
    "TraceImport",
    "detect_format",
    "import_columns",
    "import_trace",
    "import_traces",
    "load_column_map",
]

log = logging.getLogger(__name__)

#: The trace formats :func:`import_trace` reads.
FORMATS: Final = ("sinumerik-xml", "sinumerik-csv", "twincat-csv", "tncscope", "csv", "can-log")

_IMPORTERS: Final[Mapping[str, Callable[[ImportJob], RecordingMeta]]] = {
    "sinumerik-xml": import_sinumerik_xml,
    "sinumerik-csv": import_sinumerik_csv,
    "twincat-csv": import_twincat_csv,
    "tncscope": import_tncscope,
    "can-log": import_can_log,
}
_SNIFF_BYTES: Final = 1 << 16


def detect_format(path: str | os.PathLike[str]) -> str:
    """The format of a trace file, from its content (not its name).

    Returns:
        One of :data:`FORMATS`.

    Raises:
        RecordingError: The file cannot be read, or its content matches no format.
    """
    source = Path(path)
    if is_can_log(source) and source.is_file():
        return "can-log"  # binary (BLF) or a tool's text: python-can's readers tell by the ending
    try:
        with source.open("rb") as file:
            head = file.read(_SNIFF_BYTES)
    except FileNotFoundError as exc:
        raise RecordingError(f"{source}: no such file") from exc
    except IsADirectoryError as exc:
        raise RecordingError(f"{source}: is a directory, expected a trace file") from exc
    except OSError as exc:
        raise RecordingError(f"{source}: cannot be read ({exc.strerror or exc})") from exc
    if not head.strip():
        raise RecordingError(f"{source}: the file is empty")
    if is_matlab(source):
        raise RecordingError(
            f"{source}: a MATLAB file: name its variables in a column map "
            '(--columns MAP.toml, column = "data.time"; docs/traces.md)'
        )
    if b"\x00" in head:
        raise RecordingError(
            f"{source}: a binary file, not a trace export (formats: {', '.join(FORMATS)})"
        )
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    stripped = text.lstrip()
    if stripped.startswith("<"):
        if "<traceSession" in text:
            return "sinumerik-xml"
        raise RecordingError(
            f"{source}: an XML file without a <traceSession> element: not a Sinumerik trace"
        )
    lines = text.splitlines()
    first = lines[0] if lines else ""
    if any(line.strip().upper() in ("%[GLOBAL]", "%[DATA]") for line in lines) or any(
        line.strip().upper().startswith("%[CURVE") for line in lines
    ):
        return "tncscope"
    if (
        first.startswith("Name")
        and len(first) > 4
        and ("Starttime of export" in text or "SampleTime" in text)
    ):
        return "twincat-csv"
    if first.split(",")[0].strip() == "time_s":
        return "csv"
    if ("/Nck/" in text or "/Channel/" in text) and "[u" in text:
        return "sinumerik-csv"
    raise RecordingError(
        f"{source}: the trace format is not recognised; formats: {', '.join(FORMATS)} "
        "(pass the format explicitly if the file is one of them)"
    )


def import_trace(
    path: str | os.PathLike[str],
    directory: str | os.PathLike[str],
    *,
    format: str | None = None,
    machine: MachineConfig | None = None,
    axis_names: Mapping[str, str] | None = None,
    progress: ProgressFn | None = None,
    columns: ColumnMap | str | os.PathLike[str] | None = None,
    measured_at: dt.datetime | None = None,
) -> TraceImport:
    """Make a recording from a controller trace export.

    Args:
        path: The trace file.
        directory: The new recording (must not exist or be empty).
        format: One of :data:`FORMATS`; detected from the content when None.
        machine: The machine file: its axes name the controller's axes in
            order (when ``axis_names`` is not given), its screw leads and
            torque constants convert motor speed and torque, and its axis
            data go into ``meta.json``.
        axis_names: Controller axis (index as a string, e.g. ``"1"``, or
            name) to axis name, e.g. ``{"1": "X", "2": "Y"}``. Controller axes
            left out are not imported.
        progress: Called now and then with ``(bytes_read, total_bytes)``.
        columns: A column map (or the path of its TOML file): read ``path`` as
            delimited text whose columns the map names (:func:`import_columns`);
            ``format`` and ``axis_names`` do not apply then.
        measured_at: When the machine was measured (aware; it wins over a date in
            the data). Without it the recording's ``start_utc`` is the data's date
            (an XML start time, a preamble's ``Date: 2024-03-05 14:22:10``, a
            date-time column), else null: unknown, never the time of the import.

    An axis with a position and no velocity channel gets its velocity derived from
    the position (:func:`~ncmeasure.traces.files.derive_velocity`); the report says so.

    Returns:
        The recording (source ``import:<format>``, ``import:columns`` with a
        column map) and the report.

    Raises:
        RecordingError: The file cannot be read or is not valid in its format
            (the message names ``file:line`` or the element), no signal can be
            imported, or the recording cannot be written. Nothing is left in
            ``directory`` then.
        ConfigError: ``format`` is unknown, ``axis_names`` does not fit, the
            column map is not valid, or ``columns`` comes with ``format`` or
            ``axis_names``.
    """
    return join_imports(
        [Path(path)],
        Path(directory),
        _importer(format, machine, axis_names, columns, progress),
        machine=machine,
        measured_at=measured_at,
    )


def _importer(
    format: str | None,
    machine: MachineConfig | None,
    axis_names: Mapping[str, str] | None,
    columns: ColumnMap | str | os.PathLike[str] | None,
    progress: ProgressFn | None = None,
) -> ImportOne:
    """Reads one file into a new recording with these settings (:func:`_import_file`;
    ``format="mdf4"`` or an ``.mf4`` name: :func:`~ncmeasure.traces.mdf4.import_mdf4`)."""

    def import_one(
        source: Path, target: Path, when: dt.datetime | None, step: ProgressFn | None
    ) -> TraceImport:
        if columns is None and (
            format == "mdf4" or (format is None and source.suffix.lower() in (".mf4", ".mdf"))
        ):
            from ncmeasure.traces.mdf4 import import_mdf4

            check_source(source)
            rec = import_mdf4(source, target, machine=machine, measured_at=when)
            return TraceImport(target, rec.meta, list(rec.meta.link.get("report", [])))
        return _import_file(
            source,
            target,
            format=format,
            machine=machine,
            axis_names=axis_names,
            progress=progress or step,
            columns=columns,
            measured_at=when,
        )

    return import_one


def _import_file(
    path: Path,
    directory: Path,
    *,
    format: str | None,
    machine: MachineConfig | None,
    axis_names: Mapping[str, str] | None,
    progress: ProgressFn | None,
    columns: ColumnMap | str | os.PathLike[str] | None,
    measured_at: dt.datetime | None,
) -> TraceImport:
    """One file into a new recording, as its format's importer reads it."""
    source = Path(path)
    target = Path(directory)
    if columns is not None:
        if format is not None:
            raise ConfigError(
                f"a column map and format {format!r} exclude each other: the column map says "
                "how to read the file (leave the format out)"
            )
        if axis_names:
            raise ConfigError(
                "axis_names does not apply with a column map: its channel names "
                "(X_current_a, ...) already name the axes"
            )
        return import_columns(
            source, target, columns, machine=machine, progress=progress, measured_at=measured_at
        )
    if format == "columns":
        raise ConfigError("the columns format needs a column map (columns=MAP.toml, --columns)")
    if format is not None and format not in FORMATS:
        raise ConfigError(f"unknown trace format {format!r}; one of {', '.join(FORMATS)}")
    check_source(source)
    name = format if format is not None else detect_format(source)
    if name == "csv":
        return _import_recording_csv(source, target, machine, axis_names, progress, measured_at)
    if name == "can-log" and axis_names:
        raise ConfigError(
            "axis_names does not apply to a CAN log: the machine file's node ids name the axes"
        )
    check_target(target)
    job = ImportJob(
        source,
        target,
        name,
        machine=machine,
        axis_names=axis_names,
        progress=progress,
        measured_at=measured_at,
    )
    return run_import(job, _IMPORTERS[name])


def import_traces(
    sources: Sequence[str | os.PathLike[str]],
    directory: str | os.PathLike[str],
    *,
    format: str | None = None,
    machine: MachineConfig | None = None,
    axis_names: Mapping[str, str] | None = None,
    progress: ProgressFn | None = None,
    columns: ColumnMap | str | os.PathLike[str] | None = None,
    measured_at: dt.datetime | None = None,
) -> TraceImport:
    """Make one recording from several files: each file a segment, file after file.

    ``sources`` are files, folders (their files in natural name order: ``v2``
    before ``v10``) or glob patterns (``"captures/*.csv"``). Each file is read
    as :func:`import_trace` reads it (``format="mdf4"`` or an ``.mf4`` name:
    :func:`~ncmeasure.traces.mdf4.import_mdf4`); a segment sits at the file's
    own start time where every file names one, else one after another with a
    gap (:mod:`.files`). An axis with a position and no velocity channel gets
    its velocity derived from the position, also for a single file. The
    report lists each file.

    Raises:
        RecordingError: An argument names no file, or a file cannot be imported
            (the message names it). Nothing is left in ``directory`` then.
        ConfigError: As for :func:`import_trace`.
    """
    files = expand_sources(sources)
    return join_imports(
        files,
        Path(directory),
        _importer(format, machine, axis_names, columns),
        machine=machine,
        measured_at=measured_at,
        progress=progress,
    )


def _import_recording_csv(
    source: Path,
    target: Path,
    machine: MachineConfig | None,
    axis_names: Mapping[str, str] | None,
    progress: ProgressFn | None,
    measured_at: dt.datetime | None,
) -> TraceImport:
    """The generic CSV of ``ncmeasure export``: columns already name axes and signals."""
    if axis_names:
        raise ConfigError(
            "axis_names does not apply to the csv format: its columns already name the axes "
            "(rename the columns instead)"
        )
    total = source.stat().st_size
    meta = import_csv_meta(source, target, machine=machine, start_utc=measured_at)
    if progress is not None:
        progress(total, total)
    report = [
        f"{c.name} [{c.unit}]: from column {c.name} (ncmeasure CSV, no conversion)"
        for c in (m.to_channel() for m in meta.channels)
    ]
    report.extend(meta.link.get("report", []))
    report.append(
        "the file holds no date: the measurement's time is unknown (give it with "
        "--measured-at; the fleet store needs it)"
        if measured_at is None
        else f"measured at {meta.start_utc} (--measured-at)"
    )
    return TraceImport(target, meta, report)
