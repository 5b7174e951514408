"""Does training on the better-scored demonstrations pay (issue 29, "the proof that matters")?
robomimic's better/okay/worse study, on a crowd of our own: the successful demonstrations of a
campaign of synthetic workers of three skills (benchmarks/quality_campaign.py, through the
coordinator) are built into one dataset; BC-RNN (`crowdteleop learn bc`) is trained with the
same budget (epochs x 100 gradient steps, the same training seeds) on the top-scored half
(`mask/quality_top_50`), on all of them, and on the bottom half (`mask/quality_bottom_50`);
each policy is rolled out in plain robosuite (from the dataset's env_args).

    .venv/bin/python benchmarks/quality_bc.py out/quality_campaign/lift/skills/data/episodes \
        --epochs 100 --rollouts 50 --train-seeds 0,1

The trainings (each arm with each training seed) run side by side, one torch thread each.
JSON in --out/result.json: each run's evaluation, and each arm's successes over its seeds.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import h5py
import typer
from rich.console import Console

app = typer.Typer(add_completion=False)
console = Console(soft_wrap=True)
ARMS = {"top half": "quality_top_50", "all": "all", "bottom half": "quality_bottom_50"}


def crowdteleop(*args: str, log: Path) -> None:
    with log.open("w") as out:
        subprocess.run(
            [sys.executable, "-m", "crowdteleop", *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            check=True,
        )


def build(episodes: Path, dataset: Path, task: str) -> dict[str, Any]:
    """Every successful demonstration, none held out (each arm trains on its whole mask); an
    `all` mask beside the quality halves, and an empty `none` to validate on."""
    crowdteleop(
        "dataset",
        "build",
        str(episodes),
        "--output",
        str(dataset),
        "--task",
        task,
        "--valid-fraction",
        "0",
        "--overwrite",
        log=dataset.with_suffix(".log"),
    )
    with h5py.File(dataset, "a") as file:
        names = sorted(file["data"], key=lambda name: int(name.split("_")[1]))
        for key, members in (("all", names), ("none", [])):
            if key in file["mask"]:
                del file[f"mask/{key}"]
            file["mask"].create_dataset(key, data=[n.encode() for n in members], dtype="S16")
        return {key: [n.decode() for n in file[f"mask/{key}"][()]] for key in ARMS.values()}


def runs(out: Path, train_seeds: list[int]) -> dict[str, Path]:
    """Each (arm, training seed)'s folder, named 'arm / seed N'."""
    return {
        f"{arm} / seed {seed}": out / key / f"seed{seed}"
        for arm, key in ARMS.items()
        for seed in train_seeds
    }


def train_all(dataset: Path, folders: dict[str, Path], epochs: int) -> dict[str, float]:
    """Every (arm, seed) side by side: each one's wall time (s)."""
    started, running = time.monotonic(), {}
    for run, folder in folders.items():
        folder.mkdir(parents=True, exist_ok=True)
        key, seed = folder.parent.name, folder.name.removeprefix("seed")
        command = [sys.executable, "-m", "crowdteleop", "learn", "bc", str(dataset)]
        command += ["--output", str(folder), "--epochs", str(epochs), "--seed", seed]
        # no validation: it would score every window of the demos each epoch, and pick nothing
        command += ["--train-filter", key, "--valid-filter", "none", "--threads", "1"]
        log = (folder / "train.log").open("w")
        running[run] = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    seconds = {}
    for run, process in running.items():
        if process.wait() != 0:
            raise RuntimeError(f"training {run} failed: see {folders[run] / 'train.log'}")
        seconds[run] = round(time.monotonic() - started, 1)
    return seconds


def evaluate(folders: dict[str, Path], rollouts: int, seed: int) -> dict[str, Any]:
    """Every run's policy rolled out in plain robosuite, the runs side by side."""
    running = {}
    for run, folder in folders.items():
        command = [sys.executable, "-m", "crowdteleop", "learn", "eval", str(folder / "model.pt")]
        command += ["--sim", "robosuite", "--episodes", str(rollouts), "--seed", str(seed)]
        log = (folder / "eval.log").open("w")
        running[run] = subprocess.Popen(
            [*command, "--video", "0"], stdout=log, stderr=subprocess.STDOUT
        )
    for run, process in running.items():
        if process.wait() != 0:
            raise RuntimeError(f"evaluating {run} failed: see {folders[run] / 'eval.log'}")
    return {run: json.loads((folder / "eval.json").read_text()) for run, folder in folders.items()}


def successes(results: dict[str, Any], rollouts: int) -> dict[str, str]:
    """Each arm's successes summed over its training seeds, 'k / n'."""
    totals: dict[str, list[int]] = {}
    for run, report in results.items():
        arm = run.split(" / ")[0]
        total = totals.setdefault(arm, [0, 0])
        total[0] += int(report["results"]["robosuite"]["successes"])
        total[1] += rollouts
    return {arm: f"{won} / {tried}" for arm, (won, tried) in totals.items()}


@app.command()
def main(
    episodes: Path,
    task: str = "lift",
    epochs: int = 100,
    rollouts: int = 20,
    seed: int = 1000,
    train_seeds: str = typer.Option("0", help="training seeds, comma-separated: each arm each"),
    out: Path = Path("out/quality_bc"),
) -> None:
    out.mkdir(parents=True, exist_ok=True)
    dataset = out / f"{task}.hdf5"
    masks = build(episodes, dataset, task)
    console.print({arm: len(masks[key]) for arm, key in ARMS.items()})
    folders = runs(out, [int(s) for s in train_seeds.split(",")])
    seconds = train_all(dataset, folders, epochs)
    results = evaluate(folders, rollouts, seed)
    summary = {
        "task": task,
        "epochs": epochs,
        "gradient_steps": epochs * 100,
        "rollout_seeds": f"{seed}-{seed + rollouts - 1}",
        "demos": {arm: len(masks[key]) for arm, key in ARMS.items()},
        "train_wall_s": seconds,
        "successes": successes(results, rollouts),
        "results": results,
    }
    (out / "result.json").write_text(json.dumps(summary, indent=2))
    console.print_json(json.dumps(summary))


if __name__ == "__main__":
    app()
