"""A new worker's practice round in real headless Chromium, against a real coordinator and
teleop server: the page says it is practice and not recorded, counts down (the keyboard's
first command, sent as the page connects, starts the clock), skips on the button, and the
next move starts demonstration 1."""

from __future__ import annotations

import asyncio
import re

import pytest

from tests.fixtures.browser import browser_context, join_to_video, require_chromium, wait_js
from tests.fixtures.coord import coord_server

pytestmark = pytest.mark.slow

JOIN = "/join?PROLIFIC_PID=practice1&STUDY_ID=st&SESSION_ID=se"
CAMPAIGN = {"name": "study", "demos_required": 3, "time_limit_s": 600, "practice_s": 20}
TEXT = "document.getElementById('practice-text').textContent"
SHOWN = "!document.getElementById('practice').hidden"
STATUS = "crowdteleop.connection.state.status"


def test_the_page_shows_the_practice_round_and_skipping_it_leads_to_demonstration_one(
    tmp_path, screenshots
):
    require_chromium()
    from playwright.async_api import async_playwright

    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as coord:

        async def visit() -> dict:
            async with async_playwright() as playwright, browser_context(playwright) as desktop:
                page = await desktop.new_page()
                await join_to_video(page, coord.url + JOIN)
                seen: dict = {"first": await wait_js(page, f"{SHOWN} && {TEXT}", 10)}
                left_s = await page.evaluate(f"{STATUS}.practice_left_s")
                await page.keyboard.down("r")  # moving while practising
                await asyncio.sleep(0.6)
                await page.keyboard.up("r")
                await wait_js(page, f"{STATUS}.practice_left_s < {left_s - 1}", 10)
                seen["later"] = await page.evaluate(TEXT)
                seen["episode_while_practising"] = await page.evaluate(f"{STATUS}.episode")
                await page.screenshot(path=str(screenshots / "practice-round.png"))
                await page.click("#skip-practice")
                seen["done"] = await wait_js(page, f"{STATUS}.practice === 'done' && {TEXT}", 10)
                seen["skip_hidden"] = await page.evaluate(
                    "document.getElementById('skip-practice').hidden"
                )
                await page.keyboard.down("r")
                await wait_js(page, f"{STATUS}.episode === 1 && {STATUS}.state === 'running'", 10)
                await page.keyboard.up("r")
                await wait_js(page, f"!({SHOWN})", 5)
                return seen

        seen = asyncio.run(visit())

    words = re.compile(
        r"^Practice \(not recorded\): move the hand to the green ball — (\d+) s left$"
    )
    first, later = (words.match(seen[key]) for key in ("first", "later"))
    assert first and later, seen
    assert 0 < int(later[1]) < int(first[1]) <= 20
    assert seen["episode_while_practising"] == 0, "nothing is recorded while practising"
    assert seen["done"] == "Practice done: the next time you move, demonstration 1 starts"
    assert seen["skip_hidden"] is True
    assert (screenshots / "practice-round.png").stat().st_size > 5_000
