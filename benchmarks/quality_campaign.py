"""A campaign of synthetic workers through the coordinator (issue 29's first Done-when line):
bots of three skills join as workers do (study link, queue, WebRTC, real-time 20 Hz), each
demonstration is measured by its teleop server and scored by the coordinator against the
campaign's successful demonstrations so far, exactly as a crowd's would be. Then bots that
make one fault in every demonstration (`--faults idle,detour,drop,press`) check the flags name it.

    .venv/bin/python benchmarks/quality_campaign.py --task lift --bots-per-level 3 --demos 10
    .venv/bin/python benchmarks/quality_campaign.py --task pick-place-can --bots-per-level 3 \
        --demos 10 --faults idle,detour,drop,press

Reports, per level: demonstrations, successes, median score as stored, the flags raised; the
ROC AUC of the stored score between levels (successful demonstrations: what a dataset holds),
and the same re-scored against the campaign's final distribution (the stored score of an
early demonstration was judged against the few before it); per fault: how many of its
demonstrations carry the flag named for it, and what else was flagged. JSON in --out.
"""

from __future__ import annotations

import collections
import json
import secrets
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import typer
from rich.console import Console

from crowdteleop.recording.quality import SCORED_METRICS, EpisodeMetrics, quality_score
from crowdteleop.teleop.ready import stop_gracefully, wait_ready

app = typer.Typer(add_completion=False)
console = Console(soft_wrap=True)
ADMIN = secrets.token_urlsafe(32)
LEVELS = ("expert", "intermediate", "novice")
FAULT_FLAG = {
    "idle": "longest_pause_s",
    "detour": "path_ratio",
    "drop": "setbacks",
    "press": "table_contact_s",
}


def roc_auc(positives: list[float], negatives: list[float]) -> float | None:
    """P(a positive scores above a negative), ties half: the Mann-Whitney form of the AUC."""
    if not positives or not negatives:
        return None
    wins = sum((p > n) + 0.5 * (p == n) for p in positives for n in negatives)
    return wins / (len(positives) * len(negatives))


def coordinator(folder: Path, task: str, capacity: int, demos: int) -> tuple[Any, str]:
    """`crowdteleop serve` with one campaign of `task` on a Panda under OSC, no practice."""
    campaign = {
        "tasks": [task],
        "robots": ["Panda"],
        "controllers": ["osc"],
        "practice_s": 0,
        "time_limit_s": 3600,
    }
    config = {
        "capacity": capacity,
        "spare_servers": 0,
        "admission": {
            "live_sessions_per_address": 256,
            "joins_per_minute_per_address": 600,
            "max_wait_s": 86400,  # a benchmark's crowd waits its turn, however long
        },
        "campaigns": [{**campaign, "name": "quality", "demos_required": demos}],
    }
    (folder / "coord.json").write_text(json.dumps(config))
    log = folder / "coord.log"
    command = [sys.executable, "-m", "crowdteleop", "serve", "--port", "0", "--admin-token", ADMIN]
    command += ["--data-dir", str(folder / "data"), "--config", str(folder / "coord.json")]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log.open("w"), text=True)
    return process, wait_ready(process, log, 90.0, "coordinator")


def crowd(
    url: str, folder: Path, task: str, extra: list[str], timeout_s: float
) -> list[dict[str, Any]]:
    """Run `crowdteleop bot --coordinator` to the end; the bots' JSON report."""
    name = "quality"
    report = folder / "crowd.json"
    command = [sys.executable, "-m", "crowdteleop", "bot", "--coordinator", url]
    command += ["--admin-token", ADMIN, "--campaign", name, "--task", task]
    command += ["--timeout", str(timeout_s), "--json", str(report), *extra]
    with (folder / "crowd.log").open("w") as log:
        subprocess.run(command, stdout=log, stderr=subprocess.STDOUT, timeout=timeout_s + 600)
    data = json.loads(report.read_text())
    return data["workers"] if isinstance(data, dict) else data


def episodes_of(url: str, session_id: str) -> list[dict[str, Any]]:
    headers = {"Authorization": f"Bearer {ADMIN}"}
    response = httpx.get(f"{url}/api/admin/sessions/{session_id}/episodes", headers=headers)
    response.raise_for_status()
    return list(response.json())


def levels_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per level and between levels, on the demonstrations as the coordinator scored them."""
    done = [row for row in rows if row["outcome"] == "success" and row["score"] is not None]
    final = {  # the campaign's distribution at the end
        name: sorted(m for row in done if (m := row["metrics"].get(name)) is not None)
        for name in SCORED_METRICS
    }
    for row in done:
        row["final_score"] = quality_score(EpisodeMetrics.model_validate(row["metrics"]), final)
    summary: dict[str, Any] = {}
    for level in LEVELS:
        mine = [row for row in rows if row["skill"] == level]
        ok = [row for row in done if row["skill"] == level]
        flags = collections.Counter(f["metric"] for row in mine for f in row["flags"] or [])
        summary[level] = {
            "episodes": len(mine),
            "successes": len(ok),
            "median_score": round(statistics.median(r["score"] for r in ok), 1) if ok else None,
            "median_time_s": round(statistics.median(r["duration_s"] for r in ok), 1)
            if ok
            else None,
            "flags": dict(flags),
        }
    for key in ("score", "final_score"):
        by = {level: [row[key] for row in done if row["skill"] == level] for level in LEVELS}
        for better, worse in (
            ("expert", "novice"),
            ("expert", "intermediate"),
            ("intermediate", "novice"),
        ):
            auc = roc_auc(by[better], by[worse])
            summary[f"auc_{key}_{better}_vs_{worse}"] = None if auc is None else round(auc, 3)
    return summary


def faults_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per fault: its demonstrations, how many carry the flag named for it, what else."""
    summary: dict[str, Any] = {}
    for fault, metric in FAULT_FLAG.items():
        mine = [row for row in rows if row["fault"] == fault]
        if not mine:
            continue
        named = [row for row in mine if any(f["metric"] == metric for f in row["flags"] or [])]
        others = collections.Counter(
            f["metric"] for row in mine for f in row["flags"] or [] if f["metric"] != metric
        )
        summary[fault] = {
            "episodes": len(mine),
            "outcomes": dict(collections.Counter(row["outcome"] for row in mine)),
            "flagged_by_name": len(named),
            "expected_flag": metric,
            "reasons": sorted(
                {f["reason"] for row in named for f in row["flags"] if f["metric"] == metric}
            )[:3],
            "other_flags": dict(others),
        }
    return summary


def campaign(
    folder: Path, task: str, capacity: int, demos: int, bots: list[str], timeout_s: float
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """A coordinator, a crowd of bots through it to the end: their reports and episodes."""
    folder.mkdir(parents=True, exist_ok=True)
    process, url = coordinator(folder, task, capacity, demos)
    try:
        workers = crowd(url, folder, task, bots, timeout_s)
        return workers, rows_of(url, workers)
    finally:
        stop_gracefully(process, 60)


def rows_of(url: str, workers: list[dict[str, Any]]) -> list[dict[str, Any]]:
    rows = []
    for worker in workers:
        if not worker.get("session_id"):
            continue
        for episode in episodes_of(url, worker["session_id"]):
            if episode["outcome"] == "disconnect":
                continue  # cut short when the session ended: the bot did not finish it
            episode["skill"], episode["fault"] = worker.get("skill"), worker.get("fault")
            episode["flags"] = episode.get("flags") or []
            episode["metrics"] = episode.get("metrics") or {}
            rows.append(episode)
    return rows


@app.command()
def main(
    task: str = "lift",
    bots_per_level: int = 3,
    demos: int = 10,
    capacity: int = 3,
    faults: str = "idle,detour",
    out: Path = Path("out/quality_campaign"),
    timeout_s: float = 2400.0,
) -> None:
    folder = out / task
    started = time.monotonic()
    workers: list[dict[str, Any]] = []
    rows: list[dict[str, Any]] = []
    if bots_per_level > 0:  # 0: the faults alone
        skills = ["--count", str(3 * bots_per_level), "--skills", ",".join(LEVELS)]
        with console.status(f"{3 * bots_per_level} bots of three skills on {task} ..."):
            workers, rows = campaign(folder / "skills", task, capacity, demos, skills, timeout_s)
    fault_rows: list[dict[str, Any]] = []
    if faults:
        # a coordinator of its own: the crowd's bots are named bot-000..., and a worker who
        # finished a study is not a new worker in the next
        faulty = ["--count", str(len(faults.split(","))), "--skill", "expert", "--faults", faults]
        with console.status(f"bots making the faults {faults} ..."):
            _, fault_rows = campaign(folder / "faults", task, capacity, 2, faulty, 300.0)
    result = {
        "task": task,
        "bots_per_level": bots_per_level,
        "demos_required": demos,
        "capacity": capacity,
        "wall_s": round(time.monotonic() - started, 1),
        "bot_errors": [w.get("error") for w in workers if w.get("error")],
        "levels": levels_summary(rows),
        "faults": faults_summary(fault_rows),
    }
    (folder / "result.json").write_text(json.dumps(result, indent=2))
    (folder / "episodes.json").write_text(json.dumps(rows + fault_rows, indent=1))
    console.print_json(json.dumps(result))


if __name__ == "__main__":
    app()
