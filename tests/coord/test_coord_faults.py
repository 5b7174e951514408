"""Faults with real processes: a teleop server frozen mid-episode (SIGSTOP) and a coordinator
killed outright (SIGKILL). Workers keep their place and their count; nothing recorded is lost."""

from __future__ import annotations

import asyncio
import os
import signal
import time

import httpx
import pytest

from crowdteleop.client.bot import Bot
from crowdteleop.client.connection import TeleopClient
from crowdteleop.recording.episode_file import read_episode
from tests.fixtures.coord import ADMIN, Worker, auth, coord_server, pid_alive

pytestmark = pytest.mark.slow

CAMPAIGN = {"name": "study", "demos_required": 3, "time_limit_s": 600}


async def teleop_pid(http: httpx.AsyncClient, sid: str) -> int | None:
    overview = (await http.get("/api/admin/overview", headers=auth(ADMIN))).json()
    return next((s["pid"] for s in overview["teleop_servers"] if s["session_id"] == sid), None)


async def bot_mid_episode(http: httpx.AsyncClient, sid: str, elapsed_s: float) -> TeleopClient:
    """A privileged bot driving the session's robot, once its episode has run `elapsed_s`."""
    access = (await http.get(f"/api/admin/sessions/{sid}/teleop", headers=auth(ADMIN))).json()
    client = TeleopClient(
        access["url"], access["token"], role="admin", admin_token=access["admin_token"]
    )
    Bot(client, seed=1)
    await client.connect()
    await client.wait_for(
        lambda s: s.status is not None and s.status.elapsed_s >= elapsed_s, timeout=60
    )
    return client


@pytest.mark.exclusive  # runs alone under xdist: given up within 10 s
@pytest.mark.parametrize("spares", [0, 1], ids=["fresh-server", "warm-spare"])
def test_a_frozen_teleop_server_is_given_up_within_10_s_and_its_episode_kept(tmp_path, spares):
    """The next server recovers the frozen one's write-ahead log, whether it is started for
    the session or a warm spare handed to it."""
    config = {"capacity": 1, "campaigns": [CAMPAIGN], "spare_servers": spares}
    with coord_server(tmp_path, **config) as server:

        async def scenario() -> dict:
            async with httpx.AsyncClient(base_url=server.url, timeout=60) as http:
                worker = Worker(http, {"PROLIFIC_PID": "frozen1", "STUDY_ID": "st"})
                await worker.start()
                await worker.until("ready", 120)
                if spares:  # wait for the replacement spare, so the new robot is one
                    while not (await http.get("/health")).json()["spares"]:
                        await asyncio.sleep(0.5)
                bot = await bot_mid_episode(http, worker.sid, elapsed_s=1.5)
                frozen = await teleop_pid(http, worker.sid)
                assert frozen is not None
                os.kill(frozen, signal.SIGSTOP)
                stopped_at = time.monotonic()
                while pid_alive(frozen):
                    assert time.monotonic() - stopped_at < 10, "the frozen server holds on"
                    await asyncio.sleep(0.2)
                given_up_s = time.monotonic() - stopped_at
                notices = set()
                while worker.view.get("state") != "ready" or (
                    await teleop_pid(http, worker.sid)
                ) in (None, frozen):
                    if worker.view.get("notice"):
                        notices.add(worker.view["notice"])
                    assert time.monotonic() - stopped_at < 120, worker.view
                    await asyncio.sleep(0.2)
                await asyncio.wait_for(bot.close(), 10)
                await worker.stop()
                return {
                    "sid": worker.sid,
                    "given_up_s": given_up_s,
                    "notices": notices,
                    "view": worker.view,
                }

        outcome = asyncio.run(scenario())
    assert outcome["given_up_s"] < 10
    assert outcome["view"]["ended_reason"] is None and outcome["view"]["demos_done"] == 0
    if not spares:  # a warm spare takes over between two of the page's heartbeats
        assert any("stopped responding" in n for n in outcome["notices"]), outcome["notices"]
    session_dir = server.data_dir / "episodes" / "study" / outcome["sid"]
    kept = sorted(session_dir.rglob("other/*.hdf5"))
    assert len(kept) == 1, "the frozen server's episode, recovered by the next one"
    episode = read_episode(kept[0])
    assert episode.outcome == "crash" and episode.recovered and len(episode.actions) > 0


def test_a_coordinator_killed_and_restarted_keeps_every_workers_place_and_count(tmp_path):
    params = [{"PROLIFIC_PID": "alice9", "STUDY_ID": "st"}, {"workerId": "BOB9"}]
    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as first:

        async def before() -> tuple[list[tuple[str, str]], int]:
            async with httpx.AsyncClient(base_url=first.url, timeout=60) as http:
                alice, bob = (Worker(http, p) for p in params)
                await alice.start()
                await alice.until("ready", 120)
                await bob.start()
                assert bob.view["queue_position"] == 1
                pid = await teleop_pid(http, alice.sid)
                for worker in (alice, bob):
                    await worker.stop()
                return [(alice.token, alice.sid), (bob.token, bob.sid)], pid or 0

        workers, old_pid = asyncio.run(before())
        first.process.kill()  # SIGKILL: no shutdown at all
        first.process.wait(10)
        deadline = time.monotonic() + 20
        while pid_alive(old_pid):  # PR_SET_PDEATHSIG: the orphan stops itself
            assert time.monotonic() < deadline, "the teleop server outlived its coordinator"
            time.sleep(0.2)

    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as second:

        async def after() -> dict:
            async with httpx.AsyncClient(base_url=second.url, timeout=60) as http:
                (alice_token, alice_sid), (bob_token, bob_sid) = workers
                path = f"/api/sessions/{bob_sid}/heartbeat"
                bob_view = (await http.post(path, headers=auth(bob_token))).json()
                alice = Worker(http, {})
                alice.token, alice.sid = alice_token, alice_sid
                alice._task = asyncio.create_task(alice._beat())
                await asyncio.sleep(0.6)
                view = await alice.until("ready", 120)
                await alice.stop()
                return {"alice": view, "bob": bob_view}

        outcome = asyncio.run(after())
    assert outcome["bob"]["state"] == "queued" and outcome["bob"]["queue_position"] == 1
    assert outcome["alice"]["state"] == "ready" and outcome["alice"]["ended_reason"] is None
