"""The pages run under the coordinator's Content-Security-Policy, in real headless Chromium:
each page's modules load and do their work (fetches, tables, pairing), the browser reports no
violation, and script injected into a page is refused. The teleop servers are the fake
launcher's: no simulator runs, so the offers are answered but no robot connects."""

from __future__ import annotations

import asyncio
from typing import Any

import httpx
import pytest

from crowdteleop.coord.app import create_app
from tests.fixtures.browser import browser_context, require_chromium, wait_js
from tests.fixtures.coord import ADMIN, FakeLauncher, Worker, auth, coord_config, served_app

pytestmark = pytest.mark.slow

RECORD_VIOLATIONS = """
window.violations = [];
document.addEventListener("securitypolicyviolation", (event) => {
  window.violations.push(`${event.violatedDirective} ${event.blockedURI}`);
});
"""
BANNER = "document.getElementById('banner').textContent"


async def _violations(page: Any) -> list[str]:
    return await page.evaluate("window.violations")


def test_every_page_works_under_the_policy_and_injected_script_is_refused(tmp_path):
    require_chromium()
    from playwright.async_api import async_playwright

    launcher = FakeLauncher()
    app = create_app(coord_config(tmp_path, capacity=2), launcher)

    async def visit(url: str) -> dict[str, Any]:
        seen: dict[str, Any] = {"console": []}
        async with async_playwright() as playwright, browser_context(playwright) as context:
            await context.add_init_script(RECORD_VIOLATIONS)
            context.on("console", lambda m: seen["console"].append(f"{m.type}: {m.text}"))

            # The join page's module runs; agreeing joins (a fetch) and moves on.
            page = await context.new_page()
            await page.goto(f"{url}/join?PROLIFIC_PID=csp-worker&STUDY_ID=s&SESSION_ID=v")
            # It loads the study's figures (a fetch) before anyone agrees.
            await wait_js(page, "document.getElementById('required').textContent !== '–'", 20)
            seen["join_text"] = await page.inner_text("main")
            seen["join"] = await _violations(page)
            await page.check("#consent")
            await page.click("#agree")
            await page.wait_for_url("**/teleop")

            # The teleop page builds its legend, loads the protocol, gets a session and sends
            # its WebRTC offer (the fake server's answer is no real SDP: the page says so).
            await wait_js(page, "document.querySelectorAll('#legend kbd').length > 0", 20)
            await wait_js(page, f"{BANNER}.includes('Could not connect')", 40)
            seen["qr"] = await page.evaluate(
                """() => new Promise((resolve) => {
                    const img = document.getElementById('qr');
                    img.onload = () => resolve(img.naturalWidth);
                    img.onerror = () => resolve(0);
                    img.src = '/qr.svg?text=' + encodeURIComponent(location.origin + '/phone');
                })"""
            )
            seen["teleop"] = await _violations(page)

            # The phone page pairs with a code another worker's ready session shows, and
            # offers to that session's server.
            async with httpx.AsyncClient(base_url=url) as http:
                worker = Worker(http, {})
                await worker.start()
                await worker.until("ready", 20)
                await worker.stop()
                path = f"/api/sessions/{worker.sid}/pairing"
                code = (await http.post(path, headers=auth(worker.token))).json()["code"]
            phone = await context.new_page()
            await phone.goto(f"{url}/phone?code={code}")
            await wait_js(phone, f"{BANNER}.length > 0", 20)
            seen["phone_offers"] = [o["role"] for o in launcher.handles[worker.sid].offers]
            seen["phone"] = await _violations(phone)

            # The admin page fills its tables with innerHTML; an injected handler is refused.
            admin = await context.new_page()
            await admin.goto(f"{url}/admin")
            await admin.fill("#token", ADMIN)
            await admin.click("#login button")
            await wait_js(admin, "document.querySelectorAll('#sessions tr').length > 1", 20)
            seen["admin"] = await _violations(admin)
            await admin.evaluate(
                """document.body.insertAdjacentHTML('beforeend',
                   '<img src="/static/style.css" onerror="window.injected = true">')"""
            )
            await asyncio.sleep(0.5)
            seen["injected"] = await admin.evaluate("window.injected === true")
            seen["refused"] = await _violations(admin)
        return seen

    with served_app(app) as url:
        seen = asyncio.run(visit(url))
    for name in ("join", "teleop", "phone", "admin"):
        assert seen[name] == [], (name, seen[name])
    # The join page says what the study asks before anyone agrees (its campaign's figures).
    assert "Needed: 3 successful demonstrations, at most 30 min" in seen["join_text"]
    assert seen["phone_offers"] == ["phone"], "the phone page's offer reached its server"
    assert seen["qr"] > 0, "the QR code (an image of our own origin) loads"
    assert not seen["injected"], "script-src 'self' refuses an inline event handler"
    assert any(v.startswith("script-src") for v in seen["refused"]), seen["refused"]
    blocked = [m for m in seen["console"] if "Content Security Policy" in m]
    assert len(blocked) == 1 and "inline event handler" in blocked[0], blocked
