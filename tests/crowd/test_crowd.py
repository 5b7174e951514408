"""Bots that join through the coordinator as workers do: a real `crowdteleop serve`, real
teleop servers it launches, real WebRTC through the coordinator's signalling."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys

import httpx
import pytest

from crowdteleop.crowd.report import summary
from crowdteleop.crowd.worker import CrowdSettings, run_crowd
from tests.fixtures.coord import ADMIN, coord_server

pytestmark = pytest.mark.exclusive  # runs alone under xdist: the bots' frame rates

CAMPAIGN = {
    "name": "crowd",
    "title": "Lift the cube",
    "instructions": "Lift the cube.",
    "tasks": ["lift"],
    "demos_required": 1,
    "time_limit_s": 600,
}


@pytest.mark.slow
def test_three_bots_join_through_the_coordinator_and_complete_lift_concurrently(tmp_path):
    with coord_server(tmp_path, capacity=3, campaigns=[CAMPAIGN]) as coord:
        settings = CrowdSettings(
            coord.url, ADMIN, campaign="crowd", task="lift", session_timeout_s=300, phone_every=3
        )
        reports = asyncio.run(asyncio.wait_for(run_crowd(settings, 3), 600))
        recorded = [
            episode
            for report in reports
            for episode in httpx.get(
                f"{coord.url}/api/admin/sessions/{report.session_id}/episodes",
                headers={"Authorization": f"Bearer {ADMIN}"},
            ).json()
        ]

    for report in reports:
        assert report.error is None, f"{report.name}: {report.error}"
        assert report.completion_code and len(report.completion_code) >= 6
        assert report.outcomes.count("success") >= 1
        assert report.first_frame_s is not None and report.first_frame_s < 60
        assert report.latency_ms, f"{report.name} measured no control-to-frame latency"
        assert report.fps > 5
    assert [report.device for report in reports] == ["bot", "bot", "phone"]
    assert len({report.session_id for report in reports}) == 3, "a robot each"
    assert len({report.completion_code for report in reports}) == 3
    assert summary(reports)["completed"] == 3
    # Every demonstration was measured as it was stored, and the coordinator keeps it (issue 29).
    for episode in (e for e in recorded if e["outcome"] == "success"):
        metrics = episode["metrics"]
        assert metrics["completion_time_s"] == pytest.approx(episode["steps"] / 20)
        assert 0.05 < metrics["path_length_m"] < 3.0, metrics
        assert metrics["path_ratio"] >= 1.0 and metrics["clutch_reanchors"] >= 0, metrics
        assert 0.0 <= metrics["joint_limit_fraction"] <= 1.0, metrics
        # the latency the pages (here: bots) reported, once some has been: unknown, never 0
        latency = metrics["latency_p50_ms"]
        assert (latency is None or latency > 0) and metrics["loss_fraction"] >= 0, metrics


def test_a_crowd_without_the_admin_token_is_refused_before_joining():
    result = subprocess.run(
        [sys.executable, "-m", "crowdteleop", "bot", "--coordinator", "http://127.0.0.1:9"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "--admin-token" in result.stdout


def test_a_coordinator_that_is_not_there_is_each_bots_clear_error(tmp_path):
    out = tmp_path / "crowd.json"
    command = [sys.executable, "-m", "crowdteleop", "bot", "--coordinator", "http://127.0.0.1:9"]
    command += ["--admin-token", "x", "--count", "2", "--json", str(out)]
    result = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    body = json.loads(out.read_text())
    assert body["summary"]["completed"] == 0 and body["summary"]["errors"] == 2
    assert all("Connect" in worker["error"] for worker in body["workers"])
