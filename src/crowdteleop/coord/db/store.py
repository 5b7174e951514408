"""The coordinator's database as the service sees it: one engine, and a store per concern
(workers, sessions, episodes, pairing, reviews), each call one short transaction; the tables that
replicas share (their heartbeats, the warm spares, the shared limits) and the admission lock
are made here too, on the same engine."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from sqlalchemy.ext.asyncio import AsyncEngine

from crowdteleop.coord.db.engine import make_sessionmaker
from crowdteleop.coord.db.episodes import EpisodeStore
from crowdteleop.coord.db.pairing import PairingStore
from crowdteleop.coord.db.replicas import AdmissionLock, Replicas
from crowdteleop.coord.db.reviews import ReviewStore
from crowdteleop.coord.db.sessions import SessionStore
from crowdteleop.coord.db.shared_limits import SHARED_WINDOW_S, SharedWindowLimiter, forget_old
from crowdteleop.coord.db.spare_registry import SpareRegistry
from crowdteleop.coord.db.tables import Campaign
from crowdteleop.coord.db.workers import WorkerStore


class Store:
    def __init__(self, engine: AsyncEngine) -> None:
        self.engine = engine
        # SQLAlchemy calls these sessions; here each is one short transaction (`Session` is a
        # worker's teleop session, a table).
        self.transactions = make_sessionmaker(engine)
        self.workers = WorkerStore(self.transactions)
        self.sessions = SessionStore(self.transactions)
        self.episodes = EpisodeStore(self.transactions)
        self.pairing = PairingStore(self.transactions)
        self.reviews = ReviewStore(self.transactions)

    async def close(self) -> None:
        await self.engine.dispose()

    async def save_campaigns(self, campaigns: Mapping[str, dict[str, Any]]) -> None:
        """Record each campaign's settings (name -> its config as JSON), kept when unchanged."""
        now = time.time()
        async with self.transactions.begin() as db:
            for name, config in campaigns.items():
                row = await db.get(Campaign, name)
                if row is None:
                    db.add(Campaign(name=name, config=config, created_at=now, updated_at=now))
                elif row.config != config:
                    row.config, row.updated_at = config, now

    def admission_lock(self) -> AdmissionLock:
        return AdmissionLock(self.engine)

    def replicas(self, name: str, stale_after_s: float) -> Replicas:
        return Replicas(self.transactions, name, stale_after_s)

    def spare_registry(self, replica: str) -> SpareRegistry:
        return SpareRegistry(self.transactions, replica)

    def limiter(self, name: str, limit: int) -> SharedWindowLimiter:
        """A rate limit counted in the database, across replicas."""
        return SharedWindowLimiter(self.transactions, name, limit)

    async def forget_old_limit_events(self) -> None:
        """Drop the shared limits' events no window counts any more."""
        await forget_old(self.transactions, SHARED_WINDOW_S)
