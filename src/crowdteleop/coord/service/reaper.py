"""Which sessions the reaper ends, so their slot (and process) goes to the next worker, and
which it gives a new server (the Coordinator applies the verdicts at each sweep):

- no heartbeat for `heartbeat_timeout_s` (tab closed, phone locked): abandoned
- queued for longer than the admission's `max_wait_s`: queue_timeout
- past the session's time limit since it became ready: timeout
- its teleop server exited: restart (queued again at its place), or error past `max_restarts`
"""

from __future__ import annotations

from typing import Final

from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.service.config import CoordConfig

RESTART: Final = "restart"  # not an end: the session gets a new server


def verdict(
    session: Session, now: float, config: CoordConfig, server_alive: bool | None
) -> str | None:
    """The reason a live session ends now, `RESTART`, or None to leave it be;
    `server_alive` is its server's (None while it starts)."""
    waited_s = now - (session.queued_at or session.created_at)
    if now - session.last_heartbeat_at > config.heartbeat_timeout_s:
        return "abandoned"
    if session.state == "queued" and waited_s > config.admission.max_wait_s:
        return "queue_timeout"
    if session.state == "ready":
        if session.ready_at is not None and now > session.ready_at + session.time_limit_s:
            return "timeout"
        if server_alive is False:
            return RESTART
    return None
