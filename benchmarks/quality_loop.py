"""Does measuring each stored episode cost the 20 Hz loop anything (issue 29, "Cost")? A real
teleop server (`crowdteleop teleop-server`, lift, Panda, OSC) driven over WebRTC by an expert
bot for --episodes short episodes, so an episode is stored (and measured, in the storing
thread) every few seconds; the server's own counters give the share of control ticks that
ran on time. The same with measuring switched off: the child process replaces the one
function `write_episode` calls to measure (`recording.episode_file._quality`) by one that
returns nothing, the only difference between the arms. Arms alternate, --repeats each.

    .venv/bin/python benchmarks/quality_loop.py --episodes 10 --repeats 3
"""

from __future__ import annotations

import json
import secrets
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import typer
from rich.console import Console

from crowdteleop.teleop.ready import stop_gracefully, wait_ready

app = typer.Typer(add_completion=False)
console = Console(soft_wrap=True)
ADMIN = secrets.token_urlsafe(32)
TOKEN = secrets.token_urlsafe(16)
UNMEASURED = (
    "import sys; import crowdteleop.recording.episode_file as f; "
    "f._quality = lambda partial, metadata: {}; "
    "from crowdteleop.cli import app; sys.argv[0] = 'crowdteleop'; app()"
)


def server(directory: Path, measured: bool) -> tuple[subprocess.Popen[str], str]:
    start = ["-m", "crowdteleop"] if measured else ["-c", UNMEASURED]
    command = [sys.executable, *start, "teleop-server", "--task", "lift", "--robot", "Panda"]
    command += ["--controller", "osc", "--token", TOKEN, "--admin-token", ADMIN, "--port", "0"]
    command += ["--record-dir", str(directory)]
    log = directory / "server.log"
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log.open("w"), text=True)
    return process, wait_ready(process, log, 90.0, "teleop server")


def counters(url: str) -> dict[str, Any]:
    headers = {"Authorization": f"Bearer {ADMIN}"}
    telemetry: dict[str, Any] = httpx.get(f"{url}/telemetry", headers=headers, timeout=10).json()
    return telemetry


def one_run(measured: bool, episodes: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as folder:
        directory = Path(folder)
        process, url = server(directory, measured)
        try:
            before = counters(url)
            bot = [sys.executable, "-m", "crowdteleop", "bot", "--url", url, "--token", TOKEN]
            bot += ["--admin-token", ADMIN, "--episodes", str(episodes), "--skill", "expert"]
            started = time.monotonic()
            subprocess.run(bot, capture_output=True, text=True, timeout=900, check=True)
            wall_s = time.monotonic() - started
            after = counters(url)
        finally:
            stop_gracefully(process, 30)
        stored = sorted(directory.rglob("*.hdf5"))
        quality = [_has_quality(path) for path in stored]
    ticks = after["ticks"] - before["ticks"]
    late, skipped = after["late"] - before["late"], after["skipped"] - before["skipped"]
    return {
        "measured": measured,
        "episodes_stored": len(stored),
        "with_metrics": sum(quality),
        "ticks": ticks,
        "on_time": (ticks - late) / (ticks + skipped) if ticks else 0.0,
        "wall_s": round(wall_s, 1),
    }


def _has_quality(path: Path) -> bool:
    from crowdteleop.recording.episode_file import read_metadata

    return bool(read_metadata(path).get("quality"))


@app.command()
def main(episodes: int = 10, repeats: int = 3, json_out: Path | None = None) -> None:
    runs = []
    for repeat in range(repeats):
        for measured in (True, False):
            run = one_run(measured, episodes)
            console.print(f"repeat {repeat + 1}: {run}")
            runs.append(run)
    summary = {}
    for measured in (True, False):
        mine = [run for run in runs if run["measured"] == measured]
        summary["measured" if measured else "unmeasured"] = {
            "on_time_median": round(statistics.median(r["on_time"] for r in mine), 4),
            "on_time_min": round(min(r["on_time"] for r in mine), 4),
            "episodes_stored": sum(r["episodes_stored"] for r in mine),
            "with_metrics": sum(r["with_metrics"] for r in mine),
        }
    result = {"episodes_per_run": episodes, "repeats": repeats, "runs": runs, "summary": summary}
    if json_out is not None:
        json_out.write_text(json.dumps(result, indent=2))
    console.print_json(json.dumps(summary))


if __name__ == "__main__":
    app()
