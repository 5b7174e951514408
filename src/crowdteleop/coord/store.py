"""Every read and write of the coordinator's database, each a short transaction."""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

from sqlalchemy import CursorResult, Result, func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncEngine
from sqlalchemy.sql import ColumnElement

from crowdteleop.coord.campaign import CampaignConfig
from crowdteleop.coord.db import make_sessionmaker
from crowdteleop.coord.security import new_id, new_token, token_hash
from crowdteleop.coord.tables import (
    Base,
    Campaign,
    Episode,
    Event,
    PairingCode,
    PhoneToken,
    Session,
    Worker,
    WorkerToken,
)

LIVE_STATES = ("queued", "starting", "ready")


class Store:
    def __init__(self, engine: AsyncEngine) -> None:
        self.engine = engine
        # SQLAlchemy calls these sessions; here each is one short transaction (`Session` is a
        # worker's teleop session, a table).
        self.transactions = make_sessionmaker(engine)

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
    ) -> tuple[Worker, str, bool]:
        """(worker, a new bearer token, created?). The same external id: the same worker."""
        token = new_token()
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
                        worker.external_session = external_session or worker.external_session
                        worker.campaign = campaign  # the link they came by last
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

    async def worker_by_token(self, token: str) -> Worker | None:
        async with self.transactions() as db:
            return await db.scalar(
                select(Worker)
                .join(WorkerToken, WorkerToken.worker_id == Worker.id)
                .where(WorkerToken.token_hash == token_hash(token))
            )

    async def worker(self, worker_id: str) -> Worker | None:
        async with self.transactions() as db:
            return await db.get(Worker, worker_id)

    # --- sessions -------------------------------------------------------------------------

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
            return _rowcount(result) == 1

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

    # --- pairing --------------------------------------------------------------------------

    async def add_pairing_code(self, session_id: str, code: str, expires_at: float) -> bool:
        """False if `code` is already live for some session (the caller draws another)."""
        async with self.transactions.begin() as db:
            clash = await db.scalar(
                select(PairingCode.id).where(
                    PairingCode.code == code,
                    PairingCode.used_at.is_(None),
                    PairingCode.expires_at > time.time(),
                )
            )
            if clash is not None:
                return False
            db.add(PairingCode(code=code, session_id=session_id, expires_at=expires_at))
            return True

    async def redeem_pairing_code(self, code: str, now: float) -> tuple[str, str] | None:
        """(session id, phone token) for a live code, which is used up; else None."""
        async with self.transactions.begin() as db:
            row = await db.scalar(
                select(PairingCode).where(
                    PairingCode.code == code,
                    PairingCode.used_at.is_(None),
                    PairingCode.expires_at > now,
                )
            )
            if row is None:
                return None
            claimed = await db.execute(
                update(PairingCode)
                .where(PairingCode.id == row.id, PairingCode.used_at.is_(None))
                .values(used_at=now)
            )
            if _rowcount(claimed) != 1:  # someone else redeemed it in between
                return None
            token = new_token()
            db.add(
                PhoneToken(token_hash=token_hash(token), session_id=row.session_id, created_at=now)
            )
            db.add(Event(at=now, kind="paired", session_id=row.session_id, data={}))
            return row.session_id, token

    async def session_by_phone_token(self, token: str) -> Session | None:
        async with self.transactions() as db:
            return await db.scalar(
                select(Session)
                .join(PhoneToken, PhoneToken.session_id == Session.id)
                .where(PhoneToken.token_hash == token_hash(token))
            )


class _DuplicateError(Exception):
    pass


def _rowcount(result: Result[*tuple[Any, ...]]) -> int:
    """The rows an UPDATE matched. The ORM runs an UPDATE to a `CursorResult`; SQLAlchemy
    types `AsyncSession.execute` as returning a plain `Result`, which has no row count."""
    assert isinstance(result, CursorResult)
    return result.rowcount
