"""Reviewing demonstrations (issue 29, item 4; docs/review.md) on SQLite and PostgreSQL: the
decisions with their history, undo, two reviewers at once, the grid's filters, the API's
refusals, and the decision stored beside the episode file."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import create_engine
from sqlalchemy.orm import Session as Transaction

from crowdteleop.coord.db.engine import make_engine, migrate, sync_url
from crowdteleop.coord.db.reviews import (
    EpisodeNotFoundError,
    NothingToUndoError,
    ReviewConflictError,
    ReviewFilters,
)
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Episode, Session, Worker
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.coord.service.review import DecidedMeanwhileError, Reviews, Sidecars
from crowdteleop.recording.review import ReviewRecord, current_review
from crowdteleop.recording.stores import StorageConfig
from tests.fixtures.coord import ADMIN, Api, FakeLauncher, coord_config, in_process_app
from tests.fixtures.s3 import BUCKET, moto_s3

pytestmark = pytest.mark.filterwarnings("ignore:Using `httpx`")


def _run(coroutine):
    return asyncio.run(asyncio.wait_for(coroutine, 60))


def _worker(wid: str) -> Worker:
    return Worker(id=wid, source="anonymous", campaign="default", params={}, created_at=time.time())


def _session(sid: str, wid: str) -> Session:
    now = time.time()
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
        created_at=now,
        last_heartbeat_at=now,
        ended_reason="completed",
        report_token_hash=f"hash-{sid}",
    )


def _episode(eid: str, sid: str, wid: str, uri: str, **more: Any) -> Episode:
    return Episode(
        episode_id=eid,
        session_id=sid,
        worker_id=wid,
        number=more.pop("number", 1),
        outcome=more.pop("outcome", "success"),
        steps=100,
        duration_s=more.pop("duration_s", 10.0),
        uri=uri,
        interface="keyboard",
        task=more.pop("task", "lift"),
        telemetry={},
        created_at=more.pop("created_at", time.time()),
        **more,
    )


FLAG = [{"metric": "path_ratio", "reason": "path 2.1x the straight line"}]


def _crowd(tmp_path: Path) -> list[Any]:
    """Two workers; five episodes of two tasks, scores 20..90, one flagged, one timeout."""
    rows: list[Any] = [_worker("w_a"), _worker("w_b"), _session("s_a", "w_a")]
    rows.append(_session("s_b", "w_b"))
    specs = [
        ("e1", "s_a", "w_a", {"score": 90.0, "duration_s": 12.0}),
        ("e2", "s_a", "w_a", {"score": 50.0, "duration_s": 30.0, "flags": FLAG}),
        ("e3", "s_a", "w_a", {"score": None, "outcome": "timeout", "flags": []}),
        ("e4", "s_b", "w_b", {"score": 20.0, "task": "stack", "duration_s": 8.0}),
        ("e5", "s_b", "w_b", {"score": 70.0, "duration_s": 20.0}),
    ]
    for number, (eid, sid, wid, more) in enumerate(specs):
        uri = (tmp_path / f"{eid}.hdf5").as_uri()
        rows.append(_episode(eid, sid, wid, uri, number=number, created_at=1000.0 + number, **more))
    return rows


async def _store(url: str, rows: list[Any]) -> Store:
    await migrate(url)
    store = Store(make_engine(url))
    async with store.transactions.begin() as db:
        for row in rows:
            db.add(row)
            await db.flush()
    return store


def test_decisions_undo_and_history(tmp_path, database_url):
    async def scenario() -> None:
        store = await _store(database_url, _crowd(tmp_path))
        reviews = store.reviews
        try:
            first = await reviews.decide("e1", 0, "accepted", "", "ada")
            assert (first.seq, first.decision, first.reviewer) == (1, "accepted", "ada")
            await reviews.decide("e1", 1, "rejected", "gripper slipped", "bob")
            undo = await reviews.undo("e1", 2, "ada")
            assert (undo.seq, undo.decision) == (3, "accepted"), "back to before the reject"
            again = await reviews.undo("e1", 3, "ada")
            assert again.decision == "rejected", "undoing an undo redoes"
            episode = await reviews.episode("e1")
            assert episode is not None
            assert (episode.decision, episode.review_seq) == ("rejected", 4)
            history = await reviews.history("e1")
            assert [(r.seq, r.decision, r.reviewer) for r in history] == [
                (1, "accepted", "ada"),
                (2, "rejected", "bob"),
                (3, "accepted", "ada"),
                (4, "rejected", "ada"),
            ]
            assert history[1].reason == "gripper slipped" and history[1].at > 0

            await reviews.decide("e5", 0, "accepted", "", "ada")
            back = await reviews.undo("e5", 1, "ada")
            assert back.decision is None, "undoing the first decision: undecided again"
            with pytest.raises(NothingToUndoError):
                await reviews.undo("e2", 0, "ada")
            with pytest.raises(EpisodeNotFoundError):
                await reviews.decide("nope", 0, "accepted", "", "ada")
            with pytest.raises(EpisodeNotFoundError):
                await reviews.undo("nope", 0, "ada")
        finally:
            await store.close()

    _run(scenario())


def test_two_reviewers_at_once_one_wins(tmp_path, database_url):
    async def scenario() -> None:
        store = await _store(database_url, _crowd(tmp_path))
        reviews = store.reviews
        try:
            results = await asyncio.gather(
                reviews.decide("e2", 0, "accepted", "", "ada"),
                reviews.decide("e2", 0, "rejected", "too slow", "bob"),
                return_exceptions=True,
            )
            won = [r for r in results if not isinstance(r, BaseException)]
            lost = [r for r in results if isinstance(r, BaseException)]
            assert len(won) == 1 and len(lost) == 1, results
            conflict = lost[0]
            assert isinstance(conflict, ReviewConflictError)
            assert conflict.episode.decision == won[0].decision
            assert conflict.last is not None and conflict.last.reviewer == won[0].reviewer
            assert len(await reviews.history("e2")) == 1
            with pytest.raises(ReviewConflictError):  # a stale count, sequentially
                await reviews.undo("e2", 0, "bob")
        finally:
            await store.close()

    _run(scenario())


def _ids(page) -> list[str]:
    return [episode.episode_id for episode in page.episodes]


def test_the_grid_filters_and_sorts(tmp_path, database_url):
    async def scenario() -> None:
        store = await _store(database_url, _crowd(tmp_path))
        reviews = store.reviews
        try:
            await reviews.decide("e1", 0, "accepted", "", "ada")
            await reviews.decide("e4", 0, "rejected", "dropped", "ada")
            page = await reviews.page(ReviewFilters())
            assert (_ids(page), page.total) == (["e5", "e4", "e3", "e2", "e1"], 5)
            assert _ids(await reviews.page(ReviewFilters(sort="score"))) == [
                "e1", "e5", "e2", "e4", "e3"
            ]  # fmt: skip
            by_time = ReviewFilters(sort="duration_s", descending=False)
            assert _ids(await reviews.page(by_time))[:3] == ["e4", "e3", "e1"]
            cases = {
                "task": (ReviewFilters(task="stack"), ["e4"]),
                "worker": (ReviewFilters(worker="w_a"), ["e3", "e2", "e1"]),
                "accepted": (ReviewFilters(decision="accepted"), ["e1"]),
                "undecided": (ReviewFilters(decision="undecided"), ["e5", "e3", "e2"]),
                "flagged": (ReviewFilters(flagged=True), ["e2"]),
                "unflagged": (ReviewFilters(flagged=False), ["e5", "e4", "e3", "e1"]),
                "scores": (ReviewFilters(score_min=50, score_max=80), ["e5", "e2"]),
                "outcome": (ReviewFilters(outcome="timeout"), ["e3"]),
            }
            for name, (filters, expected) in cases.items():
                assert _ids(await reviews.page(filters)) == expected, name
            page = await reviews.page(ReviewFilters(limit=2, offset=2))
            assert (_ids(page), page.total) == (["e3", "e2"], 5)
        finally:
            await store.close()

    _run(scenario())


def test_a_malformed_filter_is_refused_by_name():
    with pytest.raises(ValueError, match="score_min"):
        ReviewFilters(score_min=80, score_max=20)
    with pytest.raises(ValueError, match="decision"):
        ReviewFilters.model_validate({"decision": "maybe"})
    with pytest.raises(ValueError, match="extra"):
        ReviewFilters.model_validate({"colour": "red"})


# --- the API ---------------------------------------------------------------------------------

ADA = "ada-review-token-Zr8Qm2Xv7Lp4Kw9N"
AUTO_CAMPAIGN = {"name": "auto", "review": {"auto_accept_score": 80, "auto_reject_score": 30}}


def _write(database_url: str, rows: list[Any]) -> None:
    engine = create_engine(sync_url(database_url))
    try:
        with Transaction(engine) as db, db.begin():
            for row in rows:
                db.add(row)
                db.flush()
    finally:
        engine.dispose()


@contextlib.contextmanager
def _reviewing(tmp_path: Path, database_url: str) -> Iterator[Any]:
    """The app with the crowd's rows, their episode files' folder made, and ada a reviewer."""
    config = coord_config(
        tmp_path, database_url, reviewer_tokens={"ada": ADA}, campaigns=[{}, AUTO_CAMPAIGN]
    )
    (tmp_path / "episodes").mkdir()
    with in_process_app(config, FakeLauncher()) as client:
        _write(database_url, _crowd(tmp_path / "episodes"))
        yield client


def _as(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def _decide(client, eid: str, token: str = ADA, **body: Any):
    return client.post(f"/api/review/episodes/{eid}/decision", json=body, headers=_as(token))


def test_who_may_review(tmp_path, database_url):
    with _reviewing(tmp_path, database_url) as client:
        assert client.get("/api/review/me", headers=_as(ADA)).json() == {"reviewer": "ada"}
        assert client.get("/api/review/me", headers=_as(ADMIN)).json() == {"reviewer": "admin"}
        for headers in ({}, _as("forged-token-0123456789abcdef"), {"Authorization": "Basic x"}):
            answer = client.get("/api/review/episodes", headers=headers)
            assert answer.status_code == 401, headers
            assert answer.json()["error"] == "unauthorized"
            refused = _decide(client, "e1", "", decision="accepted", expected_seq=0)
            assert refused.status_code == 401
        counts = client.app_state.metrics.refusal_counts()
        assert counts["admin_bad_token"] >= 3
        history = client.get("/api/review/episodes/e1", headers=_as(ADA)).json()["history"]
        assert history == [], "nothing refused was recorded"
        page = client.get("/review")
        assert page.status_code == 200 and "review.js" in page.text


def test_deciding_through_the_api_stores_the_decision_beside_the_file(tmp_path, database_url):
    with _reviewing(tmp_path, database_url) as client:
        answer = _decide(client, "e2", decision="accepted", expected_seq=0)
        assert answer.status_code == 200, answer.text
        assert answer.json()["episode"]["decision"] == "accepted"
        episode_file = tmp_path / "episodes" / "e2.hdf5"
        stored = current_review(episode_file)
        assert stored is not None
        assert (stored.seq, stored.decision, stored.reviewer) == (1, "accepted", "ada")

        rejected = _decide(client, "e2", ADMIN, decision="rejected", reason="slow", expected_seq=1)
        assert rejected.json()["decision"]["reviewer"] == "admin"
        undo = client.post(
            "/api/review/episodes/e2/undo", json={"expected_seq": 2}, headers=_as(ADA)
        )
        assert undo.json()["episode"]["decision"] == "accepted"
        current = current_review(episode_file)
        assert current is not None and (current.seq, current.decision) == (3, "accepted")
        assert len(list((tmp_path / "episodes").glob("e2.review.*.json"))) == 3, "none replaced"
        detail = client.get("/api/review/episodes/e2", headers=_as(ADA)).json()
        assert [(h["seq"], h["decision"], h["reviewer"]) for h in detail["history"]] == [
            (1, "accepted", "ada"),
            (2, "rejected", "admin"),
            (3, "accepted", "ada"),
        ]
        assert detail["history"][1]["reason"] == "slow"


def test_bad_input_is_a_clear_error_and_loses_nothing(tmp_path, database_url):
    with _reviewing(tmp_path, database_url) as client:
        assert _decide(client, "e1", decision="accepted", expected_seq=0).status_code == 200
        late = _decide(client, "e1", decision="rejected", reason="no", expected_seq=0)
        assert late.status_code == 409
        body = late.json()
        assert body["error"] == "conflict" and "decided by ada" in body["message"]
        assert (body["episode"]["decision"], body["episode"]["review_seq"]) == ("accepted", 1)

        unknown = _decide(client, "nope", decision="accepted", expected_seq=0)
        assert (unknown.status_code, unknown.json()["error"]) == (404, "not_found")
        assert client.get("/api/review/episodes/nope", headers=_as(ADA)).status_code == 404
        nothing = client.post(
            "/api/review/episodes/e5/undo", json={"expected_seq": 1}, headers=_as(ADA)
        )
        assert nothing.status_code == 409

        malformed = {
            "score_min=90&score_max=10": "score_min",
            "decision=maybe": "decision",
            "sort=colour": "sort",
            "limit=0": "limit",
            "flagged=perhaps": "flagged",
            "colour=red": "colour",
        }
        for query, field in malformed.items():
            answer = client.get(f"/api/review/episodes?{query}", headers=_as(ADA))
            assert answer.status_code == 422, query
            assert answer.json()["error"] == "invalid_request"
            assert field in answer.json()["message"], answer.json()
        no_reason = _decide(client, "e3", decision="rejected", expected_seq=0)
        assert no_reason.status_code == 422 and "reason" in no_reason.json()["message"]
        assert _decide(client, "e3", decision="maybe", expected_seq=0).status_code == 422
        counts = client.app_state.metrics.refusal_counts()
        assert counts["review_conflict"] == 2 and counts["review_unknown_episode"] == 2
        assert counts["review_invalid"] == 8

        page = client.get("/api/review/episodes?decision=accepted", headers=_as(ADA)).json()
        assert [e["episode_id"] for e in page["episodes"]] == ["e1"]
        assert (
            client.get("/api/review/episodes/e1", headers=_as(ADA)).json()["history"][0]["reviewer"]
            == "ada"
        )
        assert client.get("/api/review/episodes/e3", headers=_as(ADA)).json()["history"] == []


def test_a_video_that_cannot_be_rendered_says_why(tmp_path, database_url):
    with _reviewing(tmp_path, database_url) as client:
        card = client.get("/api/review/episodes/e1", headers=_as(ADA)).json()
        answer = client.get(card["video_url"])  # e1's file was never recorded
        assert answer.status_code == 502, answer.text
        assert "e1.hdf5 is missing" in answer.json()["message"]
        forged = card["video_url"].replace("sig=", "sig=0")[:-1]
        assert client.get(forged).status_code == 401
        other = card["video_url"].replace("/e1/", "/e2/")
        assert client.get(other).status_code == 401, "a link is for its episode only"


def test_the_campaigns_score_rule_decides_automatically(tmp_path, database_url):
    with _reviewing(tmp_path, database_url) as client:
        automatic = client.app_state.reviews.automatic
        decided = {eid: client.portal.call(automatic, eid, "auto") for eid in ("e1", "e2", "e4")}
        assert decided["e1"] is not None and decided["e1"].decision.decision == "accepted"
        assert decided["e2"] is None, "flagged: left to the reviewers"
        assert decided["e4"] is not None and decided["e4"].decision.decision == "rejected"
        assert decided["e4"].decision.reviewer == "auto" and decided["e4"].decision.automatic
        assert client.portal.call(automatic, "e5", "default") is None, "no rule: none"
        stored = current_review(tmp_path / "episodes" / "e1.hdf5")
        assert stored is not None and stored.automatic


def test_the_hook_hears_every_reviewers_decision(tmp_path, database_url):
    heard: list[tuple[str, str | None]] = []

    async def hook(episode: Episode) -> None:
        heard.append((episode.episode_id, episode.decision))

    async def scenario() -> None:
        store = await _store(database_url, _crowd(tmp_path))
        config = coord_config(tmp_path, database_url)
        reviews = Reviews(store, config, CoordMetrics(), on_decided=hook)
        try:
            await reviews.decide("e1", 0, "accepted", "", "ada")
            await reviews.undo("e1", 1, "ada")
            with pytest.raises(DecidedMeanwhileError):
                await reviews.decide("e1", 0, "rejected", "late", "bob")
        finally:
            await store.close()

    _run(scenario())
    assert heard == [("e1", "accepted"), ("e1", None)], "not the refused one"


def test_a_decision_on_an_s3_episode_is_stored_beside_it_in_the_bucket(tmp_path):
    with moto_s3() as server:
        server.client().create_bucket(Bucket=BUCKET)
        s3 = server.config(prefix="campaign-7")
        sidecars = Sidecars(StorageConfig(kind="s3", s3=s3))
        uri = f"s3://{BUCKET}/campaign-7/episodes/s_1/ep-3.hdf5"
        record = ReviewRecord(
            episode_id="ep-3", seq=2, decision="rejected", reason="dropped", reviewer="ada", at=1.0
        )
        sidecars.write(uri, record)
        local = tmp_path / "ep-3.review.000002.json"
        key = "campaign-7/episodes/s_1/ep-3.review.000002.json"
        server.client().download_file(BUCKET, key, str(local))
    assert current_review(tmp_path / "ep-3.hdf5") == record
    with pytest.raises(ValueError, match="not in the configured store"):
        sidecars.write("s3://elsewhere/x.hdf5", record)


def test_an_automatic_accept_of_a_reported_episode_releases_the_held_code(tmp_path, database_url):
    """The score rule runs as the report is recorded, before the completion check: a
    campaign that holds the code for one accepted demonstration completes at once."""
    held = {
        "name": "held",
        "demos_required": 1,
        "review": {"accepted_required": 1, "auto_accept_score": 10},
        "prolific_completion_code": "AUTO2024",
    }
    launcher = FakeLauncher()
    config = coord_config(tmp_path, database_url, capacity=1, campaigns=[held])
    params = {"PROLIFIC_PID": "5f0a1b2c3d4e5f6a7b8c9d0f", "STUDY_ID": "s1", "SESSION_ID": "x1"}
    with in_process_app(config, launcher) as client:
        api = Api(client)
        token = api.join(params, campaign="held")["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")
        teleop = launcher.handles[sid].config
        report = {
            "session_id": sid,
            "worker_id": teleop.worker_id,
            "episode": 1,
            "episode_id": f"{sid}-e1",
            "outcome": "success",
            "steps": 70,
            "duration_s": 3.5,
            "uri": (tmp_path / "e1.hdf5").as_uri(),
            "telemetry": {},
            "metrics": {"completion_time_s": 3.5},
        }
        headers = {"Authorization": f"Bearer {teleop.report_token}"}
        answer = client.post("/internal/episodes", json=report, headers=headers)
        assert answer.status_code == 200 and answer.json()["completed"] is True, answer.text
        assert api.session(token, sid)["completion_code"] == "AUTO2024"
        detail = client.get(f"/api/review/episodes/{sid}-e1", headers=_as(ADMIN)).json()
    assert [(h["decision"], h["reviewer"], h["automatic"]) for h in detail["history"]] == [
        ("accepted", "auto", True)
    ]
    stored = current_review(tmp_path / "e1.hdf5")
    assert stored is not None and stored.reviewer == "auto"


def test_one_render_per_episode_at_a_time_and_a_failure_is_not_retried_at_once(
    tmp_path, monkeypatch
):
    from crowdteleop.coord.service import review_video

    renders: list[Path] = []

    async def replay(source: Path, output: Path) -> None:
        renders.append(source)
        await asyncio.sleep(0.05)
        if source.name == "broken.hdf5":
            raise review_video.RenderError("the replay tool failed (1): no states")
        output.write_bytes(b"an mp4")

    monkeypatch.setattr(review_video, "replay", replay)
    for name in ("good.hdf5", "broken.hdf5"):
        (tmp_path / name).write_bytes(b"")
    videos = review_video.EpisodeVideos(coord_config(tmp_path))
    good = Episode(episode_id="good", uri=(tmp_path / "good.hdf5").as_uri())
    broken = Episode(episode_id="broken", uri=(tmp_path / "broken.hdf5").as_uri())

    async def scenario() -> list[Any]:
        paths = await asyncio.gather(*(videos.video(good) for _ in range(3)))
        failures = await asyncio.gather(
            *(videos.video(broken) for _ in range(2)), return_exceptions=True
        )
        return [
            *paths,
            *failures,
            *await asyncio.gather(videos.video(broken), return_exceptions=True),
        ]

    results = _run(scenario())
    assert results[0] == results[1] == results[2] == videos.cache / "good.mp4"
    assert all(isinstance(r, review_video.RenderError) for r in results[3:]), results
    assert "no states" in str(results[-1])
    assert [path.name for path in renders] == ["good.hdf5", "broken.hdf5"], "once each"
