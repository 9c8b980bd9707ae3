"""uvicorn, configured so that no connection can hold the server: a deadline for a request's headers (a
half-open connection is closed), a keep-alive timeout, a cap on concurrent connections, a cap on header size,
and a short graceful shutdown after SIGTERM (the app's shutdown then stops the worker process)."""

from __future__ import annotations

from collections import OrderedDict

from uvicorn.protocols.http.h11_impl import H11Protocol

from .server_limits import (EVICT_RESERVE, GRACEFUL_SHUTDOWN_S, HEADER_TIMEOUT_S, KEEP_ALIVE_S, MAX_CONNECTIONS,
                            MAX_HEADER_BYTES, MAX_STREAM_MESSAGE_BYTES)


def header_timeout_protocol(seconds: float = HEADER_TIMEOUT_S, evict_at: int = MAX_CONNECTIONS - EVICT_RESERVE) -> type:
    """uvicorn's h11 protocol, closing a connection that has not sent a request's complete headers within
    ``seconds`` of connecting (or of its first bytes after a response); and when a new connection brings the
    server to ``evict_at`` connections, closing the oldest of those still waiting for their headers (idle or
    half-sent: all clients may share one address, so a flood of them must not hold the cap that makes the
    server answer 503)."""
    waiting: OrderedDict = OrderedDict()  # the connections whose header timer runs, oldest first
    evicted: set = set()  # closed by eviction, not yet gone from the server's connections

    class HeaderTimeoutH11(H11Protocol):
        _header_timer = None
        _armed_cycle = None

        def connection_made(self, transport) -> None:
            super().connection_made(transport)
            self._arm()
            excess = len(self.server_state.connections) - len(evicted) - evict_at + 1
            for old in [c for c in waiting if c is not self][:max(0, excess)]:
                old._disarm()
                evicted.add(old)
                old.transport.close()

        def data_received(self, data: bytes) -> None:
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


def uvicorn_config(app, host: str, port: int, *, header_timeout: float = HEADER_TIMEOUT_S, **overrides):
    """The uvicorn.Config `smf serve` runs with (tests use it with a free port and shorter timeouts)."""
    import uvicorn

    settings = dict(host=host, port=port, log_level="warning", http=header_timeout_protocol(header_timeout),
                    timeout_keep_alive=KEEP_ALIVE_S, limit_concurrency=MAX_CONNECTIONS,
                    h11_max_incomplete_event_size=MAX_HEADER_BYTES, timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S,
                    server_header=False, ws="websockets-sansio", ws_max_size=MAX_STREAM_MESSAGE_BYTES)
    return uvicorn.Config(app, **{**settings, **overrides})
