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
