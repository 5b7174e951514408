"""The worker's pages at real screen sizes, in headless Chromium with touch: every phone mode
(orientation + drag, camera, AR) shows every control a worker needs without scrolling, big
enough for a thumb and hit by a tap at its centre, on phones from 568 to 932 px tall; the
teleop page's marker is in view at desktop sizes and stays put when the phone takes control.

One coordinator, one robot and one paired phone page per mode for the whole module: the
viewports change in place."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

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
from tests.fixtures.xr_phone import EMULATED_PHONE, IWER

pytestmark = pytest.mark.slow

CAMPAIGN = {
    "name": "layouts",
    "title": "Phone layouts",
    "instructions": "Lift the cube.",
    "demos_required": 5,
    "time_limit_s": 600,
}
JOIN = "/join?PROLIFIC_PID=layout-worker&STUDY_ID=study-1&SESSION_ID=visit-1"
PORTRAIT = {
    "iPhone SE": (320, 568),
    "small Android": (360, 640),
    "iPhone 13": (390, 664),
    "iPhone 15 Pro Max": (430, 739),
    "Pixel 7": (412, 839),
    "iPhone 15 Pro Max, full screen": (430, 932),
}
LANDSCAPE = {"iPhone SE landscape": (568, 320), "Pixel 7 landscape": (839, 412)}
DESKTOPS = [(1280, 720), (1920, 1080)]
STATUS = ["#connection", "#driver", "#motion", "#clutch-state"]
# What a worker needs in each mode: (controls to tap, lines to read).
MODES = {
    "orientation": (
        ["#motion-permission", "#start-camera", "#pad", "#lift", "#clutch", "#gripper"],
        [*STATUS, "#motion-why"],
    ),
    "camera": (
        ["#motion-permission", "#pad", "#lift", "#clutch", "#gripper"],
        [*STATUS, "#camera-view", "#camera-hint"],
    ),
    "ar": (["#recentre", "#pad", "#clutch", "#gripper"], STATUS),
}
CAMERA_FLAGS = ("--use-fake-device-for-media-stream", "--use-fake-ui-for-media-stream")

# Each element's box, and whether a tap at its centre lands on it (what is on top there).
MEASURE = """(selectors) => Object.fromEntries(selectors.map((selector) => {
  const element = document.querySelector(selector);
  if (!element) return [selector, { x: 0, y: 0, width: 0, height: 0, hit: false }];
  const box = element.getBoundingClientRect();
  const hit = document.elementFromPoint(box.x + box.width / 2, box.y + box.height / 2);
  return [selector, { x: box.x, y: box.y, width: box.width, height: box.height,
                      hit: element.contains(hit) }];
}))"""


async def _measure(page: Any, selectors: list[str]) -> dict[str, Any]:
    boxes = await page.evaluate(MEASURE, selectors)
    scroll = await page.evaluate("[scrollX, scrollY]")
    return {"boxes": boxes, "scroll": scroll}


async def _pair_phone(desktop: Any, handset: Any, emulate_xr: bool = False) -> Any:
    """A phone page paired with the desktop's robot through a fresh pairing link."""
    link = await desktop.evaluate(
        """async () => {
      const response = await fetch(`/api/sessions/${crowdteleop.view.session_id}/pairing`,
        { method: "POST", headers: { Authorization: `Bearer ${crowdteleop.token}` } });
      return (await response.json()).phone_url;
    }"""
    )
    phone = await handset.new_page()
    if emulate_xr:
        await phone.add_init_script(path=str(IWER))
        await phone.add_init_script(EMULATED_PHONE)
    path = link[link.index("/phone") :]
    await phone.goto(desktop.url[: desktop.url.index("/teleop")] + path)
    await phone_paired(phone)
    return phone


async def _start_mode(phone: Any, button: str, mode: str) -> None:
    """Tap the mode's button until the mode runs (a banner that appears as the finger lands
    moves the button; a worker would tap again); else what the page said."""
    for _ in range(3):
        await phone.tap(button)
        if await _comes_true(phone, f"document.body.classList.contains('{mode}')", 10):
            return
    raise AssertionError(f"{mode} never started: {await phone.inner_text('#banner')}")


async def _tap_holds_the_clutch(phone: Any, cdp: Any) -> bool:
    """A real touch on "Hold to move": the page holds the clutch while the finger is down."""
    await touch(cdp, "touchStart", [await centre(phone, "#clutch")])
    held = await _comes_true(phone, "crowdteleop.engaged === true")
    await touch(cdp, "touchEnd", [])
    await wait_js(phone, "crowdteleop.engaged === false", 5)
    return held


async def _comes_true(page: Any, expression: str, timeout_s: float = 5) -> bool:
    """Whether `expression` comes true in time: a fault for a test below to report."""
    try:
        await wait_js(page, expression, timeout_s)
    except AssertionError:
        return False
    return True


async def _sizes(phone: Any, cdp: Any, mode: str, results: dict[str, Any]) -> None:
    """The mode's controls at every phone size; a screenshot and a real tap at the smallest."""
    controls, lines = MODES[mode]
    for name, (width, height) in {**PORTRAIT, **LANDSCAPE}.items():
        await phone.set_viewport_size({"width": width, "height": height})
        await phone.evaluate("new Promise((done) => requestAnimationFrame(() => done()))")
        results["phones"][(mode, name)] = {
            "viewport": (width, height),
            "controls": await _measure(phone, controls),
            "lines": await _measure(phone, lines),
        }
        if name == "iPhone SE":
            results["screenshots"][f"phone-{mode}-320x568.png"] = await phone.screenshot()
            results["tapped"][mode] = await _tap_holds_the_clutch(phone, cdp)


async def _visit(url: str) -> dict[str, Any]:
    from playwright.async_api import async_playwright

    results: dict[str, Any] = {"phones": {}, "screenshots": {}, "tapped": {}, "desktop": {}}
    async with (
        async_playwright() as playwright,
        browser_context(playwright) as desktop_context,
        browser_context(
            playwright, mdns=False, mobile=True, args=(*CAMERA_FLAGS, "--enable-unsafe-swiftshader")
        ) as handset,
    ):
        desktop = await desktop_context.new_page()
        await desktop.goto(url + JOIN)
        await desktop.check("#consent")
        await desktop.click("#agree")
        await desktop.wait_for_url("**/teleop")
        await wait_js(desktop, "window.crowdteleop.ready === true", 150)
        for width, height in DESKTOPS:
            await desktop.set_viewport_size({"width": width, "height": height})
            results["desktop"][(width, height)] = await _measure(desktop, ["#marker"])
        await desktop.set_viewport_size({"width": 1280, "height": 720})
        results["marker_before"] = (await _measure(desktop, ["#marker"]))["boxes"]["#marker"]

        phone = await _pair_phone(desktop, handset)
        cdp = await handset.new_cdp_session(phone)
        await _sizes(phone, cdp, "orientation", results)
        results["phone_drives"] = await _comes_true(
            desktop, "document.body.classList.contains('phone-drives')"
        )
        results["marker_after"] = (await _measure(desktop, ["#marker"]))["boxes"]["#marker"]

        await phone.set_viewport_size({"width": 320, "height": 568})
        await _start_mode(phone, "#start-camera", "camera")
        await _sizes(phone, cdp, "camera", results)
        await phone.close()

        phone = await _pair_phone(desktop, handset, emulate_xr=True)
        cdp = await handset.new_cdp_session(phone)
        await _start_mode(phone, "#start-ar", "xr")
        await wait_js(phone, "crowdteleop.tracking === 'tracking'", 15)  # else a press is refused
        await _sizes(phone, cdp, "ar", results)
    return results


@pytest.fixture(scope="module")
def seen(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Everything the tests below look at, from one visit."""
    require_chromium()
    with coord_server(
        tmp_path_factory.mktemp("layouts"), capacity=1, campaigns=[CAMPAIGN]
    ) as coord:
        return asyncio.run(_visit(coord.url))


def _inside(box: dict[str, float], viewport: tuple[int, int]) -> bool:
    width, height = viewport
    right, bottom = box["x"] + box["width"], box["y"] + box["height"]
    return box["x"] >= -0.5 and box["y"] >= -0.5 and right <= width + 0.5 and bottom <= height + 0.5


def test_every_control_of_every_mode_is_on_screen_thumb_sized_and_hit_by_a_tap(seen):
    faults = []
    for (mode, phone), measured in seen["phones"].items():
        viewport = measured["viewport"]
        assert measured["controls"]["scroll"] == [0, 0]
        for selector, box in measured["controls"]["boxes"].items():
            if not _inside(box, viewport) or box["height"] == 0:
                faults.append(f"{mode} on {phone} {viewport}: {selector} off screen at {box}")
            elif box["height"] < 44 or box["width"] < 44:
                faults.append(f"{mode} on {phone}: {selector} is {box['width']}x{box['height']}")
            elif not box["hit"]:
                faults.append(f"{mode} on {phone}: a tap on {selector} lands on something else")
    assert not faults, "\n".join(faults)


def test_every_status_line_of_every_mode_is_on_screen(seen):
    faults = [
        f"{mode} on {phone}: {selector} at {box}"
        for (mode, phone), measured in seen["phones"].items()
        for selector, box in measured["lines"]["boxes"].items()
        if box["height"] == 0 or not _inside(box, measured["viewport"])
    ]
    assert not faults, "\n".join(faults)


def test_a_tap_on_hold_to_move_holds_the_clutch_in_every_mode(seen):
    assert seen["tapped"] == {"orientation": True, "camera": True, "ar": True}


def test_the_marker_is_in_view_on_desktop_screens(seen):
    for viewport, measured in seen["desktop"].items():
        box = measured["boxes"]["#marker"]
        assert box["width"] >= 200 and _inside(box, viewport), (viewport, box)


def test_the_marker_stays_put_when_the_phone_takes_control(seen):
    assert seen["phone_drives"], "the teleop page says the phone drives"
    before, after = seen["marker_before"], seen["marker_after"]
    for key in ("x", "y", "width", "height"):
        assert abs(before[key] - after[key]) <= 1, (before, after)


def test_each_mode_at_the_smallest_phone_size_in_screenshots(seen, screenshots: Path):
    assert set(seen["screenshots"]) == {f"phone-{m}-320x568.png" for m in MODES}
    for name, png in seen["screenshots"].items():
        (screenshots / name).write_bytes(png)
