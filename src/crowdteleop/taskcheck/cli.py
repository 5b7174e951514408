"""`crowdteleop tasks`: list the catalogue; `crowdteleop tasks check NAME`: measure one task."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.tasks import ROBOSUITE_ARMS, catalogue

app = typer.Typer(
    help="List the tasks (built-in and plug-ins'), and check a task's fast path.",
    invoke_without_command=True,
)
console = Console()


@app.callback()
def tasks(context: typer.Context) -> None:
    """Without a command: list the tasks workers can be given, and plug-ins left out."""
    if context.invoked_subcommand is not None:
        return
    found = catalogue()
    table = Table("task", "backend", "time limit", "source", "instruction")
    for spec in found.tasks.values():
        table.add_row(
            spec.name, spec.backend, f"{spec.time_limit_s:.0f} s", spec.source, spec.instruction
        )
    console.print(table)
    for problem in found.problems:
        console.print(f"[yellow]left out:[/yellow] {problem}")


@app.command()
def check(
    name: Annotated[str, typer.Argument(help="task name (see `crowdteleop tasks`)")],
    robot: Annotated[str, typer.Option(help=f"one of {', '.join(ROBOSUITE_ARMS)}")] = "Sawyer",
    steps: Annotated[
        int,
        typer.Option(
            min=10,
            max=2000,
            help="control steps at most (20 a second; a scripted episode "
            "ends when its success has held)",
        ),
    ] = 600,
    json_out: Annotated[Path | None, typer.Option("--json", help="write the figures here")] = None,
) -> None:
    """Step and render time against plain robosuite, picture fidelity and per-step drift.

    Exit 0: the task runs on the fast path and it is faithful, or it runs on robosuite's own
    path (said why). Exit 1: the fast path serves it unfaithfully (declare fast_path: off).
    """
    from crowdteleop.taskcheck.check import check_task

    with console.status(f"checking {name} on {robot} ({steps} steps) ..."):
        result = check_task(name, robot, steps)
    table = Table("measure", "ours", "plain robosuite", "ratio")
    table.add_row(
        "step",
        f"{result.step_ms:.2f} ms",
        f"{result.robosuite_step_ms:.2f} ms",
        f"{result.step_ratio:.1f}x",
    )
    table.add_row(
        "render 320x240",
        f"{result.render_ms:.2f} ms",
        f"{result.robosuite_render_ms:.2f} ms",
        f"{result.render_ratio:.1f}x",
    )
    table.add_row("picture MAD (0-255)", f"{result.picture_mad:.2f}", "", "")
    table.add_row(
        f"drift per step ({result.driven_by})",
        f"median {result.drift_median_m * 1000:.3f} mm",
        f"p95 {result.drift_p95_m * 1000:.2f}, max {result.drift_max_m * 1000:.2f} mm",
        "",
    )
    console.print(table)
    if json_out is not None:
        json_out.write_text(json.dumps(result.to_json(), indent=2))
    if not result.fast_path:
        console.print(
            "[yellow]robosuite's own path[/yellow] (the fast path cannot serve this task): "
            + "; ".join(result.obstacles or ["the task declares fast_path: off"])
        )
        return
    problems = result.problems()
    if problems:
        console.print("[red]the fast path is not faithful here:[/red] " + "; ".join(problems))
        console.print("declare `fast_path: off` for this task, or report it")
        raise typer.Exit(1)
    console.print("[green]the fast path is faithful here[/green]")
