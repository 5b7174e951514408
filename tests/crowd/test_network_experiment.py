"""The paper's network experiment, reduced: bots in one namespace, the coordinator and its
teleop servers in another, the emulated link between; each condition's episodes carry its
name, and `crowdteleop dataset stats` compares the conditions' completion times (KS)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from crowdteleop.crowd.experiment import PAPER_CONDITIONS, run_condition

pytestmark = pytest.mark.slow
ADMIN = "network-admin-token-0123456789"


def test_bots_complete_lift_over_the_papers_best_and_worst_links(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("network namespaces and TUN devices need root (CI runs as root)")
    conditions = {c.name: c for c in PAPER_CONDITIONS}
    runs = [
        run_condition(conditions[name], "lift", 2, 1, tmp_path, ADMIN, timeout_s=400)
        for name in ("baseline", "both")
    ]
    for run in runs:
        workers = run.crowd["workers"]
        assert [w["error"] for w in workers] == [None, None], run.condition
        assert all(w["completion_code"] for w in workers)
        assert run.link["down"]["delivered_bytes"] > 100_000, "the video crossed the link"
    baseline, both = (run.crowd["workers"] for run in runs)
    latency = {
        name: sorted(s for w in workers for s in w["latency_ms"])
        for name, workers in (("baseline", baseline), ("both", both))
    }
    median = {name: values[len(values) // 2] for name, values in latency.items()}
    assert median["both"] > median["baseline"] + 150, "200 ms more round trip shows in latency"

    out = tmp_path / "stats"
    sources = [str(run.episodes_dir) for run in runs]
    command = [sys.executable, "-m", "crowdteleop", "dataset", "stats", *sources]
    subprocess.run([*command, "--output", str(out)], check=True, capture_output=True, timeout=300)
    report = json.loads((out / "stats.json").read_text())
    by_network = report["tasks"]["lift"]["by"]["network condition"]
    groups = {group["group"]: group for group in by_network["groups"]}
    assert set(groups) == {"baseline", "both"}
    assert all(group["successes"] >= 2 for group in groups.values())
    assert "both" in by_network["ks"]["baseline"], "the KS table compares the two conditions"
    assert "network condition" in (out / "stats.md").read_text()
