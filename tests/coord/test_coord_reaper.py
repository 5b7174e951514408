"""The reaper's verdicts, one live session at a time (the Coordinator applies them each sweep)."""

from __future__ import annotations

import pytest

from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.service.reaper import RESTART, verdict
from tests.fixtures.coord import coord_config

NOW = 10_000.0


def _session(state: str, **fields: float) -> Session:
    values = {"created_at": NOW - 100, "queued_at": NOW - 100, "last_heartbeat_at": NOW - 1}
    values.update(fields)
    return Session(id="s_0000000000000001", state=state, time_limit_s=600.0, **values)


@pytest.mark.parametrize(
    ("session", "server_alive", "expected"),
    [
        (_session("ready", ready_at=NOW - 10), True, None),
        (_session("ready", ready_at=NOW - 10, last_heartbeat_at=NOW - 31), True, "abandoned"),
        (_session("queued", queued_at=NOW - 3601), None, "queue_timeout"),
        (_session("queued", queued_at=None, created_at=NOW - 3601), None, "queue_timeout"),
        (_session("ready", ready_at=NOW - 601), True, "timeout"),
        (_session("ready", ready_at=NOW - 10), False, RESTART),
        (_session("starting"), None, None),
        (_session("starting", created_at=NOW - 7200, queued_at=NOW - 7200), None, None),
    ],
)
def test_each_live_session_gets_its_verdict(tmp_path, session, server_alive, expected):
    config = coord_config(tmp_path)  # heartbeats 30 s, waits at most an hour
    assert verdict(session, NOW, config, server_alive) == expected
