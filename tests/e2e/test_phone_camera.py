"""The phone's camera mode in real headless Chromium: its fake camera plays a video (made by the
test with OpenCV) of the teleop page's marker seen from a phone moving along a known path; the
page finds the marker, recovers the phone's pose and drives the robot through a real
coordinator, teleop server and WebRTC. A stretch of the video without the marker is the camera
losing it."""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.fixtures.browser import (
    browser_context,
    centre,
    phone_paired,
    require_chromium,
    touch,
    wait_js,
)
from tests.fixtures.coord import coord_server
from tests.fixtures.marker_video import MARKER_ID, PhonePose, write_y4m
from tests.fixtures.phone_page import quat_angle_deg, relative_turn, robot_for_a_phone

pytestmark = pytest.mark.slow

CAMPAIGN = {
    "name": "camera",
    "title": "Phone camera",
    "instructions": "Lift the cube.",
    "demos_required": 5,
    "time_limit_s": 600,
}
START = PhonePose(np.array([-0.40, 0.0, 0.0]), Rotation.identity())
END = PhonePose(np.array([-0.30, 0.04, 0.04]), Rotation.from_euler("zy", [-15, 10], degrees=True))
# One loop of the video, in seconds: at START, to END, at END, back, then no marker.
HOLD_START_S, MOVE_S, HOLD_END_S, AWAY_S = 2.0, 2.0, 2.5, 1.0
LOOP_S = HOLD_START_S + MOVE_S + HOLD_END_S + MOVE_S + AWAY_S


def _between(fraction: float) -> PhonePose:
    eased = 0.5 - 0.5 * math.cos(math.pi * fraction)
    turn = (END.rotation * START.rotation.inv()).as_rotvec() * eased
    return PhonePose(
        START.position_m + eased * (END.position_m - START.position_m),
        Rotation.from_rotvec(turn) * START.rotation,
    )


def _path(t_s: float) -> PhonePose | None:
    if t_s < HOLD_START_S:
        return START
    t_s -= HOLD_START_S
    if t_s < MOVE_S:
        return _between(t_s / MOVE_S)
    t_s -= MOVE_S
    if t_s < HOLD_END_S:
        return END
    t_s -= HOLD_END_S
    if t_s < MOVE_S:
        return _between(1 - t_s / MOVE_S)
    return None


# The teleop page's marker canvas read back as cells (true = white), at each cell's centre.
MARKER_CELLS = """(() => {
  const canvas = document.getElementById("marker");
  if (!canvas || !canvas.width) return null;
  const n = 10, data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  const cell = canvas.width / n, rows = [];
  for (let y = 0; y < n; y += 1) {
    const row = [];
    for (let x = 0; x < n; x += 1) {
      const i = (Math.floor((y + 0.5) * cell) * canvas.width + Math.floor((x + 0.5) * cell)) * 4;
      row.push(data[i] > 127);
    }
    rows.push(row);
  }
  return rows;
})()"""


def _opencv_marker_cells() -> list[list[bool]]:
    """OpenCV's marker for the same dictionary and id, one pixel a cell, quiet zone added."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_ARUCO_MIP_36h12)
    marker = cv2.aruco.generateImageMarker(dictionary, MARKER_ID, 8)
    return np.pad(marker > 127, 1, constant_values=True).tolist()  # type: ignore[no-any-return]


def _near(pose: dict[str, Any], target: PhonePose, within_m: float = 0.02) -> bool:
    return bool(np.linalg.norm(np.array(pose["position"]) - target.position_m) < within_m)


async def _raw_pose(page: Any) -> dict[str, Any] | None:
    return await page.evaluate("crowdteleop.rawPose")  # type: ignore[no-any-return]


async def _poses_until(page: Any, done: Any, timeout_s: float, log: list[Any]) -> dict[str, Any]:
    """Poll the page's recovered (unfiltered) pose until done(pose); every pose goes in log."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while loop.time() < deadline:
        pose = await _raw_pose(page)
        if pose is not None:
            log.append(pose)
            if done(pose):
                return pose
        await asyncio.sleep(0.03)
    raise AssertionError(f"the recovered pose never got there (last: {log[-1:]})")


async def _poses_for(page: Any, seconds: float, log: list[Any]) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + seconds
    while loop.time() < deadline:
        log.append(await _raw_pose(page))
        await asyncio.sleep(0.03)


def _off_path_m(pose: dict[str, Any]) -> float:
    """How far the recovered position is from the path's nearest point."""
    along = [_between(k / 200).position_m for k in range(201)]
    return min(float(np.linalg.norm(np.array(pose["position"]) - p)) for p in along)


def _error(poses: list[dict[str, Any]], truth: PhonePose) -> tuple[float, float]:
    """Largest position error (m) and rotation error (deg) of poses recovered at `truth`."""
    position = max(float(np.linalg.norm(np.array(p["position"]) - truth.position_m)) for p in poses)
    rotation = max(quat_angle_deg(np.array(p["quaternion"]), truth.quaternion) for p in poses)
    return position, rotation


def test_the_phone_camera_tracks_the_marker_and_drives_the_hand_along_the_path(
    tmp_path: Path, screenshots: Path
) -> None:
    require_chromium()
    from playwright.async_api import async_playwright

    video = write_y4m(tmp_path / "marker.y4m", _path, LOOP_S)
    camera_flags = (
        "--use-fake-device-for-media-stream",
        "--use-fake-ui-for-media-stream",
        f"--use-file-for-fake-video-capture={video}",
    )
    with coord_server(tmp_path, capacity=1, campaigns=[CAMPAIGN]) as coord:

        async def visit() -> dict[str, Any]:
            results: dict[str, Any] = {}
            async with (
                robot_for_a_phone(coord.url, "camera") as (phone_link, hand),
                async_playwright() as playwright,
                browser_context(playwright, mobile=True, args=camera_flags) as handset,
            ):
                phone = await handset.new_page()
                cdp = await handset.new_cdp_session(phone)
                await phone.goto(phone_link)
                await phone_paired(phone)
                results["why"] = await phone.inner_text("#motion-why")
                await phone.click("#start-camera")
                await wait_js(phone, "crowdteleop.tracking === 'tracking'", 20)
                clutch = await centre(phone, "#clutch")

                # The marker goes out of view while the clutch is held: it lets go, the page
                # says so, and the drag pads move the hand until the marker is back.
                await touch(cdp, "touchStart", [clutch])
                await wait_js(phone, "crowdteleop.engaged === true", 10)
                await wait_js(phone, "crowdteleop.tracking === 'lost'", 2 * LOOP_S)
                results["released_on_loss"] = await phone.evaluate("!crowdteleop.engaged")
                results["lost_banner"] = await phone.inner_text("#banner")
                results["lost_motion"] = await phone.inner_text("#motion")
                await touch(cdp, "touchEnd", [])
                await phone.screenshot(path=str(screenshots / "phone-camera-marker-lost.png"))
                pad = await centre(phone, "#pad")
                before_drag = await phone.evaluate("crowdteleop.position.slice()")
                await touch(cdp, "touchStart", [pad])
                await touch(cdp, "touchMove", [(pad[0], pad[1] - 40)])
                await touch(cdp, "touchEnd", [])
                results["dragged"] = (
                    np.array(await phone.evaluate("crowdteleop.position")) - before_drag
                )

                # The marker is back at the start of the path: press and carry.
                await wait_js(phone, "crowdteleop.tracking === 'tracking'", AWAY_S + 5)
                results["back_banner"] = await phone.inner_text("#banner")
                await touch(cdp, "touchStart", [clutch])
                await wait_js(
                    phone, "crowdteleop.connection.state.status.controlling_device === 'phone'", 5
                )
                held: list[dict[str, Any]] = []
                await asyncio.sleep(HOLD_START_S / 4)
                results["start_hand"] = hand["now"].copy()
                await _poses_for(phone, HOLD_START_S / 4, held)
                results["at_start"], log = held, list(held)
                await _poses_until(phone, lambda p: _near(p, END, 0.01), MOVE_S + 3, log)
                held = []
                await _poses_for(phone, HOLD_END_S / 3, held)
                results["end_hand"] = hand["now"].copy()
                results["at_end"] = held
                await phone.screenshot(path=str(screenshots / "phone-camera.png"))
                await touch(cdp, "touchEnd", [])
                results["log"] = log + held
                results["figures"] = await phone.evaluate("crowdteleop.camera.figures.summary()")
                results["stats"] = await phone.evaluate("crowdteleop.connection.stats")
            async with (
                async_playwright() as playwright,
                browser_context(playwright) as desktop,
            ):
                page = await desktop.new_page()
                # Without a worker, teleop.js would go to the join page: only the marker here.
                await page.route("**/static/teleop.js", lambda route: route.abort())
                await page.goto(f"{coord.url}/teleop")
                results["marker_cells"] = await wait_js(page, MARKER_CELLS, 10)
                panel = page.locator("#marker-panel")
                await panel.screenshot(path=str(screenshots / "teleop-marker.png"))
            return results

        results = asyncio.run(visit())

    assert results["marker_cells"] == _opencv_marker_cells(), "the page shows OpenCV's marker"
    assert "Track the marker" in results["why"], "the page says why it offers the camera"
    assert results["released_on_loss"] and "lost the marker" in results["lost_banner"]
    assert "drag pads" in results["lost_motion"]
    assert results["dragged"][0] > 0.01, "the pads move the hand while the marker is lost"
    assert "Marker found" in results["back_banner"]

    start_error = _error(results["at_start"], START)
    end_error = _error(results["at_end"], END)
    off_path_m = max(_off_path_m(p) for p in results["log"])
    moved = results["end_hand"][:3] - results["start_hand"][:3]
    expected = END.position_m - START.position_m
    turn = relative_turn(results["end_hand"][3:], results["start_hand"][3:])
    expected_turn = (END.rotation * START.rotation.inv()).as_quat()
    hand_error_m = float(np.linalg.norm(moved - expected))
    hand_error_deg = quat_angle_deg(turn, expected_turn)
    figures = results["figures"]
    print(
        f"camera mode: recovered pose at the start {1000 * start_error[0]:.1f} mm "
        f"{start_error[1]:.2f} deg, at the end {1000 * end_error[0]:.1f} mm "
        f"{end_error[1]:.2f} deg (largest), {1000 * off_path_m:.1f} mm off the path; "
        f"hand moved {np.round(moved, 4)} m for "
        f"{expected} m: {1000 * hand_error_m:.1f} mm, {hand_error_deg:.2f} deg off; "
        f"camera {figures['framesPerS']:.1f} frames/s, {figures['posesPerS']:.1f} poses/s, "
        f"detection {figures['detectMs']:.1f} ms, frame to pose {figures['latencyMs']:.1f} ms"
    )
    measured = {
        "start_error_mm": 1000 * start_error[0],
        "start_error_deg": start_error[1],
        "end_error_mm": 1000 * end_error[0],
        "end_error_deg": end_error[1],
        "off_path_mm": 1000 * off_path_m,
        "hand_error_mm": 1000 * hand_error_m,
        "hand_error_deg": hand_error_deg,
        **figures,
    }
    print("CAMERA_FIGURES " + json.dumps(measured))  # benchmarks/phone_camera.py reads this
    assert start_error[0] < 0.01 and start_error[1] < 2.0
    assert end_error[0] < 0.01 and end_error[1] < 2.0
    assert off_path_m < 0.02
    assert hand_error_m < 0.02 and hand_error_deg < 4.0
    assert figures["posesPerS"] > 10
    assert results["stats"] == {"refusedOutgoing": 0, "ignoredIncoming": 0}, "schema-valid"
