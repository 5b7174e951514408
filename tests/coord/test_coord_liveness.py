"""A teleop server that exists but answers nothing (stopped, deadlocked) does not keep its
worker's slot: the coordinator's health probes give it up and the worker gets a new robot."""

from __future__ import annotations

import time

import pytest

from tests.fixtures.coord import ADMIN, Api, FakeLauncher, coord_config, in_process_app

pytestmark = pytest.mark.exclusive  # runs alone under xdist: a slot freed within 10 s

FAST_PROBES = {"health_interval_s": 0.2, "health_timeout_s": 0.5, "unresponsive_after_s": 1.5}


def test_a_hung_server_is_given_up_and_its_worker_gets_a_new_one(tmp_path):
    launcher = FakeLauncher()
    with in_process_app(coord_config(tmp_path, **FAST_PROBES), launcher) as client:
        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        time.sleep(1.0)
        assert sid not in launcher.stopped, "a healthy server is left alone"
        hung = launcher.handles[sid]
        hung.hung = True
        started = time.monotonic()
        while launcher.handles[sid] is hung:
            assert time.monotonic() - started < 10, "still holding the slot after 10 s"
            api.heartbeat(token, sid)
            time.sleep(0.1)
        assert 1.5 <= time.monotonic() - started < 5.0
        assert sid in launcher.stopped, "the hung server is stopped"
        view = api.wait_state(token, sid, "ready")
        assert view["ended_reason"] is None
        overview = client.get("/api/admin/overview", headers=api.auth(ADMIN)).json()
        assert overview["restarts"] == 1


def test_past_max_restarts_a_hung_servers_session_ends_and_its_worker_is_told(tmp_path):
    launcher = FakeLauncher()
    config = coord_config(tmp_path, max_restarts=0, **FAST_PROBES)
    with in_process_app(config, launcher) as client:
        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        launcher.handles[sid].hung = True
        view = api.wait_state(token, sid, "ended", timeout=10)
        assert view["ended_reason"] == "error"
