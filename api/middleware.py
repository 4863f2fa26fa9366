"""ASGI middleware: hosts, browser safety and the last word on errors; bounded bodies; a time limit
per request whose lasting effects are all-or-nothing; request metrics.

Plain ASGI (not ``BaseHTTPMiddleware``) so that the body limit also counts a streamed body
without buffering it, and so that a timed-out request still gets a problem document. Every
answer given here is a :class:`~api.errors.Problem` sent by :func:`api.problems.send`.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from contextlib import contextmanager
from typing import Any, Awaitable, Callable, Iterator

from prometheus_client import CollectorRegistry, Counter, Histogram
from starlette.datastructures import Headers

from excite.errors import WorkTimeout

from . import problems
from .errors import Problem

log = logging.getLogger("excite.api")

ASGIApp = Callable[[dict, Callable, Callable], Awaitable[None]]


class BodyLimit:
    """413 when Content-Length or the streamed body exceeds ``max_bytes``; 408 when the body
    has not arrived within ``timeout_s`` (a client that announces a body and sends it slowly
    would otherwise hold a connection and a request slot forever). The body is read here (at
    most ``max_bytes`` held) and replayed to the app, so the app never sees more; a multipart
    upload is counted as it streams through instead."""

    def __init__(self, app: ASGIApp, max_bytes: int, timeout_s: float = 30.0):
        self.app, self.max_bytes, self.timeout_s = app, max_bytes, timeout_s

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        path = scope.get("path", "")
        too_large = Problem(413, f"the request body exceeds the limit of {self.max_bytes} bytes")
        headers = Headers(scope=scope)
        length = headers.get("content-length")
        if length is not None and length.strip().isdigit() and int(length) > self.max_bytes:
            return await problems.send(send, too_large, path, close=True)
        if headers.get("content-type", "").lower().startswith("multipart/form-data"):
            # uploads (bags) stream through to the form parser, which spools them to disk; the
            # limit is counted on the way (the Problem surfaces from the route: 413)
            return await self.app(scope, self._counted(receive, too_large), send)
        body = bytearray()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout_s
        while True:
            try:
                message = await asyncio.wait_for(receive(), deadline - loop.time())
            except asyncio.TimeoutError:
                log.warning("%s %s: body not received within %g s", scope.get("method"), path, self.timeout_s)
                return await problems.send(send, Problem(408, f"the request body did not arrive within "
                                                              f"{self.timeout_s:g} s", type_="body-timeout"),
                                           path, close=True)
            if message["type"] != "http.request":
                return  # the client went away
            body += message.get("body", b"")
            if len(body) > self.max_bytes:
                return await problems.send(send, too_large, path, close=True)
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

    def _counted(self, receive: Callable, too_large: Problem) -> Callable:
        seen = 0

        async def counted() -> dict:
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                raise too_large
            return message

        return counted


class Deadline:
    """A request's time limit, shared by :class:`TimeLimit` and the route (``scope["state"]``).

    A request's lasting effect (a job created) happens inside :meth:`commit`: only while the
    request has not been answered 503, and the 503 waits while it is under way. So a request is
    either answered with what it did, or answered 503 and did nothing lasting."""

    def __init__(self, timeout_s: float):
        self.timeout_s = timeout_s
        self.at = time.monotonic() + timeout_s
        self._lock = threading.Lock()
        self._state = "open"  # → "committing" | "expired"

    def work_until(self) -> float:
        """When work for the request must be done (monotonic), a little before the limit so that
        the route answers first."""
        return self.at - min(1.0, 0.05 * self.timeout_s)

    @contextmanager
    def commit(self) -> Iterator[None]:
        with self._lock:
            if self._state == "expired":
                raise problems.of(WorkTimeout(), timeout_s=self.timeout_s)
            self._state = "committing"
        yield

    def expire(self) -> bool:
        """The limit passed: True when the request may be answered 503 (nothing was committed)."""
        with self._lock:
            if self._state == "committing":
                return False
            self._state = "expired"
            return True


class TimeLimit:
    """503 when a request takes longer than ``timeout_s``, unless its lasting effect is already
    under way (:class:`Deadline`)."""

    def __init__(self, app: ASGIApp, timeout_s: float):
        self.app, self.timeout_s = app, timeout_s

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        deadline = Deadline(self.timeout_s)
        scope.setdefault("state", {})["deadline"] = deadline
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
        if state["started"] or not deadline.expire():
            return await task  # an answer is on its way, or the request's effect is: let it finish
        state["timed_out"] = True
        task.cancel()
        log.warning("%s %s exceeded the time limit of %g s", scope.get("method"), scope.get("path"),
                    self.timeout_s)
        await problems.send(send, problems.of(WorkTimeout(), timeout_s=self.timeout_s), scope.get("path", ""))


class Metrics:
    """Prometheus counters and latency histograms per route template, method and status."""

    def __init__(self, app: ASGIApp, registry: CollectorRegistry):
        self.app = app
        self.requests = Counter("excite_http_requests_total", "HTTP requests",
                                ["method", "route", "status"], registry=registry)
        self.latency = Histogram("excite_http_request_duration_seconds", "HTTP request latency",
                                 ["method", "route"], registry=registry,
                                 buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60))

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
SIMPLE_TYPES = ("multipart/form-data", "application/x-www-form-urlencoded", "text/plain")
CLIENT_HEADER = "x-excite-client"
UNSAFE = ("POST", "PUT", "PATCH", "DELETE")
CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
       "connect-src 'self'; font-src 'self'; object-src 'none'; base-uri 'none'; "
       "form-action 'self'; frame-ancestors 'none'")


def host_name(host: str) -> str:
    """``"[::1]:8000"`` → ``"::1"``, ``"Example.org:80"`` → ``"example.org"``."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


class Guard:
    """What keeps a browser from being used against the service, and the last word on errors:

    - a request whose ``Host`` is not in ``hosts`` (``"*"``: any) is refused (421; a WebSocket:
      closed) before anything else: a rebound name of another site arrives in ``Host``;
    - the server's own origins are the configured ``origins`` and ``scheme://Host`` for a Host
      listed *by name* in ``hosts`` (never one that only passed a wildcard); a WebSocket from
      another origin is refused before the handshake completes, and so is (403) a POST, PUT,
      PATCH or DELETE from another origin, one the browser calls cross-site, or one a cross-site
      HTML form could send that carries none of the headers such a form cannot set;
    - every response carries the security headers (:data:`CSP` without ``'unsafe-inline'``);
      ``HEAD`` is answered wherever ``GET`` is; an exception nothing else handled is a 500 problem
      here, so it never resets the connection (and with it the client's next request).
    """

    def __init__(self, app: ASGIApp, hosts: tuple[str, ...] = ("*",), origins: tuple[str, ...] = ()):
        self.app = app
        self.any_host = "*" in hosts
        self.hosts = frozenset(h.lower() for h in hosts if h != "*")
        self.origins = tuple(origins)

    def _allowed(self, origin: str, scope: dict) -> bool:
        origin = origin.rstrip("/").lower()
        if origin in self.origins:
            return True
        host = Headers(scope=scope).get("host")
        if host is None or host_name(host) not in self.hosts:
            return False
        scheme = {"ws": "http", "wss": "https"}.get(scope.get("scheme", "http"), scope.get("scheme", "http"))
        return origin == f"{scheme}://{host.lower()}"

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        host = Headers(scope=scope).get("host", "")
        if not self.any_host and host_name(host) not in self.hosts:
            log.warning("%s: Host %r is not an allowed host: refused", scope.get("path"), host[:200])
            if scope["type"] == "websocket":
                return await _close(receive, send)
            return await problems.send(send, Problem(421, f"this server does not answer to the host {host[:200]!r} "
                                                          "(EXCITE_ALLOWED_HOSTS)", type_="host"),
                                       scope.get("path", ""), close=True)
        if scope["type"] == "websocket":
            origin = Headers(scope=scope).get("origin")
            if origin is not None and not self._allowed(origin, scope):
                log.warning("%s: WebSocket from foreign origin %s refused", scope.get("path"), origin[:200])
                return await _close(receive, send)
            return await self.app(scope, receive, send)
        refusal = self._cross_site(scope)
        if refusal is not None:
            return await problems.send(send, Problem(403, refusal, type_="cross-site"), scope.get("path", ""))
        head = scope["method"] == "HEAD"
        if head:
            scope = dict(scope, method="GET")
        state = {"started": False}

        async def guarded(message: dict) -> None:
            if message["type"] == "http.response.start":
                state["started"] = True
                headers = [h for h in message.get("headers", [])
                           if h[0].lower() not in (b"content-security-policy", b"x-frame-options")]
                headers += [(b"content-security-policy", CSP.encode()), (b"x-frame-options", b"DENY"),
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
                await problems.send(guarded, Problem(500, problems.INTERNAL), scope.get("path", ""))

    def _cross_site(self, scope: dict) -> str | None:
        if scope["method"] not in UNSAFE:
            return None
        headers = Headers(scope=scope)
        origin = headers.get("origin")
        if origin is not None:
            if self._allowed(origin, scope):
                return None
            return (f"a {scope['method']} from the origin {origin[:200]!r} is refused: only this server's "
                    "own page (or EXCITE_ALLOWED_ORIGINS) may send one from a browser")
        site = headers.get("sec-fetch-site")
        if site in ("cross-site", "same-site"):
            return f"a {site} {scope['method']} from a browser is refused"
        if (scope["method"] == "POST" and headers.get("content-type", "").lower().startswith(SIMPLE_TYPES)
                and not {CLIENT_HEADER, "x-api-key", "authorization"} & set(headers)):
            return ("a POST a cross-site HTML form could send is refused: send the header "
                    "X-Excite-Client (any value) or an API key with it")
        return None


async def _close(receive: Callable, send: Callable) -> None:
    """Refuse a WebSocket before its handshake completes (1008)."""
    await receive()  # websocket.connect
    await send({"type": "websocket.close", "code": 1008})
