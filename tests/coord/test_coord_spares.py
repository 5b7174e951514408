"""Warm spare teleop servers: a worker gets a robot in about a second, not after a build."""

from __future__ import annotations

import asyncio
import time

import httpx
import pytest

from crowdteleop.client.bot import Bot
from crowdteleop.client.connection import TeleopClient
from tests.fixtures.coord import ADMIN, Worker, coord_server

pytestmark = pytest.mark.slow
ADMIN_HEADERS = {"Authorization": f"Bearer {ADMIN}"}


def test_a_spare_takes_the_session_and_records_under_its_identity(tmp_path):
    config = {
        "capacity": 1,
        "spare_servers": 1,
        "campaigns": [{"name": "study", "demos_required": 1, "time_limit_s": 600}],
    }
    with coord_server(tmp_path, **config) as server:

        async def scenario() -> dict:
            async with httpx.AsyncClient(base_url=server.url, timeout=60) as http:
                deadline = time.monotonic() + 120
                while (await http.get("/health")).json()["spares"] < 1:
                    assert time.monotonic() < deadline, "no spare came up"
                    await asyncio.sleep(0.5)
                worker = Worker(http, {"PROLIFIC_PID": "dora4", "STUDY_ID": "st"})
                asked = time.monotonic()
                await worker.start()
                await worker.until("ready", 30)
                ready_after = time.monotonic() - asked
                access = (
                    await http.get(
                        f"/api/admin/sessions/{worker.sid}/teleop", headers=ADMIN_HEADERS
                    )
                ).json()
                client = TeleopClient(
                    access["url"], access["token"], role="admin", admin_token=access["admin_token"]
                )
                await client.connect()
                hello_session = client.state.hello.session_id
                result = await Bot(client, seed=0).run(episodes=1, timeout_s=120)
                done = await worker.until("ended", 30)
                await client.close()
                episodes = (
                    await http.get(
                        f"/api/admin/sessions/{worker.sid}/episodes", headers=ADMIN_HEADERS
                    )
                ).json()
                await worker.stop()
                return {
                    "ready_after": ready_after,
                    "hello_session": hello_session,
                    "sid": worker.sid,
                    "bot": result.episodes,
                    "done": done,
                    "episodes": episodes,
                }

        outcome = asyncio.run(asyncio.wait_for(scenario(), 300))

    assert outcome["ready_after"] < 3.0, "a warm spare is handed over, not built"
    assert outcome["hello_session"] == outcome["sid"], "the spare took the session's identity"
    assert outcome["bot"] == ["success"]
    assert outcome["done"]["ended_reason"] == "completed"
    [episode] = outcome["episodes"]
    assert f"/episodes/study/{outcome['sid']}/" in episode["uri"], "recorded where the session's go"
