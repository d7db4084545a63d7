"""The service's ASGI middleware, outermost first: ``HostCheck`` (DNS rebinding), ``AuthFirst``
(401 before a body is read) and ``BodyLimit`` (413). Each takes what it needs as a callable, read
per request (the settings live on ``app.state``, set in the lifespan)."""

from __future__ import annotations

import ipaddress
from typing import Callable

from fastapi import HTTPException, status
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .auth import TokenTable
from .settings import Settings


class HostCheck:
    """Answer only requests whose ``Host`` is one of this service's names (421 otherwise): a web
    page can make a browser's requests to ``attacker.example`` land on 127.0.0.1 by DNS rebinding,
    and a token-less loopback service would obey them. ``NEUENH_ALLOWED_HOSTS`` lists the names;
    unset, a token-less service answers loopback names only and a token-protected one any."""

    def __init__(self, app: ASGIApp, settings: Callable[[], Settings]):
        self.app, self.settings = app, settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            host = _host_name(dict(scope["headers"]).get(b"host", b"").decode("latin-1"))
            settings = self.settings()
            allowed = [h.lower() for h in settings.allowed_hosts]
            if allowed:
                ok = host in allowed
            else:
                ok = settings.has_tokens or host in ("localhost", settings.host.lower()) or _is_ip_loopback(host)
            if not ok:
                detail = f"this service does not answer to Host {host!r} (NEUENH_ALLOWED_HOSTS)"
                await JSONResponse({"detail": detail}, status.HTTP_421_MISDIRECTED_REQUEST)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _host_name(header: str) -> str:
    """The name of a Host header value, lowercased, without the port (``[::1]:8000`` -> ``::1``)."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1:].partition("]")[0]
    return header.rpartition(":")[0] if header.count(":") == 1 else header


def _is_ip_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class AuthFirst:
    """Refuse a request to a token-protected ``/v1`` route with 401 *before* its body is read:
    FastAPI parses a JSON body, and spools a multipart upload to disk, before it runs the routes'
    dependencies, so without this a client with no token could make the service store 64 MB, or
    learn from a 422 what a valid body looks like."""

    OPEN = ("/v1/health",)

    def __init__(self, app: ASGIApp, tokens: Callable[[], TokenTable]):
        self.app, self.tokens = app, tokens

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "")
        if scope["type"] == "http" and path.startswith("/v1/") and path not in self.OPEN:
            authorization = dict(scope["headers"]).get(b"authorization")
            try:
                self.tokens().authenticate(None if authorization is None else authorization.decode("latin-1"))
            except HTTPException as refusal:
                response = JSONResponse({"detail": refusal.detail}, refusal.status_code, headers=refusal.headers)
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


class BodyLimit:
    """Refuse request bodies over ``limit(path)`` bytes with 413: at once when ``Content-Length`` says
    so, else while the body streams in."""

    def __init__(self, app: ASGIApp, limit: Callable[[str], tuple[int, str]]):
        self.app, self.limit = app, limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit, setting = self.limit(scope["path"])
        detail = f"request body over {limit} bytes ({setting})"
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > limit):
            await JSONResponse({"detail": detail}, status.HTTP_413_CONTENT_TOO_LARGE)(scope, receive, send)
            return
        seen = 0

        async def counted() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:  # FastAPI re-raises HTTPException from body reading as-is
                    raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, detail)
            return message

        await self.app(scope, counted, send)
