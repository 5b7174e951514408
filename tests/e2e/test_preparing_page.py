"""While a worker's robot is being prepared, in real headless Chromium against a real
coordinator and teleop server (no warm spare: a cold start): the join page says how long a
robot takes before Start, the teleop page says "Preparing your robot… about N s" with a
progress bar, and both go once the video shows."""

from __future__ import annotations

import asyncio
import re

import pytest

from tests.fixtures.browser import browser_context, require_chromium, wait_js
from tests.fixtures.coord import coord_server

pytestmark = pytest.mark.slow

JOIN = "/join?PROLIFIC_PID=prepared1&STUDY_ID=st&SESSION_ID=se"
BAR_SHOWN = "!document.getElementById('preparing').hidden"
BANNER = "document.getElementById('banner').textContent"


def test_the_pages_say_a_robot_is_being_prepared_and_how_long(tmp_path, screenshots):
    require_chromium()
    from playwright.async_api import async_playwright

    with coord_server(tmp_path, capacity=1, spare_servers=0) as coord:

        async def visit() -> dict:
            async with async_playwright() as playwright, browser_context(playwright) as desktop:
                page = await desktop.new_page()
                await page.goto(coord.url + JOIN)
                robot = "document.getElementById('robot').textContent"
                seen: dict = {"join": await wait_js(page, robot, 10)}
                seen["join_bar"] = await page.evaluate(BAR_SHOWN)
                await page.check("#consent")
                await page.click("#agree")
                await page.wait_for_url("**/teleop")
                preparing = f"{BAR_SHOWN} && {BANNER}.startsWith('Preparing') && {BANNER}"
                seen["teleop"] = await wait_js(page, preparing, 10)
                await page.screenshot(path=str(screenshots / "preparing.png"))
                await wait_js(page, "crowdteleop.connection.framesShown > 3", 60)
                seen["teleop_bar_after"] = await page.evaluate(BAR_SHOWN)
                shown = "document.getElementById('banner').classList.contains('show')"
                seen["banner_after"] = await page.evaluate(f"{shown} ? {BANNER} : ''")
                return seen

        seen = asyncio.run(visit())

    assert re.fullmatch(r"Preparing your robot… about \d+ s", seen["join"]), seen
    assert seen["join_bar"] is True, "the join page shows a start's progress"
    assert re.fullmatch(r"Preparing your robot… about \d+ s", seen["teleop"]), seen
    assert seen["teleop_bar_after"] is False, "the bar goes with the robot ready"
    assert not seen["banner_after"].startswith("Preparing"), seen
    assert (screenshots / "preparing.png").stat().st_size > 5_000
