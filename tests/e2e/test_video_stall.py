"""A worker whose video stops (a frozen network, a hidden tab) must not drive blind: in
Chromium, the teleop page notices no new frame for the server's limit, says so, and the
server holds the clutch released (its status says so to every device) until the picture is
back and the device presses again. After a 2 s pause, switching to the phone, its first press
drives (the issue-34 fault: it lit its button and nothing moved); the page asks for another
press only if the picture stalled again (a loaded machine does that by itself)."""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np
import pytest

from tests.fixtures.browser import (
    browser_context,
    centre,
    join_to_video,
    phone_paired,
    require_chromium,
    touch,
    wait_js,
)
from tests.fixtures.coord import coord_server

pytestmark = pytest.mark.slow

JOIN = "/join?PROLIFIC_PID=stall1&STUDY_ID=st&SESSION_ID=se"
CAMPAIGN = {"name": "study", "demos_required": 3, "time_limit_s": 600}
BANNER = "document.getElementById('banner').textContent"
STATUS = "crowdteleop.connection.state.status"
# The stalls the page reports: a loaded machine may stall the picture again on its own.
COUNT_STALLS = """window.stalls = 0; crowdteleop.connection.addEventListener('videostall',
  (e) => { if (e.detail.stalled) window.stalls += 1; });"""


def test_a_stalled_video_releases_the_clutch_and_the_page_says_so(tmp_path, screenshots):
    require_chromium()
    from playwright.async_api import async_playwright

    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as coord:

        async def visit() -> dict:
            async with (
                async_playwright() as playwright,
                browser_context(playwright) as desktop,
                browser_context(playwright, mdns=False, mobile=True) as handset,
            ):
                page = await desktop.new_page()
                await join_to_video(page, coord.url + JOIN)
                limit_ms = await page.evaluate("crowdteleop.connection.state.hello.video_stall_ms")
                await page.evaluate(COUNT_STALLS)
                # the keyboard drives (its clutch is on by default) ...
                await page.keyboard.down("r")
                await wait_js(page, f"{STATUS}.clutch === 'driving'", 10)
                await page.keyboard.up("r")
                # ... and the picture freezes for 2 s: no new frame is presented
                await page.evaluate("document.getElementById('video').pause()")
                await wait_js(page, f"{STATUS}.video_stalled === true", 10)
                stalled = {
                    "banner": await page.evaluate(BANNER),
                    "clutch": await page.evaluate(f"{STATUS}.clutch"),
                    "gap_ms": await page.evaluate(
                        "performance.now() - crowdteleop.connection.lastFrameMs"
                    ),
                }
                await page.screenshot(path=str(screenshots / "video-stalled.png"))
                await asyncio.sleep(2.0 - stalled["gap_ms"] / 1000)  # a 2 s pause in all
                await page.evaluate("document.getElementById('video').play()")
                await wait_js(page, f"{STATUS}.video_stalled === false", 10)
                # the idle keyboard let go for a fresh press: the next key drives
                await wait_js(page, f"{STATUS}.clutch === 'released'", 10)
                resumed_banner = await page.evaluate(BANNER)
                shown = await page.evaluate("document.getElementById('banner').className")
                switched = await _phone_takes_over_and_drives(page, handset, coord.url)
                return {
                    "limit_ms": limit_ms,
                    **stalled,
                    "resumed": resumed_banner,
                    "shown": shown,
                    **switched,
                }

        seen = asyncio.run(visit())

    assert seen["limit_ms"] == 1000
    assert seen["clutch"] == "video_stalled"
    assert seen["phone_clutch"] == "driving", "the phone's first press after the switch drives"
    assert seen["presses"] <= seen["later_stalls"] + 1, "pressed again only after a new stall"
    assert seen["phone_moved"] > 0.02, seen["phone_moved"]
    assert seen["clutch_word"] == "moving", "the phone says the arm follows it"
    assert "video stopped" in seen["banner"] and "press it again" in seen["banner"]
    assert seen["gap_ms"] >= 1000
    assert "show" not in seen["shown"], "the warning goes once the picture is back"
    assert (screenshots / "video-stalled.png").stat().st_size > 5_000


async def _phone_takes_over_and_drives(page: Any, handset: Any, url: str) -> dict:
    """The worker pairs their phone (orientation + drag pads) and presses its hold button once
    while dragging up: the arm follows."""
    code = await wait_js(page, "window.crowdteleop.pairing && window.crowdteleop.pairing.code")
    phone = await handset.new_page()
    cdp = await handset.new_cdp_session(phone)
    await phone.goto(f"{url}/phone")
    await phone.fill("#code", code)
    await phone.click("#pair-form button")
    await phone_paired(phone)
    before = np.array(await page.evaluate(f"{STATUS}.end_effector"))
    clutch = await centre(phone, "#clutch")
    lift_x, lift_y = await centre(phone, "#lift")
    presses = 0
    while presses < 4:
        presses += 1
        await touch(cdp, "touchStart", [clutch])
        await wait_js(page, f"{STATUS}.controlling_device === 'phone'", 10)
        await wait_js(page, f"['driving', 'press_again'].includes({STATUS}.clutch)", 10)
        if await page.evaluate(f"{STATUS}.clutch") == "driving":
            break
        # only a stall after the first one may ask for another press, as the worker is asked
        await touch(cdp, "touchEnd", [])
        await wait_js(page, f"{STATUS}.video_stalled === false", 10)
    later_stalls = await page.evaluate("window.stalls") - 1  # after the paused video's
    await touch(cdp, "touchStart", [clutch, (lift_x, lift_y + 60)])
    for step in range(1, 13):
        await touch(cdp, "touchMove", [clutch, (lift_x, lift_y + 60 - 10 * step)])
        await asyncio.sleep(0.05)
    moved = 0.0
    for _ in range(40):  # the arm catches up with the hand within a couple of seconds
        now = np.array(await page.evaluate(f"{STATUS}.end_effector"))
        moved = float(np.linalg.norm(now - before))
        if moved > 0.02:
            break
        await asyncio.sleep(0.1)
    result = {
        "phone_clutch": await page.evaluate(f"{STATUS}.clutch"),
        "clutch_word": await phone.inner_text("#clutch-state"),
        "phone_moved": moved,
        "presses": presses,
        "later_stalls": later_stalls,
    }
    await touch(cdp, "touchEnd", [])
    return result
