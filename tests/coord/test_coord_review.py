"""Reviewing demonstrations (issue 29, item 4; docs/review.md) on SQLite and PostgreSQL: the
decisions with their history, undo, two reviewers at once, the grid's filters, the API's
refusals, and the decision stored beside the episode file."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest

from crowdteleop.coord.db.engine import make_engine, migrate
from crowdteleop.coord.db.reviews import (
    EpisodeNotFoundError,
    NothingToUndoError,
    ReviewConflictError,
    ReviewFilters,
)
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Episode, Session, Worker


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
