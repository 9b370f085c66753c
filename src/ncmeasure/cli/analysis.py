"""The analysis commands: analyze a recording, compare results, simulate the axis model."""

import contextlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ncmeasure.cli._app import Outcome, app, console, handle_errors, need_matplotlib, progress_bar
from ncmeasure.cli._fleet import measurement_info, mqtt_target, open_store, publish_added
from ncmeasure.cli._options import (
    CriticalOption,
    MeasuredAtOption,
    PublishOption,
    WarningOption,
    limits,
    measured_at,
    settings,
)
from ncmeasure.cli._verdicts import print_comparison, print_verdicts, print_warnings
from ncmeasure.errors import ConfigError

if TYPE_CHECKING:
    from ncmeasure.analysis.analyze import AnalysisSettings
    from ncmeasure.formats.results import Results

ANALYSIS_SETTINGS = (
    "velocity_tolerance",
    "velocity_floor_mm_min",
    "settle_s",
    "min_window_s",
    "plateau_min_s",
    "plateau_filter_s",
    "standstill_mm_min",
    "step_tolerance",
    "step_floor_mm_min",
    "position_gap_mm",
    "position_gap_fraction",
    "max_velocity_mm_min",
    "duration_outlier_factor",
    "rapid_count_factor",
    "window_method",
)
"""The names ``analyze --set`` takes (those of AnalysisSettings; a test keeps them equal),
listed here so that ``--help`` need not import the analysis."""

AnalysisSetOption = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        metavar="KEY=VALUE",
        help="An analysis setting, KEY=VALUE, e.g. --set settle_s=0.2 --set "
        f"window_method=command. Settings: {', '.join(ANALYSIS_SETTINGS)} "
        "(docs/analysis.md, Settings).",
    ),
]


@app.command("analyze")
@handle_errors
def analyze_command(
    run: Annotated[Path, typer.Argument(help="Recording directory (recorded or imported).")],
    schedule: Annotated[
        Path | None,
        typer.Option(
            help="schedule.json of the program: labels every window with its step and position."
        ),
    ] = None,
    machine: Annotated[
        Path | None,
        typer.Option(
            help="Machine file: torque constant, screw lead, fixed-bearing end, vertical axes."
        ),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="results.json to write (default: RUN.results.json)."),
    ] = None,
    report: Annotated[Path | None, typer.Option(help="Also write this HTML report.")] = None,
    only: Annotated[
        list[str] | None,
        typer.Option(
            "--axis",
            help="Analyse only this axis (repeat for several; default: every axis).",
            metavar="AXIS",
        ),
    ] = None,
    set_: AnalysisSetOption = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress, no summary.")] = False,
    store: Annotated[
        str | None,
        typer.Option(
            "--store",
            metavar="URL",
            help="Also add the results to this fleet store, as the machine of --serial (or of "
            "the recording's serial); see `ncmeasure store --help`.",
            show_default=False,
        ),
    ] = None,
    serial: Annotated[
        str | None,
        typer.Option(
            help="The serial number of the machine measured, for the results and --store "
            "(default: the recording's; the machine file names the type)."
        ),
    ] = None,
    label: Annotated[
        str | None, typer.Option(help="For --store: delivery, service, after-repair, ...")
    ] = None,
    measured: MeasuredAtOption = None,
    publish: PublishOption = None,
) -> None:
    """Friction per position, direction and velocity; fits; position diagnosis; a verdict.

    Windows come from the marker when recorded, else from commanded vs actual velocity,
    else from constant-velocity plateaus. An axis that cannot be analysed (a dead
    channel, no motion) is skipped with the reason; the others are analysed (exit 0).
    Example: ncmeasure analyze run1 --schedule programs/schedule.json --report run1.html
    """
    from ncmeasure.analysis.analyze import analyze
    from ncmeasure.config import load_machine
    from ncmeasure.formats.results import write_results
    from ncmeasure.formats.schedule import load_schedule
    from ncmeasure.recording import RecordingHead

    target = output or run.with_name(run.name + ".results.json")
    analysis_settings = _analysis_settings(set_ or [])
    # Read chunk by chunk: memory follows the windows, not the recording's length.
    recording = RecordingHead.open(run)
    info, broker = _store_request(
        run, recording.meta.serial, store, serial, label, measured_at(measured), publish
    )
    plan_schedule = load_schedule(schedule) if schedule else None
    config = load_machine(machine) if machine else None
    traces = None
    if report is not None:
        # The raw-data figures' data is gathered on the analysis' own readings.
        from ncmeasure.report.traces import RawTraces

        traces = RawTraces(recording)
    bar, update = progress_bar(quiet)
    windows: dict[str, list[tuple[float, float]]] = {}
    with bar or contextlib.nullcontext():
        results = analyze(
            recording,
            schedule=plan_schedule,
            machine=config,
            settings=analysis_settings,
            axes=only or None,
            progress=update,
            window_times=windows,
            on_windows=traces.watch if traces is not None else None,
            serial=serial,
        )
    write_results(results, target)
    if report is not None:
        from ncmeasure.report import write_report

        found = traces.found if traces is not None else None
        write_report(results, report, recording=recording, windows=windows, traces=found)
    if info is not None:
        _store_results(results, info, store, broker, quiet)
    if quiet:
        return None
    print_verdicts(results)
    print_warnings(results)
    console().print(f"wrote {target}" + (f" and {report}" if report else ""))


def _store_request(
    run: Path,
    recorded_serial: str | None,
    store: str | None,
    serial: str | None,
    label: str | None,
    measured_utc: str | None,
    publish: str | None,
) -> tuple[Any, Any]:
    """``analyze --store --serial --label --measured-at --publish`` checked: the
    measurement's info for the store (None: not stored) and the broker to publish to
    (None: none). The serial is ``--serial``, else the recording's."""
    if store is None:
        if label is not None or measured_utc is not None or publish is not None:
            raise ConfigError(
                "--label, --measured-at and --publish are for --store: give --store and "
                "--serial too"
            )
        return None, None
    chosen = serial if serial is not None else recorded_serial
    if chosen is None:
        raise ConfigError(
            "--store needs the machine's serial number: give --serial (the recording carries none)"
        )
    broker = mqtt_target(publish)
    info = measurement_info(
        serial=chosen,
        label=label,
        recording_location=str(run.absolute()),
        measured_utc=measured_utc,
    )
    return info, broker


def _analysis_settings(values: list[str]) -> "AnalysisSettings":
    """The analysis settings of ``--set``; invalid ones as one ConfigError."""
    from pydantic import ValidationError

    from ncmeasure.analysis.analyze import AnalysisSettings
    from ncmeasure.config import format_validation_error

    try:
        return AnalysisSettings.model_validate(settings(values, example="--set settle_s=0.2"))
    except ValidationError as exc:
        raise ConfigError(
            "--set: not valid analysis settings", format_validation_error(exc)
        ) from exc


def _store_results(
    results: "Results", info: Any, store: str | None, broker: Any, quiet: bool
) -> None:
    """``analyze --store``: add the results to the store, then publish them (--publish)."""
    with open_store(store, write=True) as fleet:
        added = fleet.add(results, info)
    if not quiet:
        state = "stored as" if added.new else "already stored as"
        console().print(f"{state} measurement {added.measurement_id} of {info.serial}")
    publish_added(broker, store, added, quiet)


@app.command("compare")
@handle_errors
def compare_command(
    base: Annotated[
        Path,
        typer.Argument(
            help="results.json of the reference (the machine at delivery, or the fleet's first)."
        ),
    ],
    others: Annotated[list[Path], typer.Argument(help="results.json files to compare with it.")],
    warning: WarningOption = None,
    critical: CriticalOption = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Write the comparison as JSON.")
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option(help="Write an HTML report of the last run with the comparison."),
    ] = None,
    label: Annotated[
        list[str] | None,
        typer.Option(
            "--label",
            metavar="LABEL",
            help="Name of a compared file in the output; repeat in order, one per file "
            "after BASE (or one per file, BASE's first). Default: the file name, with its "
            "folders where names clash (m17/results, m18/results).",
        ),
    ] = None,
) -> Outcome:
    """Compare runs: the same machine over its life, or identical machines (fleet).

    Exit code 0: every deviation within the warning limit; 1: a warning limit crossed;
    3: a critical limit crossed; 2: bad input (also an output that cannot be written).

    Example: ncmeasure compare m17/results.json m18/results.json m19/results.json
    """
    from ncmeasure.analysis.judgement.compare import compare_results
    from ncmeasure.formats.comparison import write_comparison
    from ncmeasure.formats.results import load_results

    labels = _compare_labels(base, others, label)
    reference = load_results(base)
    runs = [load_results(path) for path in others]
    chosen = limits(warning, critical)
    comparison = compare_results(reference, runs, labels=labels, limits=chosen)
    if output is not None:
        write_comparison(comparison, output)
    if report is not None:
        from ncmeasure.report import write_report

        write_report(runs[-1], report, comparison=comparison)
        console().print(f"wrote {report}")
    print_comparison(comparison, runs)
    return comparison.status


def _file_labels(paths: list[Path]) -> list[str]:
    """A label per results file: its name without ``.json``; where names clash, with as
    many of its folders as tell them apart (``m17/results``), else numbered (``#2``)."""

    def label(path: Path, depth: int) -> str:
        folders = path.absolute().parent.parts[1:]
        return "/".join([*folders[len(folders) - depth :], path.stem]) if depth else path.stem

    depths = [0] * len(paths)
    labels = [path.stem for path in paths]
    while True:
        grown = False
        for name in {name for name in labels if labels.count(name) > 1}:
            group = [i for i, other in enumerate(labels) if other == name]
            if len({paths[i].absolute() for i in group}) == 1:
                continue  # the same file: only a number tells them apart
            for index in group:
                if depths[index] < len(paths[index].absolute().parent.parts) - 1:
                    depths[index] += 1
                    labels[index] = label(paths[index], depths[index])
                    grown = True
        if not grown:
            break
    doubled = {name for name in labels if labels.count(name) > 1}
    counts: dict[str, int] = {}
    for index, name in enumerate(labels):
        if name in doubled:
            counts[name] = counts.get(name, 0) + 1
            labels[index] = f"{name} #{counts[name]}"
    return labels


def _compare_labels(base: Path, others: list[Path], given: list[str] | None) -> list[str]:
    """The labels of the compared files: ``--label`` checked, or from the file names.

    Raises:
        ConfigError: ``--label`` given neither once per file after BASE nor once per
            file, empty, or twice the same.
    """
    if not given:
        return _file_labels([base, *others])[1:]
    if len(given) not in (len(others), len(others) + 1):
        raise ConfigError(
            f"--label: {len(given)} label{'s' if len(given) != 1 else ''} for "
            f"{len(others)} compared file{'s' if len(others) != 1 else ''}: give one per "
            "file after BASE, in order (or one per file, BASE's first)"
        )
    if any(not text.strip() for text in given):
        raise ConfigError("--label: a label is empty; every compared file needs a name")
    doubled = next((text for text in given if given.count(text) > 1), None)
    if doubled is not None:
        raise ConfigError(f"--label: {doubled!r} is given twice; labels must be unique")
    return list(given)


@app.command("simulate")
@handle_errors
def simulate_command(
    machine: Annotated[Path, typer.Argument(help="Machine file.")],
    variation: Annotated[
        list[str] | None,
        typer.Option(
            metavar="KEY=VALUE",
            help="An assembly variation, e.g. loose_bearing_shift_um=20 or "
            "'nut_shift_um=20, bearing_preload_change=-0.3'; repeat for side by side.",
        ),
    ] = None,
    axis: Annotated[str | None, typer.Option(help="Axis to study (default: the first).")] = None,
    plot: Annotated[
        Path | None, typer.Option(help="Write contour plots (PNG; extra: plot).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the study as JSON.")] = False,
) -> None:
    """The axis friction model alone: what does each assembly variation do along the travel?

    Example: ncmeasure simulate machine.toml --variation loose_bearing_shift_um=20
    --variation nut_shift_um=20 --plot variations.png
    """
    from rich.table import Table

    from ncmeasure.config import load_machine
    from ncmeasure.sim.explore import plot_study, study

    if plot is not None:
        need_matplotlib("--plot")
    config = load_machine(machine)
    names = [a.name for a in config.axes]
    if axis is not None and axis not in names:
        raise ConfigError(f"--axis {axis}: the machine has axes {', '.join(names)}")
    chosen = config.axis(axis or names[0])
    result = study(chosen, config.measurement_for(chosen), variation or [])
    if plot is not None:
        plot_study(result, plot)
    if as_json:
        sys.stdout.write(result.model_dump_json(indent=2) + "\n")
        return None
    table = Table(box=None, header_style="bold")
    table.add_column("variation", overflow="fold")
    table.add_column("mean Nm", justify="right")
    table.add_column("spread", justify="right")
    for position in result.positions_mm[:: max(1, len(result.positions_mm) // 5)]:
        table.add_column(f"{position:g} mm", justify="right")
    step = max(1, len(result.positions_mm) // 5)
    for scenario in result.scenarios:
        table.add_row(
            scenario.name,
            f"{scenario.mean_nm:.3f}",
            f"{scenario.spread_percent:.1f} %",
            *(f"{c:+.1f} %" for c in scenario.change_percent[::step]),
        )
    console().print(
        f"axis {result.axis}: friction change against the nominal axis, averaged over velocities"
    )
    console().print(table)
    if plot is not None:
        console().print(f"wrote {plot}")
