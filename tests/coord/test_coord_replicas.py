"""Two coordinator replicas on one PostgreSQL database (issue 14): workers joining through both
at once are admitted strictly first come, first served, never past the capacity; a pairing code
made on one redeems on the other; wrong codes count against one limit across both; a session
ended through one replica stops its server on the other; a replica that goes silent has its
sessions taken over.

Each replica is a real uvicorn server with its own instant launcher (the teleop servers of
these tests answer offers and health checks only; the Ray test in test_ray_replicas.py runs
real ones). The replicas share nothing but the database."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import psycopg

from crowdteleop.coord.app import create_app
from tests.fixtures.coord import ADMIN, FakeLauncher, coord_config, served_app

CAPACITY = 3
WORKERS = 24
# Every test worker comes from 127.0.0.1: no per-address limit, no wait limit.
OPEN_ADMISSION = {
    "max_wait_s": 86400,
    "live_sessions_per_address": 256,
    "joins_per_minute_per_address": 600,
}


@contextlib.contextmanager
def replica(tmp_path: Path, database: str, name: str, **fields: Any) -> Iterator[Any]:
    """A coordinator replica named `name`: (base URL, its launcher)."""
    config = coord_config(
        tmp_path / name,
        database,
        capacity=CAPACITY,
        replica_name=name,
        replica_stale_after_s=2.0,
        pair_failures_per_minute=4,
        admission=OPEN_ADMISSION,
        **fields,
    )
    launcher = FakeLauncher(start_delay_s=0.2)
    with served_app(create_app(config, launcher), config) as url:
        yield url, launcher


def join_and_queue(url: str, number: int) -> tuple[str, str, str]:
    """A worker joins at `url` and asks for a session: (url, token, session id)."""
    with httpx.Client(base_url=url, timeout=30) as http:
        joined = http.post("/api/join", json={"params": {"PROLIFIC_PID": f"worker{number:03d}"}})
        assert joined.status_code == 200, joined.text
        token = joined.json()["worker_token"]
        made = http.post("/api/sessions", headers={"Authorization": f"Bearer {token}"})
        assert made.status_code == 200, made.text
        return url, token, made.json()["session_id"]


def rows(database: str) -> list[dict[str, Any]]:
    with psycopg.connect(database, row_factory=psycopg.rows.dict_row) as db:
        return db.execute(
            "SELECT id, state, created_at, admitted_at, replica FROM sessions ORDER BY created_at"
        ).fetchall()


def held(database: str) -> int:
    return sum(r["state"] in ("starting", "ready") for r in rows(database))


def wait_for(condition: Any, timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def test_two_replicas_admit_in_order_within_capacity_and_share_pairing_and_limits(
    tmp_path, shared_database
):
    with (
        replica(tmp_path, shared_database, "a") as (url_a, launcher_a),
        replica(tmp_path, shared_database, "b") as (url_b, launcher_b),
    ):
        # WORKERS at once, every other one through each replica.
        with ThreadPoolExecutor(WORKERS) as pool:
            workers = list(
                pool.map(lambda n: join_and_queue((url_a, url_b)[n % 2], n), range(WORKERS))
            )
        assert held(shared_database) == CAPACITY, "never past the capacity"
        wait_for(lambda: sum(r["state"] == "ready" for r in rows(shared_database)) == CAPACITY)
        by_id = {sid: (url, token) for url, token, sid in workers}

        admitted_order: list[str] = []
        for _ in range(WORKERS):
            table = rows(shared_database)
            assert held(shared_database) <= CAPACITY
            live = [r for r in table if r["state"] in ("starting", "ready")]
            queued = [r for r in table if r["state"] == "queued"]
            admitted_order += [r["id"] for r in live if r["id"] not in admitted_order]
            if queued:  # FIFO: nobody waiting was created before anyone holding a slot
                assert min(r["created_at"] for r in queued) > max(r["created_at"] for r in live)
            oldest = min(live, key=lambda r: r["created_at"])
            # The worker leaves through the replica that did not launch its server.
            other = url_b if oldest["replica"] == "a" else url_a
            with httpx.Client(base_url=other, timeout=30) as http:
                left = http.post(
                    f"/api/sessions/{oldest['id']}/leave",
                    headers={"Authorization": f"Bearer {by_id[oldest['id']][1]}"},
                )
                assert left.status_code == 200, left.text
            if len(live) == 1 and not queued:
                break
            left_live = min(CAPACITY, len(live) + len(queued) - 1)
            wait_for(lambda n=left_live: held(shared_database) == n)
        in_order = [r["id"] for r in rows(shared_database)]
        assert admitted_order == in_order, "first come, first served"
        assert {r["replica"] for r in rows(shared_database)} == {"a", "b"}, "both launched some"
        # Each ended session's server is stopped by the replica that launched it.
        wait_for(lambda: set(launcher_a.stopped) | set(launcher_b.stopped) == set(by_id))

        # A pairing code made through one replica redeems through the other.
        _url, token, sid = join_and_queue(url_a, 1000)
        with httpx.Client(timeout=30) as http:
            auth = {"Authorization": f"Bearer {token}"}
            code = http.post(f"{url_a}/api/sessions/{sid}/pairing", headers=auth).json()["code"]
            paired = http.post(f"{url_b}/api/pair", json={"code": code})
            assert paired.status_code == 200, paired.text
            assert paired.json()["session_id"] == sid
            # Wrong codes count across both: 4 allowed per address a minute, wherever sent.
            answers = [
                http.post(f"{(url_a, url_b)[n % 2]}/api/pair", json={"code": "ZZZZZZ"}).status_code
                for n in range(6)
            ]
            assert answers == [404, 404, 404, 404, 429, 429], answers
            code = http.post(f"{url_b}/api/sessions/{sid}/pairing", headers=auth).json()["code"]
            refused = http.post(f"{url_a}/api/pair", json={"code": code})
            assert refused.status_code == 429, "even a right code waits once the limit is hit"
            admin = {"Authorization": f"Bearer {ADMIN}"}
            for base in (url_a, url_b):
                text = http.get(f"{base}/metrics", headers=admin).text
                assert 'crowdteleop_refusals_total{reason="pair_rate_address"}' in text


def test_a_silent_replicas_sessions_are_taken_over(tmp_path, shared_database):
    with replica(tmp_path, shared_database, "b") as (url_b, _launcher_b):
        with replica(tmp_path, shared_database, "a") as (url_a, _launcher_a):
            workers = [join_and_queue(url_a, n) for n in range(2)]
            wait_for(lambda: sum(r["state"] == "ready" for r in rows(shared_database)) == 2)
            assert {r["replica"] for r in rows(shared_database)} == {"a"}
        # a stopped; its instant servers cannot outlive it, so b queues the sessions again
        # at their places and launches them anew: the workers keep their sessions.
        wait_for(
            lambda: (
                [r["replica"] for r in rows(shared_database) if r["state"] == "ready"] == ["b", "b"]
            )
        )
        with httpx.Client(base_url=url_b, timeout=30) as http:
            for _url, token, sid in workers:
                view = http.get(
                    f"/api/sessions/{sid}", headers={"Authorization": f"Bearer {token}"}
                ).json()
                assert view["state"] == "ready", view


async def racing_replicas(tmp_path: Path, database: str) -> tuple[int, list[str], list[str]]:
    """Two replicas' coordinators in one event loop, 40 workers asking for a session through
    both at once (every database round trip lets the other replica in): the most sessions
    ever holding a slot, the sessions launched (once per launch), the first three asking."""
    import asyncio

    from crowdteleop.coord.db.engine import make_engine, migrate
    from crowdteleop.coord.db.store import Store
    from crowdteleop.coord.guard.session_keys import SessionKeys
    from crowdteleop.coord.service.coordinator import Coordinator

    await migrate(database)
    tmp_path.mkdir(parents=True, exist_ok=True)
    replicas, stores, launchers = [], [], []
    for name in ("a", "b"):
        config = coord_config(
            tmp_path / name,
            database,
            capacity=CAPACITY,
            replica_name=name,
            admission=OPEN_ADMISSION,
        )
        store, launcher = Store(make_engine(database)), FakeLauncher()
        coordinator = Coordinator(
            config, store, launcher, SessionKeys.load_or_create(tmp_path / f"{name}.key")
        )
        await coordinator.start()
        replicas.append(coordinator)
        stores.append(store)
        launchers.append(launcher)
    campaign = replicas[0].config.default_campaign
    workers = [
        (await stores[0].workers.join(campaign.name, "prolific", f"racer{n}"))[0] for n in range(40)
    ]
    most = 0

    async def watch() -> None:
        nonlocal most
        while True:
            most = max(most, await stores[0].sessions.held_slots())
            await asyncio.sleep(0)

    watcher = asyncio.create_task(watch())
    await asyncio.gather(
        *(replicas[n % 2].create_session(worker, campaign) for n, worker in enumerate(workers))
    )
    most = max(most, await stores[0].sessions.held_slots())
    watcher.cancel()
    await asyncio.sleep(0.5)  # the launches finish
    launched = [sid for launcher in launchers for sid in launcher.handles]
    first = [r["id"] for r in rows(database)][:CAPACITY]
    for coordinator, store in zip(replicas, stores, strict=True):
        await coordinator.close()
        await store.close()
    return most, launched, first


def test_replicas_racing_for_slots_admit_each_session_once_in_order(tmp_path, shared_database):
    import asyncio

    for attempt in range(3):
        most, launched, first = asyncio.run(
            racing_replicas(tmp_path / str(attempt), shared_database)
        )
        assert most == CAPACITY, "never past the capacity"
        assert sorted(launched) == sorted(first), "the first three, each launched once"
        with psycopg.connect(shared_database, autocommit=True) as db:
            db.execute("DROP SCHEMA public CASCADE")
            db.execute("CREATE SCHEMA public")
