"""``crowdteleop learn rl`` and PPO's side of ``learn eval`` (sb3, torch and the simulators
load inside the commands)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Annotated, Any, Literal

import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.dataset.cli import clear_errors
from crowdteleop.learn.config import VecKind

console = Console(soft_wrap=True)
BUDGET = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([kKmM]?|[smh])\s*$")
SimChoice = Literal["ours", "robosuite", "both"]


def parse_budget(text: str) -> tuple[int | None, float | None]:
    """``200k`` / ``1.5M`` / ``50000`` environment steps, or ``90s`` / ``30m`` / ``2h`` of
    wall time: (steps, seconds), one of them None."""
    match = BUDGET.match(text)
    if not match:
        raise typer.BadParameter(f"{text!r}: give steps (200k, 1.5M) or a time (30m, 2h)")
    value, unit = float(match[1]), match[2]
    if unit in ("s", "m", "h"):
        return None, value * {"s": 1, "m": 60, "h": 3600}[unit]
    return int(value * {"": 1, "k": 1e3, "K": 1e3, "M": 1e6}[unit]), None


def rl(
    output: Annotated[Path, typer.Option(help="directory; each seed trains in seed_<k>/")],
    dataset: Annotated[
        Path | None,
        typer.Option(help="built dataset: its simulation, and the demos episodes start from"),
    ] = None,
    task: Annotated[str | None, typer.Option(help="task, when no dataset is given")] = None,
    robot: Annotated[str, typer.Option(help="arm, when no dataset is given")] = "Panda",
    demos: Annotated[int, typer.Option(help="demos to start from (first n); 0: pure RL")] = 0,
    seeds: Annotated[int, typer.Option(help="seeds to train, one after another")] = 1,
    first_seed: Annotated[int, typer.Option(help="the first seed")] = 0,
    budget: Annotated[
        str, typer.Option(help="per seed: env steps (200k, 1.5M) or wall time (30m, 2h)")
    ] = "200k",
    demo_reset_p: Annotated[float, typer.Option(help="chance a reset starts in a demo")] = 0.9,
    horizon: Annotated[int, typer.Option(help="steps per training episode")] = 100,
    n_envs: Annotated[int, typer.Option(help="environments stepping in parallel")] = 4,
    vec: Annotated[VecKind, typer.Option(help="subproc, dummy (inline) or ray")] = "subproc",
    ray_address: Annotated[
        str | None, typer.Option(help="Ray cluster address (--vec ray; default: a local one)")
    ] = None,
    n_steps: Annotated[int, typer.Option(help="steps per environment per PPO update")] = 256,
    ray_actor_cpus: Annotated[float, typer.Option(help="CPUs per Ray actor")] = 1.0,
    eval_every: Annotated[int, typer.Option(help="env steps between curve points")] = 10_000,
    resume: Annotated[
        bool, typer.Option(help="continue from checkpoints where they exist")
    ] = False,
    threads: Annotated[int, typer.Option(help="torch CPU threads")] = 1,
) -> None:
    """Demonstration-guided PPO (the paper's): episodes start from demo states with
    probability --demo-reset-p, sparse reward, LSTM 100 then 300-200 for actor and critic."""
    from crowdteleop.learn.config import PPOConfig
    from crowdteleop.learn.demo_states import load_demo_states
    from crowdteleop.learn.gym_env import EnvSettings
    from crowdteleop.learn.ppo import train_ppo

    steps, seconds = parse_budget(budget)
    with clear_errors():
        if dataset is None and demos:
            raise typer.BadParameter("--demos needs a --dataset to take them from")
        if dataset is None and task is None:
            raise typer.BadParameter("give a --dataset (or a --task for pure RL)")
        states = load_demo_states(dataset, demos or None) if dataset is not None else None
        env_args = _dataset_env_args(dataset) if dataset is not None else None
        sim_config = (
            states.sim_config
            if states is not None
            else {"task": task, "robot": robot, "action_mode": "osc-pose"}
        )
        settings = EnvSettings(sim_config=sim_config, horizon=horizon, demo_reset_p=demo_reset_p)
        for seed in range(first_seed, first_seed + seeds):
            config = PPOConfig(
                demos=demos,
                demo_reset_p=demo_reset_p,
                horizon=horizon,
                total_steps=steps or 10**12,
                budget_s=seconds,
                n_envs=n_envs,
                vec=vec,
                ray_address=ray_address,
                ray_actor_cpus=ray_actor_cpus,
                n_steps=n_steps,
                batch_size=min(256, n_steps * n_envs),
                eval_every=eval_every,
                seed=seed,
                threads=threads,
            )
            run = output / f"seed_{seed}"
            console.print(f"[bold]seed {seed}[/]: {run} ({budget}, {demos} demos)")
            train_ppo(
                config,
                settings,
                states if demos else None,
                run,
                resume=resume,
                progress_bar=steps is not None,
                dataset=dataset,
                env_args=env_args,
            )
            _print_curve(run)


def _dataset_env_args(dataset: Path) -> dict[str, Any]:
    import h5py

    with h5py.File(dataset, "r") as file:
        raw = file["data"].attrs.get("env_args", "{}")
    return dict(json.loads(raw.decode() if isinstance(raw, bytes) else raw))


def _print_curve(run: Path) -> None:
    import csv

    path = run / "curve.csv"
    if not path.exists():
        return
    rows = list(csv.DictReader(path.open()))
    table = Table("steps", "minutes", "return (100 steps)", "success", title=str(path))
    for row in rows[-5:]:
        table.add_row(
            row["steps"],
            f"{float(row['seconds']) / 60:.1f}",
            f"{float(row['mean_return']):.1f}",
            f"{float(row['success_rate']):.0%}",
        )
    console.print(table)


def eval_ppo(
    run: Path, episodes: int, sim: SimChoice, horizon: int | None, seed: int, video: int
) -> None:
    """``learn eval`` of a PPO run directory: writes eval.json (and eval.mp4) beside it."""
    from crowdteleop.learn.policy_eval import EVAL_HORIZON
    from crowdteleop.learn.rl_eval import evaluate_run, run_directory

    run = run_directory(run)
    names: list[Literal["ours", "robosuite"]] = ["ours", "robosuite"] if sim == "both" else [sim]
    summaries = {}
    with clear_errors():
        for name in names:
            with console.status(f"{episodes} rollouts in {name}..."):
                report = evaluate_run(
                    run,
                    name,
                    episodes,
                    horizon or EVAL_HORIZON,
                    seed,
                    video=run / "eval.mp4" if video and name == "ours" else None,
                    video_episodes=video,
                )
            summaries[name] = report.summary()
    table = Table("simulation", "episodes", "success rate", "return (mean ± std)", "horizon")
    for name, s in summaries.items():
        table.add_row(
            name,
            str(s["episodes"]),
            f"{s['success_rate']:.0%}",
            f"{s['mean_return']:.0f} ± {s['std_return']:.0f}",
            str(s["horizon"]),
        )
    console.print(table)
    target = run / "eval.json"
    target.write_text(json.dumps({"checkpoint": str(run), "results": summaries}, indent=2))
    console.print(f"written: {target}" + (f", {run / 'eval.mp4'}" if video else ""))
