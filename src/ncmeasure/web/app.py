"""The application: the store opened for its lifetime, the routes, the guard, errors in words.

Errors become ``{"detail": "one line"}`` (under ``/api/``) or a short page:
a :class:`~ncmeasure.errors.ConfigError` while reading is something the store
does not have (404), while writing it is bad input (422); a request the API
cannot parse is 422 too; a :class:`~ncmeasure.errors.StoreError` is 503.
Anything else is 500 with a line that points to the server's log; the
traceback goes to the log, never into a response.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from starlette.exceptions import HTTPException

from ncmeasure._version import __version__
from ncmeasure.errors import ConfigError, NcMeasureError, StoreError
from ncmeasure.store import Store
from ncmeasure.store.database import connect, display_url
from ncmeasure.web import api, pages
from ncmeasure.web.context import Context
from ncmeasure.web.guard import Guard, check_token

__all__ = ["create_app"]

log = logging.getLogger(__name__)

_DESCRIPTION = """\
The fleet store of ncmeasure: every friction measurement of every machine.

With a token, send `Authorization: Bearer TOKEN` with every request.
Errors are `{"detail": "one line"}`: 404 for a machine, measurement or axis the
store does not have, 422 for bad input, 401 without the token, 503 when the
database fails.
"""


def create_app(url: str, *, token: str | None = None) -> FastAPI:
    """The dashboard and the REST API over the store at ``url``.

    The store is opened when the application starts (its schema must be
    current or is upgraded, see :func:`ncmeasure.store.database.connect`) and
    its engine disposed when it stops.

    Args:
        url: The store's URL (``sqlite:///fleet.db``, ``postgresql://...``).
        token: With a token, every request must present it (see
            :mod:`ncmeasure.web.guard`); None: open to requests addressed to
            a loopback name.

    Returns:
        The ASGI application.

    Raises:
        ConfigError: The token is unusable (too short, spaces).
    """
    check_token(token)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        with connect(url, write=False) as engine:
            app.state.context = Context(Store(engine, url))
            yield

    app = FastAPI(
        title="ncmeasure fleet store",
        version=__version__,
        description=_DESCRIPTION,
        lifespan=lifespan,
        docs_url=None,  # FastAPI's own pages load their scripts from a CDN: see _docs
        redoc_url=None,
    )
    app.state.where = display_url(url)
    _docs(app)
    app.include_router(api.router)
    app.include_router(pages.router)
    app.add_middleware(Guard, token=token)
    _errors(app)
    return app


DOCS_ASSETS = "/docs/assets"
"""Where the API docs' scripts and styles are served from (the package, not a CDN)."""


def _docs(app: FastAPI) -> None:
    """``/docs``: Swagger UI with its scripts and styles served by this server.

    A shop-floor network is often offline; FastAPI's default page loads Swagger
    UI from a CDN and stays blank there. The assets come from the
    ``swagger-ui-bundle`` package (the ``serve`` extra).
    """
    from fastapi.openapi.docs import get_swagger_ui_html
    from fastapi.responses import HTMLResponse
    from fastapi.staticfiles import StaticFiles
    from swagger_ui_bundle import swagger_ui_path

    app.mount(DOCS_ASSETS, StaticFiles(directory=swagger_ui_path), name="docs-assets")

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url="/openapi.json",
            title=f"{app.title}: API",
            swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{DOCS_ASSETS}/favicon-32x32.png",
        )


def _one_line(error: NcMeasureError) -> str:
    """The error's message and its first problems, on one line."""
    parts = [error.message, *error.problems[:3]]
    more = len(error.problems) - 3
    text = "; ".join(" ".join(p.split()) for p in parts)
    return text + (f"; … and {more} more" if more > 0 else "")


def _validation_line(error: RequestValidationError) -> str:
    """FastAPI's validation errors as ``where: what`` lines joined into one."""
    lines = []
    for problem in error.errors()[:3]:
        where = ".".join(str(p) for p in problem.get("loc", ()) if p != "body")
        lines.append(f"{where or 'body'}: {problem.get('msg', 'invalid')}")
    more = len(error.errors()) - 3
    return "; ".join(lines) + (f"; … and {more} more" if more > 0 else "")


def _answer(request: Request, status: int, detail: str, headers: Any = None) -> Response:
    if request.url.path.startswith("/api/"):
        return JSONResponse({"detail": detail}, status_code=status, headers=headers)
    return pages.html_page(request, "error.html.j2", status, title=f"{status}", detail=detail)


def _errors(app: FastAPI) -> None:
    async def config_error(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, ConfigError)
        reading = request.method in ("GET", "HEAD")
        return _answer(request, 404 if reading else 422, _one_line(exc))

    async def store_error(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, StoreError)
        log.warning("%s %s: %s", request.method, request.url.path, exc.message)
        return _answer(request, 503, _one_line(exc))

    async def other_error(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, NcMeasureError)
        log.warning("%s %s: %s", request.method, request.url.path, exc.message)
        return _answer(request, 500, _one_line(exc))

    async def invalid(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, RequestValidationError)
        return _answer(request, 422, _validation_line(exc))

    async def http_error(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, HTTPException)
        return _answer(request, exc.status_code, str(exc.detail), exc.headers)

    async def unexpected(request: Request, exc: Exception) -> Response:
        # the traceback goes to the server's log (ServerErrorMiddleware re-raises it)
        return _answer(request, 500, "internal error; the server's log has the details")

    app.add_exception_handler(ConfigError, config_error)
    app.add_exception_handler(StoreError, store_error)
    app.add_exception_handler(NcMeasureError, other_error)
    app.add_exception_handler(RequestValidationError, invalid)
    app.add_exception_handler(HTTPException, http_error)
    app.add_exception_handler(Exception, unexpected)
