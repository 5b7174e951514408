"""Real headless Chromium (Debian's /usr/bin/chromium) driven by Playwright, for page tests."""

from __future__ import annotations

import asyncio
import contextlib
import shutil
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

CHROMIUM = "/usr/bin/chromium"
FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--autoplay-policy=no-user-gesture-required",
]
# Real browsers hide local addresses behind mDNS names; this flag shows them (both are tested).
NO_MDNS = "--disable-features=WebRtcHideLocalIpsWithMdns"
DOCS_SCREENSHOTS = Path(__file__).resolve().parents[1] / "docs" / "screenshots"


def require_chromium() -> None:
    if not Path(CHROMIUM).exists():
        pytest.fail(
            f"{CHROMIUM} is missing: `bash scripts/system-deps.sh test` installs Debian's "
            "chromium for the browser tests",
            pytrace=False,
        )


@contextlib.asynccontextmanager
async def browser_context(
    playwright: Any, mdns: bool = True, mobile: bool = False
) -> AsyncIterator[Any]:
    """A fresh profile per context (launch_persistent_context), as a new user's browser."""
    profile = Path(tempfile.mkdtemp(prefix="crowdteleop-chromium-"))
    options: dict[str, Any] = {
        "executable_path": CHROMIUM,
        "headless": True,
        "args": FLAGS + ([] if mdns else [NO_MDNS]),
        "viewport": {"width": 412, "height": 860} if mobile else {"width": 1280, "height": 900},
    }
    if mobile:
        options.update(has_touch=True, is_mobile=True, device_scale_factor=2)
    context = await playwright.chromium.launch_persistent_context(str(profile), **options)
    try:
        yield context
    finally:
        await context.close()
        shutil.rmtree(profile, ignore_errors=True)


async def wait_js(page: Any, expression: str, timeout_s: float = 60.0) -> Any:
    """Poll `expression` in the page until it is truthy; its value."""
    await page.wait_for_function(expression, timeout=timeout_s * 1000)
    return await page.evaluate(expression)


async def video_fingerprint(page: Any) -> list[float]:
    """The video's current picture, 16x12 grey levels: enough to tell that it changed."""
    return await page.evaluate(
        """() => {
        const video = document.getElementById('video');
        const canvas = document.createElement('canvas');
        canvas.width = 16; canvas.height = 12;
        const context = canvas.getContext('2d');
        context.drawImage(video, 0, 0, 16, 12);
        const data = context.getImageData(0, 0, 16, 12).data;
        const grey = [];
        for (let i = 0; i < data.length; i += 4) grey.push((data[i] + data[i+1] + data[i+2]) / 3);
        return grey;
    }"""
    )


async def touch(cdp: Any, kind: str, points: list[tuple[float, float]]) -> None:
    """A real touch event through the DevTools protocol (Chromium makes pointer events of it)."""
    await cdp.send(
        "Input.dispatchTouchEvent",
        {
            "type": kind,
            "touchPoints": [{"x": x, "y": y, "id": i} for i, (x, y) in enumerate(points)],
        },
    )


async def centre(page: Any, selector: str) -> tuple[float, float]:
    box = await page.locator(selector).bounding_box()
    return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2


async def settle(seconds: float) -> None:
    await asyncio.sleep(seconds)
