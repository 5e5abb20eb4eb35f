"""The web app's ASGI middleware: what every request passes before a route sees it.

Conventions
-----------
* :func:`quatmotion.server.app.create_app` adds them outermost first: :class:`HostCheck`
  (400 for a ``Host`` the server does not answer to), :class:`CsrfGuard` (403 for a POST
  without :data:`CSRF_HEADER` or from another site), :class:`BodySizeLimit` (413 for a body
  over the limit), :class:`SecurityHeaders` (``nosniff``, no referrer, on every response).
* Each answers a refused request with JSON ``{"detail": "<one line>"}``, like the routes.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence

from fastapi import HTTPException
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = [
    "CSRF_HEADER",
    "LOOPBACK_HOSTS",
    "BodySizeLimit",
    "CsrfGuard",
    "HostCheck",
    "SecurityHeaders",
    "allowed_hosts_for",
    "host_name",
    "is_loopback",
]

CSRF_HEADER = "X-Quatmotion-Request"
"""The header every POST must carry (any value; the pages send ``1``): the guard against
cross-site request forgery (:class:`CsrfGuard`)."""

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
"""Host names a server bound to the loopback answers to (the defence against DNS rebinding:
a page of another site that resolves its own name to 127.0.0.1 is refused)."""

_SAFE_METHODS = ("GET", "HEAD", "OPTIONS")


def is_loopback(host: str) -> bool:
    """Whether binding ``host`` serves this machine only (``localhost`` or a loopback
    address)."""
    if host.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def allowed_hosts_for(host: str) -> tuple[str, ...]:
    """Host names the server answers to when bound to ``host``: the loopback names for a
    loopback address, anything otherwise (the user chose to be reachable)."""
    return LOOPBACK_HOSTS if is_loopback(host) else ("*",)


def host_name(header: str) -> str:
    """The host name of a ``Host`` header, lower-case, without its port: ``[::1]:8000`` ->
    ``::1``, ``localhost:8000`` -> ``localhost``."""
    text = header.strip().lower()
    if text.startswith("["):
        return text[1 : text.find("]")] if "]" in text else ""
    return text.rsplit(":", 1)[0] if text.count(":") == 1 else text


class BodySizeLimit:
    """ASGI middleware: a request body over ``max_bytes`` gets 413.

    A declared ``Content-Length`` over the limit is refused before anything is read; a body
    sent without one (chunked) is counted as it arrives and refused when it passes the limit.
    """

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.message = f"request body larger than the server's limit of {max_bytes} bytes"

    def _too_large(self) -> JSONResponse:
        return JSONResponse({"detail": self.message}, status_code=413)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None:
            try:
                length = int(declared)
            except ValueError:
                length = -1
            if length < 0:
                response = JSONResponse({"detail": "malformed Content-Length"}, status_code=400)
                await response(scope, receive, send)
                return
            if length > self.max_bytes:
                await self._too_large()(scope, receive, send)
                return
        received = 0
        started = False

        async def counted() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise HTTPException(413, self.message)
            return message

        async def watched(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, watched)
        except HTTPException as error:
            if error.status_code != 413 or started:
                raise
            await self._too_large()(scope, receive, send)


class SecurityHeaders:
    """ASGI middleware: ``nosniff`` and no referrer on every response."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [
                    (b"x-content-type-options", b"nosniff"),
                    (b"referrer-policy", b"no-referrer"),
                ]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_headers if scope["type"] == "http" else send)


class HostCheck:
    """ASGI middleware: a request whose ``Host`` is not one of ``allowed`` gets 400 (the
    defence against DNS rebinding); ``("*",)`` allows any. IPv6 hosts come bracketed
    (``[::1]:8000``)."""

    def __init__(self, app: ASGIApp, allowed: Sequence[str]) -> None:
        self.app = app
        self.any = "*" in allowed
        self.allowed = {host_name(h) if h.startswith("[") else h.lower() for h in allowed}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket") and not self.any:
            header = dict(scope["headers"]).get(b"host", b"").decode("latin-1")
            if host_name(header) not in self.allowed:
                response = JSONResponse({"detail": "invalid host header"}, status_code=400)
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


class CsrfGuard:
    """ASGI middleware: a request that may change something (any method but GET, HEAD and
    OPTIONS) gets 403 unless it carries the header :data:`CSRF_HEADER` and nothing says it
    comes from another site (``Sec-Fetch-Site`` other than ``same-origin``/``none``, or an
    ``Origin`` other than the server's own).

    A form of another site, posted to the server by the browser of a person who visits it,
    can set neither that header nor its own origin; the app's pages send the header.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] not in _SAFE_METHODS:
            reason = self._refused(dict(scope["headers"]))
            if reason:
                await JSONResponse({"detail": reason}, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)

    @staticmethod
    def _refused(headers: dict[bytes, bytes]) -> str:
        site = headers.get(b"sec-fetch-site", b"").decode("latin-1").lower()
        if site and site not in ("same-origin", "none"):
            return f"cross-site request refused (Sec-Fetch-Site: {site})"
        origin = headers.get(b"origin")
        if origin is not None:
            own = headers.get(b"host", b"").decode("latin-1").lower()
            given = origin.decode("latin-1").lower()
            if given.partition("://")[2] != own:
                return f"cross-origin request refused (Origin: {given[:100]})"
        if not headers.get(CSRF_HEADER.lower().encode()):
            return (
                f"a {CSRF_HEADER} header is required on this request (the app's pages send it; "
                "another site's form cannot)"
            )
        return ""
