"""What `crowdteleop dataset score` costs on a campaign of 1,000 demonstrations (issue 29:
<= 2 minutes on 2 cores). The 1,000 demos are made from a real built dataset's demos, each
copied with small noise on its observations and actions (so no two are equal): the same
lengths and dimensions a campaign's demos have. The source is a built dataset (the lift
campaign's, `out/quality_bc/lift.hdf5` from benchmarks/quality_bc.py); without one, 12
scripted lift demonstrations (Panda, OSC; four each by the expert, intermediate and novice
operators of `control.scripted.skills.SKILLS`) are recorded and built first (~30 s, not timed).
The time is `score_dataset`'s wall time (read, embed, KSG, write), the median of `--repeats`.

    .venv/bin/python benchmarks/dataset_score.py out/quality_bc/lift.hdf5 --demos 1000 --repeats 3
    .venv/bin/python benchmarks/dataset_score.py --demos 1000 --repeats 3
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Annotated

import h5py
import numpy as np
import typer
from rich.console import Console

from crowdteleop.dataset.score import OBS_KEYS, score_dataset

app = typer.Typer(add_completion=False)
console = Console(soft_wrap=True)


def campaign(source: Path, target: Path, demos: int) -> int:
    """`demos` noisy copies of the source's demos, in turn; the total steps."""
    rng = np.random.default_rng(0)
    steps = 0
    with h5py.File(source, "r") as read, h5py.File(target, "w") as write:
        names = sorted(read["data"], key=lambda name: int(name.rpartition("_")[2]))
        data = write.create_group("data")
        for k in range(demos):
            demo = read["data"][names[k % len(names)]]
            group = data.create_group(f"demo_{k + 1}")
            actions = demo["actions"][()]
            group["actions"] = actions + 0.01 * rng.standard_normal(actions.shape)
            for key in OBS_KEYS:
                values = demo[f"obs/{key}"][()]
                group[f"obs/{key}"] = values + 0.001 * rng.standard_normal(values.shape)
            steps += len(actions)
    return steps


def scripted_source(folder: Path) -> Path:
    """12 scripted lift demonstrations of the three skill levels, built into a dataset."""
    from crowdteleop.control.scripted.skills import SKILLS
    from crowdteleop.dataset.build import BuildOptions, build_dataset
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    with scripted_rig("lift", "osc", robot="Panda") as rig:
        for seed in range(12):
            skill = ("expert", "intermediate", "novice")[seed % 3]
            record_scripted_episode(
                rig, folder / "episodes", f"ep-{seed}", seed, style=SKILLS[skill]
            )
    output = folder / "source.hdf5"
    build_dataset([folder / "episodes"], output, BuildOptions(drift_tolerance=None))
    return output


@app.command()
def main(
    source: Annotated[Path | None, typer.Argument(help="a built dataset to copy")] = None,
    demos: int = 1000,
    repeats: int = 3,
) -> None:
    with tempfile.TemporaryDirectory() as folder:
        if source is None:
            source = scripted_source(Path(folder))
        target = Path(folder) / "campaign.hdf5"
        steps = campaign(source, target, demos)
        seconds = []
        for _ in range(repeats):
            started = time.perf_counter()
            result = score_dataset(target)
            seconds.append(time.perf_counter() - started)
    console.print(
        f"{demos} demos ({steps} steps, {result.samples} samples): score in median "
        f"{statistics.median(seconds):.1f} s (runs: {', '.join(f'{s:.1f}' for s in seconds)})"
    )


if __name__ == "__main__":
    app()
