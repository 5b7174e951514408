"""A crowd's reports as a table for people and JSON for scripts."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
from rich.table import Table

from crowdteleop.crowd.worker import WorkerReport


def _fmt(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def crowd_table(reports: list[WorkerReport]) -> Table:
    table = Table(
        "bot", "task", "device", "queued s", "first frame s", "episodes", "episode s",
        "latency p50/p95 ms", "fps", "completion code",
    )  # fmt: skip
    for report in reports:
        episodes = f"{report.outcomes.count('success')}/{len(report.outcomes)}"
        latency = f"{_fmt(report.latency_p50_ms, 0)}/{_fmt(report.latency_p95_ms, 0)}"
        mean_episode = float(np.mean(report.episode_s)) if report.episode_s else None
        code = report.completion_code or f"[red]{report.error or 'none'}[/red]"
        table.add_row(
            report.name, report.task, report.device, _fmt(report.queued_s),
            _fmt(report.first_frame_s), episodes, _fmt(mean_episode), latency,
            _fmt(report.fps), code,
        )  # fmt: skip
    return table


def summary(reports: list[WorkerReport]) -> dict[str, float | int | None]:
    """The crowd in a few numbers: completions, and latency over every frame of every bot."""
    latencies = [sample for report in reports for sample in report.latency_ms]
    first_frames = [r.first_frame_s for r in reports if r.first_frame_s is not None]
    return {
        "bots": len(reports),
        "completed": sum(report.completion_code is not None for report in reports),
        "errors": sum(report.error is not None for report in reports),
        "first_frame_s_median": float(np.median(first_frames)) if first_frames else None,
        "latency_p50_ms": float(np.median(latencies)) if latencies else None,
        "latency_p95_ms": float(np.percentile(latencies, 95)) if latencies else None,
        "fps_median": float(np.median([r.fps for r in reports])) if reports else None,
    }


def write_json(reports: list[WorkerReport], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    body = {"summary": summary(reports), "workers": [asdict(report) for report in reports]}
    path.write_text(json.dumps(body, indent=2))
