"""Faults a crowd meets, with bots that join as workers (issue 15, item 5)."""

from __future__ import annotations

import json
import os
import subprocess
import time

import pytest

from crowdteleop.crowd.experiment import coordinator_config, crowd_command, platform_over_link
from crowdteleop.dataset.build import episode_files, read_inputs
from crowdteleop.linkemu.shaping import LinkSettings

pytestmark = pytest.mark.slow
ADMIN = "faults-admin-token-0123456789"


@pytest.fixture(autouse=True)
def _root() -> None:
    if os.geteuid() != 0:
        pytest.skip("network namespaces and TUN devices need root (CI runs as root)")


def test_a_workers_path_cut_for_5_s_resumes_and_the_worker_completes(tmp_path):
    link_settings = LinkSettings(rate_bps=2.4e6, delay_ms=20, queue_bytes=64_000)
    config = coordinator_config("cut", "lift", bots=1, demos=3)
    with platform_over_link(link_settings, link_settings, config, tmp_path, ADMIN) as (link, url):
        report = tmp_path / "crowd.json"
        command = link.run_in("a", crowd_command(url, 1, "lift", ADMIN, 300, report))
        with (tmp_path / "crowd.log").open("w") as log:
            crowd = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
            deadline = time.monotonic() + 120
            while link.stats().get("down", {}).get("delivered_bytes", 0) < 150_000:
                assert time.monotonic() < deadline, "no video crossed the link"
                assert crowd.poll() is None, (tmp_path / "crowd.log").read_text()
                time.sleep(0.2)
            time.sleep(1.0)  # driving, mid-episode
            link.cut()
            time.sleep(5.0)
            link.restore()
            crowd.wait(timeout=400)
        time.sleep(1.5)  # the forwarder's counters are written each second
        stats = link.stats()
    assert stats["up"]["cut"] > 0 and stats["down"]["cut"] > 0, "the cut happened both ways"
    worker = json.loads(report.read_text())["workers"][0]
    assert worker["error"] is None, (tmp_path / "crowd.log").read_text()
    assert worker["completion_code"], "the session resumed and the worker finished"
    assert worker["outcomes"].count("success") >= 3
    episodes, bad = read_inputs(episode_files([tmp_path / "data" / "episodes"]))
    assert not bad, "every recorded episode, the one cut through included, reads back"
    assert len(episodes) >= len(worker["outcomes"])
