"""When a session earns its completion code (docs/workers.md).

Without a review requirement (the campaign's `review.accepted_required` is 0) the code comes
with the session's `demos_required`-th successful demonstration, reviewed or not, and ends the
session, as it always did. With N > 0 the code waits until the session also has N accepted
demonstrations: an automatic accept (a clear score) counts at once; a reviewer's arrives
later, through `on_decided`, the hook the review service calls after every decision. Until
then the session stays live (the worker may record more, each a new chance), and the
worker's page shows how many are accepted and how many await review. When the code comes
the session ends as completed; if it had already ended (time up, left), the code is kept on
it, for the worker's page (or the study platform's support) to show later.
"""

from __future__ import annotations

from dataclasses import dataclass

from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Episode, Session
from crowdteleop.coord.db.worker_stats import WorkerStatsStore
from crowdteleop.coord.guard.security import new_completion_code
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.coordinator import Coordinator


@dataclass(frozen=True)
class ReviewProgress:
    """How far a held session is toward its code."""

    accepted_required: int
    accepted: int
    awaiting_review: int


class Completion:
    def __init__(self, store: Store, config: CoordConfig, coordinator: Coordinator) -> None:
        self._stats = WorkerStatsStore(store.transactions)
        self._sessions = store.sessions
        self._config, self._coordinator = config, coordinator

    def accepted_required(self, session: Session) -> int:
        """N: the accepted demonstrations the session's campaign wants before the code."""
        campaign = self._config.campaign(session.campaign)
        return campaign.review.accepted_required if campaign is not None else 0

    async def progress(self, session: Session) -> ReviewProgress | None:
        """Accepted and awaiting review, for a campaign that holds the code; else None."""
        required = self.accepted_required(session)
        if required == 0:
            return None
        counts = await self._stats.review_counts(session.id)
        return ReviewProgress(required, counts.accepted, counts.awaiting)

    async def after_success(self, session: Session, demos_done: int) -> bool:
        """A new successful demonstration was recorded (and judged): whether it completed
        the session."""
        if demos_done < session.demos_required:
            return False
        if self.accepted_required(session) == 0:
            # A short grace lets the page hear about the saved episode before the server goes.
            return await self._coordinator.end(
                session.id, "completed", completion_code=self._code(session), stop_delay_s=2.0
            )
        return await self._issue_if_earned(session.id)

    async def on_decided(self, episode: Episode) -> None:
        """The review service's hook, after each decision (a reviewer's or automatic)."""
        await self._issue_if_earned(episode.session_id)

    async def _issue_if_earned(self, session_id: str) -> bool:
        """Issue the code to a held session that has earned it; whether it was issued now."""
        session = await self._sessions.session(session_id)
        if session is None or session.completion_code is not None:
            return False
        required = self.accepted_required(session)
        if required == 0 or session.demos_done < session.demos_required:
            return False
        if (await self._stats.review_counts(session.id)).accepted < required:
            return False
        code = self._code(session)
        if await self._coordinator.end(
            session.id, "completed", completion_code=code, stop_delay_s=2.0
        ):
            return True
        return await self._stats.issue_code(session.id, code)

    def _code(self, session: Session) -> str:
        campaign = self._config.campaign(session.campaign)
        return (campaign.prolific_completion_code if campaign else None) or new_completion_code()
