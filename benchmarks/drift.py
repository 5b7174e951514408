"""How far an action recorded on our fast path moves plain robosuite's arm from where it moved
ours: per step (from the same state) and open loop (the whole episode from its first state).

    .venv/bin/python benchmarks/drift.py [--tasks lift,pick-place-can] [--seeds 3]
"""

from __future__ import annotations

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.dataset.robosuite_replay import RobosuiteReplayer, record_scripted_osc_episode

app = typer.Typer(add_completion=False)


@app.command()
def main(tasks: str = "lift,pick-place-can,nut-assembly-round", seeds: int = 3) -> None:
    table = Table(
        "task",
        "episodes",
        "steps",
        "per-step median mm",
        "per-step p95 mm",
        "per-step max mm",
        "open-loop final mm",
        "open-loop max mm",
        title="Action drift: our fast path vs plain robosuite OSC_POSE",
    )
    for task in tasks.split(","):
        per_step, final, worst, steps = [], [], [], 0
        for seed in range(seeds):
            episode = record_scripted_osc_episode(task, seed)
            actions, ours, posture = episode.actions, episode.hands_after, episode.nullspace_posture
            replayer = RobosuiteReplayer(task, episode.mjcf_xml)
            try:
                stepped = replayer.per_step(episode.states_before, actions, posture)
                replay = replayer.open_loop(episode.states_before[0], actions, posture)
            finally:
                replayer.close()
            per_step.append(np.linalg.norm(stepped - ours, axis=1))
            open_loop = np.linalg.norm(replay - ours, axis=1)
            final.append(open_loop[-1])
            worst.append(open_loop.max())
            steps += len(actions)
        drift = np.concatenate(per_step) * 1e3
        table.add_row(
            task,
            str(seeds),
            str(steps),
            f"{np.median(drift):.2f}",
            f"{np.percentile(drift, 95):.2f}",
            f"{drift.max():.2f}",
            f"{np.median(final) * 1e3:.1f}",
            f"{np.median(worst) * 1e3:.1f}",
        )
    Console().print(table)


if __name__ == "__main__":
    app()
