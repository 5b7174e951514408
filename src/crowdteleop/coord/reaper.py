"""Ends sessions nobody is at any more, so their slot (and process) goes to the next worker."""

from __future__ import annotations

import asyncio
import logging
import time

from crowdteleop.coord.service import Coordinator

log = logging.getLogger(__name__)


async def reap_once(coordinator: Coordinator, now: float | None = None) -> list[tuple[str, str]]:
    """One sweep; returns the (session id, reason) pairs it ended.

    - no heartbeat for `heartbeat_timeout_s` (tab closed, phone locked): abandoned
    - past the session's time limit since it became ready: timeout
    - its teleop server died: error
    """
    now = time.time() if now is None else now
    timeout = coordinator.config.heartbeat_timeout_s
    verdicts: list[tuple[str, str]] = []
    for session in await coordinator.store.live_sessions():
        reason = None
        if now - session.last_heartbeat_at > timeout:
            reason = "abandoned"
        elif session.state == "ready":
            if session.ready_at is not None and now > session.ready_at + session.time_limit_s:
                reason = "timeout"
            elif coordinator.pool.alive(session.id) is False:
                reason = "error"
        if reason is not None:
            error = "the teleop server exited" if reason == "error" else None
            if await coordinator.end(session.id, reason, error=error):
                log.info("reaped session %s: %s", session.id, reason)
                verdicts.append((session.id, reason))
    return verdicts


async def run_reaper(coordinator: Coordinator) -> None:
    """Sweep every `reaper_interval_s` until cancelled; one bad sweep never stops it."""
    while True:
        await asyncio.sleep(coordinator.config.reaper_interval_s)
        try:
            await reap_once(coordinator)
        except asyncio.CancelledError:
            raise
        except Exception:
            log.exception("reaper sweep failed")
