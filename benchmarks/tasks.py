"""`crowdteleop tasks check` over every robosuite task and robot: the fast path's step and
render ratios against plain robosuite (in one run), picture fidelity and per-step drift.

    .venv/bin/python benchmarks/tasks.py [--tasks lift,stack] [--robots UR5e] [--json out/t.json]
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import track
from rich.table import Table

from crowdteleop.taskcheck.check import TaskCheck, check_task
from crowdteleop.tasks import catalogue

app = typer.Typer(add_completion=False)
OTHER_ROBOTS = "UR5e,IIWA,Kinova3,Jaco"


def _robosuite_tasks() -> str:
    return ",".join(t.name for t in catalogue().tasks.values() if t.backend == "robosuite")


def _row(result: TaskCheck) -> list[str]:
    return [
        result.task,
        result.robot,
        "fast" if result.fast_path else "robosuite's",
        f"{result.step_ms:.2f} / {result.robosuite_step_ms:.2f}",
        f"{result.step_ratio:.1f}x",
        f"{result.render_ms:.1f} / {result.robosuite_render_ms:.1f}",
        f"{result.render_ratio:.1f}x",
        f"{result.picture_mad:.2f}",
        f"{result.drift_median_m * 1000:.2f} / {result.drift_p95_m * 1000:.2f} / "
        f"{result.drift_max_m * 1000:.2f}",
        result.driven_by,
        "; ".join(result.problems()) or "faithful",
    ]


@app.command()
def main(
    tasks: Annotated[str, typer.Option(help="comma-separated, on each of --arms")] = "",
    arms: Annotated[str, typer.Option(help="arms every task is checked on")] = "Sawyer,Panda",
    robots: Annotated[str, typer.Option(help="comma-separated, each on lift")] = OTHER_ROBOTS,
    steps: int = 600,
    json_out: Annotated[Path | None, typer.Option("--json")] = None,
) -> None:
    names = [task for task in (tasks or _robosuite_tasks()).split(",") if task]
    cases = [(task, arm) for arm in arms.split(",") for task in names]
    cases += [("lift", robot) for robot in robots.split(",") if robot]
    results = [check_task(task, robot, steps) for task, robot in track(cases, "checking")]
    table = Table(
        "task",
        "robot",
        "path",
        "step ms ours / robosuite",
        "ratio",
        "render ms",
        "ratio",
        "MAD",
        "drift mm med / p95 / max",
        "verdict",
        title=f"tasks check, {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, {steps} steps",
    )
    for result in results:
        table.add_row(*_row(result))
    Console(width=200).print(table)
    if json_out is not None:
        json_out.write_text(json.dumps([r.to_json() for r in results], indent=2))


if __name__ == "__main__":
    app()
