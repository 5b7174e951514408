"""The coordinator's database layer, on SQLite and on the machine's real PostgreSQL."""

from __future__ import annotations

import asyncio
import sqlite3
import time

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import create_engine, inspect

from crowdteleop.coord.db.engine import make_engine, migrate, migrate_sync, sync_url
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Base, Episode, Session
from crowdteleop.coord.service.campaign import CampaignConfig


def _run(coroutine):
    return asyncio.run(asyncio.wait_for(coroutine, 60))


async def _store(url: str) -> Store:
    await migrate(url)
    return Store(make_engine(url))


def _session(worker_id: str, sid: str, created_at: float, state: str = "queued") -> Session:
    return Session(
        id=sid,
        worker_id=worker_id,
        campaign="default",
        state=state,
        task="lift",
        robot="Sawyer",
        controller="ik-velocity",
        interfaces=["phone", "keyboard"],
        time_limit_s=600.0,
        demos_required=2,
        demos_done=0,
        created_at=created_at,
        last_heartbeat_at=created_at,
        report_token_hash="h",
    )


def _episode(
    eid: str, sid: str, outcome: str = "success", metrics: dict | None = None, task: str = "lift"
) -> Episode:
    return Episode(
        episode_id=eid,
        session_id=sid,
        worker_id="w",
        number=1,
        outcome=outcome,
        steps=80,
        duration_s=4.0,
        uri="file:///x.hdf5",
        interface="phone",
        task=task,
        telemetry={"fps": 20},
        created_at=time.time(),
        metrics=metrics,
    )


def test_migrations_reach_the_models_and_run_twice(database_url):
    _run(migrate(database_url))
    _run(migrate(database_url))  # a second start finds nothing to do
    engine = create_engine(sync_url(database_url))
    try:
        with engine.connect() as connection:
            diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
            tables = set(inspect(connection).get_table_names())
    finally:
        engine.dispose()
    assert diff == [], "tables.py changed without an Alembic revision"
    assert {"workers", "sessions", "episodes", "events", "pairing_codes"} <= tables


def test_the_migration_to_derived_tokens_leaves_no_token_in_the_sqlite_file(tmp_path):
    database = tmp_path / "coord.sqlite3"
    url = f"sqlite:///{database}"
    migrate_sync(url, "0001")
    # Sessions as 0001 stored them, their teleop tokens in clear, over several pages.
    tokens = [f"{kind}{n:042d}" for n in range(300) for kind in "TA"]
    db = sqlite3.connect(database)
    try:
        db.execute("PRAGMA journal_mode=WAL")
        columns = [row[1] for row in db.execute("PRAGMA table_info(sessions)")]
        insert = (
            f"INSERT INTO sessions ({', '.join(columns)}) VALUES ({', '.join('?' * len(columns))})"
        )
        for n in range(300):
            row = {c: "x" for c in columns} | {
                "id": f"s_{n}",
                "teleop_token": tokens[2 * n],
                "teleop_admin_token": tokens[2 * n + 1],
            }
            db.execute(insert, list(row.values()))
        db.commit()
    finally:
        db.close()
    assert tokens[0].encode() in database.read_bytes()
    migrate_sync(url)
    stored = b"".join(p.read_bytes() for p in tmp_path.iterdir() if p.name.startswith("coord"))
    assert [t for t in tokens if t.encode() in stored] == []
    with sqlite3.connect(database) as db:
        columns = [row[1] for row in db.execute("PRAGMA table_info(sessions)")]
        assert db.execute("SELECT count(*) FROM sessions").fetchone() == (300,), "sessions kept"
    assert "teleop_token" not in columns and "teleop_admin_token" not in columns


def test_rejoining_with_the_same_external_id_is_the_same_worker(database_url):
    async def scenario():
        store = await _store(database_url)
        try:
            await store.save_campaigns({"default": CampaignConfig().model_dump(mode="json")})
            workers = store.workers
            first, token1, created1 = await workers.join("default", "prolific", "PID1", "S", "X")
            again, token2, created2 = await workers.join("default", "prolific", "PID1", "S", "Y")
            other, _, _ = await workers.join("default", "mturk", "PID1")  # another platform
            anon1, _, _ = await workers.join("default", "anonymous", None)
            anon2, _, _ = await workers.join("default", "anonymous", None)
            by_old, _ = await workers.token_holder(token1)
            by_new, _ = await workers.token_holder(token2)
            nobody, _ = await workers.token_holder("not-a-token")
            return first, again, other, anon1, anon2, by_old, by_new, nobody, created1, created2
        finally:
            await store.close()

    first, again, other, anon1, anon2, by_old, by_new, nobody, created1, created2 = _run(scenario())
    assert (created1, created2) == (True, False)
    assert again.id == first.id and again.external_session == "Y"
    assert other.id != first.id
    assert anon1.id != anon2.id
    assert by_old.id == by_new.id == first.id, "every token a worker got stays valid"
    assert nobody is None


def test_episode_reports_count_once(database_url):
    async def scenario():
        store = await _store(database_url)
        try:
            worker, _, _ = await store.workers.join("default", "anonymous", None)
            await store.sessions.add_session(_session(worker.id, "s_0000000000000001", time.time()))
            sid = "s_0000000000000001"
            results = [
                await store.episodes.add_episode(_episode("e1", sid)),
                await store.episodes.add_episode(_episode("e1", sid)),  # a retried report
                await store.episodes.add_episode(_episode("e2", sid, outcome="reset")),
                await store.episodes.add_episode(_episode("e3", sid)),
            ]
            episodes = await store.episodes.episodes(sid)
            kinds = [e.kind for e in await store.sessions.events(sid)]
            return results, episodes, kinds
        finally:
            await store.close()

    results, episodes, kinds = _run(scenario())
    assert results == [(True, 1), (False, 1), (True, 1), (True, 2)]
    assert [e.episode_id for e in episodes] == ["e1", "e2", "e3"]
    assert kinds.count("episode") == 3 and kinds[0] == "queued"


def test_each_numeric_metric_is_a_row_and_a_tasks_distribution_one_query(database_url):
    async def scenario():
        store = await _store(database_url)
        try:
            worker, _, _ = await store.workers.join("default", "anonymous", None)
            sid = "s_0000000000000001"
            await store.sessions.add_session(_session(worker.id, sid, time.time()))
            for eid, idle, task in [("e1", 0.4, "lift"), ("e2", 0.1, "lift"), ("e3", 0.2, "door")]:
                metrics = {"idle_fraction": idle, "clutch_reanchors": 2, "longest_pause_stage": "x"}
                await store.episodes.add_episode(_episode(eid, sid, metrics=metrics, task=task))
            await store.episodes.add_episode(_episode("e1", sid, metrics={"idle_fraction": 9.0}))
            await store.episodes.add_episode(_episode("e4", sid))  # reported unmeasured
            return (
                await store.episodes.metric_values("idle_fraction", "lift"),
                await store.episodes.metric_values("idle_fraction"),
                await store.episodes.metric_values("clutch_reanchors"),
                await store.episodes.metric_values("longest_pause_stage"),
                [e.metrics for e in await store.episodes.episodes(sid)],
            )
        finally:
            await store.close()

    lift, every, reanchors, stages, kept = _run(scenario())
    assert lift == [0.1, 0.4], "ascending, of the task's episodes; the retried report ignored"
    assert every == [0.1, 0.2, 0.4] and reanchors == [2.0, 2.0, 2.0]
    assert stages == [], "a stage's name is kept with the episode, not as a number"
    assert kept[0]["longest_pause_stage"] == "x" and kept[-1] is None


def test_pairing_codes_are_single_use_and_expire(database_url):
    async def scenario():
        store = await _store(database_url)
        try:
            worker, _, _ = await store.workers.join("default", "anonymous", None)
            sid = "s_0000000000000002"
            await store.sessions.add_session(_session(worker.id, sid, time.time()))
            now = time.time()
            assert await store.pairing.add_code(sid, "ABC234", now + 60)
            clash = await store.pairing.add_code(sid, "ABC234", now + 60)
            assert await store.pairing.add_code(sid, "OLD234", now - 1)
            first = await store.pairing.redeem("ABC234", now)
            second = await store.pairing.redeem("ABC234", now)
            expired = await store.pairing.redeem("OLD234", now)
            phone = await store.pairing.session_of_phone(first[1]) if first else None
            return clash, first, second, expired, phone
        finally:
            await store.close()

    clash, first, second, expired, phone = _run(scenario())
    assert clash is False, "a live code is never handed out twice"
    assert first is not None and first[0] == "s_0000000000000002"
    assert second is None and expired is None
    assert phone is not None and phone.id == "s_0000000000000002"


def test_live_sessions_keep_queue_order_and_updates_respect_state(database_url):
    async def scenario():
        store = await _store(database_url)
        try:
            worker, _, _ = await store.workers.join("default", "anonymous", None)
            base = time.time()
            for i, sid in enumerate(["s_000000000000000c", "s_000000000000000a"]):
                await store.sessions.add_session(_session(worker.id, sid, base + i))
            order = [s.id for s in await store.sessions.live_sessions()]
            ended = await store.sessions.update_session(
                "s_000000000000000c", only_if_state=("queued",), state="ended"
            )
            again = await store.sessions.update_session(
                "s_000000000000000c", only_if_state=("queued",), state="ready"
            )
            live = [s.id for s in await store.sessions.live_sessions()]
            totals = await store.episodes.totals()
            return order, ended, again, live, totals
        finally:
            await store.close()

    order, ended, again, live, totals = _run(scenario())
    assert order == ["s_000000000000000c", "s_000000000000000a"], "FIFO by arrival"
    assert (ended, again) == (True, False), "an ended session never comes back"
    assert live == ["s_000000000000000a"]
    assert totals["sessions"] == 2 and totals["workers"] == 1


def test_unsupported_database_urls_say_what_is_supported():
    from crowdteleop.coord.db.engine import DatabaseUrlError

    with pytest.raises(DatabaseUrlError, match="sqlite:///FILE or postgresql"):
        sync_url("mysql://root@localhost/test")
