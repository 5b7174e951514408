"""Regions (issue 14, item 4): a campaign served from several coordinators, each with its own
cluster. Each answers how free it is to any page that asks; the one a worker lands in records
where they went and the round trips that sent them there, down to their teleop server."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from crowdteleop.coord.guard.session_keys import SESSION_SECRET_FILE, SessionKeys
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.teleop_configs import TeleopConfigs, assignment_of
from crowdteleop.recording.metadata import RegionChoice
from crowdteleop.teleop.assign import assigned_config
from tests.fixtures.coord import ADMIN, Api, FakeLauncher, coord_config, in_process_app

REGIONS = [
    {"name": "oregon", "url": "https://oregon.example.org"},
    {"name": "china", "url": "https://china.example.org:8443"},
]
CAMPAIGN = {"name": "pilot", "regions": REGIONS}


def test_a_campaign_with_regions_needs_this_coordinators_name_among_them(tmp_path):
    with pytest.raises(ValidationError, match="set `region` to this coordinator's name"):
        CoordConfig(admin_token=ADMIN, campaigns=[CAMPAIGN])
    with pytest.raises(ValidationError, match="set `region`"):
        CoordConfig(admin_token=ADMIN, campaigns=[CAMPAIGN], region="mars")
    twice = {"name": "pilot", "regions": [REGIONS[0], REGIONS[0]]}
    with pytest.raises(ValidationError, match="region names must be unique"):
        CoordConfig(admin_token=ADMIN, campaigns=[twice], region="oregon")
    config = CoordConfig(admin_token=ADMIN, campaigns=[CAMPAIGN], region="oregon")
    assert config.region_origins() == [
        "https://china.example.org:8443",
        "https://oregon.example.org",
    ]


def test_ping_says_how_free_this_region_is_to_any_origin(tmp_path):
    config = coord_config(tmp_path, campaigns=[CAMPAIGN], region="oregon", capacity=1)
    with in_process_app(config, FakeLauncher()) as client:
        empty = client.get("/api/ping", headers={"Origin": "https://china.example.org:8443"})
        assert empty.status_code == 200
        assert empty.headers["access-control-allow-origin"] == "*"
        assert empty.headers["cache-control"] == "no-store"
        assert empty.json() == {"region": "oregon", "capacity": 1, "free_slots": 1, "queued": 0}
        api = Api(client)
        first, second = (api.join({"PROLIFIC_PID": f"p{n}"})["worker_token"] for n in (1, 2))
        api.wait_state(first, api.new_session(first)["session_id"], "ready")
        api.new_session(second)
        busy = client.get("/api/ping").json()
        assert (busy["free_slots"], busy["queued"]) == (0, 1)


def test_the_join_page_learns_the_regions_and_may_fetch_from_them(tmp_path):
    config = coord_config(tmp_path, campaigns=[CAMPAIGN], region="china")
    with in_process_app(config, FakeLauncher()) as client:
        view = client.get("/api/campaigns/pilot").json()
        assert view["region"] == "china"
        assert view["regions"] == [
            {"name": "oregon", "url": "https://oregon.example.org/"},
            {"name": "china", "url": "https://china.example.org:8443/"},
        ]
        policy = client.get("/join").headers["content-security-policy"]
        assert (
            "connect-src 'self' https://china.example.org:8443 https://oregon.example.org" in policy
        )


def test_a_workers_region_and_round_trips_reach_their_teleop_server(tmp_path):
    config = coord_config(tmp_path, campaigns=[CAMPAIGN], region="china")
    launcher = FakeLauncher()
    with in_process_app(config, launcher) as client:
        api = Api(client)
        rtts = {"oregon": 182.5, "china": 21.0}
        token = api.join({"PROLIFIC_PID": "p1"}, region_rtts_ms=rtts)["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        sent = launcher.handles[sid].config
        [shown] = api.admin("overview")["sessions"]
        assert shown["rtt_ms"] == 21.0, "the admin page shows how far each worker is"
    assert sent.region == RegionChoice(region="china", rtts_ms=rtts)
    # A warm spare (built before anyone's region) takes it on with its session.
    keys = SessionKeys.load_or_create(config.data_dir / "state" / SESSION_SECRET_FILE)
    spare = TeleopConfigs(config, keys).for_spare(("lift", "Sawyer", "ik-velocity"), "spare-1")
    assert spare.region is None
    assert assigned_config(spare, assignment_of(sent)).region == sent.region


def test_a_join_without_measurements_still_records_where_it_landed(tmp_path):
    config = coord_config(tmp_path, campaigns=[CAMPAIGN], region="oregon")
    launcher = FakeLauncher()
    with in_process_app(config, launcher) as client:
        api = Api(client)
        token = api.join({"PROLIFIC_PID": "p1"})["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        assert launcher.handles[sid].config.region == RegionChoice(region="oregon")


def test_without_regions_nothing_is_recorded(tmp_path):
    launcher = FakeLauncher()
    with in_process_app(coord_config(tmp_path), launcher) as client:
        api = Api(client)
        token = api.join()["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        assert launcher.handles[sid].config.region is None
        assert client.get("/api/ping").json()["region"] is None


@pytest.mark.parametrize(
    ("rtts", "error"),
    [
        ({"mars": 10.0}, "unknown_region"),
        ({"oregon": -1.0}, "invalid_request"),
        ({"oregon": 1e9}, "invalid_request"),
        ({"Oregon!": 10.0}, "invalid_request"),
        ({f"r{n}": 1.0 for n in range(17)}, "invalid_request"),
    ],
)
def test_bad_round_trips_are_refused_clearly_and_counted(tmp_path, rtts, error):
    config = coord_config(tmp_path, campaigns=[CAMPAIGN], region="oregon")
    with in_process_app(config, FakeLauncher()) as client:
        response = client.post("/api/join", json={"params": {}, "region_rtts_ms": rtts})
        assert response.status_code == 422, response.text
        assert response.json()["error"] == error
        if error == "unknown_region":
            assert "lists regions ['china', 'oregon']" in response.json()["message"]
            refusals = Api(client).admin("overview")["refusals"]
            assert refusals["unknown_region"] == 1
        assert client.get("/health").status_code == 200


def test_a_nan_round_trip_is_refused(tmp_path):
    config = coord_config(tmp_path, campaigns=[CAMPAIGN], region="oregon")
    with in_process_app(config, FakeLauncher()) as client:
        body = '{"params": {}, "region_rtts_ms": {"oregon": NaN}}'
        response = client.post(
            "/api/join", content=body, headers={"Content-Type": "application/json"}
        )
        assert response.status_code == 422
