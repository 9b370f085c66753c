"""``ncmeasure serve``: the application under uvicorn, until stopped.

The checks that can fail come first, as ncmeasure errors and before anything
listens: the host against the token (:func:`~ncmeasure.web.guard.check_binding`),
the store (it must exist and be an ncmeasure store), the address (in use?).
Then uvicorn serves on the socket bound here, ``on_ready`` learns the address
(port 0 picks a free port), and ``stop`` or Ctrl-C ends it.
"""

from __future__ import annotations

import logging
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass

import uvicorn

from ncmeasure.errors import ConfigError, StoreError
from ncmeasure.store import open_store
from ncmeasure.web.app import create_app
from ncmeasure.web.guard import HideToken, check_binding

__all__ = ["ServerInfo", "serve"]

_GRACE_S = 10


@dataclass(frozen=True)
class ServerInfo:
    """Where the running server listens."""

    host: str
    port: int
    token: bool
    """The server requires a token."""

    @property
    def url(self) -> str:
        """The dashboard's address, ``http://127.0.0.1:8000/``."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"


class _Server(uvicorn.Server):
    """uvicorn's server, telling when it listens and watching a stop event."""

    def __init__(
        self,
        config: uvicorn.Config,
        info: ServerInfo,
        on_ready: Callable[[ServerInfo], None] | None,
        stop: threading.Event | None,
    ) -> None:
        super().__init__(config)
        self._info = info
        self._on_ready = on_ready
        self._stop = stop

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets)
        if self.started and self._on_ready is not None:
            self._on_ready(self._info)

    async def on_tick(self, counter: int) -> bool:
        stop = self._stop is not None and self._stop.is_set()
        return await super().on_tick(counter) or stop


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        return socket.create_server((host, port), family=family, backlog=128)
    except OSError as exc:
        raise ConfigError(
            f"cannot listen on {host}:{port}: {exc.strerror or exc} (another port: --port)"
        ) from exc


def serve(
    url: str,
    host: str = "127.0.0.1",
    port: int = 8000,
    token: str | None = None,
    *,
    on_ready: Callable[[ServerInfo], None] | None = None,
    stop: threading.Event | None = None,
    log_level: str = "info",
) -> None:
    """Serve the dashboard and the REST API over the store until stopped (blocking).

    This is what ``ncmeasure serve`` calls. In the main thread Ctrl-C (SIGINT)
    and SIGTERM stop it gracefully; from any thread ``stop.set()`` does.

    Args:
        url: The store's URL (:func:`ncmeasure.store.store_url` resolves ``--store``).
        host: The address to listen on; anything but a loopback address needs ``token``.
        port: The TCP port; 0 picks a free one (``on_ready`` tells which).
        token: The secret every client must send (``Authorization: Bearer TOKEN``);
            at least 16 characters.
        on_ready: Called once the server accepts connections, with its address.
        stop: Set it to stop the server.
        log_level: uvicorn's log level (``info`` logs each request, the token hidden).

    Raises:
        ConfigError: A non-loopback host without a token, an unusable token,
            not a store URL, or the address cannot be bound (in use).
        StoreError: The store cannot be opened (missing, not an ncmeasure
            store, of a newer schema, unreachable).
    """
    check_binding(host, token)
    with open_store(url, write=False):
        pass  # fails here, in words, rather than inside uvicorn's startup
    app = create_app(url, token=token)
    sock = _bind(host, port)
    info = ServerInfo(host=host, port=int(sock.getsockname()[1]), token=token is not None)
    config = uvicorn.Config(
        app,
        log_level=log_level,
        lifespan="on",
        server_header=False,
        proxy_headers=False,
        timeout_graceful_shutdown=_GRACE_S,
    )
    hide = HideToken()
    access = logging.getLogger("uvicorn.access")
    access.addFilter(hide)
    try:
        _Server(config, info, on_ready, stop).run(sockets=[sock])
    except SystemExit as exc:  # uvicorn's way to say that the startup failed
        raise StoreError("the server could not start; the log above says why") from exc
    finally:
        access.removeFilter(hide)
        sock.close()
