"""What crash-safe recording costs the teleop loop: append per step, flush (write + fsync),
finalize and recovery reads, at a typical state size (pick-place: 71 floats, 8 actions).

    .venv/bin/python benchmarks/recording.py
    .venv/bin/python benchmarks/recording.py --steps 2000 --flushes 50 --directory out \
        --json out/bench-recording.json

The directory decides the fsync cost: give one on the disk the server will record to.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.recording.episode_file import StepRecord, read_episode
from crowdteleop.recording.wal import EpisodeRecorder
from crowdteleop.recording.wal_reader import read_partial

app = typer.Typer(add_completion=False)
STATE_SIZE = 71
ACTION_SIZE = 8
CONTROL_HZ = 20
FLUSH_INTERVAL_S = 1.0
METADATA = {"task": "pick-place", "robot": "Sawyer", "model_xml": "<mujoco/>" * 20000}


def make_steps(count: int) -> list[StepRecord]:
    """A realistic stream: a moving phone, one or two contacts per step."""
    rng = np.random.default_rng(0)
    return [
        StepRecord(
            index=index,
            state=rng.standard_normal(STATE_SIZE),
            action=rng.uniform(-1, 1, ACTION_SIZE),
            command={
                "seq": index,
                "client_time_ms": 1.7e9 + index / CONTROL_HZ,
                "position": rng.standard_normal(3).tolist(),
                "quaternion": [0.0, 0.0, 0.0, 1.0],
                "engaged": True,
                "gripper": 1.0,
                "device": "phone",
            },
            server_time=1.7e9 + index / CONTROL_HZ,
            step_duration_s=0.004,
            reward=0.0,
            success=False,
            contacts=[{"robot_part": "finger", "object": "can", "intensity": 0.3}] * (index % 3),
        )
        for index in range(count)
    ]


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q))


def measure(directory: Path, steps: int, flushes: int) -> dict[str, Any]:
    records = make_steps(steps)
    # append alone: the flush interval never passes
    recorder = EpisodeRecorder(directory, "append", METADATA, flush_interval_s=3600.0)
    append_us = []
    for record in records:
        t0 = time.perf_counter_ns()
        recorder.append(record)
        append_us.append((time.perf_counter_ns() - t0) / 1e3)
    recorder.flush()
    wal_bytes = recorder.wal_path.stat().st_size
    t0 = time.perf_counter()
    partial = read_partial(recorder.wal_path)
    read_partial_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    path = recorder.finalize("success")
    finalize_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    read_episode(path)
    read_episode_s = time.perf_counter() - t0

    # flush: one second of steps (20) buffered, then written and fsync'd
    recorder = EpisodeRecorder(directory, "flush", METADATA, flush_interval_s=3600.0)
    flush_ms = []
    for second in range(flushes):
        for record in records[second * CONTROL_HZ : (second + 1) * CONTROL_HZ]:
            recorder.append(record)
        t0 = time.perf_counter_ns()
        recorder.flush()
        flush_ms.append((time.perf_counter_ns() - t0) / 1e6)
    recorder.finalize("reset")

    append_median = statistics.median(append_us)
    flush_median = statistics.median(flush_ms)
    return {
        "state_size": STATE_SIZE,
        "action_size": ACTION_SIZE,
        "steps": steps,
        "append_us_median": append_median,
        "append_us_p99": percentile(append_us, 99),
        "flush_20_steps_ms_median": flush_median,
        "flush_20_steps_ms_p95": percentile(flush_ms, 95),
        "per_step_us_at_20hz": append_median + 1e3 * flush_median / CONTROL_HZ,
        "wal_bytes_per_step": (wal_bytes - (len(METADATA["model_xml"]) + 100)) / steps,
        "read_partial_ms": 1e3 * read_partial_s,
        "finalize_ms": 1e3 * finalize_s,
        "read_episode_ms": 1e3 * read_episode_s,
        "episode_bytes": path.stat().st_size,
        "episode_minutes": steps / CONTROL_HZ / 60,
        "partial_steps": partial.steps,
        "raw": {"append_us": append_us, "flush_ms": flush_ms},
    }


@app.command()
def main(
    steps: Annotated[int, typer.Option(help="appends timed (and the finalized episode)")] = 1200,
    flushes: Annotated[int, typer.Option(help="flushes of 20 steps timed")] = 30,
    repeats: Annotated[int, typer.Option(help="runs; the table shows their medians")] = 5,
    directory: Annotated[Path | None, typer.Option(help="where to record (default: tmp)")] = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="also write raw values")] = None,
) -> None:
    """Recording cost per control step, flush, finalize and reads; a table on stdout."""
    steps = max(steps, flushes * CONTROL_HZ)
    runs = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory(dir=directory) as tmp:
            runs.append(measure(Path(tmp), steps, flushes))
    # Each figure: the median over runs (other processes on a shared machine add outliers).
    result = {
        key: statistics.median(run[key] for run in runs)
        for key, value in runs[0].items()
        if isinstance(value, int | float)
    }
    spread = [run["append_us_median"] for run in runs]
    console = Console()
    console.print(
        f"python {platform.python_version()}, {os.cpu_count()} cpus, load "
        f"{os.getloadavg()[0]:.2f}, dir {directory or tempfile.gettempdir()}, "
        f"median of {repeats} runs (append medians {min(spread):.1f}-{max(spread):.1f} us)"
    )
    table = Table(title=f"recording, state {STATE_SIZE} floats, action {ACTION_SIZE}")
    table.add_column("measure")
    table.add_column("value", justify="right")
    rows = [
        ("append, median / p99 (us)", "append_us_median", "append_us_p99"),
        (
            "flush of 20 steps + fsync, median / p95 (ms)",
            "flush_20_steps_ms_median",
            "flush_20_steps_ms_p95",
        ),
        ("per step at 20 Hz, 1 s flushes (us)", "per_step_us_at_20hz", None),
        ("log bytes per step", "wal_bytes_per_step", None),
        (f"read_partial, {steps} steps (ms)", "read_partial_ms", None),
        (f"finalize, {steps} steps (ms)", "finalize_ms", None),
        (f"read_episode, {steps} steps (ms)", "read_episode_ms", None),
    ]
    for label, key, second in rows:
        value = f"{result[key]:.1f}" + (f" / {result[second]:.1f}" if second else "")
        table.add_row(label, value)
    table.add_row("episode file (KiB)", f"{result['episode_bytes'] / 1024:.0f}")
    console.print(table)
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps({"summary": result, "runs": runs}, indent=1))


if __name__ == "__main__":
    app()
