"""The phone's AR mode in real headless Chromium with an emulated WebXR phone (Meta's IWER,
vendored from npm), against a real coordinator, teleop server and WebRTC.

IWER emulates the WebXR runtime, not Chrome's DOM overlay, so the test adds what Chrome on
Android does with `domOverlay`: the overlay root is shown above the XR layer, a touch in it
first fires `beforexrselect` at the touched element, and unless a handler cancels it the
session fires `selectstart` / `selectend`. Tracking loss is the runtime returning no viewer
pose."""

from __future__ import annotations

import asyncio
import math
from typing import Any

import numpy as np
import pytest

from tests.fixtures.browser import (
    browser_context,
    centre,
    phone_paired,
    require_chromium,
    touch,
    wait_js,
)
from tests.fixtures.coord import coord_server
from tests.fixtures.phone_page import (
    quat_angle_deg,
    relative_turn,
    robot_for_a_phone,
    sample_hand,
)
from tests.fixtures.xr_phone import EMULATED_PHONE, IWER

pytestmark = pytest.mark.slow

CAMPAIGN = {
    "name": "xr",
    "title": "Phone AR",
    "instructions": "Lift the cube.",
    "demos_required": 5,
    "time_limit_s": 600,
}
STEPS = 60  # the path, at 30 poses a second
PATH_ROBOT_M = np.array([0.10, 0.05, 0.05])  # forward, left, up: the hand should do the same
PATH_YAW_DEG = 20.0


async def _carry(phone: Any, fraction_to_pose: Any) -> None:
    """Carry the emulated phone along the path, 30 poses a second."""
    for step in range(STEPS + 1):
        x, y, z, qx, qy, qz, qw = fraction_to_pose(0.5 - 0.5 * math.cos(math.pi * step / STEPS))
        await phone.evaluate(
            "([x, y, z, qx, qy, qz, qw]) => { emulatedPhone.position.set(x, y, z);"
            " emulatedPhone.quaternion.set(qx, qy, qz, qw); }",
            [x, y, z, qx, qy, qz, qw],
        )
        await asyncio.sleep(1 / 30)


def _xr_pose(fraction: float) -> tuple[float, ...]:
    """The path in WebXR's frame (y up, -z forward): 10 cm forward, 5 left, 5 up, 20° left."""
    forward, left, up = PATH_ROBOT_M * fraction
    half = math.radians(PATH_YAW_DEG) * fraction / 2
    return (-left, 1.6 + up, -forward, 0.0, math.sin(half), 0.0, math.cos(half))


def test_the_phone_in_ar_drives_the_hand_along_its_path_and_lets_go_when_tracking_does(
    tmp_path, screenshots
):
    require_chromium()
    from playwright.async_api import async_playwright

    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as coord:

        async def visit() -> dict[str, Any]:
            results: dict[str, Any] = {}
            async with (
                robot_for_a_phone(coord.url, "xr") as (phone_link, hand),
                async_playwright() as playwright,
                browser_context(
                    playwright, mobile=True, args=("--enable-unsafe-swiftshader",)
                ) as handset,
            ):
                await handset.add_init_script(path=str(IWER))
                await handset.add_init_script(EMULATED_PHONE)
                phone = await handset.new_page()
                cdp = await handset.new_cdp_session(phone)
                await phone.goto(phone_link)
                await phone_paired(phone)
                results["why"] = await wait_js(
                    phone, "document.getElementById('motion-why').textContent", 10
                )
                await phone.click("#start-ar")
                await wait_js(phone, "crowdteleop.tracking === 'tracking'", 20)
                results["requests"] = await phone.evaluate("xrRequests")
                results["motion"] = await phone.inner_text("#motion")
                await phone.screenshot(path=str(screenshots / "phone-ar.png"))

                # The clutch is pressed through the overlay: it engages, and is not also a select.
                clutch = await centre(phone, "#clutch")
                await touch(cdp, "touchStart", [clutch])
                await wait_js(phone, "crowdteleop.engaged === true", 10)
                await wait_js(
                    phone, "crowdteleop.connection.state.status.controlling_device === 'phone'", 10
                )
                await asyncio.sleep(1.0)
                before = hand["now"].copy()
                samples = []
                sampler = asyncio.create_task(sample_hand(hand, samples))
                await _carry(phone, _xr_pose)
                await asyncio.sleep(2.0)
                sampler.cancel()
                after = hand["now"].copy()
                results["moved"] = after[:3] - before[:3]
                results["turn"] = relative_turn(after[3:], before[3:])
                results["path"] = [s[:3] - before[:3] for s in samples]
                await touch(cdp, "touchEnd", [])
                await wait_js(phone, "crowdteleop.engaged === false", 10)

                # A touch in the overlay away from the controls is a select: hold anywhere.
                pad = await centre(phone, "#pad")
                await touch(cdp, "touchStart", [pad])
                results["select_engages"] = await wait_js(phone, "crowdteleop.engaged", 10)
                await touch(cdp, "touchEnd", [])
                await wait_js(phone, "crowdteleop.engaged === false", 10)

                # Tracking lost while moving: the clutch lets go and the page says so.
                await touch(cdp, "touchStart", [clutch])
                await wait_js(phone, "crowdteleop.engaged === true", 10)
                await phone.evaluate("trackingLost = true")
                await wait_js(phone, "crowdteleop.engaged === false", 5)
                results["lost_banner"] = await phone.inner_text("#banner")
                await phone.screenshot(path=str(screenshots / "phone-ar-tracking-lost.png"))
                await touch(cdp, "touchEnd", [])
                await phone.evaluate("trackingLost = false")
                await wait_js(phone, "crowdteleop.tracking === 'tracking'", 5)
                results["back_banner"] = await phone.inner_text("#banner")

                # The session ends (the system's back gesture): the clutch lets go.
                await touch(cdp, "touchStart", [clutch])
                await wait_js(phone, "crowdteleop.engaged === true", 10)
                await phone.evaluate("crowdteleop.xr.session.end()")
                await wait_js(phone, "crowdteleop.engaged === false", 5)
                results["ended_banner"] = await phone.inner_text("#banner")
                results["start_again"] = await phone.is_visible("#start-ar")
                await touch(cdp, "touchEnd", [])
                results["stats"] = await phone.evaluate("crowdteleop.connection.stats")
            return results

        results = asyncio.run(visit())

    [request] = results["requests"]
    assert request["mode"] == "immersive-ar" and "dom-overlay" in request["optional"]
    assert request["overlayRoot"] == "phone-ui", "the page, banner and controls, is the overlay"
    assert "6-DoF" in results["motion"]
    assert "track itself in 3D" in results["why"], "the page says why it offers AR"
    position_error_m = float(np.linalg.norm(results["moved"] - PATH_ROBOT_M))
    expected_turn = np.array(
        [0, 0, math.sin(math.radians(PATH_YAW_DEG) / 2), math.cos(math.radians(PATH_YAW_DEG) / 2)]
    )
    rotation_error_deg = quat_angle_deg(results["turn"], expected_turn)
    direction = PATH_ROBOT_M / np.linalg.norm(PATH_ROBOT_M)
    off_path_m = max(
        float(np.linalg.norm(p - np.dot(p, direction) * direction)) for p in results["path"]
    )
    print(
        f"AR path: hand moved {np.round(results['moved'], 4)} m; end error "
        f"{1000 * position_error_m:.1f} mm, {rotation_error_deg:.2f} deg; "
        f"largest distance from the path {1000 * off_path_m:.1f} mm"
    )
    assert position_error_m < 0.02, results["moved"]
    assert rotation_error_deg < 5.0, results["turn"]
    assert off_path_m < 0.02
    assert results["select_engages"] is True
    assert "lost track" in results["lost_banner"]
    assert "Tracking is back" in results["back_banner"]
    assert "AR tracking ended" in results["ended_banner"] and results["start_again"]
    assert results["stats"] == {"refusedOutgoing": 0, "ignoredIncoming": 0}, "schema-valid"
