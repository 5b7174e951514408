"""Replicas keep each other's sessions going (the Coordinator runs these at every reaper sweep
and at its start, each under its admission lock).

- `take_over`: a session's running server is watched from this replica, or, if it cannot be
  taken back, the session is queued again at its place with its count kept.
- `adopt`: a session whose replica stopped (its row gone) or went silent for
  `replica_stale_after_s` (killed, or cut off from the database) is taken over by this one.
- `reconcile`: a session this replica watches may have been ended by another (its worker
  left through the other one, or finished there): its server is stopped here. One taken over
  by another replica is let go without stopping its server.
"""

from __future__ import annotations

import logging

from crowdteleop.coord.db.replicas import Replicas
from crowdteleop.coord.db.sessions import SessionStore
from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.fleet.launcher import Launcher, reattach
from crowdteleop.coord.fleet.pool import TeleopPool
from crowdteleop.coord.service.metrics import CoordMetrics

log = logging.getLogger(__name__)


def orphans(live: list[Session], alive: set[str]) -> list[Session]:
    """The sessions of `live` holding a slot that no replica of `alive` watches."""
    return [s for s in live if s.state != "queued" and s.replica not in alive]


class Replication:
    """This replica's side of the sessions replicas share; the caller holds the admission
    lock for each call."""

    def __init__(
        self,
        sessions: SessionStore,
        pool: TeleopPool,
        launcher: Launcher,
        replicas: Replicas,
        metrics: CoordMetrics,
    ) -> None:
        self.sessions, self.pool, self.launcher = sessions, pool, launcher
        self.replicas, self.metrics = replicas, metrics

    async def take_over(self, session: Session, why: str) -> bool:
        """Watch `session`'s running server from this replica, or queue the session again
        at its place (count kept) if its server cannot be taken back; whether it was."""
        handle = await reattach(self.launcher, session.id, session.server)
        if session.state == "ready" and self.pool.attach(session.id, handle):
            await self.sessions.update_session(session.id, replica=self.replicas.name)
            await self.sessions.log("taken_over", session.id, replica=self.replicas.name)
            return True
        if handle is not None:  # a server that never became ready: nobody wants it
            await self.launcher.stop(handle, grace_s=0.0)
        if await self.sessions.requeue(session.id, why, count_restart=False):
            self.metrics.restarts.labels(cause="coordinator_restart").inc()
        return False

    async def adopt(self, orphaned: list[Session]) -> list[str]:
        """Take over those of `orphaned` that no live replica took meanwhile; their ids."""
        alive = await self.replicas.alive()
        adopted = []
        for stale in orphaned:
            session = await self.sessions.session(stale.id)  # again, under the lock
            if session is None or session.state not in ("starting", "ready"):
                continue
            if session.replica in alive:
                continue  # another replica took it meanwhile
            log.warning("session %s: replica %s is gone; taking over", session.id, session.replica)
            await self.take_over(session, "the coordinator serving it stopped")
            adopted.append(session.id)
        return adopted

    async def reconcile(self) -> None:
        """Let go of the servers of sessions this replica no longer holds."""
        watched = [session_id for session_id, _handle in self.pool.running()]
        if not watched:  # (one starting here has no handle yet: its launch decides)
            return
        sessions = await self.sessions.sessions_by_id(watched)
        for session_id in watched:
            session = sessions.get(session_id)
            held = session is not None and session.state in ("starting", "ready")
            if held and session is not None and session.replica == self.replicas.name:
                continue
            if held:  # another replica watches it now: its server keeps running
                self.pool.forget(session_id)
                log.info("session %s: now watched by %s", session_id, session and session.replica)
            else:
                self.pool.release(session_id)
                log.info("session %s ended elsewhere: its server stops", session_id)
