"""The reviewer page in real headless Chromium (issue 29, item 4; docs/review.md): two real
recorded lift episodes (scripted, as the teleop server records them) and two more rows in the
coordinator's database; the grid shows them, a filter narrows it, a click plays the episode
rendered by the replay tool (time advances, the seek bar seeks, 4x), `a` accepts, `r` with a
reason rejects, `u` undoes, a decision made meanwhile by another reviewer is reported, and the
history keeps every decision, all under the pages' Content-Security-Policy with no violation.
Saves docs/screenshots/review.png when `make screenshots` asks (tests/e2e/conftest.py)."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import create_engine
from sqlalchemy.orm import Session as Transaction

from crowdteleop.coord.app import create_app
from crowdteleop.coord.db.engine import sync_url
from crowdteleop.coord.db.tables import Episode, Session, Worker
from crowdteleop.recording.review import current_review
from tests.fixtures.browser import browser_context, require_chromium, wait_js
from tests.fixtures.coord import ADMIN, FakeLauncher, coord_config, served_app
from tests.fixtures.episodes import record_lift_episodes

pytestmark = pytest.mark.slow

ADA = "ada-review-token-Zr8Qm2Xv7Lp4Kw9N"
RECORD_VIOLATIONS = """
window.violations = [];
document.addEventListener("securitypolicyviolation", (event) => {
  window.violations.push(`${event.violatedDirective} ${event.blockedURI}`);
});
"""
CARDS = "document.querySelectorAll('#grid .card').length"
VIDEO = "document.getElementById('video')"
TITLE = "document.querySelector('#title .badge').textContent"
HISTORY = "document.querySelectorAll('#history li').length"


def _rows(episodes: Path, files: list[Path]) -> list[Any]:
    now = time.time()
    rows: list[Any] = []
    for wid in ("w_ada", "w_ben"):
        rows.append(
            Worker(id=wid, source="prolific", campaign="default", params={}, created_at=now)
        )
        rows.append(
            Session(
                id=f"s_{wid}",
                worker_id=wid,
                campaign="default",
                state="ended",
                task="lift",
                robot="Sawyer",
                controller="ik-velocity",
                interfaces=["keyboard"],
                time_limit_s=1800.0,
                demos_required=2,
                demos_done=2,
                created_at=now - 600,
                last_heartbeat_at=now,
                ended_reason="completed",
                report_token_hash=f"hash-{wid}",
            )
        )
    specs = [  # (id, worker, task, score, flags, uri)
        ("lift-0", "w_ada", "lift", 84.0, [], files[0].as_uri()),
        ("lift-1", "w_ada", "lift", 41.0, [_flag()], files[1].as_uri()),
        ("stack-0", "w_ben", "stack", 67.0, [], (episodes / "stack-0.hdf5").as_uri()),
        ("stack-1", "w_ben", "stack", 22.0, [_flag()], (episodes / "stack-1.hdf5").as_uri()),
    ]
    for number, (eid, wid, task, score, flags, uri) in enumerate(specs):
        rows.append(
            Episode(
                episode_id=eid,
                session_id=f"s_{wid}",
                worker_id=wid,
                number=number + 1,
                outcome="success",
                steps=70,
                duration_s=3.5 + number,
                uri=uri,
                interface="keyboard",
                task=task,
                telemetry={},
                created_at=now - 300 + number * 60,
                score=score,
                flags=flags,
            )
        )
    return rows


def _flag() -> dict[str, str]:
    return {"metric": "longest_pause_s", "reason": "paused 9.8 s (more than 5 s)"}


def _write(database_url: str, rows: list[Any]) -> None:
    engine = create_engine(sync_url(database_url))
    try:
        with Transaction(engine) as db, db.begin():
            for kind in (Worker, Session, Episode):
                db.add_all([r for r in rows if isinstance(r, kind)])
                db.flush()
    finally:
        engine.dispose()


async def _key(page: Any, key: str, expected: str) -> None:
    banner = "document.getElementById('banner').textContent"
    await page.evaluate(f"{banner} = ''")
    await page.keyboard.press(key)
    await wait_js(page, f"{TITLE} === '{expected}' || {banner}", 20)
    assert await page.evaluate(TITLE) == expected, await page.evaluate(banner)


async def _grid_and_filter(page: Any, seen: dict[str, Any]) -> None:
    await wait_js(page, f"{CARDS} === 4", 30)
    seen["cards"] = await page.evaluate(
        "[...document.querySelectorAll('#grid .card')].map((c) => c.dataset.episode)"
    )
    await page.fill("#filters input[name=task]", "stack")
    await wait_js(page, f"{CARDS} === 2", 10)
    await _an_older_answer_arriving_last(page)
    seen["filtered"] = await page.evaluate("document.querySelector('#grid .card').dataset.episode")
    seen["after_stale"] = await page.evaluate(CARDS)
    await page.fill("#filters input[name=task]", "")
    await page.select_option("#filters select[name=flagged]", "")
    await wait_js(page, f"{CARDS} === 4", 10)


async def _an_older_answer_arriving_last(page: Any) -> None:
    """Two filters changed in quick succession: the answer to the first (task only) is held
    until the second (task and flagged) is drawn, then let through; the grid keeps the second."""
    release = asyncio.Event()

    async def hold_unflagged(route: Any) -> None:
        if "flagged=" not in route.request.url:
            await release.wait()
        await route.continue_()

    await page.route("**/api/review/episodes?*", hold_unflagged)
    task = "#filters input[name=task]"
    await page.dispatch_event(task, "change")  # the older request: task=stack
    await page.select_option("#filters select[name=flagged]", "true")
    await wait_js(page, f"{CARDS} === 1", 10)
    async with page.expect_event("requestfinished", lambda r: "flagged=" not in r.url):
        release.set()
    await page.evaluate("new Promise((resolve) => setTimeout(resolve, 300))")  # its handling
    await page.unroute("**/api/review/episodes?*")


async def _one_card_clicked_then_another(page: Any) -> None:
    """lift-1 clicked, then lift-0 before lift-1's detail came: lift-1's answer, held until
    lift-0's is shown and then let through, must not take the player the keys decide on."""
    release = asyncio.Event()

    async def hold_lift_1(route: Any) -> None:
        if route.request.url.endswith("/lift-1"):
            await release.wait()
        await route.continue_()

    await page.route("**/api/review/episodes/lift-*", hold_lift_1)
    await page.click("#grid .card[data-episode='lift-1']")
    await page.click("#grid .card[data-episode='lift-0']")
    await wait_js(page, "document.querySelector('#title span').textContent.startsWith('lift-0')")
    async with page.expect_event("requestfinished", lambda r: r.url.endswith("/lift-1")):
        release.set()
    await page.evaluate("new Promise((resolve) => setTimeout(resolve, 300))")  # its handling
    await page.unroute("**/api/review/episodes/lift-*")


async def _play(page: Any, seen: dict[str, Any]) -> None:
    await _one_card_clicked_then_another(page)
    seen["title"] = await page.inner_text("#title")
    await wait_js(page, f"{VIDEO}.readyState >= 2 && {VIDEO}.currentTime > 0.2", 90)
    first = await page.evaluate(f"{VIDEO}.currentTime")
    await asyncio.sleep(0.4)
    seen["advanced"] = (first, await page.evaluate(f"{VIDEO}.currentTime"))
    await page.evaluate(f"{VIDEO}.pause()")
    await page.evaluate(
        "(() => { const s = document.getElementById('seek'); s.value = '500';"
        " s.dispatchEvent(new Event('input')); })()"
    )
    await wait_js(page, f"Math.abs({VIDEO}.currentTime - {VIDEO}.duration / 2) < 0.2", 10)
    seen["duration"] = await page.evaluate(f"{VIDEO}.duration")
    await page.click(".rate[data-rate='4']")
    seen["rate"] = await page.evaluate(f"{VIDEO}.playbackRate")
    await page.evaluate(f"{VIDEO}.currentTime = 0; {VIDEO}.play()")
    await asyncio.sleep(0.5)
    seen["fast"] = await page.evaluate(f"{VIDEO}.currentTime")


async def _decide(page: Any, url: str, seen: dict[str, Any]) -> None:
    await _key(page, "a", "accepted")
    await page.keyboard.press("r")
    await page.wait_for_selector("#reason", state="visible")
    await page.keyboard.type("the cube slipped out of the gripper")
    await page.keyboard.press("Enter")
    await wait_js(page, f"{TITLE} === 'rejected'", 20)
    await _key(page, "u", "accepted")
    await wait_js(page, f"{HISTORY} === 3", 10)
    seen["history"] = await page.inner_text("#history")
    seen["card"] = await page.inner_text("#grid .card[data-episode='lift-0'] .badge")
    async with httpx.AsyncClient(base_url=url) as client:  # another reviewer, quicker
        answer = await client.post(
            "/api/review/episodes/lift-0/decision",
            json={"decision": "rejected", "reason": "too slow", "expected_seq": 3},
            headers={"Authorization": f"Bearer {ADMIN}"},
        )
        assert answer.status_code == 200, answer.text
    await page.keyboard.press("a")
    await wait_js(page, "document.getElementById('banner').textContent.includes('meanwhile')", 10)
    seen["conflict"] = await page.inner_text("#banner")
    seen["after_conflict"] = await page.evaluate(TITLE)


async def _use(url: str, screenshots: Path) -> dict[str, Any]:
    from playwright.async_api import async_playwright

    seen: dict[str, Any] = {"errors": []}
    async with async_playwright() as playwright, browser_context(playwright) as ctx:
        await ctx.add_init_script(RECORD_VIOLATIONS)
        page = await ctx.new_page()
        page.on("pageerror", lambda error: seen["errors"].append(str(error)))
        await page.set_viewport_size({"width": 1440, "height": 1000})
        await page.goto(f"{url}/review")
        await page.fill("#token", ADA)
        await page.click("#login button")
        await _grid_and_filter(page, seen)
        await _play(page, seen)
        await _decide(page, url, seen)
        chosen = "document.querySelector('.card.chosen').dataset.episode"
        await page.keyboard.press("k")  # lift-0 is the last card: k goes back to lift-1
        seen["previous"] = await wait_js(page, f"{chosen} !== 'lift-0' && {chosen}", 10)
        await page.keyboard.press("j")
        seen["next"] = await wait_js(page, f"{chosen} === 'lift-0' && {chosen}", 10)
        await wait_js(page, f"{HISTORY} === 4 && {VIDEO}.readyState >= 2", 30)
        await page.evaluate(f"{VIDEO}.pause(); {VIDEO}.currentTime = 1.5")
        thumbnails = "[...document.querySelectorAll('#grid img')].filter((i) => i.naturalWidth)"
        await wait_js(page, f"{thumbnails}.length >= 2", 60)
        await page.screenshot(path=str(screenshots / "review.png"), full_page=True)
        seen["violations"] = await page.evaluate("window.violations")
    return seen


def test_the_reviewer_page_plays_and_decides_by_keyboard(tmp_path, screenshots):
    require_chromium()
    episodes = tmp_path / "episodes"
    files = [episode.path for episode in record_lift_episodes(episodes, 2)]
    config = coord_config(tmp_path, reviewer_tokens={"ada": ADA})
    app = create_app(config, FakeLauncher())
    with served_app(app, config) as url:
        _write(config.database_url, _rows(episodes, files))
        seen = asyncio.run(_use(url, screenshots))
        detail = httpx.get(
            f"{url}/api/review/episodes/lift-0", headers={"Authorization": f"Bearer {ADA}"}
        ).json()
    assert seen["errors"] == [] and seen["violations"] == [], seen
    assert seen["cards"] == ["stack-1", "stack-0", "lift-1", "lift-0"], seen  # newest first
    assert seen["filtered"] == "stack-1" and seen["after_stale"] == 1, seen
    assert seen["title"].startswith("lift-0"), seen
    start, later = seen["advanced"]
    assert later > start, seen
    assert abs(seen["duration"] - 3.5) < 0.2, seen  # 70 steps at 20 Hz
    assert seen["rate"] == 4 and seen["fast"] > 1.2, seen  # 0.5 s at 4x
    assert "the cube slipped" in seen["history"] and "by ada" in seen["history"], seen
    assert seen["card"] == "accepted", seen
    assert "decided by admin (rejected) meanwhile" in seen["conflict"], seen
    assert seen["after_conflict"] == "rejected", seen
    assert (seen["previous"], seen["next"]) == ("lift-1", "lift-0"), seen
    assert [(h["decision"], h["reviewer"]) for h in detail["history"]] == [
        ("accepted", "ada"),
        ("rejected", "ada"),
        ("accepted", "ada"),
        ("rejected", "admin"),
    ]
    stored = current_review(files[0])
    assert stored is not None and (stored.seq, stored.decision) == (4, "rejected")
