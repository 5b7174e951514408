"""What each validated client message does to the session."""

from __future__ import annotations

import time

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
    StartRequest,
    StopRequest,
    TakeControl,
)
from crowdteleop.teleop.session import TeleopSession
from crowdteleop.teleop.telemetry import SessionTelemetry


class Dispatcher:
    """Routes messages; returns whether the change is one every peer should hear of now."""

    def __init__(self, session: TeleopSession, telemetry: SessionTelemetry) -> None:
        self.session = session
        self.telemetry = telemetry

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
        board = self.session.board
        if isinstance(message, PoseCommand):
            if not board.apply_pose(peer.peer_id, message):
                peer.guard.refuse("stale")
            return False
        if isinstance(message, ClutchEvent | GripperEvent):
            if not board.apply_event(peer.peer_id, message):
                peer.guard.refuse("stale")
            return False
        if isinstance(message, TakeControl):
            return board.take_control(peer.peer_id, message.device)
        if isinstance(message, ResetRequest):
            self.session.request_reset()
        elif isinstance(message, StartRequest):
            self.session.request_start()
        elif isinstance(message, StopRequest):
            self.session.request_stop()
        elif isinstance(message, Ping):
            peer.send(PingReply(id=message.id, client_time_ms=message.client_time_ms))
        elif isinstance(message, Pong):
            self.telemetry.rtt_ms.append((time.monotonic() - message.server_time_s) * 1e3)
        elif isinstance(message, LatencyReport):
            self.telemetry.latency_ms.extend(message.samples_ms)
            if message.fps > 0:
                self.telemetry.client_fps.append(message.fps)
        return True
