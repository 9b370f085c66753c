"""The ``store`` commands: the fleet store's measurements, trends, checks, report and transfer."""

import contextlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ncmeasure.cli._app import (
    Outcome,
    console,
    handle_errors,
    need_matplotlib,
    progress_bar,
    store_app,
    warn,
)
from ncmeasure.cli._fleet import measurement_info, mqtt_target, open_store, publish_added
from ncmeasure.cli._options import (
    CriticalOption,
    MeasuredAtOption,
    PublishOption,
    StoreOption,
    WarningOption,
    limits,
    measured_at,
)
from ncmeasure.cli._verdicts import LEVEL_STYLE, verdict_text
from ncmeasure.errors import ConfigError

if TYPE_CHECKING:
    from ncmeasure.store import Store
    from ncmeasure.store.summaries import MachinePage

SerialArgument = Annotated[str, typer.Argument(help="The machine's serial number.")]

_STATUS_STYLE = {"ok": "bold green", "warning": "bold yellow", "critical": "bold red"}


@store_app.command("add")
@handle_errors
def store_add_command(
    results_file: Annotated[Path, typer.Argument(help="results.json of `ncmeasure analyze`.")],
    serial: Annotated[str, typer.Option(help="The machine's serial number.")],
    label: Annotated[
        str | None,
        typer.Option(help="What the measurement is: delivery, service, after-repair, ..."),
    ] = None,
    site: Annotated[str | None, typer.Option(help="Where the machine stands.")] = None,
    machine_type: Annotated[
        str | None,
        typer.Option(
            "--type",
            help="The machine type (default: the machine name in the results); a machine new "
            "to the store needs one.",
        ),
    ] = None,
    operator: Annotated[str | None, typer.Option(help="Who measured.")] = None,
    temperature_c: Annotated[
        float | None, typer.Option("--temperature-c", help="Machine temperature in °C.")
    ] = None,
    operating_hours: Annotated[
        float | None, typer.Option(help="The machine's operating hours.")
    ] = None,
    recording: Annotated[
        str | None,
        typer.Option(help="Where the raw recording is kept (default: its folder in the results)."),
    ] = None,
    measured: MeasuredAtOption = None,
    store: StoreOption = None,
    publish: PublishOption = None,
) -> None:
    """Add a measurement's results to the store (the same results twice are stored once).

    Example: ncmeasure store add m17.results.json --serial M17 --label delivery --temperature-c 21.5
    """
    from ncmeasure.formats.results import load_results

    info = measurement_info(
        serial=serial,
        label=label,
        site=site,
        machine_type=machine_type,
        operator=operator,
        temperature_c=temperature_c,
        operating_hours=operating_hours,
        recording_location=recording,
        measured_utc=measured_at(measured),
    )
    target = mqtt_target(publish)
    results = load_results(results_file)
    with open_store(store, write=True) as fleet:
        added = fleet.add(results, info)
        where = fleet.where
    if added.new:
        console().print(f"stored as measurement {added.measurement_id} of {serial} in {where}")
    else:
        console().print(
            f"already stored as measurement {added.measurement_id} of {serial}; nothing added"
        )
    publish_added(target, store, added, quiet=False)


@store_app.command("list")
@handle_errors
def store_list_command(
    store: StoreOption = None,
    limit: Annotated[
        int,
        typer.Option(help="Machines per page (1 to 1000); the rest are counted.", min=1),
    ] = 100,
    after: Annotated[
        str | None,
        typer.Option(
            metavar="SERIAL", help="Start after this serial (the next page: the line below)."
        ),
    ] = None,
    search: Annotated[
        str | None,
        typer.Option(metavar="TEXT", help="Only machines whose serial, type or site holds TEXT."),
    ] = None,
    status: Annotated[
        str | None,
        typer.Option(metavar="STATUS", help="Only machines of this status: ok, warning, critical."),
    ] = None,
    as_json: Annotated[
        bool,
        typer.Option("--json", help="Print the page as JSON: machines, total, next_cursor."),
    ] = False,
) -> None:
    """The machines in the store by serial, a page at a time: type, site, measurements, the
    latest verdicts.

    Example: ncmeasure store list --search HMX --status critical --limit 20
    """
    import json

    from ncmeasure.store.summaries import MAX_PAGE

    if limit > MAX_PAGE:
        raise ConfigError(f"--limit {limit}: a page holds 1 to {MAX_PAGE} machines")
    if status is not None and status not in _STATUS_STYLE:
        raise ConfigError(f"--status {status}: one of {', '.join(_STATUS_STYLE)}")
    with open_store(store, write=False) as fleet:
        statuses = None if status is None else _statuses(fleet)
        page = fleet.machine_page(
            limit=limit, after=after, search=search, status=status, statuses=statuses
        )
        where = fleet.where
    if as_json:
        found = {
            "machines": [m.model_dump(mode="json") for m in page.machines],
            "total": page.total,
            "next_cursor": page.next_cursor,
        }
        sys.stdout.write(json.dumps(found, indent=2) + "\n")
        return
    _print_page(page, where, limit, filtered=bool(search or status))


def _statuses(fleet: "Store") -> dict[str, str] | None:
    """The machines' statuses where the stored ones are not current (None: they are): each
    machine's own status as kept, and the fleet's part for all at once."""
    from ncmeasure.store.statuses import fleet_statuses
    from ncmeasure.store.summaries import statuses_current

    with fleet.reading("read the statuses") as db:
        if statuses_current(db):
            return None
    return dict(fleet_statuses(fleet).by_serial())


def _print_page(page: "MachinePage", where: str, limit: int, *, filtered: bool) -> None:
    from rich.table import Table

    if not page.machines:
        console().print(f"no machines{' that match' if filtered else ''} in {where}")
        return
    shown = len(page.machines)
    title = (
        f"{page.total} machine(s) in {where}"
        if shown == page.total
        else f"{shown} of {page.total} machine(s){' that match' if filtered else ''} in {where}"
    )
    table = Table(title=title, title_justify="left")
    for column in ("serial", "type", "site", "measurements", "latest", "label", "verdicts"):
        table.add_column(column)
    for m in page.machines:
        table.add_row(
            m.serial,
            m.machine_type,
            m.site or "",
            str(m.measurements),
            (m.latest_utc or "")[:16].replace("T", " "),
            m.latest_label or "",
            verdict_text(m.latest_verdicts),
        )
    console().print(table)
    if page.next_cursor is not None:
        console().print(
            f"more after {page.next_cursor}: --after {page.next_cursor} (--limit {limit})"
        )


@store_app.command("show")
@handle_errors
def store_show_command(serial: SerialArgument, store: StoreOption = None) -> None:
    """A machine and its measurements, oldest first."""
    from rich.table import Table
    from rich.text import Text

    with open_store(store, write=False) as fleet:
        machine, measurements = fleet.machine(serial)
    console().print(
        Text.assemble(
            (machine.serial, "bold"),
            f" · type {machine.machine_type} (config {machine.config_hash or 'unknown'})"
            + (f" · {machine.site}" if machine.site else ""),
        )
    )
    table = Table()
    for column in ("id", "measured (UTC)", "label", "°C", "hours", "link", "verdicts"):
        table.add_column(column)
    for m in measurements:
        table.add_row(
            str(m.id),
            m.measured_utc[:19].replace("T", " "),
            m.label or "",
            "" if m.temperature_c is None else f"{m.temperature_c:g}",
            "" if m.operating_hours is None else f"{m.operating_hours:g}",
            m.link or "",
            verdict_text(m.verdicts),
        )
    console().print(table)


@store_app.command("trend")
@handle_errors
def store_trend_command(
    serial: SerialArgument,
    axis: Annotated[str, typer.Option(help="The axis, e.g. X.")],
    plot: Annotated[
        Path | None,
        typer.Option(help="Also draw the trend with its limits as a PNG (extra: plot)."),
    ] = None,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    store: StoreOption = None,
) -> None:
    """Coulomb, viscous friction and the spread along the travel over the machine's life.

    Example: ncmeasure store trend M17 --axis X --plot m17-x.png
    """
    from rich.table import Table
    from rich.text import Text

    from ncmeasure.analysis.judgement.summary import format_number

    chosen = limits(warning, critical)
    if plot is not None:
        need_matplotlib("--plot")
    with open_store(store, write=False) as fleet:
        points = fleet.trend(serial, axis)
    unit = points[0].unit
    table = Table(title=f"{serial} axis {axis}", title_justify="left")
    for column in (
        "id", "measured (UTC)", "label", "hours", f"Coulomb [{unit}]",
        f"viscous [{unit} per m/min]", "spread [%]", "verdict",
    ):  # fmt: skip
        table.add_column(column)
    for p in points:
        table.add_row(
            str(p.measurement_id),
            p.measured_utc[:16].replace("T", " "),
            p.label or "",
            "" if p.operating_hours is None else f"{p.operating_hours:g}",
            format_number(p.coulomb),
            format_number(p.viscous_per_m_min),
            format_number(p.spread_percent),
            Text(p.verdict, style=LEVEL_STYLE.get(p.verdict, "bold")),
        )
    console().print(table)
    if plot is not None:
        from ncmeasure.report.plots import save_png
        from ncmeasure.store.report import trend_figure

        figure = trend_figure(axis, points, chosen)
        save_png(figure, plot)
        console().print(f"wrote {plot}")


@store_app.command("check")
@handle_errors
def store_check_command(
    serial: SerialArgument,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Also write the check as JSON.")
    ] = None,
    store: StoreOption = None,
) -> Outcome:
    """The latest measurement against the machine's delivery baseline and its fleet.

    The baseline is the first measurement labelled delivery (else the first). The fleet
    is the latest measurement of every other machine of the type: per axis and
    characteristic its median and range, and the machine's robust z-score (an outlier
    beyond 3.5, with at least 3 other machines). What differs between baseline and
    latest (program, positions, velocities, temperature, link) is said first.

    Exit code 0: within the limits; 1: a warning limit crossed or an outlier of its type;
    3: a critical limit crossed; 2: bad input.
    """
    from rich.text import Text

    from ncmeasure.store.check import check_machine, write_check

    chosen = limits(warning, critical)
    with open_store(store, write=False) as fleet:
        found = check_machine(fleet, serial, chosen)
    if output is not None:
        write_check(found, output)
    latest = found.latest
    console().print(
        Text.assemble(
            (serial, "bold"),
            f" · latest measurement {latest.id} ({latest.label or 'no label'}, "
            f"{latest.measured_utc[:16].replace('T', ' ')} UTC)",
        )
    )
    if found.baseline is not None:
        base = found.baseline
        console().print(
            f"baseline: measurement {base.id} ({base.label or 'no label'}, "
            f"{base.measured_utc[:16].replace('T', ' ')} UTC)"
        )
    if found.comparability is not None:
        for difference in found.comparability.differences:
            warn(difference)
    for finding in found.findings:
        console().print(Text(finding))
    line = Text("status: ")
    line.append(found.status, style=_STATUS_STYLE[found.status])
    console().print(line)
    return found.status


@store_app.command("report")
@handle_errors
def store_report_command(
    output: Annotated[Path, typer.Option("--output", "-o", help="The HTML file to write.")],
    trends: Annotated[
        int,
        typer.Option(min=0, max=200, help="Trend plots of the axes that moved most."),
    ] = 12,
    machines: Annotated[
        int,
        typer.Option(
            min=1,
            max=10_000,
            help="The most machines in the grid; a larger fleet lists those that need "
            "attention, the most severe first.",
        ),
    ] = 500,
    warning: WarningOption = None,
    critical: CriticalOption = None,
    store: StoreOption = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> Outcome:
    """The fleet at a glance as one HTML file: machines × axes, outliers, trends.

    Each cell is an axis of a machine's latest measurement: its verdict and the change
    since the machine's baseline, coloured by the worst of the verdict (check, fault),
    the change against the limits, and an outlier of the machine's type. Then the
    outliers, then the trends of the axes that moved most. The file opens offline (no
    script, images inside).

    Exit code 0: every axis ok; 1: a warning (verdict check, a change beyond the warning
    limit, an outlier); 3: critical (verdict fault, a change beyond the critical limit);
    2: bad input.

    Example: ncmeasure store report -o fleet.html
    """
    from ncmeasure.store.report import fleet_report, write_fleet_report

    chosen = limits(warning, critical)
    bar, update = progress_bar(quiet)
    with bar or contextlib.nullcontext(), open_store(store, write=False) as fleet:
        if update is not None:
            update("reading the fleet", None)
        shown = fleet_report(fleet, chosen, grid=machines)
        written = write_fleet_report(
            fleet,
            shown,
            output,
            trends=trends,
            progress=None if update is None else lambda d, n: update("trend plots", d / n),
        )
    counts = ", ".join(f"{shown.counts[s]} {s}" for s in ("ok", "warning", "critical"))
    console().print(f"{shown.machines} machine(s): {counts}; {shown.outlier_count} outlier(s)")
    console().print(f"wrote {written}")
    return shown.status


@store_app.command("refresh")
@handle_errors
def store_refresh_command(
    every: Annotated[
        bool,
        typer.Option(
            "--all", help="Compare every machine again, also those whose change is current."
        ),
    ] = False,
    store: StoreOption = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Store each machine's change since its baseline where it is missing or out of date.

    Adding a measurement compares the machine's latest measurement with its baseline
    and stores the diagnosis of the change, which `store report`, the dashboard, MQTT
    and OPC UA read instead of comparing again. A store filled before these rows
    existed, or by an ncmeasure whose diagnosis differs (another diagnosis version),
    lacks them: every reading of the fleet then compares those machines again, which is
    slow for a large fleet, and logs how many. This command compares them once and
    stores the result, 50 machines per transaction (an interrupted run keeps what it
    did; run it again to go on). Then it rebuilds each machine's summary row and judges
    every machine's status in the fleet as it is now, which `store list --status` and
    the counts read. The status does not change, only how fast it is read.

    Example: ncmeasure store refresh --store postgresql://ncm@db/fleet
    """
    chosen = "every machine" if every else "machines without a current change"
    bar, update = progress_bar(quiet)
    with bar or contextlib.nullcontext(), open_store(store, write=True) as fleet:
        if update is not None:
            update(f"finding {chosen}", None)
        done = fleet.refresh_changes(
            every=every,
            progress=None if update is None else lambda d, n: update("comparing", d / n),
        )
        if update is not None:
            update("judging the fleet", None)
        summarised = fleet.refresh_summaries()
        where = fleet.where
    console().print(f"stored the change since the baseline of {done} machine(s) in {where}")
    console().print(f"summarised {summarised} machine(s) and their status")


@store_app.command("export")
@handle_errors
def store_export_command(
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="JSON-lines file (default: stdout).")
    ] = None,
    store: StoreOption = None,
) -> None:
    """Write the whole store as JSON lines: a backup, or to move it (SQLite → PostgreSQL).

    Example: ncmeasure store export -o fleet.jsonl; ncmeasure store import fleet.jsonl
    --store postgresql://ncm@db/fleet
    """
    from ncmeasure.files import replace_text
    from ncmeasure.store.transfer import export_lines

    with open_store(store, write=False) as fleet:
        if output is None:
            for line in export_lines(fleet):
                sys.stdout.write(line + "\n")
            return
        with replace_text(output) as file:
            count = 0
            for line in export_lines(fleet):
                file.write(line + "\n")
                count += 1
    console(stderr=True).print(f"wrote {count - 1} measurement(s) to {output}")


@store_app.command("import")
@handle_errors
def store_import_command(
    source: Annotated[Path, typer.Argument(help="JSON-lines file of `store export`.")],
    store: StoreOption = None,
) -> None:
    """Add every measurement of an export (those already stored are skipped)."""
    from ncmeasure.store.transfer import import_lines

    try:
        stream = source.open("rb")
    except OSError as exc:
        raise ConfigError(f"{source}: cannot be read ({exc.strerror or exc})") from exc
    with stream, open_store(store, write=True) as fleet:
        added, existing = import_lines(fleet, stream, str(source))
        where = fleet.where
    console().print(f"added {added} measurement(s) to {where}; {existing} were already stored")
