"""What the join page learns before a worker agrees: the study's task, demonstrations and time."""

from __future__ import annotations

from tests.fixtures.coord import Api, FakeLauncher, coord_config, in_process_app

CAMPAIGNS = [
    {"name": "main", "title": "Lift a cube", "demos_required": 2, "time_limit_s": 600},
    {"name": "extra", "title": "Pick a can", "tasks": ["pick-place-can"], "demos_required": 5},
]


def test_a_join_link_shows_its_studys_demands_and_how_long_sessions_take(tmp_path):
    config = coord_config(tmp_path, campaigns=CAMPAIGNS)
    with in_process_app(config, FakeLauncher()) as client:
        default = client.get("/api/campaigns/default").json()
        assert (default["name"], default["title"]) == ("main", "Lift a cube")
        assert (default["demos_required"], default["time_limit_s"]) == (2, 600)
        assert default["typical_session_s"] is None, "no session has ended yet"
        extra = client.get("/api/campaigns/extra").json()
        assert extra["tasks"] == ["pick-place-can"] and extra["demos_required"] == 5
        unknown = client.get("/api/campaigns/nope")
        assert unknown.status_code == 404 and unknown.json()["error"] == "unknown_campaign"
        assert client.get("/api/campaigns/Bad%20Name").status_code == 422

        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        client.delete(f"/api/sessions/{sid}", headers=api.auth(token))
        typical = client.get("/api/campaigns/main").json()["typical_session_s"]
        assert typical is not None and 0 <= typical < 60
