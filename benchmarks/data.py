"""What the dataset path costs: recording per control step (scripted lift episodes through the
real control path), upload of one demonstration to a local S3-compatible server (moto's, over
HTTP, checksum verified), and `dataset build` throughput.

    .venv/bin/python benchmarks/data.py
    .venv/bin/python benchmarks/data.py --episodes 10 --uploads 30 --json out/bench-data.json
"""

from __future__ import annotations

import json
import logging
import platform
import socket
import statistics
import tempfile
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from crowdteleop.data.dataset import build_dataset
from crowdteleop.data.s3 import S3Config, S3Storage
from crowdteleop.data.scripted import record_scripted_episode, scripted_rig

app = typer.Typer(add_completion=False)


def record(directory: Path, episodes: int) -> tuple[dict[str, Any], list[Path]]:
    """Step time vs recording time (append, including its periodic write + fsync)."""
    step_s = record_s = step_cpu = record_cpu = 0.0
    steps = 0
    paths = []
    with scripted_rig("lift") as rig:
        for seed in range(episodes):
            extra = {"interface": "phone", "worker_id": f"w{seed % 3}"}
            episode = record_scripted_episode(rig, directory, f"bench-{seed}", seed, extra)
            step_s += episode.step_seconds
            record_s += episode.record_seconds
            step_cpu += episode.step_cpu_seconds
            record_cpu += episode.record_cpu_seconds
            steps += episode.steps
            paths.append(episode.path)
    return {
        "episodes": episodes,
        "steps": steps,
        "step_ms": 1000 * step_s / steps,
        "record_us": 1e6 * record_s / steps,
        "overhead_pct": 100 * record_s / step_s,
        "step_cpu_ms": 1000 * step_cpu / steps,
        "record_cpu_us": 1e6 * record_cpu / steps,
        "overhead_cpu_pct": 100 * record_cpu / step_cpu,
    }, paths


def upload(paths: list[Path], uploads: int) -> dict[str, Any]:
    """Seconds per verified put of one episode file (new key each time)."""
    from moto.server import ThreadedMotoServer

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    server = ThreadedMotoServer("127.0.0.1", port, verbose=False)
    server.start()
    try:
        config = S3Config(
            bucket="bench",
            endpoint_url=f"http://127.0.0.1:{port}",
            access_key_id="bench",
            secret_access_key="bench",
            prefix="bench",
        )
        store = S3Storage(config)
        store._client.create_bucket(Bucket="bench")
        times = []
        for i in range(uploads):
            path = paths[i % len(paths)]
            started = time.perf_counter()
            store.put(path, f"success/{i}-{path.name}")
            times.append(time.perf_counter() - started)
        again = time.perf_counter()
        store.put(paths[0], f"success/0-{paths[0].name}")  # idempotent retry: HEAD only
        retry = time.perf_counter() - again
    finally:
        server.stop()
    size_kib = statistics.mean(p.stat().st_size for p in paths) / 1024
    return {
        "uploads": uploads,
        "file_kib": size_kib,
        "median_ms": 1000 * statistics.median(times),
        "p95_ms": 1000 * sorted(times)[int(0.95 * (len(times) - 1))],
        "retry_ms": 1000 * retry,
    }


def build(directory: Path, out: Path, episodes: int) -> dict[str, Any]:
    results = {}
    for label, tolerance in (("with_drift_check", 1e-6), ("without", None)):
        report = build_dataset([directory], out / f"{label}.hdf5", drift_tolerance=tolerance)
        results[label] = {"seconds": report.seconds, "demos_per_s": episodes / report.seconds}
    return results


@app.command()
def main(
    episodes: Annotated[int, typer.Option(help="scripted lift episodes to record")] = 8,
    uploads: Annotated[int, typer.Option(help="puts to time")] = 20,
    json_out: Annotated[Path | None, typer.Option("--json", help="write figures here")] = None,
) -> None:
    console = Console()
    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # moto's per-request log lines
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp) / "episodes"
        recording, paths = record(directory, episodes)
        uploading = upload(paths, uploads)
        building = build(directory, Path(tmp), episodes)
    table = Table("measure", "value")
    table.add_row("control step (lift, ik-velocity)", f"{recording['step_ms']:.2f} ms")
    table.add_row("recording per step (append + flushes)", f"{recording['record_us']:.0f} us")
    table.add_row("recording overhead", f"{recording['overhead_pct']:.2f} % of step time")
    table.add_row(
        "same, CPU time of the control thread",
        f"{recording['record_cpu_us']:.0f} us of {recording['step_cpu_ms']:.2f} ms = "
        f"{recording['overhead_cpu_pct']:.2f} %",
    )
    table.add_row(
        f"upload one demo ({uploading['file_kib']:.0f} KiB) to local S3",
        f"median {uploading['median_ms']:.1f} ms, p95 {uploading['p95_ms']:.1f} ms",
    )
    table.add_row("idempotent re-put (already stored)", f"{uploading['retry_ms']:.1f} ms")
    for label, figures in building.items():
        table.add_row(
            f"build {episodes} demos ({label.replace('_', ' ')})",
            f"{figures['seconds']:.2f} s = {figures['demos_per_s']:.1f} demos/s",
        )
    console.print(table)
    if json_out is not None:
        figures = {
            "machine": platform.platform(),
            "recording": recording,
            "upload": uploading,
            "build": building,
        }
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    app()
