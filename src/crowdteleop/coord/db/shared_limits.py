"""Rate limits counted in the database, so every coordinator replica counts the same events.

Used for wrong pairing codes: their budget protects the code space, so a guesser spreading
guesses over replicas must meet the same limit as one talking to a single replica. Each
check is one indexed count over at most `limit` rows of the last `window_s`; old events are
deleted at each reaper sweep (`forget_old`). The join and admin-token limits stay in each
replica's memory (`coord/guard/limits.py`): they shield that replica's own resources.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from sqlalchemy import delete, func, select
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from crowdteleop.coord.db.tables import LimitEvent

SHARED_WINDOW_S = 60.0  # every shared limit counts per minute; older events are deleted


@dataclass(frozen=True)
class SharedWindowLimiter:
    """At most `limit` events per key in any `window_s`, counted across replicas."""

    transactions: async_sessionmaker[AsyncSession]
    name: str  # which limit: rows of different limiters never mix
    limit: int
    window_s: float = SHARED_WINDOW_S

    async def wait_s(self, key: str, now: float | None = None) -> float:
        """Seconds until `key` may have another event (0: now)."""
        now = time.time() if now is None else now
        async with self.transactions() as db:
            recent = (
                select(LimitEvent.at)
                .where(
                    LimitEvent.limiter == self.name,
                    LimitEvent.key == key,
                    LimitEvent.at > now - self.window_s,
                )
                .order_by(LimitEvent.at.desc())
                .limit(self.limit)
                .subquery()
            )
            count, oldest = (
                await db.execute(select(func.count(), func.min(recent.c.at)).select_from(recent))
            ).one()
        if count < self.limit or oldest is None:
            return 0.0
        return max(0.0, float(oldest) + self.window_s - now)

    async def hit(self, key: str, now: float | None = None) -> None:
        now = time.time() if now is None else now
        async with self.transactions.begin() as db:
            db.add(LimitEvent(limiter=self.name, key=key, at=now))


async def forget_old(
    transactions: async_sessionmaker[AsyncSession], window_s: float, now: float | None = None
) -> None:
    """Drop events no window can count any more."""
    now = time.time() if now is None else now
    async with transactions.begin() as db:
        await db.execute(delete(LimitEvent).where(LimitEvent.at <= now - window_s))
