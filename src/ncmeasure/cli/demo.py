"""The ``demo`` command: the whole pipeline on a virtual machine."""

import contextlib
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ncmeasure.cli._app import app, console, handle_errors, progress_bar, warn
from ncmeasure.cli._verdicts import print_skipped, print_verdict

if TYPE_CHECKING:
    from ncmeasure.demo import DemoResult, DemoRun


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
    seed: Annotated[int, typer.Option(help="Seed of the simulated noise.")] = 0,
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
    console().print(
        f"{run.label}: {run.machine_time_s:.0f} s of machine time in "
        f"{run.wall_time_s:.0f} s, {acquisition.rows} samples"
        + ("" if acquisition.gaps else ", no sample lost")
    )
    if acquisition.gaps:
        warn(
            f"{run.label}: {acquisition.lost_samples} samples lost in {acquisition.gaps} "
            f"gap(s) ({100 * acquisition.lost_share:.2g} %): the recording is marked "
            "incomplete, the analysis measured the windows that stayed whole and counts "
            "the rest in its report"
        )
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
