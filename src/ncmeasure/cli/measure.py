"""The measure command: at the machine, from the program's start to the verdict, in one go."""

import contextlib
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

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
)
from ncmeasure.errors import OutputError, RecordingError

if TYPE_CHECKING:
    from rich.text import Text

    from ncmeasure.acquire import Progress
    from ncmeasure.measure import Recorded, WatchState
    from ncmeasure.samples import LinkClock


def link_clock() -> "LinkClock | None":
    """The link's clock: None, the wall clock. The one seam of the end-to-end tests, which
    put here the lockstep clock of the simulated drives they serve the program from."""
    return None


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
            "PROGRAMS/measurements/SERIAL-<UTC time>).",
        ),
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
        typer.Option(help="Give up when the program has not started after this many seconds."),
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
    Exit code 0: ok; 1: a warning (a change beyond the warning limit, an axis to check);
    3: critical (beyond the critical limit, an axis at fault); 2: bad input (programs not
    the machine file's); 4: the link failed; 130: Ctrl-C (what was recorded is kept).

    Example: ncmeasure measure m.toml --programs programs --serial M17 --label delivery
    """
    from ncmeasure.measure import default_output, evaluate, load_programs, record_program

    schedule, config = load_programs(programs, machine)
    measurement_info(serial=serial, label=label, operator=operator)  # checked before waiting
    broker = mqtt_target(publish)
    chosen = limits(warning, critical)
    out = output or default_output(programs, serial)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise OutputError(f"{out}: exists and is not empty; name a new folder with -o")
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
    per_axis = axis_overrides(axis_set or [], node or [], unit or [], [a.name for a in config.axes])
    recording = out / "recording"
    out.mkdir(parents=True, exist_ok=True)
    if not quiet:
        console(stderr=True).print(
            f"programs of {schedule.machine!r} (config {schedule.config_hash}), about "
            f"{schedule.duration_s:.0f} s; recording into {recording}",
            soft_wrap=True,
        )

    def run(stop: threading.Event, show: Any) -> "Recorded":
        return record_program(
            config,
            schedule,
            recording,
            link=link,
            link_settings=overrides,
            axis_settings=per_axis,
            notes=notes,
            stop=stop,
            on_progress=show,
            clock=link_clock(),
            start_timeout_s=start_timeout,
        )

    recorded = _live(run, quiet, schedule.duration_s)
    acquisition, watch = recorded.acquisition, recorded.watch
    if acquisition.status == "interrupted":
        console(stderr=True).print(
            f"stopped: {acquisition.rows} samples kept in {recording}"
            + ("" if recorded.started else " (the program had not started)"),
            soft_wrap=True,
        )
        return "interrupted"
    if acquisition.status == "link_lost":
        console(stderr=True).print(
            f"link lost: {acquisition.rows} samples kept in {recording}; {acquisition.error}",
            soft_wrap=True,
        )
        return "link_lost"
    if watch is None or watch.start_utc is None:
        raise RecordingError(
            f"the program did not start within {start_timeout:g} s: nothing measured "
            f"({recording} holds no rows); press cycle start after starting measure"
        )
    if acquisition.ended_by == "schedule":
        warn(
            f"the program's end was not seen: the recording ended at its bound "
            f"({watch.bound_text}); the last windows may be missing"
        )
    elif not quiet:
        console(stderr=True).print(
            f"recorded {acquisition.rows} samples from the program's start to its end "
            f"({watch.windows_passed} of {watch.windows_total} windows seen"
            + (f", program slower than planned × {watch.slowing:.2f}" if watch.slowing > 1 else "")
            + ")",
            soft_wrap=True,
        )
    if acquisition.gaps:
        warn(f"{acquisition.lost_samples} samples lost in {acquisition.gaps} gap(s)")
    from ncmeasure.measure import utc_text

    info = measurement_info(
        serial=serial,
        label=label,
        operator=operator,
        recording_location=str(recording.absolute()),
        measured_utc=utc_text(watch.start_utc),
    )
    bar, update = progress_bar(quiet)
    with bar or contextlib.nullcontext():
        evaluation = evaluate(
            recording, schedule, config, out, store=store, info=info, limits=chosen, progress=update
        )
    publish_added(broker, store, evaluation.added, quiet)
    check = evaluation.check
    if not quiet:
        print_verdicts(evaluation.results, check.comparison)
        state = "stored as" if evaluation.added.new else "already stored as"
        console().print(f"{state} measurement {evaluation.added.measurement_id} of {serial}")
        if check.baseline is None:
            console().print("the machine's first measurement: its baseline from now on")
        for finding in check.findings:
            console().print(f"  {finding}")
        console().print(f"wrote {evaluation.results_file} and {evaluation.report}")
    if evaluation.status != "ok":
        note(f"verdict: {evaluation.status}")
    return evaluation.status


def _live(run: Any, quiet: bool, schedule_s: float) -> "Recorded":
    """``run(stop, show)`` with Ctrl-C/SIGTERM setting ``stop`` and, unless quiet, a live
    line on stderr: what it waits for and how far the schedule is."""
    from rich.live import Live

    stop = threading.Event()
    previous = stop_on_signals(stop)
    live: Live | None = None

    def show(progress: "Progress", state: "WatchState") -> None:
        if live is not None:
            live.update(_status(progress, state, schedule_s))

    try:
        if not quiet:
            live = Live(console=console(stderr=True), refresh_per_second=4, transient=True)
            live.start()
        return run(stop, None if quiet else show)  # type: ignore[no-any-return]
    finally:
        if live is not None:
            live.stop()
        restore_signals(previous)


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
