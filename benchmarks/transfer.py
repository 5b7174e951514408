"""Do policies trained on our demonstrations work in plain robosuite? (issue 18, "policies
transfer"): scripted demos -> `dataset build --obs low-dim` -> BC-RNN -> rollouts in our
simulation and in plain robosuite rebuilt from the dataset's env_args alone.

    .venv/bin/python benchmarks/transfer.py --task lift --controller osc --demos 50 \
        --epochs 200 --episodes 20 > out/transfer-lift-osc.log 2>&1

Writes out/transfer-<task>-<controller>/ (episodes/, dataset.hdf5, train/, result.json,
traces.npz) and prints the figures. Each failed rollout is placed in its phase (reach: the
hand never came within 2 cm of the object; grasp: it did, but the object never rose 2 cm;
lift: it rose, but no success), with the finger joints 10 steps after the gripper closed.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.learn.actions import ActionKey
from crowdteleop.learn.bc import EpochLog, load_checkpoint, train_bc
from crowdteleop.learn.cli import results_table
from crowdteleop.learn.config import BCConfig, Head, ObsRotation
from crowdteleop.learn.envs import SIM_NAMES, robosuite_scene
from crowdteleop.learn.evaluation import Episode, EvalReport, evaluate_checkpoint
from crowdteleop.vocab import ControllerName

app = typer.Typer(add_completion=False)
console = Console(soft_wrap=True)
NEAR_M, RISE_M = 0.02, 0.02
# where the object's world position sits in robosuite's object-state, per environment
OBJECT_POSITION = {"Lift": slice(0, 3), "PickPlaceCan": slice(7, 10)}


def record(
    task: str, controller: ControllerName, robot: str, demos: int, directory: Path
) -> tuple[int, float]:
    """Scripted episodes (seeds 0, 1, ...) until ``demos`` succeeded; (attempts, seconds)."""
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    started, successes, seed = time.perf_counter(), 0, 0
    directory.mkdir(parents=True, exist_ok=True)
    with scripted_rig(task, controller, robot=robot) as rig:
        while successes < demos and seed < 3 * demos:
            episode = record_scripted_episode(rig, directory, f"{task}-{seed}", seed)
            successes += episode.outcome == "success"
            seed += 1
    return seed, time.perf_counter() - started


def build(episodes: Path, output: Path) -> float:
    started = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "crowdteleop",
            "dataset",
            "build",
            str(episodes),
            "--output",
            str(output),
            "--obs",
            "low-dim",
            "--overwrite",
        ],
        check=True,
    )
    return time.perf_counter() - started


def phases(outcome: Episode, env_name: str) -> dict[str, Any]:
    """How far a rollout got, from its trace of hand, fingers, object and actions."""
    assert outcome.trace is not None
    hand = np.array(outcome.trace["robot0_eef_pos"])
    fingers = np.array(outcome.trace["robot0_gripper_qpos"])
    obj = np.array(outcome.trace["object"])[:, OBJECT_POSITION.get(env_name, slice(0, 3))]
    gripper = np.array(outcome.trace["action"])[:, -1]
    distance = np.linalg.norm(hand - obj, axis=1)
    rise = obj[:, 2] - obj[0, 2]
    closing = np.flatnonzero((gripper > 0) & (distance < NEAR_M))
    after = int(min(closing[0] + 10, len(fingers) - 1)) if len(closing) else None
    if outcome.success:
        phase = "success"
    elif distance.min() >= NEAR_M:
        phase = "reach"
    elif rise.max() < RISE_M:
        phase = "grasp"
    else:
        phase = "lift"
    return {
        "seed": outcome.seed,
        "phase": phase,
        "steps": outcome.steps,
        "min_hand_object_m": float(distance.min()),
        "max_rise_m": float(rise.max()),
        "first_close_near_step": int(closing[0]) if len(closing) else None,
        "fingers_10_steps_after_close": fingers[after].tolist() if after is not None else None,
        "hand_object_10_steps_after_close_m": float(distance[after]) if after else None,
    }


def phase_table(reports: list[EvalReport], details: dict[str, list[dict[str, Any]]]) -> Table:
    table = Table(
        "simulation",
        "success",
        "failed: reach",
        "grasp",
        "lift",
        "fingers 10 steps after closing (median)",
        "max rise (median) m",
    )
    for report in reports:
        rows = details[report.sim]
        count = {
            p: sum(r["phase"] == p for r in rows) for p in ("success", "reach", "grasp", "lift")
        }
        fingers = [
            r["fingers_10_steps_after_close"] for r in rows if r["fingers_10_steps_after_close"]
        ]
        table.add_row(
            report.sim,
            str(count["success"]),
            str(count["reach"]),
            str(count["grasp"]),
            str(count["lift"]),
            str(np.round(np.median(fingers, axis=0), 4).tolist()) if fingers else "-",
            f"{np.median([r['max_rise_m'] for r in rows]):.3f}",
        )
    return table


@app.command()
def main(
    task: str = "lift",
    controller: ControllerName = "osc",
    robot: str = "Panda",
    demos: int = 50,
    epochs: int = 200,
    episodes: int = 20,
    seed: int = 0,
    head: Head = "deterministic",
    actions: ActionKey = "actions",
    lr: float = 1e-4,
    normalize_obs: bool = False,
    obs_rotation: ObsRotation = "quaternion",
    save_every: int = 0,
    rnn_horizon: int | None = None,
    eval_seed: int = 1000,
    out: Path | None = None,
    reuse: bool = typer.Option(True, help="keep episodes / dataset / model already in --out"),
    dataset_from: Path | None = None,  # train on this built dataset instead of recording
    threads: int = typer.Option(1, help="torch threads (1: two runs share 2 cores evenly)"),
) -> None:
    torch.set_num_threads(threads)
    out = out or Path("out") / f"transfer-{task}-{controller}-{robot.lower()}"
    out.mkdir(parents=True, exist_ok=True)
    dataset, model = dataset_from or out / "dataset.hdf5", out / "train" / "model.pt"
    result: dict[str, Any] = {
        "task": task,
        "controller": controller,
        "robot": robot,
        "demos": demos,
        "epochs": epochs,
        "episodes": episodes,
        "head": head,
        "actions": actions,
        "lr": lr,
        "obs_rotation": obs_rotation,
    }
    if not (reuse and dataset.exists()):
        attempts, seconds = record(task, controller, robot, demos, out / "episodes")
        console.print(f"recorded {attempts} scripted episodes in {seconds:.0f} s")
        result.update(record_attempts=attempts, record_seconds=seconds)
        result["build_seconds"] = build(out / "episodes", dataset)
    if not (reuse and model.exists()):
        config = BCConfig(
            epochs=epochs,
            seed=seed,
            head=head,
            actions=actions,
            learning_rate=lr,
            normalize_obs=normalize_obs,
            obs_rotation=obs_rotation,
            save_every=save_every,
        )

        def show(row: EpochLog) -> None:
            if row.epoch % 10 == 0 or row.epoch == 1:
                console.print(
                    f"epoch {row.epoch}: loss {row.train_loss:.3f}, valid "
                    f"{row.valid_loss}, {row.seconds:.0f} s"
                )

        report = train_bc(dataset, out / "train", config, show, threads=threads)
        result.update(
            train_seconds=report.seconds,
            train_demos=report.train_demos,
            final_loss=report.epochs[-1].train_loss,
        )
    checkpoint = load_checkpoint(model)
    result.setdefault("train_seconds", checkpoint.train_seconds)
    reports, details, traces = [], {}, {}
    seeds = range(eval_seed, eval_seed + episodes)
    for sim in SIM_NAMES:
        started = time.perf_counter()
        report = evaluate_checkpoint(checkpoint, sim, seeds, rnn_horizon=rnn_horizon, trace=True)
        console.print(f"{sim}: {report.success_rate:.0%} in {time.perf_counter() - started:.0f} s")
        reports.append(report)
        env_name = robosuite_scene(checkpoint.dataset["env_args"]).env_name
        details[sim] = [phases(e, env_name) for e in report.episodes]
        for e in report.episodes:
            for key, values in (e.trace or {}).items():
                traces[f"{sim}/{e.seed}/{key}"] = np.array(values)
    console.print(results_table(reports))
    console.print(phase_table(reports, details))
    result.update(
        success_ours=reports[0].success_rate,
        success_robosuite=reports[1].success_rate,
        results={r.sim: r.summary() for r in reports},
        phases=details,
    )
    (out / "result.json").write_text(json.dumps(result, indent=2))
    np.savez_compressed(out / "traces.npz", **traces)
    console.print(
        json.dumps(
            {
                k: result[k]
                for k in (
                    "task",
                    "controller",
                    "epochs",
                    "success_ours",
                    "success_robosuite",
                    "train_seconds",
                )
            }
        )
    )


if __name__ == "__main__":
    app()
