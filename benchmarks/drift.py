"""How far an action recorded on our fast path moves plain robosuite's arm from where it moved
ours: per step (from the same state) and open loop (the whole episode from its first state).

    .venv/bin/python benchmarks/drift.py [--tasks lift,pick-place-can] [--seeds 3]
"""

from __future__ import annotations

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.analysis.robosuite_replay import RobosuiteReplayer
from crowdteleop.control import ControlConfig, Teleoperator
from crowdteleop.control.scripted import ScriptedOperator, run_episode
from crowdteleop.sim import SimConfig, make_simulation

app = typer.Typer(add_completion=False)


def record(task: str, seed: int):
    """A scripted OSC episode on our path: xml, nullspace posture, states, actions, hands."""
    control = ControlConfig(controller="osc")
    sim = make_simulation(SimConfig(task=task, action_mode="osc-pose"))
    teleop = Teleoperator(sim, control)
    before, actions, hands = [], [], []
    step_once = teleop.step

    def recorded(command):
        before.append(sim.get_state())
        step = step_once(command)
        actions.append(step.action)
        hands.append(sim.robot_state().end_effector.position)
        return step

    teleop.step = recorded
    result = run_episode(teleop, ScriptedOperator(sim, control.mapping, seed=seed), seed, 30.0)
    posture = sim._stepper.initial_joints.copy()
    xml = sim.mjcf_xml()
    sim.close()
    return xml, posture, before, np.array(actions), np.array(hands), result.success


@app.command()
def main(tasks: str = "lift,pick-place-can,nut-assembly-round", seeds: int = 3) -> None:
    table = Table(
        "task", "episodes", "steps", "per-step median mm", "per-step p95 mm",
        "per-step max mm", "open-loop final mm", "open-loop max mm",
        title="Action drift: our fast path vs plain robosuite OSC_POSE",
    )
    for task in tasks.split(","):
        per_step, final, worst, steps = [], [], [], 0
        for seed in range(seeds):
            xml, posture, before, actions, ours, _ = record(task, seed)
            replayer = RobosuiteReplayer(task, xml)
            try:
                per_step.append(
                    np.linalg.norm(replayer.per_step(before, actions, posture) - ours, axis=1)
                )
                replay = replayer.open_loop(before[0], actions, posture)
            finally:
                replayer.close()
            open_loop = np.linalg.norm(replay - ours, axis=1)
            final.append(open_loop[-1])
            worst.append(open_loop.max())
            steps += len(actions)
        drift = np.concatenate(per_step) * 1e3
        table.add_row(
            task, str(seeds), str(steps), f"{np.median(drift):.2f}",
            f"{np.percentile(drift, 95):.2f}", f"{drift.max():.2f}",
            f"{np.median(final) * 1e3:.1f}", f"{np.median(worst) * 1e3:.1f}",
        )
    Console().print(table)


if __name__ == "__main__":
    app()
