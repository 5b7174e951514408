"""The slots of the teleop server pool: who holds one, the server behind it, and how that
server last answered its health probe."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field

from crowdteleop.coord.fleet.launcher import Launcher, ReattachingLauncher, TeleopHandle
from crowdteleop.teleop.messages import TeleopHealth

log = logging.getLogger(__name__)


@dataclass
class Slot:
    session_id: str
    reserved_at: float = field(default_factory=time.time)
    handle: TeleopHandle | None = None  # None while the server is starting
    healthy_at: float = field(default_factory=time.monotonic)  # its last good health probe
    spool_pending: int = 0  # episodes its spool holds for the object store, at that probe
    reports_pending: int = 0  # stored episodes it has not yet told us of, at that probe
    reports_unreachable: bool = False  # it could not reach us at its report address


@dataclass(frozen=True)
class ServerState:
    """A slot as the admin page and `/metrics` see it."""

    session_id: str
    url: str | None  # None while its server starts
    pid: int | None  # a local process's (None for a cluster's)
    alive: bool
    started_at: float
    spool_pending: int
    reports_pending: int = 0
    reports_unreachable: bool = False


class TeleopPool:
    """The slots this replica watches, of at most `capacity` across replicas; a slot is taken
    when a session is admitted and given back the moment it ends (its server is then stopped
    in the background, tracked here)."""

    def __init__(self, launcher: Launcher, capacity: int) -> None:
        self.launcher = launcher
        self.capacity = capacity
        self.slots: dict[str, Slot] = {}
        self._stopping: set[asyncio.Task[None]] = set()
        self._closing = asyncio.Event()

    def reserve(self, session_id: str) -> Slot:
        """The caller counted a free slot in the database (every replica's sessions hold some)."""
        slot = self.slots[session_id] = Slot(session_id)
        return slot

    def attach(self, session_id: str, handle: TeleopHandle | None) -> bool:
        """A server still running from before a coordinator restart (if any) takes its slot
        back; whether there was one."""
        if handle is None:
            return False
        self.slots[session_id] = Slot(session_id, handle=handle)
        log.info("session %s: its teleop server %s is still running", session_id, handle.url)
        return True

    def started(self, session_id: str, handle: TeleopHandle) -> bool:
        """The session's server is up: its slot holds it, probed from now on; False if the slot
        was given back meanwhile (the session ended while its server started)."""
        slot = self.slots.get(session_id)
        if slot is None:
            return False
        slot.handle = handle
        slot.healthy_at = time.monotonic()
        return True

    def handle(self, session_id: str) -> TeleopHandle | None:
        slot = self.slots.get(session_id)
        return slot.handle if slot else None

    def release(self, session_id: str, delay_s: float = 0.0) -> None:
        """Give the slot back now; stop its server (if any) in the background, after
        `delay_s` (a grace the pool's closing cuts short)."""
        slot = self.slots.pop(session_id, None)
        if slot is not None and slot.handle is not None:
            self.stop_later(slot.handle, delay_s)

    async def kill(self, session_id: str) -> None:
        """Give the slot back and kill its server now, waiting until it is gone (a hung one
        can finish nothing, and must not hold the session's files for the next)."""
        slot = self.slots.pop(session_id, None)
        if slot is not None and slot.handle is not None:
            await self.launcher.stop(slot.handle, grace_s=0.0)

    def forget(self, session_id: str) -> None:
        """Another replica watches this session's server now: let go of it, running."""
        slot = self.slots.pop(session_id, None)
        launcher = self.launcher
        if slot is not None and slot.handle and isinstance(launcher, ReattachingLauncher):
            launcher.release(slot.handle)

    def stop_later(self, handle: TeleopHandle, delay_s: float = 0.0) -> None:
        task = asyncio.create_task(self._stop(handle, delay_s), name="stop-teleop")
        self._stopping.add(task)
        task.add_done_callback(self._stopping.discard)

    async def _stop(self, handle: TeleopHandle, delay_s: float) -> None:
        try:
            if delay_s > 0:  # a grace period, cut short when the pool closes
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._closing.wait(), delay_s)
            await self.launcher.stop(handle)
        except Exception:
            log.exception("stopping teleop server %s failed", handle.url)

    def running(self) -> list[tuple[str, TeleopHandle]]:
        """(session id, server) of every slot whose server has started."""
        return [(sid, slot.handle) for sid, slot in self.slots.items() if slot.handle is not None]

    def heard(self, session_id: str, health: TeleopHealth | None, now: float) -> float:
        """Record a probe's answer (None: no good answer in time); how long the server has
        been silent since its last good one (0.0 for a slot given up meanwhile)."""
        slot = self.slots.get(session_id)
        if slot is None:
            return 0.0
        if health is not None:
            slot.healthy_at = now
            slot.spool_pending = health.spool_pending
            slot.reports_pending = health.reports_pending
            slot.reports_unreachable = health.reports_unreachable
        return now - slot.healthy_at

    def servers(self) -> list[ServerState]:
        return [
            ServerState(
                session_id=session_id,
                url=slot.handle.url if slot.handle else None,
                pid=getattr(slot.handle, "pid", None),
                alive=slot.handle is not None and self.launcher.alive(slot.handle),
                started_at=slot.reserved_at,
                spool_pending=slot.spool_pending,
                reports_pending=slot.reports_pending,
                reports_unreachable=slot.reports_unreachable,
            )
            for session_id, slot in self.slots.items()
        ]

    def alive(self, session_id: str) -> bool | None:
        """None while starting (no server yet)."""
        handle = self.handle(session_id)
        return None if handle is None else self.launcher.alive(handle)

    async def close(self) -> None:
        """Stop every server, including those already on their way out."""
        self._closing.set()
        for session_id in list(self.slots):
            self.release(session_id)
        if self._stopping:
            with contextlib.suppress(Exception):
                await asyncio.gather(*self._stopping, return_exceptions=True)
