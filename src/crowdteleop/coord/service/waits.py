"""How long queued workers will wait: positions and estimates, from the database."""

from __future__ import annotations

import time
from collections.abc import Callable

from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.queue import expected_remaining_s, mean_session_s, queue_etas

MEAN_CACHE_S = 10.0


class WaitEstimates:
    """Queue positions and estimated waits (the mean session length cached for a while)."""

    def __init__(self, store: Store, config: CoordConfig, capacity: Callable[[], int]) -> None:
        """`capacity`: the pool's now (a cluster's changes as nodes come and go)."""
        self.store, self.config, self.capacity = store, config, capacity
        self._mean: tuple[float, float] | None = None  # (computed at, value)

    def forget_mean(self) -> None:
        """A session ended: the mean changes."""
        self._mean = None

    async def mean_session_s(self, fallback_s: float) -> float:
        now = time.monotonic()
        if self._mean is None or now - self._mean[0] > MEAN_CACHE_S:
            self._mean = (now, mean_session_s(await self.store.ended_durations(), -1.0))
        value = self._mean[1]
        return fallback_s if value < 0 else value

    async def positions(self) -> dict[str, tuple[int, float]]:
        """Queued session id -> (1-based position, estimated wait in seconds)."""
        live = await self.store.live_sessions()
        queued = [s for s in live if s.state == "queued"]
        if not queued:
            return {}
        etas = await self._etas(live, len(queued))
        return {s.id: (i + 1, eta) for i, (s, eta) in enumerate(zip(queued, etas, strict=True))}

    async def next_wait_s(self, live: list[Session], queued: int) -> float:
        """The estimated wait of a session joining behind the `queued` of `live` sessions."""
        return (await self._etas(live, queued + 1))[-1]

    async def _etas(self, live: list[Session], waiting: int) -> list[float]:
        mean = await self.mean_session_s(self.config.default_campaign.time_limit_s)
        now = time.time()
        remaining = [
            expected_remaining_s(now - (s.ready_at or now), mean, s.time_limit_s)
            for s in live
            if s.state in ("starting", "ready")
        ]
        return queue_etas(max(1, self.capacity()), remaining, waiting, mean)
