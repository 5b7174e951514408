"""How many busy sessions this machine holds, measured by running them at once.

`session.py` measures one session's CPU share alone and divides; here N busy sessions run at the
same time, each its own process (as the platform runs one teleop server per worker), their
measured windows started together, and each must keep its 20 Hz loop. Shared caches, memory
bandwidth and the scheduler all count, as they do on a loaded machine.

    .venv/bin/python benchmarks/at_once.py --tasks lift --sessions 8,10 --json out/at-once.json
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from dataclasses import asdict
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from _measure import machine_facts, median
from session import (
    DEFAULT_TASKS,
    READY_MARKER,
    CameraOption,
    ControllerOption,
    JsonOption,
    PixelsOption,
    RobotOption,
    SecondsOption,
    SessionResult,
    TasksOption,
    child_command,
    parse_child_output,
    session_options,
)
from sim import _console, _parse_tasks, facts_table

app = typer.Typer(add_completion=False)
ON_TIME_TARGET = 0.99  # a session holds its rate when >= 99% of its ticks start on their slot
SEEDS_APART = 1000  # each session works its own scenes


def run_at_once(task: str, count: int, opts: dict[str, Any]) -> list[SessionResult]:
    """`count` busy sessions of `task`, started together; each child builds and warms up, says
    so, and waits for a line on stdin, so every measured window starts at the same moment."""
    opts = opts | {"wait_for_go": True}
    children = [
        subprocess.Popen(
            child_command(task, "busy", opts, first_seed=SEEDS_APART * k),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for k in range(count)
    ]
    try:
        for child in children:  # every session built and warm before any is measured
            assert child.stdout is not None
            for line in child.stdout:
                if line.strip() == READY_MARKER:
                    break
            else:
                raise RuntimeError(f"a {task} session exited before it was ready")
        for child in children:
            assert child.stdin is not None
            child.stdin.write("go\n")
            child.stdin.flush()
        results = []
        for index, child in enumerate(children):
            stdout, stderr = child.communicate(timeout=opts["seconds"] + 300)
            label = f"{task} #{index + 1} of {count}"
            results.append(parse_child_output(label, stdout, stderr, child.returncode))
        return results
    finally:
        for child in children:
            if child.poll() is None:
                child.kill()
                child.wait()


def on_time(result: SessionResult) -> float:
    return 1.0 - result.overruns / result.ticks


def results_table(rows: list[tuple[str, int, list[SessionResult]]], opts: dict[str, Any]) -> Table:
    cores = len(os.sched_getaffinity(0))
    table = Table(
        title="Busy sessions at once",
        caption=(
            f"{opts['seconds']:g} s at 20 Hz, {opts['controller']}, {opts['camera']} "
            f"{opts['width']}x{opts['height']}, VP8 as the teleop server encodes it; each session "
            "its own process, measured windows started together; CPU = (process time - the "
            "scripted operator's) / wall; machine = all the processes' CPU, operators included; "
            "on time = ticks that ended before the next was due; "
            f"holds = every session on time >= {ON_TIME_TARGET:.0%}"
        ),
    )
    columns = ["task", "sessions", "CPU % core\nmedian", "CPU % core\nmax"]
    columns += [f"machine\n% of {cores} cores", "on time\nworst", "loop Hz\nworst"]
    columns += ["step / render /\nencode ms", "episodes\n(success)", "holds"]
    for name in columns:
        table.add_column(name, justify="left" if name == "task" else "right")
    for task, count, results in rows:
        shares = [r.cpu_percent for r in results]
        machine = sum(r.cpu_s for r in results) / max(r.wall_s for r in results) / cores
        worst = min(results, key=on_time)
        holds = all(on_time(r) >= ON_TIME_TARGET for r in results)
        phases = " / ".join(
            f"{median([r.phase_ms[p] for r in results]):.2f}" for p in ("step", "render", "encode")
        )
        episodes = f"{sum(r.episodes for r in results)} ({sum(r.successes for r in results)})"
        table.add_row(
            task,
            str(count),
            f"{median(shares):.1f}",
            f"{max(shares):.1f}",
            f"{100.0 * machine:.0f}",
            f"{100.0 * on_time(worst):.1f}%",
            f"{min(r.ticks / r.wall_s for r in results):.1f}",
            phases,
            episodes,
            "[green]yes[/]" if holds else "[red]no[/]",
        )
    return table


@app.command()
def main(
    tasks: TasksOption = DEFAULT_TASKS,
    sessions: Annotated[str, typer.Option(help="comma-separated session counts")] = "8",
    seconds: SecondsOption = 20.0,
    controller: ControllerOption = "ik-velocity",
    camera: CameraOption = "frontview",
    width: PixelsOption = 320,
    height: PixelsOption = 240,
    robot: RobotOption = "Sawyer",
    json_path: JsonOption = None,
) -> None:
    """Run N busy sessions at once per task and count how many keep their 20 Hz."""
    opts = session_options(seconds, controller, camera, width, height, robot)
    try:
        counts = [int(text) for text in sessions.split(",")]
    except ValueError as exc:
        raise typer.BadParameter(f"sessions are whole numbers, got {sessions!r}") from exc
    if any(count < 1 for count in counts):
        raise typer.BadParameter(f"session counts are at least 1, got {sessions!r}")
    task_names = _parse_tasks(tasks)
    console = _console()
    facts = machine_facts()
    console.print(facts_table(facts))
    rows = []
    with Console(stderr=True).status("") as status:
        for task in task_names:
            for count in counts:
                status.update(f"{task}: {count} busy sessions at once ({seconds:g} s)")
                rows.append((task, count, run_at_once(task, count, opts)))
                time.sleep(2.0)  # let the last processes' exits settle before the next set
    console.print(results_table(rows, opts))
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        report = {"machine": facts, "options": opts | {"tasks": task_names, "sessions": counts}}
        report["results"] = [
            {"task": task, "sessions": count, "runs": [asdict(r) for r in results]}
            for task, count, results in rows
        ]
        json_path.write_text(json.dumps(report, indent=2))
        console.print(f"raw values written to {json_path}")


if __name__ == "__main__":
    app()
