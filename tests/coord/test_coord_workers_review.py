"""Workers (issue 29, item 5; docs/workers.md) on SQLite and PostgreSQL: each worker's figures
and reputation, the completion code held until N demonstrations are accepted, blocking, and
the bonus files in Prolific's and MTurk's formats."""

from __future__ import annotations

import time
from typing import Any

import pytest
from sqlalchemy import create_engine, update
from sqlalchemy.orm import Session as Transaction

from crowdteleop.coord.db.engine import sync_url
from crowdteleop.coord.db.tables import Episode, ReviewDecisionRow, Session, Worker
from tests.fixtures.coord import ADMIN, Api, FakeLauncher, coord_config, in_process_app

pytestmark = pytest.mark.filterwarnings("ignore:Using `httpx`")

ADMIN_AUTH = {"Authorization": f"Bearer {ADMIN}"}
HELD = {
    "name": "held",
    "demos_required": 2,
    "review": {"accepted_required": 2},
    "prolific_completion_code": "HELD2024",
}
PROLIFIC = {"PROLIFIC_PID": "5f0a1b2c3d4e5f6a7b8c9d0e", "STUDY_ID": "s1", "SESSION_ID": "x1"}


def _write(database_url: str, *rows: Any) -> None:
    engine = create_engine(sync_url(database_url))
    try:
        with Transaction(engine) as db, db.begin():
            for row in rows:
                db.add(row)
                db.flush()
    finally:
        engine.dispose()


def _decide(database_url: str, episode_id: str, decision: str, reviewer: str = "ada") -> None:
    """A reviewer's decision as the review service stores it: the episode's current one and
    its history row."""
    engine = create_engine(sync_url(database_url))
    try:
        with Transaction(engine) as db, db.begin():
            episode = db.get(Episode, episode_id)
            assert episode is not None
            seq = episode.review_seq + 1
            db.execute(
                update(Episode)
                .where(Episode.episode_id == episode_id)
                .values(decision=decision, review_seq=seq)
            )
            db.add(
                ReviewDecisionRow(
                    episode_id=episode_id,
                    seq=seq,
                    decision=decision,
                    reason="",
                    reviewer=reviewer,
                    automatic=reviewer == "auto",
                    at=time.time(),
                )
            )
    finally:
        engine.dispose()


def _worker(wid: str, source: str, external: str | None, session: str | None = None) -> Worker:
    return Worker(
        id=wid,
        source=source,
        external_id=external,
        external_session=session,
        campaign="default",
        params={},
        created_at=time.time(),
    )


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


def _episode(eid: str, sid: str, wid: str, outcome: str, score: float | None, **more: Any):
    return Episode(
        episode_id=eid,
        session_id=sid,
        worker_id=wid,
        number=1,
        outcome=outcome,
        steps=100,
        duration_s=more.pop("duration_s", 10.0),
        uri=f"file:///data/{eid}.hdf5",
        interface="keyboard",
        task="lift",
        telemetry={},
        created_at=time.time(),
        score=score,
        **more,
    )


def _flag(metric: str) -> list[dict[str, str]]:
    return [{"metric": metric, "reason": f"{metric} past its threshold"}]


def _crowd(database_url: str) -> None:
    """A: 3 demonstrations (2 accepted, 1 rejected) and a timeout; B (MTurk): 2, 1 accepted;
    C: nothing yet."""
    _write(
        database_url,
        _worker("w_a", "prolific", "PA"),
        _worker("w_b", "mturk", "WB", "ASSIGN-B"),
        _worker("w_c", "anonymous", None),
        _session("s_a", "w_a"),
        _session("s_b", "w_b"),
        _episode(
            "a1", "s_a", "w_a", "success", 80.0, duration_s=10.0, flags=_flag("longest_pause_s")
        ),
        _episode("a2", "s_a", "w_a", "success", 60.0, duration_s=20.0),
        _episode("a3", "s_a", "w_a", "success", 40.0, duration_s=30.0, flags=_flag("path_ratio")),
        _episode("a4", "s_a", "w_a", "timeout", None, duration_s=60.0),
        _episode("b1", "s_b", "w_b", "success", 90.0, duration_s=12.0),
        _episode("b2", "s_b", "w_b", "success", 70.0, duration_s=14.0),
    )
    for episode_id, decision in (("a1", "accepted"), ("a2", "accepted"), ("a3", "rejected")):
        _decide(database_url, episode_id, decision)
    _decide(database_url, "b1", "accepted", reviewer="auto")


def test_each_workers_figures_and_reputation_and_the_bonus_files(tmp_path, database_url):
    config = coord_config(tmp_path, database_url, capacity=1)
    with in_process_app(config, FakeLauncher()) as client:
        _crowd(database_url)
        listed = client.get("/api/admin/workers", headers=ADMIN_AUTH)
        assert listed.status_code == 200, listed.text
        by_id = {w["worker_id"]: w for w in listed.json()}
        assert by_id["w_a"]["stats"] == {
            "episodes": 4,
            "demonstrations": 3,
            "success_rate": 0.75,
            "median_score": 60.0,
            "accepted": 2,
            "rejected": 1,
            "undecided": 0,
            "acceptance_rate": 0.6667,
            "flags": {"longest_pause_s": 1, "path_ratio": 1},
            "median_time_s": 20.0,
        }
        assert by_id["w_b"]["stats"]["undecided"] == 1
        assert by_id["w_b"]["stats"]["median_time_s"] == 13.0
        assert by_id["w_c"]["stats"]["episodes"] == 0
        # The campaign accepted 3 of 4 decided and its median score is 70: a newcomer sits
        # there (45 + 28); A's 2 of 3 and median 60 fall below it, B's 1 of 1 and 80 above.
        reputations = {w["worker_id"]: w["reputation"] for w in listed.json()}
        assert reputations == {"w_b": 76.6, "w_c": 73.0, "w_a": 69.6}
        assert [w["worker_id"] for w in listed.json()] == ["w_b", "w_c", "w_a"]
        by_score = client.get(
            "/api/admin/workers?sort=median_score&descending=false", headers=ADMIN_AUTH
        ).json()
        assert [w["worker_id"] for w in by_score] == ["w_c", "w_a", "w_b"]

        detail = client.get("/api/admin/workers/w_a", headers=ADMIN_AUTH).json()
        assert [(e["episode_id"], e["decision"]) for e in detail["episodes"]] == [
            ("a1", "accepted"),
            ("a2", "accepted"),
            ("a3", "rejected"),
            ("a4", None),
        ]
        assert detail["episodes"][2]["flags"][0]["metric"] == "path_ratio"
        assert client.get("/api/admin/workers/w_nobody", headers=ADMIN_AUTH).status_code == 404

        def bonus(fmt: str, per: str) -> str:
            query = f"campaign=default&format={fmt}&per_accepted={per}"
            response = client.get(f"/api/admin/bonus?{query}", headers=ADMIN_AUTH)
            assert response.status_code == 200, response.text
            return response.text

        assert bonus("prolific", "0.10") == "PA,0.20\n"
        assert bonus("mturk", "0.125") == (
            "WorkerId,AssignmentId,BonusAmount,Reason\n"
            "WB,ASSIGN-B,0.13,1 accepted demonstration in default\n"
        )
        assert bonus("prolific", "1") == "PA,2.00\n"
        assert client.get("/api/admin/bonus?campaign=default").status_code == 401
        assert _bonus_by_cli(database_url, tmp_path, "prolific", "0.10") == "PA,0.20\n"
        assert _bonus_by_cli(database_url, tmp_path, "mturk", "0.5").endswith(
            "WB,ASSIGN-B,0.50,1 accepted demonstration in default\n"
        )


def _bonus_by_cli(database_url: str, tmp_path, fmt: str, per: str) -> str:
    """`crowdteleop review bonus ... -o FILE`, the file's text."""
    from typer.testing import CliRunner

    from crowdteleop.cli import app

    output = tmp_path / f"bonus-{fmt}.csv"
    arguments = ["review", "bonus", "--db", database_url, "--campaign", "default"]
    arguments += ["--format", fmt, "--per-accepted", per, "-o", str(output)]
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 0, result.output
    return output.read_text(encoding="utf-8")


def _report(client, teleop, number: int, outcome: str = "success") -> dict[str, Any]:
    report = {
        "session_id": teleop.session_id,
        "worker_id": teleop.worker_id,
        "episode": number,
        "episode_id": f"{teleop.session_id}-e{number}",
        "outcome": outcome,
        "steps": 70,
        "duration_s": 3.5,
        "uri": "file:///data/ep.hdf5",
        "telemetry": {},
    }
    headers = {"Authorization": f"Bearer {teleop.report_token}"}
    response = client.post("/internal/episodes", json=report, headers=headers)
    assert response.status_code == 200, response.text
    return response.json()


def _held_session(client, launcher, params=None):
    api = Api(client)
    token = api.join(params or PROLIFIC, campaign="held")["worker_token"]
    sid = api.new_session(token)["session_id"]
    api.wait_state(token, sid, "ready")
    return api, token, sid, launcher.handles[sid].config


def _accept(client, database_url: str, episode_id: str, session_id: str, reviewer: str) -> None:
    """A decision stored, then the review service's hook called, as it does after each."""
    _decide(database_url, episode_id, "accepted", reviewer)
    completion = client.app_state.completion
    decided = Episode(episode_id=episode_id, session_id=session_id)
    client.portal.call(completion.on_decided, decided)


def test_the_completion_code_waits_for_n_accepted_demonstrations(tmp_path, database_url):
    launcher = FakeLauncher()
    config = coord_config(tmp_path, database_url, capacity=1, campaigns=[HELD])
    with in_process_app(config, launcher) as client:
        api, token, sid, teleop = _held_session(client, launcher)
        assert api.session(token, sid)["accepted_required"] == 2
        assert _report(client, teleop, 1)["completed"] is False
        assert _report(client, teleop, 2)["completed"] is False, "none accepted yet"
        view = api.heartbeat(token, sid)
        assert (view["state"], view["completion_code"]) == ("ready", None), "held, still live"
        assert (view["accepted"], view["awaiting_review"]) == (0, 2)

        _accept(client, database_url, f"{sid}-e1", sid, reviewer="auto")  # a clear score
        view = api.session(token, sid)
        assert (view["accepted"], view["awaiting_review"], view["state"]) == (1, 1, "ready")

        _accept(client, database_url, f"{sid}-e2", sid, reviewer="ada")  # a reviewer, later
        view = api.session(token, sid)
        assert (view["state"], view["ended_reason"]) == ("ended", "completed")
        assert view["completion_code"] == "HELD2024"
        assert view["redirect_url"].endswith("cc=HELD2024")
        assert (view["accepted"], view["awaiting_review"]) == (2, 0)


def test_a_code_earned_after_the_session_ended_is_kept_for_the_worker(tmp_path, database_url):
    launcher = FakeLauncher()
    config = coord_config(tmp_path, database_url, capacity=1, campaigns=[HELD])
    with in_process_app(config, launcher) as client:
        api, token, sid, teleop = _held_session(client, launcher)
        _report(client, teleop, 1)
        _report(client, teleop, 2)
        assert client.post(f"/api/sessions/{sid}/leave", headers=api.auth(token)).is_success
        _accept(client, database_url, f"{sid}-e1", sid, reviewer="ada")
        assert api.session(token, sid)["completion_code"] is None
        _accept(client, database_url, f"{sid}-e2", sid, reviewer="ada")
        view = api.session(token, sid)
        assert (view["state"], view["ended_reason"]) == ("ended", "left")
        assert view["completion_code"] == "HELD2024"


def test_a_blocked_worker_is_refused_and_their_session_ended(tmp_path, database_url):
    launcher = FakeLauncher()
    config = coord_config(tmp_path, database_url, capacity=1)
    with in_process_app(config, launcher) as client:
        api = Api(client)
        joined = api.join(PROLIFIC)
        token, wid = joined["worker_token"], joined["worker_id"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready")

        blocked = client.post(
            f"/api/admin/workers/{wid}/block", json={"reason": "bot-like"}, headers=ADMIN_AUTH
        )
        assert blocked.status_code == 200, blocked.text
        assert blocked.json()["blocked_reason"] == "bot-like"
        view = api.session(token, sid)
        assert (view["state"], view["ended_reason"]) == ("ended", "error")

        again = client.post("/api/join", json={"params": PROLIFIC})
        assert again.status_code == 403, again.text
        assert again.json()["error"] == "blocked"
        assert "no longer accepts" in again.json()["message"]
        assert "bot-like" not in again.text, "the admin's reason is the admin's"
        fresh = client.post("/api/sessions", headers=api.auth(token))
        assert (fresh.status_code, fresh.json()["error"]) == (403, "blocked")
        assert api.admin("overview")["refusals"]["blocked"] == 2
        metrics = client.get("/metrics", headers=ADMIN_AUTH).text
        assert "crowdteleop_workers_blocked_total 1.0" in metrics

        unblocked = client.post(f"/api/admin/workers/{wid}/unblock", headers=ADMIN_AUTH)
        assert unblocked.json()["blocked_at"] is None
        assert api.join(PROLIFIC)["worker_id"] == wid
        missing = client.post("/api/admin/workers/w_none/block", json={}, headers=ADMIN_AUTH)
        assert missing.status_code == 404
