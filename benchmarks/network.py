"""The paper's network experiment (Sec. 4.3, Tables 4-6) with bots (issue 15, item 4).

For each task and link condition, a coordinator and its teleop servers run in one network
namespace, a crowd of bots (`crowdteleop bot --coordinator`) in another, and the user-space
link emulator between them applies the condition both ways: the paper's four Cellsim settings
(2.4 Mbps or 500 kbps, 20 ms or 120 ms one-way), 2 % loss, and, with --trace, a recorded
cellular trace in Mahimahi's format. The bots of a condition share one link at N times the
rate and queue, so each has the paper's link as its fair share.

Every episode is recorded with its condition as `network_condition`; `crowdteleop dataset
stats` over the recorded episodes gives the completion-time table and the KS table across
conditions in the paper's layout. Beside it: video bitrate, fps and control-to-photon latency
per condition, from the episodes' telemetry and the bots' reports.

    sudo .venv/bin/python benchmarks/network.py --tasks lift,pick-place-can --bots 4 --demos 10
    sudo .venv/bin/python benchmarks/network.py --tasks lift --bots 2 --demos 2 --out out/net
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from crowdteleop.crowd.experiment import PAPER_CONDITIONS, Condition, ConditionRun, run_condition
from crowdteleop.linkemu.shaping import read_mahimahi_trace

ADMIN = "network-admin-token-0123456789"


def _median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def episode_telemetry(run: ConditionRun) -> dict[str, float | None]:
    """Medians over the condition's episodes of what their servers measured on the link."""
    from crowdteleop.dataset.build import episode_files, read_inputs

    episodes, _ = read_inputs(episode_files([run.episodes_dir]))
    telemetry = [ep.metadata.get("telemetry") or {} for _, ep in episodes]

    def median_of(key: str) -> float | None:
        return _median([float(t[key]) for t in telemetry if t.get(key) is not None])

    return {
        "episodes": len(episodes),
        "video_kbps": median_of("bitrate_kbps"),
        "server_fps": median_of("fps"),
        "rtt_ms": median_of("rtt_ms"),
        "loss_fraction": median_of("loss_fraction"),
    }


def summarize(run: ConditionRun) -> dict[str, Any]:
    crowd = run.crowd.get("workers", [])
    latency = [sample for worker in crowd for sample in worker["latency_ms"]]
    episode_s = [
        seconds
        for worker in crowd
        for seconds, outcome in zip(worker["episode_s"], worker["outcomes"], strict=False)
        if outcome == "success"
    ]
    return {
        "condition": run.condition,
        "task": run.task,
        "bots_completed": sum(worker["completion_code"] is not None for worker in crowd),
        "bots": len(crowd),
        "errors": [worker["error"] for worker in crowd if worker["error"]],
        "successes": len(episode_s),
        "episode_s_median": _median(episode_s),
        "fps_median": _median([worker["fps"] for worker in crowd]),
        "latency_p50_ms": _median(latency),
        "latency_p95_ms": statistics.quantiles(latency, n=20)[-1] if len(latency) > 1 else None,
        **episode_telemetry(run),
        "link": run.link,
        "seconds": run.seconds,
    }


def _num(value: Any, digits: int = 0) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="lift,pick-place-can")
    parser.add_argument("--conditions", default=",".join(c.name for c in PAPER_CONDITIONS))
    parser.add_argument("--trace", type=Path, help="a Mahimahi trace: one more condition")
    parser.add_argument("--bots", type=int, default=4, help="bots at once per condition")
    parser.add_argument("--demos", type=int, default=10, help="successful demos per bot")
    parser.add_argument("--out", type=Path, default=Path("out/network"))
    parser.add_argument("--timeout", type=float, default=1200.0, help="per condition, s")
    args = parser.parse_args()

    wanted = set(args.conditions.split(","))
    conditions: list[Condition] = [c for c in PAPER_CONDITIONS if c.name in wanted]
    if args.trace is not None:
        times = tuple(read_mahimahi_trace(args.trace))
        conditions.append(Condition(f"trace-{args.trace.stem}", delay_ms=20, trace_ms=times))
    console = Console()
    rows = []
    for task in args.tasks.split(","):
        for condition in conditions:
            with console.status(f"{task}, {condition.name}: {args.bots} bots ..."):
                run = run_condition(
                    condition, task, args.bots, args.demos, args.out, ADMIN, args.timeout
                )
            row = summarize(run)
            rows.append(row)
            console.print(
                f"{task} {condition.name}: {row['successes']} successes, "
                f"{row['bots_completed']}/{row['bots']} codes, {run.seconds:.0f} s"
            )
            (args.out / "network.json").write_text(json.dumps(rows, indent=2, default=str))
    table = Table(
        "task", "condition", "demos", "codes", "episode s (median)", "video kbps",
        "fps", "latency p50 / p95 ms", "rtt ms", "loss %",
    )  # fmt: skip
    for row in rows:
        table.add_row(
            row["task"], row["condition"], str(row["successes"]),
            f"{row['bots_completed']}/{row['bots']}", _num(row["episode_s_median"], 1),
            _num(row["video_kbps"]), _num(row["fps_median"], 1),
            f"{_num(row['latency_p50_ms'])} / {_num(row['latency_p95_ms'])}",
            _num(row["rtt_ms"]), _num(100 * (row["loss_fraction"] or 0), 1),
        )  # fmt: skip
    console.print(table)
    sources = [str(args.out / f"{r['task']}-{r['condition']}" / "data" / "episodes") for r in rows]
    stats = [sys.executable, "-m", "crowdteleop", "dataset", "stats", *sources]
    subprocess.run([*stats, "--output", str(args.out / "stats")], check=True)


if __name__ == "__main__":
    main()
