"""The teleop page's VR mode in real headless Chromium with an emulated Meta Quest 3 (Meta's
IWER, vendored from npm), against a real coordinator, teleop server and WebRTC: the headset
shows the live video, the right controller with its grip held drives the arm, a contact
pulses it, and leaving VR gives the page back to the keyboard."""

from __future__ import annotations

import asyncio
import base64
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.fixtures.browser import (
    browser_context,
    join_to_video,
    require_chromium,
    wait_js,
)
from tests.fixtures.coord import admin_teleop_client, coord_server

pytestmark = pytest.mark.slow

IWER = Path(__file__).parents[1] / "fixtures" / "vendor" / "iwer-2.5.0.min.js"
JOIN = "/join?PROLIFIC_PID=vr1&STUDY_ID=st&SESSION_ID=se"
CAMPAIGN = {"name": "vr", "demos_required": 3}
STATUS = "crowdteleop.connection.state.status"
HEADSET = """
(() => {
  const headset = new IWER.XRDevice(IWER.metaQuest3);
  headset.installRuntime({ forceInstall: true });
  window.headset = headset;
})();
"""
# Records every haptic pulse, and whether it went to the right (driving) controller.
SPY_PULSES = """() => {
  window.pulses = [];
  const sources = [...crowdteleop.devices.vr.session.inputSources];
  const right = sources.find((s) => s.handedness === "right").gamepad.hapticActuators[0];
  const actuator = Object.getPrototypeOf(right), pulse = actuator.pulse;
  actuator.pulse = function (value, ms) {
    window.pulses.push({ value, ms, right: this === right });
    return pulse.call(this, value, ms);
  };
}"""
# The headset's first view as the page drew it: the screen in it as 16x12 block-averaged grey
# levels; the page's video the same way (drawn at the screen's size); or the whole view as PNG.
BLOCKS = """(rgba, width, [left, bottom, right, top], flip) => {
  const grid = [];
  const [w, h] = [(right - left) / 16, (top - bottom) / 12];
  for (let gy = 0; gy < 12; gy++) for (let gx = 0; gx < 16; gx++) {
    let sum = 0, n = 0;
    for (let y = Math.ceil(bottom + gy * h + 1); y < bottom + (gy + 1) * h - 1; y++) {
      for (let x = Math.ceil(left + gx * w + 1); x < left + (gx + 1) * w - 1; x++) {
        const i = 4 * (y * width + x);
        sum += rgba[i] + rgba[i + 1] + rgba[i + 2]; n += 3;
      }
    }
    grid.push(sum / n);
  }
  if (!flip) return grid;  // WebGL's rows are bottom-up: top row first, as the video's
  const rows = [];
  for (let gy = 11; gy >= 0; gy--) rows.push(...grid.slice(gy * 16, gy * 16 + 16));
  return rows;
}"""
GRID = f"""async () => {{
  const blocks = {BLOCKS};
  const {{ width, rgba, screen }} = await crowdteleop.xrScreen.sample();
  return {{ grid: blocks(rgba, width, screen, true), screen }};
}}"""
VIDEO_GRID = f"""([left, bottom, right, top]) => {{
  const blocks = {BLOCKS};
  const canvas = document.createElement("canvas");
  [canvas.width, canvas.height] = [Math.round(right - left), Math.round(top - bottom)];
  const context = canvas.getContext("2d");
  context.drawImage(document.getElementById("video"), 0, 0, canvas.width, canvas.height);
  const rgba = context.getImageData(0, 0, canvas.width, canvas.height).data;
  return blocks(rgba, canvas.width, [0, 0, canvas.width, canvas.height], false);
}}"""
PNG = """async () => {
  const { width, height, rgba } = await crowdteleop.xrScreen.sample();
  const canvas = document.createElement("canvas");
  [canvas.width, canvas.height] = [width, height];
  const context = canvas.getContext("2d"), image = context.createImageData(width, height);
  for (let row = 0; row < height; row++) {  // WebGL's rows are bottom-up
    const bottomUp = rgba.subarray((height - 1 - row) * width * 4, (height - row) * width * 4);
    image.data.set(bottomUp, row * width * 4);
  }
  context.putImageData(image, 0, 0);
  return canvas.toDataURL("image/png");
}"""
RIGHT_START = np.array([0.2, 1.3, -0.3])  # the right controller, in the headset's frame (m)


async def _hand(page: Any) -> np.ndarray:
    return np.array(await page.evaluate(f"{STATUS}.end_effector"))


async def _carry_right(page: Any, start: np.ndarray, end: np.ndarray, seconds: float) -> None:
    steps = int(30 * seconds)
    for step in range(1, steps + 1):
        x, y, z = start + (end - start) * step / steps
        await page.evaluate(f"headset.controllers.right.position.set({x}, {y}, {z})")
        await asyncio.sleep(1 / 30)


async def _cube_and_hand(coord_url: str, page: Any) -> tuple[np.ndarray, np.ndarray]:
    """Where the cube and the hand are (the admin channel's privileged state)."""
    admin = admin_teleop_client(coord_url, await page.evaluate("crowdteleop.view.session_id"))
    await admin.connect()
    try:
        await admin.wait_for(lambda s: s.privileged is not None, 10)
        state = admin.state.privileged
        return np.array(state.objects["cube"][:3]), np.array(state.end_effector[:3])
    finally:
        await admin.close()


async def _move_the_screen(page: Any) -> list[list[float]]:
    """The left hand's thumbstick pushes the screen away; its grip drags it up. The screen's
    rectangle in the view before, after each."""
    rects = [(await page.evaluate(GRID))["screen"]]
    left = "headset.controllers.left"
    await page.evaluate(f"{left}.updateAxes('thumbstick', 0, -1)")
    await asyncio.sleep(0.5)
    await page.evaluate(f"{left}.updateAxes('thumbstick', 0, 0)")
    rects.append((await page.evaluate(GRID))["screen"])
    await page.evaluate(f"{left}.position.set(-0.2, 1.3, -0.3)")
    await page.evaluate(f"{left}.updateButtonValue('squeeze', 1)")
    await asyncio.sleep(0.1)
    await page.evaluate(f"{left}.position.set(-0.2, 1.6, -0.3)")
    await asyncio.sleep(0.1)
    await page.evaluate(f"{left}.updateButtonValue('squeeze', 0)")
    rects.append((await page.evaluate(GRID))["screen"])
    return rects


async def _enter_vr(page: Any) -> None:
    await page.evaluate(
        "([x, y, z]) => headset.controllers.right.position.set(x, y, z)", list(RIGHT_START)
    )
    await wait_js(page, "!document.getElementById('use-vr').hidden", 10)
    await page.click("#use-vr")
    await wait_js(page, "crowdteleop.xrScreen && crowdteleop.xrScreen.frames > 10", 10)
    await wait_js(page, f"{STATUS}.controlling_device === 'vr'", 10)
    await page.evaluate(SPY_PULSES)


async def _look(page: Any, screenshots: Path) -> dict[str, Any]:
    """(a) What the headset shows while the robot is still: its screen, twice, the page's
    video at the same time, the status panel; saved as vr-mode.png."""
    first = await page.evaluate(GRID)
    video = await page.evaluate(VIDEO_GRID, first["screen"])
    await asyncio.sleep(0.3)
    second = await page.evaluate(GRID)
    png = await page.evaluate(PNG)
    (screenshots / "vr-mode.png").write_bytes(base64.b64decode(png.split(",")[1]))
    return {
        "screen": first["screen"],
        "view_width": await page.evaluate("crowdteleop.xrScreen.sample().then((s) => s.width)"),
        "still": np.array(first["grid"]),
        "still_again": np.array(second["grid"]),
        "video": np.array(video),
        "panel": await page.evaluate("crowdteleop.xrScreen.panelText"),
        "instruction": await page.inner_text("#instruction"),
    }


async def _drive_to_cube(page: Any, coord_url: str) -> dict[str, Any]:
    """(b) Grip held, the right controller carries the hand down to the cube."""
    cube, hand = await _cube_and_hand(coord_url, page)
    before = await _hand(page)
    await page.evaluate("headset.controllers.right.updateButtonValue('squeeze', 1)")
    await wait_js(page, f"{STATUS}.clutch === 'driving'", 10)
    robot = cube - hand + [0.0, 0.0, 0.005]  # forward, left, up
    xr = np.array([-robot[1], robot[2], -robot[0]])  # WebXR: right, up, back
    await _carry_right(page, RIGHT_START, RIGHT_START + xr, 1.5)
    moved = await _hand(page) - before
    for _ in range(100):  # the arm catches up with the hand (slower on a loaded machine)
        if np.linalg.norm(moved - robot) < 0.03:
            break
        await asyncio.sleep(0.1)
        moved = await _hand(page) - before
    return {
        "moved": moved,
        "wanted": robot,
        "after": np.array((await page.evaluate(GRID))["grid"]),
    }


async def _leave_vr(page: Any) -> dict[str, Any]:
    """(d) The session ends: the page is back and the keyboard drives."""
    await page.evaluate("headset.controllers.right.updateButtonValue('squeeze', 0)")
    await page.evaluate("crowdteleop.devices.vr.session.end()")
    await wait_js(page, "crowdteleop.device.kind === 'keyboard'", 5)
    seen = {
        "vr_button": await page.is_enabled("#use-vr"),
        "banner": await page.inner_text("#banner"),
    }
    await wait_js(page, f"{STATUS}.controlling_device === 'keyboard'", 5)
    up = await _hand(page)
    await page.keyboard.down("r")
    await asyncio.sleep(0.6)
    await page.keyboard.up("r")
    await asyncio.sleep(0.3)
    seen["keyboard_up"] = (await _hand(page) - up)[2]
    return seen


def test_the_headset_shows_the_video_the_controller_drives_and_buzzes(tmp_path, screenshots):
    require_chromium()
    from playwright.async_api import async_playwright

    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as coord:

        async def visit() -> dict[str, Any]:
            async with (
                async_playwright() as playwright,
                browser_context(playwright, args=("--enable-unsafe-swiftshader",)) as desktop,
            ):
                await desktop.add_init_script(path=str(IWER))
                await desktop.add_init_script(HEADSET)
                page = await desktop.new_page()
                await join_to_video(page, coord.url + JOIN)
                await _enter_vr(page)
                seen = await _look(page, screenshots)
                seen.update(await _drive_to_cube(page, coord.url))
                # (c) the trigger closes the gripper on the cube: the controller buzzes
                await page.evaluate("headset.controllers.right.updateButtonValue('trigger', 1)")
                seen["pulses"] = await wait_js(page, "window.pulses.length && window.pulses", 10)
                seen["screen_moves"] = await _move_the_screen(page)
                seen.update(await _leave_vr(page))
                seen["stats"] = await page.evaluate("crowdteleop.connection.stats")
            return seen

        seen = asyncio.run(visit())

    likeness = float(np.corrcoef(seen["still"], seen["video"])[0, 1])
    still_change = float(np.abs(seen["still_again"] - seen["still"]).mean())
    moved_change = float(np.abs(seen["after"] - seen["still"]).mean())
    print(
        f"VR: hand moved {np.round(seen['moved'], 3)} m for {np.round(seen['wanted'], 3)}; "
        f"headset screen changed {still_change:.1f} still, {moved_change:.1f} moved; likeness "
        f"to the video {likeness:.3f}; screen rectangles {np.round(seen['screen_moves'])} px; "
        f"pulses {seen['pulses'][:3]}; keyboard up {seen['keyboard_up']:.3f} m"
    )
    left, _, right, _ = seen["screen"]
    width = seen["view_width"]
    assert left > 0 and right < width and abs((left + right) / 2 - width / 2) < 0.05 * width
    assert likeness > 0.95 and np.abs(seen["still"] - seen["video"]).mean() < 10, "the video"
    assert moved_change > 2.0 and moved_change > 3 * still_change, "live: the robot moved"
    assert np.linalg.norm(seen["moved"]) > 0.02
    assert np.linalg.norm(seen["moved"] - seen["wanted"]) < 0.03
    assert seen["instruction"] in seen["panel"] and "Demonstrations 0 / 3" in seen["panel"]
    assert "Ready: hold to move." in seen["panel"], "the clutch's state, in words"
    assert seen["pulses"][0]["right"] and 0.3 <= seen["pulses"][0]["value"] <= 1
    placed, farther, lifted = (np.array(rect) for rect in seen["screen_moves"])
    assert farther[2] - farther[0] < 0.85 * (placed[2] - placed[0]), "pushed away: smaller"
    assert lifted[1] > farther[1] + 50, "dragged up 30 cm: higher in the view"
    assert seen["vr_button"] and "left VR" in seen["banner"]
    assert seen["keyboard_up"] > 0.02
    assert seen["stats"] == {"refusedOutgoing": 0, "ignoredIncoming": 0}, "schema-valid"
