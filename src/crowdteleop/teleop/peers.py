"""One connected client (browser, phone or admin bot) of a teleop session."""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field

from aiortc import RTCDataChannel, RTCPeerConnection
from pydantic import BaseModel

from crowdteleop.teleop.client_clock import ClientClock
from crowdteleop.teleop.guard import InboundGuard, TokenBucket
from crowdteleop.teleop.protocol import ErrorEvent, PeerRole, encode
from crowdteleop.teleop.video import SimVideoTrack

log = logging.getLogger(__name__)

ERROR_EVENTS_PER_SECOND = 20.0  # a flooding client gets counted, not an echo of its flood


@dataclass
class Peer:
    peer_id: str
    role: PeerRole
    pc: RTCPeerConnection
    guard: InboundGuard
    track: SimVideoTrack | None = None
    channels: dict[str, RTCDataChannel] = field(default_factory=dict)
    error_budget: TokenBucket = field(
        default_factory=lambda: TokenBucket(ERROR_EVENTS_PER_SECOND, 20)
    )
    errors_suppressed: int = 0
    clock: ClientClock = field(default_factory=ClientClock)  # to date its poses
    stale_told_s: float = float("-inf")  # when it was last told its input arrives too late
    video_stalled: bool = False  # its page said its video stopped

    @property
    def wants_video(self) -> bool:
        return self.track is not None

    @property
    def is_admin(self) -> bool:
        return self.role == "admin"

    @property
    def errors(self) -> Counter[str]:
        return self.guard.errors

    def send(self, message: BaseModel, channel: str = "events") -> bool:
        """Queue a message if the channel is open; False if it is not (yet)."""
        target = self.channels.get(channel)
        if target is None or target.readyState != "open":
            return False
        try:
            target.send(encode(message))
        except Exception:  # a channel closing under us is a disconnect, handled elsewhere
            log.debug("send on %s to %s failed", channel, self.peer_id, exc_info=True)
            return False
        return True

    def send_error(self, code: str, message: str, channel: str = "") -> None:
        if self.error_budget.take():
            self.send(ErrorEvent(code=code, message=message, channel=channel))
        else:
            self.errors_suppressed += 1
