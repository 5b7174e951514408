"""A study id is not a password: a second browser joining with a worker's PROLIFIC_PID does not
silently get their live session. The same browser (its token) comes back to it; another one is
refused, or takes the session over explicitly, and the first browser is told."""

from __future__ import annotations

import sqlite3

from tests.fixtures.coord import ADMIN, Api, FakeLauncher, coord_config, in_process_app

STUDY = {"PROLIFIC_PID": "alice", "STUDY_ID": "st", "SESSION_ID": "se"}


def test_another_browser_with_the_same_study_id_cannot_take_a_live_session_silently(tmp_path):
    with in_process_app(coord_config(tmp_path), FakeLauncher()) as client:
        api = Api(client)
        first = api.join(STUDY)
        sid = api.new_session(first["worker_token"])["session_id"]
        api.wait_state(first["worker_token"], sid, "ready")
        code = client.post(f"/api/sessions/{sid}/pairing", headers=api.auth(first["worker_token"]))
        phone = client.post("/api/pair", json={"code": code.json()["code"]}).json()["phone_token"]

        stranger = client.post("/api/join", json={"params": STUDY})
        assert stranger.status_code == 409
        assert stranger.json()["error"] == "in_use"
        assert "another browser" in stranger.json()["message"]
        guessed = client.post("/api/join", json={"params": STUDY, "worker_token": "x" * 43})
        assert guessed.status_code == 409, "a made-up token proves nothing"

        # The first browser coming back (a reload, the join page again) keeps its token.
        again = api.join(STUDY, worker_token=first["worker_token"])
        assert again["worker_token"] == first["worker_token"]
        assert api.new_session(again["worker_token"])["session_id"] == sid
        assert api.heartbeat(first["worker_token"], sid)["state"] == "ready"

        # Taking over is explicit: the session moves, the first browser learns why.
        taken = api.join(STUDY, take_over=True)
        assert taken["worker_id"] == first["worker_id"]
        assert api.new_session(taken["worker_token"])["session_id"] == sid
        told = client.post(
            f"/api/sessions/{sid}/heartbeat", headers=api.auth(first["worker_token"])
        )
        assert told.status_code == 401 and told.json()["error"] == "taken_over"
        assert "another browser" in told.json()["message"]
        unpaired = client.get("/api/phone/session", headers=api.auth(phone))
        assert unpaired.status_code == 401, "the old browser's phone is unpaired"
        events = [e["kind"] for e in _events(client, sid)]
        assert "taken_over" in events
        overview = client.get("/api/admin/overview", headers=api.auth(ADMIN)).json()
        assert overview["refusals"]["in_use"] == 2


def test_without_a_live_session_the_same_study_id_joins_from_anywhere(tmp_path):
    with in_process_app(coord_config(tmp_path), FakeLauncher()) as client:
        api = Api(client)
        first = api.join(STUDY)
        sid = api.new_session(first["worker_token"])["session_id"]
        client.delete(f"/api/sessions/{sid}", headers=api.auth(first["worker_token"]))
        later = api.join(STUDY)  # say, the next day on another computer
        assert later["worker_id"] == first["worker_id"]
        assert later["worker_token"] != first["worker_token"]


def _events(client, sid: str) -> list[dict]:
    """The session's event log, read from the app's database as the coordinator wrote it."""
    database = client.app_state.config.database_url.removeprefix("sqlite:///")
    with sqlite3.connect(database) as db:
        rows = db.execute("SELECT kind FROM events WHERE session_id = ? ORDER BY id", (sid,))
        return [{"kind": kind} for (kind,) in rows]
