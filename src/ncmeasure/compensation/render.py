"""Compensation files: friction points -> the text a controller or drive takes.

Each controller has a template under ``templates/compensation/``; it gets a
frozen view model whose numbers were computed and checked here (limits of the
controller, ranges of its data types) and only chooses the words. The Jinja
environment is the program generator's sandbox.

* ``twincat``: the friction compensation table of the TwinCAT CNC axis
  compensation list (``frict_comp.*``, P-COMP-00041 … 00062), one table per
  axis for both directions (velocities ≥ 0);
* ``linuxcnc``: a HAL snippet, commanded velocity (``ddt`` of the position
  command) -> ``lincurve`` (friction current over signed velocity) -> ``sum2``
  added to the current command;
* ``cia402``: the torque offset 0x60B2 of a vertical axis' drive (gravity), as
  a reviewable list of SDO writes.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import jinja2

from ncmeasure._version import __version__
from ncmeasure.compensation.points import AxisFriction, axis_friction, select_axes, speed_grid
from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, DialectError
from ncmeasure.formats.results import Results
from ncmeasure.program.sandbox import TemplateSandbox
from ncmeasure.resources import builtin_dir

__all__ = [
    "CONTROLLERS",
    "DEFAULT_POINTS",
    "MAX_POINTS",
    "render_compensation",
]

Controller = Literal["twincat", "linuxcnc", "cia402"]
CONTROLLERS: tuple[Controller, ...] = ("twincat", "linuxcnc", "cia402")

DEFAULT_POINTS: dict[str, int] = {"twincat": 20, "linuxcnc": 15}
"""Table points by default: TwinCAT's default table size P-COMP-00062 (20, the (0, 0)
entry included); LinuxCNC: 7 per direction and the zero."""
MAX_POINTS: dict[str, int] = {"twincat": 1000, "linuxcnc": 16}
"""Most points: lincurve takes 16 (lincurve(9)); TwinCAT's table size is the axis'
P-COMP-00062, which can be raised above 20 (a sanity limit here)."""
MIN_POINTS: dict[str, int] = {"twincat": 3, "linuxcnc": 5}
"""Fewest points: the zero entry and two measured speeds per direction."""

INT16 = (-32768, 32767)
SGN32 = (-(2**31), 2**31 - 1)

UM_S_PER_MM_MIN = 1000.0 / 60.0
MM_S_PER_MM_MIN = 1.0 / 60.0


# --- view models -------------------------------------------------------------------------


@dataclass(frozen=True)
class Header:
    """Where the numbers come from."""

    results: str
    machine: str
    recorded: str
    analysed: str
    version: str
    config_hash: str
    averaged: tuple[str, ...] = ()
    """Per axis: the positions averaged and how much they differ (the spread along the travel)."""


@dataclass(frozen=True)
class TableEntry:
    """One TwinCAT table entry: ``frict_comp.table[index].in`` / ``.out``."""

    index: int
    in_um_s: int
    out: int
    speed_mm_min: float
    current_a: float
    positive_a: float
    negative_a: float


@dataclass(frozen=True)
class TwinCatAxis:
    name: str
    entries: tuple[TableEntry, ...]
    table_entries: int
    speed_range_mm_min: tuple[float, float]
    models: str
    below_fit_mm_min: float | None
    asymmetry_percent: float
    offset_a: float | None


@dataclass(frozen=True)
class CurvePoint:
    """One lincurve breakpoint: ``x-val-NN`` (mm/s) -> ``y-val-NN`` (A)."""

    index: str
    x_mm_s: float
    y_a: float
    speed_mm_min: float


@dataclass(frozen=True)
class LinuxCncAxis:
    name: str
    prefix: str
    points: tuple[CurvePoint, ...]
    personality: int
    positive_range_mm_min: tuple[float, float]
    negative_range_mm_min: tuple[float, float]
    models: str
    offset_a: float | None


@dataclass(frozen=True)
class SdoWrite:
    """One SDO download of the torque offset 0x60B2:00 (INTEGER16, ‰ of rated torque)."""

    axis: str
    node_id: int
    value: int
    offset_a: float
    offset_nm: float | None
    rated_current_a: float
    cob_id: int
    data: str


@dataclass(frozen=True)
class CompensationView:
    header: Header
    controller: str
    units_per_a: float
    twincat: tuple[TwinCatAxis, ...] = ()
    linuxcnc: tuple[LinuxCncAxis, ...] = ()
    cia402: tuple[SdoWrite, ...] = ()


# --- numbers -----------------------------------------------------------------------------


def _models(friction: AxisFriction) -> str:
    parts = []
    for d in (friction.positive, friction.negative):
        names = sorted(set(d.models))
        parts.append(f"{d.direction}: {', '.join(names)} at {len(d.models)} position(s)")
    return "; ".join(parts)


def _below(friction: AxisFriction) -> float | None:
    values = [
        d.below_fit_mm_min
        for d in (friction.positive, friction.negative)
        if d.below_fit_mm_min is not None
    ]
    return max(values) if values else None


def _check(value: float, limits: tuple[int, int], what: str) -> int:
    number = round(value)
    if not limits[0] <= number <= limits[1]:
        raise ConfigError(f"{what}: {number} is outside {limits[0]}…{limits[1]}")
    return number


def _twincat_axis(friction: AxisFriction, points: int, units_per_a: float) -> TwinCatAxis:
    low, high = friction.common_range_mm_min
    if high <= low:
        raise ConfigError(
            f"axis {friction.axis}: the two directions share no measured speeds; the TwinCAT "
            "table (velocity ≥ 0, both directions) needs them"
        )
    entries = [TableEntry(0, 0, 0, 0.0, 0.0, 0.0, 0.0)]
    peak_difference = 0.0
    for speed in speed_grid(low, high, points - 1):
        positive = friction.current_a(friction.positive.friction(speed))
        negative = friction.current_a(friction.negative.friction(speed))
        current = (positive + negative) / 2
        if current:
            peak_difference = max(peak_difference, abs(positive - negative) / abs(current))
        what = f"axis {friction.axis}: frict_comp.table[{len(entries)}]"
        entries.append(
            TableEntry(
                index=len(entries),
                in_um_s=_check(speed * UM_S_PER_MM_MIN, SGN32, what + ".in"),
                out=_check(current * units_per_a, SGN32, what + ".out"),
                speed_mm_min=speed,
                current_a=current,
                positive_a=positive,
                negative_a=negative,
            )
        )
    speeds = [e.in_um_s for e in entries]
    if any(b <= a for a, b in itertools.pairwise(speeds)):
        raise ConfigError(
            f"axis {friction.axis}: {points} table points do not fit into the measured "
            f"{low:g}–{high:g} mm/min at 1 µm/s resolution; use fewer --points"
        )
    offset = friction.current_a(friction.offset) if friction.offset is not None else None
    return TwinCatAxis(
        name=friction.axis,
        entries=tuple(entries),
        table_entries=len(entries),
        speed_range_mm_min=(low, high),
        models=_models(friction),
        below_fit_mm_min=_below(friction),
        asymmetry_percent=100.0 * peak_difference,
        offset_a=offset,
    )


def _linuxcnc_axis(friction: AxisFriction, points: int) -> LinuxCncAxis:
    per_side = (points - 1) // 2
    curve: list[tuple[float, float]] = []
    neg = friction.negative
    for speed in reversed(speed_grid(*neg.speed_range_mm_min, per_side)):
        curve.append((-speed, -friction.current_a(neg.friction(speed))))
    curve.append((0.0, 0.0))
    pos = friction.positive
    for speed in speed_grid(*pos.speed_range_mm_min, per_side):
        curve.append((speed, friction.current_a(pos.friction(speed))))
    offset = friction.current_a(friction.offset) if friction.offset is not None else None
    return LinuxCncAxis(
        name=friction.axis,
        prefix=f"ncm-{friction.axis.lower()}",
        points=tuple(
            CurvePoint(f"{i:02d}", v * MM_S_PER_MM_MIN, y, v) for i, (v, y) in enumerate(curve)
        ),
        personality=len(curve),
        positive_range_mm_min=pos.speed_range_mm_min,
        negative_range_mm_min=neg.speed_range_mm_min,
        models=_models(friction),
        offset_a=offset,
    )


def _machine_axis(machine: MachineConfig | None, name: str) -> Any:
    if machine is None:
        return None
    return next((a for a in machine.axes if a.name == name), None)


def _sdo_write(friction: AxisFriction, machine: MachineConfig | None) -> SdoWrite:
    name = friction.axis
    if not friction.vertical:
        state = "not known to be vertical" if friction.vertical is None else "not vertical"
        raise ConfigError(
            f"axis {name} is {state} in the results: the torque offset 0x60B2 is written for "
            "vertical axes only (gravity); mark it vertical = true in the machine file and "
            "analyse again"
        )
    if friction.offset is None:
        raise ConfigError(
            f"axis {name}: the results hold no offset (both directions at equal speeds are "
            "needed to separate gravity from friction); no torque offset"
        )
    axis = _machine_axis(machine, name)
    if machine is None or axis is None:
        where = "--machine" if machine is None else f"the machine file ({name} is not in it)"
        raise ConfigError(
            f"axis {name}: the SDO write needs the drive's node id and the motor's rated "
            f"current from {where}"
        )
    node_id = axis.link.get("node_id")
    if not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise ConfigError(
            f"axis {name}: the machine file gives no CANopen node id (link = {{ node_id = … }})"
        )
    rated = axis.link.get("rated_current_a") or axis.rated_current_a
    if not isinstance(rated, int | float) or not rated > 0:
        raise ConfigError(
            f"axis {name}: the torque offset 0x60B2 is in ‰ of the rated torque; the machine "
            "file gives no rated_current_a to convert the measured offset"
        )
    offset_a = friction.current_a(friction.offset)
    value = _check(1000.0 * offset_a / rated, INT16, f"axis {name}: 0x60B2")
    data = value.to_bytes(2, "little", signed=True)
    # CiA 301 expedited SDO download of 2 bytes: command byte 0x2B, index LSB first,
    # sub-index, data LSB first, 2 unused bytes.
    frame = bytes([0x2B, 0xB2, 0x60, 0x00, *data, 0x00, 0x00])
    offset_nm = (
        friction.offset
        if friction.unit == "Nm"
        else (
            friction.offset * friction.torque_constant_nm_per_a
            if friction.torque_constant_nm_per_a
            else None
        )
    )
    return SdoWrite(
        axis=name,
        node_id=node_id,
        value=value,
        offset_a=offset_a,
        offset_nm=offset_nm,
        rated_current_a=float(rated),
        cob_id=0x600 + node_id,
        data=frame.hex().upper(),
    )


# --- rendering ---------------------------------------------------------------------------


def _fixed(value: float, decimals: int = 3) -> str:
    text = f"{value:.{decimals}f}"
    if text.startswith("-") and float(text) == 0.0:
        text = text[1:]
    return text


def _hex(value: int, digits: int = 4) -> str:
    return f"0x{value:0{digits}X}"


def _environment(template_dirs: Sequence[Path]) -> TemplateSandbox:
    folders = [Path(d) / "compensation" for d in template_dirs]
    folders.append(builtin_dir("templates") / "compensation")
    env = TemplateSandbox(
        loader=jinja2.FileSystemLoader([str(f) for f in folders]),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
    )
    env.add_filters(fixed=_fixed, hex=_hex)
    env.start(0)
    return env


def _averaged(friction: AxisFriction) -> str:
    """What the table averaged over for one axis, and how much that hides."""
    parts = []
    for d in (friction.positive, friction.negative):
        low, high = d.speed_range_mm_min
        where = ", ".join(f"{p:g}" for p in d.positions_mm)
        spread = max(d.spread_percent(low), d.spread_percent(high))
        parts.append(
            f"{d.direction} averaged over {len(d.positions_mm)} position(s) ({where} mm), "
            f"which differ by up to {spread:.1f} % (max − min)/mean"
        )
    return f"axis {friction.axis}: " + "; ".join(parts)


def _header(results: Results, source: str, frictions: Sequence[AxisFriction] = ()) -> Header:
    info = results.recording
    return Header(
        results=source,
        machine=info.machine or "(unnamed)",
        recorded=info.start_utc or "(unknown)",
        analysed=results.created_utc,
        version=__version__,
        config_hash=info.config_hash or "(none)",
        averaged=tuple(_averaged(f) for f in frictions),
    )


def refuse_faults(results: Results, names: Sequence[str], *, force: bool = False) -> None:
    """Refuse to compensate an axis whose verdict is ``fault``, unless ``force``.

    A friction table averages the positions; on an axis with an assembly fault it
    would feed the fault's friction forward as if it were the machine's.

    Raises:
        ConfigError: an axis' verdict is fault and ``force`` is not set.
    """
    if force:
        return
    for name in names:
        axis = results.axes.get(name)
        if axis is not None and axis.verdict.level == "fault":
            raise ConfigError(
                f"axis {name}: the verdict is fault ({axis.verdict.reason}); a friction table "
                "would compensate the fault, not the machine. Repair and measure again, or "
                "give --force to write it anyway"
            )


def render_compensation(
    results: Results,
    controller: str,
    *,
    axes: Sequence[str] | None = None,
    points: int | None = None,
    machine: MachineConfig | None = None,
    units_per_a: float = 1000.0,
    source: str = "results.json",
    template_dirs: Sequence[Path] = (),
    force: bool = False,
) -> str:
    """The compensation file of one controller from the results of one measurement.

    Args:
        results: The analysed measurement.
        controller: ``twincat``, ``linuxcnc`` or ``cia402``.
        axes: Axes to compensate (default: every analysed axis; ``cia402``: every
            vertical one).
        points: Table points per axis (``twincat``: the entries, (0, 0) included,
            default 20; ``linuxcnc``: lincurve breakpoints, default 15, at most 16).
        machine: The machine file (``cia402``: node ids and rated currents).
        units_per_a: ``twincat``: drive current units of ``table[i].out`` per ampere
            (default 1000: mA).
        source: The results file's name, for the header.
        template_dirs: Folders with a ``compensation/`` folder of own templates, searched
            before the built-in ones.
        force: Compensate an axis whose verdict is fault too (:func:`refuse_faults`).

    Raises:
        ConfigError: an unknown controller, points out of the controller's limits, an
            axis without a friction model, a non-vertical axis or missing drive data for
            ``cia402``; an axis whose verdict is fault without ``force``.
        DialectError: a template fails.
    """
    if controller not in CONTROLLERS:
        raise ConfigError(
            f"unknown controller {controller!r} for a compensation (known: "
            f"{', '.join(CONTROLLERS)})"
        )
    if controller == "cia402":
        if points is not None:
            raise ConfigError("--points does not apply to cia402 (one torque offset per axis)")
    else:
        count = DEFAULT_POINTS[controller] if points is None else points
        if not MIN_POINTS[controller] <= count <= MAX_POINTS[controller]:
            raise ConfigError(
                f"{controller}: --points {count} is outside "
                f"{MIN_POINTS[controller]}…{MAX_POINTS[controller]}"
            )
    if not math.isfinite(units_per_a) or units_per_a <= 0:
        raise ConfigError(f"--units-per-a {units_per_a:g}: must be a positive number")
    names = select_axes(results, axes)
    if controller == "cia402" and not axes:
        names = [n for n in names if results.axes[n].vertical]
        if not names:
            raise ConfigError(
                "no axis of the results is vertical: the torque offset 0x60B2 is written for "
                "vertical axes only"
            )
    refuse_faults(results, names, force=force)
    frictions = [axis_friction(results, name) for name in names]
    header = _header(results, source, frictions)
    if controller == "twincat":
        view = CompensationView(
            header,
            controller,
            units_per_a,
            twincat=tuple(_twincat_axis(f, count, units_per_a) for f in frictions),
        )
    elif controller == "linuxcnc":
        view = CompensationView(
            header,
            controller,
            units_per_a,
            linuxcnc=tuple(_linuxcnc_axis(f, count) for f in frictions),
        )
    else:
        view = CompensationView(
            header, controller, units_per_a, cia402=tuple(_sdo_write(f, machine) for f in frictions)
        )
    env = _environment(template_dirs)
    try:
        return env.get_template(f"{controller}.j2").render(view=view)
    except jinja2.TemplateError as exc:
        raise DialectError(f"compensation template {controller}.j2: {exc}") from exc
