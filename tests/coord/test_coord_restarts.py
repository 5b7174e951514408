"""A worker keeps their place and their count when their robot's server crashes, and every
worker keeps theirs across a coordinator restart."""

from __future__ import annotations

import time

from tests.fixtures.coord import ADMIN, Api, FakeLauncher, coord_config, in_process_app


def report_success(client, launcher: FakeLauncher, sid: str, number: int) -> dict:
    """What the session's teleop server sends when a demonstration is stored."""
    teleop = launcher.handles[sid].config
    body = {
        "session_id": sid,
        "worker_id": teleop.worker_id,
        "episode": number,
        "episode_id": f"{sid}-ep{number}",
        "outcome": "success",
        "steps": 70,
        "duration_s": 3.5,
        "uri": f"file:///data/{sid}/ep{number}.hdf5",
        "telemetry": {},
    }
    headers = {"Authorization": f"Bearer {teleop.report_token}"}
    response = client.post("/internal/episodes", json=body, headers=headers)
    assert response.status_code == 200, response.text
    return response.json()


def wait_for(predicate, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.05)


def test_a_crashed_server_gives_its_worker_a_new_one_first_with_their_count_kept(tmp_path):
    launcher = FakeLauncher()
    with in_process_app(coord_config(tmp_path, capacity=1), launcher) as client:
        api = Api(client)
        alice, bob = api.join()["worker_token"], api.join()["worker_token"]
        sid = api.new_session(alice)["session_id"]
        api.wait_state(alice, sid, "ready")
        assert report_success(client, launcher, sid, 1)["demos_done"] == 1
        waiting = api.new_session(bob)
        assert waiting["queue_position"] == 1
        crashed = launcher.handles[sid]
        crashed.alive = False  # the process exited
        wait_for(lambda: launcher.handles[sid] is not crashed)
        view = api.wait_state(alice, sid, "ready")
        assert view["demos_done"] == 1 and view["ended_reason"] is None
        assert api.heartbeat(bob, waiting["session_id"])["queue_position"] == 1, "bob still next"
        assert report_success(client, launcher, sid, 2)["demos_done"] == 2
        overview = client.get("/api/admin/overview", headers=api.auth(ADMIN)).json()
        assert overview["restarts"] == 1


def test_a_session_whose_servers_keep_crashing_ends_after_max_restarts(tmp_path):
    launcher = FakeLauncher()
    with in_process_app(coord_config(tmp_path, max_restarts=1), launcher) as client:
        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        launcher.handles[sid].alive = False  # the first crash: a new server
        wait_for(lambda: launcher.handles[sid].alive)
        api.wait_state(token, sid, "ready")
        launcher.handles[sid].alive = False  # the second: past max_restarts
        view = api.wait_state(token, sid, "ended")
        assert view["ended_reason"] == "error"


def test_a_requeued_session_tells_its_worker_why_while_it_waits(tmp_path):
    launcher = FakeLauncher(start_delay_s=1.5)  # a new server takes a while to build
    with in_process_app(coord_config(tmp_path), launcher) as client:
        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        first = api.wait_state(token, sid, "ready")
        report_success(client, launcher, sid, 1)
        launcher.handles[sid].alive = False
        waiting = api.wait_state(token, sid, "starting")
        assert "teleop server exited" in waiting["notice"]
        assert "1 saved demonstration still count" in waiting["notice"]
        again = api.wait_state(token, sid, "ready")
        assert again["notice"] is None and again["ready_at"] > first["ready_at"]


def test_a_coordinator_restart_keeps_every_worker_in_their_place(tmp_path):
    config = coord_config(tmp_path, capacity=1)
    launcher = FakeLauncher()
    with in_process_app(config, launcher) as client:
        api = Api(client)
        tokens = [api.join()["worker_token"] for _ in range(3)]
        running = api.new_session(tokens[0])["session_id"]
        api.wait_state(tokens[0], running, "ready")
        report_success(client, launcher, running, 1)
        queued = [api.new_session(t)["session_id"] for t in tokens[1:]]
        waiting = list(zip(tokens[1:], queued, strict=True))
        assert [api.heartbeat(t, s)["queue_position"] for t, s in waiting] == [1, 2]
    assert launcher.handles[running].alive is False, "its server stopped with the coordinator"

    relaunched = FakeLauncher()
    with in_process_app(config, relaunched) as client:
        api = Api(client)
        view = api.wait_state(tokens[0], running, "ready")  # tokens survive, so do sessions
        assert view["demos_done"] == 1
        assert relaunched.handles[running].url, "a new server for the running session"
        positions = [api.heartbeat(t, s)["queue_position"] for t, s in waiting]
        assert positions == [1, 2]
        api.client.delete(f"/api/sessions/{running}", headers=api.auth(tokens[0]))
        assert api.wait_state(tokens[1], queued[0], "ready")["state"] == "ready"
