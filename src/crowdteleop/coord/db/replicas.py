"""Coordinator replicas on one database: who is serving, and one admission lock for all.

Every replica writes its row in `replicas` at each reaper sweep. A session's teleop server is
watched by the replica named in `sessions.replica`; when that replica's row is gone (it
stopped) or silent for `stale_after_s` (it was killed), another takes the session over
(`Replication.adopt`). The admission lock is an asyncio lock in each process and, on
PostgreSQL, a transaction-level advisory lock shared by every replica: admissions are
decided one at a time, so the queue stays strictly FIFO and the capacity is never exceeded
however many replicas serve the campaign. SQLite serves one replica (one machine).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import time
from collections.abc import AsyncIterator

from sqlalchemy import delete, func, select
from sqlalchemy.ext.asyncio import AsyncEngine, AsyncSession, async_sessionmaker

from crowdteleop.coord.db.tables import Replica

log = logging.getLogger(__name__)

# The advisory lock's key: any 64-bit number no other application on the database uses.
ADMISSION_LOCK_KEY = 0x63726F7764  # "crowd"


def default_replica_name(port: int | None = None) -> str:
    """host:port names the same replica again after a restart (it takes its sessions back
    at once); without a port, host:pid."""
    return f"{socket.gethostname()}:{port if port is not None else os.getpid()}"


class AdmissionLock:
    """`async with lock:` one admission decision at a time, in this process and (PostgreSQL)
    across every replica of the database. Re-entrant use is a deadlock, as with asyncio's."""

    def __init__(self, engine: AsyncEngine) -> None:
        self.engine = engine
        self.shared = engine.dialect.name == "postgresql"
        self._local = asyncio.Lock()
        self._held: contextlib.AbstractAsyncContextManager[None] | None = None

    @contextlib.asynccontextmanager
    async def _database_lock(self) -> AsyncIterator[None]:
        """Held until the transaction ends: a replica that dies drops it with its connection."""
        async with self.engine.connect() as connection, connection.begin():
            await connection.execute(select(func.pg_advisory_xact_lock(ADMISSION_LOCK_KEY)))
            yield

    async def __aenter__(self) -> None:
        await self._local.acquire()
        if not self.shared:
            return
        held = self._database_lock()
        try:
            await held.__aenter__()
        except BaseException:
            self._local.release()
            raise
        self._held = held

    async def __aexit__(self, *exc: object) -> None:
        held, self._held = self._held, None
        try:
            if held is not None:
                await held.__aexit__(None, None, None)
        finally:
            self._local.release()

    def locked(self) -> bool:
        return self._local.locked()


class Replicas:
    """The `replicas` table: this replica's heartbeat, and who else is alive."""

    def __init__(
        self, transactions: async_sessionmaker[AsyncSession], name: str, stale_after_s: float
    ) -> None:
        self.transactions = transactions
        self.name = name
        self.stale_after_s = stale_after_s
        self.started_at = time.time()

    async def beat(self) -> None:
        now = time.time()
        async with self.transactions.begin() as db:
            row = await db.get(Replica, self.name)
            if row is None:
                db.add(Replica(name=self.name, started_at=self.started_at, seen_at=now))
            else:
                row.seen_at = now

    async def alive(self) -> set[str]:
        """Every replica heard from within `stale_after_s`, this one included."""
        since = time.time() - self.stale_after_s
        async with self.transactions() as db:
            names = await db.scalars(select(Replica.name).where(Replica.seen_at > since))
            return set(names) | {self.name}

    async def others_alive(self) -> set[str]:
        return await self.alive() - {self.name}

    async def leave(self) -> None:
        """This replica stops: the others take its sessions at their next sweep."""
        async with self.transactions.begin() as db:
            await db.execute(delete(Replica).where(Replica.name == self.name))
        log.info("replica %s left", self.name)
