"""The coordinator's core: sessions from queued to ended, the pool's slots, episode reports.

All decisions that change who holds a slot happen under one asyncio lock, so admission is
strictly FIFO and the capacity is never exceeded; the database records every step.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from typing import Any

from crowdteleop.coord.campaign import CampaignConfig
from crowdteleop.coord.config import CoordConfig
from crowdteleop.coord.launcher import Launcher, LaunchError
from crowdteleop.coord.pool import TeleopPool
from crowdteleop.coord.queue import expected_remaining_s, mean_session_s, queue_etas
from crowdteleop.coord.schemas import EpisodeAck, SessionView
from crowdteleop.coord.security import new_completion_code, new_id, new_token, token_hash
from crowdteleop.coord.session_keys import SessionKeys
from crowdteleop.coord.spares import SpareKey, SparePool
from crowdteleop.coord.store import Store
from crowdteleop.coord.tables import Episode, Session, Worker
from crowdteleop.tasks import get_task
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.messages import Assignment, EpisodeReport

log = logging.getLogger(__name__)

PROLIFIC_COMPLETE = "https://app.prolific.com/submissions/complete?cc="
MEAN_CACHE_S = 10.0


def deep_merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _assignment(config: TeleopConfig) -> Assignment:
    """What a warm spare needs to become the server of the session `config` describes."""
    assert config.admin_token is not None  # the coordinator always gives one
    return Assignment(
        session_id=config.session_id,
        worker_id=config.worker_id,
        token=config.token,
        admin_token=config.admin_token,
        recording_directory=config.recording.directory,
        report_url=config.report_url,
        report_token=config.report_token,
    )


class Coordinator:
    def __init__(
        self, config: CoordConfig, store: Store, launcher: Launcher, keys: SessionKeys
    ) -> None:
        self.config = config
        self.store = store
        self.keys = keys
        self.pool = TeleopPool(launcher, config.capacity)
        self.spares = SparePool(launcher, self._spare_config, config.spare_servers)
        self.lock = asyncio.Lock()
        self._launches: dict[str, asyncio.Task[None]] = {}
        self._mean: tuple[float, float] | None = None  # (computed at, value)

    # --- lifecycle ------------------------------------------------------------------------

    async def start(self) -> None:
        """Sessions a previous run left live have no server any more: end them."""
        await self.store.save_campaigns(self.config.campaigns)
        for session in await self.store.live_sessions():
            await self._mark_ended(session.id, "error", error="coordinator restarted")
        self.spares.fill(self._spare_keys())

    async def close(self) -> None:
        """Stop every teleop server; live sessions end with reason 'error' (shutdown)."""
        for task in list(self._launches.values()):
            task.cancel()
        for task in list(self._launches.values()):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        async with self.lock:
            for session in await self.store.live_sessions():
                await self._mark_ended(session.id, "error", error="coordinator shut down")
                self.pool.release(session.id)
        await self.spares.close()
        await self.pool.close()

    # --- sessions -------------------------------------------------------------------------

    async def create_session(self, worker: Worker, campaign: CampaignConfig) -> Session:
        """The worker's live session, or a new one in the queue (admitted at once if free)."""
        async with self.lock:
            existing = await self.store.live_session_of(worker.id)
            if existing is not None:
                return existing
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
                    last_heartbeat_at=now,
                    report_token_hash="",
                )
            )
            await self._admit()
        return await self.store.session(session.id) or session

    async def _admit(self) -> None:
        """Give free slots to the oldest queued sessions (caller holds the lock)."""
        if self.pool.free == 0:
            return
        queued = [s for s in await self.store.live_sessions() if s.state == "queued"]
        for session in queued[: self.pool.free]:
            self.pool.reserve(session.id)
            await self.store.update_session(session.id, state="starting", admitted_at=time.time())
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
            config = self.teleop_config(session, report_token)
            key = (session.task, session.robot, session.controller)
            handle = await self.spares.take(key, _assignment(config))
            self.spares.fill([key])  # replace the spare (or start one for next time)
            if handle is None:
                handle = await self.pool.launcher.start(config)
        except asyncio.CancelledError:
            raise
        except (LaunchError, ValueError, OSError) as exc:
            log.error("session %s: %s", session_id, exc)
            await self.end(session_id, "error", error=str(exc)[-2000:])
            return
        async with self.lock:
            slot = self.pool.slots.get(session_id)
            if slot is None:  # ended while starting: nobody wants this server
                self.pool.stop_later(handle)
                return
            slot.handle = handle
            now = time.time()
            await self.store.update_session(
                session_id,
                only_if_state=("starting",),
                state="ready",
                ready_at=now,
                last_heartbeat_at=now,  # the page may have waited for the server to start
                teleop_url=handle.url,
            )
        await self.store.log("ready", session_id, session.worker_id, url=handle.url)

    def teleop_config(self, session: Session, report_token: str) -> TeleopConfig:
        directory = (self.config.data_dir / "episodes" / session.campaign / session.id).resolve()
        fields = deep_merge(
            self.config.teleop,
            {
                "session_id": session.id,
                "worker_id": session.worker_id,
                "token": self.keys.teleop_token(session.id),
                "admin_token": self.keys.teleop_admin_token(session.id),
                "sim": {"task": session.task, "robot": session.robot},
                "control": {"controller": session.controller},
                "recording": {"directory": str(directory)},
                "ice_servers": list(self.config.ice_servers),
                "allowed_origins": [self.config.public_url],
                "report_url": f"{self.config.report_base_url}/internal/episodes",
                "report_token": report_token,
            },
        )
        return TeleopConfig.model_validate(fields)

    def _spare_keys(self) -> list[SpareKey]:
        """The (task, robot, controller) combinations the campaigns hand out, round-robin."""
        keys: list[SpareKey] = []
        for campaign in self.config.campaigns:
            tasks, robots, controllers = campaign.tasks, campaign.robots, campaign.controllers
            for n in range(max(len(tasks), len(robots), len(controllers))):
                key = (
                    tasks[n % len(tasks)],
                    robots[n % len(robots)],
                    controllers[n % len(controllers)],
                )
                if key not in keys:
                    keys.append(key)
        return keys

    def _spare_config(self, key: SpareKey) -> TeleopConfig:
        """A spare's config: the simulation of `key`, a placeholder identity (standby)."""
        task, robot, controller = key
        spare_id = f"spare-{secrets.token_hex(6)}"
        fields = deep_merge(
            self.config.teleop,
            {
                "session_id": spare_id,
                "worker_id": "unassigned",
                "token": new_token(),
                "admin_token": new_token(),
                "standby": True,
                "sim": {"task": task, "robot": robot},
                "control": {"controller": controller},
                "recording": {
                    "directory": str((self.config.data_dir / "spares" / spare_id).resolve())
                },
                "ice_servers": list(self.config.ice_servers),
                "allowed_origins": [self.config.public_url],
            },
        )
        return TeleopConfig.model_validate(fields)

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
            self._mean = None
            await self.store.log("ended", session_id, reason=reason)
        return ended

    async def heartbeat(self, session: Session, interface: str | None) -> None:
        fields: dict[str, Any] = {"last_heartbeat_at": time.time()}
        if interface is not None:
            fields["interface"] = interface
        await self.store.update_session(
            session.id, only_if_state=("queued", "starting", "ready"), **fields
        )

    # --- episodes -------------------------------------------------------------------------

    async def report_episode(self, session: Session, report: EpisodeReport) -> EpisodeAck:
        """Record the episode (once); the last required success completes the session."""
        interface = report.device if report.device not in (None, "bot") else session.interface
        new, done = await self.store.add_episode(
            Episode(
                episode_id=report.episode_id,
                session_id=session.id,
                worker_id=session.worker_id,
                number=report.episode,
                outcome=report.outcome,
                steps=report.steps,
                duration_s=report.duration_s,
                uri=report.uri,
                interface=interface,
                task=session.task,
                telemetry=report.telemetry,
                created_at=time.time(),
            )
        )
        completed = False
        if new and report.outcome == "success" and done >= session.demos_required:
            campaign = self.config.campaign(session.campaign)
            code = (campaign.prolific_completion_code if campaign else None) or (
                new_completion_code()
            )
            # A short grace lets the page hear about the saved episode before the server goes.
            completed = await self.end(
                session.id, "completed", completion_code=code, stop_delay_s=2.0
            )
        return EpisodeAck(
            episode_id=report.episode_id,
            duplicate=not new,
            demos_done=done,
            demos_required=session.demos_required,
            completed=completed,
        )

    # --- views ----------------------------------------------------------------------------

    async def mean_session_s(self, fallback_s: float) -> float:
        now = time.monotonic()
        if self._mean is None or now - self._mean[0] > MEAN_CACHE_S:
            self._mean = (now, mean_session_s(await self.store.ended_durations(), -1.0))
        value = self._mean[1]
        return fallback_s if value < 0 else value

    async def queue_positions(self) -> dict[str, tuple[int, float]]:
        """Queued session id -> (1-based position, estimated wait in seconds)."""
        live = await self.store.live_sessions()
        queued = [s for s in live if s.state == "queued"]
        if not queued:
            return {}
        fallback = self.config.default_campaign.time_limit_s
        mean = await self.mean_session_s(fallback)
        now = time.time()
        remaining = [
            expected_remaining_s(now - (s.ready_at or now), mean, s.time_limit_s)
            for s in live
            if s.state in ("starting", "ready")
        ]
        etas = queue_etas(self.config.capacity, remaining, len(queued), mean)
        return {s.id: (i + 1, eta) for i, (s, eta) in enumerate(zip(queued, etas, strict=True))}

    async def view(self, session: Session, worker: Worker | None = None) -> SessionView:
        position, eta = None, None
        if session.state == "queued":
            position, eta = (await self.queue_positions()).get(session.id, (None, None))
        worker = worker or await self.store.worker(session.worker_id)
        redirect = None
        if session.completion_code and worker is not None and worker.source == "prolific":
            redirect = PROLIFIC_COMPLETE + session.completion_code
        time_left = None
        if session.state == "ready" and session.ready_at is not None:
            time_left = round(max(0.0, session.ready_at + session.time_limit_s - time.time()), 1)
        return SessionView(
            session_id=session.id,
            state=session.state,
            queue_position=position,
            eta_s=eta,
            task=session.task,
            robot=session.robot,
            controller=session.controller,
            instruction=get_task(session.task).instruction,
            interfaces=session.interfaces,
            time_limit_s=session.time_limit_s,
            time_left_s=time_left,
            demos_done=session.demos_done,
            demos_required=session.demos_required,
            completion_code=session.completion_code,
            redirect_url=redirect,
            ice_servers=list(self.config.ice_servers),
            ended_reason=session.ended_reason,
        )
