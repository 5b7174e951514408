"""The admin page draws its charts (uPlot) in real headless Chromium, on a laptop and at a
phone's width: a day of sessions and episodes is written to the coordinator's database, and
each chart's canvas must show its series' colours, with its legend's names; under the
pages' Content-Security-Policy, with no violation. Saves docs/screenshots/admin-charts.png
and admin-charts-phone.png when `make screenshots` asks (tests/e2e/conftest.py)."""

from __future__ import annotations

import asyncio
import math
import random
import time
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import create_engine
from sqlalchemy.orm import Session as Transaction

from crowdteleop.coord.app import create_app
from crowdteleop.coord.db.engine import sync_url
from crowdteleop.coord.db.tables import Episode, Session, Worker
from tests.fixtures.browser import browser_context, require_chromium, wait_js
from tests.fixtures.coord import ADMIN, FakeLauncher, coord_config, served_app

pytestmark = pytest.mark.slow

CHARTS = {
    "chart-demos": ["episodes", "successful"],
    "chart-queue": ["mean waiting", "most at once"],
    "chart-wait": ["median wait (s)", "longest wait (s)"],
    "chart-live": ["mean live", "most at once"],
    "chart-latency": ["p50 (ms)", "p95 (ms)"],
    "chart-scores": ["demonstrations"],
}
CAPACITY = 4
RECORD_VIOLATIONS = """
window.violations = [];
document.addEventListener("securitypolicyviolation", (event) => {
  window.violations.push(`${event.violatedDirective} ${event.blockedURI}`);
});
"""
# Pixels of a chart's canvas in a series' colour: saturated, where axes, grid and text are grey.
COLOURED_PIXELS = """(id) => {
  const canvas = document.querySelector(`#${id} canvas`);
  const pixels = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  let coloured = 0;
  for (let i = 0; i < pixels.length; i += 4) {
    const [r, g, b, a] = [pixels[i], pixels[i + 1], pixels[i + 2], pixels[i + 3]];
    if (a > 200 && Math.max(r, g, b) - Math.min(r, g, b) > 60) coloured += 1;
  }
  return coloured;
}"""


def _a_day(now: float, seed: int = 7) -> list[Any]:
    """A day of a campaign with CAPACITY robots: workers arrive more in the afternoon, wait
    for the first free robot (or give up after 10 min), and record episodes every minute or
    so; latency rises with the load. Everything has ended a minute before `now`."""
    rng = random.Random(seed)
    rows: list[Any] = [
        Worker(id="w-day", source="anonymous", campaign="default", params={}, created_at=now - 9e4)
    ]
    free = [now - 86400.0] * CAPACITY
    arrival, number = now - 86400.0 + 600, 0
    while arrival < now - 1800:
        hour_of_day = ((arrival - now) / 3600.0) % 24
        rate_per_h = 2.0 + 9.0 * math.exp(-(((hour_of_day - 15.0) / 3.5) ** 2))
        arrival += rng.expovariate(rate_per_h / 3600.0)
        number += 1
        slot = min(range(CAPACITY), key=free.__getitem__)
        admitted: float | None = max(arrival, free[slot])
        assert admitted is not None
        if admitted - arrival > 600:  # gave up waiting
            ended, admitted = arrival + 600, None
        else:
            ended = min(admitted + rng.uniform(600, 1500), now - 60)
            free[slot] = ended
        sid = f"s-day-{number}"
        rows.append(_session(sid, arrival, admitted, ended))
        if admitted is not None:
            busy = sum(f > admitted for f in free) / CAPACITY
            rows += _episodes(rng, sid, admitted, ended, busy)
    return rows


def _session(sid: str, queued: float, admitted: float | None, ended: float) -> Session:
    return Session(
        id=sid,
        worker_id="w-day",
        campaign="default",
        state="ended",
        task="lift",
        robot="Sawyer",
        controller="ik-velocity",
        interfaces=["keyboard", "phone"],
        time_limit_s=1800.0,
        demos_required=10,
        demos_done=0,
        created_at=queued,
        queued_at=queued,
        restarts=0,
        admitted_at=admitted,
        ended_at=ended,
        ended_reason="completed" if admitted is not None else "queue_timeout",
        last_heartbeat_at=ended,
        report_token_hash=f"hash-{sid}",
    )


def _episodes(rng: random.Random, sid: str, start: float, end: float, busy: float) -> list[Episode]:
    episodes, at, number = [], start + rng.uniform(40, 90), 0
    while at < end:
        number += 1
        success = rng.random() < 0.72
        p50 = rng.gauss(38 + 30 * busy, 6)
        score = min(100.0, max(0.0, rng.gauss(68, 16))) if success else None
        episodes.append(
            Episode(
                episode_id=f"{sid}-e{number}",
                session_id=sid,
                worker_id="w-day",
                number=number,
                outcome="success" if success else rng.choice(["reset", "timeout"]),
                steps=900,
                duration_s=45.0,
                uri=f"file:///data/{sid}-{number}.hdf5",
                interface="phone",
                task="lift",
                telemetry={"latency_p50_ms": p50, "latency_p95_ms": p50 * rng.uniform(1.8, 2.8)},
                created_at=at,
                score=score if rng.random() > 0.1 else None,
            )
        )
        at += rng.uniform(50, 110)
    return episodes


def _write(database_url: str, rows: list[Any]) -> None:
    engine = create_engine(sync_url(database_url))
    try:
        with Transaction(engine) as db, db.begin():
            db.add(rows[0])
            db.flush()
            db.add_all([r for r in rows if isinstance(r, Session)])
            db.flush()
            db.add_all([r for r in rows if isinstance(r, Episode)])
    finally:
        engine.dispose()


async def _look(url: str, screenshots: Path, phone: bool) -> dict[str, Any]:
    from playwright.async_api import async_playwright

    seen: dict[str, Any] = {"errors": []}
    async with async_playwright() as playwright, browser_context(playwright, mobile=phone) as ctx:
        await ctx.add_init_script(RECORD_VIOLATIONS)
        page = await ctx.new_page()
        page.on("pageerror", lambda error: seen["errors"].append(str(error)))
        await page.set_viewport_size(
            {"width": 390, "height": 844} if phone else {"width": 1280, "height": 1080}
        )
        await page.goto(f"{url}/admin")
        await page.fill("#token", ADMIN)
        await page.click("#login button")
        await wait_js(page, "document.querySelectorAll('.chart canvas').length === 6", 30)
        await asyncio.sleep(0.5)  # the first ResizeObserver round
        seen["coloured"] = {id_: await page.evaluate(COLOURED_PIXELS, id_) for id_ in CHARTS}
        seen["legends"] = {
            id_: await page.locator(f"#{id_} .u-legend .u-label").all_inner_texts()
            for id_ in CHARTS
        }
        seen["axes"] = {
            id_: await page.locator(f"#{id_} canvas").get_attribute("aria-label") for id_ in CHARTS
        }
        seen["widths"] = await page.evaluate(
            "() => [...document.querySelectorAll('.chart canvas')]"
            ".map((c) => c.getBoundingClientRect().right)"
        )
        seen["scroll_width"] = await page.evaluate("() => document.documentElement.scrollWidth")
        seen["violations"] = await page.evaluate("window.violations")
        name = "admin-charts-phone.png" if phone else "admin-charts.png"
        if phone:
            # Past the totals: the first charts, as a phone shows them.
            await page.evaluate("document.getElementById('chart-demos').scrollIntoView()")
            await page.evaluate("window.scrollBy(0, -64)")
        await page.screenshot(path=str(screenshots / name))
    return seen


@pytest.mark.parametrize("phone", [False, True], ids=["laptop", "phone"])
def test_the_admin_page_draws_each_chart(tmp_path, screenshots, phone):
    require_chromium()
    config = coord_config(tmp_path, capacity=CAPACITY)
    app = create_app(config, FakeLauncher())
    with served_app(app, config) as url:
        _write(config.database_url, _a_day(time.time()))
        seen = asyncio.run(_look(url, screenshots, phone))
    assert seen["errors"] == [] and seen["violations"] == [], seen
    for chart, names in CHARTS.items():
        assert seen["coloured"][chart] > 200, (chart, seen["coloured"])
        assert seen["legends"][chart] == names, (chart, seen["legends"])
    assert seen["axes"] == {
        "chart-demos": "episodes per hour against time (local)",
        "chart-queue": "workers waiting against time (local)",
        "chart-wait": "wait (s) against time (local)",
        "chart-live": "sessions against time (local)",
        "chart-latency": "latency (ms) against time (local)",
        "chart-scores": "demonstrations against quality score (0-100)",
    }, seen["axes"]
    viewport = 390 if phone else 1280
    assert max(seen["widths"]) <= viewport and seen["scroll_width"] <= viewport, seen
