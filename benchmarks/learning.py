"""Learning from the platform's demonstrations (issue 13): the paper's Table 1 experiment at
the scale of one 2-core machine, plus BC-RNN on the same data.

    .venv/bin/python benchmarks/learning.py --ppo-budget 5m --bc-epochs 50 \
        > out/learning.log 2>&1 &
    # SAC with the demos in its buffer, 100k steps a run (~35 min two at a time), lift only,
    # no BC, seeds 1 and 2 (--first-seed), the runs' results kept for `learn table` later:
    .venv/bin/python benchmarks/learning.py --out out/learning-sac --algos sac --tasks lift \
        --bc-counts "" --demo-counts 10,100 --seeds 2 --first-seed 1 --sac-budget 100k \
        --eval-sims both --eval-episodes 20 --keep benchmarks/runs/learning-sac \
        > out/learning-sac.log 2>&1 &

1. scripted demonstrations recorded through the platform's control and recording path (the
   files workers produce), ``--demos`` successes per task, Panda with OSC;
2. ``crowdteleop dataset build --obs low-dim``;
3. ``crowdteleop learn rl`` (``--algos``: ppo, sac, ibrl) per task x demonstration count
   {0, 10, 100} x seed, and ``learn bc`` on 10 and 100 demos, ``--jobs`` at a time, each then
   ``learn eval`` (ours: the paper's return over 1000 steps for PPO, success within
   robomimic's horizon for BC);
4. ``crowdteleop learn table`` (Markdown) and the learning curves (PNG).

Writes everything under ``--out`` (default out/learning/); logs per job in ``logs/``.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import typer

app = typer.Typer(add_completion=False)
CLI = [sys.executable, "-m", "crowdteleop"]


def record(task: str, demos: int, directory: Path) -> dict[str, float]:
    """Scripted episodes, seeds 0, 1, ..., until ``demos`` succeeded."""
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    started, successes, seed = time.perf_counter(), 0, 0
    directory.mkdir(parents=True, exist_ok=True)
    with scripted_rig(task, "osc", robot="Panda") as rig:
        while successes < demos and seed < 3 * demos:
            episode = record_scripted_episode(rig, directory, f"{task}-{seed}", seed)
            if episode.outcome != "success" and episode.path is not None:
                episode.path.unlink()  # the datasets hold successful demonstrations
            successes += episode.outcome == "success"
            seed += 1
    return {"attempts": seed, "successes": successes, "seconds": time.perf_counter() - started}


def robosuite_lift_step_ms() -> float:
    """Plain robosuite's Lift step, as benchmarks/sim.py measures it (Sawyer, its default
    OSC_POSE, median of 5 x 100 steps): these VMs differ ~2x in speed from day to day, so
    every run states its own."""
    from _measure import BenchOptions, TaskBench, median

    bench = TaskBench("lift", BenchOptions(memory=False))
    try:
        bench.robosuite_step()
    finally:
        bench.close()
    return median(bench.result.robosuite_step_ms) or 0.0


def run(command: list[str], log: Path) -> float:
    started = time.perf_counter()
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("a") as file:
        file.write("$ " + " ".join(command) + "\n")
        file.flush()
        subprocess.run(command, stdout=file, stderr=subprocess.STDOUT, check=True)
    return time.perf_counter() - started


def build_datasets(
    out: Path, tasks: str, demos: int, timings: dict[str, object]
) -> dict[str, Path]:
    """A low-dim dataset per task, recorded and built unless it is there already."""
    datasets = {}
    for task in tasks.split(","):
        dataset = out / f"{task}.hdf5"
        if not dataset.exists():
            timings[f"record {task}"] = record(task, demos, out / "episodes" / task)
            build = [*CLI, "dataset", "build", str(out / "episodes" / task), "--output"]
            timings[f"build {task}"] = run(
                [*build, str(dataset), "--obs", "low-dim", "--overwrite"], out / "logs" / "build"
            )
        datasets[task] = dataset
        print(task, timings.get(f"record {task}"), flush=True)
    return datasets


# what `learn table` reads of a run, a few kB: kept in the repository, runs add up over sessions
KEPT_FILES = ("run.json", "state.json", "curve.csv", "progress.csv", "eval.json")


def keep_results(out: Path, keep: Path) -> int:
    """Copies what `learn table` reads of every evaluated run under ``out`` to the same place
    under ``keep`` (no checkpoints, no videos); returns how many runs."""
    kept = 0
    for run_file in sorted(out.rglob("run.json")):
        run = run_file.parent
        if not (run / "eval.json").exists():
            continue
        target = keep / run.relative_to(out)
        target.mkdir(parents=True, exist_ok=True)
        for name in KEPT_FILES:
            if (run / name).exists():
                shutil.copy2(run / name, target / name)
        kept += 1
    return kept


Job = tuple[str, list[list[str]]]  # a name and its commands, run one after the other


def rl_jobs(
    out: Path,
    datasets: dict[str, Path],
    seed: int,
    counts: str,
    rl_options: dict[str, list[str]],
    eval_sims: str,
    eval_episodes: int,
) -> list[Job]:
    """`learn rl` then `learn eval` per algorithm, task and demonstration count, for one seed;
    ``rl_options``: each algorithm's options ("ppo", "sac")."""
    jobs = []
    for algo, options in rl_options.items():
        for task, dataset in datasets.items():
            for count in (int(c) for c in counts.split(",")):
                runs = out / algo / task / f"demos_{count}"
                rl = [*CLI, "learn", "rl", "--algo", algo, "--dataset", str(dataset)]
                rl += ["--demos", str(count), "--output", str(runs), "--first-seed", str(seed)]
                evaluate = [*CLI, "learn", "eval", str(runs / f"seed_{seed}"), "--sim", eval_sims]
                evaluate += ["--episodes", str(eval_episodes), "--video", "1"]
                jobs.append((f"{algo}-{task}-{count}-{seed}", [[*rl, *options], evaluate]))
    return jobs


def bc_jobs(
    out: Path, datasets: dict[str, Path], counts: str, epochs: int, eval_episodes: int
) -> list[Job]:
    """`learn bc` then `learn eval` per task and demonstration count (seed 0)."""
    jobs = []
    for task, dataset in datasets.items():
        for count in (int(c) for c in counts.split(",")):
            target = out / "bc" / task / f"demos_{count}" / "seed_0"
            bc = [*CLI, "learn", "bc", str(dataset), "--output", str(target)]
            bc += ["--demos", str(count), "--epochs", str(epochs)]
            evaluate = [*CLI, "learn", "eval", str(target / "model.pt"), "--sim", "ours"]
            evaluate += ["--episodes", str(eval_episodes)]
            jobs.append((f"bc-{task}-{count}", [bc, evaluate]))
    return jobs


@app.command()
def main(
    out: Path = Path("out/learning"),
    tasks: str = "lift,pick-place-can",
    demo_counts: str = "0,10,100",
    bc_counts: str = "10,100",
    seeds: int = 3,
    first_seed: int = 0,  # seeds first_seed .. first_seed + seeds - 1, e.g. to add seeds later
    demos: int = 112,  # 10 % go to mask/valid: BC still gets 100 to train on
    algos: str = "ppo",
    ppo_budget: str = "5m",
    sac_budget: str = "1h",
    sac_horizon: int = 200,  # lift's scripted demos take ~60 steps, pick-place-can's ~300
    eval_sims: str = "ours",
    bc_epochs: int = 50,
    n_envs: int = 4,
    eval_episodes: int = 10,
    jobs: int = 2,
    plot: Path = Path("benchmarks/learning-curves.png"),
    keep: Path | None = None,  # e.g. benchmarks/runs/learning-sac: what learn table reads
) -> None:
    out.mkdir(parents=True, exist_ok=True)
    timings: dict[str, object] = {"robosuite lift step ms": robosuite_lift_step_ms()}
    print(f"plain robosuite Lift step: {timings['robosuite lift step ms']:.2f} ms", flush=True)
    datasets = build_datasets(out, tasks, demos, timings)

    # seed-major, so that every condition has a first seed early (and BC after it)
    ppo = ["--budget", ppo_budget, "--vec", "dummy", "--n-envs", str(n_envs), "--resume"]
    sac = ["--budget", sac_budget, "--horizon", str(sac_horizon), "--resume"]
    options = {"ppo": ppo, "sac": sac, "ibrl": sac}  # ibrl: SAC's options, its own defaults
    rl_options = {algo: options[algo] for algo in algos.split(",")}
    commands: list[Job] = []
    for seed in range(first_seed, first_seed + seeds):
        commands += rl_jobs(out, datasets, seed, demo_counts, rl_options, eval_sims, eval_episodes)
        if seed == first_seed and bc_counts:
            commands += bc_jobs(out, datasets, bc_counts, bc_epochs, eval_episodes)

    def job(name: str, steps: list[list[str]]) -> tuple[str, float]:
        seconds = sum(run(step, out / "logs" / f"{name}.log") for step in steps)
        print(f"done {name} in {seconds:.0f} s", flush=True)
        return name, seconds

    started = time.perf_counter()
    with ThreadPoolExecutor(jobs) as pool:
        for name, seconds in pool.map(lambda item: job(*item), commands):
            timings[name] = seconds
    timings["all jobs"] = time.perf_counter() - started
    (out / "timings.json").write_text(json.dumps(timings, indent=2))
    if keep is not None:
        print(f"kept {keep_results(out, keep)} runs' results in {keep}", flush=True)
    table = [*CLI, "learn", "table", str(out), "--markdown", str(out / "table.md")]
    run([*table, "--plot", str(plot)], out / "logs" / "table.log")
    print((out / "table.md").read_text())


if __name__ == "__main__":
    app()
