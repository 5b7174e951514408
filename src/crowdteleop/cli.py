"""The `crowdteleop` command line."""

from __future__ import annotations

import contextlib
import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, cast

import typer
import typer.main
from pydantic import ValidationError
from pydantic_core import ErrorDetails
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from typer.core import TyperGroup

from crowdteleop.coord.cli import serve  # typer only: its imports are inside the command
from crowdteleop.errors import CrowdteleopError
from crowdteleop.tasks import task_names
from crowdteleop.vocab import (
    INJECTED_FAULTS,
    SKILL_NAMES,
    ControllerName,
    InjectedFault,
    SkillName,
)

if TYPE_CHECKING:  # `crowdteleop --help` loads no simulator
    from crowdteleop.control.scripted import EpisodeResult

# Command groups whose modules are imported only when one of their commands runs (or shows its
# own help): `crowdteleop serve`, `tasks` and `--help` never load scipy, MuJoCo or torch.
DEFERRED_GROUPS = {
    "dataset": (
        "crowdteleop.dataset.cli:app",
        "Build, replay, summarize and export demonstration datasets.",
    ),
    "learn": ("crowdteleop.learn.cli:app", "Train policies on datasets and evaluate them."),
    "tasks": (
        "crowdteleop.taskcheck.cli:app",
        "List the tasks (built-in and plug-ins'), and check a task's fast path.",
    ),
    "node": (
        "crowdteleop.coord.node:app",
        "Join this machine to the Ray cluster that runs teleop servers.",
    ),
    "review": (
        "crowdteleop.coord.cli:review_app",
        "Files from the review decisions: bonus payments for the study platforms.",
    ),
}


class _DeferredGroup(TyperGroup):
    """Stands in for a command group in the listing; the group itself is imported when the
    command line reaches it (`make_context`, which parses and then runs it)."""

    def __init__(self, name: str, target: str, help_text: str) -> None:
        super().__init__(name=name, help=help_text)
        self.target = target

    def load(self) -> TyperGroup:
        module, _, attribute = self.target.partition(":")
        group = typer.main.get_group(getattr(importlib.import_module(module), attribute))
        group.name = self.name
        return group

    def make_context(
        self, info_name: str | None, args: list[str], parent: Any = None, **extra: Any
    ) -> Any:
        return self.load().make_context(info_name, args, parent=parent, **extra)


class CrowdteleopCommands(TyperGroup):
    """The top-level commands, with the deferred groups added after the eager ones."""

    def __init__(self, **attrs: Any) -> None:
        super().__init__(**attrs)
        for name, (target, help_text) in DEFERRED_GROUPS.items():
            self.add_command(_DeferredGroup(name, target, help_text))


app = typer.Typer(
    help="crowdteleop: crowdsourced robot teleoperation.",
    no_args_is_help=True,
    cls=CrowdteleopCommands,
)
console = Console()


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
        return "; ".join(_field_message(error) for error in exc.errors())
    return str(exc)


def _field_message(error: ErrorDetails) -> str:
    """One pydantic error as "field: message", so a user knows which option to fix."""
    message = error["msg"].removeprefix("Value error, ")
    field = ".".join(str(part) for part in error.get("loc", ()))
    return f"{field}: {message}" if field else message


def _film_demo(
    task: str,
    robot: str,
    controller: ControllerName,
    seed: int,
    camera: str,
    width: int,
    height: int,
    output: Path,
) -> EpisodeResult:
    # Heavy imports here so `crowdteleop --help` stays instant.
    from crowdteleop.control.config import ControlConfig
    from crowdteleop.control.scripted import ScriptedOperator, run_episode
    from crowdteleop.control.teleoperator import Teleoperator, TeleopStep
    from crowdteleop.dataset.video import Mp4Writer
    from crowdteleop.sim import SimConfig, make_simulation
    from crowdteleop.sim.rendering import validate_resolution
    from crowdteleop.tasks import get_task

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

            def film(step: TeleopStep) -> None:
                video.write(sim.render(camera, width, height))
                bar.advance(job, sim.control_dt)

            result = run_episode(teleop, operator, seed, on_step=film)
            bar.update(job, completed=limit)  # an early success finishes the bar
            return result
    finally:
        sim.close()


@app.command("teleop-server")
def teleop_server(
    config: Annotated[
        Path | None, typer.Option(help="TeleopConfig as JSON (other options override it)")
    ] = None,
    task: Annotated[str | None, typer.Option(help="task name")] = None,
    robot: Annotated[str | None, typer.Option(help="robosuite arm")] = None,
    controller: Annotated[ControllerName | None, typer.Option(help="ik-velocity or osc")] = None,
    codec: Annotated[str | None, typer.Option(help="vp8 or h264")] = None,
    token: Annotated[str | None, typer.Option(help="workers' session token")] = None,
    admin_token: Annotated[str | None, typer.Option(help="enables the admin channel")] = None,
    record_dir: Annotated[Path | None, typer.Option(help="where episodes are written")] = None,
    host: Annotated[str, typer.Option(help="address to bind")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port; 0 picks a free one")] = 8001,
) -> None:
    """Run one teleop session (one simulated robot, one worker) until interrupted."""
    import asyncio
    import logging

    from crowdteleop.teleop.config import TeleopConfig
    from crowdteleop.teleop.server import serve

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s %(message)s")
    try:
        fields = {} if config is None else _read_json(config)
        overrides = {"token": token, "admin_token": admin_token}
        fields.update({key: value for key, value in overrides.items() if value is not None})
        if controller is not None:
            fields["control"] = {**fields.get("control", {}), "controller": controller}
        sim = dict(fields.get("sim", {}))
        sim.update({key: v for key, v in {"task": task, "robot": robot}.items() if v is not None})
        fields["sim"] = sim
        if codec is not None:
            fields["video"] = {**fields.get("video", {}), "codec": codec}
        if record_dir is not None:
            fields["recording"] = {**fields.get("recording", {}), "directory": str(record_dir)}
        settings = TeleopConfig.model_validate(fields)
    except (CrowdteleopError, ValidationError, OSError, ValueError) as exc:
        Console(stderr=True).print(f"[red]error:[/red] {_explain(exc)}")
        raise typer.Exit(2) from exc
    try:
        with contextlib.suppress(KeyboardInterrupt):
            asyncio.run(serve(settings, host, port))
    except CrowdteleopError as exc:  # e.g. a task whose environment cannot be built
        # one line, unwrapped: the coordinator quotes a server's last output when it fails
        Console(stderr=True, soft_wrap=True).print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from exc


@app.command()
def bot(
    url: Annotated[str, typer.Option(help="teleop server URL")] = "http://127.0.0.1:8001",
    token: Annotated[str, typer.Option(help="session token")] = "dev-token",
    admin_token: Annotated[str, typer.Option(help="admin token (privileged state)")] = "",
    episodes: Annotated[int, typer.Option(help="episodes to drive")] = 1,
    timeout: Annotated[float, typer.Option(help="give up after this many seconds")] = 300.0,
    coordinator: Annotated[
        str | None,
        typer.Option(help="join through this coordinator as workers do, instead of --url"),
    ] = None,
    count: Annotated[int, typer.Option(help="with --coordinator: how many bots join")] = 1,
    campaign: Annotated[str | None, typer.Option(help="with --coordinator: campaign")] = None,
    task: Annotated[
        str | None, typer.Option(help="with --coordinator: the task the campaign must assign")
    ] = None,
    phone_every: Annotated[
        int, typer.Option(help="with --coordinator: every k-th bot drives from a paired phone")
    ] = 0,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="with --coordinator: per-bot report file")
    ] = None,
    skill: Annotated[
        SkillName | None,
        typer.Option(
            help="a synthetic worker of known skill (docs/quality.md); default: the steady "
            "scripted operator"
        ),
    ] = None,
    skills: Annotated[
        str | None,
        typer.Option(help="with --coordinator: skills the bots take in turn, e.g. novice,expert"),
    ] = None,
    fault: Annotated[
        InjectedFault | None,
        typer.Option(
            help="a fault made in every demonstration, to test the quality flags: a 10 s idle "
            "before the grasp, a detour, a drop (docs/quality.md)"
        ),
    ] = None,
    faults: Annotated[
        str | None,
        typer.Option(help="with --coordinator: faults the bots take in turn, e.g. idle,drop"),
    ] = None,
) -> None:
    """Drive a running teleop session with a scripted operator, through the network; or, with
    --coordinator, join COUNT bots as workers and report what each lived through."""
    if not admin_token:
        console.print("[red]error:[/red] the bot needs --admin-token (it reads object poses)")
        raise typer.Exit(2)
    if coordinator is None:
        if skills is not None or faults is not None:
            console.print(
                "[red]error:[/red] --skills and --faults are for a crowd (--coordinator); use "
                "--skill and --fault"
            )
            raise typer.Exit(2)
        _one_bot(url, token, admin_token, episodes, timeout, skill, fault)
        return
    crowd_skills = _skill_list(skills) if skills is not None else (skill,) if skill else ()
    crowd_faults = _fault_list(faults) if faults is not None else (fault,) if fault else ()
    _crowd(
        coordinator,
        admin_token,
        count,
        campaign,
        task,
        phone_every,
        timeout,
        json_out,
        crowd_skills,
        crowd_faults,
    )


def _one_bot(
    url: str,
    token: str,
    admin_token: str,
    episodes: int,
    timeout: float,
    skill: SkillName | None,
    fault: InjectedFault | None,
) -> None:
    """One bot driving the teleop server at `url`, and what became of its episodes."""
    from crowdteleop.client.bot import main as run_bot

    try:
        result = run_bot(url, token, admin_token, episodes, timeout, skill, fault)
    except (ConnectionError, TimeoutError, OSError) as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(1) from exc
    console.print(
        f"{result.successes}/{len(result.episodes)} episodes succeeded "
        f"({', '.join(result.episodes)}) in {result.seconds:.1f} s"
    )


def _skill_list(text: str) -> tuple[SkillName, ...]:
    """`--skills novice,expert` as skill names; an unknown one is an error naming the known."""
    return tuple(cast("SkillName", name) for name in _names(text, SKILL_NAMES, "skill"))


def _fault_list(text: str) -> tuple[InjectedFault, ...]:
    """`--faults idle,drop` as fault names; an unknown one is an error naming the known."""
    return tuple(cast("InjectedFault", name) for name in _names(text, INJECTED_FAULTS, "fault"))


def _names(text: str, known: tuple[str, ...], what: str) -> list[str]:
    """A comma-separated list of `known` names; anything else is an error naming them."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in known]
    if unknown or not names:
        console.print(
            f"[red]error:[/red] unknown {what}(s) {', '.join(map(repr, unknown)) or repr(text)};"
            f" known: {', '.join(known)}"
        )
        raise typer.Exit(2)
    return names


def _crowd(
    coordinator: str,
    admin_token: str,
    count: int,
    campaign: str | None,
    task: str | None,
    phone_every: int,
    timeout: float,
    json_out: Path | None,
    skills: tuple[SkillName, ...] = (),
    faults: tuple[InjectedFault, ...] = (),
) -> None:
    import asyncio

    from crowdteleop.crowd.report import crowd_table, summary, write_json
    from crowdteleop.crowd.worker import CrowdSettings, run_crowd

    if task is not None and task not in task_names():
        console.print(f"[red]error:[/red] unknown task {task!r}; known: {', '.join(task_names())}")
        raise typer.Exit(2)
    settings = CrowdSettings(
        coordinator,
        admin_token,
        campaign,
        task,
        session_timeout_s=timeout,
        phone_every=phone_every,
        skills=skills,
        faults=faults,
    )
    with console.status(f"{count} bot(s) joining {coordinator} ..."):
        reports = asyncio.run(run_crowd(settings, count))
    console.print(crowd_table(reports))
    totals = summary(reports)
    console.print(
        f"{totals['completed']}/{count} bots got a completion code; latency p50 "
        f"{totals['latency_p50_ms']} ms, p95 {totals['latency_p95_ms']} ms"
    )
    if json_out is not None:
        write_json(reports, json_out)
    if totals["completed"] != count:
        raise typer.Exit(1)


@app.command("protocol-schema")
def protocol_schema() -> None:
    """Print the JSON Schema of the teleop message protocol."""
    import json

    from crowdteleop.teleop.protocol import json_schema

    print(json.dumps(json_schema(), indent=2))


def _read_json(path: Path) -> dict[str, Any]:
    import json

    fields: dict[str, Any] = json.loads(path.read_text())
    return fields


app.command("serve")(serve)  # listed after the teleop commands
