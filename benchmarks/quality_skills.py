"""Does the composite score separate workers of known skill (issue 29)? Synthetic workers
(`control/scripted/skills.py`) recorded in-process on the scripted rig, each episode measured
as it is written, then scored as a campaign would score it (`recording.quality.quality_score`
against the successful episodes of all levels), and flagged at the default thresholds.

    .venv/bin/python benchmarks/quality_skills.py --task lift --per-level 30
    .venv/bin/python benchmarks/quality_skills.py --task pick-place-can --per-level 30

Reports, per level: successes, median completion time and score, the flags raised; the ROC AUC
of the score for expert against novice (successful episodes); and what the novices' flags
named. In-process, not through the coordinator: the same functions the coordinator calls on
each report, without WebRTC's real-time pace (the crowd run is tests/crowd and capacity.py).
"""

from __future__ import annotations

import collections
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import typer
from rich.console import Console

from crowdteleop.control.scripted.skills import SKILLS
from crowdteleop.recording.episode_file import read_metadata
from crowdteleop.recording.quality import (
    SCORED_METRICS,
    EpisodeMetrics,
    QualityThresholds,
    quality_flags,
    quality_score,
)

app = typer.Typer(add_completion=False)
console = Console(soft_wrap=True)
LEVELS = ("expert", "intermediate", "novice")


def record(
    task: str, robot: str, per_level: int, directory: Path
) -> list[tuple[str, str, EpisodeMetrics]]:
    """(level, outcome, metrics) of `per_level` episodes per level, reset seeds 0.."""
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    recorded = []
    with scripted_rig(task, "osc", robot=robot) as rig:
        for level in LEVELS:
            for seed in range(per_level):
                episode = record_scripted_episode(
                    rig, directory, f"{level}-{seed}", seed, style=SKILLS[level], time_limit_s=60
                )
                assert episode.path is not None
                metrics = EpisodeMetrics.model_validate(read_metadata(episode.path)["quality"])
                recorded.append((level, episode.outcome, metrics))
    return recorded


def roc_auc(positives: list[float], negatives: list[float]) -> float:
    """P(a positive scores above a negative), ties half."""
    p, n = np.asarray(positives)[:, None], np.asarray(negatives)[None, :]
    return float(np.mean((p > n) + 0.5 * (p == n)))


@app.command()
def main(task: str = "lift", robot: str = "Panda", per_level: int = 30) -> None:
    began = time.perf_counter()
    with tempfile.TemporaryDirectory() as scratch:
        recorded = record(task, robot, per_level, Path(scratch))
    successes = [(level, m) for level, outcome, m in recorded if outcome == "success"]
    distributions = {
        name: sorted(v for _, m in successes if (v := getattr(m, name)) is not None)
        for name in SCORED_METRICS
    }
    thresholds = QualityThresholds()
    summary: dict[str, object] = {"date": time.strftime("%Y-%m-%d %H:%M"), "task": task}
    scores: dict[str, list[float]] = {}
    for level in LEVELS:
        mine = [m for lv, m in successes if lv == level]
        scores[level] = [s for m in mine if (s := quality_score(m, distributions)) is not None]
        flags = collections.Counter(
            f.metric for lv, _, m in recorded if lv == level for f in quality_flags(m, thresholds)
        )
        summary[level] = {
            "episodes": per_level,
            "successes": len(mine),
            "median_time_s": statistics.median(m.completion_time_s for m in mine) if mine else None,
            "median_score": statistics.median(scores[level]) if scores[level] else None,
            "flags": dict(flags),
        }
    summary["auc_expert_vs_novice"] = round(roc_auc(scores["expert"], scores["novice"]), 3)
    summary["auc_intermediate_vs_novice"] = round(
        roc_auc(scores["intermediate"], scores["novice"]), 3
    )
    summary["seconds"] = round(time.perf_counter() - began, 1)
    console.print_json(json.dumps(summary))


if __name__ == "__main__":
    app()
