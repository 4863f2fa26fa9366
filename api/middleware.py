"""ASGI middleware: browser safety and the last word on errors, bounded bodies, a time limit
per request, request metrics.

Plain ASGI (not ``BaseHTTPMiddleware``) so that the body limit also counts a streamed body
without buffering it, and so that a timed-out request still gets a problem document.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from typing import Any, Awaitable, Callable

from prometheus_client import CollectorRegistry, Counter, Histogram

from .problems import PROBLEM_JSON, TYPE_BASE, capped

log = logging.getLogger("excite.api")

ASGIApp = Callable[[dict, Callable, Callable], Awaitable[None]]


async def send_problem(send: Callable, status: int, title: str, type_: str, detail: str,
                       instance: str, headers: list[tuple[bytes, bytes]] | None = None) -> None:
    body = json.dumps(capped({"type": TYPE_BASE + type_, "title": title, "status": status,
                              "detail": detail, "instance": instance})).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", PROBLEM_JSON.encode()),
                            (b"content-length", str(len(body)).encode()), *(headers or [])]})
    await send({"type": "http.response.body", "body": body})


class BodyLimit:
    """413 when Content-Length or the streamed body exceeds ``max_bytes``; 408 when the body
    has not arrived within ``timeout_s`` (a client that announces a body and sends it slowly
    would otherwise hold a connection and a request slot forever)."""

    def __init__(self, app: ASGIApp, max_bytes: int, timeout_s: float = 30.0):
        self.app, self.max_bytes, self.timeout_s = app, max_bytes, timeout_s

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        detail = f"the request body exceeds the limit of {self.max_bytes} bytes"
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    too_big = int(value) > self.max_bytes
                except ValueError:
                    too_big = False
                if too_big:
                    return await send_problem(send, 413, "Content too large", "too-large", detail,
                                              scope.get("path", ""), [(b"connection", b"close")])
        if _is_multipart(scope):
            # Uploads (bags) stream through to the endpoint, which spools them to disk; the
            # limit is counted on the way (ProblemError → 413 problem+json from the app).
            return await self.app(scope, self._counted(receive, detail), send)
        # Read the body here (at most max_bytes are held), then replay it: an exception raised
        # from inside a streamed receive would surface as a parse error, not a 413.
        body = bytearray()
        deadline = asyncio.get_running_loop().time() + self.timeout_s
        while True:
            try:
                message = await asyncio.wait_for(receive(), deadline - asyncio.get_running_loop().time())
            except asyncio.TimeoutError:
                log.warning("%s %s: body not received within %g s", scope.get("method"),
                            scope.get("path"), self.timeout_s)
                return await send_problem(send, 408, "Request timeout", "body-timeout",
                                          f"the request body did not arrive within {self.timeout_s:g} s",
                                          scope.get("path", ""), [(b"connection", b"close")])
            if message["type"] != "http.request":
                return  # the client went away
            body += message.get("body", b"")
            if len(body) > self.max_bytes:
                return await send_problem(send, 413, "Content too large", "too-large", detail,
                                          scope.get("path", ""), [(b"connection", b"close")])
            if not message.get("more_body", False):
                break
        replayed = False

        async def replay() -> dict:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": bytes(body), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


    def _counted(self, receive: Callable, detail: str) -> Callable:
        seen = 0

        async def counted() -> dict:
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                from .errors import ProblemError

                raise ProblemError(413, detail, headers={"Connection": "close"})
            return message

        return counted


def _is_multipart(scope: dict) -> bool:
    return any(name == b"content-type" and value.lower().startswith(b"multipart/form-data")
               for name, value in scope.get("headers", []))


class TimeLimit:
    """503 when a request takes longer than ``timeout_s`` (the work itself is bounded by the
    input limits; this bounds the client's wait)."""

    def __init__(self, app: ASGIApp, timeout_s: float):
        self.app, self.timeout_s = app, timeout_s

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        state = {"started": False, "timed_out": False}

        async def tracked(message: dict) -> None:
            if state["timed_out"]:
                return  # the 503 went out: the late answer is dropped
            if message["type"] == "http.response.start":
                state["started"] = True
            await send(message)

        task = asyncio.ensure_future(self.app(scope, receive, tracked))
        done, _ = await asyncio.wait({task}, timeout=self.timeout_s)
        if done:
            return task.result()
        if state["started"]:
            return await task  # an answer is already on its way: let it finish
        state["timed_out"] = True
        task.cancel()
        log.warning("%s %s exceeded the time limit of %g s", scope.get("method"),
                    scope.get("path"), self.timeout_s)
        await send_problem(send, 503, "Service unavailable", "timeout",
                           f"the request exceeded the time limit of {self.timeout_s:g} s",
                           scope.get("path", ""), [(b"retry-after", b"10")])


class Metrics:
    """Prometheus counters and latency histograms per route template, method and status."""

    def __init__(self, app: ASGIApp, registry: CollectorRegistry):
        self.app = app
        self.requests = Counter("excite_http_requests_total", "HTTP requests",
                                ["method", "route", "status"], registry=registry)
        self.latency = Histogram("excite_http_request_duration_seconds", "HTTP request latency",
                                 ["method", "route"], registry=registry,
                                 buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10,
                                          30, 60))

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        status = {"code": 500}
        t0 = time.perf_counter()

        async def tracked(message: dict[str, Any]) -> None:
            if message["type"] == "http.response.start":
                status["code"] = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, tracked)
        finally:
            route = scope.get("route")
            name = getattr(route, "path", None) or "unmatched"
            method = scope.get("method", "")
            self.requests.labels(method, name, str(status["code"])).inc()
            self.latency.labels(method, name).observe(time.perf_counter() - t0)


# Content types a cross-site HTML form (or a "simple" fetch) can send without a preflight
SIMPLE_TYPES = (b"multipart/form-data", b"application/x-www-form-urlencoded", b"text/plain")
CLIENT_HEADER = b"x-excite-client"
UNSAFE = ("POST", "PUT", "PATCH", "DELETE")
CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
       "connect-src 'self'; font-src 'self'; object-src 'none'; base-uri 'none'; "
       "form-action 'self'; frame-ancestors 'none'")
# Swagger UI (/docs) loads its script and style from a CDN and starts with an inline script
DOCS_CSP = ("default-src 'self'; script-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net; "
            "style-src 'self' https://cdn.jsdelivr.net; img-src 'self' data: https://fastapi.tiangolo.com; "
            "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'")


def own_origin(scope: dict) -> str | None:
    """``http://host:port`` of the server as the client addressed it (its Host header)."""
    host = next((v for k, v in scope.get("headers", []) if k == b"host"), None)
    if host is None:
        return None
    scheme = {"ws": "http", "wss": "https"}.get(scope.get("scheme", "http"), scope.get("scheme", "http"))
    return f"{scheme}://{host.decode('latin-1').lower()}"


class Guard:
    """What keeps a browser from being used against the service, and the last word on errors:

    - a WebSocket whose ``Origin`` is neither the server's own nor in ``origins`` is refused
      before the handshake completes (HTTP 403);
    - a state-changing request (POST, PUT, PATCH, DELETE) is refused (403 problem+json) when its
      ``Origin`` is foreign, when the browser says it is cross-site (``Sec-Fetch-Site``), or when
      it is one a cross-site HTML form could send (multipart, urlencoded or text/plain) and
      carries none of the headers such a form cannot set (``X-Excite-Client``, ``X-API-Key``,
      ``Authorization``);
    - every response carries a Content-Security-Policy (``frame-ancestors 'none'``),
      ``X-Frame-Options: DENY``, ``X-Content-Type-Options: nosniff`` and ``Referrer-Policy``;
    - ``HEAD`` is answered wherever ``GET`` is (the GET's headers, no body);
    - an exception nothing else handled becomes a 500 problem here, so it never reaches the
      server (which would reset the connection and with it the client's next request).
    """

    def __init__(self, app: ASGIApp, origins: tuple[str, ...] = ()):
        self.app, self.origins = app, tuple(origins)

    def _allowed(self, origin: str, scope: dict) -> bool:
        origin = origin.rstrip("/").lower()
        return origin == own_origin(scope) or origin in self.origins

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] == "websocket":
            origin = _header(scope, b"origin")
            if origin is not None and not self._allowed(origin, scope):
                log.warning("%s: WebSocket from foreign origin %s refused", scope.get("path"), origin[:200])
                await receive()  # websocket.connect
                return await send({"type": "websocket.close", "code": 1008})
            return await self.app(scope, receive, send)
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        refusal = self._cross_site(scope)
        if refusal is not None:
            return await send_problem(send, 403, "Forbidden", "cross-site", refusal, scope.get("path", ""))
        head = scope["method"] == "HEAD"
        if head:
            scope = dict(scope, method="GET")
        csp = (DOCS_CSP if scope.get("path") == "/docs" else CSP).encode()
        state = {"started": False}

        async def guarded(message: dict) -> None:
            if message["type"] == "http.response.start":
                state["started"] = True
                headers = [h for h in message.get("headers", [])
                           if h[0].lower() not in (b"content-security-policy", b"x-frame-options")]
                headers += [(b"content-security-policy", csp), (b"x-frame-options", b"DENY"),
                            (b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer")]
                message = dict(message, headers=headers)
            elif head and message["type"] == "http.response.body":
                message = dict(message, body=b"")
            await send(message)

        try:
            await self.app(scope, receive, guarded)
        except Exception:
            log.exception("unhandled error on %s %s", scope.get("method"), scope.get("path"))
            if not state["started"]:
                await send_problem(guarded, 500, "Internal server error", "internal",
                                   "The server failed to handle this request; the error is logged.",
                                   scope.get("path", ""))

    def _cross_site(self, scope: dict) -> str | None:
        if scope["method"] not in UNSAFE:
            return None
        origin = _header(scope, b"origin")
        if origin is not None:
            if self._allowed(origin, scope):
                return None
            return (f"a {scope['method']} from the origin {origin[:200]!r} is refused: only this server's "
                    "own page (or EXCITE_ALLOWED_ORIGINS) may send one from a browser")
        site = _header(scope, b"sec-fetch-site")
        if site in ("cross-site", "same-site"):
            return f"a {site} {scope['method']} from a browser is refused"
        ctype = (_header(scope, b"content-type") or "").lower().encode("latin-1")
        simple = ctype.startswith(SIMPLE_TYPES)  # a form always has one
        names = {k for k, _ in scope.get("headers", [])}
        if scope["method"] == "POST" and simple and not names & {CLIENT_HEADER, b"x-api-key", b"authorization"}:
            return ("a POST a cross-site HTML form could send is refused: send the header "
                    "X-Excite-Client (any value) or an API key with it")
        return None


def _header(scope: dict, name: bytes) -> str | None:
    for k, v in scope.get("headers", []):
        if k == name:
            return v.decode("latin-1")
    return None
