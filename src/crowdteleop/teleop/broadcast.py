"""What the peers hear after each control step: the new frame and its tag, status, haptics,
privileged state for admins, and, once per telemetry interval, telemetry and a ping."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from crowdteleop.teleop.clock import LoopStats
from crowdteleop.teleop.config import VideoConfig
from crowdteleop.teleop.peering import PeerSet
from crowdteleop.teleop.protocol import (
    FrameTag,
    HapticEvent,
    PrivilegedState,
    ServerPing,
    TaskStatus,
    Telemetry,
)
from crowdteleop.teleop.session import TeleopSession, TickResult
from crowdteleop.teleop.telemetry import SessionTelemetry
from crowdteleop.teleop.video import FrameSource, YuvConverter

STATUS_EVERY_TICKS = 2  # 10 Hz at 20 Hz control: smooth enough for a progress bar


class TickBroadcaster:
    """Turns a tick's result into messages; owns the keep-alive and the telemetry cadence."""

    def __init__(
        self,
        peers: PeerSet,
        frames: FrameSource,
        telemetry: SessionTelemetry,
        loop: LoopStats,
        video: VideoConfig,
        telemetry_interval_s: float,
        snapshot: Callable[[], dict[str, Any]],
    ) -> None:
        self._peers = peers
        self._frames = frames
        self._telemetry = telemetry
        self._loop = loop
        self._video = video
        self._telemetry_interval_s = telemetry_interval_s
        self._snapshot = snapshot
        self._keepalive_yuv = YuvConverter()
        self._last_publish_s = 0.0
        self._last_telemetry_s = 0.0
        self._status_due = True

    def status_soon(self) -> None:
        """Send the status with the next tick, whatever the cadence (something changed)."""
        self._status_due = True

    async def after_tick(self, session: TeleopSession, result: TickResult | None) -> None:
        if result is not None:
            await self._publish(result)
            for contact in result.haptics:
                self._peers.broadcast(
                    HapticEvent(
                        intensity=min(1.0, max(0.0, contact.intensity)),
                        robot_part=contact.robot_part,
                        object=contact.object,
                    )
                )
            admins = self._peers.admins()
            if result.privileged is not None and admins:
                message = PrivilegedState(
                    step=self._loop.ticks, command_seq=result.command_seq, **result.privileged
                )
                for admin in admins:
                    admin.send(message, "admin")
            if self._status_due or self._loop.ticks % STATUS_EVERY_TICKS == 0:
                self._peers.broadcast(status_of(session, result))
                self._status_due = False
        await self._maybe_send_telemetry()

    async def _publish(self, result: TickResult) -> None:
        now = time.monotonic()
        keepalive_s = 1.0 / self._video.keepalive_fps
        if not result.image_changed and now - self._last_publish_s < keepalive_s:
            return
        self._last_publish_s = now
        # A keep-alive re-sends the picture as a new frame: a frame object is never given two
        # timestamps, since an encoder thread may still be reading the previous one.
        video_frame = result.video_frame or self._keepalive_yuv.convert(result.image)
        frame = await self._frames.publish(video_frame, result.command_seq)
        self._telemetry.frame_published()
        tag = FrameTag(
            pts=frame.pts, command_seq=frame.command_seq, server_time_s=frame.server_time_s
        )
        for peer in self._peers:
            if peer.wants_video:
                peer.send(tag)

    async def _maybe_send_telemetry(self) -> None:
        now = time.monotonic()
        if now - self._last_telemetry_s < self._telemetry_interval_s:
            return
        self._last_telemetry_s = now
        self._telemetry.update_fps()
        self._telemetry.update_link(await self._peers.video_link())
        snapshot = self._snapshot()
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
        for peer in self._peers:
            peer.send(message)
            peer.send(ServerPing(id=self._loop.ticks, server_time_s=time.monotonic()))


def status_of(session: TeleopSession, result: TickResult) -> TaskStatus:
    """The task's state as the worker's page shows it."""
    tracker = session.tracker
    driver = session.board.driver
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
        controlling_device=driver.device if driver else None,
        successes=tracker.successes,
        video_stalled=session.board.video_stalled,
        clutch=session.board.clutch.state,
        practice=session.practice.stage,
        practice_left_s=round(session.practice.left_s, 1),
        practice_reached=session.practice.reached,
        end_effector=(
            float(result.end_effector[0]),
            float(result.end_effector[1]),
            float(result.end_effector[2]),
        ),
    )
