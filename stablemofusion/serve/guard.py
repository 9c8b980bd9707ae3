"""The server's gate (pure ASGI middleware), checked before any route runs:

- the request line and headers together are at most MAX_HEADER_BYTES (431), however they arrived (uvicorn's own
  bound only holds while the headers are incomplete: a large block sent in one write passes it);
- the Host header names this machine (loopback names, plus ``--allow-host``): no DNS rebinding;
- a request with both Content-Length and Transfer-Encoding, or a malformed length, is refused (400);
- the body is read here, whatever its transfer encoding (chunked included), and refused (413) as soon as it
  passes the route's limit, or (408) when it does not arrive within BODY_TIMEOUT_S; the route gets it replayed;
- a WebSocket (/v1/stream) must name the server in its Host header too, and a browser's Origin header (if
  sent) must name an allowed host: a page of another site cannot open a stream (WebSockets skip CORS);
  refused before the handshake completes (HTTP 403);
- uploads (/v1/convert) are held against one budget for all clients (UPLOAD_BUDGET_BYTES): each reserves its
  declared size (or the largest allowed) before a byte is read and gives it back when answered; past the budget,
  503 at once, so many large uploads cannot take the server's memory;
- a POST of a file (/v1/convert) must be ``application/octet-stream`` or carry our own header, and a JSON
  route ``application/json``: a web page cannot send either without a CORS preflight, which is not answered.
"""

from __future__ import annotations

import asyncio
import json

from .http_errors import ServeError
from .server_limits import (BODY_TIMEOUT_S, CLIENT_HEADER, LOOPBACK_HOSTS, MAX_HEADER_BYTES, MAX_UPLOAD_BYTES,
                            UPLOAD_BUDGET_BYTES)

UPLOAD_PATHS = ("/v1/convert",)
JSON_PATHS = ("/v1/generate", "/v1/timeline")


def host_name(host: str) -> str:
    """'example.com:8000' -> 'example.com'; '[::1]:8000' -> '::1' (lower case)."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


class Guard:
    """Wraps an ASGI app with the checks above; ``max_body_bytes`` for JSON routes, MAX_UPLOAD_BYTES for
    uploads; ``allowed_hosts`` is added to the loopback names."""

    def __init__(self, app, *, max_body_bytes: int, allowed_hosts: tuple[str, ...] = (),
                 upload_budget: int = UPLOAD_BUDGET_BYTES):
        self.app, self.max_body_bytes = app, max_body_bytes
        self.hosts = {host_name(h) for h in (*LOOPBACK_HOSTS, *allowed_hosts)}
        self.upload_budget, self.uploads_held = upload_budget, 0  # bytes reserved by uploads being handled

    async def __call__(self, scope, receive, send):
        if scope["type"] in ("http", "websocket") and header_bytes(scope) > MAX_HEADER_BYTES:
            if scope["type"] == "websocket":
                return await send({"type": "websocket.close", "code": 1009})
            return await send_error(send, 431, f"request line and headers larger than {MAX_HEADER_BYTES} bytes")
        if scope["type"] == "websocket":
            if not self._websocket_allowed(_headers(scope)):
                return await send({"type": "websocket.close", "code": 1008})
            return await self.app(scope, receive, send)
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        reserved = 0
        try:
            headers = _headers(scope)
            self._check_headers(scope, headers)
            if scope["path"] in UPLOAD_PATHS:
                reserved = self._reserve(headers)
            body = await asyncio.wait_for(self._read(receive, self._limit(scope["path"])), BODY_TIMEOUT_S)
        except ServeError as e:
            self.uploads_held -= reserved
            return await send_error(send, e.status, e.message)
        except asyncio.TimeoutError:
            self.uploads_held -= reserved
            return await send_error(send, 408, f"the request body did not arrive within {BODY_TIMEOUT_S:g} s")
        except BaseException:
            self.uploads_held -= reserved
            raise
        try:
            await self.app(scope, _replay(body, receive), send)
        finally:
            self.uploads_held -= reserved

    def _reserve(self, headers: dict[bytes, list[bytes]]) -> int:
        """Reserve an upload's declared size (or the largest allowed) against the budget, or 503."""
        lengths = headers.get(b"content-length", [])
        size = int(lengths[0]) if lengths else MAX_UPLOAD_BYTES
        if self.uploads_held + size > self.upload_budget:
            raise ServeError(503, f"the server is reading other uploads ({self.uploads_held} bytes); retry shortly")
        self.uploads_held += size
        return size

    def _websocket_allowed(self, headers: dict[bytes, list[bytes]]) -> bool:
        """One allowed Host; no Origin (a program) or one whose host is allowed (our own page)."""
        hosts, origins = headers.get(b"host", []), headers.get(b"origin", [])
        if len(hosts) != 1 or host_name(hosts[0].decode("latin-1")) not in self.hosts or len(origins) > 1:
            return False
        if not origins:
            return True
        origin = origins[0].decode("latin-1")
        scheme, sep, rest = origin.partition("://")
        return bool(sep) and scheme.lower() in ("http", "https") and host_name(rest.split("/")[0]) in self.hosts

    def _limit(self, path: str) -> int:
        return MAX_UPLOAD_BYTES if path in UPLOAD_PATHS else self.max_body_bytes

    def _check_headers(self, scope, headers: dict[bytes, list[bytes]]) -> None:
        hosts = headers.get(b"host", [])
        if len(hosts) != 1 or host_name(hosts[0].decode("latin-1")) not in self.hosts:
            raise ServeError(400, "Host header not allowed (start the server with --allow-host NAME to add one)")
        lengths, encodings = headers.get(b"content-length", []), headers.get(b"transfer-encoding", [])
        if lengths and encodings:
            raise ServeError(400, "a request may not have both Content-Length and Transfer-Encoding")
        if len(lengths) > 1 or (lengths and not lengths[0].strip().isdigit()):
            raise ServeError(400, "Content-Length must be one number")
        limit = self._limit(scope["path"])
        if lengths and int(lengths[0]) > limit:
            raise ServeError(413, f"request body larger than {limit} bytes")
        if scope["method"] == "POST":
            self._check_content_type(scope["path"], headers)

    @staticmethod
    def _check_content_type(path: str, headers: dict[bytes, list[bytes]]) -> None:
        kind = b";".join(headers.get(b"content-type", [])).split(b";")[0].strip().lower()
        if path in UPLOAD_PATHS and kind != b"application/octet-stream" and CLIENT_HEADER.encode() not in headers:
            raise ServeError(415, f"send the file as Content-Type: application/octet-stream (or with an "
                                  f"{CLIENT_HEADER} header)")
        if path in JSON_PATHS and kind != b"application/json":
            raise ServeError(415, "send the request as Content-Type: application/json")

    @staticmethod
    async def _read(receive, limit: int) -> bytes:
        """The whole body, refused as soon as it passes ``limit`` bytes."""
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                raise ServeError(400, "the client disconnected")
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > limit:
                raise ServeError(413, f"request body larger than {limit} bytes")
            chunks.append(chunk)
            if not message.get("more_body", False):
                return b"".join(chunks)


def header_bytes(scope) -> int:
    """About the size of the request line and headers as sent: names, values, separators, the path and query."""
    line = len(scope.get("raw_path") or scope.get("path", "").encode()) + len(scope.get("query_string", b"")) + 16
    return line + sum(len(name) + len(value) + 4 for name, value in scope.get("headers", ()))


def _headers(scope) -> dict[bytes, list[bytes]]:
    out: dict[bytes, list[bytes]] = {}
    for name, value in scope["headers"]:
        out.setdefault(name.lower(), []).append(value)
    return out


def _replay(body: bytes, receive):
    """An ASGI receive that gives ``body`` once, then what the client sends next (its disconnect)."""
    sent = False

    async def replay():
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()
    return replay


async def send_error(send, status: int, message: str) -> None:
    """A complete ``{"error": message}`` response."""
    body = json.dumps({"error": message}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})
