"""Episodes the teleop servers reported, and the totals the admin page shows."""

from __future__ import annotations

from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker
from sqlalchemy.sql import ColumnElement

from crowdteleop.coord.db.tables import Base, Episode, EpisodeMetric, Event, Session, Worker


class EpisodeStore:
    """Each reported episode once (by its id), counting successes toward its session."""

    def __init__(self, transactions: async_sessionmaker[AsyncSession]) -> None:
        self.transactions = transactions

    async def add_episode(self, episode: Episode) -> tuple[bool, int]:
        """(new?, demos done). Idempotent by episode id: a retried report counts once. Its
        numeric quality metrics go into `episode_metrics` in the same transaction."""
        try:
            async with self.transactions.begin() as db:
                if await db.get(Episode, episode.episode_id) is not None:
                    raise _DuplicateError
                db.add(episode)
                db.add_all(metric_rows(episode))
                if episode.outcome == "success":
                    await db.execute(
                        update(Session)
                        .where(Session.id == episode.session_id)
                        .values(demos_done=Session.demos_done + 1)
                    )
                db.add(
                    Event(
                        at=episode.created_at,
                        kind="episode",
                        session_id=episode.session_id,
                        worker_id=episode.worker_id,
                        data={"episode_id": episode.episode_id, "outcome": episode.outcome},
                    )
                )
            new = True
        except (_DuplicateError, IntegrityError):
            new = False
        async with self.transactions() as db:
            done = await db.scalar(
                select(Session.demos_done).where(Session.id == episode.session_id)
            )
        return new, done or 0

    async def metric_values(
        self, name: str, task: str | None = None, campaign: str | None = None
    ) -> list[float]:
        """The metric `name` over the successful episodes (of `task`, of `campaign`'s
        sessions), ascending: the distribution a score is a percentile of."""
        statement = (
            select(EpisodeMetric.value)
            .join(Episode)
            .where(EpisodeMetric.name == name, Episode.outcome == "success")
        )
        if task is not None:
            statement = statement.where(Episode.task == task)
        if campaign is not None:
            statement = statement.join(Session).where(Session.campaign == campaign)
        async with self.transactions() as db:
            return list(await db.scalars(statement.order_by(EpisodeMetric.value)))

    async def judge(
        self, episode_id: str, score: float | None, flags: list[dict[str, str]]
    ) -> None:
        """Keep the score and flags the coordinator gave the episode."""
        async with self.transactions.begin() as db:
            await db.execute(
                update(Episode)
                .where(Episode.episode_id == episode_id)
                .values(score=score, flags=flags)
            )

    async def episodes_since(self, since: float) -> list[Episode]:
        async with self.transactions() as db:
            return list(await db.scalars(select(Episode).where(Episode.created_at >= since)))

    async def episodes(self, session_id: str | None = None) -> list[Episode]:
        async with self.transactions() as db:
            statement = select(Episode).order_by(Episode.created_at)
            if session_id is not None:
                statement = statement.where(Episode.session_id == session_id)
            return list(await db.scalars(statement))

    async def totals(self) -> dict[str, int]:
        async with self.transactions() as db:

            async def count(model: type[Base], *where: ColumnElement[bool]) -> int:
                return await db.scalar(select(func.count()).select_from(model).where(*where)) or 0

            return {
                "workers": await count(Worker),
                "sessions": await count(Session),
                "completed_sessions": await count(Session, Session.ended_reason == "completed"),
                "episodes": await count(Episode),
                "successes": await count(Episode, Episode.outcome == "success"),
            }


def metric_rows(episode: Episode) -> list[EpisodeMetric]:
    """The episode's numeric metrics as rows (counts and booleans are numbers too; the
    stage a pause was in is not)."""
    return [
        EpisodeMetric(episode_id=episode.episode_id, name=name, value=float(value))
        for name, value in (episode.metrics or {}).items()
        if isinstance(value, int | float)
    ]


class _DuplicateError(Exception):
    pass
