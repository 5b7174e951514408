"""docs/deploy.md's Ray cluster works when done exactly as the guide says (issue 30): its node
commands start a head and a second node (each a machine of its own to the other: a network
namespace each), its service's command line starts the coordinator with its config file only
(loopback bind, no overriding flag), behind its Caddyfile, and four bots work through Caddy.
The coordinator is stopped with SIGTERM while every slot is in use, and killed with SIGKILL
after the first demonstration, and started again each time.

Everything run is read from the guide (tests/fixtures/guide.py: the blocks marked
`<!-- tested: NAME -->`), only its placeholders replaced, so the guide cannot drift from what
works. Ray listens on every interface, so all of it runs in network namespaces this test makes
and removes (`unshare --net`, which needs root)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.fixtures.guide import guide_blocks
from tests.fixtures.netns import NEEDS_ROOT, run_check

CHECK = Path(__file__).parents[1] / "fixtures" / "deploy_guide_check.py"
GUIDE = Path(__file__).parents[2] / "docs" / "deploy.md"

pytestmark = [
    pytest.mark.slow,
    NEEDS_ROOT,
    pytest.mark.serial("ray"),  # `ray stop --force` ends every cluster on the machine
]


def test_the_guide_marks_the_blocks_this_test_runs():
    blocks = guide_blocks(GUIDE)
    assert {"nodes", "coord.yaml", "unit", "Caddyfile"} <= set(blocks)
    assert "crowdteleop node start" in blocks["nodes"]
    assert "--config /etc/crowdteleop/coord.yaml" in blocks["unit"]


def test_a_ray_campaign_deployed_as_the_guide_says_counts_every_demonstration_once(
    tmp_path, shared_database
):
    assert shutil.which("caddy"), "Caddy is installed by `make test` (scripts/system-deps.sh)"
    database = shared_database.rsplit("/", 1)[1]  # emptied: other tests leave sessions
    results = run_check(
        CHECK,
        str(tmp_path),
        database,
        marker="DEPLOY_GUIDE",
        logs=tmp_path,
        network="ip link set lo up",
    )
    print(f"the coordinator: {' '.join(results['command'])}")
    print(f"the nodes: {results['node_commands']}")
    print(
        f"SIGTERM: exit {results['sigterm_exit']} in {results['sigterm_s']:.1f} s; demos done "
        f"per session when SIGKILLed: {results['demos_done_at_kill']}; "
        f"{len(results['stored'])} episodes stored, {len(results['counted'])} reported"
    )
    print(
        f"start to READY: {', '.join(f'{s:.1f}' for s in results['ready_s'])} s; "
        f"{results['uncounted_at_restart']} demonstrations stored while it was down, all "
        f"counted {results['reports_landed_s']:.1f} s after it was READY again"
    )
    for report in results["reports"]:
        print(f"a worker: code {report['code']}, {report['outcomes']}, error {report['error']}")
    assert "--config" in results["command"] and "--admin-token" not in results["command"]
    assert results["loopback_exit"] == 3, "a report address on its loopback: refused at start"
    assert "10.213.1.2" in results["loopback_said"][0], "naming the node that could not report"
    assert results["local_exit"] == 3, "episodes on each machine's own disk: refused at start"
    assert results["local_said"], "saying to use S3 or a shared folder"
    assert results["capacity"] == 2 * 2 - 1, "both nodes' slots, less the spare"
    assert results["hosts"] == ["10.213.1.1", "10.213.1.2"], "sessions ran on both machines"
    assert results["sigterm_exit"] == 0, "systemctl stop is a graceful stop"
    assert results["servers_ran_on"], "and leaves the teleop servers running"
    assert results["taken_back"], "the next start takes each session's server back"
    assert max(results["demos_done_at_kill"]) < 2, "killed mid-campaign"
    assert results["sigkill_exit"] == -9
    reports = results["reports"]
    assert len(reports) == 4 and all(r["error"] is None and r["code"] for r in reports), reports
    # A bot goes on until its code arrives: a last demonstration may land after it is due.
    assert all(done >= required for done, required in results["sessions"]), results["sessions"]
    counted = [uri for uri, _ in results["counted"]]
    assert len(counted) == len(set(counted)), "no episode counted twice"
    stored = set(results["stored"])
    assert set(counted) <= stored, "nothing counted that is not stored"
    demos = {uri for uri, outcome in results["counted"] if outcome == "success"}
    assert demos == {uri for uri in stored if "/success/" in uri}, "every demonstration counted"
    assert sum(done for done, _ in results["sessions"]) == len(demos), "each once"
    assert results["final_exit"] == 0
