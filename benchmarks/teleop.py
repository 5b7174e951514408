"""What live teleop sessions cost and how they feel, measured end to end over loopback WebRTC.

For each session count N: N teleop server processes (`crowdteleop teleop-server`), each driven
by a scripted bot in its own client process exactly as a browser would (WebRTC video + data
channels; privileged object poses over the admin channel). Client 0 decodes its video and
measures control-to-photon latency; the others count received frames without decoding
(`crowdteleop.client.counting`), as a load generator should. Servers and clients share this
machine, so their CPU is reported apart.

    .venv/bin/python benchmarks/teleop.py                      # N = 1, 2, 4, 6, 8
    .venv/bin/python benchmarks/teleop.py --sessions 1 --seconds 20 --json out/bench-teleop.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.fixtures.ready import wait_ready

from crowdteleop.coord.fleet.launcher import teleop_server_argv

TOKEN = "bench-token-1"
ADMIN = "bench-admin-1"
ON_TIME = 0.95
MIN_FPS = 18.0
STREAM_HZ = 30.0  # the bot streams its pose as the phone page does (web/static/phone.js)


# --- the client process -------------------------------------------------------------------


async def _circle(client, hz: float) -> None:
    """A worker's hand tracing a 6 cm circle (2 s period) with the clutch held: the arm and the
    picture move all the time, and nothing privileged is needed (no admin channel)."""
    import math

    started = time.monotonic()
    while True:
        phase = 2 * math.pi * (time.monotonic() - started) / 2.0
        radius = 0.03 * min(1.0, (time.monotonic() - started) / 1.0)
        position = (0.0, radius * math.cos(phase) - radius, radius * math.sin(phase))
        client.send_pose(position, (0.0, 0.0, 0.0, 1.0), True, False)
        await asyncio.sleep(1.0 / hz)


async def _client(url: str, decode: bool, warmup: float, seconds: float, circle: bool) -> dict:
    if not decode:
        from crowdteleop.client.counting import disable_decoding

        disable_decoding()
    from crowdteleop.client.bot import Bot
    from crowdteleop.client.connection import TeleopClient

    if circle:
        client = TeleopClient(url, TOKEN, role="worker", device="phone")
        await client.connect()
        streaming = asyncio.create_task(_circle(client, STREAM_HZ))
    else:
        client = TeleopClient(url, TOKEN, role="admin", admin_token=ADMIN)
        bot = Bot(client, seed=os.getpid())
        await client.connect()
        streaming = asyncio.create_task(bot.stream(STREAM_HZ))
    await asyncio.sleep(warmup)
    me = psutil.Process()
    cpu0, frames0, lat0 = (
        me.cpu_times(),
        client.state.frames_received,
        len(client.latency.samples_ms),
    )
    started = time.monotonic()
    while time.monotonic() - started < seconds:
        await asyncio.sleep(1.0)
        client.report_latency()
    wall = time.monotonic() - started
    cpu1 = me.cpu_times()
    latency = client.latency.samples_ms[lat0:]
    result = {
        "fps": (client.state.frames_received - frames0) / wall,
        "cpu_s": (cpu1.user + cpu1.system) - (cpu0.user + cpu0.system),
        "wall_s": wall,
        "latency_ms": latency,
        "episodes": [e.outcome for e in client.state.episodes],
    }
    streaming.cancel()
    await client.close()
    return result


# --- the orchestrator ---------------------------------------------------------------------


def _start_server(directory: Path, index: int, task: str) -> subprocess.Popen:
    config = {
        "session_id": f"bench{index}",
        "token": TOKEN,
        "admin_token": ADMIN,
        "sim": {"task": task},
        "recording": {"directory": str(directory / f"rec{index}"), "keep_failed": False},
    }
    path = directory / f"teleop{index}.json"
    path.write_text(json.dumps(config))
    process = subprocess.Popen(
        teleop_server_argv(path),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    return process


async def _telemetry(url: str) -> dict:
    import aiohttp

    headers = {"Authorization": f"Bearer {ADMIN}"}
    async with (
        aiohttp.ClientSession() as http,
        http.get(f"{url}/telemetry", headers=headers) as response,
    ):
        return await response.json()


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q / 100 * (len(ordered) - 1)))]


def measure(n: int, task: str, warmup: float, seconds: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-teleop-") as tmp:
        directory = Path(tmp)
        servers = [_start_server(directory, i, task) for i in range(n)]
        clients: list[subprocess.Popen] = []
        try:
            urls = [wait_ready(process, None, 180.0, "a teleop server") for process in servers]
            for i, url in enumerate(urls):
                clients.append(
                    subprocess.Popen(
                        [
                            sys.executable,
                            __file__,
                            "--client",
                            url,
                            "--decode" if i == 0 else "--count",
                            "--warmup",
                            str(warmup),
                            "--seconds",
                            str(seconds),
                        ],
                        stdout=subprocess.PIPE,
                        stderr=subprocess.DEVNULL,
                        text=True,
                    )
                )
            time.sleep(warmup + 2.0)  # clients connect (~1-2 s) and warm up
            procs = [psutil.Process(p.pid) for p in servers]
            before = [asyncio.run(_telemetry(u)) for u in urls]
            cpu0 = [p.cpu_times() for p in procs]
            t0 = time.monotonic()
            time.sleep(seconds - 3.0)
            wall = time.monotonic() - t0
            cpu1 = [p.cpu_times() for p in procs]
            after = [asyncio.run(_telemetry(u)) for u in urls]
            results = []
            for client in clients:
                out, _ = client.communicate(timeout=seconds + warmup + 120)
                line = next(x for x in out.splitlines() if x.startswith("BENCH-CLIENT "))
                results.append(json.loads(line.removeprefix("BENCH-CLIENT ")))
        finally:
            for process in clients + servers:
                if process.poll() is None:
                    process.terminate()
            for process in clients + servers:
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
    on_time = []  # ticks that started on time / control slots (skipped slots count as missed)
    for b, a in zip(before, after, strict=True):
        ticks = a["ticks"] - b["ticks"]
        late, skipped = a["late"] - b["late"], a["skipped"] - b["skipped"]
        on_time.append((ticks - late) / (ticks + skipped) if ticks else 0.0)
    server_cpu = [
        ((c1.user + c1.system) - (c0.user + c0.system)) / wall
        for c0, c1 in zip(cpu0, cpu1, strict=True)
    ]
    fps = [r["fps"] for r in results]
    latency = results[0]["latency_ms"]
    ok = min(on_time) >= ON_TIME and min(fps) >= MIN_FPS
    return {
        "sessions": n,
        "ok": ok,
        "on_time_min": min(on_time),
        "fps_min": min(fps),
        "fps_decoded": fps[0],
        "server_cpu_per_session": statistics.median(server_cpu),
        "client_cpu_per_session": statistics.median(r["cpu_s"] / r["wall_s"] for r in results),
        "latency_p50_ms": _percentile(latency, 50),
        "latency_p95_ms": _percentile(latency, 95),
        "latency_samples": len(latency),
        "episodes": sum(len(r["episodes"]) for r in results),
        "successes": sum(r["episodes"].count("success") for r in results),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", default="1,2,4,6,8")
    parser.add_argument("--task", default="lift")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--warmup", type=float, default=6.0)
    parser.add_argument("--repeats", type=int, default=1, help="runs of N=1 for latency medians")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--client")
    parser.add_argument("--decode", action="store_true")
    parser.add_argument("--count", action="store_true")
    parser.add_argument("--circle", action="store_true", help="client: a worker tracing a circle")
    args = parser.parse_args()
    if args.client:
        result = asyncio.run(
            _client(args.client, args.decode, args.warmup, args.seconds, args.circle)
        )
        print("BENCH-CLIENT " + json.dumps(result), flush=True)
        return

    from rich.console import Console
    from rich.table import Table

    console = Console()
    console.print(
        f"machine: {psutil.cpu_count(logical=False)} physical / {psutil.cpu_count()} logical "
        f"cores, load {os.getloadavg()[0]:.2f}; task {args.task}, 20 Hz, 320x240 VP8"
    )
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from learning import robosuite_lift_step_ms

    step_ms = robosuite_lift_step_ms()  # these VMs differ ~2x from day to day: state this one's
    console.print(f"plain robosuite Lift step: {step_ms:.2f} ms")
    rows = []
    for n in [int(x) for x in args.sessions.split(",")]:
        for _ in range(args.repeats if n == 1 else 1):
            console.print(f"measuring {n} session(s)...")
            rows.append(measure(n, args.task, args.warmup, args.seconds))
    table = Table(
        "sessions",
        "ok",
        "on-time min %",
        "fps min",
        "fps decoded",
        "server CPU %/session",
        "client CPU %/session",
        "latency p50 / p95 ms",
        "episodes (success)",
    )
    for r in rows:
        table.add_row(
            str(r["sessions"]),
            "yes" if r["ok"] else "no",
            f"{100 * r['on_time_min']:.1f}",
            f"{r['fps_min']:.1f}",
            f"{r['fps_decoded']:.1f}",
            f"{100 * r['server_cpu_per_session']:.1f}",
            f"{100 * r['client_cpu_per_session']:.1f}",
            f"{r['latency_p50_ms']:.0f} / {r['latency_p95_ms']:.0f}",
            f"{r['episodes']} ({r['successes']})",
        )
    console.print(table)
    best = max((r["sessions"] for r in rows if r["ok"]), default=0)
    console.print(
        f"largest session count at full rate: {best}; normalized to a 3.5 ms robosuite step: "
        f"{best} x {step_ms:.2f} / 3.5 = {best * step_ms / 3.5:.1f}"
    )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        document = {"rows": rows, "options": vars(args), "robosuite_lift_step_ms": step_ms}
        args.json.write_text(json.dumps(document, indent=2, default=str))


if __name__ == "__main__":
    main()
