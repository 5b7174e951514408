"""Time from a worker clicking Start to the first video frame on their screen.

A real coordinator (`crowdteleop serve`, capacity 1) and real headless Chromium (Debian's
/usr/bin/chromium through Playwright): each run is a new worker with a fresh browser profile who
opens the join link, ticks the consent box and clicks Start; the clock stops when the teleop
page presents its first video frame (requestVideoFrameCallback). Then the worker leaves and the
next run waits until the coordinator is idle again (and, with spares, until a spare is warm).

    .venv/bin/python benchmarks/web.py                     # 10 warm runs (spares) + 3 cold runs
    .venv/bin/python benchmarks/web.py --warm-runs 20 --cold-runs 0 --json out/bench-web.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.fixtures.browser import browser_context
from tests.fixtures.coord import coord_server

TARGET_P95_S = 3.0


async def _idle(url: str, spares: int, timeout: float = 180) -> None:
    deadline = time.monotonic() + timeout
    async with httpx.AsyncClient(base_url=url, timeout=10) as http:
        while True:
            health = (await http.get("/health")).json()
            if health["busy"] == 0 and health.get("spares", 0) >= spares:
                return
            if time.monotonic() > deadline:
                raise TimeoutError(f"coordinator not idle: {health}")
            await asyncio.sleep(0.5)


async def _one_run(playwright, url: str, index: int) -> float:
    async with browser_context(playwright) as context:
        page = await context.new_page()
        await page.goto(f"{url}/join?PROLIFIC_PID=bench{index}&STUDY_ID=b&SESSION_ID=r{index}")
        await page.check("#consent")
        clicked_ms = time.time() * 1000
        await page.click("#agree")
        await page.wait_for_function(  # a function, not a bare expression: the CSP forbids eval
            "() => window.crowdteleop && window.crowdteleop.connection"
            " && window.crowdteleop.connection.firstFrameAt",
            timeout=180_000,
        )
        first_ms = await page.evaluate("window.crowdteleop.connection.firstFrameAt")
        timeline = await page.evaluate("window.crowdteleop.timeline")
        await page.close()  # the page's beacon ends the session
    marks = {k: round((v - clicked_ms) / 1000, 3) for k, v in timeline.items()}
    print(f"    marks after the click (s): {marks}", flush=True)
    return (first_ms - clicked_ms) / 1000


async def _runs(url: str, runs: int, spares: int) -> list[float]:
    from playwright.async_api import async_playwright

    seconds = []
    async with async_playwright() as playwright:
        for index in range(runs):
            await _idle(url, spares)
            seconds.append(await _one_run(playwright, url, index))
            print(f"  run {index + 1}/{runs}: {seconds[-1]:.2f} s", flush=True)
    return seconds


def measure(runs: int, spares: int) -> list[float]:
    if runs == 0:
        return []
    with tempfile.TemporaryDirectory(prefix="bench-web-") as tmp:
        config = {"capacity": 1, "spare_servers": spares}
        with coord_server(Path(tmp), **config) as server:
            return asyncio.run(_runs(server.url, runs, spares))


def _summary(values: list[float]) -> dict:
    if not values:
        return {}
    ordered = sorted(values)
    p95 = ordered[min(len(ordered) - 1, round(0.95 * (len(ordered) - 1)))]
    return {
        "runs": len(values),
        "median_s": statistics.median(values),
        "p95_s": p95,
        "max_s": max(values),
        "values": values,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--warm-runs", type=int, default=10, help="with one warm spare server")
    parser.add_argument("--cold-runs", type=int, default=3, help="without spares")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    print("warm (spare_servers=1):")
    warm = _summary(measure(args.warm_runs, spares=1))
    print("cold (spare_servers=0):")
    cold = _summary(measure(args.cold_runs, spares=0))
    for name, summary in (("warm", warm), ("cold", cold)):
        if summary:
            verdict = "met" if summary["p95_s"] <= TARGET_P95_S else "not met"
            print(
                f"{name}: median {summary['median_s']:.2f} s, p95 {summary['p95_s']:.2f} s, "
                f"max {summary['max_s']:.2f} s over {summary['runs']} runs "
                f"(target p95 <= {TARGET_P95_S} s: {verdict})"
            )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"warm": warm, "cold": cold}, indent=2))


if __name__ == "__main__":
    main()
