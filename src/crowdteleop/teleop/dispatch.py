"""What each validated client message does to the session."""

from __future__ import annotations

import time
from collections.abc import Iterable

from pydantic import BaseModel

from crowdteleop.teleop.commands import NotInControlError
from crowdteleop.teleop.peers import Peer
from crowdteleop.teleop.protocol import (
    ClutchEvent,
    GripperEvent,
    LatencyReport,
    Ping,
    PingReply,
    Pong,
    PoseCommand,
    ProtocolError,
    ResetRequest,
    SkipPractice,
    StartRequest,
    StopRequest,
    TakeControl,
    VideoStatus,
)
from crowdteleop.teleop.session import TeleopSession
from crowdteleop.teleop.telemetry import SessionTelemetry

STALE_NOTICE_EVERY_S = 2.0  # a peer whose input arrives late is told, not flooded
MAX_PING_RTT_S = 10.0  # a pong later than this says nothing useful of the client's clock


def worker_video_stalled(peers: Iterable[Peer]) -> bool:
    """Stalled when every worker page showing the video says so: a second tab left hidden in
    the background stalls, the one the worker looks at does not."""
    watching = [peer for peer in peers if peer.role == "worker" and peer.wants_video]
    return bool(watching) and all(peer.video_stalled for peer in watching)


class Dispatcher:
    """Routes messages; returns whether the change is one every peer should hear of now."""

    def __init__(
        self,
        session: TeleopSession,
        telemetry: SessionTelemetry,
        max_input_age_ms: float,
        peers: Iterable[Peer],
    ) -> None:
        self.session = session
        self.telemetry = telemetry
        self.max_input_age_ms = max_input_age_ms
        self.peers = peers

    def handle(self, peer: Peer, channel: str, raw: str | bytes) -> bool:
        try:
            message = peer.guard.admit(channel, raw)
        except ProtocolError as exc:
            peer.send_error(exc.code, str(exc), channel)
            return False
        try:
            return self._apply(peer, message)
        except NotInControlError as exc:
            peer.guard.refuse("not_in_control")
            peer.send_error("not_in_control", str(exc), channel)
            return False

    def _apply(self, peer: Peer, message: BaseModel) -> bool:
        if isinstance(message, PoseCommand | ClutchEvent | GripperEvent):
            self._apply_input(peer, message)
            return False
        if isinstance(message, TakeControl):
            return self.session.board.take_control(peer.peer_id, message.device)
        if isinstance(message, VideoStatus):
            return self._on_video_status(peer, message)
        if isinstance(message, ResetRequest | StartRequest | StopRequest | SkipPractice):
            self._request(message)
        elif isinstance(message, Ping):
            peer.send(PingReply(id=message.id, client_time_ms=message.client_time_ms))
        elif isinstance(message, Pong):
            self._on_pong(peer, message)
        elif isinstance(message, LatencyReport):
            self.telemetry.latency_ms.extend(message.samples_ms)
            if message.fps > 0:
                self.telemetry.client_fps.append(message.fps)
        return True

    def _apply_input(self, peer: Peer, message: PoseCommand | ClutchEvent | GripperEvent) -> None:
        """A device's pose, clutch or gripper command goes to the board unless it is too old;
        one the board finds stale (not newer than the last applied seq) is counted."""
        if self._too_old(peer, message):
            return
        board = self.session.board
        if isinstance(message, PoseCommand):
            applied = board.apply_pose(peer.peer_id, message)
        else:
            applied = board.apply_event(peer.peer_id, message)
        if not applied:
            peer.guard.refuse("stale")

    def _request(self, message: ResetRequest | StartRequest | StopRequest | SkipPractice) -> None:
        if isinstance(message, ResetRequest):
            self.session.request_reset()
        elif isinstance(message, StartRequest):
            self.session.request_start()
        elif isinstance(message, StopRequest):
            self.session.request_stop()
        else:
            self.session.request_skip_practice()

    def _on_video_status(self, peer: Peer, message: VideoStatus) -> bool:
        if peer.role != "worker":
            peer.guard.refuse("not_worker")
            peer.send_error("not_worker", "only the worker's page reports its video")
            return False
        if message.stalled and not peer.video_stalled:
            self.telemetry.video_stalls += 1
        peer.video_stalled = message.stalled
        return self.session.board.set_video_stalled(worker_video_stalled(self.peers))

    def _on_pong(self, peer: Peer, message: Pong) -> None:
        now = time.monotonic()
        rtt_s = now - message.server_time_s
        if not 0 <= rtt_s <= MAX_PING_RTT_S:
            peer.guard.refuse("bad_pong")  # not an echo of one of our pings
            return
        self.telemetry.rtt_ms.append(rtt_s * 1e3)
        if message.client_time_ms is not None:
            peer.clock.add_round_trip(message.server_time_s, now, message.client_time_ms)

    def _too_old(self, peer: Peer, message: PoseCommand | ClutchEvent | GripperEvent) -> bool:
        """A pose, press or gripper command older than the limit is not applied (counted,
        and the peer told every few seconds); a clutch release always is: letting go is safe
        however late it comes."""
        if isinstance(message, ClutchEvent) and not message.engaged:
            return False
        now = time.monotonic()
        age_ms = peer.clock.age_ms(message.client_time_ms, now)
        # Refused only when surely too old: a page whose round trips were all slow (a tab
        # just opened on a busy machine) has a rough clock offset, not necessarily old input.
        if age_ms is None or age_ms - peer.clock.uncertainty_ms() <= self.max_input_age_ms:
            return False
        peer.guard.refuse("stale_input")
        if now - peer.stale_told_s >= STALE_NOTICE_EVERY_S:
            peer.stale_told_s = now
            peer.send_error(
                "stale_input",
                f"your moves reach the robot {age_ms:.0f} ms late (the limit is "
                f"{self.max_input_age_ms:.0f} ms), so they are not applied: check your network",
                "control" if isinstance(message, PoseCommand) else "events",
            )
        return True
