"""The workers page in real headless Chromium (issue 29, item 5; docs/workers.md): a crowd's
workers, episodes and review decisions are written to the coordinator's database; the page
lists them with their reputation, sorts by a column, opens a worker's demonstrations and
blocks them, under the pages' Content-Security-Policy with no violation. Saves
docs/screenshots/workers.png when `make screenshots` asks (tests/e2e/conftest.py)."""

from __future__ import annotations

import asyncio
import random
import time
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import create_engine
from sqlalchemy.orm import Session as Transaction

from crowdteleop.coord.app import create_app
from crowdteleop.coord.db.engine import sync_url
from crowdteleop.coord.db.tables import Episode, Session, Worker
from tests.fixtures.browser import browser_context, require_chromium, wait_js
from tests.fixtures.coord import ADMIN, FakeLauncher, coord_config, served_app

pytestmark = pytest.mark.slow

RECORD_VIOLATIONS = """
window.violations = [];
document.addEventListener("securitypolicyviolation", (event) => {
  window.violations.push(`${event.violatedDirective} ${event.blockedURI}`);
});
"""
FLAGS = ("longest_pause_s", "path_ratio", "setbacks", "gripper_chatter")
# (worker id, source, demonstrations (the last one undecided), share accepted, score middle)
CROWD = (
    ("w_ada", "prolific", 9, 0.95, 78),
    ("w_ben", "prolific", 6, 0.7, 62),
    ("w_cai", "mturk", 4, 0.3, 38),
    ("w_dee", "prolific", 7, 0.85, 70),
    ("w_eli", "mturk", 2, 0.5, 50),
    ("w_fay", "prolific", 0, 0.0, 0),
)


def _crowd(now: float, seed: int = 3) -> list[Any]:
    rng = random.Random(seed)
    rows: list[Any] = []
    for number, (wid, source, demos, accept, middle) in enumerate(CROWD):
        rows.append(
            Worker(
                id=wid,
                source=source,
                external_id=f"{source[:2].upper()}{number:04d}",
                external_session=f"A{number:04d}" if source == "mturk" else None,
                campaign="default",
                params={},
                created_at=now - 7200 + number,
            )
        )
        sid = f"s_{wid}"
        rows.append(_session(sid, wid, now))
        for n in range(demos + rng.randint(0, 2)):
            success = n < demos
            flagged = rng.random() < 0.3
            rows.append(
                Episode(
                    episode_id=f"{wid}-e{n}",
                    session_id=sid,
                    worker_id=wid,
                    number=n + 1,
                    outcome="success" if success else "timeout",
                    steps=400,
                    duration_s=round(rng.uniform(12, 40), 1),
                    uri=f"file:///data/{wid}-{n}.hdf5",
                    interface="keyboard",
                    task="lift",
                    telemetry={},
                    created_at=now - 3600 + n * 60,
                    score=round(min(100, max(0, rng.gauss(middle, 12))), 1) if success else None,
                    flags=[
                        {"metric": (m := rng.choice(FLAGS)), "reason": f"{m} past its threshold"}
                    ]
                    if flagged
                    else [],
                    decision=_decision(n, demos - 1, accept) if success and n < demos - 1 else None,
                )
            )
    return rows


def _decision(n: int, decided: int, accept: float) -> str:
    """The first `accept` share of a worker's decided demonstrations accepted, the rest not."""
    return "accepted" if n < round(accept * decided) else "rejected"


def _session(sid: str, wid: str, now: float) -> Session:
    return Session(
        id=sid,
        worker_id=wid,
        campaign="default",
        state="ended",
        task="lift",
        robot="Sawyer",
        controller="ik-velocity",
        interfaces=["keyboard"],
        time_limit_s=1800.0,
        demos_required=3,
        demos_done=3,
        created_at=now - 3700,
        last_heartbeat_at=now,
        ended_reason="completed",
        report_token_hash=f"hash-{sid}",
    )


def _write(database_url: str, rows: list[Any]) -> None:
    engine = create_engine(sync_url(database_url))
    try:
        with Transaction(engine) as db, db.begin():
            for kind in (Worker, Session, Episode):
                db.add_all([r for r in rows if isinstance(r, kind)])
                db.flush()
    finally:
        engine.dispose()


ORDER = "() => [...document.querySelectorAll('#workers tbody tr')].map((tr) => tr.dataset.worker)"


async def _one_worker_clicked_then_another(page: Any) -> None:
    """w_ada clicked, then w_cai before w_ada's figures came: w_ada's answer, held until
    w_cai's is shown and then let through, must not take the panel Block acts on."""
    release = asyncio.Event()

    async def hold_ada(route: Any) -> None:
        if route.request.url.endswith("/w_ada"):
            await release.wait()
        await route.continue_()

    await page.route("**/api/admin/workers/w_*", hold_ada)
    await page.click("#workers tr[data-worker='w_ada']")
    await page.click("#workers tr[data-worker='w_cai']")
    await wait_js(page, "document.getElementById('detail-title').textContent.startsWith('w_cai')")
    async with page.expect_event("requestfinished", lambda r: r.url.endswith("/w_ada")):
        release.set()
    await page.evaluate("new Promise((resolve) => setTimeout(resolve, 300))")  # its handling
    await page.unroute("**/api/admin/workers/w_*")


async def _use(url: str, screenshots: Path) -> dict[str, Any]:
    from playwright.async_api import async_playwright

    seen: dict[str, Any] = {"errors": []}
    async with async_playwright() as playwright, browser_context(playwright) as ctx:
        await ctx.add_init_script(RECORD_VIOLATIONS)
        page = await ctx.new_page()
        page.on("pageerror", lambda error: seen["errors"].append(str(error)))
        await page.set_viewport_size({"width": 1440, "height": 1000})
        await page.goto(f"{url}/workers")
        await page.fill("#token", ADMIN)
        await page.click("#login button")
        await wait_js(page, "document.querySelectorAll('#workers tbody tr').length === 6", 30)
        seen["by_reputation"] = await page.evaluate(ORDER)
        await page.click("#workers th[data-column='4']")  # demos, most first
        seen["by_demos"] = await page.evaluate(ORDER)
        await page.click("#workers th[data-column='4']")  # and fewest first
        seen["by_demos_up"] = await page.evaluate(ORDER)
        await _one_worker_clicked_then_another(page)
        seen["title"] = await page.inner_text("#detail-title")
        seen["episodes"] = await page.locator("#episodes tr").count()
        await page.fill("#block-reason", "rushed, dropped objects")
        await page.click("#block")
        await wait_js(
            page,
            "document.querySelector(\"tr[data-worker='w_cai']\").classList.contains('blocked')",
            10,
        )
        seen["status"] = await page.inner_text("#detail-status")
        seen["unblock_shown"] = await page.is_visible("#unblock")
        await page.click("#workers th[data-column='3']")  # back to reputation, best first
        await page.screenshot(path=str(screenshots / "workers.png"), full_page=True)
        seen["violations"] = await page.evaluate("window.violations")
    return seen


def test_the_workers_page_sorts_opens_a_worker_and_blocks_them(tmp_path, screenshots):
    require_chromium()
    config = coord_config(tmp_path, capacity=2)
    app = create_app(config, FakeLauncher())
    with served_app(app, config) as url:
        _write(config.database_url, _crowd(time.time()))
        seen = asyncio.run(_use(url, screenshots))
        import httpx

        cai = httpx.get(
            f"{url}/api/admin/workers/w_cai", headers={"Authorization": f"Bearer {ADMIN}"}
        ).json()
    assert seen["errors"] == [] and seen["violations"] == [], seen
    assert seen["by_reputation"][0] == "w_ada" and seen["by_reputation"][-1] == "w_cai", seen
    assert seen["by_demos"][:2] == ["w_ada", "w_dee"] and seen["by_demos"][-1] == "w_fay", seen
    assert seen["by_demos_up"] == seen["by_demos"][::-1] or seen["by_demos_up"][0] == "w_fay"
    assert seen["title"].startswith("w_cai"), seen
    assert seen["episodes"] == 1 + len(cai["episodes"]), seen
    assert seen["status"].startswith("blocked") and "rushed" in seen["status"], seen
    assert seen["unblock_shown"], seen
    assert cai["blocked_reason"] == "rushed, dropped objects"


HELD = {"name": "held", "demos_required": 2, "review": {"accepted_required": 2}}
DEMOS = "document.getElementById('demos').textContent"


async def _held_page(url: str, launcher: FakeLauncher, database_url: str) -> str:
    """The worker's page of a campaign that holds the code for review, after two
    demonstrations of which one is accepted: what its demonstrations line says."""
    import httpx
    from playwright.async_api import async_playwright

    async with async_playwright() as playwright, browser_context(playwright) as ctx:
        page = await ctx.new_page()
        await page.goto(f"{url}/join?PROLIFIC_PID=held1&STUDY_ID=st&SESSION_ID=se&campaign=held")
        await page.check("#consent")
        await page.click("#agree")
        await page.wait_for_url("**/teleop")
        await wait_js(page, f"{DEMOS}.includes('0 of 2 accepted')", 20)
        [teleop] = [handle.config for handle in launcher.handles.values()]
        async with httpx.AsyncClient(base_url=url) as client:
            for number in (1, 2):
                report = {
                    "session_id": teleop.session_id,
                    "worker_id": teleop.worker_id,
                    "episode": number,
                    "episode_id": f"held-e{number}",
                    "outcome": "success",
                    "steps": 70,
                    "duration_s": 3.5,
                    "uri": "file:///data/ep.hdf5",
                    "telemetry": {},
                }
                auth = {"Authorization": f"Bearer {teleop.report_token}"}
                response = await client.post("/internal/episodes", json=report, headers=auth)
                assert response.status_code == 200, response.text
        _accept(database_url, "held-e1")
        return str(await wait_js(page, f"{DEMOS}.includes('1 of 2') && {DEMOS}", 20))


def _accept(database_url: str, episode_id: str) -> None:
    from sqlalchemy import update

    engine = create_engine(sync_url(database_url))
    try:
        with Transaction(engine) as db, db.begin():
            db.execute(
                update(Episode)
                .where(Episode.episode_id == episode_id)
                .values(decision="accepted", review_seq=1)
            )
    finally:
        engine.dispose()


def test_the_workers_own_page_says_how_many_are_accepted_and_await_review(tmp_path):
    require_chromium()
    launcher = FakeLauncher()
    config = coord_config(tmp_path, capacity=1, campaigns=[HELD])
    app = create_app(config, launcher)
    with served_app(app, config) as url:
        shown = asyncio.run(_held_page(url, launcher, config.database_url))
    assert shown == "2 / 2 · 1 of 2 accepted, 1 awaiting review", shown
