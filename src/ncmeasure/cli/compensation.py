"""The compensation commands: friction compensation files, and the CiA 402 offsets applied."""

import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from ncmeasure.cli._app import app, console, handle_errors
from ncmeasure.cli._options import given, settings


@app.command("compensation")
@handle_errors
def compensation_command(
    results_file: Annotated[
        Path, typer.Argument(help="results.json of the measurement (`ncmeasure analyze`).")
    ],
    controller: Annotated[
        str,
        typer.Option(
            help="twincat: TwinCAT CNC friction table (frict_comp.*); linuxcnc: HAL snippet "
            "(ddt -> lincurve -> sum2); cia402: torque offset 0x60B2 of vertical axes as SDO "
            "writes."
        ),
    ],
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="File to write (default: print it).")
    ] = None,
    only: Annotated[
        list[str] | None,
        typer.Option(
            "--axis",
            metavar="AXIS",
            help="Compensate only this axis (repeat for several; default: every analysed axis, "
            "cia402: every vertical one).",
        ),
    ] = None,
    points: Annotated[
        int | None,
        typer.Option(
            help="Table points per axis: twincat 3–1000 (default 20, the 0 entry included; "
            "more than 20 needs frict_comp.max_points), linuxcnc 5–16 (default 15)."
        ),
    ] = None,
    machine: Annotated[
        Path | None,
        typer.Option(help="Machine file; cia402 takes node_id and rated_current_a from it."),
    ] = None,
    units_per_a: Annotated[
        float,
        typer.Option(
            help="twincat: drive current units of table[i].out per ampere (1000: mA); check "
            "the unit of dig_drv.act_torque for your drive."
        ),
    ] = 1000.0,
    force: Annotated[
        bool,
        typer.Option(
            "--force",
            help="Write the table also for an axis whose verdict is fault (it would "
            "compensate the fault).",
        ),
    ] = False,
) -> None:
    """Friction compensation for the controller, from a measurement, with sources and limits.

    Per axis and direction the friction the analysis found (its model, the measured points
    in the Stribeck region), averaged over the positions, at speeds between the slowest
    and the fastest measured (denser at low speed), as motor current. The header of the
    file names the manual pages behind every parameter and what the file leaves out;
    docs/shop-floor.md explains how to apply each. Review before loading it; a cia402 file
    is then written to the drives by `ncmeasure apply-compensation FILE --machine M --yes`.

    An axis the analysis could not fit in both directions, not vertical for cia402, or
    whose verdict is fault (unless --force), is refused in one line (exit 2). The file's
    header says per axis which positions it averaged and how much they differ.

    Example: ncmeasure compensation run1.results.json --controller twincat --axis X -o X.lis
    """
    from ncmeasure.compensation import render_compensation
    from ncmeasure.config import load_machine
    from ncmeasure.files import write_whole
    from ncmeasure.formats.results import load_results

    results = load_results(results_file)
    text = render_compensation(
        results,
        controller,
        axes=only,
        points=points,
        machine=load_machine(machine) if machine is not None else None,
        units_per_a=units_per_a,
        source=results_file.name,
        force=force,
    )
    if output is None:
        sys.stdout.write(text)
        return
    write_whole(output, text, newline="\n")
    console().print(f"wrote {output}")


@app.command("apply-compensation")
@handle_errors
def apply_compensation_command(
    file: Annotated[
        Path,
        typer.Argument(
            help="The torque offsets to write: the file of `ncmeasure compensation "
            "--controller cia402`, reviewed."
        ),
    ],
    machine: Annotated[
        Path,
        typer.Option(
            help="Machine file: its [link] (type canopen) and the axes' node ids, as for "
            "`ncmeasure record`.",
            show_default=False,
        ),
    ],
    yes: Annotated[
        bool,
        typer.Option("--yes", help="Write. Without it nothing is sent: the writes are listed."),
    ] = False,
    interface: Annotated[
        str | None,
        typer.Option(
            help="python-can interface (socketcan, pcan, ...), over the machine file's.",
            rich_help_panel="CANopen",
        ),
    ] = None,
    channel: Annotated[
        str | None, typer.Option(help="python-can channel.", rich_help_panel="CANopen")
    ] = None,
    bitrate: Annotated[
        int | None, typer.Option(help="Bit rate in bit/s.", rich_help_panel="CANopen")
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Any other link setting, KEY=VALUE (e.g. sdo_timeout_s=2).",
            metavar="KEY=VALUE",
        ),
    ] = None,
) -> None:
    """Write the torque offset 0x60B2 of vertical axes to their CiA 402 drives over SDO.

    Reads the reviewed file of `ncmeasure compensation --controller cia402`, checks it
    against the machine file (CANopen link, each axis with the node id the file names)
    and lists what it would write. With --yes it writes each axis: the value before is
    read, the new one written, and read back; another value read back is an error. Only
    0x60B2:00 is ever written; no NMT, no SYNC, no "store parameters": a drive keeps the
    offset until it is switched off unless you store it (its manual says how).

    Exit code 0: listed, or written and read back; 2: bad input; 4: the bus or a drive
    failed (the line says what was written before).

    Example: ncmeasure apply-compensation z-offset.toml --machine machine.toml --yes
    """
    from ncmeasure.config import load_machine
    from ncmeasure.formats.offsets import read_offset_file
    from ncmeasure.links.canopen.offsets import apply_offsets, link_for_offsets

    writes = read_offset_file(file)
    overrides = given(interface=interface, channel=channel, bitrate=bitrate)
    overrides.update(settings(set_ or [], example="--set sdo_timeout_s=2"))
    link = link_for_offsets(writes, load_machine(machine), overrides)
    bus = (
        f"interface {link.interface or '(python-can config)'}, channel "
        f"{link.channel or '(default)'}, {link.bitrate} bit/s"
    )
    if not yes:
        _list_writes(writes, file, bus)
        return
    done = apply_offsets(writes, link, on_written=_print_written)
    console().print(
        f"wrote {len(done)} torque offset(s) over CANopen ({bus}); a drive keeps them until "
        "it is switched off unless it stores them"
    )


def _list_writes(writes: list[Any], file: Path, bus: str) -> None:
    """What --yes would write, and that nothing was sent."""
    console().print(f"{len(writes)} torque offset(s) of {file} over CANopen ({bus}):")
    for write in writes:
        console().print(
            f"  axis {write.axis}: node {write.node_id}, 0x60B2:00 = {write.value} "
            f"(‰ of the rated torque, {write.value / 10:g} %)"
        )
    console().print(
        "nothing was sent: review the file, then add --yes to write (each value is read "
        "before and read back after)"
    )


def _print_written(done: Any) -> None:
    """One line per offset written: the value before, written, and read back."""
    w = done.write
    console().print(
        f"axis {w.axis}: node {w.node_id}, 0x60B2:00 was {done.before}, wrote {w.value}, "
        f"read back {done.after}"
    )
