"""Sessions relayed through a real TURN server (coturn) with relay-only ICE, from the Python
client and from Chromium: the coordinator issues each session its own time-limited TURN
credentials (the TURN REST API scheme) and hands them over as full RTCIceServer objects."""

from __future__ import annotations

import asyncio
import base64
import hashlib
import hmac
import time

import httpx
import pytest

from crowdteleop.client.connection import IceOptions, TeleopClient
from tests.fixtures.browser import browser_context, require_chromium, wait_js
from tests.fixtures.coord import ADMIN, Worker, auth, coord_server
from tests.fixtures.turn import turn_server

pytestmark = pytest.mark.slow

SELECTED_PAIR = """async () => {
  const stats = await crowdteleop.connection.pc.getStats();
  let pair = null;
  stats.forEach((s) => {
    if (s.type === "candidate-pair" && s.nominated && s.state === "succeeded") pair = s;
  });
  return pair && stats.get(pair.localCandidateId).candidateType;
}"""


def coord_settings(turn) -> dict:
    return {
        "capacity": 1,
        "turn": {"urls": [turn.url], "secret": turn.secret, "ttl_s": 600},
        "ice_transport_policy": "relay",
    }


def test_the_python_client_connects_through_turn_only_with_the_sessions_credentials(tmp_path):
    with (
        turn_server(tmp_path / "turn") as turn,
        coord_server(tmp_path, **coord_settings(turn)) as coord,
    ):

        async def scenario() -> dict:
            async with httpx.AsyncClient(base_url=coord.url, timeout=60) as http:
                worker = Worker(http, {"PROLIFIC_PID": "relayed1"})
                await worker.start()
                view = await worker.until("ready", 120)
                path = f"/api/admin/sessions/{worker.sid}/teleop"
                access = (await http.get(path, headers=auth(ADMIN))).json()
                client = TeleopClient(
                    access["url"],
                    access["token"],
                    role="admin",
                    admin_token=access["admin_token"],
                    ice=IceOptions(view["ice_servers"], relay_only=True),
                )
                try:
                    await client.connect()
                    await client.wait_for(lambda s: s.frames_received > 10, timeout=60)
                    offered = client.pc.localDescription.sdp
                finally:
                    await client.close()
                await worker.stop()
                return {"view": view, "offered": offered, "sid": worker.sid}

        outcome = asyncio.run(scenario())
        turn_log = turn.log()
    view = outcome["view"]
    assert view["ice_transport_policy"] == "relay"
    (server,) = view["ice_servers"]
    assert server["urls"] == [turn.url]
    expiry, name = server["username"].split(":", 1)
    assert name == outcome["sid"] and 0 < int(expiry) - time.time() <= 600
    expected = hmac.new(turn.secret.encode(), server["username"].encode(), hashlib.sha1)
    assert server["credential"] == base64.b64encode(expected.digest()).decode()
    candidates = [line for line in outcome["offered"].splitlines() if "a=candidate" in line]
    assert candidates and all(" typ relay" in line for line in candidates), candidates
    assert "ALLOCATE processed, success" in turn_log


def test_chromium_connects_through_turn_only(tmp_path):
    require_chromium()
    from playwright.async_api import async_playwright

    with (
        turn_server(tmp_path / "turn") as turn,
        coord_server(tmp_path, **coord_settings(turn)) as coord,
    ):

        async def visit() -> str:
            async with async_playwright() as playwright, browser_context(playwright) as desktop:
                page = await desktop.new_page()
                await page.goto(f"{coord.url}/join?PROLIFIC_PID=relayed2&STUDY_ID=s")
                await page.check("#consent")
                await page.click("#agree")
                await page.wait_for_url("**/teleop")
                await wait_js(page, "window.crowdteleop.ready === true", 150)
                await wait_js(page, "window.crowdteleop.connection.framesShown > 10", 30)
                return await page.evaluate(SELECTED_PAIR)

        assert asyncio.run(visit()) == "relay"
