"""Start a real teleop server process (`crowdteleop teleop-server`) for a test."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import aiohttp

from crowdteleop.coord.launcher import teleop_server_argv
from tests.ready import stop_gracefully, wait_ready

TOKEN = "worker-token-123"
ADMIN_TOKEN = "admin-token-456"


@dataclass
class ServerProcess:
    url: str
    process: subprocess.Popen[str]
    record_dir: Path
    log_path: Path

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.process.poll() is None

    def kill9(self) -> None:
        os.kill(self.process.pid, signal.SIGKILL)
        self.process.wait(timeout=10)

    async def telemetry(self) -> dict[str, Any]:
        headers = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
        async with (
            aiohttp.ClientSession() as http,
            http.get(f"{self.url}/telemetry", headers=headers) as response,
        ):
            return await response.json()

    async def health(self) -> dict[str, Any]:
        async with aiohttp.ClientSession() as http, http.get(f"{self.url}/health") as response:
            return await response.json()


def teleop_config(record_dir: Path, **overrides: Any) -> dict[str, Any]:
    config: dict[str, Any] = {
        "session_id": "test",
        "token": TOKEN,
        "admin_token": ADMIN_TOKEN,
        "recording": {"directory": str(record_dir)},
    }
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(config.get(key), dict):
            config[key] = {**config[key], **value}
        else:
            config[key] = value
    return config


@contextlib.contextmanager
def teleop_server(tmp_path: Path, **overrides: Any) -> Iterator[ServerProcess]:
    """A server on a free loopback port; killed (and its log kept) when the test ends."""
    record_dir = tmp_path / "episodes"
    config_path = tmp_path / "teleop.json"
    config_path.write_text(json.dumps(teleop_config(record_dir, **overrides)))
    log_path = tmp_path / "teleop.log"
    log_file = log_path.open("w")
    process = subprocess.Popen(
        teleop_server_argv(config_path),
        stdout=subprocess.PIPE,
        stderr=log_file,
        text=True,
    )
    try:
        url = wait_ready(process, log_path, 90.0, "teleop server")
        yield ServerProcess(url, process, record_dir, log_path)
    finally:
        stop_gracefully(process, 20)
        log_file.close()


def run(coroutine: Any, timeout: float = 240.0) -> Any:
    """Run a test scenario on a fresh event loop, with an overall time limit."""
    return asyncio.run(asyncio.wait_for(coroutine, timeout))


def wait_until(predicate: Any, timeout: float, interval: float = 0.1) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return False
