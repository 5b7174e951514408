"""A worker whose video stops (a frozen network, a hidden tab) must not drive blind: in
Chromium, the teleop page notices no new frame for the server's limit, says so, and the
server holds the clutch released (its status says so to every device) until the picture is
back and the device presses again."""

from __future__ import annotations

import asyncio

import pytest

from tests.fixtures.browser import browser_context, join_to_video, require_chromium, wait_js
from tests.fixtures.coord import coord_server

pytestmark = pytest.mark.slow

JOIN = "/join?PROLIFIC_PID=stall1&STUDY_ID=st&SESSION_ID=se"
CAMPAIGN = {"name": "study", "demos_required": 3, "time_limit_s": 600}
BANNER = "document.getElementById('banner').textContent"
STATUS = "crowdteleop.connection.state.status"


def test_a_stalled_video_releases_the_clutch_and_the_page_says_so(tmp_path, screenshots):
    require_chromium()
    from playwright.async_api import async_playwright

    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as coord:

        async def visit() -> dict:
            async with async_playwright() as playwright, browser_context(playwright) as desktop:
                page = await desktop.new_page()
                await join_to_video(page, coord.url + JOIN)
                limit_ms = await page.evaluate("crowdteleop.connection.state.hello.video_stall_ms")
                # the picture freezes: no new frame is presented
                await page.evaluate("document.getElementById('video').pause()")
                await wait_js(page, f"{STATUS}.video_stalled === true", 10)
                stalled = {
                    "banner": await page.evaluate(BANNER),
                    "gap_ms": await page.evaluate(
                        "performance.now() - crowdteleop.connection.lastFrameMs"
                    ),
                }
                await page.screenshot(path=str(screenshots / "video-stalled.png"))
                await page.evaluate("document.getElementById('video').play()")
                await wait_js(page, f"{STATUS}.video_stalled === false", 10)
                await asyncio.sleep(0.5)
                resumed_banner = await page.evaluate(BANNER)
                shown = await page.evaluate("document.getElementById('banner').className")
                return {"limit_ms": limit_ms, **stalled, "resumed": resumed_banner, "shown": shown}

        seen = asyncio.run(visit())

    assert seen["limit_ms"] == 1000
    assert "video stopped" in seen["banner"] and "press it again" in seen["banner"]
    assert seen["gap_ms"] >= 1000
    assert "show" not in seen["shown"], "the warning goes once the picture is back"
    assert (screenshots / "video-stalled.png").stat().st_size > 5_000
