"""``crowdteleop learn bc | rl | eval | table`` (torch, sb3 and the simulators load inside the
commands, so ``crowdteleop --help`` stays fast)."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.dataset.cli import clear_errors, progress_columns
from crowdteleop.learn.actions import ActionKey
from crowdteleop.learn.config import BCConfig, Head, ObsRotation, RlAlgo, VecKind

if TYPE_CHECKING:
    from crowdteleop.learn.evaluation import EvalReport

app = typer.Typer(help="Train policies on datasets and evaluate them.", no_args_is_help=True)
console = Console(soft_wrap=True)
SimChoice = Literal["ours", "robosuite", "both"]
BUDGET = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([kKmM]?|[smh])\s*$")


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


@app.command()
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
    demo_reset_p: Annotated[
        float | None,
        typer.Option(
            help="chance a reset starts in a demo (default: ppo 0.9, sac 0.5)", min=0, max=1
        ),
    ] = None,
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
    algo: Annotated[
        RlAlgo,
        typer.Option(
            help="ppo: the paper's; sac: SAC with the demos in its buffer; ibrl: sac whose "
            "cloned actor, frozen, proposes beside the learner"
        ),
    ] = "ppo",
) -> None:
    """Demonstration-guided PPO (the paper's): episodes start from demo states with
    probability --demo-reset-p, sparse reward, LSTM 100 then 300-200 for actor and critic.
    With --algo sac: SAC whose batches are half demos, its actor first cloned from them
    (docs/learning.md); a training episode ends when solved. With --algo ibrl: the same, and
    the cloned actor, kept frozen, proposes an action beside the learner's at every step and
    in every TD target, the critic taking the better (IBRL)."""
    with clear_errors():
        if dataset is None and demos:
            raise typer.BadParameter("--demos needs a --dataset to take them from")
        if dataset is None and task is None:
            raise typer.BadParameter("give a --dataset (or a --task for pure RL)")
    steps, seconds = parse_budget(budget)
    default_reset_p = {"ppo": 0.9, "sac": 0.5, "ibrl": 0.5}[algo]
    run = RlRun(
        output,
        dataset,
        task,
        robot,
        demos,
        default_reset_p if demo_reset_p is None else demo_reset_p,
        steps,
        seconds,
        horizon,
        resume,
        threads,
    )
    seed_range = range(first_seed, first_seed + seeds)
    if algo != "ppo":
        _train_sac_seeds(run, seed_range, algo)
        return
    options = PpoOptions(n_envs, vec, ray_address, n_steps, ray_actor_cpus, eval_every)
    _train_ppo_seeds(run, options, seed_range)


@dataclass(frozen=True)
class RlRun:
    """What `learn rl` was asked for, whatever the algorithm, seeds aside."""

    output: Path
    dataset: Path | None
    task: str | None
    robot: str
    demos: int
    demo_reset_p: float
    steps: int | None
    seconds: float | None
    horizon: int
    resume: bool
    threads: int


@dataclass(frozen=True)
class PpoOptions:
    """What only PPO's runs take: their vector of environments and update size."""

    n_envs: int
    vec: VecKind
    ray_address: str | None
    n_steps: int
    ray_actor_cpus: float
    eval_every: int


def _budget_text(run: RlRun) -> str:
    return f"{run.steps:,} steps" if run.steps is not None else f"{run.seconds:.0f} s"


def _train_ppo_seeds(run: RlRun, options: PpoOptions, seeds: range) -> None:
    from crowdteleop.learn.config import PPOConfig
    from crowdteleop.learn.data import dataset_env_args
    from crowdteleop.learn.demo_states import load_demo_states
    from crowdteleop.learn.envs import EnvSettings
    from crowdteleop.learn.ppo import train_ppo

    with clear_errors():
        dataset = run.dataset
        states = load_demo_states(dataset, run.demos or None) if dataset is not None else None
        env_args = dataset_env_args(dataset) if dataset is not None else None
        sim_config: dict[str, object] = (
            states.sim_config
            if states is not None
            else {"task": run.task, "robot": run.robot, "action_mode": "osc-pose"}
        )
        settings = EnvSettings(
            sim_config=sim_config, horizon=run.horizon, demo_reset_p=run.demo_reset_p
        )
        for seed in seeds:
            config = PPOConfig(
                demos=run.demos,
                demo_reset_p=run.demo_reset_p,
                horizon=run.horizon,
                total_steps=run.steps or 10**12,
                budget_s=run.seconds,
                n_envs=options.n_envs,
                vec=options.vec,
                ray_address=options.ray_address,
                ray_actor_cpus=options.ray_actor_cpus,
                n_steps=options.n_steps,
                batch_size=min(256, options.n_steps * options.n_envs),
                eval_every=options.eval_every,
                seed=seed,
                threads=run.threads,
            )
            directory = run.output / f"seed_{seed}"
            console.print(
                f"[bold]seed {seed}[/]: {directory} ({_budget_text(run)}, {run.demos} demos)"
            )
            train_ppo(
                config,
                settings,
                states if run.demos else None,
                directory,
                resume=run.resume,
                progress_bar=run.steps is not None,
                dataset=run.dataset,
                env_args=env_args,
            )
            _print_curve(directory)


def _train_sac_seeds(run: RlRun, seeds: range, algo: RlAlgo) -> None:
    from crowdteleop.learn.config import IBRL_SETTINGS, SACConfig
    from crowdteleop.learn.data import dataset_env_args
    from crowdteleop.learn.demo_buffer import load_demo_transitions
    from crowdteleop.learn.demo_states import load_demo_states
    from crowdteleop.learn.envs import EnvSettings
    from crowdteleop.learn.sac import Demonstrations, train_sac

    with clear_errors():
        settings = EnvSettings(
            sim_config=(
                load_demo_states(run.dataset, 1).sim_config
                if run.dataset is not None
                else {"task": run.task, "robot": run.robot, "action_mode": "osc-pose"}
            ),
            horizon=run.horizon,
            demo_reset_p=run.demo_reset_p,
            terminate_on_success=True,
        )
        demos = (
            Demonstrations(
                load_demo_transitions(run.dataset, run.demos, settings.obs_keys),
                load_demo_states(run.dataset, run.demos) if run.demo_reset_p else None,
            )
            if run.dataset is not None and run.demos
            else None
        )
        env_args = dataset_env_args(run.dataset) if run.dataset is not None else None
        for seed in seeds:
            config = SACConfig(
                **(IBRL_SETTINGS if algo == "ibrl" else {}),
                demos=run.demos,
                horizon=run.horizon,
                total_steps=run.steps or 10**12,
                budget_s=run.seconds,
                seed=seed,
                threads=run.threads,
            )
            directory = run.output / f"seed_{seed}"
            console.print(f"[bold]seed {seed}[/]: {directory} ({algo}, {run.demos} demos)")
            train_sac(
                config,
                settings,
                demos,
                directory,
                resume=run.resume,
                progress_bar=run.steps is not None,
                dataset=run.dataset,
                env_args=env_args,
            )
            _print_curve(directory)


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


@app.command()
def bc(
    dataset: Annotated[Path, typer.Argument(help="dataset with low-dim obs (dataset build)")],
    output: Annotated[Path, typer.Option(help="directory for model.pt and log.csv")],
    epochs: Annotated[int, typer.Option(help="epochs of --steps-per-epoch gradient steps")] = 200,
    seed: Annotated[int, typer.Option(help="seed of weights and batches (the first one)")] = 0,
    seeds: Annotated[
        int, typer.Option(help="seeds to train one after another (then in output/seed_<k>)")
    ] = 1,
    head: Annotated[Head, typer.Option(help="deterministic or gmm (5 modes)")] = "deterministic",
    actions: Annotated[
        ActionKey, typer.Option(help="learn the deltas, or actions_abs (absolute hand targets)")
    ] = "actions",
    lr: Annotated[float, typer.Option(help="Adam learning rate")] = 1e-4,
    batch_size: Annotated[int, typer.Option(help="sequences per batch")] = 100,
    seq_length: Annotated[int, typer.Option(help="sequence length (RNN horizon)")] = 10,
    hidden_dim: Annotated[int, typer.Option(help="LSTM hidden size")] = 400,
    num_layers: Annotated[int, typer.Option(help="LSTM layers")] = 2,
    steps_per_epoch: Annotated[int, typer.Option(help="gradient steps per epoch")] = 100,
    obs_key: Annotated[
        list[str] | None, typer.Option(help="observation keys in order (default: robomimic's)")
    ] = None,
    normalize_obs: Annotated[bool, typer.Option(help="standardize observations")] = False,
    obs_rotation: Annotated[
        ObsRotation, typer.Option(help="quaternion inputs as recorded, or as 6D rotations")
    ] = "quaternion",
    train_filter: Annotated[str, typer.Option(help="mask/<key> to train on")] = "train",
    valid_filter: Annotated[str, typer.Option(help="mask/<key> to validate on")] = "valid",
    save_every: Annotated[int, typer.Option(help="keep epoch_<n>.pt every n epochs")] = 0,
    threads: Annotated[int, typer.Option(help="torch CPU threads")] = 1,
    demos: Annotated[
        int | None, typer.Option(help="train on the first n demos of the train filter")
    ] = None,
    resume: Annotated[bool, typer.Option(help="continue from output/resume.pt if there")] = False,
) -> None:
    """Train a BC-RNN policy (robomimic's low-dim BC-RNN) on a dataset."""
    from crowdteleop.learn.config import STOCK_OBS_KEYS

    with clear_errors():
        base = BCConfig(
            obs_keys=tuple(obs_key or STOCK_OBS_KEYS),
            head=head,
            actions=actions,
            learning_rate=lr,
            batch_size=batch_size,
            seq_length=seq_length,
            hidden_dim=hidden_dim,
            num_layers=num_layers,
            epochs=epochs,
            steps_per_epoch=steps_per_epoch,
            normalize_obs=normalize_obs,
            obs_rotation=obs_rotation,
            train_filter=train_filter,
            valid_filter=valid_filter,
            seed=seed,
            save_every=save_every,
            max_demos=demos,
        )
        for k in range(seed, seed + seeds):
            run = output if seeds == 1 else output / f"seed_{k}"
            _train_bc_seed(dataset, run, base.model_copy(update={"seed": k}), threads, resume)


def _train_bc_seed(
    dataset: Path, output: Path, config: BCConfig, threads: int, resume: bool
) -> None:
    from rich.progress import Progress, TextColumn

    from crowdteleop.learn.bc import EpochLog, train_bc

    columns = progress_columns(TextColumn("{task.fields[loss]}"))
    with Progress(*columns, console=console) as bar:
        job = bar.add_task(f"seed {config.seed}: epochs", total=config.epochs, loss="")

        def advance(row: EpochLog) -> None:
            valid = "" if row.valid_loss is None else f", valid {row.valid_loss:.3f}"
            bar.update(job, completed=row.epoch, loss=f"loss {row.train_loss:.3f}{valid}")

        report = train_bc(dataset, output, config, advance, threads, resume)
    info = {"algo": "bc", "task": report.task, "demos": report.train_demos}
    info |= {"seed": config.seed, "dataset": str(dataset)}
    (output / "run.json").write_text(json.dumps(info, indent=2))  # for `learn table`
    if not report.epochs:
        console.print(f"{report.checkpoint}: already trained for {config.epochs} epochs")
        return
    last = report.epochs[-1]
    console.print(
        f"{report.checkpoint}: {config.epochs} epochs on {report.train_demos} demos "
        f"({report.valid_demos} valid) in {report.seconds:.0f} s; loss {last.train_loss:.3f}"
        + ("" if last.valid_loss is None else f", valid {last.valid_loss:.3f}")
        + f"; log: {report.log}"
    )


@app.command("eval")
def evaluate_command(
    checkpoint: Annotated[
        Path, typer.Argument(help="model.pt from `learn bc`, or a `learn rl` seed directory")
    ],
    episodes: Annotated[int, typer.Option(help="rollouts per simulation")] = 20,
    sim: Annotated[SimChoice, typer.Option(help="ours, robosuite (env_args) or both")] = "both",
    horizon: Annotated[
        int | None,
        typer.Option(help="steps per rollout (BC: 400 lift, 500 otherwise; RL: 1000, the paper's)"),
    ] = None,
    seed: Annotated[int, typer.Option(help="seed of the first episode")] = 0,
    rnn_horizon: Annotated[
        int | None,
        typer.Option(help="restart the LSTM state every n steps (default: seq length; 0 never)"),
    ] = None,
    output: Annotated[
        Path | None, typer.Option(help="JSON to write (default: eval.json beside the model)")
    ] = None,
    threads: Annotated[int, typer.Option(help="torch CPU threads")] = 1,
    video: Annotated[int, typer.Option(help="rollouts in ours to keep as eval.mp4 (0: none)")] = 2,
) -> None:
    """Roll a trained policy out in our simulation and/or plain robosuite; success rates
    (and, for RL, the paper's return: steps solved out of the horizon)."""
    import torch

    from crowdteleop.learn.evaluation import is_ppo_run

    torch.set_num_threads(threads)
    sims: list[Literal["ours", "robosuite"]] = ["ours", "robosuite"] if sim == "both" else [sim]
    if is_ppo_run(checkpoint):
        _eval_ppo(checkpoint, episodes, sims, horizon, seed if seed else 1000, video)
    else:
        _eval_bc(checkpoint, episodes, sims, horizon, seed, rnn_horizon, output, video)


def _eval_bc(
    checkpoint: Path,
    episodes: int,
    sims: list[Literal["ours", "robosuite"]],
    horizon: int | None,
    seed: int,
    rnn_horizon: int | None,
    output: Path | None,
    video: int,
) -> None:
    from crowdteleop.learn.bc import load_checkpoint
    from crowdteleop.learn.evaluation import evaluate_checkpoint

    reports: list[EvalReport] = []
    with clear_errors():
        policy = load_checkpoint(checkpoint)
        for name in sims:
            with console.status(f"{episodes} rollouts in {name}..."):
                clip = checkpoint.with_name("eval.mp4") if video and name == "ours" else None
                reports.append(
                    evaluate_checkpoint(
                        policy,
                        name,
                        range(seed, seed + episodes),
                        horizon,
                        rnn_horizon,
                        video=clip,
                        video_episodes=video,
                    )
                )
    console.print(results_table(reports))
    print_simulator_errors(reports)
    target = output or checkpoint.with_name("eval.json")
    result = {
        "checkpoint": str(checkpoint),
        "epoch": policy.epoch,
        "task": policy.dataset.get("task"),
        "controller": policy.dataset.get("controller"),
        "results": {r.sim: r.summary() for r in reports},
    }
    target.write_text(json.dumps(result, indent=2))
    console.print(f"written: {target}")


def _eval_ppo(
    run: Path,
    episodes: int,
    sims: list[Literal["ours", "robosuite"]],
    horizon: int | None,
    seed: int,
    video: int,
) -> None:
    """A PPO run directory: writes eval.json (and eval.mp4) beside it."""
    from crowdteleop.learn.evaluation import EVAL_HORIZON, evaluate_run, run_directory

    run = run_directory(run)
    reports: list[EvalReport] = []
    with clear_errors():
        for name in sims:
            with console.status(f"{episodes} rollouts in {name}..."):
                reports.append(
                    evaluate_run(
                        run,
                        name,
                        range(seed, seed + episodes),
                        horizon or EVAL_HORIZON,
                        video=run / "eval.mp4" if video and name == "ours" else None,
                        video_episodes=video,
                    )
                )
    table = Table("simulation", "episodes", "success rate", "return (mean ± std)", "horizon")
    for report in reports:
        table.add_row(
            report.sim,
            str(len(report.episodes)),
            f"{report.success_rate:.0%}",
            f"{report.mean_return:.0f} ± {report.std_return:.0f}",
            str(report.horizon),
        )
    console.print(table)
    print_simulator_errors(reports)
    target = run / "eval.json"
    summaries = {r.sim: r.summary() for r in reports}
    target.write_text(json.dumps({"checkpoint": str(run), "results": summaries}, indent=2))
    console.print(f"written: {target}" + (f", {run / 'eval.mp4'}" if video else ""))


@app.command()
def table(
    runs: Annotated[list[Path], typer.Argument(help="directories holding evaluated runs")],
    sim: Annotated[str, typer.Option(help="which evaluation: ours or robosuite")] = "ours",
    markdown: Annotated[Path | None, typer.Option(help="also write the table here")] = None,
    plot: Annotated[Path | None, typer.Option(help="PNG of the RL runs' learning curves")] = None,
) -> None:
    """The paper's Table 1 layout: mean ± std of the final return (success rate, runs) per
    task and demonstration count, beside the paper's figures."""
    from crowdteleop.learn.table import RL_ALGOS, collect, plot_curves
    from crowdteleop.learn.table import markdown as as_markdown

    results = collect(runs, sim)
    if not results:
        raise typer.BadParameter(f"no evaluated runs (run.json + eval.json) under {runs}")
    text = as_markdown(results)
    console.print(text)
    if markdown is not None:
        markdown.write_text(text)
    if plot is not None and any(r.algo in RL_ALGOS for r in results):
        plot_curves(results, plot)
        console.print(f"written: {plot}")


def print_simulator_errors(reports: list[EvalReport]) -> None:
    """Episodes the simulator aborted, said once each: they count as they stood then."""
    for report in reports:
        if report.errors:
            console.print(
                f"[yellow]{len(report.errors)} of {len(report.episodes)} episodes in "
                f"{report.sim} ended on a simulator error (counted as they stood):[/yellow]"
            )
            for line in report.errors:
                console.print(f"  {line}", markup=False)


def results_table(reports: list[EvalReport]) -> Table:
    table = Table("simulation", "episodes", "successes", "success rate", "mean steps to success")
    for report in reports:
        steps = report.mean_steps_to_success
        table.add_row(
            report.sim,
            str(len(report.episodes)),
            str(sum(e.success for e in report.episodes)),
            f"{report.success_rate:.0%}",
            "-" if steps is None else f"{steps:.0f}",
        )
    return table
