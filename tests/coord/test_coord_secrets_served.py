"""`crowdteleop serve` with a real teleop server: its secrets are private on disk from the start,
no token is in the database in clear, and the teleop server refuses a foreign page's direct
admin offer while the coordinator's proxied offers and a bot (no Origin) get through."""

from __future__ import annotations

import asyncio
import json
import stat
from pathlib import Path
from typing import Any

import httpx
import pytest

from crowdteleop.client.connection import TeleopClient
from tests.fixtures.coord import ADMIN, Worker, auth, coord_server
from tests.fixtures.signalling import hello_through

pytestmark = pytest.mark.slow


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


async def direct_offer(url: str, body: dict[str, Any], origin: str | None) -> httpx.Response:
    headers = {"Origin": origin} if origin else {}
    async with httpx.AsyncClient(timeout=30) as http:
        return await http.post(f"{url}/offer", json=body, headers=headers)


def test_a_served_session_keeps_its_secrets_private_and_its_server_refuses_foreign_pages(
    tmp_path,
):
    with coord_server(tmp_path, capacity=1) as server:

        async def scenario() -> dict[str, Any]:
            async with httpx.AsyncClient(base_url=server.url, timeout=60) as http:
                worker = Worker(http, {})
                await worker.start()
                await worker.until("ready", 120)
                path = f"/api/admin/sessions/{worker.sid}/teleop"
                access = (await http.get(path, headers=auth(ADMIN))).json()
                url = access["url"]
                proxied = await hello_through(
                    http, f"/api/sessions/{worker.sid}/offer", auth(worker.token)
                )
                admin_offer = {
                    "sdp": "v=0",
                    "token": access["token"],
                    "role": "admin",
                    "admin_token": access["admin_token"],
                }
                foreign = await direct_offer(url, admin_offer, "https://evil.example")
                # The coordinator's own origin passes the origin check; a bare "v=0" is then
                # refused for what it lacks (no data channel section), not for its origin.
                coordinator = await direct_offer(url, admin_offer, server.url)
                bot = TeleopClient(
                    url, access["token"], role="admin", admin_token=access["admin_token"]
                )
                await bot.connect()  # signals straight to the teleop server, no Origin
                bot_hello = bot.state.hello
                await bot.close()
                async with httpx.AsyncClient(timeout=30) as direct:
                    telemetry = (
                        await direct.get(f"{url}/telemetry", headers=auth(access["admin_token"]))
                    ).json()
                await worker.stop()
                return {
                    "sid": worker.sid,
                    "worker_token": worker.token,
                    "access": access,
                    "proxied": proxied,
                    "foreign": (foreign.status_code, foreign.json()),
                    "coordinator": (coordinator.status_code, coordinator.json()),
                    "bot_hello": bot_hello,
                    "telemetry": telemetry,
                }

        outcome = asyncio.run(asyncio.wait_for(scenario(), 300))
        data = server.data_dir
        folder = data / "sessions" / outcome["sid"]
        database = data / "coord.sqlite3"
        folders = [data, data / "sessions", data / "state", folder]
        files = [
            data / "state" / "session.key",
            folder / "teleop.json",
            folder / "teleop.log",
            database,
            database.with_name("coord.sqlite3-wal"),
            database.with_name("coord.sqlite3-shm"),
        ]
        modes = {str(p): mode(p) for p in folders + files}
        teleop = json.loads((folder / "teleop.json").read_text())
        stored = b"".join(
            p.read_bytes() for p in data.iterdir() if p.name.startswith("coord.sqlite3")
        )

    assert modes == {str(p): 0o700 for p in folders} | {str(p): 0o600 for p in files}

    assert outcome["proxied"]["role"] == "worker", "the coordinator's path works"
    assert outcome["bot_hello"] is not None and outcome["bot_hello"].role == "admin"
    assert outcome["foreign"][0] == 403 and outcome["foreign"][1]["error"] == "foreign_origin"
    assert outcome["coordinator"][0] == 400, outcome["coordinator"]
    assert outcome["coordinator"][1]["error"] == "incomplete_offer", outcome["coordinator"]
    assert outcome["telemetry"]["errors"].get("http_foreign_origin") == 1

    access = outcome["access"]
    assert (teleop["token"], teleop["admin_token"]) == (access["token"], access["admin_token"])
    assert teleop["allowed_origins"] == [server.url]
    assert outcome["sid"].encode() in stored
    for name in ("token", "admin_token", "report_token"):
        assert teleop[name].encode() not in stored, f"teleop.json's {name} is in the database"
    assert outcome["worker_token"].encode() not in stored
