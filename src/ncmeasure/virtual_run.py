"""Generated NC programs on the virtual machine: simulated, recorded through its drives, analysed.

The one path ``ncmeasure demo`` and ``ncmeasure dryrun`` share, :func:`run_programs`:

1. the :class:`~ncmeasure.sim.machine.VirtualMachine` reads the programs with
   ncmeasure's own program reader and simulates them; the caller sees the
   whole run before it is recorded (``on_simulated``: the demo writes the
   model's friction, the dry run holds the motion against the limits);
2. simulated drives serve the run and the real link records it
   (:func:`record_run`): CiA 402 drives on a python-can virtual bus, or a
   Modbus TCP server on 127.0.0.1. Link and drives share a
   :class:`~ncmeasure.samples.SimulatedClock`: cycle ``k`` is the virtual
   machine at ``k × period``, as fast as the computer allows, so the recording
   is the same on an idle and on a loaded computer;
3. the analysis reads the recording with the schedule and the machine file
   and writes ``results.json``.

:func:`simulated_link` says which settings the link and the drives use: those
of the machine file's ``[link]`` table and its axes' ``link`` tables when they
are of the link's kind, else the demo's, with the transport (bus, address)
replaced by the simulated drives' own.
"""

from __future__ import annotations

import contextlib
import shutil
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from ncmeasure.acquire import AcquisitionResult, record
from ncmeasure.analysis.analyze import analyze
from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, LinkError, OutputError
from ncmeasure.examples import DEMO_LINKS, demo_link_tables
from ncmeasure.formats.results import Results, write_results
from ncmeasure.formats.schedule import Schedule
from ncmeasure.inputs import format_validation_error
from ncmeasure.links.canopen.objects import load_object_map
from ncmeasure.links.canopen.settings import CanOpenAxis, CanOpenSettings
from ncmeasure.links.modbus.settings import settings_from_tables
from ncmeasure.recording import RecordingWriter, read_recording
from ncmeasure.samples import SimulatedClock
from ncmeasure.sim.axis import Variation
from ncmeasure.sim.cia402 import DriveScaling, SimulatedDrives
from ncmeasure.sim.machine import BeyondLimits, MachineRun, VirtualMachine
from ncmeasure.sim.modbus_drive import ModbusDriveScaling, SimulatedUnit, running_server
from ncmeasure.sim.realism import Realism
from ncmeasure.sim.rig import rig_mechanics

__all__ = [
    "ANSWER_TIMEOUT_S",
    "Progress",
    "SimulatedLink",
    "VirtualRun",
    "prepare_folder",
    "record_directly",
    "record_run",
    "run_programs",
    "serving",
    "simulated_link",
]

Progress = Callable[[str, float | None], None]
"""``progress(stage, fraction)``: a new stage with fraction None, then its fraction done."""

ANSWER_TIMEOUT_S = 10.0
"""How long the link waits for a simulated drive's answer (SDO, Modbus request). The
drives answer on this computer's scheduler, not on a bus: with other work running an
answer can come a second late, and a real drive's 0.5 s would call a busy computer a
dead drive. In lockstep nothing else depends on the answer's time."""


def _silent(_stage: str, _fraction: float | None) -> None:
    """No progress display."""


def prepare_folder(
    directory: Path,
    *,
    marker: str,
    own: Sequence[str],
    what: str,
    command: str,
    replace: bool,
) -> bool:
    """Make ``directory`` a new or empty folder for one run of ``command``, marked as its.

    A non-empty folder without the hidden ``marker`` file is refused, so nothing of
    the user's is ever replaced. One with it holds an earlier run: with ``replace``
    its ``own`` files (the marker among them) are removed, else it is refused.

    Args:
        directory: The folder (created when missing).
        marker: Name of the marker file.
        own: Names of the files and folders the command writes there.
        what: What the folder is for, in words (``demo``, ``dry run``).
        command: The command (``demo``), written into the marker.
        replace: Replace an earlier run's files.

    Returns:
        True when an earlier run's files were replaced.

    Raises:
        OutputError: not a folder, someone else's folder, or an earlier run without
            ``replace``.
    """
    if directory.exists() and not directory.is_dir():
        raise OutputError(f"{directory}: exists and is not a directory")
    replaced = False
    if directory.is_dir() and any(directory.iterdir()):
        if not (directory / marker).is_file():
            raise OutputError(
                f"{directory}: exists and is not empty; name a new folder for the {what}"
            )
        if not replace:
            raise OutputError(
                f"{directory}: holds an earlier {what}; pass --force to replace it, "
                "or name a new folder"
            )
        for name in own:
            path = directory / name
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()
        replaced = True
    directory.mkdir(parents=True, exist_ok=True)
    (directory / marker).write_text(f"written by ncmeasure {command}\n", encoding="utf-8")
    return replaced


@dataclass(frozen=True)
class SimulatedLink:
    """The link a run of the virtual machine is recorded through, and its simulated drives.

    Build it with :func:`simulated_link`.
    """

    kind: str
    """``canopen`` or ``modbus``."""
    table: Mapping[str, Any]
    """The ``[link]`` settings (without ``type``), transport replaced."""
    axes: Mapping[str, Mapping[str, Any]]
    """Each axis' ``link`` settings, by axis name."""
    source: str
    """Where the settings come from, in words (for the console)."""

    def machine(self, config: MachineConfig) -> MachineConfig:
        """``config`` with these settings as its ``[link]`` and axes' ``link`` tables."""
        return config.model_copy(
            update={
                "link": {"type": self.kind, **self.table},
                "axes": [
                    axis.model_copy(update={"link": dict(self.axes[axis.name])})
                    for axis in config.axes
                ],
            }
        )


def simulated_link(config: MachineConfig, kind: str | None = None) -> SimulatedLink:
    """The link to record ``config``'s virtual machine through, with the settings it reads.

    Args:
        config: The machine.
        kind: ``canopen`` or ``modbus``; default: the type of the machine file's
            ``[link]`` table, else ``canopen``.

    The machine file's ``[link]`` table is used when it is of this kind (or names
    none), as ``record`` would use it; so is an axis' ``link`` table. Where the file
    has none, the demo's settings stand in (node or unit id = the axis' number,
    CANopen: 131072 increments per revolution, velocity demand read; Modbus: the
    ``generic`` map polled at 125 Hz). The transport becomes the simulated drives':
    CANopen on a python-can virtual bus of its own (no raw log, no bus options, the
    link producing SYNC and NMT), Modbus TCP on 127.0.0.1.

    Raises:
        ConfigError: a kind the simulated drives do not speak.
    """
    table = dict(config.link or {})
    file_kind = table.pop("type", None)
    chosen = kind or file_kind or "canopen"
    if chosen not in DEMO_LINKS:
        raise ConfigError(
            f"link {chosen!r}: the virtual machine's simulated drives speak "
            f"{' or '.join(DEMO_LINKS)} (choose one with --link)"
        )
    demo_table, demo_axes = demo_link_tables(chosen, len(config.axes))
    demo_table.pop("type", None)
    own = file_kind in (None, chosen)  # as record() takes the file's settings
    from_file = [own and bool(table)] + [own and bool(axis.link) for axis in config.axes]
    if not from_file[0]:
        table = demo_table
    axes = {
        axis.name: dict(axis.link) if used else demo_axes[i]
        for i, (axis, used) in enumerate(zip(config.axes, from_file[1:], strict=True))
    }
    if all(from_file):
        source = "the machine file's settings"
    elif any(from_file):
        source = "the machine file's settings, the demo's where it has none"
    else:
        source = f"the demo's settings (the machine file has none for {chosen})"
    if chosen == "canopen":
        table.update(
            interface="virtual",  # the channel: one of its own per run (record_run)
            sdo_timeout_s=ANSWER_TIMEOUT_S,
            listen_only=False,
            sync_producer=True,
            nmt_control=True,
            raw_log=None,
            bus_options={},
        )
        transport = "on a python-can virtual bus"
    else:
        table.update(mode="tcp", host="127.0.0.1", serial_port=None, timeout_s=ANSWER_TIMEOUT_S)
        transport = "over TCP on 127.0.0.1"
    return SimulatedLink(chosen, table, axes, f"{source}, {transport}")


def _canopen_settings(
    link: SimulatedLink, channel: str
) -> tuple[CanOpenSettings, list[CanOpenAxis]]:
    """The CANopen settings of ``link`` on ``channel``, validated as the link validates them.

    Raises:
        ConfigError: one ``location: message`` line per problem.
    """
    problems: list[str] = []
    settings: CanOpenSettings | None = None
    try:
        settings = CanOpenSettings.model_validate(
            {"type": "canopen", **link.table, "channel": channel}
        )
    except ValidationError as exc:
        problems += format_validation_error(exc, "link")
    axes: list[CanOpenAxis] = []
    for index, table in enumerate(link.axes.values()):
        try:
            axes.append(CanOpenAxis.model_validate(table))
        except ValidationError as exc:
            problems += format_validation_error(exc, f"axes[{index}].link")
    if problems or settings is None:
        raise ConfigError("the settings of the canopen link are not valid", problems)
    return settings, axes


@contextlib.contextmanager
def serving(
    config: MachineConfig,
    run: MachineRun,
    link: SimulatedLink,
    clock: SimulatedClock,
    *,
    port: int = 0,
    servers: list[Any] | None = None,
) -> Iterator[dict[str, Any]]:
    """Simulated drives serving ``run`` on ``clock``; yields the link settings that reach them.

    The drives move the axes the machine file describes, as the virtual machine
    does (facts the file leaves out are the test rig's): a link made from
    ``link.machine(config)`` with the yielded settings (the bus channel, the port)
    reads them with the same facts, in lockstep when it runs on ``clock``. Modbus drives
    listen on 127.0.0.1 at ``port`` (0: a free one, whatever the machine file says; a
    given port serves the same drives again after an outage). ``servers`` gets the
    Modbus server's handle (what a link wrote to the drives).

    Raises:
        ConfigError: invalid link settings.
        LinkError: the simulated drives failed to start.
    """
    mechanics = [rig_mechanics(axis.mechanics()) for axis in config.axes]
    if link.kind == "canopen":
        channel = f"ncmeasure-vm-{uuid.uuid4().hex[:8]}"  # a virtual bus of its own
        settings, axes = _canopen_settings(link, channel)
        object_map = load_object_map(settings.object_map)
        scaling = {
            i: DriveScaling(
                mechanics=(
                    rig_mechanics(mechanics[i], rated_current_a=drive.rated_current_a)
                    if drive.rated_current_a is not None
                    else mechanics[i]
                ),
                increments_per_rev=drive.increments_per_rev,
                gear_ratio=drive.gear_ratio,
                velocity_unit=drive.velocity_unit or object_map.velocity_unit,
                marker_input_bit=drive.marker_input_bit,  # the marker wired to that input
            )
            for i, drive in enumerate(axes)
        }
        eds = {i: found for i, drive in enumerate(axes) if (found := drive.eds or settings.eds)}
        with SimulatedDrives.start(
            channel,
            {i: drive.node_id for i, drive in enumerate(axes)},
            run,
            scaling=scaling,
            period_s=1.0 / settings.sync_hz,
            eds=eds or None,  # None: the built-in CiA 402 dictionary
            object_map=object_map,
            clock=clock,
            answer="on_send",
        ):
            yield {"channel": channel}
        return
    modbus, units = settings_from_tables(link.table, link.axes)
    served = [
        SimulatedUnit(
            name,
            unit.unit_id,
            unit.register_map or modbus.register_map,
            i,
            mechanics[i],
            unit.counts_per_rev or ModbusDriveScaling().counts_per_rev,
            {str(signal): scale for signal, scale in unit.scales.items()},
            unit.marker,  # the program's marker wired to that input
            unit.ready,  # the recorder's ready output, held as written
        )
        for i, (name, unit) in enumerate(units.items())
    ]
    with running_server(
        served,
        host="127.0.0.1",
        port=port,
        source=run,
        clock=clock,
    ) as server:
        if servers is not None:
            servers.append(server)
        yield {"port": server.port}


def record_run(
    config: MachineConfig,
    run: MachineRun,
    schedule: Schedule,
    out: Path,
    link: SimulatedLink,
    *,
    notes: str,
    progress: Progress = _silent,
    stage: str = "recording",
    stop: threading.Event | None = None,
) -> AcquisitionResult:
    """Serve ``run`` through simulated drives and record it with the real link, in lockstep.

    Raises:
        ConfigError: invalid link settings.
        LinkError: the link or the simulated drives failed to start.
    """
    clock = SimulatedClock()
    total = run.duration_s

    def on_progress(p: Any) -> None:
        progress(stage, min(1.0, p.link_time_s / total) if total > 0 else None)

    with serving(config, run, link, clock) as transport:
        return record(
            link.machine(config),
            out=out,
            link_settings=transport,
            duration_s=total,
            schedule=schedule,
            notes=notes,
            on_progress=on_progress,
            stop=stop,
            clock=clock,
        )


def record_directly(
    config: MachineConfig,
    run: MachineRun,
    schedule: Schedule,
    out: Path,
    *,
    period_s: float = 0.004,
    notes: str = "virtual machine, recorded without a drive link",
) -> Path:
    """Write the virtual machine's signals as a recording, without drives and link.

    What the drives would report, sampled every ``period_s``, without the link's
    quantisation and timing: the fast path for studies over many runs (detection
    limits, false alarms), where serving every run through simulated drives would
    only cost time. The demo and the dry run record through the real link
    (:func:`record_run`).

    Returns:
        The recording directory ``out``.
    """
    channels, block = run.sample(period_s)
    with RecordingWriter.create(
        out,
        channels,
        nominal_period_s=period_s,
        machine=config,
        config_hash=schedule.config_hash,
        source="virtual machine",
        notes=notes,
        faster_than_real_time=True,
    ) as writer:
        writer.append(block)
    return out


@dataclass
class VirtualRun:
    """One run of programs on the virtual machine: its recording and its analysis."""

    vm: VirtualMachine
    """The machine that ran them (its axis models, its excursions)."""
    directory: Path
    """Where recording/ and results.json are."""
    machine_time_s: float
    acquisition: AcquisitionResult | None
    """How the recording went; None when stopped before it began."""
    results: Results | None
    """The analysis; None when the recording was stopped."""
    wall_time_s: float

    @property
    def interrupted(self) -> bool:
        """True when a stop request cut the run short (no analysis then)."""
        return self.results is None

    @property
    def recording(self) -> Path:
        """The recording directory."""
        return self.directory / "recording"


def _stage(label: str, what: str) -> str:
    return f"{label}: {what}" if label else what


def run_programs(
    config: MachineConfig,
    programs: Path,
    schedule: Schedule,
    out: Path,
    *,
    link: SimulatedLink,
    notes: str,
    label: str = "",
    variations: Mapping[str, Variation] | None = None,
    seed: int = 0,
    beyond_limits: BeyondLimits = "stop",
    controllers_dirs: Sequence[Path] = (),
    progress: Progress | None = None,
    stop: threading.Event | None = None,
    on_simulated: Callable[[VirtualMachine, MachineRun], None] | None = None,
    realism: Realism | None = None,
    machine_seed: int = 0,
) -> VirtualRun:
    """Run the programs in ``programs`` on the virtual machine, record and analyse them.

    Args:
        config: The machine (the programs' machine file).
        programs: Folder of the programs and their schedule.json.
        schedule: That schedule.
        out: Folder for recording/ and results.json (created).
        link: The link to record through (:func:`simulated_link`).
        notes: Free text stored with the recording.
        label: Prefix of the progress stages (``reference: simulating the program``).
        variations: Assembly variations by axis name.
        seed: Seed of the simulated noise.
        beyond_limits: What the machine does with a block beyond a limit
            (:class:`~ncmeasure.sim.machine.VirtualMachine`).
        controllers_dirs: Folders searched first for the schedule's dialect.
        progress: ``progress(stage, fraction)`` for a progress display.
        stop: Set it to stop (Ctrl-C): what was recorded is kept, nothing is analysed.
        on_simulated: Called with the machine and its whole run before recording.
        realism: The virtual machine's fingerprint, drift and drive noise (None: an
            ideal machine).
        machine_seed: The fingerprint's seed (with ``realism``).

    Raises:
        ProgramError: a program that cannot be read, or that leaves the travel (``stop``).
        LinkError: the recording failed.
        NcMeasureError: anything else of the pipeline (settings, analysis).
    """
    started = time.monotonic()
    report = progress or _silent
    report(_stage(label, "simulating the program"), None)
    vm = VirtualMachine.from_programs(
        config,
        programs,
        controllers_dirs=controllers_dirs,
        variations=variations,
        seed=seed,
        beyond_limits=beyond_limits,
        realism=realism,
        machine_seed=machine_seed,
    )
    run = vm.run()
    machine_time_s = run.duration_s
    out.mkdir(parents=True, exist_ok=True)
    if on_simulated is not None:
        on_simulated(vm, run)
    done = VirtualRun(vm, out, machine_time_s, None, None, 0.0)
    if stop is not None and stop.is_set():
        done.wall_time_s = time.monotonic() - started
        return done
    stage = _stage(label, f"recording {machine_time_s:.0f} s of machine time through {link.kind}")
    report(stage, None)
    done.acquisition = record_run(
        config,
        run,
        schedule,
        done.recording,
        link,
        notes=notes,
        progress=report,
        stage=stage,
        stop=stop,
    )
    del run  # the analysis reads the recording; the simulated signals may be large
    status = done.acquisition.status
    if status == "interrupted":
        done.wall_time_s = time.monotonic() - started
        return done
    if status not in ("complete", "incomplete"):
        error = done.acquisition.error
        raise LinkError(
            f"{_stage(label, 'the recording')} ended {status}" + (f": {error}" if error else "")
        )
    report(_stage(label, "analysing"), None)
    done.results = analyze(
        read_recording(done.recording),
        schedule=schedule,
        machine=config,
        progress=lambda _stage_name, fraction: report(_stage(label, "analysing"), fraction),
    )
    write_results(done.results, out / "results.json")
    done.wall_time_s = time.monotonic() - started
    return done
