"""Does training on the better-scored demonstrations pay (issue 29, "the proof that matters")?
robomimic's better/okay/worse study, on a crowd of our own: the successful demonstrations of a
campaign of synthetic workers of three skills (benchmarks/quality_campaign.py, through the
coordinator) are built into one dataset; BC-RNN (`crowdteleop learn bc`) is trained with the
same budget (epochs x 100 gradient steps, same seed) on the top-scored half
(`mask/quality_top_50`), on all of them, and on the bottom half (`mask/quality_bottom_50`);
each policy is rolled out in plain robosuite (from the dataset's env_args).

    .venv/bin/python benchmarks/quality_bc.py out/quality_campaign/lift/skills/data/episodes \
        --epochs 100 --rollouts 20

The three trainings run side by side (one torch thread each). JSON in --out/result.json.
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


def train_all(dataset: Path, out: Path, epochs: int) -> dict[str, float]:
    """The arms side by side: each one's wall time (s)."""
    started, running = time.monotonic(), {}
    for arm, key in ARMS.items():
        folder = out / key
        folder.mkdir(parents=True, exist_ok=True)
        command = [sys.executable, "-m", "crowdteleop", "learn", "bc", str(dataset)]
        command += ["--output", str(folder), "--epochs", str(epochs), "--seed", "0"]
        # no validation: it would score every window of the demos each epoch, and pick nothing
        command += ["--train-filter", key, "--valid-filter", "none", "--threads", "1"]
        log = (folder / "train.log").open("w")
        running[arm] = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    seconds = {}
    for arm, process in running.items():
        if process.wait() != 0:
            raise RuntimeError(f"training {arm} failed: see {out / ARMS[arm] / 'train.log'}")
        seconds[arm] = round(time.monotonic() - started, 1)
    return seconds


def evaluate(out: Path, rollouts: int, seed: int) -> dict[str, Any]:
    results = {}
    for arm, key in ARMS.items():
        model = out / key / "model.pt"
        crowdteleop(
            "learn",
            "eval",
            str(model),
            "--sim",
            "robosuite",
            "--episodes",
            str(rollouts),
            "--seed",
            str(seed),
            "--video",
            "0",
            log=out / key / "eval.log",
        )
        report = json.loads((out / key / "eval.json").read_text())
        results[arm] = report
    return results


@app.command()
def main(
    episodes: Path,
    task: str = "lift",
    epochs: int = 100,
    rollouts: int = 20,
    seed: int = 1000,
    out: Path = Path("out/quality_bc"),
) -> None:
    out.mkdir(parents=True, exist_ok=True)
    dataset = out / f"{task}.hdf5"
    masks = build(episodes, dataset, task)
    console.print({arm: len(masks[key]) for arm, key in ARMS.items()})
    seconds = train_all(dataset, out, epochs)
    results = evaluate(out, rollouts, seed)
    summary = {
        "task": task,
        "epochs": epochs,
        "gradient_steps": epochs * 100,
        "rollout_seeds": f"{seed}-{seed + rollouts - 1}",
        "demos": {arm: len(masks[key]) for arm, key in ARMS.items()},
        "train_wall_s": seconds,
        "results": results,
    }
    (out / "result.json").write_text(json.dumps(summary, indent=2))
    console.print_json(json.dumps(summary))


if __name__ == "__main__":
    app()
