"""Running the app with uvicorn, with a time limit on each request's headers.

uvicorn bounds the body only through the app (:class:`~api.middleware.BodyLimit`), and has no
time limit for the headers: its keep-alive timer is cancelled by every byte received, so a
client that sends its headers one byte at a time (or opens a connection and sends nothing)
holds a connection for as long as it likes, and a few hundred of them exhaust the server. ASGI
middleware cannot help, since the app is called only once the headers are complete. Here the
HTTP protocol itself arms a deadline whenever it waits for a request's headers (a new
connection, or a kept-alive one after a response) and disarms it when they are complete; past
it a client that sent part of its headers is answered 408, and the connection is closed (an
idle one silently, as uvicorn's keep-alive timeout does).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

from .errors import Problem
from .problems import response

log = logging.getLogger("excite.api")


def header_timeout_protocol(timeout_s: float) -> type[H11Protocol]:
    """uvicorn's h11 protocol with a ``timeout_s`` limit on receiving each request's headers."""

    class HeaderTimeoutProtocol(H11Protocol):
        _header_timer: asyncio.TimerHandle | None = None
        _partial = False  # some bytes of the awaited headers arrived

        def _arm(self) -> None:
            self._disarm()
            self._partial = False
            self._header_timer = self.loop.call_later(timeout_s, self._headers_too_slow)

        def _disarm(self) -> None:
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

        def data_received(self, data: bytes) -> None:
            before = self.cycle
            super().data_received(data)
            if self.cycle is not before:  # the headers of a request are complete
                self._disarm()
                self._partial = False
            elif self._header_timer is not None:
                self._partial = True  # part of the next request's headers

        def on_response_complete(self) -> None:
            before = self.cycle
            super().on_response_complete()
            # kept alive and no pipelined request started: wait for the next request's headers
            if self.cycle is before and not self.transport.is_closing():
                self._arm()

        def handle_websocket_upgrade(self, event: Any) -> None:
            self._disarm()  # the connection belongs to the WebSocket protocol now
            super().handle_websocket_upgrade(event)

        def _headers_too_slow(self) -> None:
            self._header_timer = None
            if self.transport.is_closing():
                return
            if not self._partial:  # an idle connection: closed without a word, as keep-alive does
                self.transport.close()
                return
            log.warning("%s: request headers not received within %g s; connection closed",
                        "%s:%d" % self.client if self.client else "a client", timeout_s)
            r = response(Problem(408, f"the request headers did not arrive within {timeout_s:g} s",
                                 type_="header-timeout"), "", close=True)
            self.transport.write(b"HTTP/1.1 408 Request Timeout\r\n" + b"".join(
                k + b": " + v + b"\r\n" for k, v in r.raw_headers) + b"\r\n" + r.body)
            self.transport.close()

    return HeaderTimeoutProtocol


def run(app: Any, header_timeout_s: float, host: str, port: int, log_level: str) -> None:
    """Serve ``app`` in this process (several replicas: several processes on one PostgreSQL
    job store). Refuses (:class:`~api.errors.Exposed`) to serve an open app on an address
    other than loopback unless its settings say it is open on purpose."""
    import uvicorn

    from .auth import check_exposure
    from .pool import few_arenas
    from .routers.live import MAX_MESSAGE_BYTES

    few_arenas()  # before uvicorn's and the service's threads start
    ctx = app.state.ctx
    check_exposure(host, ctx.keys is not None, ctx.settings.open)

    uvicorn.run(app, host=host, port=port, log_level=log_level, timeout_graceful_shutdown=10,
                http=header_timeout_protocol(header_timeout_s), ws_max_size=MAX_MESSAGE_BYTES)
