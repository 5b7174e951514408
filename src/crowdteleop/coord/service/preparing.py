"""What the pages and `crowdteleop serve` say while a robot is prepared: how long a teleop
server's start takes here (measured), how much of it is left for a session's, for a worker
who would join now, and when the first warm spare is up."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable, Iterator
from typing import NamedTuple

from crowdteleop.coord.db.spare_registry import SpareKey, SpareRegistry
from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.fleet.launcher import Launcher, TeleopHandle
from crowdteleop.coord.fleet.spares import SparePool
from crowdteleop.coord.fleet.startup import StartupStats
from crowdteleop.teleop.config import TeleopConfig

FIRST_SPARE_GRACE_S = 2.0  # `first_robot` gives up when no spare is starting by then


class Preparing(NamedTuple):
    """A robot on its way: about `eta_s` more seconds of a start that takes `total_s`."""

    eta_s: float
    total_s: float


class Preparation:
    """The starts of this replica's servers, timed, and what they let it tell. `free_slots()`
    counts the slots no session holds, `wanted()` the spares each kind should have, and
    `handing_over(session_id)` says whether a session's launch is under way here."""

    def __init__(
        self,
        startup: StartupStats,
        spares: SparePool,
        registry: SpareRegistry,
        free_slots: Callable[[], Awaitable[int]],
        wanted: Callable[[], Awaitable[dict[SpareKey, int]]],
        launching: Callable[[str], bool],
    ) -> None:
        self.startup, self.spares, self.registry = startup, spares, registry
        self.free_slots, self.wanted, self.launching = free_slots, wanted, launching
        self._cold: dict[str, float] = {}  # session id -> when its own server's start began
        self._handing: set[str] = set()  # sessions a spare is being handed to

    @contextlib.contextmanager
    def handing_over(self, session_id: str) -> Iterator[None]:
        """While a warm spare is looked for and assigned to the session."""
        self._handing.add(session_id)
        try:
            yield
        finally:
            self._handing.discard(session_id)

    async def cold_start(
        self, launcher: Launcher, session_id: str, config: TeleopConfig
    ) -> TeleopHandle:
        """A server of the session's own (no spare was ready), its start timed."""
        began = self._cold[session_id] = time.time()
        try:
            handle = await launcher.start(config)
        finally:
            self._cold.pop(session_id, None)
        self.startup.started(time.time() - began, getattr(handle, "pid", None))
        return handle

    def typical_start_s(self) -> float:
        """How long a teleop server takes to start here (the median of recent starts)."""
        return round(self.startup.typical_start_s(), 1)

    def of(self, session: Session) -> Preparing | None:
        """While a session's robot starts: how much longer, from the start times measured
        here (a warm spare being handed over: about a second)."""
        if session.state != "starting":
            return None
        began = self._cold.get(session.id)
        spare_likely = session.id in self._handing or bool(self.spares.handles)
        if began is None and self.launching(session.id) and spare_likely:
            return Preparing(1.0, 1.0)  # a warm spare is (most likely) being handed over
        began = began or session.admitted_at or time.time()
        return Preparing(self.startup.remaining_s(time.time() - began), self.typical_start_s())

    async def newcomer_wait(self) -> Preparing | None:
        """How long a worker joining now would wait for a robot if a slot is free: 0 with a
        warm spare ready, the rest of a spare's start, or a whole start; None when every slot
        is held (the queue's estimate applies then)."""
        if await self.free_slots() == 0:
            return None
        typical = self.typical_start_s()
        rows = await self.registry.rows()
        if self.spares.ready(rows):
            return Preparing(0.0, typical)
        begun = [r.started_at for r in self.spares.starting(rows) if r.started_at is not None]
        if begun:
            return Preparing(self.startup.remaining_s(time.time() - min(begun)), typical)
        return Preparing(typical, typical)

    async def first_robot(self, timeout_s: float) -> float | None:
        """Wait until a warm spare is ready, at most `timeout_s`: the seconds that took, or
        None when no spare is wanted or none came (its start failed, or was too slow)."""
        if not any((await self.wanted()).values()):
            return None
        began = time.monotonic()
        while (waited := time.monotonic() - began) < timeout_s:
            rows = await self.registry.rows()
            if self.spares.ready(rows):
                return waited
            if not self.spares.starting(rows) and waited > FIRST_SPARE_GRACE_S:
                return None
            await asyncio.sleep(0.1)
        return None
