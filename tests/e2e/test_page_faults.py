"""What a worker sees in Chromium when things go wrong: their robot's server dies (the page
reconnects to the new robot by itself, the count kept), and another browser joins with their
study id (it must choose to take over; the first page is told)."""

from __future__ import annotations

import asyncio
import os
import signal
from typing import Any

import httpx
import pytest

from tests.fixtures.browser import browser_context, require_chromium, wait_js
from tests.fixtures.coord import ADMIN, coord_server

pytestmark = pytest.mark.slow

JOIN = "/join?PROLIFIC_PID=faulty1&STUDY_ID=st&SESSION_ID=se"
CAMPAIGN = {"name": "study", "demos_required": 3, "time_limit_s": 600}
BANNER = "document.getElementById('banner').textContent"


async def _agree(context: Any, url: str) -> Any:
    page = await context.new_page()
    await page.goto(url + JOIN)
    await page.check("#consent")
    await page.click("#agree")
    return page


def _teleop_pid(url: str) -> int:
    headers = {"Authorization": f"Bearer {ADMIN}"}
    overview = httpx.get(f"{url}/api/admin/overview", headers=headers, timeout=10).json()
    return next(s["pid"] for s in overview["teleop_servers"] if s["pid"])


def test_the_page_reconnects_by_itself_when_its_robots_server_dies(tmp_path, screenshots):
    require_chromium()
    from playwright.async_api import async_playwright

    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as coord:

        async def visit() -> dict:
            async with async_playwright() as playwright, browser_context(playwright) as desktop:
                page = await _agree(desktop, coord.url)
                await page.wait_for_url("**/teleop")
                await wait_js(page, "window.crowdteleop.ready === true", 150)
                await wait_js(page, "window.crowdteleop.connection.framesShown > 10", 30)
                first_ready = await page.evaluate("crowdteleop.readyAt")
                os.kill(_teleop_pid(coord.url), signal.SIGKILL)
                # While the new robot starts the page says why ("...: a new robot is on its
                # way"), unless it is ready before the page's next heartbeat; either way it
                # reconnects by itself and says so.
                await wait_js(
                    page,
                    f"crowdteleop.ready && crowdteleop.readyAt !== {first_ready}"
                    " && crowdteleop.connection.framesShown > 10",
                    150,
                )
                told = await page.evaluate(BANNER)
                await page.screenshot(path=str(screenshots / "teleop-page-new-robot.png"))
                return {"told": told, "view": await page.evaluate("crowdteleop.view")}

        outcome = asyncio.run(visit())
    assert "connected to a new robot" in outcome["told"]
    assert outcome["view"]["state"] == "ready" and outcome["view"]["ended_reason"] is None


def test_a_second_browser_must_take_over_and_the_first_is_told(tmp_path, screenshots):
    require_chromium()
    from playwright.async_api import async_playwright

    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as coord:

        async def visit() -> dict:
            async with (
                async_playwright() as playwright,
                browser_context(playwright) as first,
                browser_context(playwright) as second,
            ):
                page = await _agree(first, coord.url)
                await page.wait_for_url("**/teleop")
                await wait_js(page, "window.crowdteleop.ready === true", 150)
                sid = await page.evaluate("crowdteleop.view.session_id")

                other = await _agree(second, coord.url)
                refused = await wait_js(other, f"{BANNER}.includes('another browser') && {BANNER}")
                take_over_shown = await other.is_visible("#take-over")
                await other.screenshot(path=str(screenshots / "join-page-take-over.png"))
                await other.click("#take-over")
                await other.wait_for_url("**/teleop")
                await wait_js(other, "window.crowdteleop.ready === true", 60)
                moved = await other.evaluate("crowdteleop.view.session_id")

                told = await wait_js(page, f"{BANNER}.includes('taken over') && {BANNER}", 20)
                ended = await page.evaluate("crowdteleop.ended")
                await page.screenshot(path=str(screenshots / "teleop-page-taken-over.png"))
                return {
                    "sid": sid,
                    "moved": moved,
                    "refused": refused,
                    "shown": take_over_shown,
                    "told": told,
                    "ended": ended,
                }

        outcome = asyncio.run(visit())
    assert "another browser" in outcome["refused"] and outcome["shown"]
    assert outcome["moved"] == outcome["sid"], "the same session continues in the new browser"
    assert "taken over in another browser" in outcome["told"] and outcome["ended"]
