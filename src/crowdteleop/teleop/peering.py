"""The session's connected clients: an accepted offer becomes a `Peer` whose data channels feed
the dispatcher; a peer that leaves, or does not connect in time, is closed and counted."""

from __future__ import annotations

import asyncio
import logging
import secrets
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from aiortc import (
    RTCConfiguration,
    RTCDataChannel,
    RTCIceServer,
    RTCPeerConnection,
    RTCRtpSender,
    RTCRtpTransceiver,
    RTCSessionDescription,
)
from pydantic import BaseModel

from crowdteleop.teleop.config import LimitsConfig, VideoConfig
from crowdteleop.teleop.guard import InboundGuard
from crowdteleop.teleop.messages import IceServer, OfferRequest
from crowdteleop.teleop.peers import Peer
from crowdteleop.teleop.remb import RembTap
from crowdteleop.teleop.video import FrameSource, SimVideoTrack

log = logging.getLogger(__name__)

CLIENT_CHANNELS = frozenset({"control", "events", "admin"})

MessageHandler = Callable[[Peer, str, str | bytes], None]
PeerCallback = Callable[[Peer], None]


@dataclass
class LinkStats:
    bytes_sent: int = 0
    packets_sent: int = 0
    packets_lost: int = 0  # as the receivers' RTCP reports counted them
    rtcp_rtt_s: float = 0.0
    receiver_estimate_kbps: float | None = None  # the lowest REMB a video receiver sent


class PeerSet:
    """Every peer of one session, from offer to departure.

    ``on_message`` gets each message a client sends on ``control`` or ``events``;
    ``on_events_open`` runs when a peer's events channel opens (the server says hello);
    ``on_left`` runs once per peer that leaves (it may have been driving the arm).

    A peer holds one of the session's ``limits.max_peers`` slots from its offer on, so one
    that is not connected within ``limits.connect_timeout_s`` (its ICE never completed, or it
    lost its connection and did not get it back) is dropped and counted as
    ``peer_connect_timeout``: a stale offer cannot lock the worker out of their robot.
    aiortc itself has no "disconnected" state (a lost peer turns "failed" once ICE consent
    expires, about 30 s), and a peer made from an offer without transports never leaves "new".
    """

    def __init__(
        self,
        ice_servers: list[IceServer],
        limits: LimitsConfig,
        video: VideoConfig,
        frames: FrameSource,
        on_message: MessageHandler,
        on_events_open: PeerCallback,
        on_left: PeerCallback,
    ) -> None:
        self.ice_servers = ice_servers  # a warm spare gets its session's on assignment
        self._limits = limits
        self._video = video
        self._frames = frames
        self._on_message = on_message
        self._remb: dict[str, RembTap] = {}  # peer id -> its video sender's REMB tap
        self._on_events_open = on_events_open
        self._on_left = on_left
        self._peers: dict[str, Peer] = {}
        self._departed_errors: Counter[str] = Counter()
        self._unconnected: dict[str, asyncio.Task[None]] = {}  # peer id -> its waiting timer
        self._timers: set[asyncio.Task[None]] = set()  # every timer until it ends

    def __len__(self) -> int:
        return len(self._peers)

    def __iter__(self) -> Iterator[Peer]:
        return iter(list(self._peers.values()))

    @property
    def full(self) -> bool:
        return len(self._peers) >= self._limits.max_peers

    def admins(self) -> list[Peer]:
        return [peer for peer in self._peers.values() if peer.is_admin]

    def broadcast(self, message: BaseModel) -> None:
        for peer in self._peers.values():
            peer.send(message)

    def errors(self) -> Counter[str]:
        """Refusals counted on every peer, those that left included."""
        total = Counter(self._departed_errors)
        for peer in self._peers.values():
            total += peer.errors
        return total

    async def connect(self, offer: OfferRequest) -> tuple[RTCSessionDescription, str]:
        """Answer `offer`; the new peer's id comes back with the answer."""
        pc = RTCPeerConnection(RTCConfiguration(iceServers=rtc_ice_servers(self.ice_servers)))
        limits = self._limits
        peer = Peer(
            peer_id=secrets.token_hex(6),
            role=offer.role,
            pc=pc,
            guard=InboundGuard(limits.max_message_bytes, limits.messages_per_second, limits.burst),
        )
        self._peers[peer.peer_id] = peer
        self._start_connect_timer(peer)

        @pc.on("datachannel")
        def on_datachannel(channel: RTCDataChannel) -> None:
            self._attach_channel(peer, channel)

        @pc.on("connectionstatechange")
        async def on_state() -> None:
            state = pc.connectionState
            if state in ("failed", "closed"):
                await self.drop(peer)
            elif state == "connected":
                self._stop_connect_timer(peer)
            elif peer.peer_id in self._peers:  # connecting again (or "disconnected")
                self._start_connect_timer(peer)

        try:
            if offer.role != "phone" and "\nm=video " in offer.sdp:
                # Made before the offer is applied, so the codec preference shapes the answer
                # (aiortc negotiates codecs in setRemoteDescription).
                peer.track = SimVideoTrack(self._frames)
                transceiver = pc.addTransceiver(peer.track, direction="sendonly")
                self._prefer_codec(transceiver)
                self._remb[peer.peer_id] = RembTap(transceiver.sender)
            sdp = without_mdns_candidates(offer.sdp)
            await pc.setRemoteDescription(RTCSessionDescription(sdp, offer.type))
            await pc.setLocalDescription(await pc.createAnswer())
        except Exception:
            await self.drop(peer)
            raise
        return pc.localDescription, peer.peer_id

    async def drop(self, peer: Peer) -> None:
        """Close a peer that left (idempotent)."""
        self._stop_connect_timer(peer)
        self._remb.pop(peer.peer_id, None)
        if self._peers.pop(peer.peer_id, None) is None:
            return
        self._departed_errors += peer.errors
        self._on_left(peer)
        await peer.pc.close()

    async def close(self) -> None:
        waiting, self._unconnected = list(self._unconnected.values()), {}
        for timer in waiting:
            timer.cancel()
        # A timer already dropping its peer finishes closing it.
        await asyncio.gather(*self._timers, return_exceptions=True)
        peers, self._peers = list(self._peers.values()), {}
        await asyncio.gather(*(peer.pc.close() for peer in peers))

    def _start_connect_timer(self, peer: Peer) -> None:
        """Drop `peer` unless it is connected within ``limits.connect_timeout_s`` (a timer
        already running for it keeps its deadline)."""
        if peer.peer_id in self._unconnected:
            return
        timer = asyncio.create_task(
            self._drop_if_unconnected(peer), name=f"connect-timer-{peer.peer_id}"
        )
        self._unconnected[peer.peer_id] = timer
        self._timers.add(timer)
        timer.add_done_callback(self._timers.discard)

    def _stop_connect_timer(self, peer: Peer) -> None:
        timer = self._unconnected.pop(peer.peer_id, None)
        if timer is not None:
            timer.cancel()

    async def _drop_if_unconnected(self, peer: Peer) -> None:
        await asyncio.sleep(self._limits.connect_timeout_s)
        # Out of the waiting timers: from here on `drop` and `close` let it finish.
        self._unconnected.pop(peer.peer_id, None)
        if peer.peer_id not in self._peers or peer.pc.connectionState == "connected":
            return
        log.info(
            "peer %s (%s) not connected after %g s (%s): dropped",
            peer.peer_id,
            peer.role,
            self._limits.connect_timeout_s,
            peer.pc.connectionState,
        )
        self._departed_errors["peer_connect_timeout"] += 1
        try:
            await self.drop(peer)
        except Exception:  # closing a half-made connection must not go unnoticed
            log.exception("closing unconnected peer %s failed", peer.peer_id)

    async def video_link(self) -> LinkStats:
        """What the video senders put on the wire so far and what the receivers' RTCP reports
        said of it (packets lost, round trip): the link as measured, for telemetry."""
        link = LinkStats()
        for peer in list(self._peers.values()):
            if not peer.wants_video:
                continue
            tap = self._remb.get(peer.peer_id)
            if tap is not None and tap.estimate_bps is not None:
                kbps = tap.estimate_bps / 1000
                known = link.receiver_estimate_kbps
                link.receiver_estimate_kbps = kbps if known is None else min(known, kbps)
            for sender in peer.pc.getSenders():
                if sender.track is None:
                    continue
                for s in (await sender.getStats()).values():
                    if s.type == "outbound-rtp":
                        link.bytes_sent += getattr(s, "bytesSent", 0)
                        link.packets_sent += getattr(s, "packetsSent", 0)
                    elif s.type == "remote-inbound-rtp":
                        link.packets_lost += max(0, getattr(s, "packetsLost", 0))
                        if getattr(s, "roundTripTime", None):
                            link.rtcp_rtt_s = max(link.rtcp_rtt_s, float(s.roundTripTime))
        return link

    def _prefer_codec(self, transceiver: RTCRtpTransceiver) -> None:
        codecs = RTCRtpSender.getCapabilities("video").codecs
        preferred = [c for c in codecs if c.mimeType == self._video.mime_type]
        rtx = [c for c in codecs if c.mimeType == "video/rtx"]
        transceiver.setCodecPreferences(preferred + rtx)

    def _attach_channel(self, peer: Peer, channel: RTCDataChannel) -> None:
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
            self._on_message(peer, label, raw)

        if label == "events":

            @channel.on("open")
            def on_open() -> None:
                self._on_events_open(peer)

            if channel.readyState == "open":
                self._on_events_open(peer)


def rtc_ice_servers(servers: list[IceServer]) -> list[RTCIceServer]:
    """aiortc's form of our `IceServer`s (TURN credentials included)."""
    return [
        RTCIceServer(urls=s.urls, username=s.username, credential=s.credential) for s in servers
    ]


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
