"""Every read and write of the coordinator's database, each a short transaction."""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncEngine, AsyncSession
from sqlalchemy.sql import ColumnElement

from crowdteleop.coord.db.engine import make_sessionmaker, rowcount
from crowdteleop.coord.db.pairing import PairingStore
from crowdteleop.coord.db.tables import (
    Base,
    Campaign,
    Episode,
    Event,
    PhoneToken,
    Session,
    Worker,
    WorkerToken,
)
from crowdteleop.coord.guard.security import new_id, new_token, token_hash
from crowdteleop.coord.service.campaign import CampaignConfig

LIVE_STATES = ("queued", "starting", "ready")


class Store:
    def __init__(self, engine: AsyncEngine) -> None:
        self.engine = engine
        # SQLAlchemy calls these sessions; here each is one short transaction (`Session` is a
        # worker's teleop session, a table).
        self.transactions = make_sessionmaker(engine)
        self.pairing = PairingStore(self.transactions)

    async def close(self) -> None:
        await self.engine.dispose()

    # --- campaigns and workers ------------------------------------------------------------

    async def save_campaigns(self, campaigns: Iterable[CampaignConfig]) -> None:
        now = time.time()
        async with self.transactions.begin() as db:
            for campaign in campaigns:
                row = await db.get(Campaign, campaign.name)
                config = campaign.model_dump(mode="json")
                if row is None:
                    db.add(
                        Campaign(name=campaign.name, config=config, created_at=now, updated_at=now)
                    )
                elif row.config != config:
                    row.config, row.updated_at = config, now

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

    # --- sessions -------------------------------------------------------------------------

    async def set_worker_region(self, worker_id: str, region: dict[str, Any] | None) -> None:
        """Where the worker's latest join landed (their next session records it)."""
        async with self.transactions.begin() as db:
            await db.execute(update(Worker).where(Worker.id == worker_id).values(region=region))

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

    # --- episodes -------------------------------------------------------------------------

    async def add_episode(self, episode: Episode) -> tuple[bool, int]:
        """(new?, demos done). Idempotent by episode id: a retried report counts once."""
        try:
            async with self.transactions.begin() as db:
                if await db.get(Episode, episode.episode_id) is not None:
                    raise _DuplicateError
                db.add(episode)
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
        session = await self.session(episode.session_id)
        return new, session.demos_done if session else 0

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


class _DuplicateError(Exception):
    pass


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
