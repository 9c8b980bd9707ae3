"""uvicorn, configured so that no connection can hold the server: a deadline for a request's headers (a
half-open connection is closed), a keep-alive timeout, a cap on concurrent connections, a cap on header size,
and a short graceful shutdown after SIGTERM (the app's shutdown then stops the worker process).

Past the cap every refusal is an answer, never a reset: a request over the cap gets the JSON 503 every other
refusal gets (:class:`Capped`), and a connection closed to make room (the oldest still without a request) is first
sent that 503 and half-closed, so that its client reads it whenever it sends its request."""

from __future__ import annotations

import json
from collections import OrderedDict

from uvicorn.protocols.http.h11_impl import H11Protocol

from .server_limits import (EVICT_RESERVE, GRACEFUL_SHUTDOWN_S, HEADER_TIMEOUT_S, KEEP_ALIVE_S, MAX_CONNECTIONS,
                            MAX_HEADER_BYTES, MAX_LINGERING, MAX_STREAM_MESSAGE_BYTES, REFUSED_LINGER_S)

AT_CAPACITY = f"the server is at its limit of {MAX_CONNECTIONS} connections; retry shortly"
_BUSY_BODY = json.dumps({"error": AT_CAPACITY}).encode()
BUSY_RESPONSE = (b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\nretry-after: 1\r\n"
                 b"connection: close\r\ncontent-length: " + str(len(_BUSY_BODY)).encode() + b"\r\n\r\n" + _BUSY_BODY)


def header_timeout_protocol(seconds: float = HEADER_TIMEOUT_S, evict_at: int = MAX_CONNECTIONS - EVICT_RESERVE) -> type:
    """uvicorn's h11 protocol, closing a connection that has not sent a request's complete headers within
    ``seconds`` of connecting (or of its first bytes after a response); and when a new connection brings the
    server to ``evict_at`` connections, closing the oldest of those still waiting for their headers (idle or
    half-sent: all clients may share one address, so a flood of them must not hold the cap that makes the
    server answer 503)."""
    waiting: OrderedDict = OrderedDict()  # the connections whose header timer runs, oldest first
    evicted: set = set()  # refused to make room, not yet gone from the server's connections

    class HeaderTimeoutH11(H11Protocol):
        _header_timer = None
        _armed_cycle = None
        _refused = False
        connections: set = set()  # the server's open connections (what :class:`Capped` counts) ...
        refused = evicted  # ... less those refused, closing

        def connection_made(self, transport) -> None:
            super().connection_made(transport)
            HeaderTimeoutH11.connections = self.server_state.connections
            self._arm()
            excess = len(self.server_state.connections) - len(evicted) - evict_at + 1
            for old in [c for c in waiting if c is not self][:max(0, excess)]:
                old._refuse()

        def _refuse(self) -> None:
            """Answer 503 before any request, stop sending, and close once the client has had time to read it (a
            close with its request unread would reach it as a reset)."""
            self._disarm()
            evicted.add(self)
            self._refused = True
            self.transport.write(BUSY_RESPONSE)
            if len(evicted) > MAX_LINGERING or not self.transport.can_write_eof():
                self.transport.close()  # a flood: sockets stay bounded, its answer may arrive as a reset
                return
            self.transport.write_eof()
            self.loop.call_later(REFUSED_LINGER_S, self.transport.close)

        def data_received(self, data: bytes) -> None:
            if self._refused:
                return  # answered already: what it sends is read and dropped
            if self._header_timer is None and (self.cycle is None or self.cycle.response_complete):
                self._arm()
            super().data_received(data)
            if self.cycle is not self._armed_cycle:  # a request's headers arrived: no longer waiting
                self._disarm()

        def connection_lost(self, exc) -> None:
            self._disarm()
            evicted.discard(self)
            super().connection_lost(exc)

        def handle_websocket_upgrade(self, event) -> None:
            self._disarm()  # the headers are complete: the WebSocket (a live stream) may stay open
            super().handle_websocket_upgrade(event)

        def _arm(self) -> None:
            self._armed_cycle = self.cycle
            self._header_timer = self.loop.call_later(seconds, self._expired)
            waiting[self] = None

        def _disarm(self) -> None:
            waiting.pop(self, None)
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _expired(self) -> None:
            waiting.pop(self, None)
            self._header_timer = None
            if self.cycle is self._armed_cycle and not self.transport.is_closing():
                self.transport.close()  # no new request's headers arrived in time

    return HeaderTimeoutH11


class Capped:
    """``app`` answering a JSON 503 (``Retry-After: 1``) to a request that arrives while the server holds more than
    ``limit`` connections (counted by ``protocol``, :func:`header_timeout_protocol`'s class, less those it is
    closing); a live stream is told so and closed with 1013 (try again later), as at the stream limit. uvicorn's
    own cap would answer in plain text. Anything else (``state``) is the app's."""

    def __init__(self, app, protocol: type, limit: int = MAX_CONNECTIONS):
        self.app, self.protocol, self.limit = app, protocol, limit

    def __getattr__(self, name: str):
        return getattr(self.app, name)

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] in ("http", "websocket") and (
                len(self.protocol.connections) - len(self.protocol.refused) > self.limit):
            if scope["type"] == "websocket":  # as the stream limit is said (serve/live.py): accepted, told, closed
                await receive()  # websocket.connect
                await send({"type": "websocket.accept"})
                await send({"type": "websocket.send", "text": json.dumps({"type": "error", "error": AT_CAPACITY})})
                await send({"type": "websocket.close", "code": 1013})
                return
            await send({"type": "http.response.start", "status": 503,
                        "headers": [(b"content-type", b"application/json"), (b"retry-after", b"1"),
                                    (b"connection", b"close"), (b"content-length", str(len(_BUSY_BODY)).encode())]})
            await send({"type": "http.response.body", "body": _BUSY_BODY})
            return
        await self.app(scope, receive, send)


def uvicorn_config(app, host: str, port: int, *, header_timeout: float = HEADER_TIMEOUT_S, **overrides):
    """The uvicorn.Config `smf serve` runs with (tests use it with a free port and shorter timeouts)."""
    import uvicorn

    protocol = header_timeout_protocol(header_timeout)
    settings = dict(host=host, port=port, log_level="warning", http=protocol,
                    timeout_keep_alive=KEEP_ALIVE_S,
                    h11_max_incomplete_event_size=MAX_HEADER_BYTES, timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S,
                    server_header=False, ws="websockets-sansio", ws_max_size=MAX_STREAM_MESSAGE_BYTES)
    return uvicorn.Config(Capped(app, protocol), **{**settings, **overrides})
