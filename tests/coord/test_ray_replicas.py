"""Two coordinator replicas on one PostgreSQL database behind a real load balancer (HAProxy,
round robin), launching teleop servers on a real Ray cluster (issue 14): four bots join through
both at once and are admitted first come, first served, never past the cluster's two slots;
half of them pair a phone through the balancer (codes made on one replica, redeemed on
whichever the next call reaches). Stopping the replica that watches a running session loses no
session: the other takes its server over (same process, no reconnect) and every worker
finishes.

Ray listens on every interface, so everything runs in a network namespace of its own
(`unshare --net`, which needs root); PostgreSQL is reached over its Unix socket."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from crowdteleop.dataset.build import episode_files, read_inputs

CHECK = Path(__file__).parents[1] / "fixtures" / "ray_replicas_check.py"
ROOT = Path(__file__).parents[2]

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        os.geteuid() != 0,
        reason="needs root for a network namespace of its own (Ray binds every interface)",
    ),
]


def test_replicas_share_one_queue_and_a_stopped_one_loses_no_session(tmp_path, postgres_database):
    assert shutil.which("haproxy"), "HAProxy is installed by `make test` (scripts/system-deps.sh)"
    network = "ip link set lo up && ip link add ct0 type veth peer name ct1"
    network += " && ip link set ct0 up && ip link set ct1 up"
    network += " && ip addr add 10.213.0.1/24 dev ct0"
    database = postgres_database.rsplit("/", 1)[1]
    command = f"{network} && {sys.executable} {CHECK} {tmp_path} {database}"
    done = subprocess.run(
        ["unshare", "--net", "--", "bash", "-c", command],
        capture_output=True,
        text=True,
        timeout=1500,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    lines = [line for line in done.stdout.splitlines() if line.startswith("RAY_REPLICAS ")]
    logs = "".join(p.read_text()[-3000:] for p in sorted(tmp_path.glob("*.log")))
    assert done.returncode == 0 and lines, done.stdout[-3000:] + done.stderr[-5000:] + logs
    results = json.loads(lines[-1].removeprefix("RAY_REPLICAS "))
    print(
        f"replica stopped in {results['replica_stop_s']:.1f} s; its sessions taken over in "
        f"{results['taken_over_s']:.1f} s; most sessions holding a slot: {results['most_held']}"
    )
    assert results["most_held"] == 2, "never past the cluster's two slots"
    assert results["admitted_order"] == results["created_order"], "first come, first served"
    assert results["moved"] and results["same_servers"], "taken over: the same servers run on"
    reports = results["reports"]
    assert all(r["error"] is None and r["code"] for r in reports), reports
    assert all(r["reconnects"] == 0 for r in reports), "nobody needed a new robot"
    assert sum(r["device"] == "phone" for r in reports) == 2, "two drove from a paired phone"
    assert results["servers_left"] == 0, "the last replica's stop stops every server"
    episodes, bad = read_inputs(episode_files([Path(results["data_dir"]) / "episodes"]))
    assert not bad, "every stored episode reads back"
    assert sum(e.outcome == "success" for _, e in episodes) >= 8, "all workers' demos stored"
