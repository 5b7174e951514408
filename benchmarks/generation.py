"""MimicGen-style generation on the platform (issue 32): scripted sources -> labelled dataset ->
`dataset generate` -> success rate, why attempts failed, throughput; optionally the training
dataset (sources + generated) the BC study trains on.

    .venv/bin/python benchmarks/generation.py --task lift --sources 10 --num 1000 --workers 2 \
        > out/generation-lift.log 2>&1
    .venv/bin/python benchmarks/generation.py --throughput --task lift  # 1, 2 processes; 2 raylets

Writes out/generation/<task>/ (sources/, sources.hdf5, generated/, train.hdf5, result.json).
Throughput runs generate into fresh folders (no resuming) and need root for Ray's namespace.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import typer
from rich.console import Console

from crowdteleop.dataset.build import BuildOptions, build_dataset
from crowdteleop.dataset.generation.attempt import Settings
from crowdteleop.dataset.generation.run import GenerateOptions, generate

app = typer.Typer(add_completion=False)
console = Console(soft_wrap=True)
GCS_PORT, NODE2_PORT = 6394, 6395


def record_sources(task: str, count: int, robot: str, directory: Path) -> dict[str, Any]:
    """Scripted OSC episodes (seeds 0, 1, ...) until ``count`` succeeded."""
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    started, kept, seed = time.perf_counter(), 0, 0
    directory.mkdir(parents=True, exist_ok=True)
    with scripted_rig(task, "osc", robot=robot) as rig:
        while kept < count and seed < 5 * count:
            episode = record_scripted_episode(rig, directory, f"{task}-{seed}", seed)
            kept += episode.outcome == "success"
            seed += 1
    return {"source_attempts": seed, "sources": kept, "record_s": time.perf_counter() - started}


def cpu_seconds() -> float:
    """This process's and its finished children's CPU time."""
    mine, children = os.times()[:2], os.times()[2:4]
    return float(sum(mine) + sum(children))


def run_generation(
    sources: Path,
    output: Path,
    num: int,
    workers: int,
    ray: str | None = None,
    action_noise: float = 0.0,
    robosuite_step: bool = False,
) -> dict[str, Any]:
    started, cpu = time.perf_counter(), cpu_seconds()
    settings = Settings(action_noise=action_noise, robosuite_step=robosuite_step)
    options = GenerateOptions(
        num=num, workers=workers, ray_address=ray, build=False, settings=settings
    )
    report = generate(sources, output, options)
    seconds = time.perf_counter() - started
    return {
        "num": num,
        "workers": workers,
        "ray": ray,
        "action_noise": action_noise,
        "robosuite_step": robosuite_step,
        "attempts": report.attempts,
        "successes": report.successes,
        "success_rate": report.success_rate,
        "reasons": dict(report.reasons.most_common()),
        "wall_s": seconds,
        "cpu_s": cpu_seconds() - cpu,
        "generated_per_min": 60.0 * report.successes / seconds,
        "attempts_per_min": 60.0 * report.attempts / seconds,
    }


@app.command()
def main(
    task: str = "lift",
    sources: int = 10,
    num: int = 1000,
    workers: int = 2,
    robot: str = "Panda",
    train_dataset: bool = typer.Option(True, help="build sources + generated for training"),
    throughput: bool = typer.Option(False, help="measure 1 / 2 processes and 2 raylets only"),
    throughput_num: int = 40,
    action_noise: float = typer.Option(0.0, help="MimicGen's action noise (its configs: 0.05)"),
    robosuite_step: bool = typer.Option(False, help="execute on robosuite's own step"),
) -> None:
    root = Path("out") / "generation" / task
    # without noise: generated/, train.hdf5, result.json; with it: generated-noise-<std>/...;
    # on robosuite's own step: generated-robosuite-step/... (with noise: -noise-<std> after it)
    tag = ("-robosuite-step" if robosuite_step else "") + (
        f"-noise-{action_noise:g}" if action_noise else ""
    )
    result: dict[str, Any] = {"task": task, "robot": robot, "date": time.strftime("%Y-%m-%d %H:%M")}
    source_dataset = root / "sources.hdf5"
    if not source_dataset.exists():
        result |= record_sources(task, sources, robot, root / "sources")
        started = time.perf_counter()
        build_dataset([root / "sources"], source_dataset, BuildOptions(drift_tolerance=None))
        result["source_build_s"] = time.perf_counter() - started
    if throughput:
        result["throughput"] = measure_throughput(source_dataset, root, throughput_num)
    else:
        generated = root / f"generated{tag}"
        result["generation"] = run_generation(
            source_dataset,
            generated,
            num,
            workers,
            action_noise=action_noise,
            robosuite_step=robosuite_step,
        )
        console.print(result["generation"])
        if train_dataset:
            started = time.perf_counter()
            build_dataset(
                [root / "sources", *sorted((generated / "episodes").glob("*.hdf5"))[:num]],
                root / f"train{tag}.hdf5",
                BuildOptions(drift_tolerance=None),
                overwrite=True,
            )
            result["train_build_s"] = time.perf_counter() - started
    name = "throughput.json" if throughput else f"result{tag}.json"
    (root / name).write_text(json.dumps(result, indent=2))
    console.print_json(json.dumps(result))


def measure_throughput(sources: Path, root: Path, num: int) -> list[dict[str, Any]]:
    """Fresh runs: one process, a pool of two, and two one-CPU raylets (root: a namespace)."""
    rows = []
    for workers in (1, 2):
        output = root / f"throughput-{workers}-{time.time_ns()}"
        rows.append(run_generation(sources, output, num, workers))
        console.print(rows[-1])
    if os.geteuid() == 0:
        rows.append(ray_throughput(sources, root, num))
        console.print(rows[-1])
    return rows


def ray_throughput(sources: Path, root: Path, num: int) -> dict[str, Any]:
    """The same on a Ray cluster of two raylets in a loopback-only network namespace."""
    ray = str(Path(sys.executable).with_name("ray"))
    common = "--num-cpus=1 --node-ip-address=127.0.0.1"
    output = root / f"throughput-ray-{time.time_ns()}"
    inner = (
        f"from benchmarks.generation import run_generation; import json, pathlib; print('RESULT', "
        f"json.dumps(run_generation(pathlib.Path('{sources}'), pathlib.Path('{output}'), {num}, 2,"
        f" '127.0.0.1:{GCS_PORT}')))"
    )
    script = " && ".join(
        [
            "ip link set lo up",
            f"{ray} start --head --port={GCS_PORT} --include-dashboard=false {common}",
            f"{ray} start --address=127.0.0.1:{GCS_PORT} --node-manager-port={NODE2_PORT} {common}",
            f'{sys.executable} -c "{inner}"',
        ]
    )
    env = {
        **os.environ,
        "RAY_USAGE_STATS_ENABLED": "0",
        "RAY_AUTH_MODE": "disabled",
        "PYTHONPATH": str(Path.cwd()),
    }
    done = subprocess.run(
        ["unshare", "--net", "--", "bash", "-c", f"{script}; rc=$?; {ray} stop --force; exit $rc"],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    line = next((row for row in done.stdout.splitlines() if row.startswith("RESULT ")), None)
    if line is None:
        raise RuntimeError(done.stdout[-2000:] + done.stderr[-2000:])
    return {**json.loads(line[len("RESULT ") :]), "raylets": 2}


if __name__ == "__main__":
    app()
