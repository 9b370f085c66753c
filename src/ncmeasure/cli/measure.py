"""The measure command: at the machine, from the program's start to the verdict, in one go."""

import contextlib
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import typer

from ncmeasure.cli._app import (
    Outcome,
    app,
    console,
    handle_errors,
    note,
    progress_bar,
    restore_signals,
    stop_on_signals,
    warn,
)
from ncmeasure.cli._fleet import measurement_info, mqtt_target, publish_added
from ncmeasure.cli._options import (
    CriticalOption,
    PublishOption,
    StoreOption,
    WarningOption,
    axis_overrides,
    given,
    limits,
    settings,
)
from ncmeasure.cli._verdicts import print_verdicts
from ncmeasure.cli.record import (
    AxisSet,
    Bitrate,
    Channel,
    Eds,
    Host,
    Interface,
    Nodes,
    PollHz,
    Port,
    RegisterMap,
    SerialPort,
    SetOption,
    SyncHz,
    Units,
    skipped_message,
)
from ncmeasure.errors import ConfigError, LinkError, NcMeasureError, OutputError, RecordingError

if TYPE_CHECKING:
    from rich.text import Text

    from ncmeasure.acquire import Progress
    from ncmeasure.measure import Recorded, WatchState
    from ncmeasure.samples import LinkClock


def link_clock() -> "LinkClock | None":
    """The link's clock: None, the wall clock. The one seam of the end-to-end tests, which
    put here the lockstep clock of the simulated drives they serve the program from."""
    return None


@dataclass
class _Job:
    """What every run of a measurement (one, or each of a series) is made with."""

    config: Any
    schedule: Any
    serial: str
    label: str | None
    operator: str | None
    store: str | None
    broker: Any
    limits: Any
    link: str | None
    overrides: dict[str, Any]
    per_axis: dict[str, dict[str, Any]]
    notes: str
    quiet: bool
    start_timeout: float | None


@dataclass
class _RunEnd:
    """How one run ended."""

    kind: Literal["stored", "interrupted", "link_lost", "no_start"]
    status: "Outcome"
    """The verdict (stored), else the outcome the command exits with."""
    rows: int = 0
    started: bool = False
    measurement: int | None = None
    windows: str = ""
    text: str = ""
    error: str = ""
    """The link's error (link_lost)."""


@app.command("measure")
@handle_errors
def measure_command(
    machine: Annotated[Path, typer.Argument(help="Machine file the programs were generated from.")],
    serial: Annotated[str, typer.Option(help="The machine's serial number, for the store.")],
    programs: Annotated[
        Path,
        typer.Option(
            help="The folder `ncmeasure generate` wrote (schedule.json, SETUP.md): its "
            "programs must be the ones the machine file generates."
        ),
    ],
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="New folder for recording/, results.json and report.html (default: "
            "PROGRAMS/measurements/SERIAL-<UTC time>); with --series the series' folder "
            "(series.log, run-001/, run-002/, ...; default PROGRAMS/measurements/"
            "SERIAL-series-<UTC time>).",
        ),
    ] = None,
    series: Annotated[
        bool,
        typer.Option(
            "--series",
            help="Unattended: after each measurement wait for the next program start (the "
            "controller or PLC starts it), a line per run in series.log; a link outage "
            "between runs is waited out. Ends with Ctrl-C or after --runs.",
        ),
    ] = False,
    runs: Annotated[
        int | None,
        typer.Option(min=1, help="With --series: end after this many stored measurements."),
    ] = None,
    store: StoreOption = None,
    label: Annotated[str | None, typer.Option(help="delivery, service, after-repair, ...")] = None,
    operator: Annotated[str | None, typer.Option(help="Who measures.")] = None,
    publish: PublishOption = None,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    link: Annotated[
        str | None, typer.Option(help="canopen, modbus, or a registered link (default: [link]).")
    ] = None,
    interface: Interface = None,
    channel: Channel = None,
    bitrate: Bitrate = None,
    node: Nodes = None,
    sync_hz: SyncHz = None,
    eds: Eds = None,
    host: Host = None,
    port: Port = None,
    unit: Units = None,
    register_map: RegisterMap = None,
    poll_hz: PollHz = None,
    serial_port: SerialPort = None,
    set_: SetOption = None,
    axis_set: AxisSet = None,
    start_timeout: Annotated[
        float | None,
        typer.Option(
            help="Give up when the program has not started after this many seconds "
            "(with --series: end the series when no further start comes)."
        ),
    ] = None,
    notes: Annotated[str, typer.Option(help="Free text stored with the recording.")] = "",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No live display.")] = False,
) -> Outcome:
    """Wait for the program's start, record it to its end, analyse, store, compare, report.

    Start the command, then cycle start on the control. The start is the marker's first
    edge where the link records a marker, else the first motion of an axis; the end: every
    axis back at its park and still after the last window.
    The recording is bounded by the schedule's duration, stretched as far as the program
    runs slower (override), plus 30 s. The measurement is stored with --serial (measured
    at the program's start) and compared with the machine's baseline in the store.
    With --series it goes on: every program start is a new measurement, until Ctrl-C.
    Exit code 0: ok; 1: a warning (a change beyond the warning limit, an axis to check);
    3: critical (beyond the critical limit, an axis at fault); 2: bad input (programs not
    the machine file's); 4: the link failed; 130: Ctrl-C (what was recorded is kept).
    A series exits with the worst verdict of its runs (none stored: 130 after Ctrl-C, 2
    when no program started within --start-timeout).

    Example: ncmeasure measure m.toml --programs programs --serial M17 --label delivery
    """
    from ncmeasure.measure import default_output, load_programs

    if runs is not None and not series:
        raise ConfigError("--runs counts the runs of a series: give --series too")
    schedule, config = load_programs(programs, machine)
    measurement_info(serial=serial, label=label, operator=operator)  # checked before waiting
    overrides = given(
        interface=interface,
        channel=channel,
        bitrate=bitrate,
        sync_hz=sync_hz,
        eds=eds,
        host=host,
        port=port,
        register_map=register_map,
        poll_hz=poll_hz,
        serial_port=serial_port,
    )
    overrides.update(settings(set_ or []))
    job = _Job(
        config=config,
        schedule=schedule,
        serial=serial,
        label=label,
        operator=operator,
        store=store,
        broker=mqtt_target(publish),
        limits=limits(warning, critical),
        link=link,
        overrides=overrides,
        per_axis=axis_overrides(
            axis_set or [], node or [], unit or [], [a.name for a in config.axes]
        ),
        notes=notes,
        quiet=quiet,
        start_timeout=start_timeout,
    )
    if series:
        folder = output or default_output(programs, f"{serial}-series")
        return _series(job, _new_folder(folder), runs)
    out = _new_folder(output or default_output(programs, serial))
    if not quiet:
        console(stderr=True).print(
            f"programs of {schedule.machine!r} (config {schedule.config_hash}), about "
            f"{schedule.duration_s:.0f} s; recording into {out / 'recording'}",
            soft_wrap=True,
        )
    stop = threading.Event()
    previous = stop_on_signals(stop)
    try:
        end = _measure_once(job, out, stop)
    finally:
        restore_signals(previous)
    if end.kind == "no_start":
        raise RecordingError(end.text)
    return end.status


def _new_folder(folder: Path) -> Path:
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise OutputError(f"{folder}: exists and is not empty; name a new folder with -o")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{folder}: cannot create the folder ({exc.strerror})") from exc
    return folder


def _measure_once(job: _Job, out: Path, stop: threading.Event) -> _RunEnd:
    """One run: wait for the start, record to the end, analyse, store, compare, report.

    Raises:
        LinkError: the link cannot be opened (nothing recorded).
        NcMeasureError: the analysis, the store or the report failed.
    """
    from ncmeasure.measure import record_program

    recording = out / "recording"

    def run(show: Any) -> "Recorded":
        return record_program(
            job.config,
            job.schedule,
            recording,
            link=job.link,
            link_settings=job.overrides,
            axis_settings=job.per_axis,
            notes=job.notes,
            stop=stop,
            on_progress=show,
            clock=link_clock(),
            start_timeout_s=job.start_timeout,
            serial=job.serial,
        )

    recorded = _live(run, job.quiet, job.schedule.duration_s)
    acquisition, watch = recorded.acquisition, recorded.watch
    rows = acquisition.rows
    if acquisition.status == "interrupted":
        text = f"stopped: {rows} samples kept in {recording}" + (
            "" if recorded.started else " (the program had not started)"
        )
        console(stderr=True).print(text, soft_wrap=True)
        return _RunEnd("interrupted", "interrupted", rows, recorded.started, text=text)
    if acquisition.status == "link_lost":
        error = acquisition.error or "the link failed"
        text = (
            f"link lost: {rows} samples kept in {recording}; {error}"
            if recorded.started or rows
            else f"the drives stopped answering while waiting for the start: {error}"
        )
        console(stderr=True).print(text, soft_wrap=True)
        return _RunEnd("link_lost", "link_lost", rows, recorded.started, text=text, error=error)
    if watch is None or watch.start_utc is None:
        text = (
            f"the program did not start within {job.start_timeout:g} s: nothing measured "
            f"({recording} holds no rows); press cycle start after starting measure"
        )
        return _RunEnd("no_start", "problems", rows, text=text)
    windows = f"{watch.windows_passed}/{watch.windows_total}"
    if watch.marker_missing:
        warn(
            "the marker channel is recorded but never rose while the axes moved: the start "
            "was the first motion and the windows come from the velocity; check how the "
            "marker output is wired to the drives' input (SETUP.md)"
        )
    if acquisition.ended_by == "schedule":
        warn(
            f"the program's end was not seen: the recording ended at its bound "
            f"({watch.bound_text}); the last windows may be missing"
        )
    elif not job.quiet:
        console(stderr=True).print(
            f"recorded {rows} samples from the program's start to its end "
            f"({watch.windows_passed} of {watch.windows_total} windows seen"
            + (f", program slower than planned × {watch.slowing:.2f}" if watch.slowing > 1 else "")
            + ")",
            soft_wrap=True,
        )
    if acquisition.gaps:
        warn(f"{acquisition.lost_samples} samples lost in {acquisition.gaps} gap(s)")
    if acquisition.skipped_cycles:
        warn(skipped_message(acquisition))
    status, measurement = _evaluate(job, out, recording, watch)
    return _RunEnd("stored", status, rows, True, measurement, windows)


def _evaluate(job: _Job, out: Path, recording: Path, watch: Any) -> tuple["Outcome", int]:
    """Analyse, store, compare, report and publish one recorded run; its verdict."""
    from ncmeasure.measure import evaluate, utc_text

    info = measurement_info(
        serial=job.serial,
        label=job.label,
        operator=job.operator,
        recording_location=str(recording.absolute()),
        measured_utc=utc_text(watch.start_utc),
    )
    bar, update = progress_bar(job.quiet)
    with bar or contextlib.nullcontext():
        evaluation = evaluate(
            recording,
            job.schedule,
            job.config,
            out,
            store=job.store,
            info=info,
            limits=job.limits,
            progress=update,
        )
    publish_added(job.broker, job.store, evaluation.added, job.quiet)
    check = evaluation.check
    if not job.quiet:
        print_verdicts(evaluation.results, check.comparison)
        state = "stored as" if evaluation.added.new else "already stored as"
        console().print(f"{state} measurement {evaluation.added.measurement_id} of {job.serial}")
        if check.baseline is None:
            console().print("the machine's first measurement: its baseline from now on")
        for finding in check.findings:
            console().print(f"  {finding}")
        console().print(f"wrote {evaluation.results_file} and {evaluation.report}")
    if evaluation.status != "ok":
        note(f"verdict: {evaluation.status}")
    return evaluation.status, int(evaluation.added.measurement_id)


def _series(job: _Job, folder: Path, runs: int | None) -> Outcome:
    """Measure run after run until Ctrl-C, ``runs`` stored runs, or no start in time.

    A link that cannot be reached (between runs, or lost while waiting) is tried again
    after :data:`~ncmeasure.measure.SERIES_RETRY_S`; a run whose link failed after its
    start keeps its recording and is logged, not analysed. An analysis, store or report
    failure of one run is logged and the series goes on.
    """
    from ncmeasure.measure import SERIES_LOG, SERIES_RETRY_S, SeriesLog

    log = SeriesLog(folder / SERIES_LOG)
    say = console(stderr=True)
    say.print(
        f"series of {job.schedule.machine!r} (config {job.schedule.config_hash}) for "
        f"{job.serial} in {folder}; the log: {log.path}. Each program start is a measurement; "
        "Ctrl-C ends the series.",
        soft_wrap=True,
    )
    stop = threading.Event()
    previous = stop_on_signals(stop)
    stored: list[Outcome] = []
    number, failures = 1, 0
    no_start: str | None = None
    try:
        while not stop.is_set() and (runs is None or len(stored) < runs):
            run_folder = folder / f"run-{number:03d}"
            if run_folder.exists():
                shutil.rmtree(run_folder)  # an attempt that recorded nothing
            run_folder.mkdir()
            try:
                end = _measure_once(job, run_folder, stop)
            except LinkError as exc:
                end = _RunEnd("link_lost", "link_lost", text=exc.message, error=exc.message)
            except NcMeasureError as exc:
                warn(f"run {number}: {exc.message}; the series goes on")
                log.line(run=number, outcome="failed", folder=run_folder.name, note=exc.message)
                number += 1
                continue
            if end.kind == "stored":
                stored.append(end.status)
                failures = 0
                log.line(
                    run=number,
                    outcome="stored",
                    verdict=end.status,
                    measurement=end.measurement or "",
                    windows=end.windows,
                    folder=run_folder.name,
                )
                say.print(
                    f"run {number}: stored as measurement {end.measurement}, {end.status}; "
                    "waiting for the next start",
                    soft_wrap=True,
                )
                number += 1
                continue
            if end.started or end.rows:  # a run cut short: its recording is kept
                log.line(run=number, outcome=end.kind, folder=run_folder.name, note=end.text)
                number += 1
            if end.kind == "interrupted":
                break
            if end.kind == "no_start":
                log.line(run=number, outcome="no start", note=end.text)
                shutil.rmtree(run_folder, ignore_errors=True)
                no_start = end.text
                break
            wait_s = SERIES_RETRY_S[min(failures, len(SERIES_RETRY_S) - 1)]
            if not end.started:
                log.line(run="", outcome="link down", note=f"{end.error}; trying again")
            say.print(f"the drives cannot be reached: trying again in {wait_s:g} s", soft_wrap=True)
            failures += 1
            if stop.wait(wait_s):
                break
    finally:
        restore_signals(previous)
        leftover = folder / f"run-{number:03d}"
        if leftover.is_dir() and not any(leftover.iterdir()):
            leftover.rmdir()
    log.line(run="", outcome="series ended", note=f"{len(stored)} run(s) stored")
    say.print(f"series ended: {len(stored)} run(s) stored; the log: {log.path}", soft_wrap=True)
    if not stored:
        if no_start is not None:  # nothing measured: the same error as a single run
            raise RecordingError(no_start)
        return "interrupted"
    from ncmeasure.formats.comparison import worst_status

    return worst_status(stored)  # type: ignore[arg-type]


def _live(run: Any, quiet: bool, schedule_s: float) -> "Recorded":
    """``run(show)`` with, unless quiet, a live line on stderr: what it waits for and how
    far the schedule is."""
    from rich.live import Live

    live: Live | None = None

    def show(progress: "Progress", state: "WatchState") -> None:
        if live is not None:
            live.update(_status(progress, state, schedule_s))

    try:
        if not quiet:
            live = Live(console=console(stderr=True), refresh_per_second=4, transient=True)
            live.start()
        return run(None if quiet else show)  # type: ignore[no-any-return]
    finally:
        if live is not None:
            live.stop()


def _status(progress: "Progress", state: "WatchState", schedule_s: float) -> "Text":
    from rich.text import Text

    line = Text(state.text)
    if state.program_time_s is not None:
        line.append(
            f"\nprogram {state.program_time_s:.0f} s of about {schedule_s * state.slowing:.0f} s"
            f" · {progress.rows} samples"
        )
    if progress.gaps:
        line.append(f" · {progress.lost_samples} samples lost in {progress.gaps} gap(s)")
    return line
