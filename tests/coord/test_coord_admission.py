"""Admission limits: a public join link cannot be flooded, and a normal worker still gets in.

Run against a real uvicorn server. Clients are told apart by address; on loopback the test
plays a reverse proxy (`trusted_proxies: 127.0.0.1`) whose `X-Forwarded-For` names them.
"""

from __future__ import annotations

import time

import httpx
import pytest

from crowdteleop.coord.app import create_app
from crowdteleop.coord.service.config import CoordConfig
from tests.fixtures.coord import ADMIN, FakeLauncher, coord_config, served_app

PROXY = {"trusted_proxies": ["127.0.0.1"]}


def behind(address: str) -> dict[str, str]:
    """Headers of a request the trusted proxy forwards from `address`."""
    return {"X-Forwarded-For": address}


def join(http: httpx.Client, address: str, params: dict[str, str] | None = None) -> httpx.Response:
    return http.post("/api/join", json={"params": params or {}}, headers=behind(address))


def session(http: httpx.Client, address: str, token: str) -> httpx.Response:
    headers = {**behind(address), "Authorization": f"Bearer {token}"}
    return http.post("/api/sessions", headers=headers)


def metric(http: httpx.Client, reason: str) -> float:
    text = http.get("/metrics", headers={"Authorization": f"Bearer {ADMIN}"}).text
    for line in text.splitlines():
        if line.startswith(f'crowdteleop_refusals_total{{reason="{reason}"}}'):
            return float(line.split()[-1])
    return 0.0


def serve(config: CoordConfig, launcher: FakeLauncher | None = None):
    return served_app(create_app(config, launcher or FakeLauncher()), config)


def test_a_join_flood_from_one_address_is_refused_while_a_normal_worker_still_joins(tmp_path):
    admission = {"joins_per_minute_per_address": 20, "joins_per_minute": 100}
    config = coord_config(tmp_path, admission=admission, **PROXY)
    with serve(config) as url, httpx.Client(base_url=url, timeout=30) as http:
        flood = [join(http, "203.0.113.66").status_code for _ in range(200)]
        assert flood[:20] == [200] * 20
        assert set(flood[20:]) == {429}, "past 20 a minute from one address"
        refused = join(http, "203.0.113.66")
        assert refused.json()["error"] == "rate_limited"
        assert 1 <= int(refused.headers["Retry-After"]) <= 61
        # Someone else, from another address, joins and gets a robot at once.
        worker = join(http, "198.51.100.7", {"PROLIFIC_PID": "alice"})
        assert worker.status_code == 200
        view = session(http, "198.51.100.7", worker.json()["worker_token"]).json()
        assert view["state"] in ("starting", "ready")
        assert metric(http, "join_rate_address") == 181
        # A spray over many addresses meets the limit of everyone together.
        spray = [join(http, f"192.0.2.{n}").status_code for n in range(1, 120)]
        assert spray.count(200) == 100 - 21 and set(spray[79:]) == {429}
        assert metric(http, "join_rate_total") == 119 - 79


def test_an_ipv6_client_counts_as_its_64_and_a_forged_forwarded_for_counts_for_nothing(tmp_path):
    admission = {"joins_per_minute_per_address": 5}
    # No trusted proxy: the header is whatever the client wrote, so it is ignored.
    with (
        serve(coord_config(tmp_path, admission=admission)) as url,
        httpx.Client(base_url=url, timeout=30) as http,
    ):
        forged = [join(http, f"10.0.0.{n}").status_code for n in range(1, 11)]
        assert forged == [200] * 5 + [429] * 5
    with (
        serve(coord_config(tmp_path / "v6", admission=admission, **PROXY)) as url,
        httpx.Client(base_url=url, timeout=30) as http,
    ):
        hosts = [join(http, f"2001:db8:1:2::{n:x}").status_code for n in range(1, 8)]
        assert hosts == [200] * 5 + [429] * 2, "one /64 is one subscriber"
        assert join(http, "2001:db8:1:3::1").status_code == 200, "the next /64 is another"


def test_live_sessions_per_address_are_capped(tmp_path):
    config = coord_config(tmp_path, capacity=2, admission={"live_sessions_per_address": 2}, **PROXY)
    with serve(config) as url, httpx.Client(base_url=url, timeout=30) as http:
        tokens = [join(http, "203.0.113.5").json()["worker_token"] for _ in range(3)]
        assert session(http, "203.0.113.5", tokens[0]).status_code == 200
        assert session(http, "203.0.113.5", tokens[1]).status_code == 200
        third = session(http, "203.0.113.5", tokens[2])
        assert third.status_code == 429 and third.json()["error"] == "too_many_sessions"
        # The worker's own live session is always theirs to fetch again.
        assert session(http, "203.0.113.5", tokens[0]).status_code == 200
        other = join(http, "198.51.100.9").json()["worker_token"]
        assert session(http, "198.51.100.9", other).status_code == 200
        assert metric(http, "sessions_per_address") == 1


def test_the_queue_is_capped_and_a_wait_past_the_maximum_is_refused_and_reaped(tmp_path):
    admission = {"max_queue": 2, "max_wait_s": 3000}
    campaign = {"name": "c", "time_limit_s": 1200}  # a busy slot is expected for up to 20 min
    config = coord_config(tmp_path, capacity=1, admission=admission, campaigns=[campaign], **PROXY)
    with serve(config) as url, httpx.Client(base_url=url, timeout=30) as http:
        views = []
        for n in range(4):
            token = join(http, f"192.0.2.{n + 1}").json()["worker_token"]
            views.append(session(http, f"192.0.2.{n + 1}", token))
        assert [v.status_code for v in views[:3]] == [200, 200, 200]
        assert [v.json()["state"] for v in views[1:3]] == ["queued", "queued"]
        # Queued: 1200 s then 2400 s; a third would wait 3600 s > 3000 s, but the cap is first.
        assert views[3].status_code == 503 and views[3].json()["error"] == "queue_full"
        assert int(views[3].headers["Retry-After"]) > 0
    admission = {"max_queue": 10, "max_wait_s": 2000}
    config = coord_config(
        tmp_path / "wait", capacity=1, admission=admission, campaigns=[campaign], **PROXY
    )
    with serve(config) as url, httpx.Client(base_url=url, timeout=30) as http:
        statuses = []
        for n in range(3):
            token = join(http, f"192.0.2.{n + 1}").json()["worker_token"]
            statuses.append(session(http, f"192.0.2.{n + 1}", token))
        # The second waits ~1200 s; the third would wait ~2400 s > 2000 s.
        assert [s.status_code for s in statuses] == [200, 200, 503]
        body = statuses[2].json()
        assert body["error"] == "wait_too_long" and "min" in body["message"]


def test_a_queued_session_past_the_maximum_wait_ends_and_is_told_why(tmp_path):
    # The estimate (from the default campaign's 0.5 s limit) lets the second one queue; the
    # first then holds the slot far longer than estimated.
    campaigns = [{"name": "quick", "time_limit_s": 0.5}, {"name": "long"}]
    config = coord_config(
        tmp_path, capacity=1, admission={"max_wait_s": 1.0}, campaigns=campaigns, **PROXY
    )
    with serve(config) as url, httpx.Client(base_url=url, timeout=30) as http:
        body = {"params": {}, "campaign": "long"}
        first = http.post("/api/join", json=body, headers=behind("192.0.2.1"))
        first_token = first.json()["worker_token"]
        first_sid = session(http, "192.0.2.1", first_token).json()["session_id"]
        second = http.post("/api/join", json=body, headers=behind("192.0.2.2"))
        second_token = second.json()["worker_token"]
        queued = session(http, "192.0.2.2", second_token).json()
        assert queued["state"] == "queued"
        headers = {"Authorization": f"Bearer {second_token}"}
        first_headers = {"Authorization": f"Bearer {first_token}"}
        deadline = time.monotonic() + 10
        view = queued
        while view["state"] != "ended" and time.monotonic() < deadline:
            http.post(f"/api/sessions/{first_sid}/heartbeat", headers=first_headers)
            view = http.post(f"/api/sessions/{queued['session_id']}/heartbeat", headers=headers)
            view = view.json()
            time.sleep(0.2)
        assert view["state"] == "ended" and view["ended_reason"] == "queue_timeout"


def test_a_campaign_can_refuse_anonymous_joins(tmp_path):
    campaign = {"name": "study", "allow_anonymous": False}
    with (
        serve(coord_config(tmp_path, campaigns=[campaign])) as url,
        httpx.Client(base_url=url, timeout=30) as http,
    ):
        anonymous = http.post("/api/join", json={"params": {}})
        assert anonymous.status_code == 403
        assert anonymous.json()["error"] == "study_link_required"
        assert "Prolific" in anonymous.json()["message"]
        listed = http.post("/api/join", json={"params": {"PROLIFIC_PID": "p1", "STUDY_ID": "s"}})
        assert listed.status_code == 200
        assert metric(http, "anonymous") == 1
        overview = http.get("/api/admin/overview", headers={"Authorization": f"Bearer {ADMIN}"})
        assert overview.json()["refusals"]["anonymous"] == 1


def test_wrong_admin_tokens_are_limited_and_weak_admin_tokens_refused(tmp_path):
    config = coord_config(tmp_path, admin_failures_per_minute=5)
    with serve(config) as url, httpx.Client(base_url=url, timeout=30) as http:
        wrong = {"Authorization": "Bearer " + "x" * 40}
        statuses = [http.get("/api/admin/overview", headers=wrong).status_code for _ in range(8)]
        assert statuses == [401] * 5 + [429] * 3
    for weak in ("a" * 16, "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa", "password1234567890"):
        with pytest.raises(ValueError, match="too weak"):
            CoordConfig(admin_token=weak)
    CoordConfig(admin_token="Xk3_v9Qm-2LpZr7TbW1cNf8HsJd4GyUe")  # 32 random URL-safe characters


def test_forged_forwarded_for_does_not_multiply_pairing_guesses(tmp_path):
    config = coord_config(tmp_path, pair_failures_per_minute=10, pair_failures_per_minute_total=25)
    with serve(config) as url, httpx.Client(base_url=url, timeout=30) as http:
        guesses = [
            http.post(
                "/api/pair", json={"code": "ZZZZZZ"}, headers=behind(f"198.51.100.{n}")
            ).status_code
            for n in range(1, 31)
        ]
        assert guesses == [404] * 10 + [429] * 20, "one client, however many addresses it claims"
        assert metric(http, "pair_rate_address") == 20
    # Behind a trusted proxy each real client is counted apart, and all of them together meet
    # the budget of everyone.
    config = coord_config(
        tmp_path / "proxy", pair_failures_per_minute=10, pair_failures_per_minute_total=25, **PROXY
    )
    with serve(config) as url, httpx.Client(base_url=url, timeout=30) as http:
        spread = [
            http.post(
                "/api/pair", json={"code": "ZZZZZZ"}, headers=behind(f"198.51.100.{n % 5}")
            ).status_code
            for n in range(40)
        ]
        assert spread[:25] == [404] * 25 and set(spread[25:]) == {429}
        assert metric(http, "pair_rate_total") == 15
