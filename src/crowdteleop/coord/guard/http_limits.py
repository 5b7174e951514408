"""Size, time and connection limits of the coordinator's HTTP server, so big, slow or many
clients cannot hold it (docs/coordination.md, "Configuration").

- `BodyLimitMiddleware`: a request body over `max_body_bytes` is refused (413) before any
  handler reads it.
- `BodyTimeoutMiddleware`: a request body must arrive whole within `body_timeout_s` of the
  first read, else 408 and the connection is closed.
- `HeaderTimeoutProtocol`: a connection must send a request's headers within
  `header_timeout_s` of being opened (or of its previous response), else it is closed.
- `uvicorn_options`: how both listeners are served: no address taken from headers (the app
  decides which proxies to believe: `CoordConfig.trusted_proxies`), at most
  `max_connections` connections, the header timeout's protocol.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from typing import Any, Protocol

import h11
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from uvicorn.protocols.http.h11_impl import H11Protocol

from crowdteleop.coord.guard.errors import error_response

log = logging.getLogger(__name__)

KEEP_ALIVE_S = 5  # uvicorn's default: an idle keep-alive connection is closed after this


class BodyLimitMiddleware:
    """Refuses bodies over `max_bytes` (413) before any handler reads them."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope.get("headers") or []).get(b"content-length")
        if declared is not None:
            try:
                too_big = int(declared) > self.max_bytes
            except ValueError:
                too_big = False  # the server refuses a malformed length itself
            if too_big:
                await self._refuse(scope, receive, send)
                return
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                await self.app(scope, _replay([message], receive), send)
                return
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_bytes:
                await self._refuse(scope, receive, send)
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        body = {"type": "http.request", "body": b"".join(chunks), "more_body": False}
        await self.app(scope, _replay([body], receive), send)

    async def _refuse(self, scope: Scope, receive: Receive, send: Send) -> None:
        message = f"request bodies are limited to {self.max_bytes} bytes"
        await error_response(413, "too_large", message)(scope, receive, send)


def _replay(messages: list[Message], receive: Receive) -> Receive:
    pending = list(messages)

    async def replayed() -> Message:
        if pending:
            return pending.pop(0)
        return await receive()

    return replayed


class BodyTimeoutError(Exception):
    """The request body did not arrive whole before its deadline."""


class BodyTimeoutMiddleware:
    """Bounds the time from the first read of a request body to its last byte (408 after).

    It reads nothing itself: it hands the app inside it (`BodyLimitMiddleware`, the one place
    that reads bodies) a `receive` that fails once the deadline has passed while the body is
    still incomplete. After the body's last part, `receive` is the server's own again, so an
    app waiting for the client to disconnect is never cut short. The 408 says
    `Connection: close`: the rest of the body is never read.
    """

    def __init__(self, app: ASGIApp, timeout_s: float) -> None:
        self.app, self.timeout_s = app, timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        deadline: float | None = None
        body_done = False
        started = False

        async def bounded_receive() -> Message:
            nonlocal deadline, body_done
            if body_done:
                return await receive()
            loop = asyncio.get_running_loop()
            if deadline is None:
                deadline = loop.time() + self.timeout_s
            try:
                async with asyncio.timeout_at(deadline):
                    message = await receive()
            except TimeoutError:
                raise BodyTimeoutError from None
            if message["type"] != "http.request" or not message.get("more_body", False):
                body_done = True
            return message

        async def watched_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, bounded_receive, watched_send)
        except BodyTimeoutError:
            client = scope.get("client")
            log.info("request body from %s too slow: 408", client[0] if client else "?")
            if started:
                return  # the server closes a response left unfinished
            message = f"the request body did not arrive within {self.timeout_s:g} s"
            response = error_response(408, "timeout", message, {"Connection": "close"})
            await response(scope, receive, send)


class HeaderTimeoutProtocol(H11Protocol):
    """uvicorn's h11 protocol, closing connections that are slow to send a request's headers.

    uvicorn (checked at 0.54, h11_impl.py and httptools_impl.py) starts no timer when a
    connection opens, and its keep-alive timer is cancelled by any byte that arrives, so a
    client sending a header line now and then holds a connection (and with it a slot of
    `limit_concurrency`) for as long as it likes. Here a deadline starts whenever the
    connection waits for a request's headers: when it opens, and when a response is done on a
    keep-alive connection. Bytes arriving do not move it; the headers being complete (h11 no
    longer IDLE on the client's side) cancel it. On expiry the connection is closed without an
    answer, as uvicorn's keep-alive timeout does. TLS handshakes come before `connection_made`
    and are bounded by asyncio's `ssl_handshake_timeout` (60 s). Request bodies are
    `BodyTimeoutMiddleware`'s.

    `uvicorn_options` passes this class as `http=`, so the h11 implementation is used even
    where httptools is installed. `header_timeout_s` is set on a subclass made per config
    (`with_header_timeout`): uvicorn builds protocols from the class itself.
    """

    header_timeout_s: float = 10.0

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._headers_deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._watch_headers()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._watch_headers()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._watch_headers()

    def connection_lost(self, exc: Exception | None) -> None:
        self._stop_headers_deadline()
        super().connection_lost(exc)

    def _watch_headers(self) -> None:
        waiting = self.conn.their_state is h11.IDLE and not self.transport.is_closing()
        if not waiting:
            self._stop_headers_deadline()
        elif self._headers_deadline is None:
            self._headers_deadline = self.loop.call_later(
                self.header_timeout_s, self._headers_too_slow
            )

    def _stop_headers_deadline(self) -> None:
        if self._headers_deadline is not None:
            self._headers_deadline.cancel()
            self._headers_deadline = None

    def _headers_too_slow(self) -> None:
        self._headers_deadline = None
        if self.transport.is_closing():
            return
        log.debug("closing %s: no request headers within %g s", self.client, self.header_timeout_s)
        self.conn.send(h11.ConnectionClosed())
        self.transport.close()


def with_header_timeout(timeout_s: float) -> type[HeaderTimeoutProtocol]:
    """`HeaderTimeoutProtocol` closing after `timeout_s` (a subclass: uvicorn takes a class)."""

    class Limited(HeaderTimeoutProtocol):
        header_timeout_s = timeout_s

    return Limited


def listening_socket(host: str, port: int) -> socket.socket:
    """A bound TCP socket for uvicorn's `sockets=`.

    Made with `IPPROTO_TCP` named: asyncio turns Nagle's algorithm off (TCP_NODELAY) only on
    connections whose socket says TCP, and a plain `socket.socket()` says 0. With Nagle on,
    every request on a kept-alive connection waited ~40 ms for the client's delayed ACK
    between the response's headers and its body (benchmarks/coord_http.py)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    return sock


class ConnectionLimits(Protocol):
    """What a listener's limits are read from (the coordinator's settings)."""

    @property
    def max_connections(self) -> int: ...

    @property
    def header_timeout_s(self) -> float: ...


def uvicorn_options(config: ConnectionLimits) -> dict[str, Any]:
    """`uvicorn.Config` keyword arguments for a listener of the coordinator.

    `proxy_headers=False`: uvicorn would otherwise rewrite the client's address from
    `X-Forwarded-For` for any peer on loopback, letting a local client (or anyone behind a
    local proxy) choose the address the rate limits count; which proxies to believe is the
    app's decision (`CoordConfig.trusted_proxies`). `limit_concurrency`: a request arriving
    while `max_connections` connections are open (itself included) gets 503.
    """
    return {
        "proxy_headers": False,
        "forwarded_allow_ips": [],
        "limit_concurrency": config.max_connections,
        "http": with_header_timeout(config.header_timeout_s),
        "timeout_keep_alive": KEEP_ALIVE_S,
    }
