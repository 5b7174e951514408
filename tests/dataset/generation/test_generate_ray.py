"""``dataset generate --ray``: attempts run on Ray actors across two raylets (two nodes of one
cluster, one CPU each, so each holds one actor) and come back to the one process that writes
episodes and the log.

Ray listens on every interface and has no authentication by default, so the test runs it in a
network namespace of its own that has only loopback (`unshare --net`, which needs root)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [
    pytest.mark.serial("ray"),  # `ray stop --force` ends every cluster on the machine
    pytest.mark.slow,
    pytest.mark.skipif(
        os.geteuid() != 0,
        reason="needs root for a loopback-only network namespace (Ray binds every interface)",
    ),
]
GCS_PORT, NODE2_PORT = 6392, 6393


def test_attempts_run_on_both_raylets_and_one_process_writes_them(lift_sources, tmp_path):
    ray = str(Path(sys.executable).with_name("ray"))
    common = "--num-cpus=1 --node-ip-address=127.0.0.1"
    output = tmp_path / "out"
    script = " && ".join(
        [
            "ip link set lo up",
            f"{ray} start --head --port={GCS_PORT} --include-dashboard=false {common}",
            f"{ray} start --address=127.0.0.1:{GCS_PORT} --node-manager-port={NODE2_PORT} {common}",
            f"{sys.executable} -m crowdteleop dataset generate {lift_sources.dataset} --num 4 "
            f"--workers 2 --ray 127.0.0.1:{GCS_PORT} --output {output}",
        ]
    )
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}
    result = subprocess.run(
        ["unshare", "--net", "--", "bash", "-c", f"{script}; rc=$?; {ray} stop --force; exit $rc"],
        capture_output=True,
        text=True,
        timeout=900,
        env=env,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    entries = [json.loads(line) for line in (output / "attempts.jsonl").read_text().splitlines()]
    nodes = {entry["worker"].split(":")[0] for entry in entries}
    assert len(nodes) == 2, nodes  # both raylets ran attempts
    assert all(node.startswith("ray node ") for node in nodes)
    assert sum(entry["success"] for entry in entries) >= 4
    assert len(list((output / "episodes").glob("*.hdf5"))) == sum(e["success"] for e in entries)
    assert (output / "demo.hdf5").exists()
