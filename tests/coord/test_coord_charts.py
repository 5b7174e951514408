"""The admin page's charts (`GET /api/admin/charts`), on SQLite and PostgreSQL: sessions and
episodes written at known times land in the bins they should, with the queue's and the live
sessions' levels over time, the waits, the latencies and the scores' histogram."""

from __future__ import annotations

import time
from typing import Any

import pytest
from sqlalchemy import create_engine
from sqlalchemy.orm import Session as Transaction

from crowdteleop.coord.db.engine import sync_url
from crowdteleop.coord.db.tables import Episode, Session, Worker
from tests.fixtures.coord import ADMIN, FakeLauncher, coord_config, in_process_app

pytestmark = pytest.mark.filterwarnings("ignore:Using `httpx`")
HOUR = 3600.0


def _session(sid: str, queued: float, admitted: float | None, ended: float | None) -> Session:
    return Session(
        id=sid,
        worker_id="w-charts",
        campaign="default",
        state="ended" if ended is not None else "ready",
        task="lift",
        robot="Sawyer",
        controller="ik-velocity",
        interfaces=["keyboard"],
        time_limit_s=600.0,
        demos_required=3,
        demos_done=0,
        created_at=queued,
        queued_at=queued,
        restarts=0,
        admitted_at=admitted,
        ended_at=ended,
        ended_reason="left" if ended is not None else None,
        last_heartbeat_at=ended or queued,
        report_token_hash=f"hash-{sid}",
    )


def _episode(
    eid: str, at: float, outcome: str, score: float | None = None, **figures: Any
) -> Episode:
    return Episode(
        episode_id=eid,
        session_id="s-one",
        worker_id="w-charts",
        number=1,
        outcome=outcome,
        steps=70,
        duration_s=3.5,
        uri=f"file:///data/{eid}.hdf5",
        interface="keyboard",
        task="lift",
        telemetry=figures.get("telemetry", {}),
        metrics=figures.get("metrics"),
        created_at=at,
        score=score,
    )


def _write_history(database_url: str, b0: float) -> None:
    """Three hours, b0 the first one's start (b1 = b0 + 1 h, the last starts at b0 + 2 h)."""
    b1, b2 = b0 + HOUR, b0 + 2 * HOUR
    rows: list[Any] = [
        Worker(
            id="w-charts", source="anonymous", campaign="default", params={}, created_at=b0 - 9000
        ),
        _session("s-gone", b0 - 7200, b0 - 7100, b0 - 3600),  # over before the window
        _session("s-one", b0 + 600, b0 + 900, b0 + 2700),  # waited 300 s, live 30 min
        _session("s-two", b0 + 700, b0 + 1500, b1 + 1800),  # waited 800 s, live into b1
        _session("s-left", b1 + 100, None, b1 + 400),  # gave up after 300 s in line
        _session("s-early", b0 - 1000, b0 - 500, b1 + 600),  # live since before the window
    ]
    rows += [
        _episode("e-before", b0 - 100, "success", 10.0),  # before the window: not counted
        _episode(
            "e-1",
            b0 + 1000,
            "success",
            95.0,
            metrics={"latency_p50_ms": 40.0, "latency_p95_ms": 90.0},
        ),
        _episode(
            "e-2",
            b0 + 2000,
            "timeout",
            telemetry={"latency_p50_ms": 60.0, "latency_p95_ms": 150.0},
        ),
        # A latency of 0: no client reported one (unknown, not instant).
        _episode("e-3", b1 + 10, "success", 100.0, telemetry={"latency_p50_ms": 0, "fps": 20.0}),
        _episode("e-4", b1 + 20, "success"),  # reported unmeasured: no score
        _episode("e-5", b2, "success", 42.5),  # the bin still filling
    ]
    engine = create_engine(sync_url(database_url))
    try:
        with Transaction(engine) as db, db.begin():
            db.add_all(rows[:1])
            db.flush()
            db.add_all(rows[1:6])
            db.flush()
            db.add_all(rows[6:])
    finally:
        engine.dispose()


def _this_hour() -> float:
    """The current clock hour's start; waits out the last seconds of an hour, so the request
    below sees the same bins."""
    now = time.time()
    if now % HOUR > HOUR - 20:
        time.sleep(HOUR - now % HOUR + 0.5)
        now = time.time()
    return now - now % HOUR


def test_sessions_and_episodes_fall_in_their_bins(tmp_path, database_url):
    with in_process_app(coord_config(tmp_path, database_url), FakeLauncher()) as client:
        current = _this_hour()
        b0 = current - 2 * HOUR
        _write_history(database_url, b0)
        response = client.get(
            "/api/admin/charts",
            params={"hours": 3, "bin_s": 3600},
            headers={"Authorization": f"Bearer {ADMIN}"},
        )
    assert response.status_code == 200, response.text
    charts = response.json()
    assert charts["bin_s"] == 3600 and charts["now_s"] >= current
    first, second, last = charts["bins"]
    assert [b["start_s"] for b in charts["bins"]] == [b0, b0 + HOUR, current]

    assert (first["episodes"], first["successes"]) == (2, 1)
    assert (second["episodes"], second["successes"]) == (2, 2)
    assert (last["episodes"], last["successes"]) == (1, 1)

    # In line: s-one [600, 900) and s-two [700, 1500) overlap; s-left [100, 400) of b1.
    assert first["queue_length_max"] == 2
    assert first["queue_length_mean"] == pytest.approx((300 + 800) / HOUR, abs=1e-3)
    assert second["queue_length_max"] == 1
    assert second["queue_length_mean"] == pytest.approx(300 / HOUR, abs=1e-3)
    assert last["queue_length_max"] == 0 and last["queue_length_mean"] == 0

    # Waits end when a session is admitted or leaves the line: 300 s and 800 s, then 300 s.
    assert (first["queue_wait_s_median"], first["queue_wait_s_max"]) == (550.0, 800.0)
    assert (second["queue_wait_s_median"], second["queue_wait_s_max"]) == (300.0, 300.0)
    assert last["queue_wait_s_median"] is None and last["queue_wait_s_max"] is None

    # Holding a robot: s-early all of b0 and 600 s of b1, s-one 1800 s, s-two 2100 + 1800 s.
    assert first["live_sessions_max"] == 3
    assert first["live_sessions_mean"] == pytest.approx((3600 + 1800 + 2100) / HOUR, abs=1e-3)
    assert second["live_sessions_max"] == 2
    assert second["live_sessions_mean"] == pytest.approx((600 + 1800) / HOUR, abs=1e-3)
    assert last["live_sessions_max"] == 0

    # The median of the episodes' own figures; metrics first, else telemetry; 0 is unknown.
    assert (first["latency_p50_ms"], first["latency_p95_ms"]) == (50.0, 120.0)
    assert second["latency_p50_ms"] is None and second["latency_p95_ms"] is None

    # The window's successful episodes: 95 and 100 in the top bin, 42.5 in 40-50.
    histogram = {(s["score_from"], s["score_to"]): s["demonstrations"] for s in charts["scores"]}
    assert len(histogram) == 10 and sum(histogram.values()) == 3
    assert histogram[(90.0, 100.0)] == 2 and histogram[(40.0, 50.0)] == 1
    assert charts["unscored"] == 1


def test_the_charts_need_the_admin_token_and_bounded_bins(tmp_path):
    with in_process_app(coord_config(tmp_path), FakeLauncher()) as client:
        admin = {"Authorization": f"Bearer {ADMIN}"}
        assert client.get("/api/admin/charts").status_code == 401
        empty = client.get("/api/admin/charts", headers=admin).json()
        too_many = client.get("/api/admin/charts?hours=168&bin_s=60", headers=admin)
        too_short = client.get("/api/admin/charts?bin_s=1", headers=admin)
    assert len(empty["bins"]) == 24 and empty["unscored"] == 0
    assert all(b["episodes"] == 0 and b["latency_p50_ms"] is None for b in empty["bins"])
    assert sum(s["demonstrations"] for s in empty["scores"]) == 0
    assert too_many.status_code == 422 and too_short.status_code == 422
