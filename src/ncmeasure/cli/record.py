"""The recording commands: record from the drives, simulate-drive to try it without a machine."""

import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ncmeasure.cli._app import (
    Outcome,
    app,
    console,
    handle_errors,
    note,
    restore_signals,
    stop_on_signals,
    warn,
)
from ncmeasure.cli._options import axis_overrides, given, pairs, settings
from ncmeasure.errors import ConfigError

if TYPE_CHECKING:
    from rich.table import Table

    from ncmeasure.acquire import AcquisitionResult, Progress

# The link options of `record`, each over the machine file's [link] table.
Interface = Annotated[
    str | None,
    typer.Option(
        help="CANopen: python-can interface (virtual, socketcan, pcan, slcan, ...).",
        rich_help_panel="CANopen",
    ),
]
Channel = Annotated[
    str | None, typer.Option(help="CANopen: python-can channel.", rich_help_panel="CANopen")
]
Bitrate = Annotated[
    int | None, typer.Option(help="CANopen: bit rate in bit/s.", rich_help_panel="CANopen")
]
Nodes = Annotated[
    list[str] | None,
    typer.Option(
        help="CANopen: AXIS=NODE_ID, repeat per axis.",
        rich_help_panel="CANopen",
        metavar="AXIS=NODE_ID",
    ),
]
SyncHz = Annotated[
    float | None, typer.Option(help="CANopen: SYNC rate in Hz.", rich_help_panel="CANopen")
]
Eds = Annotated[
    Path | None,
    typer.Option(help="CANopen: the drives' EDS/DCF file.", rich_help_panel="CANopen"),
]
Host = Annotated[str | None, typer.Option(help="Modbus TCP: host.", rich_help_panel="Modbus")]
Port = Annotated[int | None, typer.Option(help="Modbus TCP: port.", rich_help_panel="Modbus")]
Units = Annotated[
    list[str] | None,
    typer.Option(
        help="Modbus: AXIS=UNIT_ID, repeat per axis.",
        rich_help_panel="Modbus",
        metavar="AXIS=UNIT_ID",
    ),
]
RegisterMap = Annotated[
    str | None,
    typer.Option(
        help="Modbus: register map (built-in name or TOML file).", rich_help_panel="Modbus"
    ),
]
PollHz = Annotated[
    float | None, typer.Option(help="Modbus: polls per second.", rich_help_panel="Modbus")
]
SerialPort = Annotated[
    str | None, typer.Option(help="Modbus RTU: serial port.", rich_help_panel="Modbus")
]
Source = Annotated[
    Path | None,
    typer.Option(help="Replay: the recording to play back.", rich_help_panel="Replay"),
]
Speed = Annotated[
    float | None,
    typer.Option(
        help="Replay: 1 = recorded speed, 0 = as fast as possible.", rich_help_panel="Replay"
    ),
]
SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="Any other link setting, KEY=VALUE.", metavar="KEY=VALUE"),
]
AxisSet = Annotated[
    list[str] | None,
    typer.Option(
        "--axis-set",
        help="A per-axis link setting (what an axis' link table holds): KEY=VALUE for "
        "every axis, AXIS.KEY=VALUE for one, e.g. --axis-set increments_per_rev=10000 "
        "--axis-set Z.gear_ratio=2. Over the machine file's; --node and --unit go last.",
        metavar="[AXIS.]KEY=VALUE",
    ),
]


_STATUS_OUTCOME: dict[str, Outcome] = {"interrupted": "interrupted", "link_lost": "link_lost"}
"""The outcome of a recording's status: the others (complete, incomplete) are ok."""


@app.command("record")
@handle_errors
def record_command(
    machine: Annotated[
        Path,
        typer.Argument(
            help="Machine file; its [link] table and the axes' link settings are the defaults."
        ),
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="New recording directory.")],
    link: Annotated[
        str | None,
        typer.Option(help="canopen, modbus, replay, or a registered link (default: [link] type)."),
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
    source: Source = None,
    speed: Speed = None,
    set_: SetOption = None,
    axis_set: AxisSet = None,
    duration: Annotated[
        float | None, typer.Option(help="Seconds to record (positive, finite).")
    ] = None,
    schedule: Annotated[
        Path | None,
        typer.Option(
            help="schedule.json of the program: without --duration, stop after its estimated "
            "end plus a margin (a guide); --duration is a limit and wins."
        ),
    ] = None,
    raw_log: Annotated[
        Path | None, typer.Option(help="CANopen: also log every frame (.blf/.asc).")
    ] = None,
    notes: Annotated[str, typer.Option(help="Free text stored with the recording.")] = "",
    serial: Annotated[
        str | None,
        typer.Option(
            help="The serial number of the machine measured (the machine file names its "
            "type): kept in meta.json and carried into the results and the store."
        ),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No live display.")] = False,
) -> Outcome:
    """Record motor current, velocity and position from the drives into a recording.

    Stops after --duration (a limit), else at the end of --schedule plus a margin (a
    guide), at the end of a replay, or on Ctrl-C/SIGTERM, and says which ended it; every
    way of stopping closes the recording with what was received.
    Exit code 0: complete; 2: bad input; 4: the link failed; 130: stopped by Ctrl-C/SIGTERM.

    A file from `ncmeasure init` names no drives: --node (CANopen) or --unit (Modbus)
    gives each axis its drive, --axis-set the rest of its link table.

    Example: ncmeasure record m.toml --link canopen --interface socketcan --channel can0
    --node X=1 --node Y=2 --node Z=3 --axis-set increments_per_rev=10000 --sync-hz 250
    --duration 60 -o run1
    """
    from ncmeasure.acquire import record
    from ncmeasure.config import load_machine
    from ncmeasure.formats.schedule import load_schedule

    config = load_machine(machine)
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
        source=source,
        speed=speed,
        raw_log=raw_log,
    )
    overrides.update(settings(set_ or []))
    axes = [a.name for a in config.axes]
    per_axis = axis_overrides(axis_set or [], node or [], unit or [], axes)
    plan_schedule = load_schedule(schedule) if schedule else None

    def run(
        stop: threading.Event, on_progress: "Callable[[Progress], None] | None"
    ) -> "AcquisitionResult":
        return record(
            config,
            out=output,
            link=link,
            link_settings=overrides,
            axis_settings=per_axis,
            duration_s=duration,
            schedule=plan_schedule,
            notes=notes,
            stop=stop,
            on_progress=on_progress,
            serial=serial,
        )

    result = _record_live(run, quiet)
    _print_recorded(result, quiet)
    return _STATUS_OUTCOME.get(result.status, "ok")  # complete, or incomplete with a warning


def _record_live(
    run: "Callable[[threading.Event, Callable[[Progress], None] | None], AcquisitionResult]",
    quiet: bool,
) -> "AcquisitionResult":
    """``run(stop, on_progress)`` with Ctrl-C/SIGTERM setting ``stop`` and, unless quiet,
    a live table of the latest values on stderr."""
    from rich.live import Live

    stop = threading.Event()
    previous = stop_on_signals(stop)
    live: Live | None = None

    def show(progress: "Progress") -> None:
        if live is not None:
            live.update(_progress_table(progress))

    try:
        if not quiet:
            live = Live(console=console(stderr=True), refresh_per_second=4, transient=True)
            live.start()
        result = run(stop, None if quiet else show)
    finally:
        if live is not None:
            live.stop()  # before any message, so the display does not overwrite it
        restore_signals(previous)
    return result


def _progress_table(progress: "Progress") -> "Table":
    from rich.table import Table

    table = Table(
        title=f"recording · {progress.elapsed_s:.0f} s · {progress.rows} samples · "
        f"{progress.rows_per_s:.0f} samples/s",
        box=None,
        header_style="bold",
    )
    table.add_column("axis")
    table.add_column("current A", justify="right")
    table.add_column("velocity mm/min", justify="right")
    table.add_column("position mm", justify="right")
    axes = list(dict.fromkeys(name.split("_", 1)[0] for name in progress.latest))
    for axis in axes:
        values = [
            progress.latest.get(f"{axis}_{s}")
            for s in ("current_a", "velocity_mm_min", "position_mm")
        ]
        table.add_row(axis, *("—" if v is None else f"{v:.3f}" for v in values))
    table.caption = (
        f"gaps {progress.gaps} ({progress.lost_samples} samples lost"
        + (f", {progress.skipped_cycles} cycles skipped" if progress.skipped_cycles else "")
        + f") · faults {progress.faults}"
        + (f" · last: {progress.last_event}" if progress.last_event else "")
    )
    return table


def _print_recorded(result: "AcquisitionResult", quiet: bool) -> None:
    """What was recorded, and what was lost, on stderr."""
    if result.moved_aside is not None:
        note(
            f"the unfinished earlier attempt in {result.directory} was moved to "
            f"{result.moved_aside}, whole"
        )
    if not quiet or result.status != "complete":
        console(stderr=True).print(
            f"{result.status}: {result.rows} samples over {result.link_time_s:.1f} s in "
            f"{result.directory}" + (f"; {result.error}" if result.error else ""),
            soft_wrap=True,
        )
    ended = ended_message(result)
    if ended and (not quiet or result.ended_by == "schedule"):
        console(stderr=True).print(ended, soft_wrap=True)
    if (
        result.ended_by == "duration"
        and result.duration_s is not None
        and result.schedule_end_s is not None
        and result.duration_s < result.schedule_end_s
    ):
        warn(
            f"--duration {result.duration_s:g} s ended the recording before the schedule's "
            f"end ({result.schedule_end_s:g} s with its margin): the last windows may be "
            "missing"
        )
    if result.gaps:
        warn(
            f"{result.lost_samples} samples lost in {result.gaps} gap(s), "
            f"{100 * result.lost_share:.2g} % of the recording; the gap events in "
            f"{result.directory} say when and why, and the analysis reports them"
        )
    skipped = skipped_message(result)
    if skipped:
        warn(skipped)


def skipped_message(result: "AcquisitionResult") -> str:
    """The cycles the link skipped as a share of the recording and the rate it reached
    ("" when none were skipped): never hidden among the lost samples."""
    if not result.skipped_cycles:
        return ""
    text = (
        f"{result.skipped_cycles} cycles skipped by the link (the host fell behind): "
        f"{100 * result.skipped_share:.2g} % of the recording"
    )
    achieved = result.achieved_rate_hz
    if achieved is not None and result.nominal_period_s:
        text += f", {achieved:.0f} Hz instead of {1 / result.nominal_period_s:.0f} Hz"
    return text


def ended_message(result: "AcquisitionResult") -> str:
    """Which limit ended the recording, when a duration or a schedule was given."""
    schedule = (
        f"the schedule's end with its margin ({result.schedule_end_s:g} s)"
        if result.schedule_end_s is not None
        else ""
    )
    if result.ended_by == "duration" and result.duration_s is not None:
        beside = f"; {schedule} is only a guide" if schedule else ""
        return f"ended by --duration {result.duration_s:g} s{beside}"
    if result.ended_by == "schedule":
        return (
            f"ended at {schedule}: a program slowed by the override or a feed hold runs "
            "longer; give --duration to record longer"
        )
    return ""


DEFAULT_DRIVES = {"X": 1, "Y": 2, "Z": 3}
"""The simulated drives without --node/--unit: axis -> node or unit id."""


@app.command("simulate-drive")
@handle_errors
def simulate_drive_command(
    link: Annotated[str, typer.Option(help="canopen or modbus.")],
    interface: Annotated[
        str | None,
        typer.Option(
            help="CANopen: python-can interface. The default, virtual, reaches only this "
            "process; for `record` in another terminal use socketcan (with a vcan device) "
            "or udp_multicast with a multicast group as channel, e.g. 239.74.163.2 (needs "
            "the udp-multicast extra: msgpack).",
            rich_help_panel="CANopen",
        ),
    ] = "virtual",
    channel: Annotated[
        str | None, typer.Option(help="CANopen: python-can channel.", rich_help_panel="CANopen")
    ] = "ncmeasure",
    node: Annotated[
        list[str] | None,
        typer.Option(
            help="CANopen: AXIS=NODE_ID per simulated drive (default X=1 Y=2 Z=3).",
            metavar="AXIS=NODE_ID",
            rich_help_panel="CANopen",
        ),
    ] = None,
    eds: Annotated[
        Path | None,
        typer.Option(
            help="CANopen: build the drives' object dictionary from this EDS/DCF.",
            rich_help_panel="CANopen",
        ),
    ] = None,
    host: Annotated[
        str, typer.Option(help="Modbus TCP: address to listen on.", rich_help_panel="Modbus")
    ] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Modbus TCP: port.", rich_help_panel="Modbus")] = 5020,
    unit: Annotated[
        list[str] | None,
        typer.Option(
            help="Modbus: AXIS=UNIT_ID per simulated drive (default X=1 Y=2 Z=3).",
            metavar="AXIS=UNIT_ID",
            rich_help_panel="Modbus",
        ),
    ] = None,
    register_map: Annotated[
        str, typer.Option(help="Modbus: register map served.", rich_help_panel="Modbus")
    ] = "generic",
    serial_port: Annotated[
        str | None,
        typer.Option(
            help="Modbus RTU: serve on this serial port instead of TCP.", rich_help_panel="Modbus"
        ),
    ] = None,
    baudrate: Annotated[
        int, typer.Option(help="Modbus RTU: baud rate.", rich_help_panel="Modbus")
    ] = 19200,
    parity: Annotated[
        str,
        typer.Option(help="Modbus RTU: parity N, E or O.", rich_help_panel="Modbus"),
    ] = "E",
    duration: Annotated[
        float | None, typer.Option(help="Seconds to run (default: until Ctrl-C).")
    ] = None,
) -> None:
    """Run simulated servo drives, for trying `ncmeasure record` without a machine.

    The drives report a smooth test motion of every axis. Example, in two terminals:
    `ncmeasure simulate-drive --link modbus --port 5020` and
    `ncmeasure record m.toml --link modbus --host 127.0.0.1 --port 5020 --unit X=1 ...`.
    Exit code 0: stopped; 2: bad input (an interface python-can does not know); 4: the
    drives cannot serve there (port in use, a CAN interface that cannot be opened).
    """
    stop = threading.Event()
    previous = stop_on_signals(stop)
    if duration is not None:
        threading.Timer(duration, stop.set).start()
    try:
        if link == "modbus":
            units = {a: v["unit_id"] for a, v in pairs(unit or [], "--unit", "unit_id").items()}
            _serve_modbus(
                stop,
                units=units or DEFAULT_DRIVES,
                host=host,
                port=port,
                register_map=register_map,
                serial_port=serial_port,
                baudrate=baudrate,
                parity=parity,
            )
        elif link == "canopen":
            nodes = {a: v["node_id"] for a, v in pairs(node or [], "--node", "node_id").items()}
            ids = list((nodes or DEFAULT_DRIVES).values())
            _serve_canopen(stop, nodes=ids, interface=interface, channel=channel, eds=eds)
        else:
            raise ConfigError(f"--link {link!r}: simulated drives exist for canopen and modbus")
    finally:
        stop.set()
        restore_signals(previous)


def _serve_modbus(
    stop: threading.Event,
    *,
    units: dict[str, int],
    host: str,
    port: int,
    register_map: str,
    serial_port: str | None,
    baudrate: int,
    parity: str,
) -> None:
    """Serve simulated Modbus drives until ``stop``."""
    from ncmeasure.links.modbus.settings import settings_from_tables
    from ncmeasure.sim.modbus_drive import ServerInfo, serve

    def ready(info: ServerInfo) -> None:
        units_text = ", ".join(f"{a}={u}" for a, u in info.units.items())
        console(stderr=True).print(
            f"simulated Modbus drives on {info.endpoint}, units {units_text}; Ctrl-C stops",
            soft_wrap=True,
        )

    settings, axes = settings_from_tables(
        {
            "host": host,
            "port": port or 502,  # 0: a free port (free_port)
            "register_map": register_map,
            "serial_port": serial_port,
            "baudrate": baudrate,
            "parity": parity,
        },
        {axis: {"unit_id": unit_id} for axis, unit_id in units.items()},
    )
    serve(settings, axes, free_port=port == 0, ready=ready, stop=stop)


def _serve_canopen(
    stop: threading.Event,
    *,
    nodes: list[int],
    interface: str | None,
    channel: str | None,
    eds: Path | None,
) -> None:
    """Serve simulated CiA 402 drives until ``stop``."""
    from ncmeasure.links.canopen.settings import CanOpenSettings
    from ncmeasure.sim.cia402 import VIRTUAL_BUS_REACH
    from ncmeasure.sim.cia402 import serve as serve_canopen

    def canopen_ready(_: object) -> None:
        console(stderr=True).print(
            f"simulated CiA 402 drives, nodes {nodes}, on {interface}:{channel}; Ctrl-C stops",
            soft_wrap=True,
        )
        if interface == "virtual":
            note(VIRTUAL_BUS_REACH)

    serve_canopen(
        CanOpenSettings(type="canopen", channel=channel, interface=interface, eds=eds),
        nodes,
        stop=stop,
        on_ready=canopen_ready,
    )
