"""Simulation cost per task: our control step and teleop step, rendering, state, memory, next to
plain robosuite. See benchmarks/README.md for what each column means.

    .venv/bin/python benchmarks/sim.py --tasks lift,mujoco-lift --repeats 5 --steps 100
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Table

from _measure import (
    BenchOptions,
    TaskBench,
    TaskResult,
    machine_facts,
    median,
    release_memory,
    size_key,
)
from crowdteleop.tasks import task_names

app = typer.Typer(add_completion=False)
TABLE_WIDTH = 160  # when not writing to a terminal, don't squeeze the table into 80 columns


def _console() -> Console:
    console = Console()
    return console if console.is_terminal else Console(width=TABLE_WIDTH)


def _parse_tasks(text: str) -> list[str]:
    tasks = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in tasks if name not in task_names()]
    if unknown or not tasks:
        raise typer.BadParameter(
            f"unknown task(s) {', '.join(unknown) or '(none)'}; "
            f"choose from: {', '.join(task_names())}"
        )
    return tasks


def _parse_sizes(text: str) -> tuple[tuple[int, int], ...]:
    try:
        sizes = tuple(
            (int(w), int(h)) for w, h in (item.lower().split("x") for item in text.split(","))
        )
    except ValueError:
        sizes = ()
    if not sizes or any(w < 16 or h < 16 for w, h in sizes):
        raise typer.BadParameter(f"sizes are WIDTHxHEIGHT[,WIDTHxHEIGHT...], got {text!r}")
    return sizes


def _fmt(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _ratio(theirs: float | None, ours: float | None) -> str:
    """How many times faster ours is (ratio of medians from the same run)."""
    return "-" if not theirs or not ours else f"{theirs / ours:.1f}x"


def results_table(results: list[TaskResult], options: BenchOptions) -> Table:
    """One row per task: medians of the repeats."""
    table = Table(
        title="Simulation cost per task (medians)",
        caption=(
            f"control step: median of {options.repeats} runs x {options.steps} steps at "
            f"{options.control_hz:g} Hz; render: median of {options.repeats} runs x "
            f"{options.frames} frames; state: median of batch means, {options.state_calls} calls; "
            "rs = plain robosuite (OSC_POSE default controller)"
        ),
    )
    table.add_column("task", no_wrap=True)
    table.add_column("step\nms", justify="right")
    table.add_column("teleop\nms", justify="right")
    table.add_column("rs step\nms", justify="right")
    table.add_column("step\nspeed-up", justify="right")
    for size in options.sizes:
        table.add_column(f"render\n{size_key(size)}\nours ms", justify="right")
        table.add_column(f"render\n{size_key(size)}\nrs ms", justify="right")
        table.add_column(f"render\n{size_key(size)}\nspeed-up", justify="right")
    table.add_column("get_state\nus", justify="right")
    table.add_column("set_state\nus", justify="right")
    if options.memory:
        table.add_column("RSS base\nMiB", justify="right")
        table.add_column("+1st sim\nMiB", justify="right")
        table.add_column("+2nd sim\nMiB", justify="right")
    for result in results:
        row = [
            result.task,
            _fmt(median(result.step_ms), 2),
            _fmt(median(result.teleop_ms), 2),
            _fmt(median(result.robosuite_step_ms), 2),
            _ratio(median(result.robosuite_step_ms), median(result.step_ms)),
        ]
        for size in options.sizes:
            key = size_key(size)
            rs_render = result.robosuite_render_ms or {}
            ours, theirs = median(result.render_ms.get(key)), median(rs_render.get(key))
            row += [_fmt(ours, 1), _fmt(theirs, 1), _ratio(theirs, ours)]
        row += [_fmt(median(result.get_state_us), 1), _fmt(median(result.set_state_us), 1)]
        if options.memory:
            memory = result.memory_mib or {}
            row += [
                _fmt(memory.get("baseline"), 0),
                _fmt(memory.get("first_sim"), 0),
                _fmt(memory.get("second_sim"), 0),
            ]
        table.add_row(*row)
    return table


def facts_table(facts: dict[str, str]) -> Table:
    table = Table(title="Machine", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    for name, value in facts.items():
        table.add_row(name, value)
    return table


def run(tasks: list[str], options: BenchOptions) -> list[TaskResult]:
    """Every phase of every task, one after another, under a progress bar (on stderr)."""
    benches = [TaskBench(task, options) for task in tasks]
    total = sum(len(bench.phases()) for bench in benches)
    results = []
    progress = Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=Console(stderr=True),
        transient=True,
    )
    with progress:
        bar = progress.add_task("starting", total=total)
        for bench in benches:
            try:
                for label, phase in bench.phases():
                    progress.update(bar, description=f"{bench.spec.name}: {label}")
                    phase()
                    progress.advance(bar)
            finally:
                bench.close()
            results.append(bench.result)
            release_memory()
    return results


@app.command()
def main(
    tasks: Annotated[str, typer.Option(help="comma-separated task names")] = ",".join(task_names()),
    repeats: Annotated[int, typer.Option(min=1, help="runs per measurement (median)")] = 5,
    steps: Annotated[int, typer.Option(min=1, help="control steps per run")] = 100,
    frames: Annotated[int, typer.Option(min=1, help="rendered frames per run")] = 10,
    sizes: Annotated[str, typer.Option(help="render sizes, WxH,...")] = "320x240,480x360",
    state_calls: Annotated[int, typer.Option(min=50, help="get/set_state calls")] = 2000,
    robot: Annotated[str, typer.Option(help="robosuite arm")] = "Sawyer",
    memory: Annotated[bool, typer.Option(help="measure RSS in a subprocess per task")] = True,
    json_path: Annotated[
        Path | None, typer.Option("--json", help="also write raw values here")
    ] = None,
) -> None:
    """Measure each task's simulation costs and print one table."""
    options = BenchOptions(
        robot=robot,
        repeats=repeats,
        steps=steps,
        frames=frames,
        sizes=_parse_sizes(sizes),
        state_calls=state_calls,
        memory=memory,
    )
    task_names = _parse_tasks(tasks)
    console = _console()
    facts = machine_facts()
    console.print(facts_table(facts))
    results = run(task_names, options)
    console.print(results_table(results, options))
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        report = {
            "machine": facts,
            "options": {
                "tasks": task_names,
                "robot": robot,
                "control_hz": options.control_hz,
                "repeats": repeats,
                "steps": steps,
                "frames": frames,
                "sizes": [size_key(s) for s in options.sizes],
                "state_calls": state_calls,
            },
            "results": [result.to_json() for result in results],
        }
        json_path.write_text(json.dumps(report, indent=2))
        console.print(f"raw values written to {json_path}")


if __name__ == "__main__":
    app()
