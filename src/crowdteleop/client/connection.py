"""A Python client of a teleop server, speaking WebRTC exactly as a browser or phone does."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections import deque
from collections.abc import Awaitable, Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import aiohttp
import numpy as np
import numpy.typing as npt
from aiortc import (
    MediaStreamTrack,
    RTCConfiguration,
    RTCIceTransportPolicy,
    RTCPeerConnection,
    RTCSessionDescription,
)
from aiortc.mediastreams import MediaStreamError
from av import VideoFrame
from pydantic import BaseModel

from crowdteleop.client.latency import FrameMatcher, LatencyTracker
from crowdteleop.client.receiver import complete_frames_on_marker
from crowdteleop.teleop.messages import IceServer, OfferAnswer, OfferRequest
from crowdteleop.teleop.peering import rtc_ice_servers
from crowdteleop.teleop.protocol import (
    PROTOCOL_VERSION,
    EpisodeEnded,
    EpisodeSaved,
    ErrorEvent,
    FrameTag,
    HapticEvent,
    Hello,
    PeerRole,
    PrivilegedState,
    ServerPing,
    TaskStatus,
    Telemetry,
    parse_server_message,
)
from crowdteleop.vocab import DeviceKind

log = logging.getLogger(__name__)


class OfferRefusedError(ConnectionError):
    """The server answered the offer with an error (wrong token, full, ...)."""

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(f"{status} {code}: {message}")
        self.status, self.code = status, code


class ConnectionLostError(ConnectionError):
    """The peer connection failed (no answer to ICE consent checks for ~30 s: a network gone)
    or was closed by the server: nothing more will arrive on it. A page says "reload to
    reconnect"; a bot connects again."""


@dataclass
class ClientState:
    """Everything the server told this client, newest last."""

    hello: Hello | None = None
    status: TaskStatus | None = None
    telemetry: Telemetry | None = None
    privileged: PrivilegedState | None = None
    episodes: list[EpisodeEnded] = field(default_factory=list)
    saved: list[EpisodeSaved] = field(default_factory=list)
    haptics: list[HapticEvent] = field(default_factory=list)
    errors: list[ErrorEvent] = field(default_factory=list)
    frames_received: int = 0
    latest_frame: npt.NDArray[np.uint8] | None = None
    frame_times: deque[float] = field(default_factory=lambda: deque(maxlen=100))

    def fps(self) -> float:
        if len(self.frame_times) < 2:
            return 0.0
        span = self.frame_times[-1] - self.frame_times[0]
        return (len(self.frame_times) - 1) / span if span > 0 else 0.0

    def keep(self, message: BaseModel) -> None:
        """Keep what a server message says: the latest hello, status, telemetry and privileged
        state; every haptic, episode end, saved episode and error."""
        if isinstance(message, Hello):
            self.hello = message
        elif isinstance(message, TaskStatus):
            self.status = message
        elif isinstance(message, Telemetry):
            self.telemetry = message
        elif isinstance(message, PrivilegedState):
            self.privileged = message
        elif isinstance(message, HapticEvent):
            self.haptics.append(message)
        elif isinstance(message, EpisodeEnded):
            self.episodes.append(message)
        elif isinstance(message, EpisodeSaved):
            self.saved.append(message)
        elif isinstance(message, ErrorEvent):
            self.errors.append(message)


@dataclass(frozen=True)
class IceOptions:
    """How a client reaches the server: its STUN/TURN servers, and whether to use only TURN's
    relayed candidates (as a browser with iceTransportPolicy "relay")."""

    servers: Sequence[IceServer | str] = ()
    relay_only: bool = False


class TeleopClient:
    """Connect with `await connect()`; send commands; read `state`; `await close()`."""

    def __init__(
        self,
        base_url: str,
        token: str,
        role: PeerRole = "worker",
        device: DeviceKind = "bot",
        admin_token: str | None = None,
        video: bool = True,
        ice: IceOptions = IceOptions(),
        offer_via: Callable[[str], Awaitable[OfferAnswer]] | None = None,
    ) -> None:
        """`offer_via(sdp)` signals through someone else (the coordinator, as a worker's page
        does) instead of posting to the teleop server's `/offer` with `token`. Set
        `on_privileged` to hear each privileged state as it arrives."""
        self.offer_via = offer_via
        self.base_url = base_url.rstrip("/")
        self.token, self.role, self.device = token, role, device
        self.admin_token = admin_token
        self.video = video and role != "phone"
        self.state = ClientState()
        self.matcher = FrameMatcher()
        self.latency = LatencyTracker()
        self.on_privileged: Callable[[PrivilegedState], None] | None = None
        complete_frames_on_marker()  # frames reach us when a browser would see them
        servers = rtc_ice_servers([IceServer.model_validate(server) for server in ice.servers])
        policy = RTCIceTransportPolicy.RELAY if ice.relay_only else RTCIceTransportPolicy.ALL
        self.pc = RTCPeerConnection(RTCConfiguration(iceServers=servers, iceTransportPolicy=policy))
        self._channels: dict[str, Any] = {}
        self._seq = 0
        self._reported = 0
        self._tasks: list[asyncio.Task[Any]] = []
        self._changed = asyncio.Event()
        self.pc.on("connectionstatechange", self._changed.set)  # waiters look again
        self.peer_id = ""

    @property
    def lost(self) -> bool:
        """The connection failed or was closed (by either side)."""
        return self.pc.connectionState in ("failed", "closed")

    # --- connecting -----------------------------------------------------------------------

    async def connect(self, timeout: float = 30.0) -> None:
        self._channels["control"] = self.pc.createDataChannel(
            "control", ordered=False, maxRetransmits=0
        )
        self._channels["events"] = self.pc.createDataChannel("events")
        self._channels["events"].on("message", self._on_message)
        if self.role == "admin":
            self._channels["admin"] = self.pc.createDataChannel("admin")
            self._channels["admin"].on("message", self._on_message)
        if self.video:
            self.pc.addTransceiver("video", direction="recvonly")
            self.pc.on("track", self._on_track)
        await self.pc.setLocalDescription(await self.pc.createOffer())
        sdp = self.pc.localDescription.sdp
        if self.offer_via is not None:
            accepted = await self.offer_via(sdp)
        else:
            accepted = await self._offer_directly(sdp)
        self.peer_id = accepted.peer_id
        await self.pc.setRemoteDescription(RTCSessionDescription(accepted.sdp, accepted.type))
        await self.wait_for(lambda s: s.hello is not None, timeout)

    async def _offer_directly(self, sdp: str) -> OfferAnswer:
        offer = OfferRequest(
            sdp=sdp, token=self.token, role=self.role, admin_token=self.admin_token or None
        )
        async with (
            aiohttp.ClientSession() as http,
            http.post(
                f"{self.base_url}/offer",
                data=offer.model_dump_json(),
                headers={"Content-Type": "application/json"},
            ) as response,
        ):
            answer = await response.json()
            if response.status != 200:
                raise OfferRefusedError(
                    response.status, answer.get("error", "?"), answer.get("message", "")
                )
        return OfferAnswer.model_validate(answer)

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, MediaStreamError):
                await task
        await self.pc.close()

    async def wait_for(self, predicate: Callable[[ClientState], bool], timeout: float) -> None:
        """Wait until `predicate(state)` holds; TimeoutError names what was awaited, and
        ConnectionLostError says when it never can."""
        deadline = time.monotonic() + timeout
        while not predicate(self.state):
            if self.lost:
                raise ConnectionLostError(
                    f"the connection to the teleop server is {self.pc.connectionState}"
                )
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"timed out after {timeout} s waiting for the server")
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), min(remaining, 0.5))

    # --- receiving ------------------------------------------------------------------------

    def _on_track(self, track: MediaStreamTrack) -> None:
        self._tasks.append(asyncio.create_task(self._read_video(track)))

    async def _read_video(self, track: MediaStreamTrack) -> None:
        while True:
            try:
                frame = await track.recv()
            except MediaStreamError:
                return
            # The server sends one video track; aiortc's decoders stamp every frame's pts.
            assert isinstance(frame, VideoFrame) and frame.pts is not None
            now = time.monotonic()
            self.state.frames_received += 1
            self.state.frame_times.append(now)
            if frame.width > 2:
                rgb = frame.to_ndarray(format="rgb24")  # uint8 already: asarray copies nothing
                self.state.latest_frame = np.asarray(rgb, dtype=np.uint8)
            seq = self.matcher.command_seq_of(frame.pts)
            if seq is not None:
                self.latency.frame_shown(seq, now)
            self._changed.set()

    def _on_message(self, raw: str | bytes) -> None:
        message = parse_server_message(raw)
        if isinstance(message, FrameTag):
            self.matcher.add_tag(message.pts, message.command_seq)
        elif isinstance(message, ServerPing):
            pong = {"type": "pong", "id": message.id, "server_time_s": message.server_time_s}
            self.send_raw("events", {**pong, "client_time_ms": self._now_ms()})
        else:
            self.state.keep(message)
            if isinstance(message, PrivilegedState) and self.on_privileged is not None:
                self.on_privileged(message)
        self._changed.set()

    # --- sending --------------------------------------------------------------------------

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def _now_ms(self) -> float:
        return time.time() * 1e3

    def send_raw(self, channel: str, message: dict[str, Any] | str | bytes) -> bool:
        """Send a message as given (a dict gets ``v``): also how tests send bad input."""
        target = self._channels.get(channel)
        if target is None or target.readyState != "open":
            return False
        if isinstance(message, dict):
            message = json.dumps({"v": PROTOCOL_VERSION, **message})
        target.send(message)
        return True

    def send_pose(
        self,
        position: Iterable[float],
        quaternion: Iterable[float],
        engaged: bool,
        gripper: bool,
    ) -> int:
        seq = self._next_seq()
        self.latency.command_sent(seq, time.monotonic())
        self.send_raw(
            "control",
            {
                "type": "pose",
                "seq": seq,
                "client_time_ms": self._now_ms(),
                "device": self.device,
                "position": [float(x) for x in position],
                "quaternion": [float(x) for x in quaternion],
                "engaged": engaged,
                "gripper": gripper,
            },
        )
        return seq

    def send_clutch(self, engaged: bool) -> int:
        seq = self._next_seq()
        event = {"type": "clutch", "engaged": engaged}
        self.send_raw(
            "events", {**event, "seq": seq, "client_time_ms": self._now_ms(), "device": self.device}
        )
        return seq

    def send_gripper(self, closed: bool) -> int:
        seq = self._next_seq()
        event = {"type": "gripper", "closed": closed}
        self.send_raw(
            "events", {**event, "seq": seq, "client_time_ms": self._now_ms(), "device": self.device}
        )
        return seq

    def request(self, kind: str) -> None:
        """``reset``, ``start``, ``stop`` or ``skip_practice``."""
        self.send_raw("events", {"type": kind})

    def take_control(self) -> None:
        self.send_raw("events", {"type": "take_control", "device": self.device})

    def report_latency(self) -> None:
        """Send the latencies measured since the last report (at most 100) for telemetry."""
        samples = self.latency.samples_ms[self._reported : self._reported + 100]
        self._reported += len(samples)
        self.send_raw("events", {"type": "latency", "samples_ms": samples, "fps": self.state.fps()})
