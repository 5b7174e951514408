"""`crowdteleop serve` with real teleop server processes: what workers experience end to end
(capacity 1: queue, leave, abandon, WebRTC through the coordinator, a bot's demonstration
completing the session), and no process left behind."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import httpx
import pytest

from crowdteleop.client.bot import Bot
from crowdteleop.client.connection import TeleopClient
from tests.fixtures.coord import ADMIN, Worker, auth, coord_server, pid_alive
from tests.fixtures.signalling import hello_through

pytestmark = pytest.mark.slow

ADMIN_HEADERS = {"Authorization": f"Bearer {ADMIN}"}


async def teleop_pids(http: httpx.AsyncClient) -> dict[str, int]:
    overview = (await http.get("/api/admin/overview", headers=ADMIN_HEADERS)).json()
    return {s["session_id"]: s["pid"] for s in overview["teleop_servers"] if s["pid"]}


async def until(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, what
        await asyncio.sleep(0.2)


def test_capacity_one_queue_leave_reap_signal_and_complete(tmp_path):
    config = {
        "capacity": 1,
        "heartbeat_timeout_s": 4.0,
        "campaigns": [{"name": "study", "demos_required": 1, "time_limit_s": 600}],
    }
    seen_pids: list[int] = []
    with coord_server(tmp_path, **config) as server:

        async def scenario() -> dict:
            async with httpx.AsyncClient(base_url=server.url, timeout=60) as http:
                alice = Worker(http, {"PROLIFIC_PID": "alice1", "STUDY_ID": "st"})
                bob = Worker(http, {"workerId": "BOB2"})
                carol = Worker(http, {"PROLIFIC_PID": "carol3", "STUDY_ID": "st"})
                await alice.start()
                await alice.until("ready", 120)
                queued = await bob.start()
                assert (queued["state"], queued["queue_position"]) == ("queued", 1)
                assert queued["eta_s"] > 0

                # WebRTC signalling through the coordinator, for the page and the phone.
                hello = await hello_through(
                    http, f"/api/sessions/{alice.sid}/offer", auth(alice.token)
                )
                assert (hello["session_id"], hello["role"]) == (alice.sid, "worker")
                path = f"/api/sessions/{alice.sid}/pairing"
                code = (await http.post(path, headers=auth(alice.token))).json()["code"]
                phone = (await http.post("/api/pair", json={"code": code})).json()
                hello = await hello_through(
                    http, "/api/phone/offer", auth(phone["phone_token"]), video=False
                )
                assert (hello["session_id"], hello["role"]) == (alice.sid, "phone")

                # Alice closes the tab: the beacon frees the slot, her process goes, Bob starts.
                alice_pid = (await teleop_pids(http))[alice.sid]
                seen_pids.append(alice_pid)
                await alice.stop()
                left = await http.post(f"/api/sessions/{alice.sid}/leave?token={alice.token}")
                assert left.json()["ended_reason"] == "left"
                await until(lambda: not pid_alive(alice_pid), 20, "alice's server still runs")
                await bob.until("ready", 120)
                await carol.start()
                assert carol.view["queue_position"] == 1

                # Bob's phone locks (no more heartbeats): reaped, process gone, Carol admitted.
                bob_pid = (await teleop_pids(http))[bob.sid]
                seen_pids.append(bob_pid)
                bob.beating = False
                silent_since = time.monotonic()
                await bob.until("ended", 15)
                reaped_after = time.monotonic() - silent_since
                assert bob.view["ended_reason"] == "abandoned"
                await until(lambda: not pid_alive(bob_pid), 20, "bob's server still runs")
                await carol.until("ready", 120)
                seen_pids.append((await teleop_pids(http))[carol.sid])

                # A scripted operator does Carol's demonstration through the admin door.
                path = f"/api/admin/sessions/{carol.sid}/teleop"
                access = (await http.get(path, headers=ADMIN_HEADERS)).json()
                client = TeleopClient(
                    access["url"], access["token"], role="admin", admin_token=access["admin_token"]
                )
                await client.connect()
                result = await Bot(client, seed=0).run(episodes=1, timeout_s=120)
                done = await carol.until("ended", 30)
                await client.close()
                path = f"/api/admin/sessions/{carol.sid}/episodes"
                episodes = (await http.get(path, headers=ADMIN_HEADERS)).json()
                # The teleop server retries a report whose answer it lost: counted once.
                written = server.data_dir / "sessions" / carol.sid / "teleop.json"
                report_token = json.loads(written.read_text())["report_token"]
                first = episodes[0]
                replay = await http.post(
                    "/internal/episodes",
                    headers=auth(report_token),
                    json={**first, "episode": first["number"], "telemetry": {}},
                )
                overview = (await http.get("/api/admin/overview", headers=ADMIN_HEADERS)).json()
                for worker in (bob, carol):
                    await worker.stop()
                return {
                    "episodes": episodes,
                    "replay": replay.json(),
                    "reaped_after": reaped_after,
                    "bot": result.episodes,
                    "carol": done,
                    "overview": overview,
                }

        outcome = asyncio.run(asyncio.wait_for(scenario(), 420))
        log = server.log()

    assert outcome["reaped_after"] < 4.0 + 3.0, outcome["reaped_after"]
    assert outcome["bot"] == ["success"]
    [episode] = outcome["episodes"]
    assert episode["outcome"] == "success" and episode["task"] == "lift"
    stored = episode["uri"].removeprefix("file://")
    assert Path(stored).is_file() and str(server.data_dir / "episodes" / "study") in stored
    assert outcome["replay"]["duplicate"] is True and outcome["replay"]["demos_done"] == 1
    carol = outcome["carol"]
    assert carol["ended_reason"] == "completed" and carol["demos_done"] == 1
    assert carol["completion_code"]
    assert carol["redirect_url"].endswith(f"cc={carol['completion_code']}")
    overview = outcome["overview"]
    assert overview["totals"]["successes"] == 1 and overview["totals"]["completed_sessions"] == 1
    assert len(set(seen_pids)) == 3
    assert not [pid for pid in seen_pids if pid_alive(pid)], "a teleop server outlived serve"
    assert "Traceback" not in log, log[-3000:]


def test_stopping_serve_stops_its_teleop_servers(tmp_path):
    with coord_server(tmp_path, capacity=1) as server:

        async def scenario() -> int:
            async with httpx.AsyncClient(base_url=server.url, timeout=60) as http:
                worker = Worker(http, {})
                await worker.start()
                await worker.until("ready", 120)
                pid = (await teleop_pids(http))[worker.sid]
                await worker.stop()
                return pid

        pid = asyncio.run(asyncio.wait_for(scenario(), 180))
        assert pid_alive(pid)
        server.process.send_signal(2)  # SIGINT, as Ctrl-C
        server.process.wait(timeout=30)
    assert not pid_alive(pid), "the teleop server outlived its coordinator"
