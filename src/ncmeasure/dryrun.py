"""``ncmeasure dryrun``: a user's generated programs on the virtual machine, before the real one.

:func:`run_dryrun` takes a folder written by ``ncmeasure generate`` and the
machine file the programs were generated from (schedule.json holds neither the
axes' acceleration and jerk nor the link, and its ``config_hash`` must be the
file's), then runs the programs the way ``ncmeasure demo`` runs its own
(:func:`~ncmeasure.virtual_run.run_programs`): the virtual machine with the
file's axes (travel, limits, mechanics, drive data) executes them, simulated
drives serve the motion, the link of the file's kind records it, the analysis
cuts the windows of schedule.json and the report shows them.

Unlike the demo, the virtual machine follows the programs wherever they go
(``beyond_limits="follow"``): a block beyond an axis' travel or a feed above its
maximum is driven, and :class:`~ncmeasure.formats.dryrun.DryRun` says how far
each axis went against the machine file's soft limits, maximum velocity and
maximum acceleration. The commanded motion is judged, as a controller judges
it; the actual one (the servo loop overshoots every ramp a little) is kept
beside it for the record.

The folder it writes (``PROGRAMS/dryrun`` unless told otherwise)::

    dryrun.json       per axis: its limits, how far it went, what it exceeded
    recording/        the recording through the simulated drives
    results.json      the friction results
    report.html       the report (plots in report_plots/)

A hidden ``.ncmeasure-dryrun`` marks the folder; a later dry run replaces what
an earlier one wrote there, and a folder without the mark is refused.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ncmeasure.config import MachineConfig
from ncmeasure.formats.dryrun import (
    DRYRUN_FILE,
    AxisLimits,
    AxisReach,
    DryRun,
    Excess,
    Reach,
    write_dryrun,
)
from ncmeasure.formats.schedule import Schedule
from ncmeasure.program.check import programs_of
from ncmeasure.recording import read_recording
from ncmeasure.sim.machine import AxisExtremes, MachineRun, VirtualMachine
from ncmeasure.virtual_run import (
    Progress,
    SimulatedLink,
    VirtualRun,
    prepare_folder,
    run_programs,
    simulated_link,
)

__all__ = ["DRYRUN_FOLDER", "DryRunResult", "judge_reach", "run_dryrun"]

DRYRUN_FOLDER = "dryrun"
"""The dry run's folder inside the programs' folder, unless told otherwise."""
_MARKER_FILE = ".ncmeasure-dryrun"
_OWN = (DRYRUN_FILE, "recording", "results.json", "report.html", "report_plots", _MARKER_FILE)

_POSITION_TOLERANCE_MM = 1e-6
"""A setpoint this close to a soft limit is at it (the virtual machine's own tolerance)."""
_RELATIVE_TOLERANCE = 1e-9
"""A velocity or acceleration this close to its maximum is at it (rounding of the
interpolation, which never commands more than the maximum)."""
_LISTED_EXCURSIONS = 50
"""Blocks beyond a limit listed in dryrun.json (the rest are counted)."""


@dataclass
class DryRunResult:
    """What :func:`run_dryrun` did and wrote."""

    directory: Path
    """The dry run's folder."""
    programs: Path
    machine_file: Path
    schedule: Schedule
    link: SimulatedLink
    reach: DryRun
    """dryrun.json: how far every axis went, against the machine file's limits."""
    run: VirtualRun
    replaced: bool
    """An earlier dry run's files in ``directory`` were replaced."""
    report: Path | None = None
    stopped: bool = False
    """A stop request came (during the recording, or after it: then no report)."""

    @property
    def interrupted(self) -> bool:
        """True when a stop request cut the run short (what was done is kept)."""
        return self.stopped or self.run.interrupted

    @property
    def reach_file(self) -> Path:
        """dryrun.json."""
        return self.directory / DRYRUN_FILE


def _reach(extremes: AxisExtremes) -> Reach:
    return Reach(
        min_position_mm=extremes.min_position_mm,
        max_position_mm=extremes.max_position_mm,
        max_velocity_mm_min=extremes.velocity_mm_min,
        max_acceleration_m_s2=extremes.acceleration_m_s2,
    )


def judge_reach(config: MachineConfig, run: MachineRun) -> list[AxisReach]:
    """Every axis' reach in ``run`` against ``config``'s limits, the commanded motion judged."""
    commanded, actual = run.extremes(commanded=True), run.extremes()
    found: list[AxisReach] = []
    for axis in config.axes:
        reached = commanded[axis.name]
        low, high = axis.travel_mm
        top, most = axis.max_velocity_mm_min, axis.max_acceleration_m_s2
        name = f"axis {axis.name}"
        exceeded: list[Excess] = []
        if reached.min_position_mm < low - _POSITION_TOLERANCE_MM:
            exceeded.append(
                Excess(
                    limit="travel_min",
                    limit_value=low,
                    reached=reached.min_position_mm,
                    message=f"{name}: down to {reached.min_position_mm:g} mm, "
                    f"{low - reached.min_position_mm:g} mm below its soft limit {low:g} mm",
                )
            )
        if reached.max_position_mm > high + _POSITION_TOLERANCE_MM:
            exceeded.append(
                Excess(
                    limit="travel_max",
                    limit_value=high,
                    reached=reached.max_position_mm,
                    message=f"{name}: up to {reached.max_position_mm:g} mm, "
                    f"{reached.max_position_mm - high:g} mm beyond its soft limit {high:g} mm",
                )
            )
        if reached.velocity_mm_min > top * (1 + _RELATIVE_TOLERANCE):
            exceeded.append(
                Excess(
                    limit="max_velocity_mm_min",
                    limit_value=top,
                    reached=reached.velocity_mm_min,
                    message=f"{name}: {reached.velocity_mm_min:g} mm/min, above its "
                    f"max_velocity_mm_min {top:g}",
                )
            )
        if reached.acceleration_m_s2 > most * (1 + _RELATIVE_TOLERANCE):
            exceeded.append(
                Excess(
                    limit="max_acceleration_m_s2",
                    limit_value=most,
                    reached=reached.acceleration_m_s2,
                    message=f"{name}: {reached.acceleration_m_s2:.3g} m/s², above its "
                    f"max_acceleration_m_s2 {most:g}",
                )
            )
        found.append(
            AxisReach(
                name=axis.name,
                limits=AxisLimits(
                    travel_mm=(low, high), max_velocity_mm_min=top, max_acceleration_m_s2=most
                ),
                commanded=_reach(reached),
                actual=_reach(actual[axis.name]),
                exceeded=exceeded,
            )
        )
    return found


def run_dryrun(
    programs: str | Path,
    machine_file: str | Path,
    *,
    output: str | Path | None = None,
    link: str | None = None,
    seed: int = 0,
    report: bool = True,
    controllers_dirs: Sequence[Path] = (),
    progress: Progress | None = None,
    stop: threading.Event | None = None,
) -> DryRunResult:
    """Run the generated programs in ``programs`` on the virtual machine (module docstring).

    Args:
        programs: Folder written by ``ncmeasure generate`` (the programs, schedule.json).
        machine_file: The machine file they were generated from.
        output: Folder to write into; default ``programs/dryrun``.
        link: ``canopen`` or ``modbus``; default: the machine file's ``[link]`` type,
            else ``canopen``.
        seed: Seed of the simulated noise.
        report: Write report.html.
        controllers_dirs: Folders searched first for the programs' dialect.
        progress: ``progress(stage, fraction)`` for a progress display.
        stop: Set it to stop (Ctrl-C): dryrun.json and the recording so far are kept.

    Returns:
        What was done; ``reach.within_limits`` says whether every limit held.

    Raises:
        ProgramError: no such folder, no schedule.json, a program that cannot be read.
        ConfigError: the machine file is unreadable or not the programs', a link kind
            the simulated drives do not speak, invalid link settings.
        OutputError: the output folder is not usable.
        LinkError: the recording failed.
        NcMeasureError: anything else of the pipeline.
    """
    programs = Path(programs)
    machine_file = Path(machine_file)
    schedule, config = programs_of(programs, machine_file)
    drives = simulated_link(config, link)
    directory = Path(output) if output is not None else programs / DRYRUN_FOLDER
    replaced = prepare_folder(
        directory, marker=_MARKER_FILE, own=_OWN, what="dry run", command="dryrun", replace=True
    )
    reach: list[DryRun] = []

    def hold_against_limits(vm: VirtualMachine, run: MachineRun) -> None:
        found = DryRun(
            machine=schedule.machine,
            controller=schedule.controller,
            config_hash=schedule.config_hash,
            programs=str(programs),
            machine_file=str(machine_file),
            machine_time_s=run.duration_s,
            axes=judge_reach(config, run),
            excursions=vm.excursions[:_LISTED_EXCURSIONS],
            excursions_total=len(vm.excursions),
        )
        write_dryrun(found, directory / DRYRUN_FILE)  # kept, whatever happens next
        reach.append(found)

    done = run_programs(
        config,
        programs,
        schedule,
        directory,
        link=drives,
        notes=f"ncmeasure dryrun: {programs} on the virtual machine, simulated time (lockstep)",
        seed=seed,
        beyond_limits="follow",
        controllers_dirs=controllers_dirs,
        progress=progress,
        stop=stop,
        on_simulated=hold_against_limits,
    )
    result = DryRunResult(
        directory=directory,
        programs=programs,
        machine_file=machine_file,
        schedule=schedule,
        link=drives,
        reach=reach[0],
        run=done,
        replaced=replaced,
        stopped=stop is not None and stop.is_set(),
    )
    if report and done.results is not None and not result.stopped:
        from ncmeasure.report import write_report

        if progress is not None:
            progress("writing the report", None)
        result.report = write_report(
            done.results,
            directory / "report.html",
            recording=read_recording(done.recording),
            title=f"ncmeasure dry run: {schedule.machine} on the virtual machine",
        )
    return result
