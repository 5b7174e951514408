"""Teleop servers on a Ray cluster against local processes (issue 14): the time from a worker
joining to their first video frame, with each launcher, cold (no warm spare) and warm (one
spare); and sessions driven at once on two raylets against one, same machine (so the same total
is expected: the point is that placement spreads them). Root: the cluster runs in a network
namespace of its own (Ray listens on every interface).

    .venv/bin/python benchmarks/ray_launch.py --runs 3 --sessions 4 --json out/ray-launch.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
INSIDE = "CROWDTELEOP_BENCH_NETNS"
NETWORK = (
    "ip link set lo up && ip link add ct0 type veth peer name ct1 && ip link set ct0 up"
    " && ip link set ct1 up && ip addr add 10.213.0.1/24 dev ct0"
)


def first_frames(work: Path, config: dict[str, Any], runs: int) -> list[float]:
    """One bot at a time joins a fresh coordinator; seconds from joining to its first frame."""
    from tests.fixtures.coord import ADMIN, coord_server

    from crowdteleop.crowd.experiment import coordinator_config
    from crowdteleop.crowd.worker import CrowdSettings, run_crowd

    campaign = {**coordinator_config("bench", "lift", 1, 1)["campaigns"][0], "name": "bench"}
    times = []
    for run in range(runs):
        folder = work / f"{config.get('ray') is not None}-{config['spare_servers']}-{run}"
        with coord_server(folder, campaigns=[campaign], **config) as coord:
            if config["spare_servers"]:
                time.sleep(20)  # the spare warms up before the worker comes
            settings = CrowdSettings(coord.url, ADMIN, campaign="bench", session_timeout_s=300)
            [report] = asyncio.run(run_crowd(settings, 1))
            assert report.error is None and report.first_frame_s, report
            times.append(report.first_frame_s)
    return times


def at_once(work: Path, config: dict[str, Any], sessions: int) -> list[float]:
    """`sessions` bots driving at once for 20 s: each one's frames per second."""
    from tests.fixtures.coord import ADMIN, coord_server

    from crowdteleop.crowd.experiment import coordinator_config
    from crowdteleop.crowd.worker import CrowdSettings, run_crowd

    campaign = {**coordinator_config("bench", "lift", sessions, 50)["campaigns"][0]}
    campaign["name"] = "bench"
    with coord_server(work, campaigns=[campaign], **config) as coord:
        settings = CrowdSettings(coord.url, ADMIN, campaign="bench", window_s=20.0, warmup_s=5.0)
        reports = asyncio.run(run_crowd(settings, sessions))
    assert all(r.error is None for r in reports), [r.error for r in reports]
    return [r.fps for r in reports]


def inside(args: argparse.Namespace) -> dict[str, Any]:
    from tests.fixtures.ray_launch_check import ENV, GCS_PORT, NODE2_PORT, RAY, ray_start

    work = Path(args.work)
    figures: dict[str, Any] = {}
    for spares in (0, 1):
        local = {"spare_servers": spares, "capacity": 4}
        figures[f"local, {spares} spare"] = first_frames(work / "local", local, args.runs)
    common = ["--num-cpus=2", "--node-ip-address=127.0.0.1"]

    def cluster(nodes: int, slots_each: int) -> None:
        slots = f'--resources={{"teleop": {slots_each}}}'
        ray_start("--head", f"--port={GCS_PORT}", "--include-dashboard=false", slots, *common)
        if nodes == 2:
            ray_start(
                f"--address=127.0.0.1:{GCS_PORT}",
                f"--node-manager-port={NODE2_PORT}",
                slots,
                *common,
            )

    def stop() -> None:
        subprocess.run([RAY, "stop", "--force"], env=ENV, capture_output=True)

    ray = {"address": f"127.0.0.1:{GCS_PORT}", "node_work_dir": str(work / "nodes")}
    try:
        cluster(2, 2)
        for spares in (0, 1):
            config = {"spare_servers": spares, "ray": ray}
            figures[f"ray, {spares} spare"] = first_frames(work / "ray", config, args.runs)
        figures["fps, two raylets"] = at_once(work / "two", {"ray": ray}, args.sessions)
        stop()
        cluster(1, 4)
        figures["fps, one raylet"] = at_once(work / "one", {"ray": ray}, args.sessions)
    finally:
        stop()
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--sessions", type=int, default=4)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--work", default="/tmp/crowdteleop-ray-bench")
    args = parser.parse_args()
    if os.environ.get(INSIDE):
        print("RAY_BENCH " + json.dumps(inside(args)), flush=True)
        return
    command = f"{NETWORK} && {sys.executable} {Path(__file__).resolve()} " + " ".join(
        f"--{k} {v}"
        for k, v in (("runs", args.runs), ("sessions", args.sessions), ("work", args.work))
    )
    env = {**os.environ, INSIDE: "1", "PYTHONPATH": str(ROOT), "RAY_USAGE_STATS_ENABLED": "0"}
    done = subprocess.run(
        ["unshare", "--net", "--", "bash", "-c", command],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
    )
    lines = [line for line in done.stdout.splitlines() if line.startswith("RAY_BENCH ")]
    if not lines:
        raise SystemExit(done.stdout[-3000:] + done.stderr[-5000:])
    figures = json.loads(lines[-1].removeprefix("RAY_BENCH "))
    sys.path.insert(0, str(Path(__file__).parent))
    from rich.console import Console
    from rich.table import Table

    from learning import robosuite_lift_step_ms

    lift_ms = robosuite_lift_step_ms()
    table = Table(title=f"Ray launcher vs local (Lift step {lift_ms:.2f} ms)")
    for column in ("measured", "median", "runs"):
        table.add_column(column)
    for name, values in figures.items():
        unit = "fps per session" if name.startswith("fps") else "s, join to first frame"
        shown = ", ".join(f"{v:.1f}" for v in values)
        table.add_row(f"{name} ({unit})", f"{statistics.median(values):.2f}", shown)
    Console().print(table)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"lift_step_ms": lift_ms, **figures}, indent=1))


if __name__ == "__main__":
    main()
