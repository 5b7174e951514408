"""The coordination server's HTTP API in process, with a fake launcher (instant servers)."""

from __future__ import annotations

import time

import httpx
import pytest

from tests.fixtures.coord import OFFER_SDP, Api, FakeLauncher, coord_config, in_process_app

# starlette warns that its TestClient will move from httpx to httpx2; nothing to do here.
pytestmark = pytest.mark.filterwarnings("ignore:Using `httpx`")


@pytest.fixture
def launcher():
    return FakeLauncher()


@pytest.fixture
def client(tmp_path, launcher):
    with in_process_app(coord_config(tmp_path, capacity=2), launcher) as client:
        yield client


def _report(client, launcher, sid, episode_id, outcome="success", token=None, **extra):
    config = launcher.handles[sid].config
    body = {
        "session_id": sid,
        "worker_id": config.worker_id,
        "episode": 1,
        "episode_id": episode_id,
        "outcome": outcome,
        "steps": 70,
        "duration_s": 3.5,
        "uri": f"file:///data/{episode_id}.hdf5",
        "telemetry": {"fps": 20.0},
        **extra,
    }
    assert config.report_url == "http://testserver/internal/episodes"
    headers = {"Authorization": f"Bearer {token or config.report_token}"}
    return client.post("/internal/episodes", json=body, headers=headers)


def test_join_recognises_prolific_mturk_and_anonymous_workers(client):
    api = Api(client)
    prolific = api.join({"PROLIFIC_PID": "5f00aa", "STUDY_ID": "st1", "SESSION_ID": "se1"})
    again = api.join({"PROLIFIC_PID": "5f00aa", "STUDY_ID": "st1", "SESSION_ID": "se2"})
    mturk = api.join({"workerId": "A1B2", "assignmentId": "x", "hitId": "h"})
    anon1, anon2 = api.join(), api.join({"utm_source": "mail"})
    assert prolific["source"] == "prolific" and mturk["source"] == "mturk"
    assert anon1["source"] == "anonymous"
    assert again["worker_id"] == prolific["worker_id"]
    assert again["worker_token"] != prolific["worker_token"]
    assert anon1["worker_id"] != anon2["worker_id"]
    campaign = prolific["campaign"]
    assert campaign["tasks"] == ["lift"] and campaign["demos_required"] == 3
    assert set(campaign) >= {"name", "title", "instructions", "interfaces", "time_limit_s"}
    bad = client.post("/api/join", json={"params": {"PROLIFIC_PID": "<script>"}})
    unknown = client.post("/api/join", json={"params": {}, "campaign": "nope"})
    assert bad.status_code == 422 and bad.json()["error"] == "invalid_request"
    assert unknown.status_code == 404 and unknown.json()["error"] == "unknown_campaign"


def test_a_session_becomes_ready_and_offers_reach_its_server_with_its_token(client, launcher):
    api = Api(client)
    worker = api.join()
    token = worker["worker_token"]
    view = api.new_session(token)
    assert view["state"] in ("starting", "ready")
    assert api.new_session(token)["session_id"] == view["session_id"], "one live session each"
    view = api.wait_state(token, view["session_id"], "ready")
    assert view["task"] == "lift" and view["robot"] == "Sawyer"
    assert view["controller"] == "ik-velocity" and view["instruction"]
    assert view["queue_position"] is None and view["eta_s"] is None
    assert view["time_left_s"] <= view["time_limit_s"]
    sid = view["session_id"]
    bare = client.post(
        f"/api/sessions/{sid}/offer", json={"sdp": "v=0", "type": "offer"}, headers=api.auth(token)
    )
    assert bare.status_code == 400 and bare.json()["error"] == "incomplete_offer"
    assert launcher.handles[sid].offers == [], "refused before the teleop server is bothered"
    answer = client.post(
        f"/api/sessions/{sid}/offer",
        json={"sdp": OFFER_SDP, "type": "offer"},
        headers=api.auth(token),
    )
    assert answer.status_code == 200, answer.text
    assert answer.json() == {"sdp": "v=0 answer", "type": "answer", "peer_id": "p1"}
    handle = launcher.handles[sid]
    assert handle.offers[-1]["role"] == "worker"
    assert handle.offers[-1]["token"] == handle.config.token
    assert handle.config.token not in str(view), "the browser never sees the teleop token"
    refused = client.post(
        f"/api/sessions/{sid}/offer",
        json={"sdp": OFFER_SDP + "bad", "type": "offer"},
        headers=api.auth(token),
    )
    assert refused.status_code == 400 and refused.json()["error"] == "invalid_sdp"
    access = api.admin(f"sessions/{sid}/teleop")
    assert access == {
        "url": handle.url,
        "token": handle.config.token,
        "admin_token": handle.config.admin_token,
    }


def test_workers_cannot_see_or_control_each_others_sessions(client):
    api = Api(client)
    alice, bob = api.join()["worker_token"], api.join()["worker_token"]
    sid = api.new_session(alice)["session_id"]
    for method, path in (
        ("get", f"/api/sessions/{sid}"),
        ("post", f"/api/sessions/{sid}/heartbeat"),
        ("post", f"/api/sessions/{sid}/leave"),
        ("delete", f"/api/sessions/{sid}"),
        ("post", f"/api/sessions/{sid}/pairing"),
    ):
        as_bob = client.request(method, path, headers=api.auth(bob))
        assert as_bob.status_code == 404, (path, as_bob.text)
        nobody = client.request(method, path)
        assert nobody.status_code == 401 and nobody.json()["error"] == "unauthorized"
        wrong = client.request(method, path, headers=api.auth("forged-token"))
        assert wrong.status_code == 401
    offer = client.post(
        f"/api/sessions/{sid}/offer",
        json={"sdp": "v=0", "type": "offer"},
        headers=api.auth(bob),
    )
    assert offer.status_code == 404
    assert client.get("/api/admin/overview", headers=api.auth(alice)).status_code == 401
    assert client.get(f"/api/admin/sessions/{sid}/teleop").status_code == 401
    assert api.session(alice, sid)["state"] != "ended", "nothing bob did touched it"


def test_capacity_queues_fifo_with_eta_and_leaving_admits_the_next(tmp_path, database_url):
    launcher = FakeLauncher()
    config = coord_config(tmp_path, database_url, capacity=1)
    with in_process_app(config, launcher) as client:
        api = Api(client)
        tokens = [api.join()["worker_token"] for _ in range(3)]
        first = api.new_session(tokens[0])
        api.wait_state(tokens[0], first["session_id"], "ready")
        second = api.new_session(tokens[1])
        third = api.new_session(tokens[2])
        assert (second["state"], second["queue_position"]) == ("queued", 1)
        assert (third["state"], third["queue_position"]) == ("queued", 2)
        assert 0 < second["eta_s"] <= 1800 and third["eta_s"] > second["eta_s"]
        offer = client.post(
            f"/api/sessions/{second['session_id']}/offer",
            json={"sdp": "v=0", "type": "offer"},
            headers=api.auth(tokens[1]),
        )
        assert offer.status_code == 409 and offer.json()["error"] == "not_ready"
        overview = api.admin("overview")
        assert [s["session_id"] for s in overview["queue"]] == [
            second["session_id"],
            third["session_id"],
        ]
        # The page leaves with navigator.sendBeacon: token in the query, no header.
        left = client.post(f"/api/sessions/{first['session_id']}/leave?token={tokens[0]}")
        assert left.status_code == 200 and left.json()["ended_reason"] == "left"
        assert launcher.stopped == [first["session_id"]] or _eventually(
            lambda: launcher.stopped == [first["session_id"]]
        )
        api.wait_state(tokens[1], second["session_id"], "ready")
        assert api.heartbeat(tokens[2], third["session_id"])["queue_position"] == 1
        gone = client.delete(f"/api/sessions/{second['session_id']}", headers=api.auth(tokens[1]))
        assert gone.json()["state"] == "ended"
        api.wait_state(tokens[2], third["session_id"], "ready")
        overview = api.admin("overview")
        assert overview["totals"]["sessions"] == 3 and len(overview["teleop_servers"]) == 1


def test_silent_sessions_are_reaped_and_their_slot_reused(tmp_path):
    launcher = FakeLauncher()
    config = coord_config(tmp_path, capacity=1, heartbeat_timeout_s=1.0)
    with in_process_app(config, launcher) as client:
        api = Api(client)
        quiet, waiting = api.join()["worker_token"], api.join()["worker_token"]
        sid = api.new_session(quiet)["session_id"]
        api.wait_state(quiet, sid, "ready")
        other = api.new_session(waiting)["session_id"]
        started = time.monotonic()
        api.wait_state(waiting, other, "ready", timeout=5)  # only `waiting` beats
        assert time.monotonic() - started < 3.0
        assert api.session(quiet, sid)["ended_reason"] == "abandoned"
        assert sid in launcher.stopped
        # A server that dies: the session gets a new one, keeping its place (test_coord_restarts).
        dead = launcher.handles[other]
        dead.alive = False
        deadline = time.monotonic() + 5
        while launcher.handles[other] is dead and time.monotonic() < deadline:
            api.heartbeat(waiting, other)
            time.sleep(0.1)
        assert launcher.handles[other] is not dead
        assert api.wait_state(waiting, other, "ready", timeout=5)["ended_reason"] is None


def test_time_limit_ends_the_session(tmp_path):
    import json

    campaigns = [{"name": "quick", "time_limit_s": 1.0}]
    config = coord_config(tmp_path, campaigns=json.loads(json.dumps(campaigns)))
    with in_process_app(config, FakeLauncher()) as client:
        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        view = api.wait_state(token, sid, "ended", timeout=5)
        assert view["ended_reason"] == "timeout"


def test_failing_launches_end_with_error_and_do_not_hold_the_slot(tmp_path):
    with in_process_app(coord_config(tmp_path, capacity=1), FakeLauncher(fail=True)) as client:
        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        view = api.wait_state(token, sid, "ended")
        assert view["ended_reason"] == "error"
        assert api.admin("overview")["teleop_servers"] == []


def test_episode_reports_are_idempotent_and_complete_the_session(tmp_path, database_url):
    launcher = FakeLauncher()
    with in_process_app(coord_config(tmp_path, database_url), launcher) as client:
        api = Api(client)
        worker = api.join({"PROLIFIC_PID": "p1", "STUDY_ID": "s", "SESSION_ID": "x"})
        token = worker["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        api.heartbeat(token, sid, interface="phone")
        acks = [
            _report(client, launcher, sid, "ep-1").json(),
            _report(client, launcher, sid, "ep-1").json(),  # retried after a lost answer
            _report(client, launcher, sid, "ep-2", outcome="reset").json(),
            _report(client, launcher, sid, "ep-3", device="keyboard").json(),
        ]
        assert [(a["duplicate"], a["demos_done"]) for a in acks] == [
            (False, 1),
            (True, 1),
            (False, 1),
            (False, 2),
        ]
        assert api.session(token, sid)["demos_done"] == 2
        assert api.session(token, sid)["completion_code"] is None
        last = _report(client, launcher, sid, "ep-4").json()
        assert last["completed"] is True and last["demos_done"] == 3
        view = api.session(token, sid)
        assert view["state"] == "ended" and view["ended_reason"] == "completed"
        code = view["completion_code"]
        assert code and len(code) >= 8
        assert view["redirect_url"] == f"https://app.prolific.com/submissions/complete?cc={code}"
        late = _report(client, launcher, sid, "ep-5").json()
        assert late["completed"] is False and api.session(token, sid)["completion_code"] == code
        wrong = _report(client, launcher, sid, "ep-6", token="not-the-report-token")
        assert wrong.status_code == 401
        overview = api.admin("overview")
        per_interface = {s["key"]: s for s in overview["completion_time_per_interface"]}
        assert (
            per_interface["phone"]["successes"] == 3 and per_interface["keyboard"]["successes"] == 1
        )
        assert per_interface["phone"]["mean_s"] == 3.5
        assert sum(h["successes"] for h in overview["demos_per_hour"]) == 4
        assert overview["totals"]["completed_sessions"] == 1


def test_reports_for_another_session_are_refused(client, launcher):
    api = Api(client)
    a, b = api.join()["worker_token"], api.join()["worker_token"]
    sa, sb = api.new_session(a)["session_id"], api.new_session(b)["session_id"]
    api.wait_state(a, sa, "ready")
    api.wait_state(b, sb, "ready")
    token_a = launcher.handles[sa].config.report_token
    forged = _report(client, launcher, sb, "x-1", token=token_a)
    assert forged.status_code == 403 and forged.json()["error"] == "wrong_session"


def test_pairing_codes_are_single_use_expire_and_guessing_is_rate_limited(tmp_path, launcher):
    config = coord_config(tmp_path, pairing_ttl_s=1.0, pair_failures_per_minute=5)
    with in_process_app(config, launcher) as client:
        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        pairing = client.post(f"/api/sessions/{sid}/pairing", headers=api.auth(token)).json()
        code = pairing["code"]
        assert len(code) == 6 and set(code) <= set("2346789ACDEFGHJKMNPQRTUVWXYZ")
        link = httpx.URL(pairing["phone_url"])
        assert link.path == "/phone" and link.params["code"] == code
        assert len(link.params["key"]) >= 43, "the QR link's key: 256 bits"
        assert pairing["expires_s"] == 1.0
        paired = client.post("/api/pair", json={"code": code.lower()})
        assert paired.status_code == 200 and paired.json()["session_id"] == sid
        phone = {"Authorization": f"Bearer {paired.json()['phone_token']}"}
        reused = client.post("/api/pair", json={"code": code})
        assert reused.status_code == 404 and reused.json()["error"] == "bad_code"
        status = client.get("/api/phone/session", headers=phone).json()
        assert status["session_id"] == sid and status["state"] == "ready"
        answer = client.post(
            "/api/phone/offer", json={"sdp": OFFER_SDP, "type": "offer"}, headers=phone
        )
        assert answer.status_code == 200 and launcher.handles[sid].offers[-1]["role"] == "phone"
        stale = client.post(f"/api/sessions/{sid}/pairing", headers=api.auth(token)).json()
        time.sleep(1.2)
        expired = client.post("/api/pair", json={"code": stale["code"]})
        assert expired.status_code == 404
        statuses = [client.post("/api/pair", json={"code": "ZZZZZZ"}).status_code for _ in range(4)]
        assert statuses == [404, 404, 404, 429], "5 failures a minute, then refused"
        fresh = client.post(f"/api/sessions/{sid}/pairing", headers=api.auth(token)).json()
        blocked = client.post("/api/pair", json={"code": fresh["code"]})
        assert blocked.status_code == 429 and int(blocked.headers["Retry-After"]) > 0
        assert "QR code" in blocked.json()["message"]
        # The QR link's code with its key still pairs from the blocked address.
        key = httpx.URL(fresh["phone_url"]).params["key"]
        wrong_key = client.post("/api/pair", json={"code": fresh["code"], "key": "x" * 43})
        assert wrong_key.status_code == 404
        scanned = client.post("/api/pair", json={"code": fresh["code"], "key": key})
        assert scanned.status_code == 200 and scanned.json()["session_id"] == sid
        assert client.get("/api/phone/session", headers=api.auth(token)).status_code == 401
        api.client.delete(f"/api/sessions/{sid}", headers=api.auth(token))
        after = client.post("/api/phone/offer", json={"sdp": "v=0", "type": "offer"}, headers=phone)
        assert after.status_code == 409


def test_pages_redirect_static_protocol_and_error_shapes(client):
    redirect = client.get("/?PROLIFIC_PID=abc&STUDY_ID=s", follow_redirects=False)
    assert redirect.status_code == 307
    assert redirect.headers["location"] == "/join?PROLIFIC_PID=abc&STUDY_ID=s"
    for page in ("join", "teleop", "phone", "admin"):
        response = client.get(f"/{page}")
        assert response.status_code in (200, 404)
        assert response.headers["content-type"].startswith("text/html")
    assert client.get("/static/no-such-file.js").status_code == 404
    schema = client.get("/protocol.json").json()
    assert schema and isinstance(schema, dict)
    assert client.get("/health").json()["status"] == "ok"
    missing = client.get("/api/nothing-here")
    assert missing.status_code == 404 and set(missing.json()) == {"error", "message"}
    invalid = client.post(
        "/api/join", content=b"{not json", headers={"content-type": "application/json"}
    )
    assert invalid.status_code == 422 and invalid.json()["error"] == "invalid_request"
    huge = client.post("/api/pair", json={"code": "x" * 300_000})
    assert huge.status_code == 413 and huge.json()["error"] == "too_large"
    bad_id = client.get("/api/sessions/../../etc", headers={"Authorization": "Bearer x"})
    assert 400 <= bad_id.status_code < 500


def _eventually(predicate, timeout=5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return False
