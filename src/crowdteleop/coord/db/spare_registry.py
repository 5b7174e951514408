"""Every replica's warm spares, in the database (the `spares` table).

On a cluster a spare holds a slot, so capacity is the cluster's slots less every replica's
spares, and any replica may hand any spare to the worker it admits: a claim takes the oldest
ready one of its kind and deletes its row in one transaction, skipping rows another replica is
claiming at that moment (`FOR UPDATE SKIP LOCKED` on PostgreSQL; SQLite serves one replica).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from sqlalchemy import delete, func, select, update
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from crowdteleop.coord.db.tables import Spare

SpareKey = tuple[str, str, str]  # task, robot, controller


def key_text(key: SpareKey) -> str:
    return "/".join(key)


@dataclass(frozen=True)
class SpareRow:
    id: str
    key: str
    replica: str
    server: str | None
    url: str | None  # none while it starts
    started_at: float | None = None  # when its start began (Unix seconds)


def _row(spare: Spare) -> SpareRow:
    return SpareRow(spare.id, spare.key, spare.replica, spare.server, spare.url, spare.started_at)


class SpareRegistry:
    """The `spares` rows, as seen by the replica named `replica`."""

    def __init__(self, transactions: async_sessionmaker[AsyncSession], replica: str) -> None:
        self.transactions, self.replica = transactions, replica

    async def add(self, spare_id: str, key: SpareKey) -> None:
        """A spare about to start (it counts from now: it will hold a slot)."""
        async with self.transactions.begin() as db:
            db.add(
                Spare(id=spare_id, key=key_text(key), replica=self.replica, started_at=time.time())
            )

    async def ready(self, spare_id: str, url: str, server: str | None) -> None:
        async with self.transactions.begin() as db:
            await db.execute(
                update(Spare).where(Spare.id == spare_id).values(url=url, server=server)
            )

    async def remove(self, spare_id: str) -> None:
        async with self.transactions.begin() as db:
            await db.execute(delete(Spare).where(Spare.id == spare_id))

    async def watch(self, spare_id: str) -> None:
        """This replica watches the spare now (its own replica is gone)."""
        async with self.transactions.begin() as db:
            await db.execute(update(Spare).where(Spare.id == spare_id).values(replica=self.replica))

    async def count(self, key: SpareKey | None = None, own: bool = False) -> int:
        """Spares (starting or ready) of `key` (any), of every replica or this one's own."""
        statement = select(func.count()).select_from(Spare)
        if key is not None:
            statement = statement.where(Spare.key == key_text(key))
        if own:
            statement = statement.where(Spare.replica == self.replica)
        async with self.transactions() as db:
            return int(await db.scalar(statement) or 0)

    async def rows(self) -> list[SpareRow]:
        async with self.transactions() as db:
            return [_row(spare) for spare in await db.scalars(select(Spare))]

    async def claim(self, key: SpareKey, any_replica: bool) -> SpareRow | None:
        """The oldest ready spare of `key` (of any replica, or this one's), removed from the
        registry for the caller to assign; None if there is none."""
        statement = (
            select(Spare)
            .where(Spare.key == key_text(key), Spare.url.is_not(None))
            .order_by(Spare.started_at)
            .limit(1)
            .with_for_update(skip_locked=True)
        )
        if not any_replica:
            statement = statement.where(Spare.replica == self.replica)
        async with self.transactions.begin() as db:
            spare = await db.scalar(statement)
            if spare is None:
                return None
            await db.delete(spare)
            return _row(spare)
