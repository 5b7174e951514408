"""``crowdteleop learn bc | rl | eval | table`` (torch and the simulators load inside the
commands, so ``crowdteleop --help`` stays fast)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any, Literal

import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.dataset.cli import clear_errors, progress_columns
from crowdteleop.learn.actions import ActionKey
from crowdteleop.learn.cli_rl import eval_ppo, rl
from crowdteleop.learn.config import BCConfig, Head

app = typer.Typer(help="Train policies on datasets and evaluate them.", no_args_is_help=True)
app.command()(rl)
console = Console(soft_wrap=True)
SimChoice = Literal["ours", "robosuite", "both"]


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

    from crowdteleop.learn.rl_eval import is_ppo_run

    torch.set_num_threads(threads)
    if is_ppo_run(checkpoint):
        eval_ppo(checkpoint, episodes, sim, horizon, seed if seed else 1000, video)
        return

    from crowdteleop.learn.bc import load_checkpoint
    from crowdteleop.learn.rollout import EvalReport, evaluate

    torch.set_num_threads(threads)
    sims: list[Literal["ours", "robosuite"]] = ["ours", "robosuite"] if sim == "both" else [sim]
    reports: list[EvalReport] = []
    with clear_errors():
        policy = load_checkpoint(checkpoint)
        for name in sims:
            with console.status(f"{episodes} rollouts in {name}..."):
                clip = checkpoint.with_name("eval.mp4") if video and name == "ours" else None
                reports.append(
                    evaluate(policy, name, episodes, horizon, seed, rnn_horizon, False, clip, video)
                )
    console.print(results_table(reports))
    target = output or checkpoint.with_name("eval.json")
    result: dict[str, Any] = {
        "checkpoint": str(checkpoint),
        "epoch": policy.epoch,
        "task": policy.dataset.get("task"),
        "controller": policy.dataset.get("controller"),
        "results": {r.sim: r.summary() for r in reports},
    }
    target.write_text(json.dumps(result, indent=2))
    console.print(f"written: {target}")


@app.command()
def table(
    runs: Annotated[list[Path], typer.Argument(help="directories holding evaluated runs")],
    sim: Annotated[str, typer.Option(help="which evaluation: ours or robosuite")] = "ours",
    markdown: Annotated[Path | None, typer.Option(help="also write the table here")] = None,
    plot: Annotated[Path | None, typer.Option(help="PNG of PPO's learning curves")] = None,
) -> None:
    """The paper's Table 1 layout: mean ± std of the final return (success rate, runs) per
    task and demonstration count, beside the paper's figures."""
    from crowdteleop.learn.table import collect, plot_curves
    from crowdteleop.learn.table import markdown as as_markdown

    results = collect(runs, sim)
    if not results:
        raise typer.BadParameter(f"no evaluated runs (run.json + eval.json) under {runs}")
    text = as_markdown(results)
    console.print(text)
    if markdown is not None:
        markdown.write_text(text)
    if plot is not None and any(r.algo == "ppo" for r in results):
        plot_curves(results, plot)
        console.print(f"written: {plot}")


def results_table(reports: list[Any]) -> Table:
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
