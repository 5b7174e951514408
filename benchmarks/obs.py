"""What `dataset build --obs` costs per demo-step: the same episodes built with no
observations, robosuite's low-dim keys, and low-dim plus an 84x84 camera, medians of runs.

    .venv/bin/python benchmarks/obs.py [--episodes 10] [--runs 3] [--task lift]
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.dataset.build import BuildOptions, build_dataset
from crowdteleop.dataset.observations import parse_obs
from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

app = typer.Typer(add_completion=False)
VARIANTS = ("none", "low-dim", "low-dim,rgb:agentview:84x84")


@app.command()
def main(episodes: int = 10, runs: int = 3, task: str = "lift", controller: str = "osc") -> None:
    with tempfile.TemporaryDirectory() as work:
        folder = Path(work) / "episodes"
        with scripted_rig(task, controller=controller) as rig:  # type: ignore[arg-type]
            steps = sum(
                record_scripted_episode(rig, folder, f"ep-{i}", i).steps for i in range(episodes)
            )
        seconds: dict[str, list[float]] = {v: [] for v in VARIANTS}
        for _ in range(runs):
            for variant in VARIANTS:  # alternating, so machine drift hits all alike
                started = time.perf_counter()
                build_dataset(
                    [folder],
                    Path(work) / "out.hdf5",
                    BuildOptions(drift_tolerance=None, obs=parse_obs([variant])),
                    overwrite=True,
                )
                seconds[variant].append(time.perf_counter() - started)
    table = Table(
        "--obs",
        "build s (median)",
        "ms per demo-step",
        "extra ms per demo-step",
        title=f"dataset build, {episodes} {task} demos, {steps} steps",
    )
    base = statistics.median(seconds["none"])
    for variant in VARIANTS:
        median = statistics.median(seconds[variant])
        table.add_row(
            variant,
            f"{median:.2f}",
            f"{median / steps * 1e3:.2f}",
            f"{(median - base) / steps * 1e3:.2f}",
        )
    Console().print(table)


if __name__ == "__main__":
    app()
