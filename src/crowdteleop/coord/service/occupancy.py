"""How free this coordinator is, as `GET /api/ping` answers it.

The ping is what the campaign's join pages time to find the nearest region: its answer must
cost no more than the network does. Read from the database it waits behind whatever the
database is doing (on SQLite, a commit's fsync behind a running session's heartbeats: 40 ms
on a busy disk), and the page measures that instead of the distance. So the answer is read
at most once per `max_age_s` and served from memory in between: a page's first ping (which
also opens the connection, and is not timed) refreshes it, the timed ones that follow are
answered at once. This replica forgets it whenever it changes its sessions (the `Coordinator`
admits after every change); another replica's changes show within a second, which is nothing
to a choice of region."""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

from crowdteleop.coord.db.tables import Session

MAX_AGE_S = 1.0


@dataclass(frozen=True)
class Occupancy:
    capacity: int
    held: int  # sessions starting or running: each holds a slot
    queued: int

    @property
    def free_slots(self) -> int:
        return max(0, self.capacity - self.held)


class OccupancyCache:
    """The last `Occupancy` read, re-read once it is `max_age_s` old."""

    def __init__(
        self,
        live_sessions: Callable[[], Awaitable[list[Session]]],
        capacity: Callable[[], int],
        max_age_s: float = MAX_AGE_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._live_sessions, self._capacity = live_sessions, capacity
        self._max_age_s, self._clock = max_age_s, clock
        self._last: tuple[float, Occupancy] | None = None

    def forget(self) -> None:
        self._last = None

    async def current(self) -> Occupancy:
        now = self._clock()
        if self._last is not None and now - self._last[0] < self._max_age_s:
            return self._last[1]
        live = await self._live_sessions()
        occupancy = Occupancy(
            capacity=self._capacity(),
            held=sum(session.state in ("starting", "ready") for session in live),
            queued=sum(session.state == "queued" for session in live),
        )
        self._last = (now, occupancy)
        return occupancy
