"""A phone page opened over plain http on a LAN: the browser switches its motion sensors and
WebXR off without a word, so the page says so, and what to do; on a secure origin it does not."""

from __future__ import annotations

import asyncio
from urllib.parse import urlsplit

import pytest

from crowdteleop.coord.app import create_app
from tests.fixtures.browser import browser_context, require_chromium, wait_js
from tests.fixtures.coord import FakeLauncher, coord_config, served_app

pytestmark = pytest.mark.slow

BANNER = "document.getElementById('banner').textContent"
# A name that is not localhost reaches our loopback server: an insecure origin, as a LAN
# address over http is for a phone.
LAN_NAME = "phone-lan.test"


def test_the_phone_page_says_when_it_is_not_secure_and_what_to_do(tmp_path):
    require_chromium()
    from playwright.async_api import async_playwright

    config = coord_config(tmp_path)
    with served_app(create_app(config, FakeLauncher()), config) as url:
        port = urlsplit(url).port
        rules = f"--host-resolver-rules=MAP {LAN_NAME} 127.0.0.1"

        async def visit() -> dict:
            async with (
                async_playwright() as playwright,
                browser_context(playwright, mobile=True, args=(rules,)) as phone,
            ):
                page = await phone.new_page()
                await page.goto(f"http://{LAN_NAME}:{port}/phone")
                told = await wait_js(page, f"{BANNER}.includes('not secure') && {BANNER}", 20)
                insecure = await page.evaluate("crowdteleop.secure")
                await page.goto(f"{url}/phone")  # 127.0.0.1: a secure context
                await wait_js(page, "document.getElementById('pair-form') !== null", 20)
                await asyncio.sleep(0.5)
                return {
                    "told": told,
                    "insecure": insecure,
                    "secure": await page.evaluate("crowdteleop.secure"),
                    "banner": await page.evaluate(BANNER),
                }

        outcome = asyncio.run(visit())
    assert outcome["insecure"] is False and "over HTTPS" in outcome["told"]
    assert "--https" in outcome["told"], "it says what the organiser has to do"
    assert outcome["secure"] is True and "not secure" not in outcome["banner"]
