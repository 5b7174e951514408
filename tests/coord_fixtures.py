"""Fixtures for the coordination server's tests: databases (SQLite and the machine's real
PostgreSQL), an in-process app with a fake launcher, and a real `crowdteleop serve` process."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import secrets
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest
from aiohttp import web

from crowdteleop.coord.app import create_app
from crowdteleop.coord.config import CoordConfig
from crowdteleop.teleop.config import TeleopConfig
from tests.ready import stop_gracefully, wait_ready

ADMIN = "admin-token-for-tests-0123456789"
POSTGRES_ADMIN_URL = os.environ.get(
    "CROWDTELEOP_TEST_POSTGRES", "postgresql://postgres@127.0.0.1:5432/test"
)


# --- databases ------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def postgres_database() -> Iterator[str]:
    """A database of its own on the machine's PostgreSQL for this test run, dropped after."""
    import psycopg

    name = f"crowdteleop_test_{secrets.token_hex(4)}"
    try:
        admin = psycopg.connect(POSTGRES_ADMIN_URL, autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as exc:
        pytest.fail(
            f"PostgreSQL is not reachable at {POSTGRES_ADMIN_URL} ({exc}). The database tests "
            "run against a real PostgreSQL: `bash scripts/system-deps.sh test` installs and "
            "starts it (or set CROWDTELEOP_TEST_POSTGRES to another server's URL).",
            pytrace=False,
        )
    with admin:
        admin.execute(f'CREATE DATABASE "{name}"')
    base = POSTGRES_ADMIN_URL.rsplit("/", 1)[0]
    try:
        yield f"{base}/{name}"
    finally:
        with psycopg.connect(POSTGRES_ADMIN_URL, autocommit=True) as admin:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """An empty database of each kind; on PostgreSQL, a fresh schema-less database per test."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'coord.sqlite3'}"
        return
    import psycopg

    server = request.getfixturevalue("postgres_database")
    with psycopg.connect(server, autocommit=True) as db:
        db.execute("DROP SCHEMA public CASCADE")
        db.execute("CREATE SCHEMA public")
    yield server


# --- a fake launcher: instant "teleop servers" that answer offers ---------------------------


@dataclass
class FakeHandle:
    url: str
    config: TeleopConfig
    runner: web.AppRunner
    alive: bool = True
    offers: list[dict[str, Any]] = field(default_factory=list)


class FakeLauncher:
    """Starts a tiny aiohttp server per session that records offers and answers them."""

    def __init__(self, start_delay_s: float = 0.0, fail: bool = False) -> None:
        self.start_delay_s, self.fail = start_delay_s, fail
        self.handles: dict[str, FakeHandle] = {}
        self.stopped: list[str] = []

    async def start(self, config: TeleopConfig) -> FakeHandle:
        await asyncio.sleep(self.start_delay_s)
        if self.fail:
            from crowdteleop.coord.launcher import LaunchError

            raise LaunchError("fake launcher told to fail")
        handle: FakeHandle

        async def offer(request: web.Request) -> web.Response:
            body = await request.json()
            handle.offers.append(body)
            if body.get("token") != config.token:
                return web.json_response({"error": "bad_token", "message": "no"}, status=401)
            if body.get("sdp") == "bad":
                return web.json_response({"error": "invalid_sdp", "message": "bad"}, status=400)
            return web.json_response({"sdp": "v=0 answer", "type": "answer", "peer_id": "p1"})

        app = web.Application()
        app.add_routes([web.post("/offer", offer)])
        runner = web.AppRunner(app)
        await runner.setup()
        site = web.TCPSite(runner, "127.0.0.1", 0)
        await site.start()
        port = runner.addresses[0][1]
        handle = FakeHandle(f"http://127.0.0.1:{port}", config, runner)
        self.handles[config.session_id] = handle
        return handle

    async def stop(self, handle: FakeHandle) -> None:
        if handle.alive:
            handle.alive = False
            self.stopped.append(handle.config.session_id)
            await handle.runner.cleanup()

    def alive(self, handle: FakeHandle) -> bool:
        return handle.alive


def coord_config(tmp_path: Path, database_url: str | None = None, **fields: Any) -> CoordConfig:
    values: dict[str, Any] = {
        "database_url": database_url or f"sqlite:///{tmp_path / 'coord.sqlite3'}",
        "data_dir": tmp_path / "data",
        "admin_token": ADMIN,
        "public_url": "http://testserver",
        "reaper_interval_s": 0.2,
        "spare_servers": 0,  # tests of spares ask for them
    }
    values.update(fields)
    return CoordConfig.model_validate(values)


@contextlib.contextmanager
def in_process_app(config: CoordConfig, launcher: Any) -> Iterator[Any]:
    """The app in a TestClient (its lifespan and background tasks run in a portal thread)."""
    from fastapi.testclient import TestClient

    app = create_app(config, launcher)
    with TestClient(app, raise_server_exceptions=False) as client:
        client.app_state = app.state  # type: ignore[attr-defined]
        yield client


class Api:
    """Shorthands over an httpx-style client for a worker's calls."""

    def __init__(self, client: Any) -> None:
        self.client = client

    def join(self, params: dict[str, str] | None = None, **extra: Any) -> dict[str, Any]:
        response = self.client.post("/api/join", json={"params": params or {}, **extra})
        assert response.status_code == 200, response.text
        return response.json()

    def auth(self, token: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {token}"}

    def new_session(self, token: str) -> dict[str, Any]:
        response = self.client.post("/api/sessions", headers=self.auth(token))
        assert response.status_code == 200, response.text
        return response.json()

    def session(self, token: str, sid: str) -> dict[str, Any]:
        response = self.client.get(f"/api/sessions/{sid}", headers=self.auth(token))
        assert response.status_code == 200, response.text
        return response.json()

    def heartbeat(self, token: str, sid: str, **body: Any) -> dict[str, Any]:
        response = self.client.post(
            f"/api/sessions/{sid}/heartbeat", headers=self.auth(token), json=body or None
        )
        assert response.status_code == 200, response.text
        return response.json()

    def admin(self, path: str) -> dict[str, Any]:
        response = self.client.get(f"/api/admin/{path}", headers=self.auth(ADMIN))
        assert response.status_code == 200, response.text
        return response.json()

    def wait_state(
        self, token: str, sid: str, state: str, timeout: float = 10.0, beat: bool = True
    ) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            view = self.heartbeat(token, sid) if beat else self.session(token, sid)
            if view["state"] == state or time.monotonic() > deadline:
                assert view["state"] == state, view
                return view
            time.sleep(0.1)


# --- a real `crowdteleop serve` process -----------------------------------------------------


@dataclass
class CoordProcess:
    url: str
    process: subprocess.Popen[str]
    log_path: Path
    data_dir: Path

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def client(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, timeout=30)


@contextlib.contextmanager
def coord_server(tmp_path: Path, *args: str, **config: Any) -> Iterator[CoordProcess]:
    """`crowdteleop serve --port 0` with `config` (CoordConfig fields) in a file; SIGINT at the
    end, and every teleop server it started must be gone after."""
    data_dir = tmp_path / "coord"
    data_dir.mkdir(parents=True, exist_ok=True)
    config_path = data_dir / "coord.json"
    config_path.write_text(json.dumps({"reaper_interval_s": 0.5, "spare_servers": 0, **config}))
    log_path = data_dir / "coord.log"
    log_file = log_path.open("w")
    command = [sys.executable, "-m", "crowdteleop", "serve", "--port", "0"]
    command += ["--data-dir", str(data_dir), "--config", str(config_path)]
    command += ["--admin-token", ADMIN, *args]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log_file, text=True)
    try:
        url = wait_ready(process, log_path, 60.0, "coordinator")
        yield CoordProcess(url, process, log_path, data_dir)
    finally:
        stop_gracefully(process, 30)
        log_file.close()


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with contextlib.suppress(FileNotFoundError):
        state = Path(f"/proc/{pid}/stat").read_text().split(") ")[-1].split()[0]
        return state != "Z"
    return False
