"""The teleop server process: HTTP signalling and its auth, and the fixed-rate control loop.

The rest lives beside it, one concern each: `peering` (WebRTC peers), `dispatch` (what a
client message does), `broadcast` (what peers hear each tick), `archive` (storing and
reporting episodes), `session` (the simulated robot).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import threading
from pathlib import Path
from typing import Any

from aiohttp import web
from aiohttp.typedefs import Handler
from pydantic import ValidationError

from crowdteleop.recording.wal_recovery import recover_orphans
from crowdteleop.teleop.archive import EpisodeArchive, reports_delayed
from crowdteleop.teleop.assign import assigned_config
from crowdteleop.teleop.auth import bearer_matches, token_matches
from crowdteleop.teleop.broadcast import TickBroadcaster
from crowdteleop.teleop.clock import FixedRateClock
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.dispatch import Dispatcher, worker_video_stalled
from crowdteleop.teleop.messages import (
    MAX_OFFER_BYTES,
    Assignment,
    OfferAnswer,
    OfferRequest,
    TeleopHealth,
    missing_offer_sections,
)
from crowdteleop.teleop.origin import origin_allowed
from crowdteleop.teleop.peering import PeerSet
from crowdteleop.teleop.peers import Peer
from crowdteleop.teleop.protocol import ErrorEvent, Hello, json_schema
from crowdteleop.teleop.session import TeleopSession
from crowdteleop.teleop.telemetry import SessionTelemetry
from crowdteleop.teleop.video import FrameSource, configure_encoder_bitrates

log = logging.getLogger(__name__)


class TeleopServer:
    """Owns the session, its peers and its loop. `await start()`, then serve `app`."""

    def __init__(self, config: TeleopConfig) -> None:
        self.config = config
        self.frames = FrameSource()
        self.telemetry = SessionTelemetry()
        self.clock = FixedRateClock(config.sim.control_hz)
        self.peers = PeerSet(
            config.ice_servers,
            config.limits,
            config.video,
            self.frames,
            on_message=self._on_message,
            on_events_open=self._on_events_open,
            on_left=self._on_left,
        )
        self.broadcaster = TickBroadcaster(
            self.peers,
            self.frames,
            self.telemetry,
            self.clock.stats,
            config.video,
            config.telemetry_interval_s,
            self.telemetry_snapshot,
        )
        self.archive = EpisodeArchive(self.peers, self.telemetry)
        self._told_recording_failure: str | None = None  # what the peers last heard of it
        self.session: TeleopSession
        self.dispatcher: Dispatcher
        self._loop_task: asyncio.Task[None] | None = None
        self._background: set[asyncio.Task[bool]] = set()
        self.app = web.Application(
            client_max_size=MAX_OFFER_BYTES * 2, middlewares=[self._check_origin]
        )
        self.app.add_routes(
            [
                web.post("/offer", self.handle_offer),
                web.get("/health", self.handle_health),
                web.get("/telemetry", self.handle_telemetry),
                web.get("/protocol.json", self.handle_protocol),
                web.post("/assign", self.handle_assign),
            ]
        )
        self.app.on_startup.append(lambda _app: self.start())
        self.app.on_shutdown.append(lambda _app: self.stop())

    async def start(self) -> None:
        configure_encoder_bitrates(self.config.video)
        recovered = await asyncio.to_thread(
            recover_orphans, self.config.recording.directory / "incoming"
        )
        self.session = await TeleopSession.create(self.config)
        await self._store_recovered(recovered)
        self._probe_reports()
        self.dispatcher = Dispatcher(
            self.session, self.telemetry, self.config.limits.max_input_age_ms, self.peers
        )
        self._loop_task = asyncio.create_task(self._run_loop(), name="control-loop")

    def _probe_reports(self) -> None:
        """Whether the coordinator answers where this server will report (a node that cannot
        reach it says so now, not after the worker's first demonstration)."""
        if self.config.report_url is not None:
            probe = self.archive.reports.probe(self.config.report_url)
            task = asyncio.create_task(probe, name="report-probe")
            self._background.add(task)
            task.add_done_callback(self._background.discard)

    async def _store_recovered(self, recovered: list[Path]) -> None:
        """A crashed or hung server's last episode, finalized from its write-ahead log: kept
        for analysis (outcome "crash"), under other/, never counted as a demonstration."""
        for path in recovered:
            uri = await asyncio.to_thread(self.session.storage.put, path, f"other/{path.name}")
            path.unlink(missing_ok=True)
            log.warning("recovered an episode a crashed session left: %s", uri)

    async def stop(self) -> None:
        if self._loop_task is not None:
            self._loop_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._loop_task
        await self.peers.close()
        await self.session.close()
        await self.archive.close()

    # --- HTTP: signalling and its auth ---------------------------------------------------

    def _http_error(self, status: int, code: str, message: str) -> web.Response:
        self.telemetry.errors[f"http_{code}"] += 1
        return web.json_response({"error": code, "message": message}, status=status)

    @web.middleware
    async def _check_origin(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """A browser request from a foreign page: 403, counted as `http_foreign_origin`."""
        if not origin_allowed(request, self.config.allowed_origins):
            origin = request.headers.get("Origin", "")[:200]
            log.warning("refused %s %s from origin %r", request.method, request.path, origin)
            return self._http_error(
                403,
                "foreign_origin",
                "this server takes browser requests from its coordinator only",
            )
        return await handler(request)

    async def handle_offer(self, request: web.Request) -> web.Response:
        try:
            offer = OfferRequest.model_validate_json(await request.read())
        except ValidationError as exc:
            return self._http_error(400, "invalid_offer", str(exc.errors()[0]["msg"]))
        refusal = self._refusal(offer)
        if refusal is not None:
            return self._http_error(*refusal)
        try:
            answer, peer_id = await self.peers.connect(offer)
        except Exception as exc:  # a malformed SDP must not take the session down
            log.info("offer refused: %s", exc)
            return self._http_error(400, "invalid_sdp", f"could not use the offer: {exc}")
        body = OfferAnswer(sdp=answer.sdp, type=answer.type, peer_id=peer_id)
        return web.json_response(body.model_dump())

    def _refusal(self, offer: OfferRequest) -> tuple[int, str, str] | None:
        """Why an offer is refused before its SDP is used (status, code, message), or None."""
        if self.config.standby:
            return 409, "standby", "this server has no session yet"
        if not token_matches(offer.token, self.config.token):
            return 401, "bad_token", "the session token is wrong"
        if offer.role == "admin" and not token_matches(offer.admin_token, self.config.admin_token):
            return 403, "bad_admin_token", "admin role needs the admin token"
        missing = missing_offer_sections(offer.sdp, offer.role)
        if missing:
            sections = " and ".join(f"an m={kind} section" for kind in missing)
            return (
                400,
                "incomplete_offer",
                f"a {offer.role} offer needs {sections} (data channels; video for the "
                "worker): create them before createOffer",
            )
        if self.peers.full:
            return 503, "full", "this session has all the peers it allows"
        return None

    async def handle_health(self, _request: web.Request) -> web.Response:
        health = TeleopHealth(
            session_id=self.config.session_id,
            peers=len(self.peers),
            state=self.session.tracker.state,
            episodes=self.session.tracker.number,
            successes=self.session.tracker.successes,
            ticks=self.clock.stats.ticks,
            spool_pending=await asyncio.to_thread(self.session.storage.pending_count),
            reports_pending=self.archive.reports.pending,
            reports_unreachable=self.archive.reports.unreachable is not None,
        )
        return web.json_response(health.model_dump(mode="json"))

    async def handle_telemetry(self, request: web.Request) -> web.Response:
        if not bearer_matches(request, self.config.admin_token):
            return self._http_error(401, "bad_admin_token", "telemetry needs the admin token")
        return web.json_response({**self.telemetry_snapshot(), "stored": self.archive.stored})

    async def handle_assign(self, request: web.Request) -> web.Response:
        """Give a warm spare its session (`teleop/assign.py`)."""
        if not bearer_matches(request, self.config.admin_token):
            return self._http_error(401, "bad_admin_token", "assigning needs the admin token")
        if not self.config.standby:
            return self._http_error(409, "assigned", "this server already has its session")
        try:
            assignment = Assignment.model_validate_json(await request.read())
            config = assigned_config(self.config, assignment)
        except ValidationError as exc:
            return self._http_error(400, "invalid_assignment", str(exc.errors()[0]["msg"]))
        self.config = config
        self.session.assign(config)
        self.peers.ice_servers = config.ice_servers
        log.info("assigned to session %s", config.session_id)
        # The session may be here because its previous server crashed or hung mid-episode.
        incoming = config.recording.directory / "incoming"
        await self._store_recovered(await asyncio.to_thread(recover_orphans, incoming))
        self._probe_reports()
        return web.json_response({"session_id": config.session_id})

    async def handle_protocol(self, _request: web.Request) -> web.Response:
        return web.json_response(json_schema())

    # --- peers ---------------------------------------------------------------------------

    def _on_message(self, peer: Peer, channel: str, raw: str | bytes) -> None:
        if self.dispatcher.handle(peer, channel, raw):
            self.broadcaster.status_soon()

    def _on_left(self, peer: Peer) -> None:
        if self.session.board.release(peer.peer_id):
            self.session.request_end("disconnect")
            self.broadcaster.status_soon()
        others = (other for other in self.peers if other is not peer)
        if self.session.board.set_video_stalled(worker_video_stalled(others)):
            self.broadcaster.status_soon()

    def _on_events_open(self, peer: Peer) -> None:
        self._send_hello(peer)
        if self.archive.reports.unreachable is not None:
            peer.send(reports_delayed())
        # A page that has just joined shows its video (or soon will): a stall that only the
        # other, hidden tab reported no longer holds the arm (as when a peer leaves).
        if self.session.board.set_video_stalled(worker_video_stalled(self.peers)):
            self.broadcaster.status_soon()

    def _send_hello(self, peer: Peer) -> None:
        driver = self.session.board.driver
        peer.send(
            Hello(
                session_id=self.config.session_id,
                peer_id=peer.peer_id,
                role=peer.role,
                task=self.config.sim.task,
                instruction=self.session.task.instruction,
                fps=self.config.sim.control_hz,
                width=self.config.video.width,
                height=self.config.video.height,
                controlling_device=driver.device if driver else None,
                video_stall_ms=self.config.limits.video_stall_ms,
                max_input_age_ms=self.config.limits.max_input_age_ms,
            )
        )

    # --- the control loop ----------------------------------------------------------------

    def telemetry_snapshot(self) -> dict[str, Any]:
        snapshot = self.telemetry.snapshot(self.clock.stats, self.peers.errors())
        snapshot["sim_errors"] = self.session.sim_errors
        return snapshot

    async def _run_loop(self) -> None:
        while True:
            due = await self.clock.wait_next()
            try:
                await self._one_tick()
            except asyncio.CancelledError:
                raise
            except Exception:  # the loop must outlive any one bad tick
                log.exception("control tick failed")
                self.telemetry.errors["tick"] += 1
            self.clock.finished(due)

    async def _one_tick(self) -> None:
        result = await self.session.tick(want_privileged=bool(self.peers.admins()))
        if self.session.tracker.recording:
            self.telemetry.episode_running(self.session.tracker.number)
        failure = self.session.recording_failure
        if failure != self._told_recording_failure:
            self._told_recording_failure = failure
            if failure is not None:
                self.telemetry.errors["recording"] += 1
                self.peers.broadcast(
                    ErrorEvent(
                        code="recording_failed",
                        message=f"Recording has stopped: {failure}. Your demonstrations "
                        "cannot be saved now, so the robot holds still. Please tell the study "
                        "team; this is not your fault.",
                    )
                )
        for finished in self.session.pop_finished():
            snapshot = self.telemetry_snapshot()
            self.archive.episode_ended(self.session, finished, self.config, snapshot)
            self.broadcaster.status_soon()
        await self.broadcaster.after_tick(self.session, result)


async def serve(config: TeleopConfig, host: str = "127.0.0.1", port: int = 0) -> None:
    """Run until cancelled; prints ``READY http://host:port`` once it accepts offers."""
    server = TeleopServer(config)
    runner = web.AppRunner(server.app, access_log=None)
    await runner.setup()
    site = web.TCPSite(runner, host, port)
    await site.start()
    bound = runner.addresses[0][1] if runner.addresses else port
    print(f"READY http://{host}:{bound}", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    # SIGTERM (process managers) and SIGINT stop the server the same way: the running episode
    # is finalized and stored. Installed explicitly because a process started in the
    # background of a script inherits SIGINT ignored, and unblocked because one started by a
    # Ray actor inherits SIGINT blocked (the mask of Ray's event-loop thread).
    handled = _STOP_SIGNALS if _main_thread() else ()
    for sig in handled:
        loop.add_signal_handler(sig, stop.set)
    if handled:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, handled)
    try:
        await stop.wait()
    finally:
        for sig in handled:
            loop.remove_signal_handler(sig)
        await runner.cleanup()


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _main_thread() -> bool:
    """Signal handlers can only be installed from the main thread."""
    return threading.current_thread() is threading.main_thread()
