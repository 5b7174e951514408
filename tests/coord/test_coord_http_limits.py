"""The coordinator's HTTP server bounds what slow or many clients can hold: a body must arrive
whole within `body_timeout_s` (408), a connection must send its request's headers within
`header_timeout_s` (closed), at most `max_connections` are served (503), and no header chooses
the address a client is counted under. Against a real uvicorn over raw sockets."""

from __future__ import annotations

import asyncio
import contextlib
import json
import select
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import FastAPI, Request

from crowdteleop.coord.app import create_app
from crowdteleop.coord.guard.http_limits import uvicorn_options
from tests.fixtures.coord import FakeLauncher, coord_config, served_app

pytestmark = pytest.mark.exclusive  # runs alone under xdist: request timeouts, timed

TIMEOUT_S = 1.5
SLACK = 3  # a connection must be answered or closed within SLACK * TIMEOUT_S


@contextlib.contextmanager
def _served(tmp_path: Path, **fields: Any) -> Iterator[tuple[str, FastAPI]]:
    """The coordinator (fake launcher) served as `crowdteleop serve` serves it: its URL, app."""
    config = coord_config(tmp_path, **fields)
    app = create_app(config, FakeLauncher())

    @app.get("/test/peer")  # only in these tests: the client address the app sees
    async def peer(request: Request) -> dict[str, str | None]:
        return {
            "host": request.client.host if request.client else None,
            "scheme": request.url.scheme,
        }

    @app.get("/test/slow")
    async def slow() -> dict[str, bool]:
        await asyncio.sleep(2 * TIMEOUT_S)
        return {"ok": True}

    with served_app(app, config) as url:
        yield url, app


def _connect(url: str) -> socket.socket:
    host, port = url.removeprefix("http://").split(":")
    return socket.create_connection((host, int(port)), timeout=10)


def _dribble(sock: socket.socket, data: bytes, every_s: float, limit_s: float) -> bytes | None:
    """Sends `data` a byte every `every_s` until the server answers and closes; everything
    it sent then, or None if the connection was still open after `limit_s`."""
    deadline = time.monotonic() + limit_s
    sent = 0
    while time.monotonic() < deadline:
        readable, _, _ = select.select([sock], [], [], every_s)
        if readable:
            return _read_to_close(sock, deadline)
        if sent < len(data):
            sock.sendall(data[sent : sent + 1])
            sent += 1
    return None


def _read_to_close(sock: socket.socket, deadline: float) -> bytes | None:
    received = b""
    while True:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            chunk = sock.recv(65536)
        except ConnectionResetError:
            return received
        except TimeoutError:
            return None  # answered but left open
        if not chunk:
            return received
        received += chunk


def _read_response(sock: socket.socket) -> tuple[int, bytes]:
    """One whole response (status, body) on a connection that stays open."""
    received = b""
    while b"\r\n\r\n" not in received:
        received += sock.recv(65536)
    head, body = received.split(b"\r\n\r\n", 1)
    lines = head.decode().split("\r\n")
    length = next(int(v) for k, _, v in (x.partition(": ") for x in lines) if k == "content-length")
    while len(body) < length:
        body += sock.recv(65536)
    return int(lines[0].split()[1]), body


def test_a_body_sent_slowly_gets_408_and_its_connection_closes(tmp_path):
    body = json.dumps({"params": {}}).encode()
    with _served(tmp_path, body_timeout_s=TIMEOUT_S) as (url, _), _connect(url) as sock:
        head = "POST /api/join HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
        sock.sendall(f"{head}Content-Length: {len(body) + 1000}\r\n\r\n".encode())
        began = time.monotonic()
        answer = _dribble(sock, body, every_s=0.25, limit_s=SLACK * TIMEOUT_S)
        assert answer is not None, "the slow body was still being read"
        took = time.monotonic() - began
        assert TIMEOUT_S * 0.9 <= took < SLACK * TIMEOUT_S
        status, _, rest = answer.partition(b"\r\n")
        assert status.startswith(b"HTTP/1.1 408"), answer
        assert b"x-frame-options: deny" in rest.lower(), "the security headers are there too"
        assert json.loads(rest.split(b"\r\n\r\n", 1)[1])["error"] == "timeout"
        response = httpx.post(f"{url}/api/join", json={"params": {}}, timeout=10)
        assert response.status_code == 200, "a whole body right after is served"


def test_a_body_slower_than_the_header_timeout_but_in_time_is_served(tmp_path):
    """Only headers have `header_timeout_s`: a body and a slow handler are not cut by it."""
    body = json.dumps({"params": {}}).encode().ljust(40)
    fields = {"header_timeout_s": TIMEOUT_S, "body_timeout_s": 4 * TIMEOUT_S}
    with _served(tmp_path, **fields) as (url, _), _connect(url) as sock:
        head = "POST /api/join HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
        sock.sendall(f"{head}Content-Length: {len(body)}\r\n\r\n".encode())
        for start in range(0, len(body), len(body) // 4):  # over ~2 header timeouts
            sock.sendall(body[start : start + len(body) // 4])
            time.sleep(TIMEOUT_S / 2)
        status, answer = _read_response(sock)
        assert status == 200 and json.loads(answer)["worker_id"], answer
        sock.sendall(b"GET /test/slow HTTP/1.1\r\nHost: x\r\n\r\n")
        assert _read_response(sock)[0] == 200, "a handler slower than the timeout finishes"


@pytest.mark.parametrize("after_a_response", [False, True], ids=["new", "keep-alive"])
def test_a_connection_slow_to_send_its_headers_is_closed(tmp_path, after_a_response):
    with _served(tmp_path, header_timeout_s=TIMEOUT_S) as (url, _), _connect(url) as sock:
        if after_a_response:  # uvicorn's keep-alive timer stops at the first byte that comes
            sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n")
            assert _read_response(sock)[0] == 200
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\n")
        began = time.monotonic()
        answer = _dribble(sock, b"X-Slow: " + b"a" * 200, every_s=0.25, limit_s=SLACK * TIMEOUT_S)
        assert answer == b"", "closed without an answer (still open: None)"
        assert TIMEOUT_S * 0.9 <= time.monotonic() - began < SLACK * TIMEOUT_S
        assert httpx.get(f"{url}/health", timeout=10).status_code == 200


def test_forwarded_headers_from_loopback_do_not_change_the_client_the_app_sees(tmp_path):
    """Rate limits count `request.client.host` (or what trusted proxies say, decided by the
    app): uvicorn must not rewrite it from a header, even for a peer on loopback."""
    forged = {"X-Forwarded-For": "203.0.113.9", "X-Forwarded-Proto": "https"}
    with _served(tmp_path) as (url, _):
        seen = httpx.get(f"{url}/test/peer", headers=forged, timeout=10).json()
    assert seen == {"host": "127.0.0.1", "scheme": "http"}


def test_the_uvicorn_options_take_no_address_from_headers_and_apply_the_limits(tmp_path):
    config = coord_config(tmp_path, max_connections=7, header_timeout_s=2.5)
    options = uvicorn_options(config)
    assert options["proxy_headers"] is False and not options["forwarded_allow_ips"]
    assert options["limit_concurrency"] == 7
    assert options["http"].header_timeout_s == 2.5


def test_a_request_beyond_max_connections_gets_503_until_some_close(tmp_path):
    with contextlib.ExitStack() as stack:
        url, _ = stack.enter_context(_served(tmp_path, max_connections=3))
        held = [stack.enter_context(_connect(url)) for _ in range(3)]
        assert _status_within(f"{url}/health", 503, 5.0), "the limit was not applied"
        for sock in held:
            sock.close()
        assert _status_within(f"{url}/health", 200, 5.0), "served again once they closed"


def _status_within(url: str, status: int, limit_s: float) -> bool:
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if httpx.get(url, timeout=10).status_code == status:
            return True
        time.sleep(0.1)
    return False


def test_connections_to_the_coordinators_listener_send_without_waiting_for_acks():
    """Nagle off (TCP_NODELAY) on every accepted connection: with it on, each request on a
    kept-alive connection waited ~40 ms for the client's delayed ACK (benchmarks/coord_http.py)."""
    from crowdteleop.coord.guard.http_limits import listening_socket

    async def accepted_nodelay() -> int:
        seen: asyncio.Future[int] = asyncio.get_running_loop().create_future()

        def on_connection(_reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            sock = writer.get_extra_info("socket")
            seen.set_result(sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
            writer.close()

        listener = listening_socket("127.0.0.1", 0)
        server = await asyncio.start_server(on_connection, sock=listener)
        _reader, writer = await asyncio.open_connection(*listener.getsockname())
        try:
            return await asyncio.wait_for(seen, 5)
        finally:
            writer.close()
            server.close()
            await server.wait_closed()

    assert asyncio.run(accepted_nodelay()) != 0
