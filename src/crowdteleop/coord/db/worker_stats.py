"""What the workers page, the completion hold and the bonus files read: each worker's
episodes with their review decisions, a session's accepted demonstrations, and blocking."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from sqlalchemy import func, select, update
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from crowdteleop.coord.db.engine import rowcount
from crowdteleop.coord.db.tables import Episode, Session, Worker


@dataclass(frozen=True)
class ReviewCounts:
    """A session's demonstrations by their review decision."""

    accepted: int
    rejected: int
    awaiting: int  # successful and undecided (or undone)


class WorkerStatsStore:
    """Reads of workers and their episodes; the workers' blocked marks."""

    def __init__(self, transactions: async_sessionmaker[AsyncSession]) -> None:
        self.transactions = transactions

    async def workers(self, campaign: str | None = None) -> list[Worker]:
        """Every worker, or those with a session in `campaign`, oldest first."""
        statement = select(Worker).order_by(Worker.created_at)
        if campaign is not None:
            ids = select(Session.worker_id).where(Session.campaign == campaign)
            statement = statement.where(Worker.id.in_(ids))
        async with self.transactions() as db:
            return list(await db.scalars(statement))

    async def worker(self, worker_id: str) -> Worker | None:
        async with self.transactions() as db:
            return await db.get(Worker, worker_id)

    async def episodes(
        self, worker_ids: Iterable[str] | None = None, campaign: str | None = None
    ) -> list[Episode]:
        """The episodes of `worker_ids` (every worker's: None), of `campaign`'s sessions if
        given, oldest first."""
        statement = select(Episode).order_by(Episode.created_at)
        if worker_ids is not None:
            statement = statement.where(Episode.worker_id.in_(list(worker_ids)))
        if campaign is not None:
            statement = statement.join(Session).where(Session.campaign == campaign)
        async with self.transactions() as db:
            return list(await db.scalars(statement))

    async def review_counts(self, session_id: str) -> ReviewCounts:
        """The session's accepted and rejected episodes, and its successes awaiting review."""
        statement = (
            select(Episode.decision, Episode.outcome, func.count())
            .where(Episode.session_id == session_id)
            .group_by(Episode.decision, Episode.outcome)
        )
        counts = {"accepted": 0, "rejected": 0, "awaiting": 0}
        async with self.transactions() as db:
            for decision, outcome, count in await db.execute(statement):
                if decision in ("accepted", "rejected"):
                    counts[decision] += count
                elif outcome == "success":
                    counts["awaiting"] += count
        return ReviewCounts(**counts)

    async def issue_code(self, session_id: str, code: str) -> bool:
        """Give an ended session its completion code, unless it has one already."""
        async with self.transactions.begin() as db:
            result = await db.execute(
                update(Session)
                .where(Session.id == session_id, Session.completion_code.is_(None))
                .values(completion_code=code)
            )
            return rowcount(result) == 1

    async def set_blocked(
        self, worker_id: str, at: float | None, reason: str | None
    ) -> Worker | None:
        """Block (at: when) or unblock (at None) a worker; the worker, or None if unknown."""
        async with self.transactions.begin() as db:
            worker = await db.get(Worker, worker_id)
            if worker is not None:
                worker.blocked_at, worker.blocked_reason = at, reason
            return worker
