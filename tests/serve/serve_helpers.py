"""Helpers of the serve tests: requests through the ASGI app, and a live uvicorn server on a free loopback
port (configured as `smf serve` configures it)."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time

import httpx

OCTETS = {"Content-Type": "application/octet-stream"}


def call(app, *requests):
    """Send (method, url, json) requests concurrently to the app; returns the responses."""
    async def go():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
            return await asyncio.gather(*[client.request(m, u, json=j) for m, u, j in requests])
    return asyncio.run(go())


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def live_server(app, **overrides):
    """``app`` served by uvicorn on 127.0.0.1 (a free port) in a thread; yields its base URL."""
    import uvicorn

    from stablemofusion.serve.server import uvicorn_config

    port = free_port()
    srv = uvicorn.Server(uvicorn_config(app, "127.0.0.1", port, **overrides))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not srv.started and time.monotonic() < deadline:
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        srv.should_exit = True
        thread.join(10)


class VirtualClockLoop(asyncio.SelectorEventLoop):
    """An event loop on a virtual clock: whenever nothing is ready it jumps to its next timer instead of waiting,
    so code that paces itself by ``loop.time()`` and ``asyncio.sleep`` runs at once, and the times it sees are
    exactly those it scheduled (no wall clock in the test). Callbacks from other threads still arrive (the
    selector is polled), but the clock does not wait for them: use it with code that only awaits the loop."""

    def __init__(self):
        super().__init__()
        self._virtual = 0.0
        real, loop = self._selector, self

        class Selector:
            def select(self, timeout=None):
                events = real.select(0)
                if not events and timeout is not None and timeout > 0:
                    loop._virtual += timeout
                return events

            def __getattr__(self, name):
                return getattr(real, name)

        self._selector = Selector()

    def time(self) -> float:
        return self._virtual


def run_virtual(coroutine):
    """Run ``coroutine`` to its end on a :class:`VirtualClockLoop`."""
    loop = VirtualClockLoop()
    try:
        return loop.run_until_complete(coroutine)
    finally:
        loop.close()
