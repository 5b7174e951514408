"""The `crowdteleop` command line."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from crowdteleop.control.config import ControllerName
from crowdteleop.errors import CrowdteleopError
from crowdteleop.sim.registry import TASKS

app = typer.Typer(help="crowdteleop: crowdsourced robot teleoperation.", no_args_is_help=True)
console = Console()


@app.command()
def tasks() -> None:
    """List the tasks workers can be given."""
    table = Table("task", "backend", "time limit", "instruction")
    for spec in TASKS.values():
        table.add_row(spec.name, spec.backend, f"{spec.time_limit_s:.0f} s", spec.instruction)
    console.print(table)


@app.command()
def demo(
    task: Annotated[str, typer.Option(help="task name (see `crowdteleop tasks`)")] = "lift",
    robot: Annotated[str, typer.Option(help="robosuite arm")] = "Sawyer",
    controller: Annotated[ControllerName, typer.Option(help="ik-velocity or osc")] = "ik-velocity",
    seed: Annotated[int, typer.Option(help="episode seed")] = 0,
    camera: Annotated[str, typer.Option(help="camera to film")] = "frontview",
    width: Annotated[int, typer.Option(help="video width (even)")] = 320,
    height: Annotated[int, typer.Option(help="video height (even)")] = 240,
    output: Annotated[Path, typer.Option(help="MP4 to write")] = Path("out/demo.mp4"),
) -> None:
    """A scripted operator performs the task headless, filmed to an MP4."""
    try:
        result = _film_demo(task, robot, controller, seed, camera, width, height, output)
    except (CrowdteleopError, ValidationError) as exc:
        console.print(f"[red]error:[/red] {_explain(exc)}")
        raise typer.Exit(2) from exc
    verdict = "[green]success[/green]" if result.success else "[yellow]no success[/yellow]"
    console.print(
        f"{task}: {verdict} after {result.sim_seconds:.1f} s of simulated time "
        f"({result.steps} steps); video: {output}"
    )


def _explain(exc: Exception) -> str:
    if isinstance(exc, ValidationError):
        return "; ".join(error["msg"].removeprefix("Value error, ") for error in exc.errors())
    return str(exc)


def _film_demo(
    task: str,
    robot: str,
    controller: ControllerName,
    seed: int,
    camera: str,
    width: int,
    height: int,
    output: Path,
):
    # Heavy imports here so `crowdteleop --help` stays instant.
    from crowdteleop.control import ControlConfig, Teleoperator
    from crowdteleop.control.scripted import ScriptedOperator, run_episode
    from crowdteleop.data.video import Mp4Writer
    from crowdteleop.sim import SimConfig, get_task, make_simulation
    from crowdteleop.sim.rendering import validate_resolution

    control = ControlConfig(controller=controller)
    validate_resolution(width, height)
    with console.status(f"building {task} on {robot}..."):
        sim = make_simulation(SimConfig(task=task, robot=robot, action_mode=control.action_mode))
    try:
        sim.render(camera, width, height)  # fail fast on an unknown camera
        teleop = Teleoperator(sim, control)
        operator = ScriptedOperator(sim, control.mapping, seed=seed)
        limit = get_task(task).time_limit_s
        fps = round(1.0 / sim.control_dt)
        columns = (TextColumn("{task.description}"), BarColumn(), TimeRemainingColumn())
        with Mp4Writer(output, fps) as video, Progress(*columns, console=console) as bar:
            job = bar.add_task(f"{task} (simulated seconds)", total=limit)

            def film(step: object) -> None:
                video.write(sim.render(camera, width, height))
                bar.advance(job, sim.control_dt)

            result = run_episode(teleop, operator, seed, on_step=film)
            bar.update(job, completed=limit)  # an early success finishes the bar
            return result
    finally:
        sim.close()
