"""The teleop server process: HTTP signaling, WebRTC peers, and the fixed-rate control loop."""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import logging
import secrets
import signal
import threading
import time
from collections import Counter
from typing import Any

from aiohttp import web
from aiortc import (
    RTCConfiguration,
    RTCIceServer,
    RTCPeerConnection,
    RTCRtpSender,
    RTCSessionDescription,
)
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from crowdteleop.recording.wal import recover_orphans
from crowdteleop.teleop.assign import Assignment, assigned_config
from crowdteleop.teleop.clock import FixedRateClock
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.dispatch import Dispatcher
from crowdteleop.teleop.guard import InboundGuard
from crowdteleop.teleop.peers import Peer
from crowdteleop.teleop.protocol import (
    EpisodeEnded,
    EpisodeSaved,
    FrameTag,
    HapticEvent,
    Hello,
    PeerRole,
    PrivilegedState,
    ServerPing,
    TaskStatus,
    Telemetry,
    json_schema,
)
from crowdteleop.teleop.report import report_episode
from crowdteleop.teleop.session import TeleopSession, TickResult
from crowdteleop.teleop.telemetry import SessionTelemetry
from crowdteleop.teleop.video import (
    FrameSource,
    SimVideoTrack,
    YuvConverter,
    configure_encoder_bitrates,
)

log = logging.getLogger(__name__)

MAX_OFFER_BYTES = 64 * 1024
CLIENT_CHANNELS = {"control", "events", "admin"}


class OfferRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")

    sdp: str = Field(max_length=MAX_OFFER_BYTES)
    type: str = Field(pattern="^offer$")
    token: str = Field(max_length=256)
    role: PeerRole = "worker"
    admin_token: str | None = Field(None, max_length=256)


class TeleopServer:
    """Owns the session, its peers and its loop. `await start()`, then serve `app`."""

    def __init__(self, config: TeleopConfig) -> None:
        self.config = config
        self.peers: dict[str, Peer] = {}
        self.frames = FrameSource()
        self._keepalive_yuv = YuvConverter()
        self.telemetry = SessionTelemetry()
        self.clock = FixedRateClock(config.sim.control_hz)
        self.departed_errors: Counter[str] = Counter()
        self.session: TeleopSession
        self.dispatcher: Dispatcher
        self._loop_task: asyncio.Task[None] | None = None
        self._store_tasks: set[asyncio.Task[Any]] = set()
        self._last_publish = 0.0
        self._last_telemetry = 0.0
        self._status_due = True
        self._bytes_mark = (0, time.monotonic())
        self.stored: list[str] = []
        self.app = web.Application(client_max_size=MAX_OFFER_BYTES * 2)
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
        for path in recovered:  # a crashed session's episode: kept for analysis, as "crash"
            uri = await asyncio.to_thread(self.session.storage.put, path, f"other/{path.name}")
            path.unlink(missing_ok=True)
            log.warning("recovered an episode a crashed session left: %s", uri)
        self.dispatcher = Dispatcher(self.session, self.telemetry)
        self._loop_task = asyncio.create_task(self._run_loop(), name="control-loop")

    async def stop(self) -> None:
        if self._loop_task is not None:
            self._loop_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._loop_task
        await asyncio.gather(*(peer.pc.close() for peer in list(self.peers.values())))
        self.peers.clear()
        await self.session.close()
        if self._store_tasks:
            await asyncio.gather(*self._store_tasks, return_exceptions=True)

    # --- HTTP -----------------------------------------------------------------------------

    def _http_error(self, status: int, code: str, message: str) -> web.Response:
        self.telemetry.errors[f"http_{code}"] += 1
        return web.json_response({"error": code, "message": message}, status=status)

    async def handle_offer(self, request: web.Request) -> web.Response:
        try:
            offer = OfferRequest.model_validate_json(await request.read())
        except ValidationError as exc:
            return self._http_error(400, "invalid_offer", str(exc.errors()[0]["msg"]))
        if self.config.standby:
            return self._http_error(409, "standby", "this server has no session yet")
        if not hmac.compare_digest(offer.token.encode(), self.config.token.encode()):
            return self._http_error(401, "bad_token", "the session token is wrong")
        if offer.role == "admin" and not (
            self.config.admin_token
            and offer.admin_token
            and hmac.compare_digest(offer.admin_token.encode(), self.config.admin_token.encode())
        ):
            return self._http_error(403, "bad_admin_token", "admin role needs the admin token")
        if len(self.peers) >= self.config.limits.max_peers:
            return self._http_error(503, "full", "this session has all the peers it allows")
        try:
            answer, peer = await self._connect(offer)
        except Exception as exc:  # a malformed SDP must not take the session down
            log.info("offer refused: %s", exc)
            return self._http_error(400, "invalid_sdp", f"could not use the offer: {exc}")
        return web.json_response({"sdp": answer.sdp, "type": answer.type, "peer_id": peer})

    async def _connect(self, offer: OfferRequest) -> tuple[RTCSessionDescription, str]:
        ice = [RTCIceServer(urls=url) for url in self.config.ice_servers]
        pc = RTCPeerConnection(RTCConfiguration(iceServers=ice))
        limits = self.config.limits
        peer = Peer(
            peer_id=secrets.token_hex(6),
            role=offer.role,
            pc=pc,
            guard=InboundGuard(limits.max_message_bytes, limits.messages_per_second, limits.burst),
        )
        self.peers[peer.peer_id] = peer

        @pc.on("datachannel")
        def on_datachannel(channel: Any) -> None:
            self._attach_channel(peer, channel)

        @pc.on("connectionstatechange")
        async def on_state() -> None:
            if pc.connectionState in ("failed", "closed"):
                await self._drop(peer)

        try:
            video = None
            if offer.role != "phone" and "\nm=video " in offer.sdp:
                # Made before the offer is applied, so the codec preference shapes the answer
                # (aiortc negotiates codecs in setRemoteDescription).
                peer.track = SimVideoTrack(self.frames)
                video = pc.addTransceiver(peer.track, direction="sendonly")
                self._prefer_codec(video)
            sdp = without_mdns_candidates(offer.sdp)
            await pc.setRemoteDescription(RTCSessionDescription(sdp, offer.type))
            await pc.setLocalDescription(await pc.createAnswer())
        except Exception:
            await self._drop(peer)
            raise
        return pc.localDescription, peer.peer_id

    def _prefer_codec(self, transceiver: Any) -> None:
        codecs = RTCRtpSender.getCapabilities("video").codecs
        preferred = [c for c in codecs if c.mimeType == self.config.video.mime_type]
        rtx = [c for c in codecs if c.mimeType == "video/rtx"]
        transceiver.setCodecPreferences(preferred + rtx)

    def _attach_channel(self, peer: Peer, channel: Any) -> None:
        label = channel.label
        if label not in CLIENT_CHANNELS or (label == "admin" and not peer.is_admin):
            peer.guard.refuse("channel")
            channel.close()
            return
        peer.channels[label] = channel

        @channel.on("message")
        def on_message(raw: str | bytes) -> None:
            if label == "admin":
                peer.guard.refuse("channel")
                peer.send_error("channel", "the admin channel is server-to-client only", label)
                return
            if self.dispatcher.handle(peer, label, raw):
                self._broadcast_status_soon()

        if label == "events":

            @channel.on("open")
            def on_open() -> None:
                self._send_hello(peer)

            if channel.readyState == "open":
                self._send_hello(peer)

    def _send_hello(self, peer: Peer) -> None:
        controller = self.session.board.controller
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
                controlling_device=controller.device if controller else None,
            )
        )

    async def _drop(self, peer: Peer) -> None:
        if self.peers.pop(peer.peer_id, None) is None:
            return
        self.departed_errors += peer.errors
        if self.session.board.release(peer.peer_id):
            self.session.request_end("disconnect")
            self._broadcast_status_soon()
        await peer.pc.close()

    async def handle_health(self, _request: web.Request) -> web.Response:
        return web.json_response(
            {
                "status": "ok",
                "session_id": self.config.session_id,
                "peers": len(self.peers),
                "state": self.session.tracker.state,
                "episodes": self.session.tracker.number,
                "successes": self.session.tracker.successes,
                "ticks": self.clock.stats.ticks,
            }
        )

    async def handle_telemetry(self, request: web.Request) -> web.Response:
        expected = f"Bearer {self.config.admin_token}"
        given = request.headers.get("Authorization", "")
        if not self.config.admin_token or not hmac.compare_digest(given, expected):
            return self._http_error(401, "bad_admin_token", "telemetry needs the admin token")
        return web.json_response({**self.telemetry_snapshot(), "stored": self.stored})

    async def handle_assign(self, request: web.Request) -> web.Response:
        """Give a warm spare its session (`teleop/assign.py`)."""
        given = request.headers.get("Authorization", "")
        if not self.config.admin_token or not hmac.compare_digest(
            given, f"Bearer {self.config.admin_token}"
        ):
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
        log.info("assigned to session %s", config.session_id)
        return web.json_response({"session_id": config.session_id})

    async def handle_protocol(self, _request: web.Request) -> web.Response:
        return web.json_response(json_schema())

    # --- the control loop -----------------------------------------------------------------

    def peer_errors(self) -> Counter[str]:
        total = Counter(self.departed_errors)
        for peer in self.peers.values():
            total += peer.errors
        return total

    def telemetry_snapshot(self) -> dict[str, Any]:
        snapshot = self.telemetry.snapshot(self.clock.stats, self.peer_errors())
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
        admins = [p for p in self.peers.values() if p.is_admin]
        result = await self.session.tick(want_privileged=bool(admins))
        for finished in self.session.pop_finished():
            self._broadcast(
                EpisodeEnded(
                    episode=finished.number,
                    outcome=finished.outcome,
                    steps=finished.steps,
                    successes=self.session.tracker.successes,
                )
            )
            self._store(finished)
            self._status_due = True
        if result is not None:
            await self._publish(result)
            for contact in result.haptics:
                self._broadcast(
                    HapticEvent(
                        intensity=min(1.0, max(0.0, contact.intensity)),
                        robot_part=contact.robot_part,
                        object=contact.object,
                    )
                )
            if result.privileged is not None:
                message = PrivilegedState(
                    step=self.clock.stats.ticks,
                    command_seq=result.command_seq,
                    **result.privileged,
                )
                for admin in admins:
                    admin.send(message, "admin")
            if self._status_due or self.clock.stats.ticks % 2 == 0:
                self._broadcast(self._status(result))
                self._status_due = False
        await self._maybe_send_telemetry()

    async def _publish(self, result: TickResult) -> None:
        now = time.monotonic()
        keepalive = 1.0 / self.config.video.keepalive_fps
        if not result.image_changed and now - self._last_publish < keepalive:
            return
        self._last_publish = now
        # A keep-alive re-sends the picture as a new frame: a frame object is never given two
        # timestamps, since an encoder thread may still be reading the previous one.
        video_frame = result.video_frame or self._keepalive_yuv.convert(result.image)
        frame = await self.frames.publish(video_frame, result.command_seq)
        self.telemetry.frame_published()
        tag = FrameTag(
            pts=frame.pts, command_seq=frame.command_seq, server_time_s=frame.server_time_s
        )
        for peer in self.peers.values():
            if peer.wants_video:
                peer.send(tag)

    def _status(self, result: TickResult) -> TaskStatus:
        tracker = self.session.tracker
        controller = self.session.board.controller
        progress = result.progress
        return TaskStatus(
            episode=tracker.number,
            state=tracker.state,
            elapsed_s=round(tracker.elapsed_s, 3),
            time_limit_s=tracker.time_limit_s,
            success=result.success,
            stage=progress.stage if progress else "",
            message=progress.message if progress else "",
            completed=progress.completed if progress else 0,
            total=progress.total if progress else 0,
            controlling_device=controller.device if controller else None,
            successes=tracker.successes,
            end_effector=tuple(float(x) for x in result.end_effector),
        )

    def _broadcast_status_soon(self) -> None:
        self._status_due = True

    def _broadcast(self, message: BaseModel) -> None:
        for peer in self.peers.values():
            peer.send(message)

    def _store(self, finished: Any) -> None:
        snapshot = self.telemetry_snapshot()

        async def store() -> None:
            try:
                uri = await self.session.store(finished, {"telemetry": snapshot})
            except Exception:
                log.exception("storing episode %s failed", finished.episode_id)
                self.telemetry.errors["storage"] += 1
                return
            if uri is None:
                return
            self.stored.append(uri)
            self._broadcast(
                EpisodeSaved(episode=finished.number, outcome=finished.outcome, uri=uri)
            )
            if self.config.report_url:
                payload = {
                    "session_id": self.config.session_id,
                    "worker_id": self.config.worker_id,
                    "episode": finished.number,
                    "episode_id": finished.episode_id,
                    "outcome": finished.outcome,
                    "steps": finished.steps,
                    "duration_s": finished.steps / self.config.sim.control_hz,
                    "uri": uri,
                    "telemetry": snapshot,
                }
                ok = await report_episode(self.config.report_url, self.config.report_token, payload)
                if not ok:
                    self.telemetry.errors["report"] += 1

        task = asyncio.create_task(store())
        self._store_tasks.add(task)
        task.add_done_callback(self._store_tasks.discard)

    async def _maybe_send_telemetry(self) -> None:
        now = time.monotonic()
        if now - self._last_telemetry < self.config.telemetry_interval_s:
            return
        self._last_telemetry = now
        self.telemetry.update_fps()
        await self._update_bitrate()
        snapshot = self.telemetry_snapshot()
        message = Telemetry(
            loop_hz=snapshot["loop_hz"],
            jitter_ms=snapshot["jitter_ms"],
            overruns=snapshot["overruns"],
            frames_sent=snapshot["frames_sent"],
            fps=snapshot["fps"],
            bitrate_kbps=snapshot["bitrate_kbps"],
            rtt_ms=snapshot["rtt_ms"],
            errors=snapshot["errors"],
        )
        for peer in self.peers.values():
            peer.send(message)
            peer.send(ServerPing(id=self.clock.stats.ticks, server_time_s=time.monotonic()))

    async def _update_bitrate(self) -> None:
        """Bits the video senders put on the wire since the last report."""
        total = 0
        for peer in list(self.peers.values()):
            if not peer.wants_video:
                continue
            for sender in peer.pc.getSenders():
                if sender.track is None:
                    continue
                stats = await sender.getStats()
                total += sum(
                    getattr(s, "bytesSent", 0) for s in stats.values() if s.type == "outbound-rtp"
                )
        previous, then = self._bytes_mark
        now = time.monotonic()
        if now > then and total >= previous:
            self.telemetry.bitrate_kbps = (total - previous) * 8 / 1000 / (now - then)
        self._bytes_mark = (total, now)


def without_mdns_candidates(sdp: str) -> str:
    """Drop the browser's mDNS (``*.local``) host candidates from an offer.

    Browsers hide local addresses behind mDNS names; aioice resolves each one before the answer
    is made, which costs about a second (and fails where multicast does not pass). Without them
    the connection still forms: the browser checks our candidates, and its address is learnt from
    those checks (a peer-reflexive candidate), as the ICE standard provides.
    """
    lines = sdp.split("\r\n")
    kept = [line for line in lines if not (line.startswith("a=candidate:") and ".local " in line)]
    return "\r\n".join(kept)


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
    # background of a script inherits SIGINT ignored.
    handled = _STOP_SIGNALS if _main_thread() else ()
    for sig in handled:
        loop.add_signal_handler(sig, stop.set)
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
