"""The bus the CANopen link opens: on python-can's virtual interface the link's own echo
comes first, as on a real bus."""

from __future__ import annotations

import queue
import uuid

import can
import can.interfaces.virtual as virtual

from ncmeasure.links.canopen.bus import open_bus

SYNC = 0x080
TPDO1 = 0x181


class _AnsweringQueue(queue.Queue):
    """A drive's receive queue that answers a SYNC before its put returns.

    It stands for the drive's thread being scheduled at once while the sender is
    preempted between two receivers: the worst order a loaded computer produces.
    """

    def __init__(self, answer: can.BusABC) -> None:
        super().__init__()
        self.answer = answer

    def put(self, item, block=True, timeout=None):
        super().put(item, block, timeout)
        if item.arbitration_id == SYNC:
            self.answer.send(
                can.Message(arbitration_id=TPDO1, data=b"\x01\x02", is_extended_id=False)
            )


def test_own_sync_echo_precedes_an_answer_from_a_bus_opened_earlier():
    channel = f"echo-order-{uuid.uuid4().hex}"
    drive = can.Bus(interface="virtual", channel=channel)  # opened first: first in the channel
    try:
        link = open_bus(
            channel, {"interface": "virtual", "receive_own_messages": True}, "link.interface"
        )
        try:
            with virtual.channels_lock:
                queues = virtual.channels[channel]
                answering = _AnsweringQueue(drive)
                queues[queues.index(drive.queue)] = answering
                drive.queue = answering
            for _ in range(3):
                link.send(can.Message(arbitration_id=SYNC, data=b"", is_extended_id=False))
            order = [link.recv(timeout=1.0) for _ in range(6)]
            assert [m.arbitration_id for m in order] == [SYNC, TPDO1] * 3
            assert [m.is_rx for m in order] == [False, True] * 3
        finally:
            link.shutdown()
    finally:
        drive.shutdown()


def test_other_receivers_still_get_every_frame_once():
    channel = f"echo-order-{uuid.uuid4().hex}"
    a = can.Bus(interface="virtual", channel=channel)
    link = open_bus(
        channel, {"interface": "virtual", "receive_own_messages": True}, "link.interface"
    )
    b = can.Bus(interface="virtual", channel=channel)
    try:
        link.send(can.Message(arbitration_id=SYNC, data=b"", is_extended_id=False))
        for rx in (a, b):
            got = rx.recv(timeout=1.0)
            assert got is not None and got.arbitration_id == SYNC and got.is_rx
            assert rx.recv(timeout=0.05) is None
        own = link.recv(timeout=1.0)
        assert own is not None and not own.is_rx
        assert link.recv(timeout=0.05) is None
    finally:
        for bus in (a, link, b):
            bus.shutdown()
