"""The session's picture as a WebRTC video track: one frame per control step, tagged."""

from __future__ import annotations

import asyncio
import fractions
import time
from dataclasses import dataclass

import aiortc.codecs.h264
import aiortc.codecs.vpx
import numpy as np
import numpy.typing as npt
from aiortc import MediaStreamTrack
from av import VideoFrame
from av.video.reformatter import VideoReformatter

from crowdteleop.teleop.config import VideoConfig

RTP_CLOCK_HZ = 90_000
TIME_BASE = fractions.Fraction(1, RTP_CLOCK_HZ)


def configure_encoder_bitrates(video: VideoConfig) -> None:
    """Set aiortc's encoder start / floor / ceiling bitrates for this process.

    aiortc reads them from module constants when an encoder is made and when the receiver's
    estimate (REMB) arrives, with no per-connection option. One teleop server process serves
    one session, so the process-wide setting is the session's setting.
    """
    if video.codec == "vp8":
        aiortc.codecs.vpx.DEFAULT_BITRATE = video.start_bitrate_bps
        aiortc.codecs.vpx.MIN_BITRATE = video.min_bitrate_bps
        aiortc.codecs.vpx.MAX_BITRATE = video.max_bitrate_bps
    else:
        aiortc.codecs.h264.DEFAULT_BITRATE = video.start_bitrate_bps
        aiortc.codecs.h264.MIN_BITRATE = video.min_bitrate_bps
        aiortc.codecs.h264.MAX_BITRATE = video.max_bitrate_bps


class YuvConverter:
    """RGB frames to the encoder's YUV 4:2:0, with one converter kept for the session.

    aiortc converts each RGB frame itself, building a new swscale context (and its threads)
    every time: about half a millisecond a frame. Converting here, in the simulation thread,
    with one context, costs a fraction of that and keeps the work off the event loop.
    """

    def __init__(self) -> None:
        self._reformatter = VideoReformatter()

    def convert(self, image: npt.NDArray[np.uint8]) -> VideoFrame:
        rgb = VideoFrame.from_ndarray(image, format="rgb24")
        return self._reformatter.reformat(rgb, format="yuv420p")


@dataclass(frozen=True)
class PublishedFrame:
    index: int
    pts: int  # RTP clock ticks since the session's first frame
    frame: VideoFrame  # yuv420p; one object per publication, never re-sent with another pts
    command_seq: int
    server_time_s: float


class FrameSource:
    """The latest frame of the session; every video track waits on it.

    Tracks never queue frames: a slow encoder skips to the newest picture instead of falling
    behind (latest wins, as for commands).
    """

    def __init__(self) -> None:
        self._changed = asyncio.Condition()
        self._latest: PublishedFrame | None = None
        self._origin = time.monotonic()
        self.published = 0

    @property
    def latest(self) -> PublishedFrame | None:
        return self._latest

    async def publish(self, frame: VideoFrame, command_seq: int) -> PublishedFrame:
        pts = round((time.monotonic() - self._origin) * RTP_CLOCK_HZ)
        if self._latest is not None and pts <= self._latest.pts:
            pts = self._latest.pts + 1
        frame.pts = pts
        frame.time_base = TIME_BASE
        published = PublishedFrame(self.published, pts, frame, command_seq, time.time())
        self.published += 1
        async with self._changed:
            self._latest = published
            self._changed.notify_all()
        return published

    async def next_after(self, index: int) -> PublishedFrame:
        async with self._changed:
            await self._changed.wait_for(
                lambda: self._latest is not None and self._latest.index > index
            )
            assert self._latest is not None
            return self._latest


class SimVideoTrack(MediaStreamTrack):
    """One peer's view of the FrameSource. aiortc's sender pulls frames from `recv`."""

    kind = "video"

    def __init__(self, source: FrameSource) -> None:
        super().__init__()
        self._source = source
        self._last_index = -1
        self.frames_sent = 0

    async def recv(self) -> VideoFrame:
        published = await self._source.next_after(self._last_index)
        self._last_index = published.index
        self.frames_sent += 1
        return published.frame
