"""The rows the admin page's charts are drawn from: the times of the sessions and episodes of
the last hours, as few columns as the charts read (no episode's telemetry beyond its
latency, no session's tokens)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import or_, select
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from crowdteleop.coord.db.tables import Episode, Session


@dataclass(frozen=True)
class SessionTimes:
    """When a session was queued, admitted and ended (None: not yet)."""

    created_at: float
    queued_at: float | None
    admitted_at: float | None
    ended_at: float | None


@dataclass(frozen=True)
class EpisodeFigures:
    """What the charts read of an episode."""

    created_at: float
    outcome: str
    score: float | None
    metrics: dict[str, Any] | None
    telemetry: dict[str, Any]


class HistoryStore:
    """Range scans over `sessions` and `episodes` by time (both are indexed on created_at)."""

    def __init__(self, transactions: async_sessionmaker[AsyncSession]) -> None:
        self.transactions = transactions

    async def sessions_since(self, since: float) -> list[SessionTimes]:
        """Sessions that were still running or waiting at `since`, or began after it."""
        statement = select(
            Session.created_at, Session.queued_at, Session.admitted_at, Session.ended_at
        ).where(or_(Session.ended_at.is_(None), Session.ended_at >= since))
        async with self.transactions() as db:
            return [SessionTimes(*row) for row in await db.execute(statement)]

    async def episodes_since(self, since: float) -> list[EpisodeFigures]:
        """Episodes reported at `since` or after."""
        statement = select(
            Episode.created_at, Episode.outcome, Episode.score, Episode.metrics, Episode.telemetry
        ).where(Episode.created_at >= since)
        async with self.transactions() as db:
            return [EpisodeFigures(*row) for row in await db.execute(statement)]
