"""The slots of the teleop server pool: who holds one, and the server behind it."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field

from crowdteleop.coord.fleet.launcher import Launcher, ReattachingLauncher, TeleopHandle

log = logging.getLogger(__name__)


@dataclass
class Slot:
    session_id: str
    reserved_at: float = field(default_factory=time.time)
    handle: TeleopHandle | None = None  # None while the server is starting
    healthy_at: float = field(default_factory=time.monotonic)  # its last good health probe
    spool_pending: int = 0  # episodes its spool holds for the object store, at that probe


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
        """The caller counted a free slot in the database (`Coordinator.free_slots`)."""
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

    def holds(self, session_id: str) -> bool:
        return session_id in self.slots

    def handle(self, session_id: str) -> TeleopHandle | None:
        slot = self.slots.get(session_id)
        return slot.handle if slot else None

    def release(self, session_id: str) -> None:
        """Give the slot back now; stop its server (if any) in the background."""
        slot = self.slots.pop(session_id, None)
        if slot is not None and slot.handle is not None:
            self.stop_later(slot.handle)

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
