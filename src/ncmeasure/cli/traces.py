"""The exchange commands: import a trace or an exported file, export a recording."""

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated

import typer

from ncmeasure.cli._app import app, console, handle_errors
from ncmeasure.errors import ConfigError

_FORMATS = {"csv": ".csv", "mdf4": ".mf4"}


@app.command("export")
@handle_errors
def export_command(
    run: Annotated[Path, typer.Argument(help="Recording directory.")],
    fmt: Annotated[str, typer.Option("--format", "-f", help="csv or mdf4.")] = "csv",
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Output file (default: next to RUN).")
    ] = None,
) -> None:
    """Write a recording as one CSV (time_s, then <AXIS>_<signal> columns) or MDF4 file."""
    from ncmeasure.recording import RecordingHead
    from ncmeasure.traces.csv import export_csv
    from ncmeasure.traces.mdf4 import export_mdf4

    if fmt not in _FORMATS:
        raise ConfigError(f"--format {fmt!r}: expected one of {', '.join(_FORMATS)}")
    target = output or run.with_suffix(_FORMATS[fmt])
    head = RecordingHead.open(run)  # the samples are read chunk by chunk while written
    if fmt == "csv":
        export_csv(head, target)
    else:
        export_mdf4(head, target)
    # what was wrong with the recording is logged as a warning when read, as for analyze
    console().print(f"wrote {target} ({head.rows} samples)")


@app.command("import")
@handle_errors
def import_command(
    files: Annotated[
        list[str],
        typer.Argument(
            help="Trace or exported file(s) to import: files, folders (their files) or glob "
            "patterns ('captures/*.csv'); several become one recording, file after file.",
            metavar="FILE...",
        ),
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="New recording directory.")],
    fmt: Annotated[
        str | None,
        typer.Option(
            "--format",
            "-f",
            help="sinumerik-xml, sinumerik-csv, twincat-csv, tncscope, csv, mdf4, can-log "
            "(default: detected from the content; CAN logs by their ending .blf, .asc, "
            ".log, .trc).",
        ),
    ] = None,
    machine: Annotated[
        Path | None,
        typer.Option(
            help="Machine file: axis names, screw lead and torque constant for unit conversion."
        ),
    ] = None,
    axis: Annotated[
        list[str] | None,
        typer.Option(
            help="Map a trace's axis to a machine axis, e.g. --axis 1=X --axis 2=Y.",
            metavar="TRACE_AXIS=AXIS",
        ),
    ] = None,
    columns: Annotated[
        Path | None,
        typer.Option(
            "--columns",
            help="Column map (TOML): read FILE as any CSV (or MATLAB .mat, Parquet) whose "
            "columns (variables) it names (channel = column by header text or 1-based position, "
            "scale, offset; period_s or a time column). "
            "Not with --format or --axis.",
        ),
    ] = None,
    measured: Annotated[
        str | None,
        typer.Option(
            "--measured-at",
            metavar="ISO8601",
            help="When the machine was measured, e.g. 2024-03-05T14:22:10+01:00; a time "
            "without a zone is taken as UTC. Default: the date in the data (an XML start "
            "time, a Date: line before the header, a date-time column); without one the "
            "time is unknown (never the import's), and `store add` asks for it.",
            show_default=False,
        ),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress, no report.")] = False,
) -> None:
    """Turn controller traces or exported CSV/MDF4 files into a recording.

    Reads SINUMERIK trace XML and CSV, TwinCAT Scope CSV, TNCscope text and the
    CSV of `ncmeasure export`, any CSV or MATLAB .mat file through a column map
    (--columns), and CAN logs of a CANopen bus (.blf, .asc, .log, .trc: decoded with
    the machine file's [link] settings, as the CANopen link reads the live bus);
    reports what was mapped, converted and left out. Several files (one per speed
    and direction, as EPOS Studio exports them) become one recording, each file a
    segment. A position without a velocity channel gives a derived velocity.
    Examples: ncmeasure import trace.xml --machine machine.toml --axis 1=X -o run1
    ·  ncmeasure import capture.blf --machine machine.toml -o run2
    ·  ncmeasure import captures/ --columns epos.toml -o run3
    """
    from ncmeasure.config import load_machine, parse_assignments
    from ncmeasure.formats.identity import parse_utc
    from ncmeasure.traces import import_traces
    from ncmeasure.traces.files import expand_sources

    measured_at = parse_utc(measured, "--measured-at") if measured is not None else None

    axis_names = dict(
        parse_assignments(axis or [], "--axis", form="TRACE_AXIS=MACHINE_AXIS", example="1=X")
    )
    config = load_machine(machine) if machine else None
    sources = expand_sources(files)
    with _import_progress(
        sources[0].name if len(sources) == 1 else f"{len(sources)} files", quiet
    ) as progress:
        result = import_traces(
            sources,
            output,
            format=fmt,
            machine=config,
            axis_names=axis_names or None,
            progress=progress,
            columns=columns,
            measured_at=measured_at,
        )
    # the counts from meta.json: reading a large recording back would cost its size in memory
    report, samples = result.report, result.meta.samples or 0
    channels = len(result.meta.channels)
    if not quiet:
        for line in report:
            console(stderr=True).print(f"  {line}")
    console().print(f"wrote {output} ({samples} samples, {channels} channels)")


@contextlib.contextmanager
def _import_progress(name: str, quiet: bool) -> Iterator[Callable[[int, int], None]]:
    """A transient progress bar of the bytes read, on stderr, unless quiet; yields the
    ``progress(done, total)`` callback an importer takes."""
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn

    bar = (
        None
        if quiet
        else Progress(
            TextColumn("importing {task.description}", markup=False),
            BarColumn(),
            DownloadColumn(),
            console=console(stderr=True),
            transient=True,
        )
    )
    task = bar.add_task(name, total=None) if bar else None

    def progress(done: int, total: int) -> None:
        if bar is not None and task is not None:
            bar.update(task, completed=done, total=total)

    if bar is not None:
        bar.start()
    try:
        yield progress
    finally:
        if bar is not None:
            bar.stop()
