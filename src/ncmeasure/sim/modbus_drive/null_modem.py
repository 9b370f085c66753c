"""A serial null modem for Modbus RTU without hardware: two pseudo-terminals wired together."""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty
from collections.abc import Iterator

__all__ = ["pty_null_modem"]


@contextlib.contextmanager
def pty_null_modem() -> Iterator[tuple[str, str]]:
    """Two pseudo-terminals wired to each other, like a null-modem cable (POSIX).

    Yields the two device paths: a server opens one, a client the other.
    Bytes written to either arrive at the other; the baud rate is not emulated.
    """
    master_a, slave_a = os.openpty()
    master_b, slave_b = os.openpty()
    for fd in (slave_a, slave_b):
        tty.setraw(fd)
    stop = threading.Event()

    def relay() -> None:
        while not stop.is_set():
            try:
                readable, _, _ = select.select([master_a, master_b], [], [], 0.05)
            except (OSError, ValueError):
                return
            for fd in readable:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                with contextlib.suppress(OSError):
                    os.write(master_b if fd == master_a else master_a, data)

    thread = threading.Thread(target=relay, name="ncmeasure-null-modem", daemon=True)
    thread.start()
    try:
        yield os.ttyname(slave_a), os.ttyname(slave_b)
    finally:
        stop.set()
        thread.join(timeout=2)
        for fd in (master_a, slave_a, master_b, slave_b):
            with contextlib.suppress(OSError):
                os.close(fd)
