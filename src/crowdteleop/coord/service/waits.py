"""How long queued workers will wait: positions and estimates for the FIFO queue. The
estimates are pure functions of the busy slots' expected remaining times (easy to test);
`WaitEstimates` feeds them from the database."""

from __future__ import annotations

import heapq
import statistics
import time
from collections.abc import Callable, Sequence

from crowdteleop.coord.db.sessions import SessionStore
from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.service.config import CoordConfig

MEAN_CACHE_S = 10.0


def mean_session_s(observed: Sequence[float], fallback_s: float) -> float:
    """Mean of the observed session durations; the time limit until there are any."""
    durations = [d for d in observed if d > 0]
    return statistics.fmean(durations) if durations else fallback_s


def queue_etas(
    capacity: int, remaining_s: Sequence[float], waiting: int, mean_s: float
) -> list[float]:
    """Estimated wait of each of `waiting` queued sessions, first in line first.

    Each busy slot frees after its session's expected remaining time (`remaining_s`, one per
    busy slot); each queued session then holds the slot it takes for `mean_s`.
    """
    free_at = [max(0.0, r) for r in remaining_s][:capacity]
    free_at += [0.0] * (capacity - len(free_at))
    heapq.heapify(free_at)
    etas = []
    for _ in range(waiting):
        start = heapq.heappop(free_at)
        etas.append(round(start, 1))
        heapq.heappush(free_at, start + mean_s)
    return etas


def expected_remaining_s(elapsed_s: float, mean_s: float, time_limit_s: float) -> float:
    """How much longer a running session is expected to hold its slot."""
    expected_total = min(time_limit_s, max(mean_s, elapsed_s))
    return max(0.0, expected_total - elapsed_s)


class WaitEstimates:
    """Queue positions and estimated waits (the mean session length cached for a while)."""

    def __init__(
        self, sessions: SessionStore, config: CoordConfig, capacity: Callable[[], int]
    ) -> None:
        """`capacity`: the pool's now (a cluster's changes as nodes come and go)."""
        self.sessions, self.config, self.capacity = sessions, config, capacity
        self._mean: tuple[float, float] | None = None  # (computed at, value)

    def forget_mean(self) -> None:
        """A session ended: the mean changes."""
        self._mean = None

    async def mean_session_s(self, fallback_s: float) -> float:
        now = time.monotonic()
        if self._mean is None or now - self._mean[0] > MEAN_CACHE_S:
            self._mean = (now, mean_session_s(await self.sessions.ended_durations(), -1.0))
        value = self._mean[1]
        return fallback_s if value < 0 else value

    async def positions(self) -> dict[str, tuple[int, float]]:
        """Queued session id -> (1-based position, estimated wait in seconds)."""
        live = await self.sessions.live_sessions()
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
