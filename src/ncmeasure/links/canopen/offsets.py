"""The torque offset 0x60B2:00 of CiA 402 drives, written over SDO: ``apply-compensation``.

``ncmeasure compensation --controller cia402`` writes a list of SDO writes
(``[[sdo_write]]``, TOML) for the user to review;
:func:`~ncmeasure.formats.offsets.read_offset_file` reads it back as
:class:`OffsetWrite` entries. This module writes them with the machine file's
CANopen link settings, those ``ncmeasure record`` uses (``[link]`` interface,
channel, bitrate, bus_options, sdo_timeout_s; the axes' node ids):

* :func:`link_for_offsets` checks them against the machine file: a CANopen link
  that may send (not ``listen_only``), every axis in the file with the node id
  the machine file gives it;
* :func:`apply_offsets` writes, per axis: the value before (an SDO upload), the
  new value (an expedited download of 2 bytes, little-endian), and the value
  read back, which must be the one written.

Nothing else is sent: no NMT, no SYNC, no store-parameters command (0x1010). A
written offset lasts until the drive powers off unless it is stored (see the
drive's manual). Every failure is one :class:`~ncmeasure.errors.LinkError` line
that also says what was written before it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ncmeasure.config import MachineConfig
from ncmeasure.errors import ConfigError, LinkError, LinkTimeoutError, NcMeasureError
from ncmeasure.formats.offsets import TORQUE_OFFSET, OffsetWrite

if TYPE_CHECKING:
    from ncmeasure.links.canopen.settings import CanOpenSettings

__all__ = [
    "OffsetWritten",
    "apply_offsets",
    "link_for_offsets",
]

_ABORT_READ_ONLY = 0x06010002


@dataclass(frozen=True)
class OffsetWritten:
    """What the drive held before, and what it holds after the write."""

    write: OffsetWrite
    before: int
    after: int


def link_for_offsets(
    writes: Sequence[OffsetWrite], machine: MachineConfig, overrides: Mapping[str, Any]
) -> CanOpenSettings:
    """The machine file's CANopen link settings (with ``overrides``), checked for the writes.

    Returns:
        The :class:`~ncmeasure.links.canopen.settings.CanOpenSettings`.

    Raises:
        ConfigError: The machine file's link is not CANopen or only listens; its link
            settings are not valid; an axis of the file is not in the machine file or has
            another node id there.
    """
    from pydantic import ValidationError

    from ncmeasure.config import format_validation_error
    from ncmeasure.links.canopen.settings import CanOpenSettings

    table = dict(machine.link or {})
    link_type = table.pop("type", None)
    if link_type not in (None, "canopen"):
        raise ConfigError(
            f"the machine file's link is {link_type!r}: the torque offset 0x60B2 is written "
            "over CANopen ([link] type = 'canopen')"
        )
    table.update(overrides)
    try:
        settings = CanOpenSettings.model_validate({**table, "type": "canopen"})
    except ValidationError as exc:
        raise ConfigError(
            "the settings of the canopen link are not valid", format_validation_error(exc, "link")
        ) from exc
    if settings.listen_only:
        raise ConfigError(
            "link.listen_only: the machine file says the controller owns this bus and "
            "ncmeasure sends nothing on it; write 0x60B2 through the controller, or apply "
            "with --set listen_only=false when nothing else uses the drives' SDO channel"
        )
    axes = {a.name: a for a in machine.axes}
    for write in writes:
        axis = axes.get(write.axis)
        if axis is None:
            raise ConfigError(
                f"axis {write.axis} of the file is not in the machine file "
                f"({', '.join(axes)}): was the file made for another machine?"
            )
        node_id = axis.link.get("node_id")
        if node_id != write.node_id:
            raise ConfigError(
                f"axis {write.axis}: the file writes to node {write.node_id}, the machine file "
                f"names node {node_id}: make the file again from this machine file "
                "(ncmeasure compensation … --controller cia402 --machine …)"
            )
    return settings


def apply_offsets(
    writes: Sequence[OffsetWrite],
    settings: CanOpenSettings,
    *,
    on_written: Callable[[OffsetWritten], None] | None = None,
) -> list[OffsetWritten]:
    """Write each torque offset over SDO: read it, write it, read it back.

    Args:
        writes: From :func:`~ncmeasure.formats.offsets.read_offset_file`.
        settings: From :func:`link_for_offsets`.
        on_written: Called after each verified write.

    Raises:
        LinkError: The bus cannot be opened; a drive aborts the transfer (e.g. 0x60B2
            read-only over SDO); a drive reads back another value.
        LinkTimeoutError: A drive does not answer within ``sdo_timeout_s``.
    """
    import can
    import canopen
    from canopen.objectdictionary import ObjectDictionary
    from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

    from ncmeasure.links.canopen.bus import open_bus
    from ncmeasure.links.canopen.objects import sdo_error_text

    bus = open_bus(settings.channel, settings.bus_kwargs(), "link.interface")
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.1  # bounds how long disconnect waits for the receive thread
    done: list[OffsetWritten] = []
    try:
        network.connect()
        for write in writes:
            node = network.add_node(write.node_id, ObjectDictionary())  # type: ignore[no-untyped-call]
            node.sdo.RESPONSE_TIMEOUT = settings.sdo_timeout_s
            who = f"axis {write.axis} (node {write.node_id})"
            step = "reading 0x60B2:00"
            try:
                before = _int16(node.sdo.upload(*TORQUE_OFFSET), who)
                step = f"writing 0x60B2:00 = {write.value}"
                node.sdo.download(*TORQUE_OFFSET, write.value.to_bytes(2, "little", signed=True))
                step = "reading 0x60B2:00 back"
                after = _int16(node.sdo.upload(*TORQUE_OFFSET), who)
            except SdoAbortedError as exc:
                hint = (
                    "; this drive takes the torque offset only through an RPDO of the "
                    "controller (docs/shop-floor.md)"
                    if exc.code == _ABORT_READ_ONLY
                    else ""
                )
                raise LinkError(
                    f"{who}: {step} failed: {sdo_error_text(exc)}{hint}{_so_far(done)}"
                ) from exc
            except SdoCommunicationError as exc:
                raise LinkTimeoutError(
                    f"{who}: {step} failed: {sdo_error_text(exc, settings.sdo_timeout_s)}; "
                    f"check the node id, bitrate and wiring{_so_far(done)}"
                ) from exc
            if after != write.value:
                raise LinkError(
                    f"{who}: wrote 0x60B2:00 = {write.value} but read back {after} (it was "
                    f"{before}): the drive did not take the value as written{_so_far(done)}"
                )
            written = OffsetWritten(write, before, after)
            done.append(written)
            if on_written is not None:
                on_written(written)
    except NcMeasureError:  # LinkError is an OSError too: those above stay as they are
        raise
    except (can.CanError, OSError, ValueError) as exc:  # python-can's failures of a bus
        raise LinkError(f"the CAN bus failed ({type(exc).__name__}: {exc}){_so_far(done)}") from exc
    finally:
        network.disconnect()
    return done


def _int16(data: bytes, who: str) -> int:
    if len(data) != 2:
        raise LinkError(f"{who}: 0x60B2:00 answered {len(data)} bytes, not the 2 of an INTEGER16")
    return int.from_bytes(data, "little", signed=True)


def _so_far(done: Sequence[OffsetWritten]) -> str:
    """What was written before a failure, for its message."""
    if not done:
        return "; no other axis was written"
    items = ", ".join(f"axis {d.write.axis} {d.before} -> {d.after}" for d in done)
    return f"; written before it: {items}"
