"""Who may open a new session: a join link is public, so the queue has limits
(`CoordConfig.admission`, docs/security.md): live sessions per client address, the queue's
length, and the wait a newcomer would face."""

from __future__ import annotations

from crowdteleop.coord.db.sessions import SessionStore
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.limits import retry_after
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.coord.service.waits import WaitEstimates


class AdmissionRules:
    def __init__(
        self,
        sessions: SessionStore,
        config: CoordConfig,
        metrics: CoordMetrics,
        waits: WaitEstimates,
    ) -> None:
        self.sessions, self.limits = sessions, config.admission
        self.metrics, self.waits = metrics, waits

    async def check(self, client_tag: str | None, free_slots: int) -> None:
        """Refuse a new session past the per-address, queue-length and wait limits; the
        caller holds the admission lock, so the counts cannot change under it."""
        limits = self.limits
        if client_tag is not None:
            open_here = await self.sessions.live_sessions_of_client(client_tag)
            if open_here >= limits.live_sessions_per_address:
                self.metrics.refused("sessions_per_address")
                raise ApiError(
                    429,
                    "too_many_sessions",
                    f"{open_here} sessions are already open from your network; finish or close "
                    "one first",
                )
        if free_slots > 0:
            return  # admitted at once: no queue to join
        live = await self.sessions.live_sessions()
        queued = sum(s.state == "queued" for s in live)
        if queued >= limits.max_queue:
            self.metrics.refused("queue_full")
            raise ApiError(
                503,
                "queue_full",
                f"the queue is full ({queued} waiting); please try again later",
                headers=retry_after(60),
            )
        wait_s = await self.waits.next_wait_s(live, queued)
        if wait_s > limits.max_wait_s:
            self.metrics.refused("wait_too_long")
            raise ApiError(
                503,
                "wait_too_long",
                f"the wait is about {wait_s / 60:.0f} min, longer than this study's "
                f"{limits.max_wait_s / 60:.0f} min; please try again later",
                headers=retry_after(min(wait_s - limits.max_wait_s, 3600)),
            )
