"""Axis resolution: which trace signal becomes which channel of which machine axis.

Every importer turns the signals of a controller trace into *candidates*
(this trace column could be that ncmeasure signal of that controller axis, in
this unit) and lets :func:`plan_channels` decide which become channels of the
recording: :func:`resolve_axes` names the controller's axes after the machine
axes, the machine file's screw leads and torque constants convert motor
speed and torque, and one measuring system is chosen per axis.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, TypeVar

from ncmeasure.errors import ConfigError, RecordingError
from ncmeasure.formats.axis import AXIS_NAME_PATTERN
from ncmeasure.recording import machine_axis
from ncmeasure.samples import SIGNAL_UNITS, Channel
from ncmeasure.traces.job import ImportJob

if TYPE_CHECKING:  # the machine-file models: exporting a recording reads no machine file
    from ncmeasure.config import MachineConfig

__all__ = ["Candidate", "Mapped", "Needs", "plan_channels", "plan_sources", "resolve_axes"]

_S = TypeVar("_S")


Needs = Literal["", "screw_lead", "torque_constant"]


@dataclass(frozen=True)
class Candidate:
    """A trace signal that can become an ncmeasure channel.

    Attributes:
        source: The signal as the trace names it.
        axis_id: The controller's axis (an index such as ``"1"`` or a name).
        signal: The ncmeasure signal (a key of ``SIGNAL_UNITS``).
        factor: Multiplies the trace values into ncmeasure units (before ``needs``).
        needs: Machine data the conversion needs: ``screw_lead`` (motor rpm
            to mm/min) or ``torque_constant`` (Nm to A).
        rank: Lower wins when several signals give the same channel; it
            also decides the measuring system of an axis (see below).
        conversion: How the unit is converted, for the report.
        measuring_system: The measuring system (encoder) whose value this
            is, e.g. ``"measuring system 2"``; empty for a value tied to
            none (a current, a motor speed). The channels of one axis that
            come from a measuring system all come from the same one: that of
            the best-ranked such candidate that is imported. A candidate of
            another measuring system of that axis is not imported.
        measuring_system_reason: Why this measuring system is the one to use
            if it is chosen, for the report ("the command position ... refers
            to it").
    """

    source: str
    axis_id: str
    signal: str
    factor: float = 1.0
    needs: Needs = ""
    rank: int = 0
    conversion: str = ""
    measuring_system: str = ""
    measuring_system_reason: str = ""


@dataclass(frozen=True)
class Mapped:
    """A candidate that became a channel, with the factor that converts its values."""

    candidate: Candidate
    channel: Channel
    factor: float
    conversion: str


def _id_order(ids: Sequence[str]) -> list[str]:
    numeric = sorted((i for i in ids if i.isdigit()), key=int)
    return numeric + [i for i in ids if not i.isdigit()]


def resolve_axes(
    ids: Sequence[str],
    machine: MachineConfig | None,
    axis_names: Mapping[str, str] | None,
    report: list[str],
) -> dict[str, str]:
    """Machine axis names for controller axes; the ones left out are reported.

    ``axis_names`` decides alone when given; else controller axes named like a
    machine axis take that axis and the others take the remaining machine
    axes in order (numeric indices ascending); without a machine file a
    controller axis keeps a name that is a valid axis name and an index ``n``
    becomes ``An``.

    Raises:
        ConfigError: ``axis_names`` names an invalid or unknown axis, or two
            controller axes get the same name.
    """
    known = [a.name for a in machine.axes] if machine is not None else None
    result: dict[str, str] = {}
    if axis_names is not None:
        problems: list[str] = []
        for key, name in axis_names.items():
            if not re.fullmatch(AXIS_NAME_PATTERN, name):
                problems.append(
                    f"axis_names[{key!r}]: {name!r} is not an axis name (X, Y, Z1, ...)"
                )
            elif known is not None and name not in known:
                problems.append(
                    f"axis_names[{key!r}]: {name} is not an axis of the machine "
                    f"({', '.join(known)})"
                )
        targets = list(axis_names.values())
        for name in sorted({n for n in targets if targets.count(n) > 1}):
            problems.append(f"axis_names: more than one controller axis is mapped to {name}")
        if problems:
            raise ConfigError("axis_names does not fit", problems)
        for axis_id in ids:
            if axis_id in axis_names:
                result[axis_id] = axis_names[axis_id]
                report.append(f"controller axis {axis_id} -> {axis_names[axis_id]} (axis_names)")
            else:
                report.append(f"controller axis {axis_id}: not imported (not in axis_names)")
        for key in axis_names:
            if key not in ids:
                report.append(f"axis_names: controller axis {key!r} does not appear in the trace")
        return result
    if known is not None:
        free = list(known)
        for axis_id in ids:
            if axis_id in free:
                result[axis_id] = axis_id
                free.remove(axis_id)
                report.append(f"controller axis {axis_id} -> {axis_id} (same name in the machine)")
        for axis_id in _id_order([i for i in ids if i not in result]):
            if not free:
                report.append(
                    f"controller axis {axis_id}: not imported (the machine file has no further "
                    "axis; pass axis_names)"
                )
                continue
            result[axis_id] = free.pop(0)
            report.append(
                f"controller axis {axis_id} -> {result[axis_id]} (machine axes in order; "
                "pass axis_names to choose)"
            )
        return result
    used: set[str] = set()
    for axis_id in _id_order(ids):
        if re.fullmatch(AXIS_NAME_PATTERN, axis_id):
            name = axis_id
        elif axis_id.isdigit() and re.fullmatch(AXIS_NAME_PATTERN, f"A{int(axis_id)}"):
            name = f"A{int(axis_id)}"
        else:
            name = next(f"A{k}" for k in range(1, 10_000) if f"A{k}" not in used)
        if name in used:
            name = next(f"A{k}" for k in range(1, 10_000) if f"A{k}" not in used)
        used.add(name)
        result[axis_id] = name
        report.append(
            f"controller axis {axis_id} -> {name} (no machine file or axis_names; default name)"
        )
    return result


def plan_channels(candidates: Sequence[Candidate], job: ImportJob) -> list[Mapped]:
    """Decide which candidates become channels; report every decision.

    Returns:
        The channels, axis by axis in the order of the axes, signals in the
        order of ``SIGNAL_UNITS``.

    Raises:
        RecordingError: No candidate can be imported.
        ConfigError: ``axis_names`` does not fit (see :func:`resolve_axes`).
    """
    ids = list(dict.fromkeys(c.axis_id for c in candidates))
    axis_map = resolve_axes(ids, job.machine, job.axis_names, job.report)
    chosen: dict[Channel, Mapped] = {}
    # axis -> the candidate that decided the axis' measuring system
    systems: dict[str, Candidate] = {}
    for cand in sorted(candidates, key=lambda c: c.rank):
        axis = axis_map.get(cand.axis_id)
        if axis is None:
            job.note(f"{cand.source}: not imported (controller axis {cand.axis_id} has no name)")
            continue
        channel = Channel(axis, cand.signal, SIGNAL_UNITS[cand.signal])
        if channel in chosen:
            job.note(
                f"{cand.source}: not imported ({channel.name} already comes from "
                f"{chosen[channel].candidate.source})"
            )
            continue
        decided = systems.get(axis)
        if (
            cand.measuring_system
            and decided is not None
            and decided.measuring_system != cand.measuring_system
        ):
            job.note(
                f"{cand.source}: not imported (axis {axis} takes its values from "
                f"{decided.measuring_system}; this is {cand.measuring_system}, and the two "
                "are not mixed)"
            )
            continue
        factor = cand.factor
        conversion = cand.conversion or "no unit conversion"
        axis_config = machine_axis(job.machine, axis)
        where = "of the machine file" if job.machine is not None else "(no machine file given)"
        if cand.needs == "screw_lead":
            lead = axis_config.screw_lead_mm if axis_config is not None else None
            if lead is None:
                job.note(
                    f"{cand.source}: velocity not converted, not imported: motor speed in rpm "
                    f"needs screw_lead_mm of axis {axis} {where}"
                )
                continue
            factor *= lead
            conversion = (
                f"motor rpm x screw lead {lead:g} mm/rev = mm/min, assuming the motor "
                "drives the screw directly"
            )
        elif cand.needs == "torque_constant":
            k_t = axis_config.torque_constant_nm_per_a if axis_config is not None else None
            if k_t is None:
                job.note(
                    f"{cand.source}: torque not converted, not imported: Nm to A needs "
                    f"torque_constant_nm_per_a of axis {axis} {where}"
                )
                continue
            factor /= k_t
            conversion = f"torque Nm / torque constant {k_t:g} Nm/A = A"
        chosen[channel] = Mapped(cand, channel, factor, conversion)
        if cand.measuring_system and decided is None:
            systems[axis] = cand
    axis_order = list(dict.fromkeys(axis_map[i] for i in ids if i in axis_map))
    if job.machine is not None:
        names = [a.name for a in job.machine.axes]
        axis_order.sort(key=lambda a: names.index(a) if a in names else len(names))
    signal_order = list(SIGNAL_UNITS)
    mapped = sorted(
        chosen.values(),
        key=lambda m: (axis_order.index(m.channel.axis), signal_order.index(m.channel.signal)),
    )
    for axis in axis_order:
        if axis in systems:
            job.note(_measuring_system_sentence(axis, systems[axis], mapped, candidates, axis_map))
    for m in mapped:
        job.note(f"{m.channel.name} [{m.channel.unit}]: from {m.candidate.source} ({m.conversion})")
    if not mapped:
        raise RecordingError(
            f"{job.path}: no signal of the trace can be imported as an ncmeasure channel",
            job.report,
        )
    return mapped


def plan_sources(
    sources: Sequence[_S], candidates: Sequence[Candidate | None], job: ImportJob
) -> list[tuple[_S, Mapped]]:
    """:func:`plan_channels` over the sources (trace columns, curves) that have a candidate.

    Returns:
        Each source that becomes a channel, with its :class:`Mapped`, in the
        order of the channels.
    """
    pairs = [(s, c) for s, c in zip(sources, candidates, strict=True) if c is not None]
    mapped = plan_channels([c for _, c in pairs], job)
    by_candidate = {id(m.candidate): m for m in mapped}
    return sorted(
        ((s, by_candidate[id(c)]) for s, c in pairs if id(c) in by_candidate),
        key=lambda pair: mapped.index(pair[1]),
    )


def _quantity(signal: str) -> str:
    """``position_mm`` -> ``position``: the word for a signal in a report sentence."""
    return re.sub(r"_(mm_min|mm|a)$", "", signal).replace("_", " ")


def _measuring_system_sentence(
    axis: str,
    decider: Candidate,
    mapped: Sequence[Mapped],
    candidates: Sequence[Candidate],
    axis_map: Mapping[str, str],
) -> str:
    """``axis X: position and velocity from measuring system 2 (reason)``, and what it lacks."""
    system = decider.measuring_system
    taken = [
        m.channel.signal
        for m in mapped
        if m.channel.axis == axis and m.candidate.measuring_system == system
    ]
    offered = list(
        dict.fromkeys(
            c.signal for c in candidates if c.measuring_system and axis_map.get(c.axis_id) == axis
        )
    )
    lacking = [s for s in offered if s not in taken]
    taken.sort(key=lambda s: s != "position_mm")  # "position and velocity"
    words = " and ".join(_quantity(s) for s in taken)
    sentence = f"axis {axis}: {words} from {system} ({decider.measuring_system_reason})"
    if lacking:
        sentence += (
            f"; the trace has no {' and no '.join(_quantity(s) for s in lacking)} of {system}, "
            "and that of another measuring system is not mixed in"
        )
    return sentence
