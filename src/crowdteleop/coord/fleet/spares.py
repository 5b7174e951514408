"""Warm spare teleop servers: built before a worker arrives, handed over on admission.

A teleop server needs ~10 s to build its simulation; a spare that is already running takes
its session with one `POST /assign` (`crowdteleop.teleop.assign`), so a worker who clicks start
sees the robot in about a second. Spares are kept per (task, robot, controller) and listed in
the database (`coord/db/spare_registry.py`). On a cluster, whose servers any replica can reach,
`spare_servers` is the number for all replicas together and any replica hands any spare to
the worker it admits. With local processes each replica keeps and hands out its own. A spare
counts against no session's slot: locally only against the machine's memory (~0.9 GiB each,
~2% of a core while idle); on a cluster it holds a slot (`coord/fleet/cluster.py`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections.abc import Awaitable, Callable

import aiohttp

from crowdteleop.coord.db.spare_registry import SpareKey, SpareRegistry, SpareRow, key_text
from crowdteleop.coord.fleet.launcher import (
    Launcher,
    LaunchError,
    ReattachingLauncher,
    TeleopHandle,
    reattach,
    server_name,
)
from crowdteleop.coord.fleet.startup import StartupStats
from crowdteleop.coord.fleet.teleop_http import assign
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.messages import Assignment

log = logging.getLogger(__name__)
RETRY_AFTER_FAILURE_S = 30.0  # a kind whose spare did not start waits this long to try again


def new_spare_id() -> str:
    return f"spare-{secrets.token_hex(6)}"


class SparePool:
    """This replica's side of the spares: it starts and watches some, and claims any it can
    reach. `make_config(key, spare_id)` builds a spare's config, `admin_token_of(spare_id)` its
    admin token (derived: any replica can assign a spare), `wanted()` how many spares each kind
    should have now (`spare_servers`, or with `auto` the free slots the memory allows), `lock`
    is the admission lock (one replica at a time decides whether a kind needs more spares).
    The spares a kind lacks are started together, not one after another."""

    def __init__(
        self,
        launcher: Launcher,
        make_config: Callable[[SpareKey, str], TeleopConfig],
        admin_token_of: Callable[[str], str],
        wanted: Callable[[], Awaitable[dict[SpareKey, int]]],
        registry: SpareRegistry,
        lock: contextlib.AbstractAsyncContextManager[None],
        startup: StartupStats,
    ) -> None:
        self.launcher, self.make_config, self.admin_token_of = launcher, make_config, admin_token_of
        self.wanted, self.registry, self.lock = wanted, registry, lock
        self.startup = startup
        self.handles: dict[str, TeleopHandle] = {}  # the spares this replica watches, by id
        self._filling: dict[SpareKey, asyncio.Task[None]] = {}
        self._failed_at: dict[SpareKey, float] = {}
        self._closed = False

    @property
    def shared(self) -> bool:
        """Whether every replica can reach every spare (a cluster's servers)."""
        return isinstance(self.launcher, ReattachingLauncher)

    def fill(self, keys: list[SpareKey]) -> None:
        """Start spares in the background until each key has as many ready or starting as
        `wanted()` says."""
        if self._closed:
            return
        now = time.monotonic()
        for key in keys:
            if now - self._failed_at.get(key, -RETRY_AFTER_FAILURE_S) < RETRY_AFTER_FAILURE_S:
                continue
            task = self._filling.get(key)
            if task is None or task.done():
                self._filling[key] = asyncio.create_task(self._top_up(key), name=f"spare-{key[0]}")

    async def _top_up(self, key: SpareKey) -> None:
        while not self._closed:
            async with self.lock:
                wanted = (await self.wanted()).get(key, 0)
                missing = wanted - await self.registry.count(key, own=not self.shared)
                if missing <= 0:
                    return
                spare_ids = [new_spare_id() for _ in range(missing)]
                for spare_id in spare_ids:
                    await self.registry.add(spare_id, key)
            starts = [self._start(key, spare_id) for spare_id in spare_ids]
            if not all(await asyncio.gather(*starts)):
                return

    async def _start(self, key: SpareKey, spare_id: str) -> bool:
        log.info("spare %s starting for %s", spare_id, key_text(key))
        try:
            began = time.monotonic()
            handle = await self.launcher.start(self.make_config(key, spare_id))
            self.startup.started(time.monotonic() - began, getattr(handle, "pid", None))
        except (LaunchError, OSError) as exc:
            log.error("a spare teleop server for %s did not start: %s", key, exc)
            self._failed_at[key] = time.monotonic()
            await self.registry.remove(spare_id)
            return False
        except asyncio.CancelledError:
            await asyncio.shield(self.registry.remove(spare_id))
            raise
        if self._closed:
            await self.launcher.stop(handle)
            await self.registry.remove(spare_id)
            return False
        self.handles[spare_id] = handle
        await self.registry.ready(spare_id, handle.url, server_name(self.launcher, handle))
        log.info("spare %s ready for %s at %s", spare_id, key_text(key), handle.url)
        return True

    async def take(self, key: SpareKey, assignment: Assignment) -> TeleopHandle | None:
        """A running spare for `key`, now assigned to the session; None if there is none."""
        while (row := await self.registry.claim(key, any_replica=self.shared)) is not None:
            handle = self.handles.pop(row.id, None) or await self._reach(row)
            if handle is None or not self.launcher.alive(handle):
                continue
            try:
                await assign(handle.url, self.admin_token_of(row.id), assignment)
            except (aiohttp.ClientError, TimeoutError, LaunchError) as exc:
                log.warning("spare at %s refused its session: %s", handle.url, exc)
                await self.launcher.stop(handle)
                continue
            return handle
        return None

    async def _reach(self, row: SpareRow) -> TeleopHandle | None:
        return await reattach(self.launcher, row.id, row.server)

    def short(self, wanted: dict[SpareKey, int], rows: list[SpareRow]) -> list[SpareKey]:
        """The kinds with fewer spares in `rows` (every replica's on a cluster, this one's
        otherwise) than `wanted`: `fill` need not take the lock for the others."""
        counted = [r for r in rows if self.shared or r.replica == self.registry.replica]
        return [k for k, n in wanted.items() if sum(r.key == key_text(k) for r in counted) < n]

    def ready(self, rows: list[SpareRow]) -> list[SpareRow]:
        """The spares of `rows` this replica can hand out now."""
        return [r for r in rows if r.url is not None and (self.shared or self.mine(r))]

    def starting(self, rows: list[SpareRow]) -> list[SpareRow]:
        """The spares of `rows` still starting that this replica could hand out."""
        return [r for r in rows if r.url is None and (self.shared or self.mine(r))]

    def mine(self, row: SpareRow) -> bool:
        return row.replica == self.registry.replica

    async def sweep(self, alive_replicas: set[str]) -> list[SpareRow]:
        """Forget spares whose server is gone (the next `fill` replaces them); watch from here
        those of replicas that are gone, where they can be reached (a cluster's). Returns the
        spares still listed."""
        rows = await self.registry.rows()
        kept = list(rows)
        listed = {row.id for row in rows}
        for spare_id in [s for s in self.handles if s not in listed]:
            self._let_go(self.handles.pop(spare_id))  # another replica gave it to a worker
        for row in rows:
            mine = row.replica == self.registry.replica
            if mine and row.url is None:
                continue  # starting here
            if not mine and row.replica in alive_replicas:
                continue  # its replica watches it
            handle = self.handles.get(row.id) if mine else None
            if handle is None and row.url is not None:
                handle = await self._reach(row)  # after a restart, or from a gone replica
            if handle is None or not self.launcher.alive(handle):
                self.handles.pop(row.id, None)
                await self.registry.remove(row.id)
                kept.remove(row)
                log.info("spare %s is gone", row.id)
                continue
            self.handles[row.id] = handle
            if not mine:
                await self.registry.watch(row.id)
                log.info("spare %s of %s is watched from here now", row.id, row.replica)
        return kept

    async def forget_unstarted(self) -> None:
        """At start: this replica's spares a previous run left starting never will."""
        for row in await self.registry.rows():
            if row.replica == self.registry.replica and row.url is None:
                await self.registry.remove(row.id)

    async def close(self, hand_over: bool) -> None:
        """Stop this replica's spares; with `hand_over`, leave them running for the other
        replicas instead (they take them on once this one has left)."""
        self._closed = True
        for task in list(self._filling.values()):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        mine: set[str] | None = None
        with contextlib.suppress(Exception):  # the database may be gone too
            rows = await self.registry.rows()
            mine = {row.id for row in rows if row.replica == self.registry.replica}
        for spare_id, handle in list(self.handles.items()):
            claimed = mine is not None and spare_id not in mine and self.shared
            if claimed or hand_over:  # serving a worker through another replica, or kept
                self._let_go(handle)
                continue
            await self.launcher.stop(handle)
            with contextlib.suppress(Exception):
                await self.registry.remove(spare_id)
        self.handles.clear()

    def _let_go(self, handle: TeleopHandle) -> None:
        """Stop watching a spare that keeps running (another replica has it now)."""
        if isinstance(self.launcher, ReattachingLauncher):
            self.launcher.release(handle)
