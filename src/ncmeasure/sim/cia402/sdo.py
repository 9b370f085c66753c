"""The SDO server of a simulated CiA 402 drive: expedited and segmented transfers, aborts.

:class:`SdoServer` answers one request frame (8 bytes, CiA 301) with one
response frame: initiate download/upload, expedited or segmented (toggle bit,
sizes), abort. The objects are the drive's: the server asks it for an entry
(:meth:`~ncmeasure.sim.cia402.dictionary.Dictionary.find`), for the bytes an
upload returns (a dynamic object's value now) and to write. A failure is a
:class:`SdoAbortError` with its CiA 301 abort code; the fault switch
:meth:`~ncmeasure.sim.cia402.drive.SimulatedDrive.abort_sdo` adds
:class:`AbortRule` s.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ncmeasure.sim.cia402.dictionary import Entry

__all__ = [
    "ABORT_COMMAND",
    "ABORT_GENERAL",
    "ABORT_INCOMPATIBLE",
    "ABORT_LENGTH_HIGH",
    "ABORT_LENGTH_LOW",
    "ABORT_NOT_MAPPABLE",
    "ABORT_NO_DATA",
    "ABORT_NO_OBJECT",
    "ABORT_NO_SUBINDEX",
    "ABORT_PDO_LENGTH",
    "ABORT_READ_ONLY",
    "ABORT_TOGGLE",
    "ABORT_UNSUPPORTED",
    "ABORT_VALUE_RANGE",
    "ABORT_WRITE_ONLY",
    "AbortRule",
    "SdoAbortError",
    "SdoServer",
]

# SDO abort codes (CiA 301) the server uses.
ABORT_TOGGLE = 0x05030000
ABORT_COMMAND = 0x05040001
ABORT_UNSUPPORTED = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_INCOMPATIBLE = 0x06040043
ABORT_LENGTH_HIGH = 0x06070012
ABORT_LENGTH_LOW = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_GENERAL = 0x08000000
ABORT_NO_DATA = 0x08000024


class SdoAbortError(Exception):
    """An SDO transfer the drive aborts, with its CiA 301 abort code."""

    def __init__(self, code: int) -> None:
        super().__init__(f"SDO abort 0x{code:08X}")
        self.code = code


@dataclass
class AbortRule:
    """Abort transfers of an object (None: any) with ``code``: a fault switch for tests."""

    index: int | None
    subindex: int | None
    code: int
    upload: bool
    download: bool


@dataclass
class _Transfer:
    """A segmented SDO transfer in progress."""

    index: int
    subindex: int
    upload: bool
    data: bytearray = field(default_factory=bytearray)
    size: int | None = None
    toggle: int = 0


class SdoServer:
    """Answers SDO requests with the drive's objects (called under the drive's lock).

    Args:
        find: The entry of an object; raises :class:`SdoAbortError` when there is none.
        read: The bytes an upload of an object returns (given its entry).
        write: Writes an object (the drive's rules); raises :class:`SdoAbortError`.
    """

    def __init__(
        self,
        find: Callable[[int, int], Entry],
        read: Callable[[int, int, Entry], bytes],
        write: Callable[[int, int, bytes], None],
    ) -> None:
        self._find = find
        self._read = read
        self._write = write
        self._transfer: _Transfer | None = None
        self.rules: list[AbortRule] = []
        """The :meth:`~ncmeasure.sim.cia402.drive.SimulatedDrive.abort_sdo` rules."""

    def reset(self) -> None:
        """Forget a transfer in progress (the drive was reset)."""
        self._transfer = None

    def answer(self, req: bytes) -> bytes | None:
        """The response to one request (8 bytes); None for an abort from the client."""
        command = req[0]
        ccs = command >> 5
        index, subindex = struct.unpack_from("<HB", req, 1)
        try:
            if ccs == 1:
                return self._initiate_download(command, index, subindex, req)
            if ccs == 0:
                return self._download_segment(command, req)
            if ccs == 2:
                return self._initiate_upload(index, subindex)
            if ccs == 3:
                return self._upload_segment(command)
            if ccs == 4:
                self._transfer = None
                return None
            raise SdoAbortError(ABORT_COMMAND)
        except SdoAbortError as abort:
            if ccs in (0, 3) and self._transfer is not None:
                index, subindex = self._transfer.index, self._transfer.subindex
            self._transfer = None
            return struct.pack("<BHBI", 0x80, index, subindex, abort.code)

    def _check_rules(self, index: int, subindex: int, upload: bool) -> None:
        for rule in self.rules:
            if (
                rule.index in (None, index)
                and rule.subindex in (None, subindex)
                and (rule.upload if upload else rule.download)
            ):
                raise SdoAbortError(rule.code)

    def _initiate_download(self, command: int, index: int, subindex: int, req: bytes) -> bytes:
        self._check_rules(index, subindex, upload=False)
        self._find(index, subindex)
        if command & 0x02:  # expedited
            size = 4 - ((command >> 2) & 0x3) if command & 0x01 else 4
            self._write(index, subindex, req[4 : 4 + size])
        else:
            size_known = struct.unpack_from("<I", req, 4)[0] if command & 0x01 else None
            self._transfer = _Transfer(index, subindex, upload=False, size=size_known)
        return struct.pack("<BHB4x", 0x60, index, subindex)

    def _download_segment(self, command: int, req: bytes) -> bytes:
        transfer = self._transfer
        if transfer is None or transfer.upload:
            raise SdoAbortError(ABORT_COMMAND)
        toggle = (command >> 4) & 1
        if toggle != transfer.toggle:
            raise SdoAbortError(ABORT_TOGGLE)
        unused = (command >> 1) & 0x7
        transfer.data += req[1 : 8 - unused]
        transfer.toggle ^= 1
        if command & 0x01:  # last segment
            self._transfer = None
            if transfer.size is not None and transfer.size != len(transfer.data):
                raise SdoAbortError(
                    ABORT_LENGTH_LOW if len(transfer.data) < transfer.size else ABORT_LENGTH_HIGH
                )
            self._write(transfer.index, transfer.subindex, bytes(transfer.data))
        return struct.pack("<B7x", 0x20 | toggle << 4)

    def _initiate_upload(self, index: int, subindex: int) -> bytes:
        self._check_rules(index, subindex, upload=True)
        entry = self._find(index, subindex)
        if not entry.readable:
            raise SdoAbortError(ABORT_WRITE_ONLY)
        data = self._read(index, subindex, entry)
        if not data:
            raise SdoAbortError(ABORT_NO_DATA)
        if len(data) <= 4:
            command = 0x43 | (4 - len(data)) << 2
            return struct.pack("<BHB", command, index, subindex) + data.ljust(4, b"\0")
        self._transfer = _Transfer(index, subindex, upload=True, data=bytearray(data))
        return struct.pack("<BHBI", 0x41, index, subindex, len(data))

    def _upload_segment(self, command: int) -> bytes:
        transfer = self._transfer
        if transfer is None or not transfer.upload:
            raise SdoAbortError(ABORT_COMMAND)
        toggle = (command >> 4) & 1
        if toggle != transfer.toggle:
            raise SdoAbortError(ABORT_TOGGLE)
        chunk, transfer.data = transfer.data[:7], transfer.data[7:]
        transfer.toggle ^= 1
        last = not transfer.data
        if last:
            self._transfer = None
        head = toggle << 4 | (7 - len(chunk)) << 1 | int(last)
        return bytes([head]) + bytes(chunk).ljust(7, b"\0")
