"""How far an action recorded on our fast path moves plain robosuite's arm from where it moved
ours, for each controller and for delta and absolute actions: per step (from the same state
and finger command) and open loop (the first N actions from the episode's first state), and
how the fingers close over a grasp (opening and finger actuator force) in both simulators.

plain robosuite is rebuilt from the controller config a dataset records (`env_args`); absolute
actions (`actions_abs`) are stepped in robosuite's OSC_POSE with ``input_type="absolute"``.

    .venv/bin/python benchmarks/drift.py [--tasks lift,pick-place-can] [--seeds 3]
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.dataset.absolute import AbsoluteTargets
from crowdteleop.dataset.robosuite_replay import (
    RecordedEpisode,
    RobosuiteReplayer,
    record_scripted_episode_in_memory,
)
from crowdteleop.sim import SimConfig, make_simulation

app = typer.Typer(add_completion=False)
AFTER = (5, 20, 40)


def absolute_actions(episode: RecordedEpisode) -> np.ndarray:
    config = SimConfig(task=episode.task, action_mode="osc-pose")
    sim = make_simulation(config)
    try:
        kinematics = sim.kinematics()
    finally:
        sim.close()
    kinematics = dataclasses.replace(kinematics, mjcf_xml=episode.mjcf_xml)
    arm = episode.env_args.arm
    assert arm is not None, "a robosuite task's env_args name its controller"
    return AbsoluteTargets(kinematics, arm).of(np.array(episode.states_before), episode.actions)


def replay(episode: RecordedEpisode, absolute: bool) -> dict[str, object]:
    env_args = episode.env_args
    actions = episode.actions
    if absolute:
        assert env_args.controller is not None, "a robosuite task's env_args name its controller"
        env_args = env_args.with_controller(env_args.controller.absolute())
        actions = absolute_actions(episode)
    replayer = RobosuiteReplayer(env_args, episode.mjcf_xml)
    try:
        posture, commands = episode.nullspace_posture, list(episode.finger_commands)
        stepped = replayer.per_step(episode.states_before, actions, posture, commands)
        whole = replayer.open_loop(episode.states_before[0], actions, posture, commands[0])
        close = int(np.argmax(episode.actions[:, -1] > 0))
        window = slice(close, close + 12)
        grasp = replayer.open_loop(
            episode.states_before[close], actions[window], posture, commands[close]
        )
    finally:
        replayer.close()
    per_step = np.linalg.norm(stepped.hands - episode.hands_after, axis=1)
    open_loop = np.linalg.norm(whole.hands - episode.hands_after, axis=1)
    opening_ours = np.abs(episode.fingers_after[window]).sum(axis=1)
    opening_theirs = np.abs(grasp.fingers).sum(axis=1)
    return {
        "per_step_mm": (per_step * 1e3).tolist(),
        "open_loop_mm": {n: float(open_loop[n - 1] * 1e3) for n in AFTER if n <= len(open_loop)},
        "grasp_opening_diff_mm": float(np.abs(opening_ours - opening_theirs).max() * 1e3),
        "grasp_opening_ours_mm": (opening_ours * 1e3).round(2).tolist(),
        "grasp_opening_robosuite_mm": (opening_theirs * 1e3).round(2).tolist(),
        "grasp_finger_force_robosuite_n": grasp.finger_force_n.round(2).tolist(),
    }


@app.command()
def main(
    tasks: str = "lift,pick-place-can",
    controllers: str = "osc,ik-velocity",
    seeds: int = 3,
    json_out: Path = Path("out/drift.json"),
) -> None:
    table = Table(
        "task",
        "controller",
        "actions",
        "steps",
        "per-step median mm",
        "per-step max mm",
        *(f"open loop {n} mm" for n in AFTER),
        "grasp opening diff mm",
        title="Action drift: our fast path vs plain robosuite (medians over episodes)",
    )
    results = []
    for task in tasks.split(","):
        for controller in controllers.split(","):
            episodes = [
                record_scripted_episode_in_memory(task, seed, controller) for seed in range(seeds)
            ]
            for absolute in (False, True):
                runs = [replay(e, absolute) for e in episodes]
                per_step = np.concatenate([r["per_step_mm"] for r in runs])  # type: ignore[misc]
                after = {
                    n: float(np.median([r["open_loop_mm"][n] for r in runs]))  # type: ignore[index]
                    for n in AFTER
                }
                grasp = float(np.median([r["grasp_opening_diff_mm"] for r in runs]))
                kind = "absolute" if absolute else "delta"
                table.add_row(
                    task,
                    controller,
                    kind,
                    str(len(per_step)),
                    f"{np.median(per_step):.2f}",
                    f"{per_step.max():.2f}",
                    *(f"{after[n]:.1f}" for n in AFTER),
                    f"{grasp:.2f}",
                )
                results.append(
                    {"task": task, "controller": controller, "actions": kind, "runs": runs}
                )
    Console().print(table)
    json_out.parent.mkdir(parents=True, exist_ok=True)
    json_out.write_text(json.dumps(results))


if __name__ == "__main__":
    app()
