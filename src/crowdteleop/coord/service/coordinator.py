"""The coordinator's core: sessions from queued to ended, the pool's slots, episode reports.

All decisions that change who holds a slot happen under one admission lock, shared by every
replica on PostgreSQL (`coord/db/replicas.py`), and count the slots in the database: admission is
strictly FIFO and the capacity never exceeded, however many replicas serve. A session whose
teleop server exits or hangs is queued again at its old place with its count kept (`restart`);
so is a running session whose server a restarted coordinator cannot take back.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Any

from crowdteleop.coord.db.replicas import AdmissionLock, Replicas, default_replica_name
from crowdteleop.coord.db.spare_registry import SpareRegistry
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Session, Worker
from crowdteleop.coord.fleet.launcher import (
    Launcher,
    LaunchError,
    ReattachingLauncher,
    reattach,
    server_name,
    stop_orphans,
)
from crowdteleop.coord.fleet.pool import TeleopPool
from crowdteleop.coord.fleet.spares import SparePool
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.limits import retry_after
from crowdteleop.coord.guard.security import new_id, new_token, token_hash
from crowdteleop.coord.guard.session_keys import SessionKeys
from crowdteleop.coord.service.campaign import CampaignConfig
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.metrics import CoordMetrics, RestartCause
from crowdteleop.coord.service.teleop_configs import TeleopConfigs, assignment_of
from crowdteleop.coord.service.waits import WaitEstimates

log = logging.getLogger(__name__)


class Coordinator:
    def __init__(
        self,
        config: CoordConfig,
        store: Store,
        launcher: Launcher,
        keys: SessionKeys,
        metrics: CoordMetrics | None = None,
    ) -> None:
        self.config = config
        self.store = store
        self.keys = keys
        self.metrics = metrics or CoordMetrics()
        self.configs = TeleopConfigs(config, keys)
        self.pool = TeleopPool(launcher, config.capacity)
        self.lock = AdmissionLock(store.engine)
        name = config.replica_name or default_replica_name()
        self.replicas = Replicas(store.transactions, name, config.replica_stale_after_s)
        self.spares = SparePool(
            launcher,
            self.configs.for_spare,
            keys.teleop_admin_token,
            config.spare_servers,
            SpareRegistry(store.transactions, name),
            self.lock,
        )
        self._launches: dict[str, asyncio.Task[None]] = {}
        self.waits = WaitEstimates(store, config, lambda: self.pool.capacity)

    # --- lifecycle ------------------------------------------------------------------------

    async def start(self) -> None:
        """Sessions a previous run left live keep their place: the queued stay queued, a
        ready one whose server outlived the run (a cluster launcher's) keeps it, and the others
        are queued again ahead of the queue, their counts kept. Sessions another live replica
        watches are its own. Every page gets a fresh heartbeat allowance; servers no live
        session holds are stopped."""
        await self.store.save_campaigns(self.config.campaigns)
        await self.replicas.beat()
        others = await self.replicas.others_alive()
        await self.spares.forget_unstarted()
        await self.spares.sweep(others | {self.replicas.name})  # its own, taken back if alive
        now = time.time()
        async with self.lock:
            for session in await self.store.live_sessions():
                if session.state != "queued" and session.replica in others:
                    continue
                await self.store.update_session(session.id, last_heartbeat_at=now)
                if session.state != "queued":
                    await self.take_over(session, "the coordinator restarted")
            held = [s for s in await self.store.live_sessions() if s.state != "queued"]
            spares = await self.spares.registry.rows()
            keep = {s.id for s in held} | {s.server for s in held if s.server}
            keep |= {r.id for r in spares} | {r.server for r in spares if r.server}
            await stop_orphans(self.pool.launcher, keep)
            await self._admit()
        self.spares.fill(self.configs.spare_keys())

    async def take_over(self, session: Session, why: str) -> bool:
        """Watch `session`'s running server from this replica, or queue the session again
        at its place (count kept) if its server cannot be taken back; whether it was. The
        caller holds the lock."""
        handle = await reattach(self.pool.launcher, session.id, session.server)
        if session.state == "ready" and self.pool.attach(session.id, handle):
            await self.store.update_session(session.id, replica=self.replicas.name)
            await self.store.log("taken_over", session.id, replica=self.replicas.name)
            return True
        if handle is not None:  # a server that never became ready: nobody wants it
            await self.pool.launcher.stop(handle, grace_s=0.0)
        if await self.store.requeue(session.id, why, count_restart=False):
            self.metrics.restarts.labels(cause="coordinator_restart").inc()
        return False

    async def close(self) -> None:
        """Stop every teleop server (each stores its running episode); the sessions stay as
        they are in the database, and the next start gives them back their places. With other
        replicas alive and servers that outlive this process (a cluster's), the running
        sessions are left to them instead: their workers keep driving."""
        for task in list(self._launches.values()):
            task.cancel()
        for task in list(self._launches.values()):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        launcher = self.pool.launcher
        others: set[str] = set()
        with contextlib.suppress(Exception):  # the database may be gone too
            others = await self.replicas.others_alive()
        await self.spares.close(hand_over=bool(others))
        if others and isinstance(launcher, ReattachingLauncher):
            log.info("leaving %d running sessions to %s", len(self.pool.slots), sorted(others))
            for session_id, slot in list(self.pool.slots.items()):
                if slot.handle is not None:
                    launcher.release(slot.handle)
                else:  # its launch was cancelled above
                    await self.store.requeue(
                        session_id, "its coordinator stopped", count_restart=False
                    )
            self.pool.slots.clear()
        await self.pool.close()
        with contextlib.suppress(Exception):
            await self.replicas.leave()

    async def free_slots(self) -> int:
        """Slots no session holds, counted in the database (every replica's sessions)."""
        return max(0, self.pool.capacity - await self.store.held_slots())

    # --- sessions -------------------------------------------------------------------------

    async def create_session(
        self, worker: Worker, campaign: CampaignConfig, client_tag: str | None = None
    ) -> Session:
        """The worker's live session, or a new one in the queue (admitted at once if free).
        A new one is refused past the admission limits (`CoordConfig.admission`)."""
        async with self.lock:
            existing = await self.store.live_session_of(worker.id)
            if existing is not None:
                return existing
            await self._check_admission(client_tag)
            index = await self.store.count_sessions(campaign.name)
            task, robot, controller = campaign.assignment(index)
            now = time.time()
            session = await self.store.add_session(
                Session(
                    id=new_id("s"),
                    worker_id=worker.id,
                    campaign=campaign.name,
                    state="queued",
                    task=task,
                    robot=robot,
                    controller=controller,
                    interfaces=list(campaign.interfaces),
                    time_limit_s=campaign.time_limit_s,
                    demos_required=campaign.demos_required,
                    demos_done=0,
                    created_at=now,
                    queued_at=now,
                    restarts=0,
                    client_tag=client_tag,
                    region=worker.region,
                    last_heartbeat_at=now,
                    report_token_hash="",
                )
            )
            await self._admit()
        return await self.store.session(session.id) or session

    async def _check_admission(self, client_tag: str | None) -> None:
        """Refuse a new session past the per-address, queue-length and wait limits (the
        caller holds the lock, so the counts cannot change under it)."""
        limits = self.config.admission
        if client_tag is not None:
            open_here = await self.store.live_sessions_of_client(client_tag)
            if open_here >= limits.live_sessions_per_address:
                self.metrics.refused("sessions_per_address")
                raise ApiError(
                    429,
                    "too_many_sessions",
                    f"{open_here} sessions are already open from your network; finish or close "
                    "one first",
                )
        if await self.free_slots() > 0:
            return  # admitted at once: no queue to join
        live = await self.store.live_sessions()
        queued = sum(s.state == "queued" for s in live)
        if queued >= limits.max_queue:
            self.metrics.refused("queue_full")
            raise ApiError(
                503,
                "queue_full",
                f"the queue is full ({queued} waiting); please try again later",
                headers=retry_after(60),
            )
        wait_s = await self.waits.next_wait_s(live, queued)
        if wait_s > limits.max_wait_s:
            self.metrics.refused("wait_too_long")
            raise ApiError(
                503,
                "wait_too_long",
                f"the wait is about {wait_s / 60:.0f} min, longer than this study's "
                f"{limits.max_wait_s / 60:.0f} min; please try again later",
                headers=retry_after(min(wait_s - limits.max_wait_s, 3600)),
            )

    async def admit(self) -> None:
        async with self.lock:
            await self._admit()

    async def admit_locked(self) -> None:
        """`admit` for a caller that holds the lock already."""
        await self._admit()

    async def _admit(self) -> None:
        """Give free slots to the oldest queued sessions (caller holds the lock)."""
        free = await self.free_slots()
        if free == 0:
            return
        queued = [s for s in await self.store.live_sessions() if s.state == "queued"]
        for session in queued[:free]:
            admitted = await self.store.update_session(
                session.id,
                only_if_state=("queued",),
                state="starting",
                admitted_at=time.time(),
                replica=self.replicas.name,
            )
            if not admitted:  # gone meanwhile (its worker left through another replica)
                continue
            self.pool.reserve(session.id)
            await self.store.log("admitted", session.id, session.worker_id)
            task = asyncio.create_task(self._launch(session.id), name=f"launch-{session.id}")
            self._launches[session.id] = task

            def forget(_task: asyncio.Task[None], sid: str = session.id) -> None:
                self._launches.pop(sid, None)

            task.add_done_callback(forget)

    async def _launch(self, session_id: str) -> None:
        session = await self.store.session(session_id)
        if session is None:
            return
        report_token = new_token()
        await self.store.update_session(session_id, report_token_hash=token_hash(report_token))
        try:
            config = self.configs.for_session(session, report_token)
            key = (session.task, session.robot, session.controller)
            handle = await self.spares.take(key, assignment_of(config))
            self.spares.fill([key])  # replace the spare (or start one for next time)
            if handle is None:
                handle = await self.pool.launcher.start(config)
        except asyncio.CancelledError:
            raise
        except (LaunchError, ValueError, OSError) as exc:
            log.error("session %s: %s", session_id, exc)
            self.metrics.launch_failures.inc()
            await self.end(session_id, "error", error=str(exc)[-2000:])
            return
        async with self.lock:
            slot = self.pool.slots.get(session_id)
            if slot is None:  # ended while starting: nobody wants this server
                self.pool.stop_later(handle)
                return
            slot.handle = handle
            slot.healthy_at = time.monotonic()  # probed from now on (coord/service/liveness.py)
            now = time.time()
            await self.store.update_session(
                session_id,
                only_if_state=("starting",),
                state="ready",
                ready_at=now,
                last_heartbeat_at=now,  # the page may have waited for the server to start
                teleop_url=handle.url,
                server=server_name(self.pool.launcher, handle),
            )
        await self.store.log("ready", session_id, session.worker_id, url=handle.url)

    async def end(
        self,
        session_id: str,
        reason: str,
        error: str | None = None,
        completion_code: str | None = None,
        stop_delay_s: float = 0.0,
    ) -> bool:
        """End a live session, free its slot at once, admit the next. False if already ended."""
        async with self.lock:
            ended = await self._mark_ended(session_id, reason, error, completion_code)
            slot = self.pool.slots.pop(session_id, None)
            if slot is not None and slot.handle is not None:
                self.pool.stop_later(slot.handle, stop_delay_s)
            await self._admit()
        return ended

    async def restart(self, session_id: str, cause: RestartCause, why: str) -> bool:
        """The session's server exited or hung: kill it (a hung server can finish nothing)
        and queue the session again at its old place with its count kept, at most
        `max_restarts` times; past that it ends as `error`. False if it was not live."""
        async with self.lock:
            session = await self.store.session(session_id)
            if session is None or session.state not in ("starting", "ready"):
                return False
            slot = self.pool.slots.pop(session_id, None)
            if slot is not None and slot.handle is not None:
                # Gone before the next server looks at the session's write-ahead log: a hung
                # process still holds its lock on it (an exited one is gone already).
                await self.pool.launcher.stop(slot.handle, grace_s=0.0)
            if session.restarts >= self.config.max_restarts:
                restarted = False
                await self._mark_ended(session_id, "error", error=why)
            else:
                restarted = await self.store.requeue(session_id, why)
                if restarted:
                    self.metrics.restarts.labels(cause=cause).inc()
            await self._admit()
        log.warning(
            "session %s: %s (%s)", session_id, why, "queued again" if restarted else "ended"
        )
        return restarted

    async def _mark_ended(
        self,
        session_id: str,
        reason: str,
        error: str | None = None,
        completion_code: str | None = None,
    ) -> bool:
        fields: dict[str, Any] = {"state": "ended", "ended_reason": reason, "ended_at": time.time()}
        if error is not None:
            fields["error"] = error
        if completion_code is not None:
            fields["completion_code"] = completion_code
        ended = await self.store.update_session(
            session_id, only_if_state=("queued", "starting", "ready"), **fields
        )
        if ended:
            self.waits.forget_mean()
            self.metrics.ended.labels(reason=reason).inc()
            await self.store.log("ended", session_id, reason=reason)
        return ended

    async def heartbeat(self, session: Session, interface: str | None) -> None:
        fields: dict[str, Any] = {"last_heartbeat_at": time.time()}
        if interface is not None:
            fields["interface"] = interface
        await self.store.update_session(
            session.id, only_if_state=("queued", "starting", "ready"), **fields
        )

    async def queue_positions(self) -> dict[str, tuple[int, float]]:
        """Queued session id -> (1-based position, estimated wait in seconds)."""
        return await self.waits.positions()
