"""The sessions table and its event log: every read and write, each a short transaction."""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from crowdteleop.coord.db.engine import rowcount
from crowdteleop.coord.db.tables import Event, Session
from crowdteleop.coord.guard.security import token_hash

LIVE_STATES = ("queued", "starting", "ready")


class SessionStore:
    """Workers' sessions from queued to ended, and what happened to each (`events`)."""

    def __init__(self, transactions: async_sessionmaker[AsyncSession]) -> None:
        # SQLAlchemy calls these sessions; here each is one short transaction (`Session` is a
        # worker's teleop session, a table).
        self.transactions = transactions

    async def add_session(self, session: Session) -> Session:
        async with self.transactions.begin() as db:
            db.add(session)
            db.add(
                Event(
                    at=session.created_at,
                    kind="queued",
                    session_id=session.id,
                    worker_id=session.worker_id,
                    data={"task": session.task},
                )
            )
        return session

    async def session(self, session_id: str) -> Session | None:
        async with self.transactions() as db:
            return await db.get(Session, session_id)

    async def sessions_by_id(self, session_ids: Iterable[str]) -> dict[str, Session]:
        """Those of `session_ids` that exist, in one query."""
        async with self.transactions() as db:
            rows = await db.scalars(select(Session).where(Session.id.in_(list(session_ids))))
            return {session.id: session for session in rows}

    async def session_by_report_token(self, token: str) -> Session | None:
        async with self.transactions() as db:
            return await db.scalar(
                select(Session).where(Session.report_token_hash == token_hash(token))
            )

    async def live_session_of(self, worker_id: str) -> Session | None:
        async with self.transactions() as db:
            return await db.scalar(
                select(Session)
                .where(Session.worker_id == worker_id, Session.state.in_(LIVE_STATES))
                .order_by(Session.created_at)
            )

    async def live_sessions(self) -> list[Session]:
        """Queued ones in queue order (oldest first), then the others."""
        async with self.transactions() as db:
            rows = await db.scalars(
                select(Session)
                .where(Session.state.in_(LIVE_STATES))
                .order_by(Session.created_at, Session.id)
            )
            return list(rows)

    async def held_slots(self) -> int:
        """Sessions holding a teleop server slot (starting or ready), on every replica."""
        async with self.transactions() as db:
            statement = select(func.count()).select_from(Session)
            held = statement.where(Session.state.in_(("starting", "ready")))
            return await db.scalar(held) or 0

    async def live_sessions_of_client(self, client_tag: str) -> int:
        async with self.transactions() as db:
            statement = select(func.count()).select_from(Session)
            return (
                await db.scalar(
                    statement.where(
                        Session.client_tag == client_tag, Session.state.in_(LIVE_STATES)
                    )
                )
                or 0
            )

    async def requeue(self, session_id: str, why: str, count_restart: bool = True) -> bool:
        """Put a session whose server is gone back in the queue, at its old place (its
        `created_at`), with its demonstrations kept. False if it was not starting or ready."""
        now = time.time()
        fields: dict[str, Any] = {
            "state": "queued",
            "queued_at": now,
            "admitted_at": None,
            "ready_at": None,
            "teleop_url": None,
            "last_heartbeat_at": now,  # the page is told on its next call; give it time
            "error": why,
        }
        if count_restart:
            fields["restarts"] = Session.restarts + 1
        requeued = await self.update_session(
            session_id, only_if_state=("starting", "ready"), **fields
        )
        if requeued:
            await self.log("requeued", session_id, reason=why, counted=count_restart)
        return requeued

    async def count_sessions(self, campaign: str) -> int:
        async with self.transactions() as db:
            return (
                await db.scalar(
                    select(func.count()).select_from(Session).where(Session.campaign == campaign)
                )
                or 0
            )

    async def update_session(
        self, session_id: str, only_if_state: Iterable[str] | None = None, **fields: Any
    ) -> bool:
        """Set `fields`; with `only_if_state`, only when the session is still in one of them."""
        async with self.transactions.begin() as db:
            statement = update(Session).where(Session.id == session_id)
            if only_if_state is not None:
                statement = statement.where(Session.state.in_(list(only_if_state)))
            result = await db.execute(statement.values(**fields))
            return rowcount(result) == 1

    async def ended_durations(self, limit: int = 200) -> list[float]:
        """How long recent sessions held their slot (ready to ended)."""
        async with self.transactions() as db:
            rows = await db.execute(
                select(Session.ready_at, Session.ended_at)
                .where(Session.state == "ended", Session.ready_at.is_not(None))
                .order_by(Session.ended_at.desc())
                .limit(limit)
            )
            return [
                ended - ready for ready, ended in rows if ended is not None and ready is not None
            ]

    async def log(
        self, kind: str, session_id: str | None = None, worker_id: str | None = None, **data: Any
    ) -> None:
        async with self.transactions.begin() as db:
            db.add(
                Event(
                    at=time.time(), kind=kind, session_id=session_id, worker_id=worker_id, data=data
                )
            )

    async def events(self, session_id: str) -> list[Event]:
        async with self.transactions() as db:
            return list(
                await db.scalars(
                    select(Event).where(Event.session_id == session_id).order_by(Event.id)
                )
            )
