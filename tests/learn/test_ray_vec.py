"""PPO's environments as Ray actors (the paper trained with many distributed actors): the same
seeds give the same episodes as inline environments, a request the cluster cannot hold is
refused instead of waiting forever, and `learn rl --vec ray` trains and checkpoints.

Ray listens on every interface and has no authentication by default, so the test runs it in a
network namespace of its own that has only loopback (`unshare --net`, which needs root)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

CHECK = Path(__file__).parents[1] / "fixtures" / "ray_vec_check.py"

pytestmark = [
    pytest.mark.serial("ray"),  # `ray stop --force` ends every cluster on the machine
    pytest.mark.slow,
    pytest.mark.skipif(
        os.geteuid() != 0,
        reason="needs root for a loopback-only network namespace (Ray binds every interface)",
    ),
]


def in_private_network(command: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    # RAY_AUTH_MODE set: a local ray.init() would otherwise write a token into ~/.ray.
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}
    return subprocess.run(
        ["unshare", "--net", "--", "bash", "-c", f"ip link set lo up && {command}"],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=env,
    )


def test_ray_actors_step_the_same_episodes_and_learn_rl_trains_on_them(lift_dataset, tmp_path):
    python = sys.executable
    output = tmp_path / "ray-run"
    train = (
        f"{python} -m crowdteleop learn rl --dataset {lift_dataset} --demos 2 --output {output}"
        " --vec ray --n-envs 2 --ray-actor-cpus 0.5 --n-steps 64 --budget 256 --eval-every 128"
    )
    result = in_private_network(f"{python} {CHECK} {lift_dataset} && {train}", timeout_s=900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "ray vec env: same episodes as inline" in result.stdout
    state = json.loads((output / "seed_0" / "state.json").read_text())
    assert state["steps"] >= 256
    assert json.loads((output / "seed_0" / "run.json").read_text())["config"]["vec"] == "ray"
