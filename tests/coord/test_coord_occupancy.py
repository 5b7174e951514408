"""`GET /api/ping` is a round-trip probe: between reads of the database it answers from
memory, so the join pages time the network, not the database (coord/service/occupancy.py)."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

from crowdteleop.coord.service.occupancy import Occupancy, OccupancyCache


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_page_s_pings_read_the_database_once_a_second():
    clock, reads = Clock(), []
    sessions = [SimpleNamespace(state=s) for s in ("ready", "starting", "queued", "queued")]

    async def live_sessions():
        reads.append(clock.now)
        return sessions

    cache = OccupancyCache(live_sessions, lambda: 3, max_age_s=1.0, clock=clock)

    async def pings() -> list[Occupancy]:
        answers = []
        for _ in range(4):  # a join page's four pings, 0.1 s apart
            answers.append(await cache.current())
            clock.now += 0.1
        return answers

    answers = asyncio.run(pings())
    assert reads == [100.0], "the first ping reads, the timed ones are answered from memory"
    assert answers[-1] == Occupancy(capacity=3, held=2, queued=2)
    assert answers[-1].free_slots == 1
    sessions.pop(0)  # a session ended
    clock.now += 1.0
    assert asyncio.run(cache.current()).free_slots == 2, "a second later it reads again"
    assert len(reads) == 2
    cache.forget()  # this replica changed its sessions
    asyncio.run(cache.current())
    assert len(reads) == 3, "a change here is read at once"
