"""Who may use the dashboard and the API: the token, the loopback rule, the body limit.

The rules, applied before a request reaches any page or endpoint (an ASGI
middleware, so an unauthorised request is answered before its body is read):

* Without a token the server listens on a loopback address only
  (:func:`check_binding`) and answers only requests addressed to a loopback
  name (``Host: 127.0.0.1``, ``localhost``, ``[::1]``): a web page elsewhere
  cannot reach it through DNS rebinding.
* With a token every request needs ``Authorization: Bearer <token>``. A
  browser may instead open a page once with ``?token=<token>``: it is
  redirected to the same address without the token and keeps a session
  cookie (HttpOnly, SameSite=Lax) derived from the token. Cookie and
  ``?token=`` count for reading (GET, HEAD) only; anything that writes needs
  the header, so a page elsewhere cannot write through the browser's cookie.
  Tokens are compared with :func:`secrets.compare_digest`.
* A request body must state its length and stay within :data:`MAX_BODY_BYTES`.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import re
import secrets
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any
from urllib.parse import parse_qsl, quote, urlencode

from ncmeasure.errors import ConfigError
from ncmeasure.hosts import is_loopback

__all__ = [
    "COOKIE",
    "MAX_BODY_BYTES",
    "MIN_TOKEN_LENGTH",
    "Guard",
    "HideToken",
    "check_binding",
    "check_token",
    "is_loopback",
]

MIN_TOKEN_LENGTH = 16
"""The shortest token accepted (``secrets.token_urlsafe()`` gives 43 characters)."""
MAX_BODY_BYTES = 32 * 1024 * 1024
"""The largest request body: a results.json of a big machine is a few MB."""
COOKIE = "ncmeasure_session"
"""The session cookie a browser gets after opening a page with ``?token=``."""
_TOKEN_CHARACTERS = re.compile(r"[!-~]+")
_TOKEN_IN_QUERY = re.compile(r"(?<=[?&])token=[^&\s\"]*")

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
App = Callable[[Scope, Receive, Send], Awaitable[None]]


def check_token(token: str | None) -> str | None:
    """``token`` if it is usable (or None), else a :class:`ConfigError` saying why.

    A token is at least :data:`MIN_TOKEN_LENGTH` printable ASCII characters
    without spaces, so that it fits an HTTP header as it is.
    """
    if token is None:
        return None
    if not _TOKEN_CHARACTERS.fullmatch(token):
        raise ConfigError(
            "the token must be printable ASCII without spaces (e.g. from "
            "python -c 'import secrets; print(secrets.token_urlsafe())')"
        )
    if len(token) < MIN_TOKEN_LENGTH:
        raise ConfigError(
            f"the token has {len(token)} characters; use at least {MIN_TOKEN_LENGTH} "
            "(e.g. from python -c 'import secrets; print(secrets.token_urlsafe())')"
        )
    return token


def check_binding(host: str, token: str | None) -> None:
    """Refuse to listen beyond this computer without a token.

    Raises:
        ConfigError: ``host`` is not a loopback address and there is no token,
            or the token is unusable (:func:`check_token`).
    """
    check_token(token)
    if token is None and not is_loopback(host):
        raise ConfigError(
            f"serving on {host!r} makes the fleet store reachable from other computers: "
            "give a token (ncmeasure serve --token-file FILE or $NCMEASURE_TOKEN; every "
            "client then sends 'Authorization: Bearer TOKEN'), or listen on 127.0.0.1"
        )


def _session(token: str) -> str:
    """The cookie's value: derived from the token, so the cookie is not the token itself."""
    return hmac.new(token.encode(), b"ncmeasure web session", hashlib.sha256).hexdigest()


def _same(given: str, expected: str) -> bool:
    return secrets.compare_digest(given.encode(), expected.encode())


def _host_name(host_header: str) -> str:
    """The host of a ``Host`` header, without its port."""
    if host_header.startswith("["):
        return host_header[: host_header.find("]") + 1]
    return host_header.rsplit(":", 1)[0] if host_header.count(":") == 1 else host_header


class HideToken(logging.Filter):
    """Replaces ``token=...`` in logged request lines (uvicorn's access log) with ``token=***``."""

    def filter(self, record: logging.LogRecord) -> bool:
        """Redact the record's arguments; always keep the record."""
        if isinstance(record.args, tuple):
            record.args = tuple(
                _TOKEN_IN_QUERY.sub("token=***", a) if isinstance(a, str) else a
                for a in record.args
            )
        return True


class Guard:
    """The ASGI middleware that enforces the rules of this module."""

    def __init__(self, app: App, token: str | None) -> None:
        self.app = app
        self.token = check_token(token)
        self.session = _session(token) if token is not None else None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Answer a refused request here; pass the others on."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        refused = self._refusal(scope, headers)
        if refused is not None:
            await _answer(scope, send, *refused)
            return
        await self.app(scope, receive, send)

    def _refusal(
        self, scope: Scope, headers: dict[str, str]
    ) -> tuple[int, str, list[tuple[str, str]]] | None:
        """None to let the request pass, else (status, detail, extra headers)."""
        method = scope["method"]
        reading = method in ("GET", "HEAD")
        query = parse_qsl(scope.get("query_string", b"").decode("latin-1"), keep_blank_values=True)
        if self.token is None:
            if not is_loopback(_host_name(headers.get("host", ""))):
                return (
                    403,
                    "this server has no token and answers only requests to a loopback "
                    "address (127.0.0.1, localhost)",
                    [],
                )
        else:
            scheme, _, given = headers.get("authorization", "").partition(" ")
            if not (scheme.lower() == "bearer" and _same(given.strip(), self.token)):
                queried = [v for k, v in query if k == "token"]
                if reading and queried and _same(queried[-1], self.token):
                    if not scope["path"].startswith("/api/"):
                        return self._redirect_with_cookie(scope, query)
                elif not (reading and self._has_session(headers)):
                    what = "" if reading else " (writing needs the header)"
                    return (
                        401,
                        f"this server needs its token: send 'Authorization: Bearer TOKEN'{what}"
                        + (", or open the page with ?token=TOKEN" if reading else ""),
                        [("www-authenticate", "Bearer")],
                    )
        if not reading and method != "OPTIONS":
            return _body_refusal(headers)
        return None

    def _has_session(self, headers: dict[str, str]) -> bool:
        assert self.session is not None
        for part in headers.get("cookie", "").split(";"):
            name, _, value = part.strip().partition("=")
            if name == COOKIE and _same(value, self.session):
                return True
        return False

    def _redirect_with_cookie(
        self, scope: Scope, query: list[tuple[str, str]]
    ) -> tuple[int, str, list[tuple[str, str]]]:
        rest = urlencode([(k, v) for k, v in query if k != "token"])
        raw = scope.get("raw_path")
        path = raw.decode("latin-1") if isinstance(raw, bytes) else quote(scope["path"])
        target = path + (f"?{rest}" if rest else "")
        cookie = f"{COOKIE}={self.session}; HttpOnly; SameSite=Lax; Path=/"
        return (
            303,
            "signed in; continue without the token in the address",
            [
                ("location", target),
                ("set-cookie", cookie),
            ],
        )


def _body_refusal(headers: dict[str, str]) -> tuple[int, str, list[tuple[str, str]]] | None:
    length = headers.get("content-length")
    if length is None:
        if "transfer-encoding" in headers:
            return 411, "send the body with a Content-Length", []
        return None
    if not length.isdigit():
        return 400, "Content-Length is not a number", []
    if int(length) > MAX_BODY_BYTES:
        return (
            413,
            f"the body has {int(length)} bytes; at most {MAX_BODY_BYTES} are accepted",
            [],
        )
    return None


async def _answer(
    scope: Scope, send: Send, status: int, detail: str, extra: list[tuple[str, str]]
) -> None:
    """A refusal as JSON ``{"detail": ...}`` (HTML pages show the same line as text)."""
    if scope["path"].startswith("/api/") or scope["path"] == "/openapi.json":
        body = json.dumps({"detail": detail}).encode()
        kind = "application/json"
    else:
        body = f"{status}: {detail}\n".encode()
        kind = "text/plain; charset=utf-8"
    headers = [(b"content-type", kind.encode()), (b"content-length", str(len(body)).encode())]
    headers += [(k.encode("latin-1"), v.encode("latin-1")) for k, v in extra]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": b"" if scope["method"] == "HEAD" else body})
