"""The virtual machine's commands: ``demo`` (the whole pipeline on the demo machine) and
``dryrun`` (a user's generated programs on the virtual machine)."""

import contextlib
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ncmeasure.cli._app import (
    Outcome,
    app,
    console,
    handle_errors,
    progress_bar,
    restore_signals,
    stop_on_signals,
    warn,
)
from ncmeasure.cli._options import ControllersDir
from ncmeasure.cli._verdicts import print_skipped, print_verdict
from ncmeasure.errors import ProgramCheckError

if TYPE_CHECKING:
    from ncmeasure.acquire import AcquisitionResult
    from ncmeasure.demo import DemoResult, DemoRun
    from ncmeasure.dryrun import DryRunResult
    from ncmeasure.formats.dryrun import AxisReach, DryRun, Limit


@app.command("demo")
@handle_errors
def demo_command(
    outdir: Annotated[
        Path, typer.Argument(help="Folder to write everything into (new or empty).")
    ] = Path("ncmeasure-demo"),
    link: Annotated[
        str,
        typer.Option(
            help="Drive link to record through: canopen (simulated CiA 402 drives on a "
            "python-can virtual bus) or modbus (a simulated drive server on 127.0.0.1)."
        ),
    ] = "canopen",
    variation: Annotated[
        list[str] | None,
        typer.Option(
            metavar="KEY=VALUE",
            help="Assemble every axis of the virtual machine with this fault, e.g. "
            "loose_bearing_shift_um=500 or nut_preload_change=1.5; repeat to combine. "
            "The machine is then measured twice: assembled correctly, and with the fault. "
            "Keys: see `ncmeasure simulate --help` and docs/axis-model.md.",
        ),
    ] = None,
    controller: Annotated[
        str, typer.Option(help="Dialect of the programs the virtual machine runs.")
    ] = "linuxcnc",
    reference: Annotated[
        Path | None,
        typer.Option(
            help="An earlier demo folder without variation: compare with it instead of "
            "measuring the correctly assembled machine again."
        ),
    ] = None,
    seed: Annotated[
        int,
        typer.Option(help="Seed of the simulated noise (and, with --realistic, of the machine)."),
    ] = 0,
    realistic: Annotated[
        bool,
        typer.Option(
            help="A virtual machine as real ones are: a healthy fingerprint along the travel "
            "(assembly within tolerance, preload varying along the screw), drift of friction "
            "between runs (temperature, lubricant) and the drives' real current and velocity "
            "noise. docs/virtual-machine.md, Realism."
        ),
    ] = False,
    force: Annotated[bool, typer.Option(help="Replace an earlier demo in OUTDIR.")] = False,
    quiet: Annotated[
        bool, typer.Option("--quiet", "-q", help="Print only the report path.")
    ] = False,
) -> None:
    """The whole pipeline on a virtual machine: program, drives, recording, analysis, report.

    Writes a machine file, generates its NC programs, runs them on a virtual machine tool
    whose axes follow the programs (friction from a physical model of the feed axis),
    records the simulated drives through the real link, analyses the recording and writes
    an HTML report. Link and simulated drives run in lockstep on simulated time, as fast
    as the computer allows: the same seed gives the same recording on an idle and on a
    busy computer. Takes about 15 s on two cores; longer with --variation, which measures
    the machine twice.

    Examples: ncmeasure demo  ·  ncmeasure demo --variation loose_bearing_shift_um=500
    ·  ncmeasure demo demo-modbus --link modbus
    ·  ncmeasure demo --realistic --variation loose_bearing_shift_um=100
    """
    from ncmeasure.demo import run_demo

    chosen = _variation(variation)
    bar, progress = progress_bar(quiet, stages=True)

    started = time.monotonic()
    with bar or contextlib.nullcontext():
        result = run_demo(
            outdir,
            link=link,
            variation=chosen,
            controller=controller,
            reference=reference,
            seed=seed,
            force=force,
            progress=progress,
            realistic=realistic,
        )
        if progress is not None:
            progress("done", None)
    if quiet:
        console().print(str(result.report))
        return None
    _print_demo(result, controller, started)


def _variation(texts: list[str] | None) -> Any:
    """One variation from repeated --variation options (their keys merged)."""
    from ncmeasure.sim.axis import parse_variation

    return parse_variation(" ".join(texts or []))


def _print_demo(result: "DemoResult", controller: str, started: float) -> None:
    """What the demo did: per run its machine time, samples and verdicts, then the files
    and the time it took since ``started`` (``time.monotonic()``)."""
    from rich.text import Text

    console().print(
        f"virtual machine: axes {', '.join(result.runs[-1].results.axes)}, "
        f"{controller} programs, recorded through {result.link} in lockstep with the "
        "simulated drives"
    )
    for run in result.runs:
        _print_run(result, run)
    took = time.monotonic() - started
    console().print(Text.assemble(f"finished in {took:.0f} s. Open ", (str(result.report), "bold")))
    console().print(
        f"files: {result.directory}/ (machine.toml, programs/, recording/, results.json"
        + (", reference/" if (result.directory / "reference").is_dir() else "")
        + (", comparison.json" if result.comparison is not None else "")
        + ")"
    )


def _print_run(result: "DemoResult", run: "DemoRun") -> None:
    """One run of the demo: reused, or recorded (and what was lost), then its verdicts."""
    acquisition = run.acquisition
    if acquisition is None:
        console().print(f"{run.label}: reused from {run.directory}")
        return
    _print_recorded(run.label, run.machine_time_s, run.wall_time_s, acquisition)
    compared = result.comparison if run is result.measured else None
    for name in run.results.axes:
        print_verdict(run.results, name, compared, indent="  ")
        found = run.accuracy.get(name)
        if found is not None:
            console().print(
                f"    axis {name} against the virtual machine's own friction (mean over "
                f"{found.points} points, all velocities): {found.measured_mean_nm:.3f} Nm "
                f"measured, {found.simulated_mean_nm:.3f} Nm simulated (bias "
                f"{found.median_error_percent:+.1f} %, worst point "
                f"{found.max_error_percent:.1f} %)"
            )
    print_skipped(run.results, indent="  ")


def _print_recorded(
    label: str, machine_time_s: float, wall_time_s: float, acquisition: "AcquisitionResult"
) -> None:
    """``label: 102 s of machine time in 9 s, 25512 samples, no sample lost``, and what
    was lost in a warning."""
    console().print(
        f"{label}: {machine_time_s:.0f} s of machine time in "
        f"{wall_time_s:.0f} s, {acquisition.rows} samples"
        + ("" if acquisition.gaps else ", no sample lost")
    )
    if acquisition.gaps:
        warn(
            f"{label}: {acquisition.lost_samples} samples lost in {acquisition.gaps} "
            f"gap(s) ({100 * acquisition.lost_share:.2g} %): the recording is marked "
            "incomplete, the analysis measured the windows that stayed whole and counts "
            "the rest in its report"
        )


@app.command("dryrun")
@handle_errors
def dryrun_command(
    programs: Annotated[
        Path,
        typer.Argument(
            help="Folder written by `ncmeasure generate`: the NC programs and schedule.json.",
            show_default=False,
        ),
    ],
    machine: Annotated[
        Path,
        typer.Option(
            "--machine",
            "-m",
            help="The machine file the programs were generated from (schedule.json's "
            "config hash must be its): the axes' travel, limits and drive data, and the "
            "[link] table.",
            show_default=False,
        ),
    ],
    link: Annotated[
        str | None,
        typer.Option(
            help="Drive link to record through: canopen (simulated CiA 402 drives on a "
            "python-can virtual bus) or modbus (a simulated drive server on 127.0.0.1). "
            "Default: the type of the machine file's [link] table, else canopen.",
            show_default=False,
        ),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="Folder to write into (default: PROGRAMS/dryrun). An earlier dry run there "
            "is replaced; any other non-empty folder is refused.",
            show_default=False,
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the simulated noise.")] = 0,
    report: Annotated[bool, typer.Option("--report/--no-report", help="Write report.html.")] = True,
    controllers_dir: ControllersDir = None,
    quiet: Annotated[
        bool,
        typer.Option(
            "--quiet", "-q", help="No progress; print only the report's path (and any excess)."
        ),
    ] = False,
) -> Outcome | None:
    """Run generated programs on the virtual machine: limits, recording, analysis, report.

    A rehearsal before the real machine. The virtual machine of `ncmeasure demo`, built
    with the axes of the machine file (travel, limits, mechanics, drive data), executes
    the programs in PROGRAMS as a controller would, following them wherever they go;
    simulated drives serve its motion and the link of the machine file's kind records it
    (in lockstep, as fast as the computer allows); the analysis cuts every window of
    schedule.json and writes a report. The friction is the virtual machine's model (the
    method's test rig on your axes), not your machine's.

    Per axis it prints the smallest and largest position, the largest feed and the
    largest acceleration the programs commanded, against the machine file's travel_mm,
    max_velocity_mm_min and max_acceleration_m_s2, as a controller checks them.

    Writes into PROGRAMS/dryrun/ (or --output): dryrun.json (those figures, and the
    actual motion of the servo loop beside them), recording/, results.json and
    report.html. Copy only the program files to the control.

    Exit codes: 0 every limit held; 1 a limit was exceeded (the table and dryrun.json
    say where); 2 bad input (no such folder, no schedule.json, a machine file the
    programs were not generated from); 4 the simulated link failed; 130 stopped by Ctrl-C
    (dryrun.json and what was recorded are kept).

    Example: ncmeasure generate m.toml -o prog && ncmeasure dryrun prog --machine m.toml
    """
    from ncmeasure.dryrun import run_dryrun

    stop = threading.Event()
    bar, progress = progress_bar(quiet, stages=True)
    started = time.monotonic()
    previous = stop_on_signals(stop)  # Ctrl-C stops the recording and keeps it
    try:
        with bar or contextlib.nullcontext():
            result = run_dryrun(
                programs,
                machine,
                output=output,
                link=link,
                seed=seed,
                report=report,
                controllers_dirs=controllers_dir or (),
                progress=progress,
                stop=stop,
            )
            if progress is not None:
                progress("done", None)
    finally:
        restore_signals(previous)
    if quiet:
        if result.report is not None:
            console().print(str(result.report))
    else:
        _print_dryrun(result, started)
    if result.interrupted:
        again = "the analysis and the report" if result.run.interrupted else "the report"
        console(stderr=True).print(
            f"interrupted: kept {', '.join(_written(result))} in {result.directory}/; "
            f"run the dry run again for {again}"
        )
        return "interrupted"
    if not result.reach.within_limits:
        reach = result.reach
        where = [f"at {line}" for line in reach.excursions[:10]]
        more = reach.excursions_total - len(where)
        raise ProgramCheckError(
            f"the programs go beyond the limits of {machine}",
            [*reach.exceeded, *where, *([f"... and {more} more blocks"] if more > 0 else [])],
        )
    return None


def _print_dryrun(result: "DryRunResult", started: float) -> None:
    """The limits table, the recording and the windows per axis, then the files."""
    from rich.text import Text

    schedule = result.schedule
    console().print(
        f"dry run of {result.programs} ({schedule.controller} programs of "
        f"{schedule.machine!r}, config {schedule.config_hash}) on the virtual machine, "
        f"recorded through {result.link.kind} with {result.link.source}"
    )
    _print_reach(result.reach)
    run = result.run
    if run.interrupted and run.acquisition is not None:
        console().print(
            f"dry run: stopped after {run.acquisition.link_time_s:.0f} of "
            f"{run.machine_time_s:.0f} s of machine time, {run.acquisition.rows} samples kept"
        )
    elif run.acquisition is not None:
        _print_recorded("dry run", run.machine_time_s, run.wall_time_s, run.acquisition)
    if run.results is not None:
        for summary in schedule.axes:
            axis = run.results.axes.get(summary.name)
            if axis is not None:
                console().print(
                    f"  axis {summary.name}: {axis.windows} of {len(summary.windows)} "
                    f"windows of schedule.json measured"
                )
        print_skipped(run.results, indent="  ")
        console().print(
            "  (the friction is the virtual machine's: the test rig's model on your axes, "
            "not your machine's)"
        )
    if result.report is not None:
        took = time.monotonic() - started
        console().print(
            Text.assemble(f"finished in {took:.0f} s. Open ", (str(result.report), "bold"))
        )
    replaced = ", an earlier dry run replaced" if result.replaced else ""
    console().print(f"files: {result.directory}/ ({', '.join(_written(result))}{replaced})")


def _written(result: "DryRunResult") -> list[str]:
    """The files the dry run wrote (all of them, or as far as it came)."""
    names = ("dryrun.json", "recording/", "results.json", "report.html")
    return [name for name in names if (result.directory / name.rstrip("/")).exists()]


def _print_reach(reach: "DryRun") -> None:
    """Per axis: the commanded extremes against the limits, an excess in red."""
    from rich.table import Table
    from rich.text import Text

    table = Table(box=None, header_style="bold")
    for column in (
        "axis",
        "position mm",
        "soft limits mm",
        "feed mm/min",
        "limit",
        "acceleration m/s²",
        "limit",
        "",
    ):
        table.add_column(column, no_wrap=True)
    overshoot = [0.0, 0.0, 0.0]
    for axis in reach.axes:
        done, limits, actual = axis.commanded, axis.limits, axis.actual
        low, high = limits.travel_mm
        position = Text(f"{done.min_position_mm:.3f}", style=_red(axis, "travel_min"))
        position.append(" … ")
        position.append(f"{done.max_position_mm:.3f}", style=_red(axis, "travel_max"))
        table.add_row(
            axis.name,
            position,
            f"{low:g} … {high:g}",
            Text(f"{done.max_velocity_mm_min:.0f}", style=_red(axis, "max_velocity_mm_min")),
            f"{limits.max_velocity_mm_min:g}",
            Text(f"{done.max_acceleration_m_s2:.3g}", style=_red(axis, "max_acceleration_m_s2")),
            f"{limits.max_acceleration_m_s2:g}",
            Text("exceeded", style="bold red") if axis.exceeded else Text("ok", style="green"),
        )
        overshoot[0] = max(
            overshoot[0],
            done.min_position_mm - actual.min_position_mm,
            actual.max_position_mm - done.max_position_mm,
        )
        overshoot[1] = max(overshoot[1], actual.max_velocity_mm_min - done.max_velocity_mm_min)
        overshoot[2] = max(overshoot[2], actual.max_acceleration_m_s2 - done.max_acceleration_m_s2)
    console().print(table)
    console().print(
        "commanded motion (the interpolator's setpoints), as a controller holds it against "
        f"its limits; the servo loop overshoots it by at most {overshoot[0]:.3f} mm, "
        f"{overshoot[1]:.0f} mm/min and {overshoot[2]:.3f} m/s² (dryrun.json: actual)"
    )


def _red(axis: "AxisReach", limit: "Limit") -> str:
    """The style of a figure: red where the axis exceeded ``limit``."""
    return "red" if axis.exceeds(limit) else ""
