"""Ends sessions nobody is at any more, so their slot (and process) goes to the next worker."""

from __future__ import annotations

import asyncio
import logging
import time

from crowdteleop.coord.fleet.cluster import follow_cluster
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.coord.service.replication import sweep_shared_state

log = logging.getLogger(__name__)


async def reap_once(coordinator: Coordinator, now: float | None = None) -> list[tuple[str, str]]:
    """One sweep; returns the (session id, reason) pairs it ended.

    - no heartbeat for `heartbeat_timeout_s` (tab closed, phone locked): abandoned
    - queued for longer than the admission's `max_wait_s`: queue_timeout
    - past the session's time limit since it became ready: timeout
    - its teleop server exited: restarted (queued again at its place), or error past
      `max_restarts`
    """
    now = time.time() if now is None else now
    config = coordinator.config
    verdicts: list[tuple[str, str]] = []
    for session in await coordinator.store.live_sessions():
        reason = None
        waited_s = now - (session.queued_at or session.created_at)
        if now - session.last_heartbeat_at > config.heartbeat_timeout_s:
            reason = "abandoned"
        elif session.state == "queued" and waited_s > config.admission.max_wait_s:
            reason = "queue_timeout"
        elif session.state == "ready":
            if session.ready_at is not None and now > session.ready_at + session.time_limit_s:
                reason = "timeout"
            elif coordinator.pool.alive(session.id) is False:
                if await coordinator.restart(session.id, "exited", "the teleop server exited"):
                    verdicts.append((session.id, "restarted"))
                continue
        if reason is not None and await coordinator.end(session.id, reason):
            log.info("reaped session %s: %s", session.id, reason)
            verdicts.append((session.id, reason))
    return verdicts


async def run_reaper(coordinator: Coordinator) -> None:
    """Sweep every `reaper_interval_s` until cancelled; one bad sweep never stops it."""
    while True:
        await asyncio.sleep(coordinator.config.reaper_interval_s)
        try:
            await sweep_shared_state(coordinator)
            await follow_cluster(coordinator)
            await reap_once(coordinator)
        except asyncio.CancelledError:
            raise
        except Exception:
            log.exception("reaper sweep failed")
