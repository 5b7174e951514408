"""What one HTTP request to the coordinator costs a page: on a kept-alive connection (what
browsers do: heartbeats, the join page's region pings) and on a new connection each time,
with the coordinator's listener as it is (`listening_socket`: Nagle off) and as it was before
2026-12-03 (a plain `socket.socket()`, on which asyncio leaves Nagle on), in one run.

    .venv/bin/python benchmarks/coord_http.py --runs 5 --requests 50 --json out/coord-http.json

The real app (`create_app`, SQLite, its local launcher idle) served by uvicorn in this process,
with `crowdteleop serve`'s limits; requests from httpx on loopback.
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import uvicorn

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from crowdteleop.coord.app import create_app  # noqa: E402
from crowdteleop.coord.guard.http_limits import listening_socket, uvicorn_options  # noqa: E402
from crowdteleop.coord.service.config import CoordConfig  # noqa: E402

PATHS = ("/health", "/api/ping", "/api/campaigns/default")
ADMIN = "bench-admin-token-0123456789abcdef"


def plain_socket(host: str, port: int) -> socket.socket:
    """The listener as `crowdteleop serve` made it before: protocol 0, so no TCP_NODELAY."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    return sock


@contextmanager
def served(listener: Callable[[str, int], socket.socket], work: Path) -> Iterator[str]:
    config = CoordConfig(
        admin_token=ADMIN,
        database_url=f"sqlite:///{work / 'coord.sqlite3'}",
        data_dir=work / "data",
        spare_servers=0,
    )
    sock = listener("127.0.0.1", 0)
    server = uvicorn.Server(
        uvicorn.Config(create_app(config), log_level="warning", **uvicorn_options(config))
    )
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        server.should_exit = True
        thread.join(30)


def timed_ms(client: httpx.Client, url: str) -> float:
    started = time.perf_counter()
    client.get(url).raise_for_status()
    return (time.perf_counter() - started) * 1000


def measure(base: str, path: str, requests: int) -> dict[str, float]:
    """Median ms per request: kept alive (after one to open it), and a new connection each."""
    with httpx.Client() as client:
        timed_ms(client, base + path)
        kept = statistics.median(timed_ms(client, base + path) for _ in range(requests))
    fresh = []
    for _ in range(requests):
        with httpx.Client() as client:
            fresh.append(timed_ms(client, base + path))
    return {"kept_alive_ms": kept, "new_connection_ms": statistics.median(fresh)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--requests", type=int, default=50, help="per path, per run")
    parser.add_argument("--json", type=Path, default=None)
    options = parser.parse_args()
    listeners = {"before (plain socket)": plain_socket, "now (listening_socket)": listening_socket}
    raw: dict[str, dict[str, list[dict[str, float]]]] = {name: {} for name in listeners}
    for run in range(options.runs):
        for name, listener in listeners.items():
            with tempfile.TemporaryDirectory() as work, served(listener, Path(work)) as base:
                for path in PATHS:
                    raw[name].setdefault(path, []).append(measure(base, path, options.requests))
        print(f"run {run + 1}/{options.runs} done", file=sys.stderr)
    print(f"{'listener':24} {'path':24} {'kept alive ms':>14} {'new conn. ms':>13}")
    for name, paths in raw.items():
        for path, runs in paths.items():
            kept = statistics.median(r["kept_alive_ms"] for r in runs)
            fresh = statistics.median(r["new_connection_ms"] for r in runs)
            print(f"{name:24} {path:24} {kept:14.1f} {fresh:13.1f}")
    if options.json is not None:
        options.json.parent.mkdir(parents=True, exist_ok=True)
        options.json.write_text(json.dumps(raw, indent=1))


if __name__ == "__main__":
    main()
