"""What a teleop server may report (`POST /internal/episodes`): numbers out of range or not
finite are refused with a 422, and the coordinator and its statistics carry on unharmed."""

from __future__ import annotations

import json
import math
import time

import pytest

from crowdteleop.teleop.messages import (
    MAX_EPISODE_DURATION_S,
    MAX_EPISODE_NUMBER,
    MAX_EPISODE_STEPS,
)
from tests.fixtures.coord import ADMIN, Api, FakeLauncher, coord_config, in_process_app

pytestmark = pytest.mark.filterwarnings("ignore:Using `httpx`")


def ready_session(client, launcher):
    """A worker joined and their session ready: (session id, its teleop server's config)."""
    api = Api(client)
    token = api.join()["worker_token"]
    sid = api.new_session(token)["session_id"]
    api.wait_state(token, sid, "ready")
    return sid, launcher.handles[sid].config


@pytest.fixture
def reporting(tmp_path, database_url):
    """A coordinator on each database, a ready session, and `post(raw_json_fields)`."""
    launcher = FakeLauncher()
    config = coord_config(tmp_path, database_url, capacity=1)
    with in_process_app(config, launcher) as client:
        sid, teleop = ready_session(client, launcher)
        headers = {
            "Authorization": f"Bearer {teleop.report_token}",
            "Content-Type": "application/json",
        }
        count = iter(range(1_000_000))

        def post(**raw: str):
            """Fields given as raw JSON text (so NaN and Infinity reach the server as sent)."""
            fields = {
                "session_id": json.dumps(sid),
                "worker_id": json.dumps(teleop.worker_id),
                "episode": "1",
                "episode_id": json.dumps(f"ep{next(count)}"),
                "outcome": '"success"',
                "steps": "70",
                "duration_s": "3.5",
                "uri": '"file:///data/ep.hdf5"',
                "telemetry": '{"fps": 20.0}',
                **raw,
            }
            body = "{" + ",".join(f'"{k}": {v}' for k, v in fields.items()) + "}"
            return client.post("/internal/episodes", content=body, headers=headers)

        post.session_id = sid  # type: ignore[attr-defined]
        yield client, Api(client), post


def _refused(response, field: str) -> None:
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["error"] == "invalid_request" and field in body["message"], body


def test_huge_or_negative_counts_are_refused_and_the_coordinator_keeps_answering(reporting):
    client, api, post = reporting
    for field, value in (
        ("steps", str(10**20)),
        ("steps", str(MAX_EPISODE_STEPS + 1)),
        ("steps", "-1"),
        ("steps", "1e300"),
        ("episode", str(10**20)),
        ("episode", str(MAX_EPISODE_NUMBER + 1)),
    ):
        _refused(post(**{field: value}), field)
    assert client.get("/health").json()["status"] == "ok"
    at_the_limits = post(steps=str(MAX_EPISODE_STEPS), episode=str(MAX_EPISODE_NUMBER))
    assert at_the_limits.status_code == 200, at_the_limits.text
    assert api.admin("overview")["totals"]["episodes"] == 1


def test_non_finite_or_absurd_durations_are_refused_and_statistics_stay_numbers(reporting):
    client, api, post = reporting
    for value in ("Infinity", "-Infinity", "NaN", "1e400", "-0.5", str(MAX_EPISODE_DURATION_S + 1)):
        _refused(post(duration_s=value), "duration_s")
    deep = '{"x": ' + "[" * 20 + "]" * 20 + "}"
    for telemetry in ('{"fps": NaN}', '{"rtt": [1.0, {"ms": Infinity}]}', deep):
        _refused(post(telemetry=telemetry), "telemetry")
    for duration in ("3.0", "4.0"):
        assert post(duration_s=duration).status_code == 200
    overview = client.get("/api/admin/overview", headers=api.auth(ADMIN))
    assert "NaN" not in overview.text and "Infinity" not in overview.text
    (summary,) = overview.json()["completion_time_per_worker"]
    figures = [summary[k] for k in ("mean_s", "median_s", "min_s", "max_s")]
    assert figures == [3.5, 3.5, 3.0, 4.0]
    assert all(isinstance(x, float) and math.isfinite(x) for x in figures)
    assert summary["successes"] == summary["episodes"] == 2


def _metric(client, name: str) -> float:
    text = client.get("/metrics", headers={"Authorization": f"Bearer {ADMIN}"}).text
    return next(float(line.split()[-1]) for line in text.splitlines() if line.startswith(name))


def test_metrics_show_demos_of_the_last_hour_and_the_spool_and_report_backlogs(tmp_path):
    """What an operator watches: successful demonstrations an hour (failed ones left out), the
    episodes the teleop servers' spools still hold for the object store, and those they could
    not yet report here, with the servers that cannot reach us at all (from /health)."""
    launcher = FakeLauncher()
    config = coord_config(tmp_path, capacity=1, health_interval_s=0.2)
    with in_process_app(config, launcher) as client:
        sid, teleop = ready_session(client, launcher)
        headers = {"Authorization": f"Bearer {teleop.report_token}"}
        for number, outcome in enumerate(("success", "timeout", "success"), start=1):
            report = {
                "session_id": sid,
                "worker_id": teleop.worker_id,
                "episode": number,
                "episode_id": f"ep{number}",
                "outcome": outcome,
                "steps": 70,
                "duration_s": 3.5,
                "uri": "file:///data/ep.hdf5",
                "telemetry": {},
            }
            assert client.post("/internal/episodes", json=report, headers=headers).is_success
        assert _metric(client, "crowdteleop_demos_last_hour") == 2
        assert _metric(client, "crowdteleop_spool_pending") == 0
        launcher.handles[sid].spool_pending = 3  # the object store is away
        deadline = time.monotonic() + 10
        while _metric(client, "crowdteleop_spool_pending") != 3 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _metric(client, "crowdteleop_spool_pending") == 3
        assert _metric(client, "crowdteleop_reports_pending") == 0
        assert _metric(client, "crowdteleop_servers_unable_to_report") == 0
        launcher.handles[sid].reports_pending = 2  # its server cannot reach us
        launcher.handles[sid].reports_unreachable = True
        while _metric(client, "crowdteleop_reports_pending") != 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _metric(client, "crowdteleop_reports_pending") == 2
        assert _metric(client, "crowdteleop_servers_unable_to_report") == 1


def test_reported_metrics_are_scored_against_the_campaign_and_flagged_with_reasons(reporting):
    """Scores are percentiles among the campaign's successful episodes of the task so far
    (itself included): the first is 50; a slower, idler one after it scores below it."""
    client, _api, post = reporting
    smooth = {
        "completion_time_s": 3.0,
        "idle_fraction": 0.05,
        "path_ratio": 1.1,
        "jerk_rms_m_s3": 20.0,
        "sparc": -2.0,
        "gripper_chatter": 0,
        "setbacks": 0,
        "clutch_reanchors": 0,
    }
    idle = {
        **smooth,
        "completion_time_s": 20.0,
        "idle_fraction": 0.6,
        "longest_pause_s": 11.0,
        "longest_pause_stage": "reach",
        "setbacks": 1,
        "first_setback": "grasped -> reach at 9.0 s",
    }
    acks = [post(metrics=json.dumps(metrics)).json() for metrics in (smooth, idle)]
    assert acks[0]["feedback"]["score"] == 50.0 and acks[0]["feedback"]["time_s"] == 3.0
    assert acks[1]["feedback"]["median_time_s"] == 11.5, "the study's middle, itself included"
    assert acks[1]["feedback"]["tip"].startswith("Keep the gripper closed"), acks[1]
    unmeasured = post().json()
    assert unmeasured["feedback"] is None, "nothing measured, nothing to say"
    assert post(metrics='{"completion_time_s": "slow"}').status_code == 422
    assert post(metrics='{"completion_time_s": NaN}').status_code == 422, "a metric it needs"
    path = f"/api/admin/sessions/{post.session_id}/episodes"
    episodes = client.get(path, headers=_admin()).json()
    first, second, _unmeasured = episodes
    assert first["score"] == 50.0 and first["flags"] == []
    assert second["score"] < first["score"]
    assert second["metrics"]["longest_pause_stage"] == "reach"
    reasons = {flag["metric"]: flag["reason"] for flag in second["flags"]}
    assert reasons == {
        "longest_pause_s": "idle 11 s in the 'reach' stage",
        "setbacks": "went back a stage (grasped -> reach at 9.0 s): dropped or lost the object",
    }


def _admin() -> dict[str, str]:
    return {"Authorization": f"Bearer {ADMIN}"}
