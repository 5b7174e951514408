"""The database side of phone pairing: short codes (with the QR link's long key) and the
phone tokens they are traded for."""

from __future__ import annotations

import time

from sqlalchemy import select, update
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from crowdteleop.coord.db.engine import rowcount
from crowdteleop.coord.db.tables import Event, PairingCode, PhoneToken, Session
from crowdteleop.coord.guard.security import new_token, token_hash


class PairingStore:
    def __init__(self, transactions: async_sessionmaker[AsyncSession]) -> None:
        self.transactions = transactions

    async def add_code(
        self, session_id: str, code: str, expires_at: float, key: str | None = None
    ) -> bool:
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
            db.add(
                PairingCode(
                    code=code,
                    session_id=session_id,
                    expires_at=expires_at,
                    key_hash=token_hash(key) if key else None,
                )
            )
            return True

    async def redeem(self, code: str, now: float, key: str | None = None) -> tuple[str, str] | None:
        """(session id, phone token) for a live code, which is used up; else None. With a
        `key`, the code must be the one the key was made with."""
        async with self.transactions.begin() as db:
            statement = select(PairingCode).where(
                PairingCode.code == code,
                PairingCode.used_at.is_(None),
                PairingCode.expires_at > now,
            )
            if key is not None:
                statement = statement.where(PairingCode.key_hash == token_hash(key))
            row = await db.scalar(statement)
            if row is None:
                return None
            claimed = await db.execute(
                update(PairingCode)
                .where(PairingCode.id == row.id, PairingCode.used_at.is_(None))
                .values(used_at=now)
            )
            if rowcount(claimed) != 1:  # someone else redeemed it in between
                return None
            token = new_token()
            db.add(
                PhoneToken(token_hash=token_hash(token), session_id=row.session_id, created_at=now)
            )
            db.add(Event(at=now, kind="paired", session_id=row.session_id, data={}))
            return row.session_id, token

    async def session_of_phone(self, token: str) -> Session | None:
        async with self.transactions() as db:
            return await db.scalar(
                select(Session)
                .join(PhoneToken, PhoneToken.session_id == Session.id)
                .where(PhoneToken.token_hash == token_hash(token))
            )
