"""Teleop servers on a real Ray cluster (issue 14): a head and a second raylet with one teleop
slot each, a coordinator launching on them, two bots as workers. Each session lands on its own
node. The coordinator killed with SIGKILL and restarted takes both servers back (the workers
keep their robots; they begin driving after it, so the other session is mid-campaign when the
node goes, however long the restart took). The second node then dies mid-episode (its raylet
and every process under it, SIGKILL): this is noticed within 10 s, its worker is told and
given a new robot with their count kept, the episode it cut short is kept as a crash, and the
other session keeps driving.

Ray listens on every interface and has no authentication by default, so everything runs in a
network namespace of its own that reaches nothing outside (`unshare --net`, which needs
root)."""

from __future__ import annotations

from pathlib import Path

import pytest

from crowdteleop.dataset.build import episode_files, read_inputs
from tests.fixtures.netns import NEEDS_ROOT, run_check

CHECK = Path(__file__).parents[1] / "fixtures" / "ray_launch_check.py"

pytestmark = [
    pytest.mark.slow,
    NEEDS_ROOT,
    pytest.mark.exclusive,
    pytest.mark.serial("ray"),  # `ray stop --force` ends every cluster on the machine
]  # runs alone under xdist: the control rate before and after a node loss


def test_sessions_spread_over_raylets_survive_a_coordinator_restart_and_a_node_loss(tmp_path):
    results = run_check(CHECK, str(tmp_path), marker="RAY_LAUNCH")
    print(
        f"Ray: cluster up in {results['cluster_up_s']:.1f} s; node loss noticed in "
        f"{results['noticed_s']:.1f} s; the other session ran "
        f"{results['kept_hz_before']:.1f} Hz before, {results['kept_hz_after']:.1f} Hz after"
    )
    assert results["capacity"] == 2, "capacity is the cluster's teleop slots, not the config's 8"
    assert results["one_per_node"], "each session on its own node"
    assert results["servers_after_kill"] == 2, "a killed coordinator takes no server with it"
    assert results["reattached"] == results["before_restart"], "the restarted one takes them back"
    assert results["noticed_s"] < 10.0
    assert results["kept_alive"], "the other node's session kept its server"
    # (a 2-core machine also runs the lost node's teardown meanwhile: some ticks are late)
    assert results["kept_hz_after"] > 0.75 * results["kept_hz_before"], "and its control rate"
    reports = {r["session_id"]: r for r in results["reports"]}
    lost, kept = reports[results["lost_session"]], reports[results["kept_session"]]
    assert kept["error"] is None and kept["code"] and kept["reconnects"] == 0, kept
    assert results["servers_left"] == 0, "no teleop server outlives the coordinator's shutdown"
    assert lost["error"] is None and lost["code"] and lost["reconnects"] == 1, lost
    assert any("new robot is on its way" in n for n in lost["notices"]), lost["notices"]
    episodes, bad = read_inputs(episode_files([Path(results["data_dir"]) / "episodes"]))
    assert not bad, "every stored episode reads back"
    cut_short = [
        e
        for _, e in episodes
        if e.metadata.get("session_id") == results["lost_session"] and e.outcome == "crash"
    ]
    print("the lost node's episode:", [(e.outcome, e.steps, e.recovered) for e in cut_short])
    # 2.5 s into it, so at least one flush of its write-ahead log (each second) is on disk:
    assert len(cut_short) == 1, "the episode the node loss cut short is kept, as a crash"
    assert cut_short[0].recovered and cut_short[0].steps >= 20, "with its steps up to then"
    successes = [e for _, e in episodes if e.outcome == "success"]
    assert len(successes) >= 12, "both workers' demonstrations are stored"
