"""Workers and their bearer tokens: who joined by which link, and which browser holds them."""

from __future__ import annotations

import time
from typing import Any

from sqlalchemy import delete, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from crowdteleop.coord.db.sessions import LIVE_STATES
from crowdteleop.coord.db.tables import Event, PhoneToken, Session, Worker, WorkerToken
from crowdteleop.coord.guard.security import new_id, new_token, token_hash


class WorkerStore:
    """Workers by the study ids their links carry, and the bearer tokens their browsers hold."""

    def __init__(self, transactions: async_sessionmaker[AsyncSession]) -> None:
        self.transactions = transactions

    async def join(
        self,
        campaign: str,
        source: str,
        external_id: str | None,
        study_id: str | None = None,
        external_session: str | None = None,
        params: dict[str, str] | None = None,
        presented_token: str | None = None,
        take_over: bool = False,
    ) -> tuple[Worker, str, bool]:
        """(worker, their bearer token, created?). The same external id: the same worker.

        A browser that presents the token it was given before keeps it. Any other browser
        joining with the id of a worker whose session is live is refused (`SessionInUseError`)
        unless it asks to take over: then every earlier token of the worker is revoked (the
        first browser is told as much on its next call) and the session's phones unpaired.
        A blocked worker is refused (`WorkerBlockedError`), with nothing written.
        """
        now = time.time()
        for _attempt in range(2):  # a concurrent first join of the same id: retry once
            try:
                async with self.transactions.begin() as db:
                    worker = None
                    if external_id is not None:
                        worker = await db.scalar(
                            select(Worker).where(
                                Worker.source == source, Worker.external_id == external_id
                            )
                        )
                    if worker is not None and worker.blocked_at is not None:
                        raise WorkerBlockedError(worker.id)
                    created = worker is None
                    if worker is None:
                        worker = Worker(
                            id=new_id("w"),
                            source=source,
                            external_id=external_id,
                            study_id=study_id,
                            external_session=external_session,
                            campaign=campaign,
                            params=params or {},
                            created_at=now,
                        )
                        db.add(worker)
                        await db.flush()
                    else:
                        kept = await _own_token(db, worker.id, presented_token)
                        if kept is not None:
                            return worker, kept, False
                        live = await db.scalar(
                            select(Session.id).where(
                                Session.worker_id == worker.id, Session.state.in_(LIVE_STATES)
                            )
                        )
                        if live is not None and not take_over:
                            raise SessionInUseError(live)
                        if live is not None:
                            await _take_over(db, worker.id, live, now)
                        worker.external_session = external_session or worker.external_session
                        worker.campaign = campaign  # the link they came by last
                    token = new_token()
                    db.add(
                        WorkerToken(
                            token_hash=token_hash(token), worker_id=worker.id, created_at=now
                        )
                    )
                    db.add(
                        Event(at=now, kind="join", worker_id=worker.id, data={"campaign": campaign})
                    )
                return worker, token, created
            except IntegrityError:
                continue
        raise RuntimeError("could not record the join")

    async def token_holder(self, token: str) -> tuple[Worker | None, bool]:
        """(the worker a token belongs to, revoked?): a revoked token names its old owner."""
        async with self.transactions() as db:
            row = await db.execute(
                select(Worker, WorkerToken.revoked_at)
                .join(WorkerToken, WorkerToken.worker_id == Worker.id)
                .where(WorkerToken.token_hash == token_hash(token))
            )
            found = row.first()
            if found is None:
                return None, False
            return found[0], found[1] is not None

    async def worker(self, worker_id: str) -> Worker | None:
        async with self.transactions() as db:
            return await db.get(Worker, worker_id)

    async def set_worker_region(self, worker_id: str, region: dict[str, Any] | None) -> None:
        """Where the worker's latest join landed (their next session records it)."""
        async with self.transactions.begin() as db:
            await db.execute(update(Worker).where(Worker.id == worker_id).values(region=region))


class WorkerBlockedError(Exception):
    """An admin blocked this worker: their joins are refused."""

    def __init__(self, worker_id: str) -> None:
        super().__init__(worker_id)
        self.worker_id = worker_id


class SessionInUseError(Exception):
    """Another browser holds this worker's live session (the join may take it over)."""

    def __init__(self, session_id: str) -> None:
        super().__init__(session_id)
        self.session_id = session_id


async def _own_token(db: AsyncSession, worker_id: str, token: str | None) -> str | None:
    """`token` if it is a valid token of this worker (the same browser coming back)."""
    if not token:
        return None
    found = await db.scalar(
        select(WorkerToken.token_hash).where(
            WorkerToken.token_hash == token_hash(token),
            WorkerToken.worker_id == worker_id,
            WorkerToken.revoked_at.is_(None),
        )
    )
    return token if found is not None else None


async def _take_over(db: AsyncSession, worker_id: str, session_id: str, now: float) -> None:
    """Revoke the worker's tokens and unpair the session's phones (a new browser takes over)."""
    await db.execute(
        update(WorkerToken)
        .where(WorkerToken.worker_id == worker_id, WorkerToken.revoked_at.is_(None))
        .values(revoked_at=now)
    )
    await db.execute(delete(PhoneToken).where(PhoneToken.session_id == session_id))
    db.add(Event(at=now, kind="taken_over", session_id=session_id, worker_id=worker_id, data={}))
