"""What measuring an episode's quality costs (issue 29): `recording.quality.measure` on stored
episode files, as `write_episode` runs it in the teleop server's storing thread.

    .venv/bin/python benchmarks/quality.py out/generation/lift/generated/episodes --limit 200
    .venv/bin/python benchmarks/quality.py            # records 10 scripted lift episodes first

Per episode: the median of `--repeats` timings; reported as the median and 95th percentile over
the episodes, per step, and what 1,000 episodes would take on one core.
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from crowdteleop.recording.episode_file import read_episode
from crowdteleop.recording.quality import measure

app = typer.Typer(add_completion=False)
console = Console(soft_wrap=True)


def scripted_episodes(directory: Path, count: int) -> list[Path]:
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    with scripted_rig("lift", "osc", robot="Panda") as rig:
        recorded = [
            record_scripted_episode(rig, directory, f"lift-{seed}", seed).path
            for seed in range(count)
        ]
    return [path for path in recorded if path is not None]


def timed_ms(path: Path, repeats: int) -> tuple[float, int]:
    """(median ms of `measure` on the episode, its steps)."""
    episode = read_episode(path)
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        measure(episode, episode.metadata)
        times.append((time.perf_counter() - began) * 1e3)
    return statistics.median(times), episode.steps


@app.command()
def main(
    episodes: Annotated[Path | None, typer.Argument(help="a folder of episode files")] = None,
    limit: int = 200,
    repeats: int = 5,
) -> None:
    with tempfile.TemporaryDirectory() as scratch:
        if episodes is None:
            paths = scripted_episodes(Path(scratch), 10)
        else:
            paths = sorted(episodes.rglob("*.hdf5"))[:limit]
        results = [timed_ms(path, repeats) for path in paths]
    per_episode = sorted(ms for ms, _ in results)
    per_step_us = [1e3 * ms / steps for ms, steps in results if steps]
    p95 = per_episode[min(len(per_episode) - 1, round(0.95 * (len(per_episode) - 1)))]
    summary = {
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "episodes": len(results),
        "median_steps": statistics.median(steps for _, steps in results),
        "median_ms": round(statistics.median(per_episode), 3),
        "p95_ms": round(p95, 3),
        "median_us_per_step": round(statistics.median(per_step_us), 2),
        "thousand_episodes_s": round(statistics.fmean(per_episode), 3),  # 1,000 x mean ms
    }
    console.print_json(json.dumps(summary))


if __name__ == "__main__":
    app()
