"""``ncmeasure serve``: the fleet store as a web dashboard and a JSON REST API.

::

    from ncmeasure.web import serve
    serve("sqlite:///fleet.db")                         # http://127.0.0.1:8000/
    serve(url, host="0.0.0.0", token=secrets.token_urlsafe())

The dashboard (:mod:`~ncmeasure.web.pages`) is a traffic-light grid of the
fleet, a page per machine and per axis with trend plots; plain HTML, no
JavaScript. The API (:mod:`~ncmeasure.web.api`) lives under ``/api/v1`` and
is described at ``/openapi.json`` and ``/docs``. Who may use either is
decided by :mod:`~ncmeasure.web.guard`: open on a loopback address, a token
for anything else. :func:`create_app` gives the ASGI application for any
ASGI server; :func:`serve` runs it under uvicorn.

Needs FastAPI and uvicorn besides the store's packages.
"""

from __future__ import annotations

from ncmeasure.web.app import create_app
from ncmeasure.web.guard import MAX_BODY_BYTES, MIN_TOKEN_LENGTH, check_binding, is_loopback
from ncmeasure.web.server import ServerInfo, serve

__all__ = [
    "MAX_BODY_BYTES",
    "MIN_TOKEN_LENGTH",
    "ServerInfo",
    "check_binding",
    "create_app",
    "is_loopback",
    "serve",
]
