"""The coordinator's core: sessions from queued to ended, the slots they hold, and the
background sweeps that keep both true.

All decisions that change who holds a slot happen under one admission lock, shared by every
replica on PostgreSQL (`coord/db/replicas.py`), and count the slots in the database: admission is
strictly FIFO and the capacity never exceeded, however many replicas serve. A session whose
teleop server exits or hangs is queued again at its old place with its count kept (`restart`);
so is a running session whose server a restarted coordinator cannot take back.

The `Coordinator` owns its collaborators (the pool, the spares, the lock, the replicas' table)
and its sweeps: each round of the reaper (`sweep`) beats for this replica, takes over the
sessions of replicas that are gone, follows a cluster's room and ends the sessions nobody is at
any more; the liveness probes and the spool sweeper run beside it. They change the sessions and
the slots only through the methods here; nothing outside reaches into them.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable
from functools import partial
from typing import Any

import aiohttp

from crowdteleop.coord.db.replicas import default_replica_name
from crowdteleop.coord.db.spare_registry import SpareKey
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Session, Worker
from crowdteleop.coord.fleet.cluster import ClusterRoom
from crowdteleop.coord.fleet.launcher import (
    Launcher,
    LaunchError,
    ReattachingLauncher,
    server_name,
    stop_orphans,
)
from crowdteleop.coord.fleet.pool import ServerState, TeleopPool
from crowdteleop.coord.fleet.spares import SparePool
from crowdteleop.coord.fleet.startup import StartupStats, available_bytes
from crowdteleop.coord.guard.security import new_id, new_token, token_hash
from crowdteleop.coord.guard.session_keys import SessionKeys
from crowdteleop.coord.service.admission import AdmissionRules
from crowdteleop.coord.service.campaign import CampaignConfig
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.liveness import Liveness
from crowdteleop.coord.service.metrics import CoordMetrics, RestartCause
from crowdteleop.coord.service.occupancy import Occupancy, OccupancyCache
from crowdteleop.coord.service.preparing import Preparation
from crowdteleop.coord.service.reaper import RESTART, verdict
from crowdteleop.coord.service.replication import Replication, orphans
from crowdteleop.coord.service.spools import SWEEP_INTERVAL_S, SpoolSweeper
from crowdteleop.coord.service.teleop_configs import TeleopConfigs, assignment_of
from crowdteleop.coord.service.waits import WaitEstimates
from crowdteleop.teleop.messages import IceServer

log = logging.getLogger(__name__)


def spread(total: int, keys: list[SpareKey]) -> dict[SpareKey, int]:
    """`total` spares over `keys`, the first kinds (the campaigns' next) getting any extra."""
    if not keys:
        return {}
    share, extra = divmod(total, len(keys))
    return {key: share + (1 if n < extra else 0) for n, key in enumerate(keys)}


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
        self._store = store
        self._sessions = store.sessions
        self._keys = keys
        self._metrics = metrics or CoordMetrics()
        self._launcher = launcher
        self._configs = TeleopConfigs(config, keys)
        self._pool = TeleopPool(launcher, config.capacity)
        self._lock = store.admission_lock()
        name = config.replica_name or default_replica_name()
        self._replicas = store.replicas(name, config.replica_stale_after_s)
        self._spare_registry = store.spare_registry(name)
        self._startup = StartupStats()
        self._spares = SparePool(
            launcher,
            self._configs.for_spare,
            keys.teleop_admin_token,
            self._spare_targets,
            self._spare_registry,
            self._lock,
            self._startup,
        )
        self.preparation = Preparation(
            self._startup,
            self._spares,
            self._spare_registry,
            self._free_slots,
            self._spare_targets,
            lambda session_id: session_id in self._launches,
        )
        self._cluster = ClusterRoom(launcher, self._spare_registry, self._spare_targets)
        self._replication = Replication(
            self._sessions, self._pool, launcher, self._replicas, self._metrics
        )
        self._waits = WaitEstimates(self._sessions, config, lambda: self._pool.capacity)
        self._occupancy = OccupancyCache(self.live_sessions, lambda: self._pool.capacity)
        self._admission = AdmissionRules(self._sessions, config, self._metrics, self._waits)
        self._liveness = Liveness(self._pool, config, self.restart)
        self._spools = SpoolSweeper(config, self._sessions)
        self._launches: dict[str, asyncio.Task[None]] = {}
        self._sweeps: list[asyncio.Task[None]] = []

    # --- lifecycle ------------------------------------------------------------------------

    async def start(self) -> None:
        """Sessions a previous run left live keep their place: the queued stay queued, a
        ready one whose server outlived the run (a cluster launcher's) keeps it, and the others
        are queued again ahead of the queue, their counts kept. Sessions another live replica
        watches are its own. Every page gets a fresh heartbeat allowance; servers no live
        session holds are stopped. A cluster's room is read before anyone is admitted."""
        await self._follow_cluster(admit=False)
        campaigns = {c.name: c.model_dump(mode="json") for c in self.config.campaigns}
        await self._store.save_campaigns(campaigns)
        await self._replicas.beat()
        others = await self._replicas.others_alive()
        await self._spares.forget_unstarted()
        await self._spares.sweep(others | {self._replicas.name})  # its own, taken back if alive
        now = time.time()
        async with self._lock:
            for session in await self._sessions.live_sessions():
                if session.state != "queued" and session.replica in others:
                    continue
                await self._sessions.update_session(session.id, last_heartbeat_at=now)
                if session.state != "queued":
                    await self._replication.take_over(session, "the coordinator restarted")
            held = [s for s in await self._sessions.live_sessions() if s.state != "queued"]
            spares = await self._spare_registry.rows()
            keep = {s.id for s in held} | {s.server for s in held if s.server}
            keep |= {r.id for r in spares} | {r.server for r in spares if r.server}
            await stop_orphans(self._launcher, keep)
            await self._admit()
        self._spares.fill(self._configs.spare_keys())

    def start_sweeps(self) -> None:
        """The reaper, the liveness probes and the spool sweeper, in the background until
        `close` cancels them; one failed round never stops a sweep."""
        config = self.config
        reaper = _every(config.reaper_interval_s, self.sweep, "reaper sweep")
        spools = _every(
            SWEEP_INTERVAL_S, self._spools.sweep_once, "sweeping the spools of ended sessions"
        )
        self._sweeps = [
            asyncio.create_task(reaper, name="reaper"),
            asyncio.create_task(self._probe_forever(), name="liveness"),
            asyncio.create_task(spools, name="spools"),
        ]

    async def _probe_forever(self) -> None:
        async with aiohttp.ClientSession() as http:
            probe = partial(self._liveness.probe_once, http)
            await _every(self.config.health_interval_s, probe, "liveness probe")

    async def close(self) -> None:
        """Stop the sweeps, then every teleop server (each stores its running episode); the
        sessions stay as they are in the database, and the next start gives them back their
        places. Servers that outlive this process (a cluster's) are left running instead, for
        the other replicas or for this one's restart (`systemctl restart`, an upgrade): their
        workers keep driving, and whoever starts next takes them over by name."""
        for task in [*self._sweeps, *self._launches.values()]:
            task.cancel()
        for task in [*self._sweeps, *self._launches.values()]:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        others: set[str] = set()
        with contextlib.suppress(Exception):  # the database may be gone too
            others = await self._replicas.others_alive()
        await self._spares.close(hand_over=bool(others))
        if isinstance(self._launcher, ReattachingLauncher):
            servers = self._pool.servers()
            heirs = sorted(others) or "this coordinator's next start"
            log.info("leaving %d running sessions to %s", len(servers), heirs)
            for server in servers:
                if server.url is None:  # its launch was cancelled above
                    await self._sessions.requeue(
                        server.session_id, "its coordinator stopped", count_restart=False
                    )
                self._pool.forget(server.session_id)  # its server runs on for the others
        await self._pool.close()
        with contextlib.suppress(Exception):
            await self._replicas.leave()

    # --- sweeps ---------------------------------------------------------------------------

    async def sweep(self) -> list[tuple[str, str]]:
        """One round of the reaper: this replica's heartbeat and the sessions of replicas that
        are gone, a cluster's room, then the sessions nobody is at any more. Returns the
        (session id, reason) pairs it ended or restarted."""
        await self._sweep_replicas()
        await self._follow_cluster()
        return await self._reap(time.time())

    async def _sweep_replicas(self) -> None:
        """Replicas keep each other's sessions going (`coord/service/replication.py`); spares
        gone anywhere are replaced; the shared limits forget what no window counts."""
        await self._replicas.beat()
        alive = await self._replicas.alive()
        orphaned = orphans(await self._sessions.live_sessions(), alive)
        if orphaned:
            async with self._lock:
                await self._replication.adopt(orphaned)
                await self._admit()
        async with self._lock:
            await self._replication.reconcile()
        listed = await self._spares.sweep(alive)
        self._spares.fill(self._spares.short(await self._spare_targets(), listed))
        await self._store.forget_old_limit_events()

    async def _follow_cluster(self, admit: bool = True) -> None:
        """A cluster's room (less every replica's spares) becomes the capacity, queued
        sessions are admitted into new room, and the cluster hears how many want a slot."""
        room = await self._cluster.sessions()
        if room is None:
            return
        if room != self._pool.capacity:
            log.info("cluster capacity %d -> %d sessions", self._pool.capacity, room)
            self._pool.capacity = room
            self._metrics.capacity.set(room)
            if admit:
                await self.admit()
        live = await self._sessions.live_sessions()
        spares = self.config.spare_servers
        await self._cluster.request(len(live) + (1 if spares == "auto" else spares))

    async def _reap(self, now: float) -> list[tuple[str, str]]:
        """End the sessions nobody is at any more; queue again those whose server exited
        (`coord/service/reaper.py` says which)."""
        verdicts: list[tuple[str, str]] = []
        for session in await self._sessions.live_sessions():
            reason = verdict(session, now, self.config, self._pool.alive(session.id))
            if reason == RESTART:
                if await self.restart(session.id, "exited", "the teleop server exited"):
                    verdicts.append((session.id, "restarted"))
            elif reason is not None and await self.end(session.id, reason):
                log.info("reaped session %s: %s", session.id, reason)
                verdicts.append((session.id, reason))
        return verdicts

    # --- reading --------------------------------------------------------------------------

    @property
    def capacity(self) -> int:
        """Teleop servers allowed at once across replicas (a cluster's: its room now)."""
        return self._pool.capacity

    async def session(self, session_id: str) -> Session | None:
        return await self._sessions.session(session_id)

    async def live_sessions(self) -> list[Session]:
        """Queued ones in queue order (oldest first), then the others."""
        return await self._sessions.live_sessions()

    async def occupancy(self) -> Occupancy:
        """Slots held and workers queued, at most a second old (`service/occupancy.py`)."""
        return await self._occupancy.current()

    async def queue_positions(self) -> dict[str, tuple[int, float]]:
        """Queued session id -> (1-based position, estimated wait in seconds)."""
        return await self._waits.positions()

    async def typical_session_s(self) -> float | None:
        """How long sessions have held their slot lately (None before any has ended)."""
        typical = await self._waits.mean_session_s(-1.0)
        return typical if typical > 0 else None

    def servers(self) -> list[ServerState]:
        """The slots this replica watches and their servers."""
        return self._pool.servers()

    def spares(self) -> list[str]:
        """The warm spares this replica watches, running."""
        return list(self._spares.handles)

    def ice_servers(self, name: str) -> list[IceServer]:
        """Everyone's STUN/TURN servers, and TURN credentials of `name`'s own, fresh now."""
        return self._configs.ice_servers(name)

    # --- warm spares and robots on their way -------------------------------------------------

    async def _spare_targets(self) -> dict[SpareKey, int]:
        """How many spares each kind should have now: `spare_servers`, or with `auto` every
        free slot (as many as the available memory holds) spread over the campaigns' kinds;
        on a cluster, where a spare holds a slot, `auto` is one per kind."""
        keys = self._configs.spare_keys()
        setting = self.config.spare_servers
        if setting != "auto":
            return dict.fromkeys(keys, setting)
        if self._spares.shared:
            return dict.fromkeys(keys, 1)
        total = await self._free_slots()
        available = available_bytes()
        if available is not None:
            kept = await self._spare_registry.count(own=True)
            total = min(total, kept + available // self._startup.server_bytes)
        return spread(total, keys)

    # --- sessions -------------------------------------------------------------------------

    async def create_session(
        self, worker: Worker, campaign: CampaignConfig, client: str | None = None
    ) -> Session:
        """The worker's live session, or a new one in the queue (admitted at once if free).
        A new one is refused past the admission limits (`CoordConfig.admission`); `client`
        is the address the request is counted under (the database keeps only an HMAC)."""
        client_tag = self._keys.client_tag(client) if client is not None else None
        async with self._lock:
            existing = await self._sessions.live_session_of(worker.id)
            if existing is not None:
                return existing
            await self._admission.check(client_tag, await self._free_slots())
            index = await self._sessions.count_sessions(campaign.name)
            task, robot, controller = campaign.assignment(index)
            now = time.time()
            session = await self._sessions.add_session(
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
        return await self._sessions.session(session.id) or session

    async def admit(self) -> None:
        async with self._lock:
            await self._admit()

    async def _free_slots(self) -> int:
        """Slots no session holds, counted in the database (every replica's sessions)."""
        return max(0, self._pool.capacity - await self._sessions.held_slots())

    async def _admit(self) -> None:
        """Give free slots to the oldest queued sessions (caller holds the lock). Every change
        of this replica's sessions (a new one, an end, a restart, a take-over) comes here, so
        the pings' remembered occupancy is dropped here too."""
        self._occupancy.forget()
        free = await self._free_slots()
        if free == 0:
            return
        queued = [s for s in await self._sessions.live_sessions() if s.state == "queued"]
        for session in queued[:free]:
            admitted = await self._sessions.update_session(
                session.id,
                only_if_state=("queued",),
                state="starting",
                admitted_at=time.time(),
                replica=self._replicas.name,
            )
            if not admitted:  # gone meanwhile (its worker left through another replica)
                continue
            self._pool.reserve(session.id)
            await self._sessions.log("admitted", session.id, session.worker_id)
            task = asyncio.create_task(self._launch(session.id), name=f"launch-{session.id}")
            self._launches[session.id] = task

            def forget(_task: asyncio.Task[None], sid: str = session.id) -> None:
                self._launches.pop(sid, None)

            task.add_done_callback(forget)

    async def _launch(self, session_id: str) -> None:
        session = await self._sessions.session(session_id)
        if session is None:
            return
        report_token = new_token()
        await self._sessions.update_session(session_id, report_token_hash=token_hash(report_token))
        try:
            config = self._configs.for_session(session, report_token)
            key = (session.task, session.robot, session.controller)
            with self.preparation.handing_over(session_id):
                handle = await self._spares.take(key, assignment_of(config))
            self._spares.fill([key])  # replace the spare (or start one for next time)
            if handle is None:
                handle = await self.preparation.cold_start(self._launcher, session_id, config)
        except asyncio.CancelledError:
            raise
        except (LaunchError, ValueError, OSError) as exc:
            log.error("session %s: %s", session_id, exc)
            self._metrics.launch_failures.inc()
            await self.end(session_id, "error", error=str(exc)[-2000:])
            return
        async with self._lock:
            if not self._pool.started(session_id, handle):  # ended while starting
                self._pool.stop_later(handle)
                return
            now = time.time()
            await self._sessions.update_session(
                session_id,
                only_if_state=("starting",),
                state="ready",
                ready_at=now,
                last_heartbeat_at=now,  # the page may have waited for the server to start
                teleop_url=handle.url,
                server=server_name(self._launcher, handle),
            )
        await self._sessions.log("ready", session_id, session.worker_id, url=handle.url)

    async def end(
        self,
        session_id: str,
        reason: str,
        error: str | None = None,
        completion_code: str | None = None,
        stop_delay_s: float = 0.0,
    ) -> bool:
        """End a live session, free its slot at once, admit the next. False if already ended."""
        async with self._lock:
            ended = await self._mark_ended(session_id, reason, error, completion_code)
            self._pool.release(session_id, stop_delay_s)
            await self._admit()
        return ended

    async def restart(self, session_id: str, cause: RestartCause, why: str) -> bool:
        """The session's server exited or hung: kill it (a hung server can finish nothing)
        and queue the session again at its old place with its count kept, at most
        `max_restarts` times; past that it ends as `error`. False if it was not live."""
        async with self._lock:
            session = await self._sessions.session(session_id)
            if session is None or session.state not in ("starting", "ready"):
                return False
            # Gone before the next server looks at the session's write-ahead log: a hung
            # process still holds its lock on it (an exited one is gone already).
            await self._pool.kill(session_id)
            if session.restarts >= self.config.max_restarts:
                restarted = False
                await self._mark_ended(session_id, "error", error=why)
            else:
                restarted = await self._sessions.requeue(session_id, why)
                if restarted:
                    self._metrics.restarts.labels(cause=cause).inc()
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
        ended = await self._sessions.update_session(
            session_id, only_if_state=("queued", "starting", "ready"), **fields
        )
        if ended:
            self._waits.forget_mean()
            self._metrics.ended.labels(reason=reason).inc()
            await self._sessions.log("ended", session_id, reason=reason)
        return ended

    async def heartbeat(self, session: Session, interface: str | None) -> None:
        fields: dict[str, Any] = {"last_heartbeat_at": time.time()}
        if interface is not None:
            fields["interface"] = interface
        await self._sessions.update_session(
            session.id, only_if_state=("queued", "starting", "ready"), **fields
        )


async def _every(interval_s: float, step: Callable[[], Awaitable[Any]], what: str) -> None:
    """Run `step` every `interval_s` until cancelled; a failed round is logged, not fatal."""
    while True:
        await asyncio.sleep(interval_s)
        try:
            await step()
        except asyncio.CancelledError:
            raise
        except Exception:
            log.exception("%s failed", what)
