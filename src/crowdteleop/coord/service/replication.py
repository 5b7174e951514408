"""Replicas keep each other's sessions going (run at every reaper sweep).

- `adopt`: a session whose replica stopped (its row gone) or went silent for
  `replica_stale_after_s` (killed, or cut off from the database) is taken over by this one:
  its running server is watched from here, or, if it cannot be taken back, the session is
  queued again at its place with its count kept.
- `reconcile`: a session this replica watches may have been ended by another (its worker
  left through the other one, or finished there): its server is stopped here. One taken over
  by another replica is let go without stopping its server.
"""

from __future__ import annotations

import logging

from crowdteleop.coord.db.shared_limits import SHARED_WINDOW_S, forget_old
from crowdteleop.coord.service.coordinator import Coordinator

log = logging.getLogger(__name__)


async def adopt(coordinator: Coordinator, alive: set[str]) -> list[str]:
    """Take over the sessions no live replica (of `alive`) watches; returns their ids."""
    replicas = coordinator.replicas
    orphaned = [
        s
        for s in await coordinator.store.live_sessions()
        if s.state != "queued" and s.replica not in alive
    ]
    if not orphaned:
        return []
    adopted = []
    async with coordinator.lock:
        alive = await replicas.alive()
        for stale in orphaned:
            session = await coordinator.store.session(stale.id)  # again, under the lock
            if session is None or session.state not in ("starting", "ready"):
                continue
            if session.replica in alive:
                continue  # another replica took it meanwhile
            log.warning("session %s: replica %s is gone; taking over", session.id, session.replica)
            await coordinator.take_over(session, "the coordinator serving it stopped")
            adopted.append(session.id)
        await coordinator.admit_locked()
    return adopted


async def reconcile(coordinator: Coordinator) -> None:
    """Let go of the servers of sessions this replica no longer holds."""
    pool, name = coordinator.pool, coordinator.replicas.name
    async with coordinator.lock:
        watched = [sid for sid, slot in pool.slots.items() if slot.handle is not None]
        if not watched:  # (one starting here has no handle yet: its launch decides)
            return
        sessions = await coordinator.store.sessions_by_id(watched)
        for session_id in watched:
            session = sessions.get(session_id)
            held = session is not None and session.state in ("starting", "ready")
            if held and session is not None and session.replica == name:
                continue
            if held:  # another replica watches it now: its server keeps running
                pool.forget(session_id)
                log.info("session %s: now watched by %s", session_id, session and session.replica)
            else:
                pool.release(session_id)
                log.info("session %s ended elsewhere: its server stops", session_id)


async def sweep_shared_state(coordinator: Coordinator) -> None:
    await coordinator.replicas.beat()
    alive = await coordinator.replicas.alive()
    await adopt(coordinator, alive)
    await reconcile(coordinator)
    spares = coordinator.spares
    listed = await spares.sweep(alive)
    spares.fill(spares.short(coordinator.configs.spare_keys(), listed))  # replace those gone
    await forget_old(coordinator.store.transactions, SHARED_WINDOW_S)
