"""Regions in a real browser (issue 14, item 4, the paper's Oregon-vs-China test): one campaign
served by two coordinators, "near" beside the worker and "far" behind an emulated link with
60 ms of delay each way (linkemu). A worker's Chromium opens the far region's link and lands
in the near one; a second worker, once the near region's only robot is taken, lands in the far
one. Each region records where its workers went and the round trips that sent them there."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import h5py
import pytest

from crowdteleop.dataset.build import BuildOptions, build_dataset, episode_files, read_inputs
from crowdteleop.dataset.files import dataset_demos
from crowdteleop.dataset.stats import compute_stats
from crowdteleop.linkemu.netns import EmulatedLink, emulated_link
from crowdteleop.linkemu.shaping import LinkSettings
from crowdteleop.teleop.ready import stop_gracefully, wait_ready
from tests.fixtures.browser import browser_context, consent_to_video, require_chromium, wait_js

# runs alone under xdist: the near round trip must stay well under the far one
pytestmark = [pytest.mark.slow, pytest.mark.exclusive]
ADMIN = "regions-admin-token-0123456789"
ONE_WAY_DELAY_MS = 60.0
NEAR_PORT, FAR_PORT = 8100, 8000


@pytest.fixture(autouse=True)
def _root() -> None:
    if os.geteuid() != 0:
        pytest.skip("the slow region sits behind an emulated link: namespaces and TUN need root")


def _campaign(near: str, far: str) -> dict[str, Any]:
    regions = [{"name": "near", "url": near}, {"name": "far", "url": far}]
    return {"name": "pilot", "practice_s": 0, "demos_required": 5, "regions": regions}


def _serve(
    link: EmulatedLink,
    side: str,
    host: str,
    port: int,
    region: str,
    campaign: dict[str, Any],
    folder: Path,
) -> subprocess.Popen[str]:
    """A coordinator of `region` with one robot, listening on `host` in `side`'s namespace."""
    folder.mkdir()
    config = {
        "region": region,
        "capacity": 1,
        "spare_servers": 0,
        "public_url": f"http://{host}:{port}",
        "teleop_host": host,
        "campaigns": [campaign],
    }
    (folder / "coord.json").write_text(json.dumps(config))
    serve = [sys.executable, "-m", "crowdteleop", "serve", "--host", host, "--port", str(port)]
    serve += ["--admin-token", ADMIN, "--data-dir", str(folder / "data")]
    serve += ["--config", str(folder / "coord.json")]
    with (folder / "coord.log").open("w") as log:
        process = subprocess.Popen(
            link.run_in(side, serve),
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,  # type: ignore[arg-type]
        )
    wait_ready(process, folder / "coord.log", 90.0, f"the {region} coordinator")
    return process


def _chromium_in(namespace: str, folder: Path) -> str:
    """Debian's Chromium started inside `namespace` (Playwright talks to it over a pipe, so
    the namespace does not get in its way)."""
    wrapper = folder / "chromium-in-namespace"
    wrapper.write_text(f'#!/bin/sh\nexec ip netns exec {namespace} /usr/bin/chromium "$@"\n')
    wrapper.chmod(0o755)
    return str(wrapper)


async def _worker(
    playwright: Any,
    chromium: str,
    link_url: str,
    lands_at: str,
    driving: asyncio.Event,
    leave: asyncio.Event | None = None,
    screenshot: Path | None = None,
) -> dict[str, Any]:
    """A worker opens `link_url`: where the page sent them; they drive an episode there (and
    say so on `driving`), and leave once `leave` is set."""
    async with browser_context(playwright, executable=chromium) as context:
        page = context.pages[0] if context.pages else await context.new_page()
        started = time.monotonic()
        await page.goto(link_url)
        await page.wait_for_url(f"{lands_at}/join?**", timeout=30_000)
        placed_s = time.monotonic() - started
        landed = page.url
        await consent_to_video(page)
        await page.keyboard.down("r")  # an episode begins with the first move
        await asyncio.sleep(1.0)
        await page.keyboard.up("r")
        await wait_js(page, "(crowdteleop.connection.state.status || {}).episode >= 1")
        if screenshot is not None:
            await page.screenshot(path=str(screenshot))
        driving.set()
        if leave is not None:
            await leave.wait()
        await page.close(run_before_unload=True)  # the worker leaves: the episode is stored
        return {"landed": landed, "placed_s": placed_s}


def _episodes_region(data: Path) -> list[dict[str, Any]]:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        episodes, _bad = read_inputs(episode_files([data / "episodes"]))
        if episodes:
            return [episode.metadata.get("region") for _, episode in episodes]
        time.sleep(0.5)
    raise AssertionError(f"no episode stored under {data}")


def test_a_joining_worker_lands_in_the_nearest_region_with_a_free_robot(tmp_path, screenshots):
    require_chromium()
    from playwright.async_api import async_playwright

    delay = LinkSettings(delay_ms=ONE_WAY_DELAY_MS)
    with emulated_link(delay, delay, workdir=tmp_path / "link") as link:
        near = f"http://127.0.0.1:{NEAR_PORT}"  # in the worker's namespace
        far = f"http://{link.address_b}:{FAR_PORT}"  # across the slow link
        campaign = _campaign(near, far)
        servers = [
            _serve(link, "a", "127.0.0.1", NEAR_PORT, "near", campaign, tmp_path / "near"),
            _serve(link, "b", link.address_b, FAR_PORT, "far", campaign, tmp_path / "far"),
        ]
        try:
            chromium = _chromium_in(link.namespace_a, tmp_path)

            async def crowd() -> tuple[dict[str, Any], dict[str, Any]]:
                study = "STUDY_ID=s1&SESSION_ID=x"
                first_drives, second_drives = asyncio.Event(), asyncio.Event()
                async with async_playwright() as playwright:
                    # The first opens the far region's link: the near one is nearer and free.
                    first = asyncio.create_task(
                        _worker(
                            playwright,
                            chromium,
                            f"{far}/?PROLIFIC_PID=w1&{study}",
                            near,
                            first_drives,
                            leave=second_drives,
                        )
                    )
                    await asyncio.wait_for(first_drives.wait(), 240)
                    # The second opens the near one's link while its only robot is taken.
                    second = await _worker(
                        playwright,
                        chromium,
                        f"{near}/?PROLIFIC_PID=w2&{study}",
                        far,
                        second_drives,
                        screenshot=screenshots / "regions-far.png",
                    )
                    return await first, second

            first, second = asyncio.run(crowd())
        finally:
            for server in servers:
                stop_gracefully(server, 60)
    assert first["landed"].startswith(f"{near}/join?"), "the nearer region, free"
    assert second["landed"].startswith(f"{far}/join?"), "the nearer region's robot was taken"
    print(f"placed in {first['placed_s']:.2f} s and {second['placed_s']:.2f} s")
    [near_choice] = _episodes_region(tmp_path / "near" / "data")
    [far_choice] = _episodes_region(tmp_path / "far" / "data")
    print("recorded:", near_choice, far_choice)
    assert (near_choice["region"], far_choice["region"]) == ("near", "far")
    for rtts in (near_choice["rtts_ms"], far_choice["rtts_ms"]):
        assert set(rtts) == {"near", "far"}
        assert rtts["far"] >= 2 * ONE_WAY_DELAY_MS, rtts
        assert rtts["near"] < rtts["far"] / 4, rtts

    # The dataset keeps them apart: a filter key per region, and the paper's tables by region.
    dataset = tmp_path / "regions.hdf5"
    sources = [tmp_path / region / "data" / "episodes" for region in ("near", "far")]
    build_dataset(sources, dataset, BuildOptions(include_failed=True, drift_tolerance=None))
    with h5py.File(dataset, "r") as file:
        assert {"region_near", "region_far"} <= set(file["mask"])
        assert file["data/demo_1"].attrs["region"] in ("near", "far")
    by_region = compute_stats(dataset_demos(dataset))["tasks"]["lift"]["by"]["region"]
    assert [group["group"] for group in by_region["groups"]] == ["far", "near"]
