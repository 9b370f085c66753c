"""The ``serve`` command: the fleet store as a web dashboard and a REST API."""

import os
import threading
from pathlib import Path
from typing import Annotated

import typer

from ncmeasure.cli._app import app, console, handle_errors, restore_signals, stop_on_signals
from ncmeasure.cli._options import StoreOption
from ncmeasure.errors import ConfigError

TOKEN_ENV = "NCMEASURE_TOKEN"


@app.command("serve")
@handle_errors
def serve_command(
    store: StoreOption = None,
    host: Annotated[
        str,
        typer.Option(help="Address to listen on; anything but loopback needs a token."),
    ] = "127.0.0.1",
    port: Annotated[
        int, typer.Option(min=0, max=65535, help="TCP port (0: a free one, printed).")
    ] = 8000,
    token_file: Annotated[
        Path | None,
        typer.Option(
            help="A file holding the token clients must send (at least 16 characters). "
            "Or set NCMEASURE_TOKEN. Needed for any address but loopback.",
        ),
    ] = None,
) -> None:
    """The fleet store as a web dashboard and a JSON REST API, until Ctrl-C.

    The dashboard: the fleet grid, a page per machine and per axis with the trends.
    The API lives under /api/v1 (machines, measurements, results, checks; POST adds a
    measurement), described at /openapi.json and /docs. On a loopback address (the
    default) it is open to this computer only; any other address needs a token, which
    clients send as "Authorization: Bearer TOKEN" (a browser opens URL?token=TOKEN once).
    The token is read from a file or the environment, never from the command line,
    where other users could see it.

    Example: ncmeasure serve --store postgresql://ncm@db/fleet --host 0.0.0.0
    --token-file /etc/ncmeasure/token
    """
    try:
        from ncmeasure.web import ServerInfo, serve
    except ImportError as exc:
        from ncmeasure.errors import DependencyError

        raise DependencyError(
            f"ncmeasure serve needs the package {exc.name!r}, which is missing "
            "(pip install 'ncmeasure[serve]')"
        ) from exc
    from ncmeasure.store import store_url

    token = _token(token_file)
    url = store_url(store)

    def ready(info: ServerInfo) -> None:
        access = "token required" if info.token else "this computer only"
        console().print(f"serving {url} at {info.url} ({access}); Ctrl-C stops")

    stop = threading.Event()
    previous = stop_on_signals(stop)
    try:
        serve(
            url, host=host, port=port, token=token, on_ready=ready, stop=stop, log_level="warning"
        )
    finally:
        restore_signals(previous)
    console().print("stopped")


def _token(path: Path | None) -> str | None:
    """The server's token: from ``--token-file``, else ``$NCMEASURE_TOKEN``, else None."""
    from ncmeasure.inputs import read_text

    if path is not None:
        return read_text(path, "a token file", 4096).strip() or _no_token(str(path))
    value = os.environ.get(TOKEN_ENV)
    if value is None:
        return None
    return value.strip() or _no_token(f"${TOKEN_ENV}")


def _no_token(where: str) -> str:
    raise ConfigError(f"{where}: empty, expected the token (at least 16 characters)")
