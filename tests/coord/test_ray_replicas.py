"""Two coordinator replicas on one PostgreSQL database behind a real load balancer (HAProxy,
round robin), launching teleop servers on a real Ray cluster (issue 14): four bots join through
both at once and are admitted first come, first served, never past the cluster's four slots
less the one warm spare both replicas keep together (and hand to whichever admits a worker);
half of them pair a phone through the balancer (codes made on one replica, redeemed on
whichever the next call reaches). Stopping the replica that watches a running session (one
that began as the spare) loses no session: the other takes its server over by name (same
process, no reconnect), and its spare too, and every worker finishes.

Ray listens on every interface, so everything runs in a network namespace of its own
(`unshare --net`, which needs root); PostgreSQL is reached over its Unix socket."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from crowdteleop.dataset.build import episode_files, read_inputs
from tests.fixtures.netns import NEEDS_ROOT, run_check

CHECK = Path(__file__).parents[1] / "fixtures" / "ray_replicas_check.py"

pytestmark = [
    pytest.mark.slow,
    NEEDS_ROOT,
    pytest.mark.serial("ray"),  # `ray stop --force` ends every cluster on the machine
]


def test_replicas_share_one_queue_and_a_stopped_one_loses_no_session(tmp_path, shared_database):
    assert shutil.which("haproxy"), "HAProxy is installed by `make test` (scripts/system-deps.sh)"
    database = shared_database.rsplit("/", 1)[1]  # emptied: other tests leave sessions
    results = run_check(CHECK, str(tmp_path), database, marker="RAY_REPLICAS", logs=tmp_path)
    print(
        f"replica stopped in {results['replica_stop_s']:.1f} s; its sessions taken over in "
        f"{results['taken_over_s']:.1f} s; most sessions holding a slot: {results['most_held']}; "
        f"most spares: {results['most_spares']}; capacities {results['capacities']}; sessions "
        f"given the spare: {results['spare_born']}, {results['moved_spare_born']} of them moved"
    )
    assert results["replica_exit"] == 0, "Ctrl-C on a Ray coordinator: a graceful stop"
    assert results["capacities"] == [3, 3], "four slots less the one spare, on both replicas"
    assert results["most_held"] == 3, "never past the slots the spare leaves"
    assert results["most_spares"] == 1, "one spare for both replicas, not one each"
    assert results["spare_born"] >= 1, "a worker was given the spare, through either replica"
    assert results["moved_spare_born"] >= 1, "a spare-born server was taken over by its name"
    assert all(r != results["victim"] for r, _ in results["spares_after_stop"]), (
        "the stopped replica's spare is watched by the other (it keeps running)"
    )
    assert results["admitted_order"] == results["created_order"], "first come, first served"
    assert results["moved"] and results["same_servers"], "taken over: the same servers run on"
    reports = results["reports"]
    assert all(r["error"] is None and r["code"] for r in reports), reports
    assert all(r["reconnects"] == 0 for r in reports), "nobody needed a new robot"
    assert sum(r["device"] == "phone" for r in reports) == 2, "two drove from a paired phone"
    assert results["servers_left"] == 0, "the last replica's stop stops every server"
    episodes, bad = read_inputs(episode_files([Path(results["data_dir"]) / "episodes"]))
    assert not bad, "every stored episode reads back"
    assert sum(e.outcome == "success" for _, e in episodes) >= 4 * 6, "all workers' demos stored"
